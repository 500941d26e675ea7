//! Semi-global matching (Hirschmüller, 2008) on rectified pairs: census costs,
//! aggregation along 3, 4, 5 or 8 image paths, winner-takes-all with a uniqueness ratio,
//! sub-pixel fit, left–right check and speckle removal.
//!
//! Block matching decides each pixel from its window alone; here every pixel's cost at
//! disparity `d` is the sum, over paths arriving from several directions, of the
//! cheapest way to reach it with small penalties for disparity steps of one pixel
//! (`p1`, slanted surfaces) and larger ones for jumps (`p2`, object edges). Weak or
//! repeated texture borrows the answer of its neighbours along the paths.
//!
//! - **Cost**: Hamming distance of 7×7 census signatures (48 bits, borders clamped): a
//!   comparison of each pixel with its neighbours, so it does not care about the gain
//!   and offset a hazy skin adds to one view.
//! - **Layout**: as the block matcher's, the disparities of one pixel contiguous
//!   (`[y][x][k]`, `d = min_disparity + k`), so every path step is a straight run over
//!   `u8` lanes (`u16` for large penalties, see [`Lane`]) the compiler vectorises;
//!   compiled portable and for AVX2, chosen at run time.
//! - **Sweeps**: a sweep takes the rows in order. The first, top to bottom, follows the
//!   paths along the row and those from the row above (straight down, and for 5 and 8
//!   paths the two downward diagonals); for 4 and 8 paths a second, bottom to top,
//!   follows the paths from below. With one sweep (3 and 5 paths: along the row both ways)
//!   each row's census costs are made as the sweep comes to it and the row is matched
//!   as soon as it is passed: no volume is kept. Two sweeps read one cost volume made
//!   beforehand; the first keeps its sums in a volume that the second adds to row by
//!   row (on one thread), or both keep a volume and run side by side (on more, when
//!   that fits: [`Schedule`]).
//! - **Boundaries**: a path starts afresh at the image edge (its first value is the
//!   pixel's cost). Candidates that fall off the right image cost the most a census
//!   can; as with block matching, the `max disparity` leftmost columns are invalid.
//!
//! Output: disparity in pixels (`x_left − x_right`, f32, NaN where invalid).

use rayon::prelude::*;
use serde::Serialize;

use super::block_match::{
    DisparityMap, Kernel, MatchError, MatchStats, SubpixelFit, pair_size, subpixel_offset,
};
use super::speckle::filter_speckles;
use crate::grid::Grid;
use refine::{RefinePlanes, refine};

#[cfg(target_arch = "x86_64")]
mod byte_paths;
mod refine;

/// Census window radius: 7×7, 48 comparisons.
const CENSUS_RADIUS: usize = 3;
/// Largest census cost (every comparison differs); also the cost of a candidate off the
/// right image.
const CENSUS_BITS: u8 = 48;
/// Most memory the matcher allocates for a frame's costs and sums ([`Schedule`]).
const MAX_VOLUME_MIB: usize = 2048;

/// Image paths the costs are aggregated along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Paths {
    /// Along the row both ways and straight down from the row above: the paths of
    /// OpenCV's `StereoSGBM` in its 3-way mode, one sweep and no volume like
    /// [`Paths::Five`]. Fastest; streaks along rows and columns where texture is weak.
    Three,
    /// Horizontal and vertical, in two sweeps over the rows.
    Four,
    /// Along the row both ways and the three paths from the row above (straight down
    /// and the two downward diagonals): one sweep, each row matched as soon as the
    /// sweep has passed it, no cost or sum volume.
    Five,
    /// Every direction and diagonal, in two sweeps: fewest streaks along rows and
    /// columns.
    Eight,
}

impl Paths {
    /// Every choice, fewest paths first.
    pub const ALL: [Paths; 4] = [Paths::Three, Paths::Four, Paths::Five, Paths::Eight];

    /// How many.
    pub fn count(self) -> usize {
        match self {
            Paths::Three => 3,
            Paths::Four => 4,
            Paths::Five => 5,
            Paths::Eight => 8,
        }
    }

    /// The choice of `count` paths, if there is one.
    pub fn with_count(count: usize) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.count() == count)
    }
}

/// A number of paths: "3", "4", "5" or "8".
impl std::str::FromStr for Paths {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        s.trim()
            .parse()
            .ok()
            .and_then(Self::with_count)
            .ok_or_else(|| {
                format!(
                    "{s:?} is not 3, 4, 5 or 8 paths (8: every direction, the default; 3: \
                     along the row both ways and down, the fastest)"
                )
            })
    }
}

/// Semi-global matching parameters. [`Default`]: 64 disparities, 8 paths, penalties
/// for the 48-bit census cost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SgmParams {
    /// Smallest disparity searched (pixels).
    pub min_disparity: u32,
    /// Number of disparities searched: a positive multiple of 16.
    pub num_disparities: u32,
    /// Penalty for a disparity step of one pixel between neighbours along a path.
    pub p1: u16,
    /// Penalty for a larger step (> `p1`).
    pub p2: u16,
    /// Paths aggregated.
    pub paths: Paths,
    /// Percent by which the best aggregated cost must beat every other (not adjacent)
    /// candidate.
    pub uniqueness_ratio: u32,
    /// Largest disagreement (pixels) between the left→right and right→left matches;
    /// `None` turns the check off.
    pub lr_max_diff: Option<u32>,
    /// Regions of at most this many pixels are removed as speckles (0: off).
    pub speckle_window: u32,
    /// Largest disparity step (pixels) inside one speckle region.
    pub speckle_range: f32,
    /// Sub-pixel fit on the aggregated costs.
    pub subpixel: SubpixelFit,
    /// Then refine each disparity on the images themselves: the least-squares shift
    /// that lines up a window of the left view with the right view (two Gauss–Newton
    /// steps from the aggregated-cost estimate). Aggregated census costs place the
    /// minimum only to about 0.15 px.
    pub refine: bool,
    /// Side of the refinement's square window (odd, 3..=31; default 11). Larger windows
    /// average more noise on smooth surfaces and blur small depth steps over more
    /// columns. The default is the smallest that keeps `stereo-eval`'s unfiltered RMS
    /// error under 0.3 % from 100 to 300 mm behind the hazy skin (ten frames a
    /// distance, 2026-11-28: 9×9 up to 0.346 %, 11×11 up to 0.279 %, 13×13 up to
    /// 0.236 %); a 0.5 px depth step spreads over about as many columns as the window.
    pub refine_window: u32,
}

impl Default for SgmParams {
    fn default() -> Self {
        Self {
            min_disparity: 0,
            num_disparities: 64,
            p1: 8,
            p2: 96,
            paths: Paths::Eight,
            uniqueness_ratio: 10,
            lr_max_diff: Some(1),
            speckle_window: 100,
            speckle_range: 1.0,
            subpixel: SubpixelFit::Equiangular,
            refine: true,
            refine_window: 11,
        }
    }
}

impl SgmParams {
    /// The largest disparity searched.
    pub fn max_disparity(&self) -> u32 {
        self.min_disparity + self.num_disparities - 1
    }

    /// Checks every field; the matcher refuses parameters that fail.
    pub fn validate(&self) -> Result<(), MatchError> {
        let bad = |name, value: String, why| Err(MatchError::InvalidParam { name, value, why });
        let n = self.num_disparities;
        if n == 0 || !n.is_multiple_of(16) || n > 1024 {
            return bad(
                "num_disparities",
                n.to_string(),
                "a multiple of 16, 16..=1024",
            );
        }
        if u64::from(self.min_disparity) + u64::from(n) > 4096 {
            return bad(
                "min_disparity",
                self.min_disparity.to_string(),
                "the largest disparity searched must be below 4096",
            );
        }
        if self.p1 == 0 || self.p2 <= self.p1 || self.p2 > 1024 {
            return bad(
                "p2",
                format!("{} (p1 = {})", self.p2, self.p1),
                "penalties 0 < p1 < p2 <= 1024",
            );
        }
        if self.uniqueness_ratio >= 100 {
            return bad(
                "uniqueness_ratio",
                self.uniqueness_ratio.to_string(),
                "a percentage below 100",
            );
        }
        let side = self.refine_window;
        if side.is_multiple_of(2) || !(3..=31).contains(&side) {
            return bad(
                "refine_window",
                side.to_string(),
                "an odd window side, 3..=31 (9 is the default)",
            );
        }
        if !(self.speckle_range.is_finite() && self.speckle_range >= 0.0) {
            return bad(
                "speckle_range",
                self.speckle_range.to_string(),
                "a finite, non-negative number of pixels",
            );
        }
        Ok(())
    }
}

/// A semi-global matcher: validated parameters and a kernel, reused for every frame
/// (with its cost volumes).
#[derive(Debug, Clone)]
pub struct SemiGlobalMatcher {
    params: SgmParams,
    kernel: Kernel,
    scratch: Scratch,
}

/// The cost volume and the sweeps' sums, for paths that take two sweeps; the census
/// images and the refinement's planes, for every frame.
#[derive(Default)]
struct Volumes {
    cost: Vec<u8>,
    first: Vec<u16>,
    second: Vec<u16>,
    census: [Vec<u8>; 2],
    refine: RefinePlanes,
}

impl Volumes {
    /// At least `cells` in the cost volume and the first `sums` sum volumes, when `sums`
    /// is not 0 (contents are overwritten before they are read).
    fn fit(&mut self, cells: usize, sums: usize) {
        if sums > 0 && self.cost.len() < cells {
            self.cost.resize(cells, 0);
        }
        for v in [&mut self.first, &mut self.second].into_iter().take(sums) {
            if v.len() < cells {
                v.resize(cells, 0);
            }
        }
    }
}

/// Volumes kept between frames; a clone starts without.
#[derive(Default)]
struct Scratch(std::sync::Mutex<Volumes>);

impl Clone for Scratch {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
}

impl SemiGlobalMatcher {
    /// A matcher with the fastest kernel this CPU runs.
    pub fn new(params: SgmParams) -> Result<Self, MatchError> {
        params.validate()?;
        Ok(Self {
            params,
            kernel: Kernel::best(),
            scratch: Scratch::default(),
        })
    }

    /// Uses `kernel` instead (benchmarks and tests).
    pub fn with_kernel(mut self, kernel: Kernel) -> Result<Self, MatchError> {
        self.kernel = kernel.checked()?;
        Ok(self)
    }

