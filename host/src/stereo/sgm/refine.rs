//! Sub-pixel refinement of semi-global matching's disparities on the images themselves:
//! a least-squares (Lucas–Kanade) step along the row per pixel, from box sums of
//! per-pixel integer terms slid exactly over the frame. Aggregated census costs place
//! the minimum only to about 0.15 px; this brings it to the images' own precision.

use rayon::prelude::*;

use crate::grid::Grid;
use crate::stereo::block_match::Kernel;

/// How far [`refine`] may take a pixel from the nearest whole pixel of its
/// aggregated-cost estimate, px: that whole pixel or its neighbour, to the half-way
/// point beyond. The aggregated costs pick a neighbouring whole pixel now and then
/// (behind the hazy skin at 300 mm, about one pixel in 200 settles more than 0.75 px
/// from its start); a bound of 0.75 px kept those pixels at their start, and they made
/// most of the unfiltered RMS error above classic Lucas–Kanade's (`stereo-eval`,
/// 9×9, 300 mm: 0.431 % with 0.75 px, 0.327 % with 1.5 px, 0.322 % classic).
const MAX_CORRECTION_PX: f32 = 1.5;

/// Gauss–Newton steps of [`refine`].
const REFINE_STEPS: usize = 2;

/// One pixel's least-squares terms for [`refine`], linearised at its own estimate `d`:
/// the right view is read at `x − d` by linear interpolation between its two whole
/// pixels there, `R[i]` and `R[i + 1]` with `i = x − ⌈d⌉`, and `g = R[i + 1] − R[i]` is
/// that interpolant's slope, so the linearisation is exact while the estimate stays
/// between them. With `e = L(x) − R(x − d)`, the window's shift `D` that minimises
/// `Σ (e + (D − d)·g)²` is `Σ (g²·d − g·e) / Σ g²`, and `g²·d − g·e` is the integer
/// `g²·⌈d⌉ − g·(L(x) − R[i])`: the `moment`. A window also tells how far its pixels'
/// estimates spread about its centre's ([`RefineTerm::solve`]) from `g²·q` and `g²·q²`
/// for the estimate in sixteenths of a pixel (`q = round(16·d)`), made from `g` and
/// `g·q` (both fit 32 bits; their products are 32×32→64-bit multiplies).
/// Integers, so window sums slide exactly and in any order.
#[derive(Clone, Copy, Default, PartialEq, Debug)]
struct RefineTerm {
    g: i32,
    moment: i32,
    q: i32,
}

/// Window sums of `g²`, the moment, `g²·q` and `g²·q²` ([`ColumnSums`]).
type RefineSums = [i64; 4];

/// Largest g²-weighted mean square by which a window's estimates may differ from its
/// centre's for [`refine`] to take the step, in sixteenths of a pixel squared: 1 px².
const MAX_SPREAD_SQ: i64 = 256;

/// An estimate in sixteenths of a pixel, as [`RefineTerm`]'s spread terms take it.
#[inline(always)]
fn sixteenths(d: f32) -> i64 {
    (d * 16.0).round() as i64
}

impl RefineTerm {
    /// Where left column `x` at disparity `d` reads a row of `w` right-view pixels:
    /// `(i, ⌈d⌉)` with `i = x − ⌈d⌉` (it reads `i` and `i + 1`), or `None` when `d` is
    /// not finite or a read is off the row.
    #[inline(always)]
    fn reads(x: usize, d: f32, w: usize) -> Option<(usize, i32)> {
        let b = d.ceil();
        let i = x as f32 - b;
        // Matched disparities are below 4096 and a step stays within 1.5 px of one, so
        // the bound on `b` only guards the 31 bits (255²·8192 + 255² < 2³¹).
        (i >= 0.0 && i + 1.0 < w as f32 && b.abs() <= 8192.0).then_some((i as usize, b as i32))
    }

    /// The terms of left column `x` (row `left`) at disparity `d`, or `None` where it
    /// reads no right-view pixels ([`RefineTerm::reads`]).
    #[inline(always)]
    fn of(left: &[u8], right: &[u8], x: usize, d: f32) -> Option<Self> {
        let (i, b) = Self::reads(x, d, right.len())?;
        let (r0, r1) = (i32::from(right[i]), i32::from(right[i + 1]));
        let g = r1 - r0;
        // |16·d| <= 131088 (the bound on ⌈d⌉ in `reads`): q and g·q fit i32
        // (255·131088 < 2²⁵), g²·q² fits i64 with room for a 31×31 window's 961 of them
        // (and the spread of `solve`, about 3·10¹⁸ at most).
        Some(Self {
            g,
            moment: g * g * b - g * (i32::from(left[x]) - r0),
            q: sixteenths(d) as i32,
        })
    }

