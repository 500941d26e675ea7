//! Depth post-processing, after the filters depth cameras ship (Intel RealSense's
//! post-processing chain), applied to disparity where noise is uniform: an
//! edge-preserving spatial filter, a temporal filter with persistence, and optional
//! hole filling. Each one is switched on and tuned on its own; NaN means "no value"
//! throughout and is never smeared into valid pixels.

use rayon::prelude::*;
use serde::Serialize;

use crate::grid::Grid;

/// Edge-preserving smoothing: recursive exponential passes left→right, right→left,
/// top→bottom and bottom→top that mix a pixel with its filtered neighbour only where the
/// two differ by less than `delta` pixels of disparity (a depth edge stops the smoothing).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SpatialFilter {
    /// Weight of the pixel itself, 0 < alpha ≤ 1 (1: no smoothing).
    pub alpha: f32,
    /// Largest step (disparity px) smoothed across.
    pub delta: f32,
    /// Number of passes over the four directions.
    pub iterations: u32,
}

impl Default for SpatialFilter {
    fn default() -> Self {
        Self {
            alpha: 0.5,
            delta: 1.0,
            iterations: 2,
        }
    }
}

impl SpatialFilter {
    /// Filters `disparity` in place. Rows are filtered in parallel; the vertical passes
    /// run a whole row at a time (row `y` against the filtered row `y ∓ 1`), which keeps
    /// them in cache and lets them vectorise, on bands of columns in parallel (one per
    /// thread: each column is filtered exactly as it would be alone).
    pub fn apply(&self, disparity: &mut Grid<f32>) {
        let alpha = self.alpha.clamp(f32::MIN_POSITIVE, 1.0);
        let (w, h) = (disparity.width(), disparity.height());
        if w == 0 || h == 0 || !self.delta.is_finite() {
            return;
        }
        let delta = self.delta;
        let data = disparity.as_mut_slice();
        // Bands at least 64 columns wide, so a row's part still fills vector lanes.
        let bands = rayon::current_num_threads().min(w / 64).max(1);
        let band_w = w.div_ceil(bands);
        for _ in 0..self.iterations {
            data.par_chunks_mut(w * ROWS_AT_ONCE)
                .for_each(|rows| smooth_rows(rows, w, alpha, delta));
            let mut columns: Vec<Vec<&mut [f32]>> =
                (0..bands).map(|_| Vec::with_capacity(h)).collect();
            for row in data.chunks_mut(w) {
                for (band, part) in columns.iter_mut().zip(row.chunks_mut(band_w)) {
                    band.push(part);
                }
            }
            columns
                .par_iter_mut()
                .for_each(|rows| smooth_vertically(rows, alpha, delta));
        }
    }
}

/// The vertical passes over one band of columns (`rows`: each row's part, top to
/// bottom): down, then up.
fn smooth_vertically(rows: &mut [&mut [f32]], alpha: f32, delta: f32) {
    for y in 1..rows.len() {
        let (done, rest) = rows.split_at_mut(y);
        smooth_towards(rest[0], done[y - 1], alpha, delta);
    }
    for y in (0..rows.len().saturating_sub(1)).rev() {
        let (head, done) = rows.split_at_mut(y + 1);
        smooth_towards(head[y], done[0], alpha, delta);
    }
}

/// One step of a vertical pass: every pixel of `row` against the pixel beside it in the
/// already filtered `previous` row.
fn smooth_towards(row: &mut [f32], previous: &[f32], alpha: f32, delta: f32) {
    for (v, &p) in row.iter_mut().zip(previous) {
        // NaN fails the comparison, so invalid pixels on either side are left alone.
        if (*v - p).abs() < delta {
            *v = alpha * *v + (1.0 - alpha) * p;
        }
    }
}

/// Rows the horizontal passes filter side by side (see [`smooth_rows`]).
const ROWS_AT_ONCE: usize = 8;