    /// The parameters.
    pub fn params(&self) -> &SgmParams {
        &self.params
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Whether its census costs count with AVX-512's `VPOPCNTB` on this CPU (the AVX2
    /// kernel where the CPU has it and `STEREOTAC_NO_AVX512` is not set).
    pub fn counts_with_vpopcntb(&self) -> bool {
        counts_with_vpopcntb(self.kernel)
    }

    /// Matches a rectified pair (8-bit grey, same size) on rayon's current pool. Images
    /// narrower than the disparity range plus a census window come out all invalid;
    /// a frame whose volumes (or, for 3 and 5 paths, rows) would take over 2 GiB is refused,
    /// whatever the thread count.
    pub fn compute(&self, left: &Grid<u8>, right: &Grid<u8>) -> Result<DisparityMap, MatchError> {
        let (w, h) = pair_size(left, right)?;
        let p = &self.params;
        let nd = p.num_disparities as usize;
        let d_max = p.max_disparity() as usize;
        let mut disparity = Grid::filled(w, h, f32::NAN);
        let mut stats = MatchStats::default();
        // The volumes are kept between frames (a fresh 59–98 MB per frame at 640×480
        // and 64 disparities costs page faults and TLB flushes, the census images and
        // refinement planes about 6.5 MB); a matcher shared by several threads at once takes
        // fresh ones.
        let mut kept = match self.scratch.0.try_lock() {
            Ok(v) => Some(v),
            // A frame that panicked while holding them: the volumes are overwritten
            // before they are read, so they are still good.
            Err(std::sync::TryLockError::Poisoned(e)) => Some(e.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        };
        let mut fresh = Volumes::default();
        let v: &mut Volumes = kept.as_deref_mut().unwrap_or(&mut fresh);
        if w > d_max + 2 * CENSUS_RADIUS && h > 2 * CENSUS_RADIUS {
            let (first, second) = p.paths.sweeps();
            let schedule = Schedule::choose(p.paths, rayon::current_num_threads(), w, h, nd);
            let mib = schedule.bytes >> 20;
            if mib > MAX_VOLUME_MIB {
                return Err(MatchError::TooLarge {
                    width: w,
                    height: h,
                    disparities: nd,
                    mib,
                    limit_mib: MAX_VOLUME_MIB,
                });
            }
            let [kl, kr] = &mut v.census;
            let right_view = View::Right {
                pad: nd + p.min_disparity as usize,
            };
            let (cl, cr) = rayon::join(
                || census(self.kernel, left, View::Left, std::mem::take(kl)),
                || census(self.kernel, right, right_view, std::mem::take(kr)),
            );
            let shape = Shape {
                w,
                h,
                nd,
                d_min: p.min_disparity as usize,
            };
            let s = &shape;
            let kernel = self.kernel;
            let row_cells = w * nd;
            let cells = row_cells * h;
            let volumes = schedule.sum_volumes;
            v.fit(cells, volumes);
            let costs = if volumes == 0 {
                CostSource::Census(&cl, &cr, kernel)
            } else {
                let volume = &mut v.cost[..cells];
                volume
                    .par_chunks_mut(row_cells)
                    .enumerate()
                    .for_each(|(y, row)| run_costs(kernel, s, cl.row(y), cr.row(y), row));
                CostSource::Volume(&v.cost[..cells])
            };
            let out = &mut disparity;
            let writing = SweepVolumes::writing;
            match second {
                None => {
                    let mut sink = |y: usize, sum: &[u16]| {
                        stats = stats.add(run_select(kernel, s, p, sum, None, out.row_mut(y)));
                    };
                    run_sweep(
                        kernel,
                        s,
                        p,
                        costs,
                        first,
                        SweepVolumes::default(),
                        &mut sink,
                    );
                }
                Some(second) if volumes == 2 => {
                    let (a, b) = (&mut v.first[..cells], &mut v.second[..cells]);
                    rayon::join(
                        || run_sweep(kernel, s, p, costs, first, writing(a), &mut |_, _| {}),
                        || run_sweep(kernel, s, p, costs, second, writing(b), &mut |_, _| {}),
                    );
                    let (a, b) = (&v.first[..cells], &v.second[..cells]);
                    stats = a
                        .par_chunks(row_cells)
                        .zip(b.par_chunks(row_cells))
                        .zip(out.as_mut_slice().par_chunks_mut(w))
                        .map(|((a, b), out)| run_select(kernel, s, p, a, Some(b), out))
                        .reduce(MatchStats::default, MatchStats::add);
                }
                Some(second) => {
                    let a = &mut v.first[..cells];
                    run_sweep(kernel, s, p, costs, first, writing(a), &mut |_, _| {});
                    let a = &v.first[..cells];
                    let mut sink = |y: usize, sum: &[u16]| {
                        let other = &a[y * row_cells..][..row_cells];
                        let row = out.row_mut(y);
                        stats = stats.add(run_select(kernel, s, p, sum, Some(other), row));
                    };
                    let volumes = SweepVolumes {
                        sums: None,
                        read_by_sink: Some(a),
                    };
                    run_sweep(kernel, s, p, costs, second, volumes, &mut sink);
                }
            }
            v.census = [cl.into_vec(), cr.into_vec()];
        }
        if p.refine {
            let radius = (p.refine_window / 2) as usize;
            refine(
                self.kernel,
                (left, right),
                radius,
                &mut disparity,
                &mut v.refine,
            );
        }
        stats.speckle = filter_speckles(&mut disparity, p.speckle_window as usize, p.speckle_range);
        stats.count_valid_and_border(&disparity);
        Ok(DisparityMap { disparity, stats })
    }
}

/// How [`SemiGlobalMatcher::compute`] runs the sweeps and the memory that takes, beyond
/// the two census images (six bytes a pixel, the right view's rows padded by the
/// disparities searched) and the disparity map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Schedule {
    /// Sum volumes kept: 0 (one sweep: each row matched as it is passed), 1 (the second
    /// sweep matches each row from its own sums and the first sweep's volume), 2 (the
    /// two sweeps side by side, each into its own volume, then the rows in parallel).
    /// The sums are integers, so every schedule gives the same disparities.
    sum_volumes: usize,
    /// Bytes that grow with the frame: for two sweeps the cost volume (a byte a cell)
    /// and the sum volumes (two bytes a cell each); for one sweep its rows.
    bytes: usize,
}

/// Bytes one sweep keeps per cell of a row (`w · nd`), at most: two rows of path costs
/// for three paths in 16-bit lanes, padded (6 · 2 · (nd + 2) / nd ≤ 13.5 for nd ≥ 16),
/// the row's costs (1) and sums (2).
const ONE_SWEEP_BYTES_PER_ROW_CELL: usize = 17;

impl Schedule {
    /// Two sweeps run side by side on more than one thread when their volumes fit under
    /// [`MAX_VOLUME_MIB`]; otherwise (and on one thread) one after the other, so whether
    /// a frame fits does not depend on the thread count.
    fn choose(paths: Paths, threads: usize, w: usize, h: usize, nd: usize) -> Self {
        let row_cells = w.saturating_mul(nd);
        let cells = row_cells.saturating_mul(h);
        match paths.sweeps().1 {
            None => Self {
                sum_volumes: 0,
                bytes: row_cells.saturating_mul(ONE_SWEEP_BYTES_PER_ROW_CELL),
            },
            Some(_) => {
                let side_by_side = cells.saturating_mul(5);
                if threads > 1 && side_by_side >> 20 <= MAX_VOLUME_MIB {
                    Self {
                        sum_volumes: 2,
                        bytes: side_by_side,
                    }
                } else {
                    Self {
                        sum_volumes: 1,
                        bytes: cells.saturating_mul(3),
                    }
                }
            }
        }
    }
}

/// Sizes every stage shares.
struct Shape {
    w: usize,
    h: usize,
    nd: usize,
    d_min: usize,
}

/// Which view a census is made for, which sets how its planes are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum View {
    /// Left to right.
    Left,
    /// Right to left with `pad` bytes after each plane row, so a left pixel's
    /// candidates (right columns `x − d_min` down to `x − d_min − nd + 1`) are one
    /// forward run of each plane ([`costs`]): `pad ≥ nd + d_min` keeps every run inside.
    Right { pad: usize },
}

/// 7×7 census signatures of one view (bit set where the neighbour is brighter than the
/// centre; neighbours outside the image are read at the nearest edge pixel), kept as six
/// byte planes a row, as [`costs`] reads them: byte `j` of every pixel of row `y` is
/// the run `data[(y·6 + j)·stride..]`, the `j`-th eight comparisons, the first in the
/// top bit.
struct CensusPlanes {
    /// What [`CensusPlanes::signature`] needs to find a pixel.
    #[cfg(test)]
    width: usize,
    #[cfg(test)]
    height: usize,
    #[cfg(test)]
    view: View,
    /// Bytes a plane row: the width, plus the right view's padding.
    stride: usize,
    data: Vec<u8>,
}

impl CensusPlanes {
    /// Row `y`'s six planes, `stride` bytes each.
    fn row(&self, y: usize) -> [&[u8]; CENSUS_BYTES] {
        let row = &self.data[y * CENSUS_BYTES * self.stride..][..CENSUS_BYTES * self.stride];
        std::array::from_fn(|j| &row[j * self.stride..][..self.stride])
    }

    /// The buffer, to be kept for the next frame.
    fn into_vec(self) -> Vec<u8> {
        self.data
    }

    /// Pixel `(x, y)`'s signature, byte `j` in bits `8j..8j + 8`.
    #[cfg(test)]
    fn signature(&self, x: usize, y: usize) -> u64 {
        let at = match self.view {
            View::Left => x,
            View::Right { .. } => self.width - 1 - x,
        };
        self.row(y)
            .iter()
            .enumerate()
            .map(|(j, plane)| u64::from(plane[at]) << (8 * j))
            .sum()
    }
}

/// The census of `img` for `view`, rows in parallel, into `kept` (its contents are
/// overwritten; the right view's padding is never read as a cost).
fn census(kernel: Kernel, img: &Grid<u8>, view: View, mut kept: Vec<u8>) -> CensusPlanes {
    let (w, h) = (img.width(), img.height());
    let stride = match view {
        View::Left => w,
        View::Right { pad } => w + pad,
    };
    let len = h * CENSUS_BYTES * stride;
    // Every plane byte a kept cost comes from is written below (the padding is read only
    // for candidates off the image, whose costs are then overwritten): a buffer of the
    // right size is taken as it is (zeroing it cost 0.5 ms a frame at 640×480).
    if kept.len() != len {
        kept.clear();
        kept.resize(len, 0);
    }
    kept.par_chunks_mut((CENSUS_BYTES * stride).max(1))
        .enumerate()
        .for_each(|(y, planes)| run_census_row(kernel, img, y, view, planes));
    CensusPlanes {
        #[cfg(test)]
        width: w,
        #[cfg(test)]
        height: h,
        #[cfg(test)]
        view,
        stride,
        data: kept,
    }
}

#[allow(unsafe_code)]
fn run_census_row(kernel: Kernel, img: &Grid<u8>, y: usize, view: View, planes: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { census_row_avx2(img, y, view, planes) };
    }
    let _ = kernel;
    census_row(img, y, view, planes)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn census_row_avx2(img: &Grid<u8>, y: usize, view: View, planes: &mut [u8]) {
    census_row(img, y, view, planes)
}

/// One row of census planes (`planes`: the row's six plane rows, each `len / 6` bytes).
/// One comparison of every pixel at a time, eight of them gathered in byte lanes, and
/// each byte written to its plane (reversed for the right view), so the work runs in
/// vector lanes.
#[inline(always)]
fn census_row(img: &Grid<u8>, y: usize, view: View, planes: &mut [u8]) {
    let (w, h) = (img.width(), img.height());
    let stride = planes.len() / CENSUS_BYTES;
    let r = CENSUS_RADIUS;
    let centre = img.row(y);
    let mut byte = vec![0u8; w];
    let mut taken = 0usize;
    for dy in 0..=2 * r {
        let src = img.row((y + dy).saturating_sub(r).min(h - 1));
        for dx in 0..=2 * r {
            if dx == r && dy == r {
                continue;
            }
            compare_shifted(src, dx as isize - r as isize, centre, &mut byte);
            taken += 1;
            if taken.is_multiple_of(8) {
                let plane = &mut planes[(taken / 8 - 1) * stride..][..w];
                match view {
                    View::Left => plane.copy_from_slice(&byte),
                    View::Right { .. } => {
                        for (o, &b) in plane.iter_mut().zip(byte.iter().rev()) {
                            *o = b;
                        }
                    }
                }
            }
        }
    }
}

/// One census comparison for a row: `byte[x] = byte[x] << 1 | (src[x + shift] > centre[x])`,
/// `x + shift` clamped to the row. Inside the row the neighbours are read in place, a
/// straight run the compiler vectorises; the few clamped ones at either end one by one.
#[inline(always)]
fn compare_shifted(src: &[u8], shift: isize, centre: &[u8], byte: &mut [u8]) {
    let w = src.len();
    let mut one = |x: usize| {
        let n = src[(x as isize + shift).clamp(0, w as isize - 1) as usize];
        byte[x] = (byte[x] << 1) | u8::from(n > centre[x]);
    };
    // Columns whose neighbour is inside the row: lo..hi.
    let lo = shift.min(0).unsigned_abs().min(w);
    let hi = w.saturating_sub(shift.max(0).unsigned_abs()).max(lo);
    for x in (0..lo).chain(hi..w) {
        one(x);
    }
    if lo == hi {
        return; // a row no wider than the shift: every neighbour clamped
    }
    let from = (lo as isize + shift) as usize;
    let inside = byte[lo..hi]
        .iter_mut()
        .zip(&src[from..])
        .zip(&centre[lo..hi]);
    for ((b, &n), &c) in inside {
        *b = (*b << 1) | u8::from(n > c);
    }
}