    /// The step's disparity from a window's sums, for a centre whose estimate is
    /// `centre` sixteenths of a pixel; `None` without gradient (`Σ g² ≤ 1`), or where
    /// the window's estimates spread about the centre's by more than [`MAX_SPREAD_SQ`]
    /// (g²-weighted mean square): at a depth edge the step would pull the centre toward
    /// the other surface, each pixel lending its own answer.
    #[inline(always)]
    fn solve(sums: RefineSums, centre: i64) -> Option<f32> {
        let [weight, moment, shift, square] = sums;
        let spread = square - 2 * centre * shift + centre * centre * weight;
        (weight > 1 && spread <= MAX_SPREAD_SQ * weight)
            .then(|| (moment as f64 / weight as f64) as f32)
    }
}

/// Least-squares sub-pixel refinement (Lucas–Kanade along the row, a square window of
/// side `2·radius + 1` (at least 3; [`super::SgmParams::refine_window`]), two
/// Gauss–Newton steps from the aggregated-cost estimate). `L(x) ≈ R(x − D)`: each step
/// expands every pixel's `R(x − D)` around that pixel's own current estimate
/// ([`RefineTerm`]), so a window's update is a ratio of two box sums of per-pixel
/// integer terms, slid down the columns and along the rows (rows in bands of
/// [`band_rows`] taken in order, bands in parallel; each band makes the terms of its
/// window's rows as it slides and keeps them in a ring, about 23 kB a row of 640 for a
/// 9×9 window, 28 kB for 11×11: they stay in the cache instead of making a frame-sized
/// plane; the times below are for 9×9).
/// Where every pixel of a window has the same estimate this is the classic Lucas–Kanade step with
/// the interpolant's slope. The previous refinement read each window at its centre's
/// estimate, so every pixel needed window sums of its own; these terms are shared
/// (640×480, 64 disparities, one core: 17.5 → about 7 ms; with the terms kept in a
/// ring per band and made eight pixels at a time, about 5). The slope is the
/// interpolant's own, so a step is exact while the estimates stay between the same two
/// whole pixels and the steps settle (a third changes nothing on `stereo-eval`); the
/// central difference read between pixels, used before, made the steps swing about the
/// answer.
///
/// Pixels without a disparity, or whose reads would leave the image, add nothing to the
/// windows around them. A step is kept only when the centre's own reads are inside the
/// image, the window has gradient (`Σ g² > 1`), its estimates spread about the
/// centre's by at most 1 px² (g²-weighted mean square: at a depth edge each pixel
/// would lend its own surface's answer, so a share `f` of the window across a step `Δ`
/// pulls by `f·Δ` and spreads by `f·Δ²`; the pull kept is at most `1 / Δ`; a tighter
/// bound left more noisy pixels unrefined: 0.5 px² took the unfiltered RMS error of
/// `stereo-eval` at 200 mm from 0.24 to 0.48 %), and the
/// result stays within [`MAX_CORRECTION_PX`] (1.5 px) of the nearest whole pixel of
/// the starting estimate;
/// otherwise the pixel keeps that estimate and takes no further steps (it still lends
/// its terms, at that estimate, to its neighbours). Only pixels whose whole window lies
/// in the image are refined. The sums are exact, so results do not depend on the
/// thread count.
pub(super) fn refine(
    kernel: Kernel,
    (left, right): (&Grid<u8>, &Grid<u8>),
    radius: usize,
    disparity: &mut Grid<f32>,
    planes: &mut RefinePlanes,
) {
    let (w, h, r) = (left.width(), left.height(), radius);
    // Radius 0 would be a window of one pixel: the parameters refuse it.
    if r == 0 || h < 2 * r + 1 || w < 2 * r + 4 {
        return;
    }
    let RefinePlanes {
        start,
        before,
        live,
    } = planes;
    start.clear();
    start.extend_from_slice(disparity.as_slice());
    // Pixels still taking steps: 1; those that stopped keep their starting estimate.
    live.clear();
    live.resize(w * h, 1);
    let band = band_rows(h, rayon::current_num_threads());
    for _ in 0..REFINE_STEPS {
        // Every window reads its pixels' terms at the previous step's estimates.
        before.clear();
        before.extend_from_slice(disparity.as_slice());
        let step = Step {
            left,
            right,
            before,
            start,
            radius: r,
        };
        disparity
            .as_mut_slice()
            .par_chunks_mut(w * band)
            .zip(live.par_chunks_mut(w * band))
            .enumerate()
            .for_each(|(i, (rows, live))| run_refine_band(kernel, &step, i * band, rows, live));
    }
}

