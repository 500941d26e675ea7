//! Block matching on rectified pairs, as OpenCV's StereoBM: x-Sobel prefilter, sums of
//! absolute differences (SAD) over a square window, texture threshold, uniqueness
//! ratio, left–right consistency, speckle removal and sub-pixel refinement.
//!
//! Speed comes from never summing a window twice. For each image row the matcher keeps
//! `col[x][k]`, the SAD of one window-high column at every candidate disparity, laid out
//! with the disparities of one column contiguous (`[x][disparity]`), and updates it by
//! adding the row entering the window and subtracting the row leaving it. The window
//! cost slides along x the same way. Disparities are stored in decreasing order
//! (`k = d_max − d`), so the right-image pixels for one column are one contiguous slice
//! and every inner loop is a straight run over `u16` lanes that the compiler vectorises.
//! The kernel is compiled twice, portable and with AVX2, and chosen at run time; rows
//! are split into bands matched in parallel (rayon).
//!
//! Output: disparity in pixels (`x_left − x_right`, f32, NaN where no valid match).
//! Invalid by construction: the `block/2` border, and the `d_max` leftmost columns whose
//! candidates would fall off the right image (depth cameras' "invalid band"). A best
//! match at either end of the disparity range is rejected too: the true minimum may lie
//! outside the range.

use std::ops::Range;

use rayon::prelude::*;
use serde::Serialize;

use super::prefilter;
use super::speckle::filter_speckles;
use crate::grid::Grid;

/// How the sub-pixel offset is fitted to the costs at `d − 1`, `d`, `d + 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SubpixelFit {
    /// A parabola through the three costs (OpenCV's StereoBM).
    Parabola,
    /// Two lines of equal and opposite slope (a "V"), which is the shape of an SAD cost
    /// near its minimum; less pulled towards whole pixels than the parabola.
    Equiangular,
}

/// Matching parameters. [`Default`] is OpenCV's usual StereoBM setting over 64
/// disparities; [`BlockMatchParams::for_depth_range`] sets the range from distances.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BlockMatchParams {
    /// Smallest disparity searched (pixels).
    pub min_disparity: u32,
    /// Number of disparities searched: a positive multiple of 16.
    pub num_disparities: u32,
    /// Window side (odd, ≥ 3).
    pub block_size: u32,
    /// Prefilter clamp (1..=63).
    pub prefilter_cap: u8,
    /// Minimum window sum of `|prefiltered − cap|`; below it a pixel is invalid.
    pub texture_threshold: u32,
    /// Percent by which the best cost must beat every other (not adjacent) candidate.
    pub uniqueness_ratio: u32,
    /// Largest disagreement (pixels) between the left→right and right→left matches;
    /// `None` turns the check off.
    pub lr_max_diff: Option<u32>,
    /// Regions of at most this many pixels are removed as speckles (0: off).
    pub speckle_window: u32,
    /// Largest disparity step (pixels) inside one speckle region.
    pub speckle_range: f32,
    /// Sub-pixel fit.
    pub subpixel: SubpixelFit,
}

impl Default for BlockMatchParams {
    fn default() -> Self {
        Self {
            min_disparity: 0,
            num_disparities: 64,
            block_size: 9,
            prefilter_cap: 31,
            texture_threshold: 10,
            uniqueness_ratio: 15,
            lr_max_diff: Some(1),
            speckle_window: 100,
            speckle_range: 1.0,
            subpixel: SubpixelFit::Equiangular,
        }
    }
}