/// A row's census planes, as [`costs`] takes them.
type PlaneRow<'a> = [&'a [u8]; CENSUS_BYTES];

#[allow(unsafe_code)]
fn run_costs(kernel: Kernel, s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if counts_with_vpopcntb(kernel) {
        // SAFETY: AVX2, BMI, AVX-512 F, BW, VL and BITALG were detected (`avx512_popcnt`).
        return unsafe { costs_avx512(s, left, right, out) };
    }
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { costs_avx2(s, left, right, out) };
    }
    let _ = kernel;
    costs(s, left, right, out)
}

/// Whether the census costs of `kernel` count with AVX-512's `VPOPCNTB` here: the AVX2
/// kernel on a CPU that has it ([`crate::cpu::avx512_popcnt`]).
fn counts_with_vpopcntb(kernel: Kernel) -> bool {
    kernel == Kernel::Avx2 && crate::cpu::avx512_popcnt()
}

/// With AVX-512's byte population count the compiler counts 64 bytes an instruction
/// instead of two table lookups per nibble; the same costs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt,avx512f,avx512bw,avx512vl,avx512bitalg")]
fn costs_avx512(s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    costs(s, left, right, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn costs_avx2(s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    costs(s, left, right, out)
}

/// Bytes in a census signature (48 comparisons).
const CENSUS_BYTES: usize = CENSUS_BITS as usize / 8;

/// One row of census costs: `out[x·nd + k]` compares left `x` with right `x − d`.
///
/// The right view's planes are stored right to left ([`View::Right`]), so a pixel's
/// candidates (right columns `x − d_min` down to `x − d_min − nd + 1`) are one forward
/// run of each plane: the Hamming distance is the sum of six byte population counts, in
/// vector lanes. The planes run on past the image's left edge (the padding), so a pixel
/// with candidates off the right image reads them as the others and then gives them the
/// largest cost.
#[inline(always)]
fn costs(s: &Shape, left: PlaneRow<'_>, right: PlaneRow<'_>, out: &mut [u8]) {
    let w = s.w;
    let [l0, l1, l2, l3, l4, l5] = left.map(|p| &p[..w]);
    for (x, cell) in out.chunks_exact_mut(s.nd).enumerate().take(w) {
        // Right x for k = 0 is x − d_min, stored at m = w − 1 − x + d_min.
        let m = w - 1 - x + s.d_min;
        let runs = right.map(|p| &p[m..m + s.nd]);
        let b = [l0[x], l1[x], l2[x], l3[x], l4[x], l5[x]];
        hamming_runs(b, runs, cell);
        // Candidates k with x − d_min − k < 0 fall off the right image.
        let inside = (x + 1).saturating_sub(s.d_min).min(s.nd);
        cell[inside..].fill(CENSUS_BITS);
    }
}

/// `out[k]`: the Hamming distance between the signature whose bytes are `b` and the one
/// whose bytes are `runs[j][k]`. Byte population counts, which the compiler keeps in
/// vector lanes (a table lookup per nibble with AVX2).
#[inline(always)]
fn hamming_runs(b: [u8; CENSUS_BYTES], runs: PlaneRow<'_>, out: &mut [u8]) {
    let n = out.len();
    let [r0, r1, r2, r3, r4, r5] = runs.map(|r| &r[..n]);
    // At most 48 ones: wrapping adds never wrap, and keep the loop free of overflow
    // checks in dev and test builds (which then ran it scalar).
    let ones = |a: u8, r: u8| (a ^ r).count_ones() as u8;
    for k in 0..n {
        out[k] = ones(b[0], r0[k])
            .wrapping_add(ones(b[1], r1[k]))
            .wrapping_add(ones(b[2], r2[k]))
            .wrapping_add(ones(b[3], r3[k]))
            .wrapping_add(ones(b[4], r4[k]))
            .wrapping_add(ones(b[5], r5[k]));
    }
}

/// One sweep over the rows and the paths it follows. Every path of a sweep comes from the
/// row before it or from the same row, so a row's sums are complete as soon as the sweep
/// has passed it.
#[derive(Clone, Copy, PartialEq, Eq)]
struct Sweep {
    /// Rows bottom to top (paths arriving from below), each right to left (following
    /// the path along the row that way), instead of top to bottom, left to right.
    upward: bool,
    /// Also the path along the row the other way (a second run over the row).
    both_ways: bool,
    /// Paths from the row before: 1 (straight) or 3 (and the two diagonals).
    from_row_before: usize,
}

impl Paths {
    /// The sweeps that follow these paths: top to bottom, left to right; then, for 4 and 8
    /// paths, bottom to top, right to left, with as many paths as the first.
    fn sweeps(self) -> (Sweep, Option<Sweep>) {
        let down = |from_row_before, both_ways| Sweep {
            upward: false,
            both_ways,
            from_row_before,
        };
        let up = |from_row_before| Sweep {
            upward: true,
            both_ways: false,
            from_row_before,
        };
        match self {
            Paths::Three => (down(1, true), None),
            Paths::Four => (down(1, false), Some(up(1))),
            Paths::Five => (down(3, true), None),
            Paths::Eight => (down(3, false), Some(up(3))),
        }
    }
}

/// Where a sweep reads its census costs.
#[derive(Clone, Copy)]
enum CostSource<'a> {
    /// Made a row at a time from the two views' census signatures, with this kernel.
    Census(&'a CensusPlanes, &'a CensusPlanes, Kernel),
    /// Read from a volume made beforehand (`[y][x][k]`), for two sweeps over one volume.
    Volume(&'a [u8]),
}

/// The volumes a sweep writes or helps to read, beyond its own rows.
#[derive(Default)]
struct SweepVolumes<'a> {
    /// The sums, written into this volume (`[y][x][k]`); without it into a row of the
    /// sweep's own, handed to the sink.
    sums: Option<&'a mut [u16]>,
    /// A volume the sink reads the same row of: fetched into the cache a row ahead.
    read_by_sink: Option<&'a [u16]>,
}

impl<'a> SweepVolumes<'a> {
    /// The sums written into `sums`, nothing read by the sink.
    fn writing(sums: &'a mut [u16]) -> Self {
        Self {
            sums: Some(sums),
            read_by_sink: None,
        }
    }
}

/// What a sweep hands each finished row to: its row number and the row's sums.
type RowSink<'a> = &'a mut dyn FnMut(usize, &[u16]);

#[allow(unsafe_code)]
fn run_sweep(
    kernel: Kernel,
    s: &Shape,
    p: &SgmParams,
    costs: CostSource<'_>,
    sweep: Sweep,
    volumes: SweepVolumes<'_>,
    sink: RowSink<'_>,
) {
    let narrow = fits_a_byte(p);
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe {
            if narrow {
                sweep_avx2::<u8>(s, p, costs, sweep, volumes, sink)
            } else {
                sweep_avx2::<u16>(s, p, costs, sweep, volumes, sink)
            }
        };
    }
    let _ = kernel;
    if narrow {
        sweep_rows::<u8, false>(s, p, costs, sweep, volumes, sink)
    } else {
        sweep_rows::<u16, false>(s, p, costs, sweep, volumes, sink)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn sweep_avx2<T: Lane>(
    s: &Shape,
    p: &SgmParams,
    costs: CostSource<'_>,
    sweep: Sweep,
    volumes: SweepVolumes<'_>,
    sink: RowSink<'_>,
) {
    sweep_rows::<T, true>(s, p, costs, sweep, volumes, sink)
}

/// Follows `sweep`'s paths over every row: each row's census costs (from `source`), then
/// the sum over the sweep's paths of every pixel's path costs (`[x][k]`; the first path
/// writes, the others add), into that row of `volume` when one is given, else into a row
/// of its own; then `sink(y, sums)`. `AVX2`: the caller runs with AVX2 enabled, and
/// byte lanes at a multiple of 32 disparities step the pixels where no path starts
/// with [`byte_paths::step_paths`].
#[inline(always)]
#[allow(unsafe_code)]
fn sweep_rows<T: Lane, const AVX2: bool>(
    s: &Shape,
    p: &SgmParams,
    source: CostSource<'_>,
    sweep: Sweep,
    volumes: SweepVolumes<'_>,
    sink: RowSink<'_>,
) {
    let SweepVolumes {
        sums: mut volume,
        read_by_sink,
    } = volumes;
    // Only prefetched, where that is an instruction.
    #[cfg(not(target_arch = "x86_64"))]
    let _ = read_by_sink;
    let (w, h, nd) = (s.w, s.h, s.nd);
    let stride = nd + 2;
    let used = sweep.from_row_before;
    let pen = Penalties::<T>::of(p);
    // Paths from the row before: that row's values and this row's.
    let mut prev: Vec<PathRow<T>> = (0..used).map(|_| PathRow::new(w, nd)).collect();
    let mut cur: Vec<PathRow<T>> = (0..used).map(|_| PathRow::new(w, nd)).collect();
    let mut along = AlongRow::<T>::new(nd);
    #[cfg(target_arch = "x86_64")]
    let bytes = AVX2 && T::IS_BYTE && nd.is_multiple_of(32);
    let mut made = match source {
        CostSource::Census(..) => vec![0u8; w * nd],
        CostSource::Volume(_) => Vec::new(),
    };
    let mut own = if volume.is_none() {
        vec![0u16; w * nd]
    } else {
        Vec::new()
    };
    for i in 0..h {
        let y = if sweep.upward { h - 1 - i } else { i };
        let cost: &[u8] = match source {
            CostSource::Census(left, right, kernel) => {
                run_costs(kernel, s, left.row(y), right.row(y), &mut made);
                &made
            }
            CostSource::Volume(v) => &v[y * w * nd..][..w * nd],
        };
        // The next row's parts of the volumes, fetched into the cache a pixel at a time
        // as this row is swept (a volume row, 40–80 kB, read when it is needed waits on
        // memory).
        #[cfg(target_arch = "x86_64")]
        let next_row = (i + 1 < h).then(|| if sweep.upward { y - 1 } else { y + 1 });
        #[cfg(target_arch = "x86_64")]
        let prefetch: [Option<(*const u8, usize)>; 3] = match next_row {
            Some(n) if AVX2 => [
                match source {
                    CostSource::Volume(v) => Some((v[n * w * nd..].as_ptr(), nd)),
                    CostSource::Census(..) => None,
                },
                volume
                    .as_deref()
                    .map(|v| (v[n * w * nd..].as_ptr().cast::<u8>(), 2 * nd)),
                read_by_sink.map(|v| (v[n * w * nd..].as_ptr().cast::<u8>(), 2 * nd)),
            ],
            _ => [None; 3],
        };
        let sum: &mut [u16] = match volume.as_deref_mut() {
            Some(v) => &mut v[y * w * nd..][..w * nd],
            None => &mut own,
        };
        for j in 0..w {
            let (x, behind, ahead) = if sweep.upward {
                let x = w - 1 - j;
                (x, (x + 1 < w).then_some(x + 1), x.checked_sub(1))
            } else {
                (j, j.checked_sub(1), (j + 1 < w).then_some(j + 1))
            };
            let c = &cost[x * nd..][..nd];
            let out_sum = &mut sum[x * nd..][..nd];
            #[cfg(target_arch = "x86_64")]
            for &(base, len) in prefetch.iter().flatten() {
                let mut at = x * len;
                while at < (x + 1) * len {
                    // SAFETY: `base` starts a row of `w` pixels of `len` bytes each
                    // inside its volume (taken by checked slicing), and `at` stays in
                    // pixel x's part of it; a prefetch reads and writes nothing.
                    unsafe {
                        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                            base.add(at).cast(),
                        )
                    };
                    at += 64;
                }
            }
            #[cfg(target_arch = "x86_64")]
            if bytes && i > 0 && j > 0 {
                if let (Some(b), Some(a)) = (behind, ahead) {
                    // SAFETY: `bytes` needs AVX2, which the caller enabled.
                    unsafe {
                        interior_bytes(c, &mut along, (&prev, &mut cur), [x, b, a], pen, out_sum)
                    };
                    continue;
                }
                if used == 1 {
                    // SAFETY: as above.
                    unsafe {
                        interior_bytes(c, &mut along, (&prev, &mut cur), [x, x, x], pen, out_sum)
                    };
                    continue;
                }
            }
            // From the row before: straight, then the diagonals from the column behind
            // and the one ahead.
            let sources = [Some(x), behind, ahead];
            let mut first = 0;
            if j > 0 && i > 0 {
                // Along the row and straight down in one run, the sums written once.
                let from = &prev[0].cost[x * stride..][..stride];
                let out = &mut cur[0].cost[x * stride + 1..][..nd];
                cur[0].min[x] =
                    along.pixel_with_straight(c, from, prev[0].min[x], pen, out, out_sum);
                first = 1;
            } else {
                // Along the row (writes the sums).
                along.pixel::<true>(j == 0, c, pen, out_sum);
            }
            for (path, source) in sources.iter().enumerate().take(used).skip(first) {
                let out = &mut cur[path].cost[x * stride + 1..][..nd];
                let least = match *source {
                    Some(sx) if i > 0 => {
                        let from = &prev[path].cost[sx * stride..][..stride];
                        step::<T, false>(c, from, prev[path].min[sx], pen, out, out_sum)
                    }
                    _ => start::<T, false>(c, out, out_sum),
                };
                cur[path].min[x] = least;
            }
        }
        std::mem::swap(&mut prev, &mut cur);
        if sweep.both_ways {
            for j in 0..w {
                let x = if sweep.upward { j } else { w - 1 - j };
                let c = &cost[x * nd..][..nd];
                let out_sum = &mut sum[x * nd..][..nd];
                #[cfg(target_arch = "x86_64")]
                if bytes && j > 0 {
                    // SAFETY: `bytes` needs AVX2, which the caller enabled.
                    unsafe { along_bytes(c, &mut along, pen, out_sum) };
                    continue;
                }
                along.pixel::<false>(j == 0, c, pen, out_sum);
            }
        }
        sink(y, sum);
    }
}

/// The integer type of path costs: `u8` where every value a step can reach fits a byte
/// ([`fits_a_byte`]), twice the lanes of `u16` per vector, else `u16`. Path costs are at
/// most `CENSUS_BITS + p2` and a step's candidates at most `CENSUS_BITS + 2·p2`.
trait Lane: Copy + Ord {
    /// Padding either side of a pixel's path costs: `step` reads `d − 1` and `d + 1` for
    /// every `d` without edge cases. Large, so `+ p1` never wins.
    const PAD: Self;
    /// Larger than any path cost.
    const MAX: Self;
    const ZERO: Self;
    /// Byte lanes: [`Lane::bytes`] and [`Lane::bytes_mut`] give the values (read by
    /// the AVX2 path steps only).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    const IS_BYTE: bool;
    /// A census cost.
    fn of_cost(c: u8) -> Self;
    /// A penalty (`p1` or `p2`), which fits when the type was chosen for it.
    fn of_penalty(v: u16) -> Self;
    fn widen(self) -> u16;
    /// Sums that stay in range by the bounds above: wrapping adds, which never wrap
    /// then and keep the loops free of overflow checks in dev and test builds (which
    /// ran the sweeps scalar, ten times slower; the tests check the sums against their
    /// definition).
    fn add(self, o: Self) -> Self;
    /// Sums that may not (a padding lane plus `p1`): clamped at the type's maximum,
    /// which no step ever needs to beat.
    fn add_clamped(self, o: Self) -> Self;
    /// A difference that stays non-negative by the bounds above (wrapping, as `add`).
    fn sub(self, o: Self) -> Self;
    /// The values as bytes, for byte lanes; `None` for wider ones.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn bytes(v: &[Self]) -> Option<&[u8]>;
    /// As [`Lane::bytes`], to write.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn bytes_mut(v: &mut [Self]) -> Option<&mut [u8]>;
}

impl Lane for u8 {
    const PAD: Self = u8::MAX;
    const MAX: Self = u8::MAX;
    const ZERO: Self = 0;
    const IS_BYTE: bool = true;
    #[inline(always)]
    fn of_cost(c: u8) -> Self {
        c
    }
    #[inline(always)]
    fn of_penalty(v: u16) -> Self {
        v as u8
    }
    #[inline(always)]
    fn widen(self) -> u16 {
        u16::from(self)
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.wrapping_add(o)
    }
    #[inline(always)]
    fn add_clamped(self, o: Self) -> Self {
        self.saturating_add(o)
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self.wrapping_sub(o)
    }
    #[inline(always)]
    fn bytes(v: &[Self]) -> Option<&[u8]> {
        Some(v)
    }
    #[inline(always)]
    fn bytes_mut(v: &mut [Self]) -> Option<&mut [u8]> {
        Some(v)
    }
}

impl Lane for u16 {
    const PAD: Self = 0x3fff;
    const MAX: Self = u16::MAX;
    const ZERO: Self = 0;
    const IS_BYTE: bool = false;
    #[inline(always)]
    fn of_cost(c: u8) -> Self {
        u16::from(c)
    }
    #[inline(always)]
    fn of_penalty(v: u16) -> Self {
        v
    }
    #[inline(always)]
    fn widen(self) -> u16 {
        self
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.wrapping_add(o)
    }
    #[inline(always)]
    fn add_clamped(self, o: Self) -> Self {
        self.saturating_add(o)
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self.wrapping_sub(o)
    }
    #[inline(always)]
    fn bytes(_: &[Self]) -> Option<&[u8]> {
        None
    }
    #[inline(always)]
    fn bytes_mut(_: &mut [Self]) -> Option<&mut [u8]> {
        None
    }
}

/// Whether path costs fit `u8` lanes: a step's largest candidate, `CENSUS_BITS + 2·p2`
/// (the previous minimum, at most `CENSUS_BITS + p2`, plus `p2`), stays within a byte,
/// so the clamped padding (255) is never below a candidate that could win.
fn fits_a_byte(p: &SgmParams) -> bool {
    u32::from(CENSUS_BITS) + 2 * u32::from(p.p2) <= u32::from(u8::MAX)
}

/// The penalties in a path cost's type.
#[derive(Clone, Copy)]
struct Penalties<T> {
    p1: T,
    p2: T,
}

impl<T: Lane> Penalties<T> {
    fn of(p: &SgmParams) -> Self {
        Self {
            p1: T::of_penalty(p.p1),
            p2: T::of_penalty(p.p2),
        }
    }
}

/// Path costs of one row for every pixel (stride `nd + 2`, padded) and their minima.
struct PathRow<T> {
    cost: Vec<T>,
    min: Vec<T>,
}

impl<T: Lane> PathRow<T> {
    fn new(w: usize, nd: usize) -> Self {
        Self {
            cost: vec![T::PAD; w * (nd + 2)],
            min: vec![T::ZERO; w],
        }
    }
}

/// The path along a row: the previous pixel's values (padded as [`PathRow`]'s), room for
/// this pixel's, and the previous minimum.
struct AlongRow<T> {
    prev: Vec<T>,
    next: Vec<T>,
    min: T,
}

impl<T: Lane> AlongRow<T> {
    fn new(nd: usize) -> Self {
        Self {
            prev: vec![T::PAD; nd + 2],
            next: vec![T::PAD; nd + 2],
            min: T::ZERO,
        }
    }

    /// The next pixel along the row, not its first, and the step of a path from the row
    /// before (`from`, `from_min`, into `out`) in the same run; writes the sums.
    /// Returns the other path's minimum.
    #[inline(always)]
    fn pixel_with_straight(
        &mut self,
        c: &[u8],
        from: &[T],
        from_min: T,
        pen: Penalties<T>,
        out: &mut [T],
        sum: &mut [u16],
    ) -> T {
        let n = c.len();
        let next = &mut self.next[1..=n];
        let (la, lo) = step_two(
            c,
            (&self.prev, self.min),
            (from, from_min),
            pen,
            next,
            out,
            sum,
        );
        self.min = la;
        std::mem::swap(&mut self.prev, &mut self.next);
        lo
    }

    /// The next pixel along the row (`first`: where the path starts): its path costs
    /// from its census costs `c`, added to its sums (or written, `SET`).
    #[inline(always)]
    fn pixel<const SET: bool>(
        &mut self,
        first: bool,
        c: &[u8],
        pen: Penalties<T>,
        sum: &mut [u16],
    ) {
        let out = &mut self.next[1..=c.len()];
        self.min = if first {
            start::<T, SET>(c, out, sum)
        } else {
            step::<T, SET>(c, &self.prev, self.min, pen, out, sum)
        };
        std::mem::swap(&mut self.prev, &mut self.next);
    }
}

/// Two steps of [`step`] in one run over the disparities, writing their sum: the path
/// along the row (`along`, `along_min`) and another (`other`, `other_min`). Returns
/// both minima.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn step_two<T: Lane>(
    cost: &[u8],
    along: (&[T], T),
    other: (&[T], T),
    pen: Penalties<T>,
    out_along: &mut [T],
    out_other: &mut [T],
    sum: &mut [u16],
) -> (T, T) {
    let n = out_along.len();
    let (pa, ma) = along;
    let (po, mo) = other;
    let (ja, jo) = (ma.add(pen.p2), mo.add(pen.p2));
    let (mut la, mut lo) = (T::MAX, T::MAX);
    let a3 = pa[..n].iter().zip(&pa[1..=n]).zip(&pa[2..n + 2]);
    let o3 = po[..n].iter().zip(&po[1..=n]).zip(&po[2..n + 2]);
    let outs = out_along
        .iter_mut()
        .zip(out_other.iter_mut())
        .zip(sum.iter_mut());
    for ((((oa, oo), s), &c), (((&ab, &am), &aa), ((&ob, &om), &oa2))) in
        outs.zip(&cost[..n]).zip(a3.zip(o3))
    {
        let a = path_cost(c, (ab, am, aa), ma, ja, pen.p1);
        let o = path_cost(c, (ob, om, oa2), mo, jo, pen.p1);
        *oa = a;
        *oo = o;
        *s = a.widen().wrapping_add(o.widen());
        la = la.min(a);
        lo = lo.min(o);
    }
    (la, lo)
}

