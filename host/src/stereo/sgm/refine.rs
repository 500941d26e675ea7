//! Sub-pixel refinement of semi-global matching's disparities on the images themselves:
//! a least-squares (Lucas–Kanade) step along the row per pixel, from box sums of
//! per-pixel integer terms slid exactly over the frame. Aggregated census costs place
//! the minimum only to about 0.15 px; this brings it to the images' own precision.

use rayon::prelude::*;

use crate::grid::Grid;
use crate::stereo::block_match::Kernel;

/// Window radius of [`refine`].
const REFINE_RADIUS: usize = 4;

/// Gauss–Newton steps of [`refine`].
const REFINE_STEPS: usize = 2;

/// One pixel's least-squares terms for [`refine`], linearised at its own estimate `d`:
/// the right view is read at `x − d` by linear interpolation between its two whole
/// pixels there, `R[i]` and `R[i + 1]` with `i = x − ⌈d⌉`, and `g = R[i + 1] − R[i]` is
/// that interpolant's slope, so the linearisation is exact while the estimate stays
/// between them. With `e = L(x) − R(x − d)`, the window's shift `D` that minimises
/// `Σ (e + (D − d)·g)²` is `Σ (g²·d − g·e) / Σ g²`, and `g²·d − g·e` is the integer
/// `g²·⌈d⌉ − g·(L(x) − R[i])`: `weight = g²`, `moment` that. With them `g²·q` and
/// `g²·q²` for the estimate in sixteenths of a pixel (`q = round(16·d)`), from which a
/// window tells how far its pixels' estimates spread about its centre's
/// ([`RefineTerm::solve`]); `q` is kept and the two products made as the sums take them
/// (12 bytes a pixel instead of 24: the terms are written and read twice per step).
/// Integers, so window sums slide exactly and in any order.
#[derive(Clone, Copy, Default, PartialEq, Debug)]
struct RefineTerm {
    weight: i32,
    moment: i32,
    q: i32,
}