impl BlockMatchParams {
    /// The default parameters with the disparity range that covers depths from
    /// `near_mm` to `far_mm` for a rectified focal length `focal_px` and baseline
    /// `baseline_mm` (one pixel of margin each side, rounded out to 16 disparities).
    pub fn for_depth_range(
        focal_px: f64,
        baseline_mm: f64,
        near_mm: f64,
        far_mm: f64,
    ) -> Result<Self, MatchError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !(ok(focal_px) && ok(baseline_mm) && ok(near_mm) && ok(far_mm) && near_mm < far_mm) {
            return Err(MatchError::BadDepthRange {
                focal_px,
                baseline_mm,
                near_mm,
                far_mm,
            });
        }
        let fb = focal_px * baseline_mm;
        let d_min = ((fb / far_mm).floor() - 1.0).max(0.0) as u32;
        let d_max = (fb / near_mm).ceil() + 1.0;
        if d_max > 4096.0 {
            return Err(MatchError::BadDepthRange {
                focal_px,
                baseline_mm,
                near_mm,
                far_mm,
            });
        }
        let span = d_max as u32 - d_min + 1;
        Ok(Self {
            min_disparity: d_min,
            num_disparities: span.div_ceil(16) * 16,
            ..Self::default()
        })
    }

    /// The largest disparity searched.
    pub fn max_disparity(&self) -> u32 {
        self.min_disparity + self.num_disparities - 1
    }

    /// Checks every field; the matcher refuses parameters that fail.
    pub fn validate(&self) -> Result<(), MatchError> {
        let bad = |name, value: f64, why| {
            Err(MatchError::InvalidParam {
                name,
                value: value.to_string(),
                why,
            })
        };
        let n = self.num_disparities;
        if n == 0 || !n.is_multiple_of(16) || n > 4096 {
            return bad(
                "num_disparities",
                n.into(),
                "must be a multiple of 16 in 16..=4096",
            );
        }
        if self.min_disparity > 4096 {
            return bad(
                "min_disparity",
                self.min_disparity.into(),
                "must be at most 4096",
            );
        }
        let b = self.block_size;
        if b < 3 || b.is_multiple_of(2) {
            return bad("block_size", b.into(), "must be odd and at least 3");
        }
        let cap = self.prefilter_cap;
        if cap == 0 || cap > 63 {
            return bad("prefilter_cap", cap.into(), "must be in 1..=63");
        }
        // Window sums live in u16 lanes: block² · 2·cap must fit.
        if u64::from(b) * u64::from(b) * 2 * u64::from(cap) > u64::from(u16::MAX) {
            return bad(
                "block_size",
                b.into(),
                "too large: at most 31 at the default prefilter_cap of 31 (window sums of \
                 block_size² · 2 · prefilter_cap must be at most 65535)",
            );
        }
        if self.uniqueness_ratio >= 100 {
            return bad(
                "uniqueness_ratio",
                self.uniqueness_ratio.into(),
                "must be below 100 (percent)",
            );
        }
        if !(self.speckle_range.is_finite() && self.speckle_range >= 0.0) {
            return bad(
                "speckle_range",
                self.speckle_range.into(),
                "must be finite and not negative",
            );
        }
        Ok(())
    }
}

/// Why a pair cannot be matched.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MatchError {
    /// The two images differ in size.
    #[error("the left image is {left:?} (w×h) but the right one is {right:?}")]
    SizeMismatch {
        /// Left size.
        left: (usize, usize),
        /// Right size.
        right: (usize, usize),
    },
    /// A parameter out of range.
    #[error("{name} = {value}: {why}")]
    InvalidParam {
        /// Field name.
        name: &'static str,
        /// The value given.
        value: String,
        /// The rule.
        why: &'static str,
    },
    /// Distances that give no disparity range.
    #[error(
        "no disparity range for --near-mm {near_mm} and --far-mm {far_mm} (focal \
         {focal_px} px, baseline {baseline_mm} mm): both must be positive and finite, \
         --near-mm below --far-mm, and the nearest depth's disparity at most 4096 px \
         (--near-mm at least {:.1} mm with this rig; in Python, near_mm and far_mm)",
        focal_px * baseline_mm / 4095.0
    )]
    BadDepthRange {
        /// Focal length.
        focal_px: f64,
        /// Baseline.
        baseline_mm: f64,
        /// Near limit.
        near_mm: f64,
        /// Far limit.
        far_mm: f64,
    },
    /// Cost and sum volumes larger than the matcher may allocate.
    #[error(
        "{width}×{height} px over {disparities} disparities needs {mib} MiB of cost and sum volumes \
         (at most {limit_mib} MiB): search fewer disparities (--near-mm/--far-mm) or use \
         --matcher bm"
    )]
    TooLarge {
        /// Image width.
        width: usize,
        /// Image height.
        height: usize,
        /// Disparities searched.
        disparities: usize,
        /// What it would need, MiB.
        mib: usize,
        /// The bound, MiB.
        limit_mib: usize,
    },
    /// The kernel asked for does not run on this CPU.
    #[error("the {0:?} kernel is not available on this CPU")]
    KernelUnavailable(Kernel),
}