/// One disparity's path cost from its census cost `c` and the previous pixel's path
/// costs at `d − 1`, `d`, `d + 1` (`around`), their minimum over every `d` (`prev_min`)
/// and that plus `p2` (`jump`): [`step`]'s formula, which [`step_two`] shares.
#[inline(always)]
fn path_cost<T: Lane>(c: u8, around: (T, T, T), prev_min: T, jump: T, p1: T) -> T {
    let (below, here, above) = around;
    let best = here.min(below.min(above).add_clamped(p1)).min(jump);
    T::of_cost(c).add(best.sub(prev_min))
}

/// A path's first pixel: its costs. Adds them to `sum` (or writes them, `SET`);
/// returns their minimum.
#[inline(always)]
fn start<T: Lane, const SET: bool>(cost: &[u8], out: &mut [T], sum: &mut [u16]) -> T {
    let mut least = T::MAX;
    for ((o, s), &c) in out.iter_mut().zip(sum.iter_mut()).zip(cost) {
        *o = T::of_cost(c);
        *s = if SET {
            o.widen()
        } else {
            s.wrapping_add(o.widen())
        };
        least = least.min(*o);
    }
    least
}

/// One step along a path: `L(d) = C(d) + min(L'(d), L'(d ± 1) + p1, min L' + p2) − min L'`
/// with `L'` the previous pixel's values (`prev`, padded: `prev[d + 1]` is `L'(d)`,
/// minimum `prev_min`). Writes `L` into `out`, adds it to `sum` (or writes it, `SET`),
/// returns its minimum. Values are at most `CENSUS_BITS + p2` (≤ 1072), so eight paths
/// sum to at most 8576. The minimum is taken before `C` is added, so no intermediate
/// exceeds `CENSUS_BITS + 2·p2`.
#[inline(always)]
fn step<T: Lane, const SET: bool>(
    cost: &[u8],
    prev: &[T],
    prev_min: T,
    pen: Penalties<T>,
    out: &mut [T],
    sum: &mut [u16],
) -> T {
    let n = out.len();
    let jump = prev_min.add(pen.p2);
    let (below, here, above) = (&prev[..n], &prev[1..=n], &prev[2..n + 2]);
    let mut least = T::MAX;
    let lanes = out
        .iter_mut()
        .zip(sum.iter_mut())
        .zip(cost)
        .zip(below.iter().zip(here).zip(above));
    for (((o, s), &c), ((&b, &m), &a)) in lanes {
        *o = path_cost(c, (b, m, a), prev_min, jump, pen.p1);
        *s = if SET {
            o.widen()
        } else {
            s.wrapping_add(o.widen())
        };
        least = least.min(*o);
    }
    least
}