/// Window sums of `g²`, the moment, `g²·q` and `g²·q²` ([`RefineTerm::sums`]).
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
        // Matched disparities are below 4096 and a step stays within a pixel of one, so
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
        let weight = g * g;
        // |16·d| <= 131088 (the bound on ⌈d⌉ in `reads`): q fits i32 and the spread
        // terms i64 (255²·131088² < 2⁶³ / 81).
        Some(Self {
            weight,
            moment: weight * b - g * (i32::from(left[x]) - r0),
            q: sixteenths(d) as i32,
        })
    }

    /// What the window sums add: `g²`, the moment, `g²·q`, `g²·q²`.
    #[inline(always)]
    fn sums(self) -> RefineSums {
        let weighted_shift = i64::from(self.weight) * i64::from(self.q);
        [
            self.weight.into(),
            self.moment.into(),
            weighted_shift,
            weighted_shift * i64::from(self.q),
        ]
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

/// Least-squares sub-pixel refinement (Lucas–Kanade along the row, 9×9 window, two
/// Gauss–Newton steps from the aggregated-cost estimate). `L(x) ≈ R(x − D)`: each step
/// expands every pixel's `R(x − D)` around that pixel's own current estimate
/// ([`RefineTerm`]), so a window's update is a ratio of two box sums of per-pixel
/// integer terms, made once per pixel and slid down the columns and along the rows
/// (rows in bands of [`REFINE_BAND`] taken in order, bands in parallel). Where every
/// pixel of a window has the same estimate this is the classic Lucas–Kanade step with
/// the interpolant's slope. The previous refinement read each window at its centre's
/// estimate, so every pixel needed window sums of its own; these terms are shared
/// (640×480, 64 disparities, one core: 17.5 → about 7 ms). The slope is the
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
/// result stays within 0.75 px of the nearest whole pixel of the starting estimate;
/// otherwise the pixel keeps that estimate and takes no further steps (it still lends
/// its terms, at that estimate, to its neighbours). Only pixels whose whole window lies
/// in the image are refined. The sums are exact, so results do not depend on the
/// thread count.
pub(super) fn refine(
    kernel: Kernel,
    left: &Grid<u8>,
    right: &Grid<u8>,
    disparity: &mut Grid<f32>,
    planes: &mut RefinePlanes,
) {
    const R: usize = REFINE_RADIUS;
    let (w, h) = (left.width(), left.height());
    if h < 2 * R + 1 || w < 2 * R + 4 {
        return;
    }
    let RefinePlanes { start, live, terms } = planes;
    start.clear();
    start.extend_from_slice(disparity.as_slice());
    let start = Grid::from_vec(w, h, std::mem::take(start)).expect("a copy of the map");
    // Pixels still taking steps: 1; those that stopped keep their starting estimate.
    live.clear();
    live.resize(w * h, 1);
    // Every pixel's terms are written before they are read.
    terms.resize(w * h, RefineTerm::default());
    let mut terms = Grid::from_vec(w, h, std::mem::take(terms)).expect("sized just above");
    for _ in 0..REFINE_STEPS {
        terms
            .as_mut_slice()
            .par_chunks_mut(w)
            .zip(disparity.as_slice().par_chunks(w))
            .enumerate()
            .for_each(|(y, (out, d))| {
                run_refine_terms(kernel, (left.row(y), right.row(y)), d, out)
            });
        let terms = &terms;
        disparity
            .as_mut_slice()
            .par_chunks_mut(w * REFINE_BAND)
            .zip(live.par_chunks_mut(w * REFINE_BAND))
            .enumerate()
            .for_each(|(band, (rows, live))| {
                let first = band * REFINE_BAND;
                let mut columns = ColumnSums::new(w);
                let rows = rows.chunks_exact_mut(w).zip(live.chunks_exact_mut(w));
                for (j, (row, live)) in rows.enumerate() {
                    let y = first + j;
                    if y < R || y + R >= h {
                        continue;
                    }
                    columns.slide_to(terms, y);
                    run_refine_step(kernel, &columns, start.row(y), row, live);
                }
            });
    }
    planes.start = start.into_vec();
    planes.terms = terms.into_vec();
}

/// The planes [`refine`] works in, kept between frames.
#[derive(Default)]
pub(super) struct RefinePlanes {
    /// The aggregated-cost estimates.
    start: Vec<f32>,
    /// Which pixels still take steps.
    live: Vec<u8>,
    /// Every pixel's terms at its current estimate.
    terms: Vec<RefineTerm>,
}

/// Rows [`refine`] takes in order on one thread, so the window's column sums slide down
/// from the row above; bands run in parallel.
const REFINE_BAND: usize = 32;

/// The [`RefineTerm`]s of every column summed over the nine rows of a window, for the
/// window around row `row` (`usize::MAX` before the first).
struct ColumnSums {
    row: usize,
    sums: Vec<RefineSums>,
}

impl ColumnSums {
    fn new(w: usize) -> Self {
        Self {
            row: usize::MAX,
            sums: vec![[0; 4]; w],
        }
    }

    /// The sums for the window around row `y`: slid down a row from the window around
    /// `y − 1`, else summed afresh.
    fn slide_to(&mut self, terms: &Grid<RefineTerm>, y: usize) {
        const R: usize = REFINE_RADIUS;
        let add = |sums: &mut Self, row: usize, sign: i64| {
            for (s, t) in sums.sums.iter_mut().zip(terms.row(row)) {
                for (s, t) in s.iter_mut().zip(t.sums()) {
                    *s += sign * t;
                }
            }
        };
        if self.row.wrapping_add(1) == y {
            add(self, y + R, 1);
            add(self, y - R - 1, -1);
        } else {
            self.sums.fill([0; 4]);
            for row in y - R..=y + R {
                add(self, row, 1);
            }
        }
        self.row = y;
    }
}

#[allow(unsafe_code)]
fn run_refine_terms(kernel: Kernel, rows: (&[u8], &[u8]), d: &[f32], out: &mut [RefineTerm]) {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { refine_terms_avx2(rows, d, out) };
    }
    let _ = kernel;
    refine_terms(rows, d, out)
}

/// With AVX2 (and so SSE4.1) the roundings are instructions instead of calls; the same
/// results.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn refine_terms_avx2(rows: (&[u8], &[u8]), d: &[f32], out: &mut [RefineTerm]) {
    refine_terms(rows, d, out)
}

/// One row's [`RefineTerm`]s at the disparities `d` (zero where there are none).
#[inline(always)]
fn refine_terms(rows: (&[u8], &[u8]), d: &[f32], out: &mut [RefineTerm]) {
    let (left, right) = rows;
    for (x, (&d, o)) in d.iter().zip(out).enumerate() {
        *o = RefineTerm::of(left, right, x, d).unwrap_or_default();
    }
}