/// The common size of a pair, or why they differ.
pub(super) fn pair_size(left: &Grid<u8>, right: &Grid<u8>) -> Result<(usize, usize), MatchError> {
    let size = |g: &Grid<u8>| (g.width(), g.height());
    if size(left) != size(right) {
        return Err(MatchError::SizeMismatch {
            left: size(left),
            right: size(right),
        });
    }
    Ok(size(left))
}

/// Which compiled variant of the inner loops runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Kernel {
    /// Plain Rust, vectorised for the target's baseline (SSE2 on x86-64, NEON on arm64).
    Portable,
    /// The same code compiled for AVX2 (with BMI1/2, POPCNT, LZCNT, as every AVX2 CPU
    /// has; x86-64 only, checked at run time).
    Avx2,
}

impl Kernel {
    /// Whether this kernel runs on this CPU.
    pub fn is_available(self) -> bool {
        match self {
            Kernel::Portable => true,
            Kernel::Avx2 => crate::cpu::avx2_bmi(),
        }
    }

    /// This kernel, or why it cannot run here.
    pub fn checked(self) -> Result<Self, MatchError> {
        if self.is_available() {
            Ok(self)
        } else {
            Err(MatchError::KernelUnavailable(self))
        }
    }

    /// The kernels the tests compare: the portable one everywhere, the AVX2 one where
    /// this CPU has it. A machine without it is reported by an ignored test
    /// (`the_avx2_kernel_is_among_those_tested`), not passed over in silence.
    #[cfg(test)]
    pub(crate) fn tested() -> Vec<Self> {
        [Kernel::Portable, Kernel::Avx2]
            .into_iter()
            .filter(|k| k.is_available())
            .collect()
    }

    /// The fastest available kernel.
    pub fn best() -> Self {
        if Kernel::Avx2.is_available() {
            Kernel::Avx2
        } else {
            Kernel::Portable
        }
    }
}

/// Why pixels were left without a disparity, and how many have one.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MatchStats {
    /// Pixels with a disparity.
    pub valid: usize,
    /// Window border and the invalid band on the left.
    pub border: usize,
    /// Too little texture in the window.
    pub low_texture: usize,
    /// Another candidate almost as good (uniqueness ratio).
    pub not_unique: usize,
    /// Best match at the end of the disparity range.
    pub range_edge: usize,
    /// Failed the left–right check.
    pub left_right: usize,
    /// Removed as a speckle.
    pub speckle: usize,
    /// Matched at a depth outside the working range (`near_mm`..`far_mm`; the search,
    /// rounded up to whole blocks of disparities, runs a little past it), dropped by the
    /// pipeline: what it writes lies within the range asked for.
    pub outside_range: usize,
    /// Pixels whose window in the left view has too little texture to match (block
    /// matching's texture measure, whichever matcher ran): not a separate outcome (with
    /// block matching these are the `low_texture` ones), but what says a pair is blank.
    /// With semi-global matching the pipeline counts them only for a result left almost
    /// without depth (after the working range and the filters: as the warnings count);
    /// `SemiGlobalMatcher` and `Matcher` alone leave 0.
    pub flat: usize,
}

impl MatchStats {
    /// Sets `valid` from `disparity` and `border` to the pixels no other count explains.
    pub(super) fn count_valid_and_border(&mut self, disparity: &Grid<f32>) {
        self.valid = disparity
            .as_slice()
            .iter()
            .filter(|v| v.is_finite())
            .count();
        let rejected =
            self.low_texture + self.not_unique + self.range_edge + self.left_right + self.speckle;
        self.border = disparity.as_slice().len() - self.valid - rejected;
    }

    pub(super) fn add(mut self, o: Self) -> Self {
        self.valid += o.valid;
        self.border += o.border;
        self.low_texture += o.low_texture;
        self.not_unique += o.not_unique;
        self.range_edge += o.range_edge;
        self.left_right += o.left_right;
        self.speckle += o.speckle;
        self.outside_range += o.outside_range;
        self.flat += o.flat;
        self
    }
}