/// The planes [`refine`] works in, kept between frames.
#[derive(Default)]
pub(super) struct RefinePlanes {
    /// The aggregated-cost estimates.
    start: Vec<f32>,
    /// The estimates before the current step.
    before: Vec<f32>,
    /// Which pixels still take steps.
    live: Vec<u8>,
}

/// What one step of [`refine`] reads: the images, the estimates before the step and
/// the starting estimates (frames of the images' size, row-major).
struct Step<'a> {
    left: &'a Grid<u8>,
    right: &'a Grid<u8>,
    before: &'a [f32],
    start: &'a [f32],
    /// The window's radius: its side is `2·radius + 1`.
    radius: usize,
}

impl Step<'_> {
    fn width(&self) -> usize {
        self.left.width()
    }

    fn height(&self) -> usize {
        self.left.height()
    }

    fn before_row(&self, y: usize) -> &[f32] {
        let w = self.width();
        &self.before[y * w..][..w]
    }

    fn start_row(&self, y: usize) -> &[f32] {
        let w = self.width();
        &self.start[y * w..][..w]
    }
}

/// The fewest rows of a band ([`band_rows`]): a band's rows are taken in order on one
/// thread, so the window's column sums slide down from the row above; bands run in
/// parallel. Each band makes the terms of the `radius` rows above its first and below
/// its last once more (an eighth more terms for bands of 64 rows and a 9×9 window).
const REFINE_BAND: usize = 64;

/// Rows a band takes: two bands a thread (some room to even out the threads' loads),
/// at least [`REFINE_BAND`]. Fewer bands make fewer rows' terms twice: on one thread at
/// 640×480, two bands instead of eight.
fn band_rows(h: usize, threads: usize) -> usize {
    h.div_ceil(2 * threads.max(1)).max(REFINE_BAND)
}

/// One row's [`RefineTerm`]s as planes: `g`, the moment and `g·q` (zero where a pixel
/// has no terms).
#[derive(Clone)]
struct TermRow {
    g: Vec<i32>,
    moment: Vec<i32>,
    gq: Vec<i32>,
}

impl TermRow {
    fn new(w: usize) -> Self {
        Self {
            g: vec![0; w],
            moment: vec![0; w],
            gq: vec![0; w],
        }
    }

    /// The terms of row `y` at the estimates before the step; with `avx2` eight pixels
    /// at a time where the CPU has AVX2 (checked here too: a cached flag), the same
    /// terms.
    #[inline(always)]
    fn fill(&mut self, step: &Step<'_>, y: usize, avx2: bool) {
        let (left, right) = (step.left.row(y), step.right.row(y));
        let d = step.before_row(y);
        let w = d.len();
        let mut x = 0;
        #[cfg(target_arch = "x86_64")]
        if avx2 && crate::cpu::avx2() {
            // SAFETY: AVX2 was detected just above.
            #[allow(unsafe_code)]
            unsafe {
                x = self.fill_avx2(left, right, d)
            };
        }
        let _ = avx2;
        let (g, moment, gq) = (&mut self.g[..w], &mut self.moment[..w], &mut self.gq[..w]);
        for x in x..w {
            let t = RefineTerm::of(left, right, x, d[x]).unwrap_or_default();
            g[x] = t.g;
            moment[x] = t.moment;
            gq[x] = t.g * t.q;
        }
    }