/// Byte lanes' values ([`Lane::bytes`]); called where the lanes are known to be bytes.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn bytes<T: Lane>(v: &[T]) -> &[u8] {
    T::bytes(v).expect("byte lanes")
}

/// As [`bytes`], to write.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn bytes_mut<T: Lane>(v: &mut [T]) -> &mut [u8] {
    T::bytes_mut(v).expect("byte lanes")
}

/// Steps every path of a pixel where none starts (not in the sweep's first row or
/// column, and with the diagonals not in its last column) in one run of
/// [`byte_paths::step_paths`]: the path along the row from `along`, and path `r` from
/// the row before from `rows.0[r]` at column `from[r]` into `rows.1[r]` at column
/// `from[0]`. Writes the sums.
///
/// # Safety
/// The CPU has AVX2; `T` is a byte lane and the disparities a multiple of 32.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
unsafe fn interior_bytes<T: Lane>(
    c: &[u8],
    along: &mut AlongRow<T>,
    rows: (&[PathRow<T>], &mut [PathRow<T>]),
    from: [usize; 3],
    pen: Penalties<T>,
    sum: &mut [u16],
) {
    let (prev, cur) = rows;
    let nd = c.len();
    let stride = nd + 2;
    let x = from[0];
    let (p1, p2) = (pen.p1.widen() as u8, pen.p2.widen() as u8);
    let source = |r: usize| {
        let row = &prev[r];
        (
            bytes(&row.cost[from[r] * stride..][..stride]),
            row.min[from[r]].widen() as u8,
        )
    };
    let along_from = (bytes(&along.prev), along.min.widen() as u8);
    let next = bytes_mut(&mut along.next[1..=nd]);
    let at = x * stride + 1;
    match cur {
        [c0] => {
            let out = [next, bytes_mut(&mut c0.cost[at..][..nd])];
            // SAFETY: AVX2, by this function's contract.
            let m = unsafe {
                byte_paths::step_paths::<2, false>(c, [along_from, source(0)], p1, p2, out, sum)
            };
            along.min = T::of_cost(m[0]);
            c0.min[x] = T::of_cost(m[1]);
        }
        [c0, c1, c2] => {
            let out = [
                next,
                bytes_mut(&mut c0.cost[at..][..nd]),
                bytes_mut(&mut c1.cost[at..][..nd]),
                bytes_mut(&mut c2.cost[at..][..nd]),
            ];
            let from = [along_from, source(0), source(1), source(2)];
            // SAFETY: AVX2, by this function's contract.
            let m = unsafe { byte_paths::step_paths::<4, false>(c, from, p1, p2, out, sum) };
            along.min = T::of_cost(m[0]);
            c0.min[x] = T::of_cost(m[1]);
            c1.min[x] = T::of_cost(m[2]);
            c2.min[x] = T::of_cost(m[3]);
        }
        _ => unreachable!("1 or 3 paths from the row before"),
    }
    std::mem::swap(&mut along.prev, &mut along.next);
}

/// The next pixel along the row, not its first, with [`byte_paths::step_paths`]: adds
/// its path costs to `sum`.
///
/// # Safety
/// As [`interior_bytes`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
unsafe fn along_bytes<T: Lane>(
    c: &[u8],
    along: &mut AlongRow<T>,
    pen: Penalties<T>,
    sum: &mut [u16],
) {
    let nd = c.len();
    let (p1, p2) = (pen.p1.widen() as u8, pen.p2.widen() as u8);
    let from = [(bytes(&along.prev), along.min.widen() as u8)];
    let out = [bytes_mut(&mut along.next[1..=nd])];
    // SAFETY: AVX2, by this function's contract.
    let [m] = unsafe { byte_paths::step_paths::<1, true>(c, from, p1, p2, out, sum) };
    along.min = T::of_cost(m);
    std::mem::swap(&mut along.prev, &mut along.next);
}

/// Selects a row's disparities (`out`, which comes in all NaN: a row selected again is
/// reset to that) from its sums (`sum`, plus `other` when the paths were summed in two
/// volumes), packed as [`Packing::of`] says.
#[allow(unsafe_code)]
fn run_select(
    kernel: Kernel,
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
) -> MatchStats {
    let wide = |out: &mut [f32]| {
        select_with::<u32>(kernel, s, p, sum, other, out, 16)
            .expect("32-bit packing holds every sum (at most 8 · (48 + 1024))")
    };
    match Packing::of(s, p) {
        Packing::Narrow(shift) => {
            select_with::<u16>(kernel, s, p, sum, other, out, shift).unwrap_or_else(|| {
                // A clamped cost decided somewhere in the row: again, exactly.
                out.fill(f32::NAN);
                wide(out)
            })
        }
        Packing::Wide => wide(out),
    }
}

#[allow(unsafe_code)]
#[inline(always)]
fn select_with<P: Packed>(
    kernel: Kernel,
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
    shift: u32,
) -> Option<MatchStats> {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { select_avx2::<P>(s, p, sum, other, out, shift) };
    }
    let _ = kernel;
    select::<P>(s, p, sum, other, out, shift)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn select_avx2<P: Packed>(
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
    shift: u32,
) -> Option<MatchStats> {
    select::<P>(s, p, sum, other, out, shift)
}

/// How [`select`] packs a candidate's aggregated cost and index into one integer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Packing {
    /// `cost << shift | k` in 16 bits (twice the lanes), costs above `u16::MAX >> shift`
    /// clamped to it. A row where a clamped cost would decide (a pixel's least cost) is
    /// selected again, wide: every result is the wide one. (A right column's best match
    /// in the left–right check is then never clamped: its candidates include the best
    /// of the pixel that reads it.)
    Narrow(u32),
    /// `cost << 16 | k` in 32 bits.
    Wide,
}

impl Packing {
    /// Narrow when the largest sum (every path at its bound, `CENSUS_BITS + p2`) shifted
    /// past the largest index fits 16 bits, or, with byte lanes ([`fits_a_byte`]: `p2`
    /// at most 103), when the clamp is at least twice the largest census cost summed
    /// over the paths (a least cost that high is a pixel matched nowhere: rare enough
    /// that a second selection costs nothing; with larger penalties paths from opposite
    /// sides of an occlusion could each carry hundreds at every candidate). At the
    /// default penalties: 3, 4 and 5 paths up to 128 disparities, 8 paths up to 64.
    fn of(s: &Shape, p: &SgmParams) -> Self {
        let shift = usize::BITS - (s.nd - 1).leading_zeros();
        let paths = p.paths.count() as u64;
        let largest_sum = paths * (u64::from(CENSUS_BITS) + u64::from(p.p2));
        let clamp = u64::from(u16::MAX) >> shift;
        let rare = fits_a_byte(p) && clamp >= 2 * paths * u64::from(CENSUS_BITS);
        if largest_sum <= clamp || rare {
            Packing::Narrow(shift)
        } else {
            Packing::Wide
        }
    }
}

/// A candidate's aggregated cost and index `k` in one integer, the cost in the high
/// bits: the smallest is the least cost at its smallest `k`.
trait Packed: Copy + Ord {
    /// No smaller than any packed candidate.
    const MAX: Self;
    /// The largest cost a packing holds: larger ones are clamped to it.
    fn largest_cost(shift: u32) -> u16;
    fn pack(cost: u16, k: u16, shift: u32) -> Self;
    fn cost(self, shift: u32) -> u16;
    fn index(self, shift: u32) -> usize;
}

impl Packed for u16 {
    const MAX: Self = u16::MAX;
    #[inline(always)]
    fn largest_cost(shift: u32) -> u16 {
        u16::MAX >> shift
    }
    #[inline(always)]
    fn pack(cost: u16, k: u16, shift: u32) -> Self {
        (cost.min(Self::largest_cost(shift)) << shift) | k
    }
    #[inline(always)]
    fn cost(self, shift: u32) -> u16 {
        self >> shift
    }
    #[inline(always)]
    fn index(self, shift: u32) -> usize {
        usize::from(self & ((1 << shift) - 1))
    }
}

impl Packed for u32 {
    const MAX: Self = u32::MAX;
    #[inline(always)]
    fn largest_cost(_: u32) -> u16 {
        u16::MAX
    }
    #[inline(always)]
    fn pack(cost: u16, k: u16, shift: u32) -> Self {
        (u32::from(cost) << shift) | u32::from(k)
    }
    #[inline(always)]
    fn cost(self, shift: u32) -> u16 {
        (self >> shift) as u16
    }
    #[inline(always)]
    fn index(self, shift: u32) -> usize {
        (self & ((1 << shift) - 1)) as usize
    }
}