/// A disparity map and its bookkeeping.
#[derive(Debug, Clone)]
pub struct DisparityMap {
    /// Disparity in pixels, NaN where invalid.
    pub disparity: Grid<f32>,
    /// Counts per outcome.
    pub stats: MatchStats,
}

/// A block matcher: validated parameters and a kernel, reused for every frame.
#[derive(Debug, Clone)]
pub struct BlockMatcher {
    params: BlockMatchParams,
    kernel: Kernel,
}

impl BlockMatcher {
    /// A matcher with the fastest kernel this CPU runs.
    pub fn new(params: BlockMatchParams) -> Result<Self, MatchError> {
        params.validate()?;
        Ok(Self {
            params,
            kernel: Kernel::best(),
        })
    }

    /// Uses `kernel` instead (benchmarks and tests).
    pub fn with_kernel(mut self, kernel: Kernel) -> Result<Self, MatchError> {
        self.kernel = kernel.checked()?;
        Ok(self)
    }

    /// The parameters.
    pub fn params(&self) -> &BlockMatchParams {
        &self.params
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Matches a rectified pair (8-bit grey, same size), in parallel on rayon's current
    /// pool. Images smaller than one window plus the disparity range come out all
    /// invalid.
    pub fn compute(&self, left: &Grid<u8>, right: &Grid<u8>) -> Result<DisparityMap, MatchError> {
        let (w, h) = pair_size(left, right)?;
        let p = &self.params;
        let r = (p.block_size / 2) as usize;
        let d_max = p.max_disparity() as usize;
        let mut disparity = Grid::filled(w, h, f32::NAN);
        let mut stats = MatchStats::default();
        if h > 2 * r && w > d_max + 2 * r {
            let cap = p.prefilter_cap;
            let ((lp, tex), rp) = rayon::join(
                || {
                    let lp = prefilter::x_sobel(left, cap);
                    let tex = prefilter::texture(&lp, cap, p.block_size as usize);
                    (lp, tex)
                },
                || prefilter::x_sobel(right, cap),
            );
            let inputs = Inputs {
                left: &lp,
                right: &rp,
                texture: &tex,
                r,
                d_max,
                nd: p.num_disparities as usize,
                texture_threshold: p.texture_threshold,
                uniqueness: p.uniqueness_ratio,
                lr_max_diff: p.lr_max_diff.map(|v| v as usize),
                subpixel: p.subpixel,
            };
            let bands = rayon::current_num_threads().max(1);
            let band_rows = h.div_ceil(bands).max(1);
            let kernel = self.kernel;
            stats = disparity
                .as_mut_slice()
                .par_chunks_mut(band_rows * w)
                .enumerate()
                .map(|(i, out)| {
                    let rows = i * band_rows..(i * band_rows + out.len() / w);
                    run_band(kernel, &inputs, rows, out)
                })
                .reduce(MatchStats::default, MatchStats::add);
        }
        stats.speckle = filter_speckles(&mut disparity, p.speckle_window as usize, p.speckle_range);
        stats.count_valid_and_border(&disparity);
        Ok(DisparityMap { disparity, stats })
    }
}

/// What one band of rows needs.
struct Inputs<'a> {
    left: &'a Grid<u8>,
    right: &'a Grid<u8>,
    texture: &'a Grid<u32>,
    r: usize,
    d_max: usize,
    nd: usize,
    texture_threshold: u32,
    uniqueness: u32,
    lr_max_diff: Option<usize>,
    subpixel: SubpixelFit,
}

#[allow(unsafe_code)]
fn run_band(
    kernel: Kernel,
    inputs: &Inputs<'_>,
    rows: Range<usize>,
    out: &mut [f32],
) -> MatchStats {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: `band_avx2` needs AVX2, BMI1/2, POPCNT and LZCNT, detected just above.
        return unsafe { band_avx2(inputs, rows, out) };
    }
    let _ = kernel;
    band_portable(inputs, rows, out)
}