    /// [`TermRow::fill`] for the columns up to the last whole eight that read two bytes
    /// short of the right row's end, eight at a time; returns the first column left to
    /// do. Each lane does what [`RefineTerm::of`] does: the same roundings
    /// (`round` half away from zero as `trunc(m) + trunc(2·(m − trunc(m)))`, exact),
    /// the same tests (ordered comparisons, false for NaN), and its two right-view
    /// bytes from one gathered 32-bit word (lanes without terms read column 0 and are
    /// zeroed).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    fn fill_avx2(&mut self, left: &[u8], right: &[u8], d: &[f32]) -> usize {
        use std::arch::x86_64::*;
        let w = d.len();
        assert!(left.len() >= w && right.len() == w && self.g.len() >= w);
        assert!(self.moment.len() >= w && self.gq.len() >= w && w < 1 << 24);
        let lanes = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let (zero, one, sixteen, two) = (
            _mm256_setzero_ps(),
            _mm256_set1_ps(1.0),
            _mm256_set1_ps(16.0),
            _mm256_set1_ps(2.0),
        );
        let width = _mm256_set1_ps(w as f32);
        let bound = _mm256_set1_ps(8192.0);
        let magnitude = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
        let byte = _mm256_set1_epi32(0xff);
        const UP: i32 = _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC;
        const TRUNC: i32 = _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC;
        let mut x = 0;
        while x + 8 <= w {
            // SAFETY: x + 8 <= w bounds every load and store below; gathered words are
            // tested to end inside the row.
            unsafe {
                let dv = _mm256_loadu_ps(d.as_ptr().add(x));
                let b = _mm256_round_ps::<UP>(dv);
                let i = _mm256_sub_ps(_mm256_add_ps(_mm256_set1_ps(x as f32), lanes), b);
                let inside = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(i, zero),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_add_ps(i, one), width),
                );
                let ok = _mm256_and_ps(
                    inside,
                    _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_and_ps(b, magnitude), bound),
                );
                let ok = _mm256_castps_si256(ok);
                let ii = _mm256_and_si256(_mm256_cvttps_epi32(i), ok);
                // Two bytes past a read at w − 2 would leave the row: such lanes wait
                // for the scalar loop.
                let last = _mm256_set1_epi32(w as i32 - 4);
                if _mm256_movemask_epi8(_mm256_cmpgt_epi32(ii, last)) != 0 {
                    break;
                }
                let word = _mm256_i32gather_epi32::<1>(right.as_ptr().cast::<i32>(), ii);
                let r0 = _mm256_and_si256(word, byte);
                let r1 = _mm256_and_si256(_mm256_srli_epi32::<8>(word), byte);
                let l = _mm256_cvtepu8_epi32(_mm_loadl_epi64(left.as_ptr().add(x).cast()));
                let g = _mm256_sub_epi32(r1, r0);
                let bi = _mm256_cvttps_epi32(b);
                let moment = _mm256_sub_epi32(
                    _mm256_mullo_epi32(_mm256_mullo_epi32(g, g), bi),
                    _mm256_mullo_epi32(g, _mm256_sub_epi32(l, r0)),
                );
                let m = _mm256_mul_ps(dv, sixteen);
                let t = _mm256_round_ps::<TRUNC>(m);
                let half = _mm256_round_ps::<TRUNC>(_mm256_mul_ps(_mm256_sub_ps(m, t), two));
                let q = _mm256_cvttps_epi32(_mm256_add_ps(t, half));
                let g = _mm256_and_si256(g, ok);
                let gq = _mm256_mullo_epi32(g, q);
                let moment = _mm256_and_si256(moment, ok);
                _mm256_storeu_si256(self.g.as_mut_ptr().add(x).cast(), g);
                _mm256_storeu_si256(self.moment.as_mut_ptr().add(x).cast(), moment);
                _mm256_storeu_si256(self.gq.as_mut_ptr().add(x).cast(), gq);
            }
            x += 8;
        }
        x
    }
}

/// The window sums of every column over the `n = 2·radius + 1` rows around row `row`
/// (`usize::MAX` before the first), and those rows' terms in a ring (row `r` in slot
/// `r % n`), so sliding down a row replaces the slot of the row that leaves with the row
/// that enters.
struct Window {
    row: usize,
    /// AVX2 was detected: [`TermRow::fill`] takes eight pixels at a time.
    avx2: bool,
    slots: Vec<TermRow>,
    entering: TermRow,
    columns: ColumnSums,
}

/// Each column's sums of `g²`, the moment, `g²·q` and `g²·q²` over a window's rows, as
/// planes.
struct ColumnSums {
    weight: Vec<i64>,
    moment: Vec<i64>,
    shift: Vec<i64>,
    square: Vec<i64>,
}

impl Window {
    fn new(w: usize, radius: usize, avx2: bool) -> Self {
        Self {
            row: usize::MAX,
            avx2,
            slots: vec![TermRow::new(w); 2 * radius + 1],
            entering: TermRow::new(w),
            columns: ColumnSums {
                weight: vec![0; w],
                moment: vec![0; w],
                shift: vec![0; w],
                square: vec![0; w],
            },
        }
    }