/// One row's disparities from its aggregated sums (`sum`, plus `other` when the paths
/// were summed in two volumes): winner takes all, uniqueness, sub-pixel fit, left–right
/// check. Candidates are packed as `P` with the index in the low `shift` bits; `None`
/// (with `out` part written) where a clamped cost would decide ([`Packing::Narrow`]).
#[inline(always)]
fn select<P: Packed>(
    s: &Shape,
    p: &SgmParams,
    sum: &[u16],
    other: Option<&[u16]>,
    out: &mut [f32],
    shift: u32,
) -> Option<MatchStats> {
    let clamp = P::largest_cost(shift);
    let (w, nd) = (s.w, s.nd);
    let mut stats = MatchStats::default();
    let mut total = vec![0u16; nd];
    let mut packed = vec![P::MAX; nd];
    let index: Vec<u16> = (0..nd as u16).collect();
    // The right image's best match per column, packed so one `min` keeps both (ties:
    // the smaller k), stored by `j = w − 1 − right column`: the candidates k of left
    // column x are then the contiguous run `j = w − 1 − x + d_min + k`.
    let check = p.lr_max_diff.is_some();
    let mut right = vec![P::MAX; w];
    let d_max = s.d_min + nd - 1;
    let mut best_k = vec![u16::MAX; w];
    for x in 0..w {
        let a = &sum[x * nd..][..nd];
        let cell: &[u16] = match other {
            Some(other) => {
                let b = &other[x * nd..][..nd];
                for ((t, &a), &b) in total.iter_mut().zip(a).zip(b) {
                    *t = a + b;
                }
                &total
            }
            None => a,
        };
        // The best candidate comes with the packing: the smallest packed value is the
        // least cost at its smallest k.
        let mut least = P::MAX;
        for ((q, &t), &k) in packed.iter_mut().zip(cell).zip(&index) {
            *q = P::pack(t, k, shift);
            least = least.min(*q);
        }
        if check && x >= s.d_min {
            // Candidates whose right column is inside the image.
            let n = (x - s.d_min).min(nd - 1) + 1;
            let j = w - 1 - (x - s.d_min);
            for (r, &q) in right[j..j + n].iter_mut().zip(&packed[..n]) {
                *r = (*r).min(q);
            }
        }
        if x < d_max {
            continue; // candidates off the right image: the invalid band
        }
        let (best, k) = (least.cost(shift), least.index(shift));
        if best == clamp {
            return None;
        }
        // Not unique: another candidate, not next to the best, within the ratio. A best
        // cost of 0 tied elsewhere counts as not unique (OpenCV's strict test keeps it).
        let limit = (u32::from(best) * 100).saturating_sub(1) / (100 - p.uniqueness_ratio);
        let t = limit.min(u32::from(u16::MAX)) as u16;
        // Counted in 16-bit lanes (a `count()` widens every lane to 64 bits); at most
        // `nd` candidates, and `nd` fits 16 bits.
        let within = cell.iter().fold(0u16, |n, &c| n + u16::from(c <= t));
        let near = (k.saturating_sub(1)..=(k + 1).min(nd - 1))
            .filter(|&i| cell[i] <= t)
            .count();
        if k == 0 || k == nd - 1 {
            stats.range_edge += 1;
            continue;
        }
        if usize::from(within) > near {
            stats.not_unique += 1;
            continue;
        }
        best_k[x] = k as u16;
        let offset = subpixel_offset(p.subpixel, cell[k - 1], best, cell[k + 1]);
        out[x] = (s.d_min + k) as f32 + offset;
    }
    if let Some(max_diff) = p.lr_max_diff {
        for x in d_max..w {
            let k = best_k[x];
            if k == u16::MAX {
                continue;
            }
            let xr = x - s.d_min - usize::from(k);
            let from_right = right[w - 1 - xr];
            // That right column's candidates include this pixel's best, whose cost is
            // below the clamp: so is the column's best.
            debug_assert!(from_right.cost(shift) < clamp);
            let right_k = from_right.index(shift);
            if right_k.abs_diff(usize::from(k)) > max_diff as usize {
                out[x] = f32::NAN;
                stats.left_right += 1;
            }
        }
    }
    Some(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::block_match::{BlockMatchParams, BlockMatcher};
    use crate::stereo::synthetic::{Membrane, Plane, StereoRig, render_pair};

    /// Random texture, smoothed a little so sub-pixel shifts interpolate.
    fn texture(w: usize, h: usize, seed: u64) -> Grid<f32> {
        let mut state = seed;
        let noise = Grid::from_fn(w, h, |_, _| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        });
        Grid::from_fn(w, h, |x, y| {
            let mut acc = 0.0;
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                acc += noise.get((x + dx).min(w - 1), (y + dy).min(h - 1));
            }
            acc / 4.0
        })
    }

    /// A pair whose disparity is `d(x, y)` everywhere: the right view samples the left
    /// scene at `x + d` (linear interpolation).
    pub(super) fn shifted_pair(
        w: usize,
        h: usize,
        d: impl Fn(usize, usize) -> f32,
    ) -> (Grid<u8>, Grid<u8>) {
        let scene = texture(w + 200, h, 7);
        let sample = |x: f32, y: usize| {
            let x0 = x.floor().max(0.0) as usize;
            let t = x - x0 as f32;
            let a = scene.get(x0.min(w + 199), y);
            let b = scene.get((x0 + 1).min(w + 199), y);
            ((a * (1.0 - t) + b * t) * 255.0).round() as u8
        };
        let left = Grid::from_fn(w, h, |x, y| sample(x as f32 + 100.0, y));
        let right = Grid::from_fn(w, h, |x, y| sample(x as f32 + 100.0 + d(x, y), y));
        (left, right)
    }

    fn matcher(paths: Paths, kernel: Kernel) -> SemiGlobalMatcher {
        SemiGlobalMatcher::new(SgmParams {
            paths,
            ..SgmParams::default()
        })
        .unwrap()
        .with_kernel(kernel)
        .unwrap()
    }

    #[test]
    fn a_constant_shift_is_found_exactly_by_every_variant() {
        let (l, r) = shifted_pair(160, 60, |_, _| 23.0);
        for paths in Paths::ALL {
            for kernel in [Kernel::Portable, Kernel::Avx2]
                .into_iter()
                .filter(|k| k.is_available())
            {
                let m = matcher(paths, kernel).compute(&l, &r).unwrap();
                let valid: Vec<f32> = m
                    .disparity
                    .as_slice()
                    .iter()
                    .copied()
                    .filter(|v| v.is_finite())
                    .collect();
                // Everything right of the invalid band (63 columns) is found.
                assert!(
                    valid.len() >= (160 - 63 - 4) * 56,
                    "{paths:?} {kernel:?}: {}",
                    valid.len()
                );
                // Whole pixels exactly; the sub-pixel fit on aggregated costs scatters
                // around them (its RMS is the figure to improve).
                let worst = valid.iter().map(|v| (v - 23.0).abs()).fold(0.0, f32::max);
                let rms = (valid.iter().map(|v| (v - 23.0).powi(2)).sum::<f32>()
                    / valid.len() as f32)
                    .sqrt();
                assert!(
                    worst < 0.5 && rms < 0.12,
                    "{paths:?} {kernel:?}: worst {worst}, RMS {rms}"
                );
                // Nothing in the invalid band.
                assert!((0..60).all(|y| (0..63).all(|x| m.disparity.get(x, y).is_nan())));
            }
        }
    }

    /// The definition of aggregation: for each path direction `(dx, dy)` (the previous
    /// pixel is `(x − dx, y − dy)`), `L(p, d) = C(p, d) + min(L(p′, d), L(p′, d ± 1) + p1,
    /// min L(p′) + p2) − min L(p′)`, starting with `C` where `p′` is off the image; the
    /// sum over the directions, in i64 with no reuse of anything the sweeps share.
    fn aggregated_by_definition(
        left: &CensusPlanes,
        right: &CensusPlanes,
        p: &SgmParams,
        directions: &[(isize, isize)],
    ) -> Vec<i64> {
        let (w, h) = (left.width, left.height);
        let nd = p.num_disparities as usize;
        let cost = |x: usize, y: usize, k: usize| -> i64 {
            let xr = x as isize - (p.min_disparity as usize + k) as isize;
            if xr < 0 {
                i64::from(CENSUS_BITS)
            } else {
                let (a, b) = (left.signature(x, y), right.signature(xr as usize, y));
                i64::from((a ^ b).count_ones())
            }
        };
        let mut total = vec![0i64; w * h * nd];
        for &(dx, dy) in directions {
            let mut l = vec![0i64; w * h * nd];
            // Rows and columns in the order the path runs, so p′ comes before p.
            let ys: Vec<usize> = if dy < 0 {
                (0..h).rev().collect()
            } else {
                (0..h).collect()
            };
            let xs: Vec<usize> = if dx < 0 {
                (0..w).rev().collect()
            } else {
                (0..w).collect()
            };
            for &y in &ys {
                for &x in &xs {
                    let (px, py) = (x as isize - dx, y as isize - dy);
                    let inside = px >= 0 && py >= 0 && px < w as isize && py < h as isize;
                    for k in 0..nd {
                        let c = cost(x, y, k);
                        let v = if inside {
                            let at = |k: usize| l[(py as usize * w + px as usize) * nd + k];
                            let least = (0..nd).map(at).min().unwrap();
                            let mut best = at(k).min(least + i64::from(p.p2));
                            if k > 0 {
                                best = best.min(at(k - 1) + i64::from(p.p1));
                            }
                            if k + 1 < nd {
                                best = best.min(at(k + 1) + i64::from(p.p1));
                            }
                            c + best - least
                        } else {
                            c
                        };
                        l[(y * w + x) * nd + k] = v;
                    }
                }
            }
            for (t, v) in total.iter_mut().zip(&l) {
                *t += v;
            }
        }
        total
    }

    /// The sweeps' sums over every path, as `compute` combines them: the second sweep
    /// adding its rows as it goes (one thread), or into a volume of its own
    /// (`side_by_side`).
    fn aggregated_by_sweeps(
        kernel: Kernel,
        left: &CensusPlanes,
        right: &CensusPlanes,
        p: &SgmParams,
        side_by_side: bool,
    ) -> Vec<i64> {
        let s = Shape {
            w: left.width,
            h: left.height,
            nd: p.num_disparities as usize,
            d_min: p.min_disparity as usize,
        };
        let row_cells = s.w * s.nd;
        let mut total = vec![0i64; row_cells * s.h];
        let (first, second) = p.paths.sweeps();
        let mut add = |y: usize, sum: &[u16]| {
            for (t, &v) in total[y * row_cells..][..row_cells].iter_mut().zip(sum) {
                *t += i64::from(v);
            }
        };
        match second {
            None => run_sweep(
                kernel,
                &s,
                p,
                CostSource::Census(left, right, kernel),
                first,
                SweepVolumes::default(),
                &mut add,
            ),
            Some(second) => {
                let mut volume = vec![0u8; row_cells * s.h];
                for (y, row) in volume.chunks_exact_mut(row_cells).enumerate() {
                    run_costs(kernel, &s, left.row(y), right.row(y), row);
                }
                let costs = CostSource::Volume(&volume);
                let mut sums = vec![0u16; row_cells * s.h];
                run_sweep(
                    kernel,
                    &s,
                    p,
                    costs,
                    first,
                    SweepVolumes::writing(&mut sums),
                    &mut |_, _| {},
                );
                for (y, row) in sums.chunks_exact(row_cells).enumerate() {
                    add(y, row);
                }
                if side_by_side {
                    let mut own = vec![0u16; row_cells * s.h];
                    run_sweep(
                        kernel,
                        &s,
                        p,
                        costs,
                        second,
                        SweepVolumes::writing(&mut own),
                        &mut |_, _| {},
                    );
                    for (y, row) in own.chunks_exact(row_cells).enumerate() {
                        add(y, row);
                    }
                } else {
                    let volumes = SweepVolumes {
                        sums: None,
                        read_by_sink: Some(&sums),
                    };
                    run_sweep(kernel, &s, p, costs, second, volumes, &mut add);
                }
            }
        }
        total
    }

    /// The census planes against the definition: for every pixel of a view (left or
    /// right, each kernel), comparison `t` of the 48 (rows then columns of the 7×7
    /// window, the centre skipped; neighbours clamped to the image) in bit
    /// `8·(t / 8) + 7 − t % 8` of its signature.
    #[test]
    fn census_planes_hold_each_comparison() {
        // Rows narrower than the window too: every neighbour clamped.
        for (iw, ih) in [(37, 11), (5, 2), (2, 3), (1, 1)] {
            let (img, _) = shifted_pair(iw, ih, |x, y| 4.0 + 0.3 * x as f32 + 0.1 * y as f32);
            let (w, h) = (iw as isize, ih as isize);
            let at = |x: isize, y: isize| {
                img.get(x.clamp(0, w - 1) as usize, y.clamp(0, h - 1) as usize)
            };
            for kernel in [Kernel::Portable, Kernel::Avx2]
                .into_iter()
                .filter(|k| k.is_available())
            {
                for view in [View::Left, View::Right { pad: 5 }] {
                    // A kept buffer of the right size with stale contents is overwritten.
                    let stale = vec![0xa5; ih * CENSUS_BYTES * (iw + 5)];
                    let kept = if view == View::Left {
                        Vec::new()
                    } else {
                        stale
                    };
                    let planes = census(kernel, &img, view, kept);
                    let mut ones = 0;
                    for y in 0..h {
                        for x in 0..w {
                            let mut want = 0u64;
                            let mut t = 0;
                            for dy in -3..=3 {
                                for dx in -3..=3 {
                                    if (dx, dy) == (0, 0) {
                                        continue;
                                    }
                                    if at(x + dx, y + dy) > at(x, y) {
                                        want |= 1 << (8 * (t / 8) + 7 - t % 8);
                                    }
                                    t += 1;
                                }
                            }
                            let got = planes.signature(x as usize, y as usize);
                            assert_eq!(got, want, "{iw}x{ih} {kernel:?} {view:?} ({x}, {y})");
                            ones += want.count_ones();
                        }
                    }
                    // Both answers occur: not a census of all zeros or all ones.
                    if iw * ih > 100 {
                        assert!(ones > 1000 && ones < 37 * 11 * 47, "{ones}");
                    }
                }
            }
        }
    }

    /// A census cost kernel agrees cell for cell with the portable one: rows of several
    /// widths and disparity counts, so the 64-byte lanes have tails.
    fn check_cost_kernel(
        name: &str,
        kernel: impl Fn(&Shape, PlaneRow<'_>, PlaneRow<'_>, &mut [u8]),
    ) {
        for (w, nd, d_min) in [(75, 16, 3), (130, 64, 0), (97, 48, 5)] {
            let (l, r) = shifted_pair(w, 9, |x, _| 4.0 + 0.05 * x as f32);
            let s = Shape { w, h: 9, nd, d_min };
            let (cl, cr) = (
                census(Kernel::Portable, &l, View::Left, Vec::new()),
                census(
                    Kernel::Portable,
                    &r,
                    View::Right { pad: nd + d_min },
                    Vec::new(),
                ),
            );
            for y in 0..s.h {
                let mut expected = vec![0; w * nd];
                costs(&s, cl.row(y), cr.row(y), &mut expected);
                let mut got = vec![0; w * nd];
                kernel(&s, cl.row(y), cr.row(y), &mut got);
                assert!(got == expected, "{name}, width {w}, {nd} d, row {y}");
                assert!(expected.iter().any(|&c| c > 0), "costs all zero");
            }
        }
    }

    /// The census costs of AVX2's nibble tables are the portable ones.
    #[test]
    #[cfg_attr(
        not(build_cpu_avx2_bmi),
        ignore = "needs AVX2 and BMI, which this machine lacks"
    )]
    #[allow(unsafe_code)]
    fn avx2_costs_are_the_portable_costs() {
        #[cfg(target_arch = "x86_64")]
        {
            assert!(
                crate::cpu::avx2_bmi(),
                "needs AVX2 and BMI: this CPU lacks them"
            );
            // SAFETY: the CPU has AVX2 and BMI (asserted above).
            check_cost_kernel("AVX2", |s, l, r, out| unsafe { costs_avx2(s, l, r, out) });
        }
        #[cfg(not(target_arch = "x86_64"))]
        panic!("no AVX2 kernel on this architecture");
    }

    /// The census costs of AVX-512's byte population count are the portable ones
    /// (whatever `STEREOTAC_NO_AVX512` says: it only keeps the pipeline off them).
    #[test]
    #[cfg_attr(
        not(build_cpu_avx512_popcnt),
        ignore = "needs AVX-512 BITALG, which this machine lacks"
    )]
    #[allow(unsafe_code)]
    fn avx512_costs_are_the_portable_costs() {
        #[cfg(target_arch = "x86_64")]
        {
            assert!(
                crate::cpu::has_avx512_popcnt(),
                "needs AVX-512 BITALG: this CPU lacks it"
            );
            // SAFETY: the CPU has AVX-512 F, BW, VL and BITALG (asserted above).
            check_cost_kernel("AVX-512", |s, l, r, out| unsafe {
                costs_avx512(s, l, r, out)
            });
        }
        #[cfg(not(target_arch = "x86_64"))]
        panic!("no AVX-512 kernel on this architecture");
    }

    #[test]
    fn the_sweeps_sum_each_path_as_defined() {
        let (l, r) = shifted_pair(75, 23, |x, y| 9.0 + 0.1 * x as f32 - 0.2 * y as f32);
        let cl = census(Kernel::Portable, &l, View::Left, Vec::new());
        let along_and_down = [(1, 0), (-1, 0), (0, 1)];
        let straight = [(1, 0), (-1, 0), (0, 1), (0, -1)];
        let from_above = [(1, 0), (-1, 0), (0, 1), (1, 1), (-1, 1)];
        let every = [
            (1, 0),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (-1, 1),
            (1, -1),
            (-1, -1),
        ];
        for (paths, directions) in [
            (Paths::Three, &along_and_down[..]),
            (Paths::Four, &straight[..]),
            (Paths::Five, &from_above[..]),
            (Paths::Eight, &every[..]),
        ] {
            // p2 = 103: the largest with byte lanes; 104 and 300: 16-bit lanes. 32
            // disparities: byte lanes with the AVX2 kernel take the pixels where no path
            // starts (byte_paths).
            let cases = [(8, 96, 16), (30, 103, 16), (8, 104, 16), (40, 300, 16)]
                .into_iter()
                .chain([(8, 96, 32), (30, 103, 32), (8, 104, 32)]);
            for (p1, p2, nd) in cases {
                let p = SgmParams {
                    min_disparity: 3,
                    num_disparities: nd,
                    paths,
                    p1,
                    p2,
                    ..SgmParams::default()
                };
                // Padding nd + d_min: every run of candidates inside.
                let pad = nd as usize + 3;
                let cr = census(Kernel::Portable, &r, View::Right { pad }, Vec::new());
                assert_eq!(fits_a_byte(&p), p2 <= 103);
                let expected = aggregated_by_definition(&cl, &cr, &p, directions);
                for kernel in [Kernel::Portable, Kernel::Avx2]
                    .into_iter()
                    .filter(|k| k.is_available())
                {
                    for side_by_side in [false, true] {
                        let got = aggregated_by_sweeps(kernel, &cl, &cr, &p, side_by_side);
                        let first_miss = got.iter().zip(&expected).position(|(a, b)| a != b);
                        assert_eq!(
                            first_miss, None,
                            "{paths:?} {kernel:?} p1 {p1} p2 {p2} {nd} d, side by side \
                             {side_by_side}"
                        );
                    }
                }
            }
        }
    }

    /// Selection packs candidates in 16 bits where every sum and index fit (3, 4 and 5
    /// paths at the default penalties and 64 disparities), or where the costs clamped
    /// at 1023 or 511 rarely decide (8 paths at 64, 5 at 128; a row where one does is
    /// selected again in 32 bits), and in 32 otherwise; all give the same disparities
    /// and counts, bit for bit, on sums up to the bound (ties included: sums drawn from
    /// a few values), from one sum volume or two, with each kernel.
    #[test]
    fn narrow_and_wide_packing_select_the_same() {
        let shape = |nd| Shape {
            w: 200,
            h: 1,
            nd,
            d_min: 2,
        };
        let at = |paths, nd: usize| SgmParams {
            paths,
            num_disparities: nd as u32,
            ..SgmParams::default()
        };
        assert_eq!(
            Packing::of(&shape(64), &at(Paths::Three, 64)),
            Packing::Narrow(6)
        );
        assert_eq!(
            Packing::of(&shape(64), &at(Paths::Five, 64)),
            Packing::Narrow(6)
        );
        // Clamped at 1023 and 511: a second selection where that decides.
        assert_eq!(
            Packing::of(&shape(64), &at(Paths::Eight, 64)),
            Packing::Narrow(6)
        );
        assert_eq!(
            Packing::of(&shape(128), &at(Paths::Five, 128)),
            Packing::Narrow(7)
        );
        assert_eq!(
            Packing::of(&shape(128), &at(Paths::Eight, 128)),
            Packing::Wide
        );
        // Not with 16-bit path costs (p2 over 103).
        let large_p2 = SgmParams {
            p2: 104,
            ..at(Paths::Eight, 64)
        };
        assert_eq!(Packing::of(&shape(64), &large_p2), Packing::Wide);
        assert_eq!(
            Packing::of(&shape(32), &at(Paths::Eight, 32)),
            Packing::Narrow(5)
        );
        let mut rng = crate::rng::Rng::new(11);
        let narrow = [
            (Paths::Three, 64),
            (Paths::Four, 64),
            (Paths::Five, 64),
            (Paths::Three, 48),
            (Paths::Eight, 32),
            (Paths::Eight, 64),
            (Paths::Five, 128),
        ];
        for (paths, nd) in narrow {
            let (s, p) = (shape(nd), at(paths, nd));
            let Packing::Narrow(shift) = Packing::of(&s, &p) else {
                panic!("{paths:?} {nd}: narrow expected");
            };
            let largest = paths.count() as u16 * (u16::from(CENSUS_BITS) + p.p2);
            let clamped = largest > u16::MAX >> shift;
            let mut draw = |n: u64| (rng.next_u64() % n) as u16;
            let mut valid = 0;
            let mut again = 0;
            for round in 0..50 {
                // Each pixel: a clear minimum at a random candidate over costs from the
                // top half; in odd rounds the costs take few values (ties), and every
                // fourth pixel's minimum is tied with another candidate. Where the
                // packing clamps, every tenth round has one pixel whose least cost is
                // clamped.
                let mut sum = vec![0u16; s.w * nd];
                for cell in sum.chunks_exact_mut(nd) {
                    for c in cell.iter_mut() {
                        *c = if round % 2 == 1 {
                            largest - 50 * draw(4)
                        } else {
                            largest / 2 + draw(u64::from(largest / 2) + 1)
                        };
                    }
                    let k = usize::from(draw(nd as u64));
                    cell[k] = draw(u64::from(largest / 4));
                    if draw(4) == 0 {
                        cell[usize::from(draw(nd as u64))] = cell[k];
                    }
                }
                if clamped && round % 10 == 0 {
                    let x = s.w - 1 - usize::from(draw(4));
                    sum[x * nd..][..nd].fill(largest - 1);
                }
                let mut narrow = vec![f32::NAN; s.w];
                let mut wide = vec![f32::NAN; s.w];
                if select::<u16>(&s, &p, &sum, None, &mut narrow, shift).is_none() {
                    again += 1;
                }
                let b = select::<u32>(&s, &p, &sum, None, &mut wide, 16).unwrap();
                // The sums whole, and split in two volumes (as two sweeps leave them).
                let first: Vec<u16> = sum.iter().map(|&v| v / 3).collect();
                let second: Vec<u16> = sum.iter().zip(&first).map(|(v, f)| v - f).collect();
                let kernels = [Kernel::Portable, Kernel::Avx2];
                for kernel in kernels.into_iter().filter(|k| k.is_available()) {
                    for split in [false, true] {
                        narrow.fill(f32::NAN);
                        let a = if split {
                            run_select(kernel, &s, &p, &first, Some(&second), &mut narrow)
                        } else {
                            run_select(kernel, &s, &p, &sum, None, &mut narrow)
                        };
                        let case = format!("{paths:?} {nd} round {round} {kernel:?} {split}");
                        assert_eq!(a, b, "{case}");
                        let same = narrow
                            .iter()
                            .zip(&wide)
                            .all(|(x, y)| x.to_bits() == y.to_bits());
                        assert!(same, "{case}");
                    }
                }
                valid += narrow.iter().filter(|v| v.is_finite()).count();
            }
            // The comparison covers chosen disparities, not only refusals, and the
            // second selection where the packing clamps (not only there).
            assert!(valid > 50 * (s.w - nd) / 4, "{paths:?} {nd}: {valid}");
            if clamped {
                assert!((5..50).contains(&again), "{paths:?} {nd}: {again} again");
            } else {
                assert_eq!(again, 0, "{paths:?} {nd}");
            }
        }
    }

    /// Byte lanes at their bound (p2 = 103): previous path costs at the largest a path
    /// can hold (`CENSUS_BITS + p2`) or 0, census costs 0 or the largest, next to the
    /// padding; every step equals the 16-bit one.
    #[test]
    fn byte_lanes_at_their_bound_equal_16_bit_lanes() {
        let p = SgmParams {
            p1: 30,
            p2: 103,
            ..SgmParams::default()
        };
        assert!(fits_a_byte(&p));
        let high = u16::from(CENSUS_BITS) + p.p2;
        let nd = 16;
        let mut rng = crate::rng::Rng::new(5);
        for round in 0..200 {
            let mut prev16 = vec![<u16 as Lane>::PAD; nd + 2];
            let mut prev8 = vec![<u8 as Lane>::PAD; nd + 2];
            for k in 0..nd {
                let v = if rng.uniform() < 0.5 { high } else { 0 };
                prev16[k + 1] = v;
                prev8[k + 1] = v as u8;
            }
            // A previous minimum as a step leaves it: the least of the values.
            let min16 = prev16[1..=nd].iter().copied().min().unwrap();
            let cost: Vec<u8> = (0..nd)
                .map(|_| if rng.uniform() < 0.5 { CENSUS_BITS } else { 0 })
                .collect();
            let (mut out16, mut out8) = (vec![0u16; nd], vec![0u8; nd]);
            let (mut sum16, mut sum8) = (vec![round; nd], vec![round; nd]);
            let least16 = step::<u16, false>(
                &cost,
                &prev16,
                min16,
                Penalties::of(&p),
                &mut out16,
                &mut sum16,
            );
            let least8 = step::<u8, false>(
                &cost,
                &prev8,
                min16 as u8,
                Penalties::of(&p),
                &mut out8,
                &mut sum8,
            );
            assert_eq!(u16::from(least8), least16);
            assert!(out16.iter().zip(&out8).all(|(&a, &b)| a == u16::from(b)));
            assert_eq!(sum16, sum8);
            assert!(out16.iter().all(|&v| v <= high));
        }
    }

    /// Whether a frame fits does not depend on the thread count: side by side only
    /// where its two volumes fit too.
    #[test]
    fn the_schedule_fits_whatever_the_threads() {
        let fits = |s: Schedule| s.bytes >> 20 <= MAX_VOLUME_MIB;
        for paths in Paths::ALL {
            for (w, h, nd) in [
                (640, 480, 64),
                (4096, 2000, 64),
                (4096, 3000, 256),
                (8192, 100, 1024),
                (100_000, 10, 1024),
            ] {
                let one = Schedule::choose(paths, 1, w, h, nd);
                let two = Schedule::choose(paths, 2, w, h, nd);
                assert_eq!(fits(one), fits(two), "{paths:?} {w}x{h}x{nd}");
                assert!(one.sum_volumes <= 1 && two.sum_volumes <= 2);
            }
        }
        // 4096×2000×64: 524 M cells; three bytes a cell fit in 2 GiB, five do not.
        let big = Schedule::choose(Paths::Eight, 2, 4096, 2000, 64);
        assert_eq!(big.sum_volumes, 1);
        assert!(fits(big));
        assert_eq!(
            Schedule::choose(Paths::Eight, 2, 640, 480, 64).sum_volumes,
            2
        );
        assert_eq!(
            Schedule::choose(Paths::Five, 2, 640, 480, 64).sum_volumes,
            0
        );
    }

    /// One thread (the second sweep matches each row as it goes) and two (the sweeps
    /// side by side, then every row) give the same disparities, bit for bit.
    #[test]
    fn one_thread_and_two_threads_give_the_same_disparities() {
        let (l, r) = shifted_pair(180, 50, |x, y| 20.0 + 0.05 * x as f32 + 0.1 * y as f32);
        let pool = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        };
        let (one, two) = (pool(1), pool(2));
        for paths in Paths::ALL {
            let m = matcher(paths, Kernel::best());
            let a = one.install(|| m.compute(&l, &r).unwrap());
            let b = two.install(|| m.compute(&l, &r).unwrap());
            assert!(a.stats.valid > 180 * 50 / 2, "{paths:?}: {}", a.stats.valid);
            let same = a
                .disparity
                .as_slice()
                .iter()
                .zip(b.disparity.as_slice())
                .all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(same, "{paths:?}");
            assert_eq!(a.stats.not_unique, b.stats.not_unique, "{paths:?}");
            assert_eq!(a.stats.left_right, b.stats.left_right, "{paths:?}");
        }
    }

    #[test]
    fn a_slanted_surface_has_sub_pixel_disparity() {
        // The right view's column xr shows the scene 20 + 0.05·xr px further on, so left
        // column x has disparity D = (20 + 0.05·x) / 1.05: sub-pixel steps everywhere.
        let (l, r) = shifted_pair(200, 60, |x, _| 20.0 + x as f32 * 0.05);
        let truth = |x: usize| (20.0 + x as f32 * 0.05) / 1.05;
        let m = matcher(Paths::Eight, Kernel::best())
            .compute(&l, &r)
            .unwrap();
        let mut errors = Vec::new();
        for y in 5..55 {
            for x in 70..195 {
                let v = m.disparity.get(x, y);
                if v.is_finite() {
                    errors.push((v - truth(x)).abs());
                }
            }
        }
        assert!(errors.len() > 50 * 110, "{} valid", errors.len());
        let rms = (errors.iter().map(|e| e * e).sum::<f32>() / errors.len() as f32).sqrt();
        let mut sorted = errors.clone();
        sorted.sort_by(f32::total_cmp);
        let q = |f: f64| sorted[((sorted.len() - 1) as f64 * f) as usize];
        // A stretched view resampled by linear interpolation of noise-like texture: the
        // views differ beyond a shift, so no exact answer; whole pixels would give 0.29.
        // The refinement whose window shared the centre's estimate read RMS 0.130, median
        // 0.059, p99 0.42 here; the one with each pixel at its own estimate 0.103, 0.092
        // and 0.19: fewer large errors, a wider middle.
        assert!(
            rms < 0.12 && q(0.5) < 0.10 && q(0.99) < 0.25,
            "RMS {rms} px, median {} p90 {} p99 {} max {}",
            q(0.5),
            q(0.9),
            q(0.99),
            q(1.0)
        );
        assert!(errors.iter().all(|&e| e < 1.0), "a pixel over 1 px off");
    }

    #[test]
    fn through_the_skin_it_finds_at_least_what_block_matching_finds() {
        let rig = StereoRig::sensor();
        let plane = Plane {
            z_mm: 120.0,
            tilt_x: 0.3,
            tilt_y: 0.1,
        };
        let (l, r) = render_pair(&rig, &plane, &Membrane::sensor(), 1);
        let truth = rig.true_disparity(&plane);
        let score = |d: &Grid<f32>| {
            let (mut good, mut bad) = (0usize, 0usize);
            for (v, t) in d.as_slice().iter().zip(truth.as_slice()) {
                if v.is_finite() && t.is_finite() {
                    if (v - t).abs() > 1.0 {
                        bad += 1
                    } else {
                        good += 1
                    }
                }
            }
            (good, bad)
        };
        let sgm = matcher(Paths::Eight, Kernel::best())
            .compute(&l, &r)
            .unwrap();
        let bm = BlockMatcher::new(BlockMatchParams::default())
            .unwrap()
            .compute(&l, &r)
            .unwrap();
        let (sg, sb) = score(&sgm.disparity);
        let (bg, bb) = score(&bm.disparity);
        assert!(sg >= bg, "SGM {sg} good against BM {bg}");
        assert!(sb * 1000 <= sg, "SGM: {sb} bad of {}", sg + sb);
        let _ = bb;
    }

    /// The refinement window is the one asked for: on a noisy slanted surface a 15×15
    /// window leaves less error than 9×9, and 3×3 more.
    #[test]
    fn a_larger_refinement_window_averages_more_noise() {
        let truth = |x: usize, y: usize| 18.0 + 0.011 * x as f32 + 0.007 * y as f32;
        let (l, r) = shifted_pair(180, 60, truth);
        let mut rng = crate::rng::Rng::new(21);
        let mut noisy = |g: &Grid<u8>| {
            Grid::from_fn(g.width(), g.height(), |x, y| {
                let n = (rng.uniform() - 0.5) * 12.0;
                (f64::from(g.get(x, y)) + n).round().clamp(0.0, 255.0) as u8
            })
        };
        let (l, r) = (noisy(&l), noisy(&r));
        let rms = |side: u32| {
            let m = SemiGlobalMatcher::new(SgmParams {
                paths: Paths::Three,
                refine_window: side,
                ..SgmParams::default()
            })
            .unwrap();
            let d = m.compute(&l, &r).unwrap().disparity;
            let (mut sum, mut n) = (0.0f64, 0);
            for y in 10..50 {
                for x in 90..170 {
                    let e = d.get(x, y) - truth(x, y);
                    if e.is_finite() {
                        sum += f64::from(e * e);
                        n += 1;
                    }
                }
            }
            assert!(n > 2500, "{side}×{side}: {n} pixels");
            (sum / f64::from(n)).sqrt()
        };
        let (small, middle, large) = (rms(3), rms(9), rms(15));
        assert!(
            small > middle && middle > large,
            "RMS (px) 3×3 {small:.4}, 9×9 {middle:.4}, 15×15 {large:.4}"
        );
    }

    #[test]
    fn odd_sizes_and_parameters_are_handled() {
        for paths in Paths::ALL {
            let m = matcher(paths, Kernel::best());
            for (w, h) in [(0, 0), (1, 1), (70, 7), (64, 100), (71, 6)] {
                let g = Grid::filled(w, h, 9u8);
                let d = m.compute(&g, &g).unwrap();
                assert_eq!(
                    d.stats.valid
                        + d.stats.border
                        + d.stats.not_unique
                        + d.stats.range_edge
                        + d.stats.left_right
                        + d.stats.speckle,
                    w * h,
                    "{paths:?} {w}x{h}"
                );
            }
        }
        let m = SemiGlobalMatcher::new(SgmParams::default()).unwrap();
        // A flat grey pair: nothing is unique, nothing is claimed.
        let g = Grid::filled(200, 40, 128u8);
        assert_eq!(m.compute(&g, &g).unwrap().stats.valid, 0);
        assert!(matches!(
            m.compute(&Grid::filled(10, 10, 0u8), &Grid::filled(11, 10, 0u8)),
            Err(MatchError::SizeMismatch { .. })
        ));
        for bad in [
            SgmParams {
                num_disparities: 0,
                ..SgmParams::default()
            },
            SgmParams {
                num_disparities: 40,
                ..SgmParams::default()
            },
            SgmParams {
                p1: 10,
                p2: 10,
                ..SgmParams::default()
            },
            SgmParams {
                uniqueness_ratio: 100,
                ..SgmParams::default()
            },
            SgmParams {
                speckle_range: f32::NAN,
                ..SgmParams::default()
            },
            SgmParams {
                min_disparity: 4090,
                ..SgmParams::default()
            },
            SgmParams {
                min_disparity: u32::MAX - 10,
                ..SgmParams::default()
            },
            SgmParams {
                refine_window: 8,
                ..SgmParams::default()
            },
            SgmParams {
                refine_window: 1,
                ..SgmParams::default()
            },
            SgmParams {
                refine_window: 33,
                ..SgmParams::default()
            },
        ] {
            assert!(matches!(
                SemiGlobalMatcher::new(bad),
                Err(MatchError::InvalidParam { .. })
            ));
        }
        let huge = SemiGlobalMatcher::new(SgmParams {
            num_disparities: 1024,
            ..SgmParams::default()
        })
        .unwrap();
        let big = Grid::filled(8192, 100, 0u8);
        assert!(matches!(
            huge.compute(&big, &big),
            Err(MatchError::TooLarge { .. })
        ));
    }
}