/// The horizontal passes (left→right, then right→left) over whole rows `rows` of width
/// `w`. Each pixel waits for its filtered neighbour, a chain of dependent steps along
/// the row; [`ROWS_AT_ONCE`] rows are stepped together so their chains overlap (a row
/// at a time spent a dozen cycles per pixel waiting). Every row is filtered exactly as
/// it would be alone.
fn smooth_rows(rows: &mut [f32], w: usize, alpha: f32, delta: f32) {
    let mut lines: Vec<&mut [f32]> = rows.chunks_mut(w).collect();
    if lines.len() != ROWS_AT_ONCE {
        for line in lines {
            smooth_line(line.iter_mut(), alpha, delta);
            smooth_line(line.iter_mut().rev(), alpha, delta);
        }
        return;
    }
    let mut previous = [f32::NAN; ROWS_AT_ONCE];
    for x in 0..w {
        for (line, p) in lines.iter_mut().zip(&mut previous) {
            *p = smoothed(line[x], *p, alpha, delta);
            line[x] = *p;
        }
    }
    let mut previous = [f32::NAN; ROWS_AT_ONCE];
    for x in (0..w).rev() {
        for (line, p) in lines.iter_mut().zip(&mut previous) {
            *p = smoothed(line[x], *p, alpha, delta);
            line[x] = *p;
        }
    }
}

/// One recursive pass along a line.
fn smooth_line<'a>(line: impl Iterator<Item = &'a mut f32>, alpha: f32, delta: f32) {
    let mut previous = f32::NAN;
    for v in line {
        *v = smoothed(*v, previous, alpha, delta);
        previous = *v;
    }
}

/// `v` mixed with its filtered neighbour `previous` when they differ by less than
/// `delta` (finite); NaN or infinite on either side fails the comparison and leaves `v`.
#[inline(always)]
fn smoothed(v: f32, previous: f32, alpha: f32, delta: f32) -> f32 {
    if (v - previous).abs() < delta {
        alpha * v + (1.0 - alpha) * previous
    } else {
        v
    }
}

/// Temporal filter settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TemporalParams {
    /// Weight of the new frame, 0 < alpha ≤ 1.
    pub alpha: f32,
    /// A change larger than this (disparity px) is motion: the new value is taken as is.
    pub delta: f32,
    /// Fill a pixel missing from this frame with its last value when it was valid in at
    /// least this many of the last four frames (0: never fill).
    pub persistence: u32,
}

impl Default for TemporalParams {
    fn default() -> Self {
        Self {
            alpha: 0.4,
            delta: 1.0,
            persistence: 2,
        }
    }
}

/// Exponential smoothing over frames, per pixel, with the state it needs between frames.
#[derive(Debug, Clone)]
pub struct TemporalFilter {
    params: TemporalParams,
    last: Option<Grid<f32>>,
    /// Per pixel: bit i set when the pixel was valid i frames ago.
    history: Vec<u8>,
}

impl TemporalFilter {
    /// A filter with no history.
    pub fn new(params: TemporalParams) -> Self {
        Self {
            params,
            last: None,
            history: Vec::new(),
        }
    }

    /// Forgets all frames (e.g. after the sensor moved).
    pub fn reset(&mut self) {
        self.last = None;
        self.history.clear();
    }

    /// Filters the next frame in place. A frame of another size restarts the filter.
    pub fn apply(&mut self, disparity: &mut Grid<f32>) {
        let alpha = self.params.alpha.clamp(f32::MIN_POSITIVE, 1.0);
        let same_size = self
            .last
            .as_ref()
            .is_some_and(|l| (l.width(), l.height()) == (disparity.width(), disparity.height()));
        if !same_size {
            self.history = disparity
                .as_slice()
                .iter()
                .map(|v| u8::from(v.is_finite()))
                .collect();
            self.last = Some(disparity.clone());
            return;
        }
        let Some(last) = self.last.as_mut() else {
            return;
        };
        for ((v, l), hist) in disparity
            .as_mut_slice()
            .iter_mut()
            .zip(last.as_mut_slice())
            .zip(&mut self.history)
        {
            let valid_before = (*hist & 0x0f).count_ones();
            *hist = (*hist << 1) | u8::from(v.is_finite());
            if v.is_finite() {
                if l.is_finite() && (*v - *l).abs() < self.params.delta {
                    *v = alpha * *v + (1.0 - alpha) * *l;
                }
                *l = *v;
            } else if l.is_finite()
                && self.params.persistence > 0
                && valid_before >= self.params.persistence
            {
                *v = *l;
            }
        }
    }
}