    /// The sums for the window around row `y`: slid down a row from the window around
    /// `y − 1`, else summed afresh.
    #[inline(always)]
    fn slide_to(&mut self, step: &Step<'_>, y: usize) {
        let (r, n) = (step.radius, self.slots.len());
        if self.row.wrapping_add(1) == y {
            let slot = &mut self.slots[(y + r) % n];
            self.entering.fill(step, y + r, self.avx2);
            self.columns.slide(&self.entering, Some(slot));
            std::mem::swap(slot, &mut self.entering);
        } else {
            let c = &mut self.columns;
            for s in [&mut c.weight, &mut c.moment, &mut c.shift, &mut c.square] {
                s.fill(0);
            }
            for row in y - r..=y + r {
                let slot = &mut self.slots[row % n];
                slot.fill(step, row, self.avx2);
                self.columns.slide(slot, None);
            }
        }
        self.row = y;
    }
}

impl ColumnSums {
    /// Adds the row of terms that enters and takes away the one that leaves, if any.
    #[inline(always)]
    fn slide(&mut self, entering: &TermRow, leaving: Option<&TermRow>) {
        let w = self.weight.len();
        let (g, m, gq) = (&entering.g[..w], &entering.moment[..w], &entering.gq[..w]);
        let (sw, sm) = (&mut self.weight[..w], &mut self.moment[..w]);
        let (ss, sq) = (&mut self.shift[..w], &mut self.square[..w]);
        for x in 0..w {
            let (g, gq) = (i64::from(g[x]), i64::from(gq[x]));
            sw[x] += g * g;
            sm[x] += i64::from(m[x]);
            ss[x] += g * gq;
            sq[x] += gq * gq;
        }
        let Some(leaving) = leaving else {
            return;
        };
        let (g, m, gq) = (&leaving.g[..w], &leaving.moment[..w], &leaving.gq[..w]);
        for x in 0..w {
            let (g, gq) = (i64::from(g[x]), i64::from(gq[x]));
            sw[x] -= g * g;
            sm[x] -= i64::from(m[x]);
            ss[x] -= g * gq;
            sq[x] -= gq * gq;
        }
    }
}

#[allow(unsafe_code)]
fn run_refine_band(
    kernel: Kernel,
    step: &Step<'_>,
    first: usize,
    rows: &mut [f32],
    live: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { refine_band_avx2(step, first, rows, live) };
    }
    let _ = kernel;
    refine_band(step, first, rows, live, false)
}

/// With AVX2 the terms take eight pixels an instruction, the window sums four columns,
/// and the roundings are instructions instead of calls; the same results.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn refine_band_avx2(step: &Step<'_>, first: usize, rows: &mut [f32], live: &mut [u8]) {
    refine_band(step, first, rows, live, true)
}

/// One step of [`refine`] for the rows of a band starting at row `first` (`rows`: their
/// estimates, `live`: which still take steps); `avx2` only where it was detected.
#[inline(always)]
fn refine_band(step: &Step<'_>, first: usize, rows: &mut [f32], live: &mut [u8], avx2: bool) {
    let (w, h, r) = (step.width(), step.height(), step.radius);
    let mut window = Window::new(w, r, avx2);
    let rows = rows.chunks_exact_mut(w).zip(live.chunks_exact_mut(w));
    for (j, (row, live)) in rows.enumerate() {
        let y = first + j;
        if y < r || y + r >= h {
            continue;
        }
        window.slide_to(step, y);
        refine_row(&window.columns, r, step.start_row(y), row, live);
    }
}