fn band_portable(inputs: &Inputs<'_>, rows: Range<usize>, out: &mut [f32]) -> MatchStats {
    band(inputs, rows, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn band_avx2(inputs: &Inputs<'_>, rows: Range<usize>, out: &mut [f32]) -> MatchStats {
    band(inputs, rows, out)
}

/// Matches output rows `rows` (their part of the map is `out`, pre-filled with NaN).
/// Everything it calls is `inline(always)` so each kernel variant gets its own copy.
#[inline(always)]
fn band(inp: &Inputs<'_>, rows: Range<usize>, out: &mut [f32]) -> MatchStats {
    let mut stats = MatchStats::default();
    let (w, h) = (inp.left.width(), inp.left.height());
    let (r, nd, d_max) = (inp.r, inp.nd, inp.d_max);
    let y_lo = rows.start.max(r);
    let y_hi = rows.end.min(h - r);
    if y_lo >= y_hi {
        return stats;
    }
    let x0 = d_max;
    let mut col = vec![0u16; w * nd];
    let mut cost = vec![0u16; nd];
    let index: Vec<u16> = (0..nd as u16).collect();
    let mut best_d = vec![usize::MAX; w];
    let mut right_cost = vec![u16::MAX; w];
    let mut right_d = vec![usize::MAX; w];

    for yy in y_lo - r..=y_lo + r {
        let (l, rt) = (inp.left.row(yy), inp.right.row(yy));
        for x in x0..w {
            add_abs(&mut col[x * nd..][..nd], l[x], &rt[x - d_max..][..nd]);
        }
    }
    for y in y_lo..y_hi {
        if y > y_lo {
            let (ln, rn) = (inp.left.row(y + r), inp.right.row(y + r));
            let (lo, ro) = (inp.left.row(y - r - 1), inp.right.row(y - r - 1));
            for x in x0..w {
                update_column(
                    &mut col[x * nd..][..nd],
                    (ln[x], &rn[x - d_max..][..nd]),
                    (lo[x], &ro[x - d_max..][..nd]),
                );
            }
        }
        let orow = &mut out[(y - rows.start) * w..][..w];
        let texture = inp.texture.row(y);
        cost.fill(0);
        for x in x0..=x0 + 2 * r {
            add_lanes(&mut cost, &col[x * nd..][..nd]);
        }
        right_cost[..w].fill(u16::MAX);
        for xc in x0 + r..w - r {
            let best = if xc > x0 + r {
                let (new, old) = (xc + r, xc - r - 1);
                slide_lanes(&mut cost, &col[new * nd..][..nd], &col[old * nd..][..nd])
            } else {
                cost.iter().copied().min().unwrap_or(u16::MAX)
            };
            best_d[xc] = usize::MAX;
            if texture[xc] < inp.texture_threshold {
                stats.low_texture += 1;
                continue;
            }
            let c = best;
            let t = u32::from(c) + u32::from(c) * inp.uniqueness / 100;
            let t = t.min(u32::from(u16::MAX)) as u16;
            let (k, within) = locate(&cost, &index, c, t);
            if k == 0 || k == nd - 1 {
                stats.range_edge += 1;
                continue;
            }
            if inp.uniqueness > 0 {
                // Candidates within the threshold, less the best and its two neighbours.
                let near = 1 + usize::from(cost[k - 1] <= t) + usize::from(cost[k + 1] <= t);
                if within > near {
                    stats.not_unique += 1;
                    continue;
                }
            }
            let d = d_max - k;
            // Costs at d − 1 and d + 1 (disparity falls as k rises).
            let (below, above) = (cost[k + 1], cost[k - 1]);
            orow[xc] = d as f32 + subpixel_offset(inp.subpixel, below, c, above);
            best_d[xc] = d;
            let xr = xc - d;
            if c < right_cost[xr] {
                right_cost[xr] = c;
                right_d[xr] = d;
            }
        }
        if let Some(max_diff) = inp.lr_max_diff {
            for xc in x0 + r..w - r {
                let d = best_d[xc];
                if d != usize::MAX && right_d[xc - d].abs_diff(d) > max_diff {
                    orow[xc] = f32::NAN;
                    stats.left_right += 1;
                }
            }
        }
    }
    stats
}

/// `|a − b|` in a form that stays in byte lanes when vectorised.
#[inline(always)]
fn abs_diff(a: u8, b: u8) -> u8 {
    a.max(b) - a.min(b)
}

/// `col[k] += |l − right[k]|`.
#[inline(always)]
fn add_abs(col: &mut [u16], l: u8, right: &[u8]) {
    for (c, &rv) in col.iter_mut().zip(right) {
        *c = c.wrapping_add(u16::from(abs_diff(l, rv)));
    }
}

/// `col[k] += |l_new − r_new[k]| − |l_old − r_old[k]|` (the column sum stays in range,
/// so wrapping arithmetic is exact).
#[inline(always)]
fn update_column(col: &mut [u16], (ln, rn): (u8, &[u8]), (lo, ro): (u8, &[u8])) {
    for ((c, &a), &b) in col.iter_mut().zip(rn).zip(ro) {
        let delta = u16::from(abs_diff(ln, a)).wrapping_sub(u16::from(abs_diff(lo, b)));
        *c = c.wrapping_add(delta);
    }
}

#[inline(always)]
fn add_lanes(acc: &mut [u16], v: &[u16]) {
    for (a, &b) in acc.iter_mut().zip(v) {
        *a = a.wrapping_add(b);
    }
}

/// `acc += new − old`, returning the smallest lane (one pass, no reload).
#[inline(always)]
fn slide_lanes(acc: &mut [u16], new: &[u16], old: &[u16]) -> u16 {
    let mut least = u16::MAX;
    for ((a, &n), &o) in acc.iter_mut().zip(new).zip(old) {
        *a = a.wrapping_add(n).wrapping_sub(o);
        least = least.min(*a);
    }
    least
}

/// The first lane equal to `best`, and how many lanes are at most `t` (`t ≥ best`).
/// Both are reductions over whole lanes (min of masked indices, sum of compares), so
/// they vectorise; `index` holds `0, 1, 2, …`.
#[inline(always)]
pub(super) fn locate(cost: &[u16], index: &[u16], best: u16, t: u16) -> (usize, usize) {
    let mut first = u16::MAX;
    let mut within = 0u16;
    for (&c, &i) in cost.iter().zip(index) {
        first = first.min(if c == best { i } else { u16::MAX });
        within = within.wrapping_add(u16::from(c <= t));
    }
    (usize::from(first), usize::from(within))
}

/// Offset in (−0.5, 0.5) of the true minimum from `d`, from the costs at `d − 1`, `d`
/// and `d + 1` (`d` the smallest of the three). 0 when the three are equal.
#[inline(always)]
pub(super) fn subpixel_offset(fit: SubpixelFit, below: u16, c: u16, above: u16) -> f32 {
    let (a, c, b) = (f32::from(below), f32::from(c), f32::from(above));
    let denom = match fit {
        SubpixelFit::Parabola => 2.0 * (a + b - 2.0 * c),
        SubpixelFit::Equiangular => 2.0 * (a.max(b) - c),
    };
    if denom > 0.0 { (a - b) / denom } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stereo kernel tests loop over [`Kernel::tested`]: on a machine without AVX2
    /// and BMI they check the portable kernel only, and this test says so (ignored).
    #[test]
    #[cfg_attr(
        not(build_cpu_avx2_bmi),
        ignore = "the stereo kernel tests check the portable kernel only: this machine \
                  lacks AVX2 and BMI"
    )]
    fn the_avx2_kernel_is_among_those_tested() {
        assert_eq!(Kernel::tested(), [Kernel::Portable, Kernel::Avx2]);
    }

    /// A random-dot texture (deterministic), values 0..=255.
    fn dots(w: usize, h: usize, seed: u64) -> Grid<u8> {
        let mut s = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        Grid::from_fn(w, h, |_, _| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 56) as u8
        })
    }

    /// The right view of `left` for a disparity that is `disp(x, y)` (integer shift).
    fn shifted(left: &Grid<u8>, disp: impl Fn(usize, usize) -> usize) -> Grid<u8> {
        Grid::from_fn(left.width(), left.height(), |x, y| {
            let xs = x + disp(x, y);
            if xs < left.width() {
                left.get(xs, y)
            } else {
                0
            }
        })
    }

    fn params(min: u32, n: u32) -> BlockMatchParams {
        BlockMatchParams {
            min_disparity: min,
            num_disparities: n,
            ..BlockMatchParams::default()
        }
    }

    #[test]
    fn a_known_integer_shift_comes_back_exactly() {
        let left = dots(160, 60, 1);
        let right = shifted(&left, |_, _| 21);
        for kernel in [Kernel::Portable, Kernel::best()] {
            let m = BlockMatcher::new(params(0, 32))
                .unwrap()
                .with_kernel(kernel)
                .unwrap();
            let out = m.compute(&left, &right).unwrap();
            let d = &out.disparity;
            // Valid region: x in 31+4 .. 160−4, y in 4 .. 56, less the right edge where
            // the right view has no data (x + 21 ≥ 160).
            for y in 4..56 {
                for x in 35..135 {
                    // Whole pixel exact; the sub-pixel fit on random dots moves it a little.
                    let v = d.get(x, y);
                    assert!((v - 21.0).abs() < 0.35, "{kernel:?} ({x},{y}) = {v}");
                }
                for x in 0..35 {
                    assert!(d.get(x, y).is_nan(), "invalid band at ({x},{y})");
                }
            }
            assert_eq!(
                out.stats.valid
                    + out.stats.border
                    + out.stats.left_right
                    + out.stats.low_texture
                    + out.stats.not_unique
                    + out.stats.range_edge
                    + out.stats.speckle,
                160 * 60
            );
            assert!(out.stats.valid >= 100 * 52, "{:?}", out.stats);
        }
    }

    #[test]
    fn two_planes_give_two_disparities_with_an_offset_range() {
        // Left half of the rows at disparity 40, right half at 27, searched from 16.
        let left = dots(200, 80, 2);
        let right = shifted(&left, |x, _| if x < 110 { 40 } else { 27 });
        let m = BlockMatcher::new(params(16, 32)).unwrap();
        let d = m.compute(&left, &right).unwrap().disparity;
        for y in 10..70 {
            assert!((d.get(80, y) - 40.0).abs() < 0.35, "{}", d.get(80, y));
            assert!((d.get(150, y) - 27.0).abs() < 0.35, "{}", d.get(150, y));
        }
    }

    #[test]
    fn kernels_agree_bit_for_bit() {
        let left = dots(300, 90, 3);
        let right = shifted(&left, |x, y| 10 + (x / 20 + y / 30) % 30);
        let base = BlockMatcher::new(params(4, 48)).unwrap();
        let a = base.clone().with_kernel(Kernel::Portable).unwrap();
        let b = base.with_kernel(Kernel::best()).unwrap();
        let (da, db) = (
            a.compute(&left, &right).unwrap(),
            b.compute(&left, &right).unwrap(),
        );
        assert_eq!(da.stats, db.stats);
        for (x, y) in da.disparity.as_slice().iter().zip(db.disparity.as_slice()) {
            assert!(x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()));
        }
    }

    #[test]
    fn sub_pixel_shifts_are_recovered() {
        // A smooth texture (sum of sines) shifted by a fraction: linear interpolation
        // of a smooth signal is close to the true shift.
        let f = |x: f64, y: f64| {
            128.0
                + 50.0 * (x * 0.31 + y * 0.05).sin()
                + 40.0 * (x * 0.17 - y * 0.23).sin()
                + 30.0 * (x * 0.53 + y * 0.41).cos()
        };
        let shift = 12.3;
        let left = Grid::from_fn(200, 60, |x, y| f(x as f64, y as f64).round() as u8);
        let right = Grid::from_fn(200, 60, |x, y| f(x as f64 + shift, y as f64).round() as u8);
        for fit in [SubpixelFit::Parabola, SubpixelFit::Equiangular] {
            let p = BlockMatchParams {
                subpixel: fit,
                ..params(0, 32)
            };
            let d = BlockMatcher::new(p)
                .unwrap()
                .compute(&left, &right)
                .unwrap()
                .disparity;
            let vals: Vec<f32> = (10..50)
                .flat_map(|y| (40..180).map(move |x| (x, y)))
                .map(|(x, y)| d.get(x, y))
                .collect();
            let valid: Vec<f32> = vals.iter().copied().filter(|v| v.is_finite()).collect();
            assert!(valid.len() * 10 > vals.len() * 9, "{fit:?}: fill");
            let mean = valid.iter().sum::<f32>() / valid.len() as f32;
            assert!((mean - shift as f32).abs() < 0.1, "{fit:?}: mean {mean}");
        }
    }

    #[test]
    fn flat_and_out_of_range_scenes_are_rejected() {
        // No texture: every window is below the texture threshold.
        let flat = Grid::filled(120, 40, 77u8);
        let out = BlockMatcher::new(params(0, 16))
            .unwrap()
            .compute(&flat, &flat)
            .unwrap();
        assert_eq!(out.stats.valid, 0);
        assert!(out.stats.low_texture > 0);
        // A true disparity of 50 searched in 0..16: the best is at the range end.
        let left = dots(200, 40, 4);
        let right = shifted(&left, |_, _| 50);
        let out = BlockMatcher::new(params(0, 16))
            .unwrap()
            .compute(&left, &right)
            .unwrap();
        let inside = 200 * 40 - out.stats.border;
        assert!(out.stats.valid * 50 < inside, "{:?}", out.stats);
        assert!(
            out.stats.range_edge > 0 && out.stats.not_unique > 0,
            "{:?}",
            out.stats
        );
    }

    #[test]
    fn degenerate_inputs_are_errors_or_empty_maps() {
        let m = BlockMatcher::new(BlockMatchParams::default()).unwrap();
        let small = Grid::filled(20, 5, 0u8);
        let out = m.compute(&small, &small).unwrap();
        assert_eq!((out.stats.valid, out.stats.border), (0, 100));
        let empty = Grid::filled(0, 0, 0u8);
        assert_eq!(m.compute(&empty, &empty).unwrap().stats.valid, 0);
        assert!(matches!(
            m.compute(&small, &Grid::filled(21, 5, 0u8)),
            Err(MatchError::SizeMismatch { .. })
        ));
        for p in [
            BlockMatchParams {
                num_disparities: 40,
                ..Default::default()
            },
            BlockMatchParams {
                block_size: 8,
                ..Default::default()
            },
            BlockMatchParams {
                prefilter_cap: 0,
                ..Default::default()
            },
            BlockMatchParams {
                block_size: 33,
                prefilter_cap: 63,
                ..Default::default()
            },
            BlockMatchParams {
                uniqueness_ratio: 100,
                ..Default::default()
            },
            BlockMatchParams {
                speckle_range: f32::NAN,
                ..Default::default()
            },
        ] {
            assert!(
                matches!(BlockMatcher::new(p), Err(MatchError::InvalidParam { .. })),
                "{p:?}"
            );
        }
    }

    #[test]
    fn depth_range_gives_the_disparities_it_needs() {
        // f·B = 336 · 14 = 4704: 600 mm → 7.84 px, 50 mm → 94.08 px.
        let p = BlockMatchParams::for_depth_range(336.0, 14.0, 50.0, 600.0).unwrap();
        assert_eq!(p.min_disparity, 6);
        assert!(p.max_disparity() >= 96 && p.num_disparities.is_multiple_of(16));
        assert_eq!(p.num_disparities, 96);
        assert!(BlockMatchParams::for_depth_range(336.0, 14.0, 600.0, 50.0).is_err());
        assert!(BlockMatchParams::for_depth_range(f64::NAN, 14.0, 50.0, 600.0).is_err());
    }

    #[test]
    fn subpixel_fits_find_the_vertex() {
        // A V with slopes ±10 and vertex at +0.3: costs at −1, 0, +1 are 13, 3, 7.
        let v = subpixel_offset(SubpixelFit::Equiangular, 13, 3, 7);
        assert!((v - 0.3).abs() < 1e-6, "{v}");
        // A parabola 10(x − 0.2)² + 1: at −1: 15.4, 0: 1.4, 1: 7.4 (×10 to integers).
        let p = subpixel_offset(SubpixelFit::Parabola, 154, 14, 74);
        assert!((p - 0.2).abs() < 1e-6, "{p}");
        assert_eq!(subpixel_offset(SubpixelFit::Parabola, 5, 5, 5), 0.0);
    }
}