/// How holes are filled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct HoleFill {
    /// Holes (runs of missing pixels along a row) up to this long are filled with the
    /// farther of their two ends (the smaller disparity, as the background is what an
    /// occlusion hides); longer ones, and runs touching the image edge, stay empty.
    pub max_width: usize,
}

impl Default for HoleFill {
    fn default() -> Self {
        Self { max_width: 16 }
    }
}

impl HoleFill {
    /// Fills holes in place; returns how many pixels it filled.
    pub fn apply(&self, disparity: &mut Grid<f32>) -> usize {
        let w = disparity.width();
        if w == 0 {
            return 0;
        }
        let mut filled = 0;
        for row in disparity.as_mut_slice().chunks_exact_mut(w) {
            let mut x = 0;
            while x < w {
                if row[x].is_finite() {
                    x += 1;
                    continue;
                }
                let start = x;
                while x < w && !row[x].is_finite() {
                    x += 1;
                }
                let len = x - start;
                if start > 0 && x < w && len <= self.max_width {
                    let fill = row[start - 1].min(row[x]);
                    row[start..x].fill(fill);
                    filled += len;
                }
            }
        }
        filled
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spatial_smooths_noise_but_keeps_a_step() {
        // Alternating ±0.2 noise on two plateaus (20 and 30) with a step at x = 10.
        let g = Grid::from_fn(20, 12, |x, y| {
            let base = if x < 10 { 20.0 } else { 30.0 };
            base + if (x + y) % 2 == 0 { 0.2 } else { -0.2 }
        });
        let mut f = g.clone();
        SpatialFilter::default().apply(&mut f);
        let rms = |g: &Grid<f32>, x0: usize, x1: usize, base: f32| {
            let v: Vec<f32> = (0..12)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .map(|(x, y)| g.get(x, y) - base)
                .collect();
            (v.iter().map(|e| e * e).sum::<f32>() / v.len() as f32).sqrt()
        };
        assert!(rms(&f, 2, 8, 20.0) < 0.5 * rms(&g, 2, 8, 20.0));
        // The step stays sharp: the pixels beside it keep their plateau.
        for y in 0..12 {
            assert!((f.get(9, y) - 20.0).abs() < 0.25 && (f.get(10, y) - 30.0).abs() < 0.25);
        }
        // NaN stays NaN and does not spread.
        let mut n = Grid::from_fn(5, 1, |x, _| if x == 2 { f32::NAN } else { 10.0 });
        SpatialFilter::default().apply(&mut n);
        assert!(n.get(2, 0).is_nan() && n.get(1, 0) == 10.0 && n.get(3, 0) == 10.0);
    }

    /// Column bands on several threads filter exactly as one thread does.
    #[test]
    fn spatial_bands_match_one_thread() {
        let mut rng = crate::rng::Rng::new(4);
        let noisy = Grid::from_fn(301, 40, |x, y| {
            if rng.uniform() < 0.05 {
                f32::NAN
            } else {
                (x / 50) as f32 * 3.0 + 0.01 * y as f32 + rng.uniform() as f32 * 0.6
            }
        });
        let run = |threads| {
            let mut d = noisy.clone();
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| SpatialFilter::default().apply(&mut d));
            d
        };
        let one = run(1);
        let changed = one.as_slice().iter().zip(noisy.as_slice());
        let changed = changed.filter(|(a, b)| a.is_finite() && a != b).count();
        assert!(
            changed > 301 * 40 / 2,
            "the filter smoothed {changed} pixels"
        );
        for threads in [2, 3, 4] {
            let many = run(threads);
            let same = one.as_slice().iter().zip(many.as_slice());
            assert!(
                same.into_iter().all(|(a, b)| a.to_bits() == b.to_bits()),
                "{threads} threads"
            );
        }
    }