/// One Gauss–Newton step of [`refine`] for a row (`row`: its estimates before the
/// step, `live`: which still take steps, `start`: the starting estimates), its window
/// sums (radius `r`) slid along the row from the window's column sums. The right row is as wide as
/// `row`, so whether the centre's own reads are inside it needs only the width.
#[inline(always)]
fn refine_row(c: &ColumnSums, r: usize, start: &[f32], row: &mut [f32], live: &mut [u8]) {
    let w = row.len();
    let columns = [&c.weight, &c.moment, &c.shift, &c.square].map(|c| &c[..w]);
    let column = |x: usize| columns.map(|c| c[x]);
    let mut sums: RefineSums = [0; 4];
    for x in 0..2 * r {
        for (s, c) in sums.iter_mut().zip(column(x)) {
            *s += c;
        }
    }
    for x in r..w - r {
        for (s, c) in sums.iter_mut().zip(column(x + r)) {
            *s += c;
        }
        if x > r {
            for (s, c) in sums.iter_mut().zip(column(x - r - 1)) {
                *s -= c;
            }
        }
        let v = row[x];
        if live[x] == 0 || !v.is_finite() {
            continue;
        }
        let reads = RefineTerm::reads(x, v, w).is_some();
        match RefineTerm::solve(sums, sixteenths(v)) {
            Some(next) if reads && (next - start[x].round()).abs() <= MAX_CORRECTION_PX => {
                row[x] = next
            }
            _ => {
                row[x] = start[x];
                live[x] = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::sgm::tests::shifted_pair;

    /// The tests' window radius (9×9; semi-global matching's default is 11×11, and
    /// the window side is a parameter the sums do not depend on otherwise).
    const REFINE_RADIUS: usize = 4;

    /// The definition of [`refine`]: every window's sums from all its pixels' terms at
    /// the previous step's estimates, no reuse.
    fn refine_by_definition(
        left: &Grid<u8>,
        right: &Grid<u8>,
        disparity: &mut Grid<f32>,
        radius: usize,
    ) {
        let r = radius;
        // A pixel's estimate in sixteenths (only read where it has terms).
        let q = |d: f32| {
            if d.is_finite() {
                (d * 16.0).round() as i64
            } else {
                0
            }
        };
        let (w, h) = (left.width(), left.height());
        let start = disparity.clone();
        let mut live = Grid::filled(w, h, true);
        for _ in 0..REFINE_STEPS {
            let before = disparity.clone();
            let term = |x: usize, y: usize| {
                RefineTerm::of(left.row(y), right.row(y), x, before.get(x, y)).unwrap_or_default()
            };
            for y in r..h.saturating_sub(r) {
                for x in r..w - r {
                    let v = before.get(x, y);
                    if !live.get(x, y) || !v.is_finite() {
                        continue;
                    }
                    let mut sums = [0i64; 4];
                    for yy in y - r..=y + r {
                        for xx in x - r..=x + r {
                            let t = term(xx, yy);
                            let weight = i64::from(t.g).pow(2);
                            sums[0] += weight;
                            sums[1] += i64::from(t.moment);
                            sums[2] += weight * q(before.get(xx, yy));
                            sums[3] += weight * q(before.get(xx, yy)).pow(2);
                        }
                    }
                    let reads = RefineTerm::of(left.row(y), right.row(y), x, v).is_some();
                    match RefineTerm::solve(sums, q(v)) {
                        Some(next)
                            if reads
                                && (next - start.get(x, y).round()).abs() <= MAX_CORRECTION_PX =>
                        {
                            disparity.set(x, y, next)
                        }
                        _ => {
                            disparity.set(x, y, start.get(x, y));
                            live.set(x, y, false);
                        }
                    }
                }
            }
        }
    }

    /// Window sums slid down the columns and along the rows (integers, so exact), bands
    /// of rows in parallel, give the definition's disparities bit for bit: on a surface
    /// whose disparity changes in both directions, with holes and whole-pixel jumps,
    /// across several row bands.
    #[test]
    fn refinement_with_slid_sums_is_the_definition() {
        let (w, h) = (200, 2 * REFINE_BAND + 11);
        let truth = |x: usize, y: usize| 20.0 + 0.013 * x as f32 + 0.05 * y as f32;
        let (l, r) = shifted_pair(w, h, truth);
        let mut rng = crate::rng::Rng::new(9);
        // Starting points as an aggregated-cost estimate gives: near the truth, with
        // whole-pixel jumps and holes.
        let start = Grid::from_fn(w, h, |x, y| match rng.uniform() {
            u if u < 0.05 => f32::NAN,
            u if u < 0.1 => truth(x, y).round() + 1.0,
            u => truth(x, y) + (u as f32 - 0.55) * 0.4,
        });
        // Planes kept from a larger frame, as a matcher keeps them between frames.
        let mut planes = RefinePlanes::default();
        let (bl, br) = shifted_pair(w + 30, h + 20, |_, _| 25.3);
        refine(
            Kernel::best(),
            (&bl, &br),
            REFINE_RADIUS,
            &mut Grid::filled(w + 30, h + 20, 25.0),
            &mut planes,
        );
        // The default window, the smallest, a larger one and the largest.
        for radius in [REFINE_RADIUS, 1, 7, 15] {
            let mut slow = start.clone();
            refine_by_definition(&l, &r, &mut slow, radius);
            for kernel in Kernel::tested() {
                let mut fast = start.clone();
                refine(kernel, (&l, &r), radius, &mut fast, &mut planes);
                let changed = fast
                    .as_slice()
                    .iter()
                    .zip(start.as_slice())
                    .filter(|(a, b)| a.to_bits() != b.to_bits())
                    .count();
                assert!(
                    changed > w * h / 3,
                    "{kernel:?}, radius {radius}: refinement moved only {changed} pixels"
                );
                for (i, (a, b)) in fast.as_slice().iter().zip(slow.as_slice()).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "{kernel:?}, radius {radius}, pixel ({}, {}): {a} vs {b}",
                        i % w,
                        i / w
                    );
                }
            }
        }
    }

    /// The eight-lane terms are the scalar terms, bit for bit: on holes, infinities,
    /// disparities off either end of the row and past the bound, estimates exactly
    /// halfway between sixteenths (rounded away from zero), and small disparities at
    /// the row's end (where the gather would leave the row and the scalar loop takes
    /// over).
    #[test]
    #[cfg_attr(
        not(build_cpu_avx2_bmi),
        ignore = "needs AVX2 and BMI, which this machine lacks"
    )]
    fn eight_lane_terms_are_the_scalar_terms() {
        assert!(
            Kernel::Avx2.is_available(),
            "needs AVX2 and BMI: this CPU lacks them"
        );
        let mut rng = crate::rng::Rng::new(11);
        for w in [8, 13, 61, 64, 203] {
            let left = Grid::from_fn(w, 1, |_, _| (rng.uniform() * 255.0) as u8);
            let right = Grid::from_fn(w, 1, |_, _| (rng.uniform() * 255.0) as u8);
            let special = [
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                -0.5,
                0.0,
                0.03125,
                -0.03125,
                1.96875,
                23.53125,
                8192.0,
                8192.5,
                -8192.0,
                1e9,
                w as f32,
                w as f32 - 1.5,
            ];
            let before: Vec<f32> = (0..w)
                .map(|x| match rng.uniform() {
                    u if u < 0.4 => special[x % special.len()],
                    u if u < 0.7 => (u as f32 - 0.4) * 4.0,
                    u => (u as f32 - 0.7) * 80.0,
                })
                .collect();
            let start = before.clone();
            let step = Step {
                left: &left,
                right: &right,
                before: &before,
                start: &start,
                radius: REFINE_RADIUS,
            };
            let (mut scalar, mut lanes) = (TermRow::new(w), TermRow::new(w));
            scalar.fill(&step, 0, false);
            lanes.fill(&step, 0, true);
            for (x, d) in before.iter().enumerate() {
                let (a, b) = (
                    (scalar.g[x], scalar.moment[x], scalar.gq[x]),
                    (lanes.g[x], lanes.moment[x], lanes.gq[x]),
                );
                assert_eq!(a, b, "width {w}, column {x}, estimate {d}");
            }
            assert!(scalar.g.iter().any(|&g| g != 0), "width {w}: no terms");
        }
    }

    /// `start` refined with the tests' window by every kernel this CPU has.
    fn refined_by_each_kernel(
        l: &Grid<u8>,
        r: &Grid<u8>,
        start: &Grid<f32>,
    ) -> Vec<(Kernel, Grid<f32>)> {
        Kernel::tested()
            .into_iter()
            .map(|kernel| {
                let mut d = start.clone();
                let planes = &mut RefinePlanes::default();
                refine(kernel, (l, r), REFINE_RADIUS, &mut d, planes);
                (kernel, d)
            })
            .collect()
    }

    /// Analytic: on a brightness ramp `L(x) = 2x + 10`, `R(x) = 2(x + 23.5) + 10` the
    /// linear interpolant is exact, so every step lands on 23.5 from estimates that
    /// scatter by ±0.3 px and round to 23 or 24 (holes among them), on either kernel.
    #[test]
    fn a_ramp_is_refined_to_its_exact_shift() {
        let (w, h) = (90, 20);
        let l = Grid::from_fn(w, h, |x, _| (2 * x + 10) as u8);
        let r = Grid::from_fn(w, h, |x, _| (2 * x + 57) as u8);
        let mut rng = crate::rng::Rng::new(4);
        let start = Grid::from_fn(w, h, |_, _| match rng.uniform() {
            u if u < 0.1 => f32::NAN,
            u => 23.2 + u as f32 * 0.6,
        });
        for (kernel, d) in refined_by_each_kernel(&l, &r, &start) {
            for y in 0..h {
                for x in 0..w {
                    let (v, s) = (d.get(x, y), start.get(x, y));
                    let inside = (REFINE_RADIUS..h - REFINE_RADIUS).contains(&y)
                        && (REFINE_RADIUS..w - REFINE_RADIUS).contains(&x)
                        && x >= 25;
                    if s.is_nan() {
                        assert!(v.is_nan(), "{kernel:?} ({x}, {y}): a hole filled");
                    } else if inside {
                        assert_eq!(v, 23.5, "{kernel:?} ({x}, {y}) from {s}");
                    } else {
                        assert!(v == s || v == 23.5, "{kernel:?} ({x}, {y}): {v} from {s}");
                    }
                }
            }
        }
    }

    /// The aggregated costs now and then pick a neighbouring whole pixel: refinement
    /// takes such pixels back to the images' answer when that is within
    /// [`MAX_CORRECTION_PX`] of their start's whole pixel, and keeps the start beyond.
    /// Ramps as above shifted by 24 px (the interpolant is exact on every interval, so
    /// each pixel's own answer is 24), estimates 24 ± 0.3 except two 16×20 patches: one
    /// started at 25.2 (1 px off: a bound of 0.75 px used to keep it there), one at
    /// 26.2 (2 px off: kept). Pixels whose window lies inside a patch are checked.
    #[test]
    fn a_neighbouring_whole_pixel_is_corrected_and_a_farther_one_kept() {
        let (w, h) = (100, 30);
        let l = Grid::from_fn(w, h, |x, _| (2 * x + 10) as u8);
        let r = Grid::from_fn(w, h, |x, _| (2 * x + 58) as u8);
        let mut rng = crate::rng::Rng::new(8);
        let near = |x: usize, y: usize| (30..46).contains(&x) && (5..25).contains(&y);
        let far = |x: usize, y: usize| (60..76).contains(&x) && (5..25).contains(&y);
        let start = Grid::from_fn(w, h, |x, y| match (near(x, y), far(x, y)) {
            (true, _) => 25.2,
            (_, true) => 26.2,
            _ => 24.0 + (rng.uniform() as f32 - 0.5) * 0.6,
        });
        let r4 = REFINE_RADIUS;
        let inside = |x: usize, y: usize, patch: &dyn Fn(usize, usize) -> bool| {
            patch(x - r4, y - r4) && patch(x + r4, y + r4)
        };
        for (kernel, d) in refined_by_each_kernel(&l, &r, &start) {
            let (mut corrected, mut kept) = (0, 0);
            for y in r4..h - r4 {
                for x in r4..w - r4 {
                    let v = d.get(x, y);
                    if inside(x, y, &near) {
                        assert_eq!(v, 24.0, "{kernel:?} ({x}, {y}): 1 px off, not corrected");
                        corrected += 1;
                    } else if inside(x, y, &far) {
                        assert_eq!(v, 26.2, "{kernel:?} ({x}, {y}): 2 px off, moved");
                        kept += 1;
                    }
                }
            }
            assert_eq!((corrected, kept), (8 * 12, 8 * 12), "{kernel:?}");
        }
    }

    /// At a depth edge a window's pixels lend answers from both surfaces; the spread
    /// test bounds the pull. Ramps as above, the top 20 rows at 23.5 px and the bottom
    /// 20 at 26.5 (a 3 px step), estimates within 0.2 px of the truth: every pixel stays
    /// within 0.4 px of its own surface (a share `f` of the window on the other side
    /// pulls by `3f` and spreads by `9f` px², at most 1: one row of nine, 0.33 px, and
    /// the scatter), and those whose window holds one surface land on it exactly.
    /// Without the test, two rows of the other surface would pull by 0.67 px.
    #[test]
    fn refinement_at_a_depth_edge_keeps_to_its_surface() {
        let (w, h, edge) = (90, 40, 20);
        let truth = |y: usize| if y < edge { 23.5 } else { 26.5 };
        let l = Grid::from_fn(w, h, |x, _| (2 * x + 10) as u8);
        let r = Grid::from_fn(w, h, |x, y| (2 * x + 10 + (2.0 * truth(y)) as usize) as u8);
        let mut rng = crate::rng::Rng::new(6);
        let start = Grid::from_fn(w, h, |_, y| truth(y) + (rng.uniform() as f32 - 0.5) * 0.4);
        let mut d = start.clone();
        refine(
            Kernel::best(),
            (&l, &r),
            REFINE_RADIUS,
            &mut d,
            &mut RefinePlanes::default(),
        );
        let mut exact = 0;
        for y in REFINE_RADIUS..h - REFINE_RADIUS {
            for x in 30..w - REFINE_RADIUS {
                let (v, t) = (d.get(x, y), truth(y));
                assert!((v - t).abs() <= 0.4, "({x}, {y}): {v} for {t}");
                if y.abs_diff(edge) > REFINE_RADIUS + 1 {
                    assert_eq!(v, t, "({x}, {y}) away from the edge");
                    exact += 1;
                }
            }
        }
        assert!(exact > 0);
    }
}