#[allow(unsafe_code)]
fn run_refine_step(
    kernel: Kernel,
    columns: &ColumnSums,
    start: &[f32],
    row: &mut [f32],
    live: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe { refine_step_avx2(columns, start, row, live) };
    }
    let _ = kernel;
    refine_step(columns, start, row, live)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn refine_step_avx2(columns: &ColumnSums, start: &[f32], row: &mut [f32], live: &mut [u8]) {
    refine_step(columns, start, row, live)
}

/// One Gauss–Newton step of [`refine`] for a row (`row`: its current estimates, `live`:
/// which still take steps, `start`: the starting estimates), its window sums slid along
/// the row from `columns`. The right row is as wide as `row`, so whether the centre's
/// own reads are inside it needs only the width.
#[inline(always)]
fn refine_step(columns: &ColumnSums, start: &[f32], row: &mut [f32], live: &mut [u8]) {
    const R: usize = REFINE_RADIUS;
    let w = row.len();
    let columns = &columns.sums;
    let mut sums: RefineSums = [0; 4];
    for c in &columns[..2 * R] {
        for (s, c) in sums.iter_mut().zip(c) {
            *s += c;
        }
    }
    for x in R..w - R {
        for (s, c) in sums.iter_mut().zip(columns[x + R]) {
            *s += c;
        }
        if x > R {
            for (s, c) in sums.iter_mut().zip(columns[x - R - 1]) {
                *s -= c;
            }
        }
        let v = row[x];
        if live[x] == 0 || !v.is_finite() {
            continue;
        }
        let reads = RefineTerm::reads(x, v, w).is_some();
        match RefineTerm::solve(sums, sixteenths(v)) {
            Some(next) if reads && (next - start[x].round()).abs() <= 0.75 => row[x] = next,
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

    /// The definition of [`refine`]: every window's sums from its 81 pixels' terms at
    /// the previous step's estimates, no reuse.
    fn refine_by_definition(left: &Grid<u8>, right: &Grid<u8>, disparity: &mut Grid<f32>) {
        const R: usize = REFINE_RADIUS;
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
            for y in R..h.saturating_sub(R) {
                for x in R..w - R {
                    let v = before.get(x, y);
                    if !live.get(x, y) || !v.is_finite() {
                        continue;
                    }
                    let mut sums = [0i64; 4];
                    for yy in y - R..=y + R {
                        for xx in x - R..=x + R {
                            let t = term(xx, yy);
                            sums[0] += i64::from(t.weight);
                            sums[1] += i64::from(t.moment);
                            sums[2] += i64::from(t.weight) * q(before.get(xx, yy));
                            sums[3] += i64::from(t.weight) * q(before.get(xx, yy)).pow(2);
                        }
                    }
                    let reads = RefineTerm::of(left.row(y), right.row(y), x, v).is_some();
                    match RefineTerm::solve(sums, q(v)) {
                        Some(next) if reads && (next - start.get(x, y).round()).abs() <= 0.75 => {
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
        let mut slow = start.clone();
        refine_by_definition(&l, &r, &mut slow);
        // Planes kept from a larger frame, as a matcher keeps them between frames.
        let mut planes = RefinePlanes::default();
        let (bl, br) = shifted_pair(w + 30, h + 20, |_, _| 25.3);
        refine(
            Kernel::best(),
            &bl,
            &br,
            &mut Grid::filled(w + 30, h + 20, 25.0),
            &mut planes,
        );
        for kernel in [Kernel::Portable, Kernel::Avx2]
            .into_iter()
            .filter(|k| k.is_available())
        {
            let mut fast = start.clone();
            refine(kernel, &l, &r, &mut fast, &mut planes);
            let changed = fast
                .as_slice()
                .iter()
                .zip(start.as_slice())
                .filter(|(a, b)| a.to_bits() != b.to_bits())
                .count();
            assert!(
                changed > w * h / 3,
                "{kernel:?}: refinement moved only {changed} pixels"
            );
            for (i, (a, b)) in fast.as_slice().iter().zip(slow.as_slice()).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "{kernel:?}, pixel ({}, {}): {a} vs {b}",
                    i % w,
                    i / w
                );
            }
        }
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
        for kernel in [Kernel::Portable, Kernel::Avx2]
            .into_iter()
            .filter(|k| k.is_available())
        {
            let mut d = start.clone();
            refine(kernel, &l, &r, &mut d, &mut RefinePlanes::default());
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
        refine(Kernel::best(), &l, &r, &mut d, &mut RefinePlanes::default());
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