    /// Rows stepped side by side come out bit for bit as each row filtered alone,
    /// with NaN and infinities among the values and a last block of fewer rows.
    #[test]
    fn rows_side_by_side_match_rows_alone() {
        let mut rng = crate::rng::Rng::new(9);
        let (w, h) = (77, 2 * ROWS_AT_ONCE + 3);
        let noisy: Vec<f32> = (0..w * h)
            .map(|i| match rng.uniform() {
                u if u < 0.04 => f32::NAN,
                u if u < 0.05 => f32::INFINITY,
                u if u < 0.06 => f32::NEG_INFINITY,
                _ => (i % w / 20) as f32 * 2.0 + rng.uniform() as f32 * 1.5,
            })
            .collect();
        let (alpha, delta) = (0.35, 1.0);
        let mut together = noisy.clone();
        for block in together.chunks_mut(w * ROWS_AT_ONCE) {
            smooth_rows(block, w, alpha, delta);
        }
        let mut alone = noisy.clone();
        for row in alone.chunks_mut(w) {
            // The filter as it was, one row at a time with explicit finiteness tests.
            for pass in 0..2 {
                let mut previous = f32::NAN;
                let mut step = |v: &mut f32| {
                    if v.is_finite() && previous.is_finite() && (*v - previous).abs() < delta {
                        *v = alpha * *v + (1.0 - alpha) * previous;
                    }
                    previous = *v;
                };
                if pass == 0 {
                    row.iter_mut().for_each(&mut step);
                } else {
                    row.iter_mut().rev().for_each(&mut step);
                }
            }
        }
        let changed = together
            .iter()
            .zip(&noisy)
            .filter(|(a, b)| a.is_finite() && a != b);
        assert!(changed.count() > w * h / 3);
        for (i, (a, b)) in together.iter().zip(&alone).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "pixel {i}: {a} vs {b}");
        }
    }

    #[test]
    fn temporal_averages_still_pixels_follows_motion_and_persists() {
        let mut t = TemporalFilter::new(TemporalParams::default());
        let frame = |v: f32| Grid::filled(2, 1, v);
        let mut a = frame(10.0);
        t.apply(&mut a);
        assert_eq!(a.get(0, 0), 10.0);
        let mut b = frame(10.5);
        t.apply(&mut b);
        // 0.4·10.5 + 0.6·10 = 10.2.
        assert!((b.get(0, 0) - 10.2).abs() < 1e-6);
        let mut c = frame(15.0); // moved: taken as is
        t.apply(&mut c);
        assert_eq!(c.get(0, 0), 15.0);
        let mut d = frame(f32::NAN); // dropped out: filled from the last value
        t.apply(&mut d);
        assert_eq!(d.get(1, 0), 15.0);
        // Missing for good: the history empties and the fill stops.
        let mut last = 0.0;
        for _ in 0..4 {
            let mut e = frame(f32::NAN);
            t.apply(&mut e);
            last = e.get(0, 0);
        }
        assert!(last.is_nan());
        // A new size restarts.
        let mut big = Grid::filled(3, 1, 7.0);
        t.apply(&mut big);
        assert_eq!(big.get(2, 0), 7.0);
    }

    #[test]
    fn holes_take_the_farther_end_and_long_or_open_runs_stay() {
        let n = f32::NAN;
        let mut g = Grid::from_vec(10, 1, vec![n, 5.0, n, n, 9.0, n, n, n, n, 4.0]).unwrap();
        let filled = HoleFill { max_width: 3 }.apply(&mut g);
        assert_eq!(filled, 2);
        let row = g.row(0);
        assert!(row[0].is_nan());
        assert_eq!((row[2], row[3]), (5.0, 5.0));
        assert!(row[5..9].iter().all(|v| v.is_nan()));
    }
}
