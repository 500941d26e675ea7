//! Slopes past the lookup table's reach, read by the light model as well.
//!
//! The table answers with the slopes its calibration presses made: its entries saturate
//! at the steepest slope the ball taught, so a steeper wall reads as that slope (one
//! ball on the tuning families: a 1 mm disk with a wall of 1.31 read 0.90 and 0.83 mm).
//! The light model ([`LightModel`]) is a straight line per strip and extrapolates, but
//! it reads gentle slopes less well than the table. So a pixel whose table reading (its
//! position gain taken out) reaches [`REACH_SHARE`] of the table's largest reading of
//! that sign is read by the light model too (both phases,
//! [`read_pair`](super::model::light::read_pair)), and takes the light model's slope on
//! an axis where it points the same way and is steeper. Pixels under the reach keep the
//! table's slopes bit for bit: a scene without steep walls costs a comparison a pixel;
//! `Reconstructor::set_past_reach(false)` turns the reading off. The perceptron
//! saturates the same way and is read past the same limits ([`Reach::extend_rows`]: its
//! slopes come as feature rows, and it takes the position as an input, so no gains).

use super::model::Lut;
use super::model::light::{LightModel, PairReader};

/// Share of the table's largest reading (of each sign) from which the light model reads
/// a pixel as well. Chosen on the tuning families (`bench skins`, one ball, 10
/// placements; see the README's section on slopes past the table's reach).
pub const REACH_SHARE: f32 = 0.75;

/// Per axis, the table readings `[positive, negative magnitude]` from which the light
/// model reads a pixel too: [`REACH_SHARE`] of the table's largest reading of that sign
/// ([`Lut::extremes`]), infinite for a sign the table never reads. Made once per model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReachLimits([[f32; 2]; 2]);

impl ReachLimits {
    /// The limits of `luts`; `None` when a table has no entries (a damaged model file
    /// reads 0 anyway).
    pub fn of(luts: [&Lut; 2]) -> Option<Self> {
        let [x, y] = [luts[0].extremes()?, luts[1].extremes()?];
        Some(Self([x, y].map(|e| {
            e.map(|v| {
                if v > 0.0 && v.is_finite() {
                    v * REACH_SHARE
                } else {
                    f32::INFINITY
                }
            })
        })))
    }
}

/// Pixels of a region [`Reach::extend`] queued for the light model and not read yet
/// ([`Reach::finish`] reads them); one per region, made empty.
#[derive(Default)]
pub struct Pending<'a>(Option<PairReader<'a>>);

/// The light models and the limits from which they read a pixel too.
#[derive(Debug, Clone, Copy)]
pub struct Reach<'a> {
    light: [&'a LightModel; 2],
    from: [[f32; 2]; 2],
}

impl<'a> Reach<'a> {
    /// The light models `light` reading past `limits`.
    pub fn new(limits: ReachLimits, light: [&'a LightModel; 2]) -> Self {
        Self {
            light,
            from: limits.0,
        }
    }

    /// The light models' reader in `slot`, made at the first pixel read (most regions
    /// read none); `None` for a damaged light model, which reads nothing.
    fn reader<'s>(&self, slot: &'s mut Option<PairReader<'a>>) -> Option<&'s mut PairReader<'a>> {
        if slot.is_none() {
            *slot = Some(PairReader::new(self.light)?);
        }
        slot.as_mut()
    }

    /// Whether a table reading `slope` (with its pixel's gains `[positive, negative]`)
    /// reaches the table's limit on `axis`.
    #[inline(always)]
    fn reached(&self, axis: usize, slope: f32, gains: [f32; 2]) -> bool {
        reaches(self.from[axis], slope, gains)
    }

    /// Queues for the light model the pixels of a run whose table slopes reach the limit
    /// on either axis and that both phases light (`lit`): `features` are the run's model
    /// inputs `[red, blue]` per phase (each phase's normalised colour times the other
    /// phase's cross factor, [`colour_features`](super::model::colour_features)),
    /// `position(k)` pixel `k`'s position `[x / width, y / height]`, `gains` the table's
    /// position gains per axis, `run` the run's indices in the region's `[p, q]` grids
    /// `slopes`. Queued pixels are read [`LANES`](super::model::light::LANES) at a time,
    /// across runs (a run rarely fills them), and an axis takes the light model's slope
    /// where it points the same way and is steeper (bounded by ±`max_slope`);
    /// [`Self::finish`] reads the last ones, after the region's last run. Returns how many
    /// pixels were queued.
    #[allow(clippy::too_many_arguments)]
    pub fn extend(
        &self,
        pending: &mut Pending<'a>,
        lit: [&[bool]; 2],
        features: [[&[f32]; 2]; 2],
        position: impl Fn(usize) -> [f32; 2],
        gains: [&[[f32; 2]]; 2],
        run: std::ops::Range<usize>,
        slopes: [&mut [f32]; 2],
        max_slope: f32,
    ) -> usize {
        let [p, q] = slopes;
        if run.start > run.end || run.end > p.len().min(q.len()) {
            return 0;
        }
        let n = [
            run.len(),
            lit[0].len(),
            lit[1].len(),
            gains[0].len(),
            gains[1].len(),
        ]
        .into_iter()
        .chain(features.iter().flatten().map(|f| f.len()))
        .min()
        .unwrap_or(0);
        let mut count = 0;
        // Which pixels to read is asked for a chunk at a time in vector lanes (most
        // chunks have none), then the chunk's marked pixels are queued in order.
        let mut marks = [false; MARK_CHUNK];
        for start in (0..n).step_by(MARK_CHUNK) {
            let end = (start + MARK_CHUNK).min(n);
            let marks = &mut marks[..end - start];
            mark_reached(
                self.from,
                [&lit[0][start..end], &lit[1][start..end]],
                [
                    &p[run.start + start..run.start + end],
                    &q[run.start + start..run.start + end],
                ],
                [&gains[0][start..end], &gains[1][start..end]],
                marks,
            );
            if !marks.iter().fold(false, |any, &m| any | m) {
                continue;
            }
            for (k, _) in (start..end).zip(marks.iter()).filter(|(_, m)| **m) {
                let Some(reader) = self.reader(&mut pending.0) else {
                    return count;
                };
                count += 1;
                let [fx, fy] = features.map(|[red, blue]| [red[k], blue[k]]);
                let [x, y] = position(k);
                // Each pixel's table slopes stay as they were until its reading comes
                // back (nothing else writes them, and a run's marks were made from its
                // slopes before any came back).
                reader.queue(run.start + k, fx, fy, x, y, |k, read| {
                    take_steeper_at([&mut *p, &mut *q], k, read, max_slope);
                });
            }
        }
        count
    }

    /// Reads the pixels [`Self::extend`] left queued in `pending` into the region's
    /// `[p, q]` grids `slopes`.
    pub fn finish(&self, pending: &mut Pending<'a>, slopes: [&mut [f32]; 2], max_slope: f32) {
        let [p, q] = slopes;
        if let Some(reader) = pending.0.as_mut() {
            reader.flush(|k, read| take_steeper_at([&mut *p, &mut *q], k, read, max_slope));
        }
    }

    /// [`Self::extend`] for a model read from feature rows (the perceptron): `rows` are
    /// each phase's `[red, blue, x / width, y / height]` of the pixels it lit, `targets`
    /// their indices in the region's `[p, q]` grids `slopes` (increasing). A pixel both
    /// phases lit whose slope reaches the limit on either axis is read (no position gains:
    /// the model takes the position as an input). Returns how many pixels were read.
    pub fn extend_rows(
        &self,
        rows: [&[[f32; 4]]; 2],
        targets: [&[usize]; 2],
        slopes: [&mut [f32]; 2],
        max_slope: f32,
    ) -> usize {
        let [p, q] = slopes;
        let n = [0, 1].map(|a| rows[a].len().min(targets[a].len()));
        let (mut i, mut j, mut count) = (0, 0, 0);
        let mut slot = None;
        while i < n[0] && j < n[1] {
            let (a, b) = (targets[0][i], targets[1][j]);
            if a != b {
                // One phase alone lit the pixel: not read.
                if a < b {
                    i += 1;
                } else {
                    j += 1;
                }
                continue;
            }
            let (fx, fy) = (rows[0][i], rows[1][j]);
            (i, j) = (i + 1, j + 1);
            let (Some(&sp), Some(&sq)) = (p.get(a), q.get(a)) else {
                continue;
            };
            if !(self.reached(0, sp, [1.0; 2]) || self.reached(1, sq, [1.0; 2])) {
                continue;
            }
            let Some(reader) = self.reader(&mut slot) else {
                return count;
            };
            count += 1;
            reader.queue(
                a,
                [fx[0], fx[1]],
                [fy[0], fy[1]],
                fx[2],
                fx[3],
                |k, read| {
                    take_steeper([&mut p[k], &mut q[k]], read, max_slope);
                },
            );
        }
        if let Some(reader) = slot.as_mut() {
            reader.flush(|k, read| take_steeper([&mut p[k], &mut q[k]], read, max_slope));
        }
        count
    }
}

/// Whether `slope` (with its pixel's gains `[positive, negative]`) reaches the limit of
/// its sign, `from` being `[positive, negative magnitude]`. Gains are positive (a model
/// file's are checked). Branch-free, so a loop over a run stays in vector lanes: both
/// signs' limits weighed and the slope's sign's answer kept (a select on the sign became
/// a branch the sign's noise mispredicted).
#[inline(always)]
fn reaches(from: [f32; 2], slope: f32, gains: [f32; 2]) -> bool {
    let negative = slope < 0.0;
    let size = slope.abs();
    (!negative & (size >= from[0] * gains[0])) | (negative & (size >= from[1] * gains[1]))
}

/// Pixels a chunk of [`Reach::extend`] asks about at once.
const MARK_CHUNK: usize = 64;

/// Marks the pixels both phases light (`lit`) whose slopes `[p, q]` reach the limits
/// `from` ([`reaches`], per axis) on either axis. Runs the AVX2 copy when
/// the CPU has it.
#[allow(unsafe_code)]
fn mark_reached(
    from: [[f32; 2]; 2],
    lit: [&[bool]; 2],
    slopes: [&[f32]; 2],
    gains: [&[[f32; 2]]; 2],
    marks: &mut [bool],
) {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::avx2() {
        // SAFETY: `mark_reached_avx2` only needs AVX2, detected just above.
        return unsafe { mark_reached_avx2(from, lit, slopes, gains, marks) };
    }
    mark_reached_portable(from, lit, slopes, gains, marks)
}

/// [`mark_reached_portable`] in 8-wide lanes (comparisons only: the same marks).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn mark_reached_avx2(
    from: [[f32; 2]; 2],
    lit: [&[bool]; 2],
    slopes: [&[f32]; 2],
    gains: [&[[f32; 2]]; 2],
    marks: &mut [bool],
) {
    mark_reached_portable(from, lit, slopes, gains, marks)
}

#[inline(always)]
fn mark_reached_portable(
    from: [[f32; 2]; 2],
    lit: [&[bool]; 2],
    slopes: [&[f32]; 2],
    gains: [&[[f32; 2]]; 2],
    marks: &mut [bool],
) {
    let n = marks.len();
    let (lx, ly) = (&lit[0][..n], &lit[1][..n]);
    let (p, q) = (&slopes[0][..n], &slopes[1][..n]);
    let (gx, gy) = (&gains[0][..n], &gains[1][..n]);
    for i in 0..n {
        marks[i] = lx[i] & ly[i] & (reaches(from[0], p[i], gx[i]) | reaches(from[1], q[i], gy[i]));
    }
}

/// [`take_steeper`] at index `k` of the `[p, q]` grids `slopes`; nothing where `k` lies
/// past them (a queue kept from a larger region).
#[inline]
fn take_steeper_at(slopes: [&mut [f32]; 2], k: usize, read: [f32; 2], max_slope: f32) {
    let [p, q] = slopes;
    if let (Some(p), Some(q)) = (p.get_mut(k), q.get_mut(k)) {
        take_steeper([p, q], read, max_slope);
    }
}

/// Each slope takes the light model's `read` where it points the same way and is
/// steeper, bounded by ±`max_slope`.
#[inline]
fn take_steeper(slopes: [&mut f32; 2], read: [f32; 2], max_slope: f32) {
    for (s, r) in slopes.into_iter().zip(read) {
        if r.is_finite() && r * *s > 0.0 && r.abs() > s.abs() {
            *s = r.clamp(-max_slope, max_slope);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tactile::model::{Sample, matte_features};

    /// Cotangent of the strips' elevation on the analytic skin.
    const K: f32 = 1.6;

    /// Model inputs of the analytic matte skin at slopes `(p, q)` ([`matte_features`]).
    fn features(p: f32, q: f32) -> [[f32; 2]; 2] {
        matte_features(p, q, K)
    }

    /// A table and a light model per axis, both taught slopes up to `taught` (a ball's).
    fn models(taught: f32) -> ([Lut; 2], [LightModel; 2]) {
        let mut sets = [Vec::new(), Vec::new()];
        for i in -20..=20 {
            for j in -20..=20 {
                let (p, q) = (i as f32 / 20.0 * taught, j as f32 / 20.0 * taught);
                if p.hypot(q) > taught {
                    continue;
                }
                let f = features(p, q);
                for (axis, (set, s)) in sets.iter_mut().zip([p, q]).enumerate() {
                    set.push(Sample {
                        features: [f[axis][0], f[axis][1], 0.5, 0.5],
                        target: s,
                    });
                }
            }
        }
        (
            [0, 1].map(|a| Lut::fit(&sets[a], 64, 4.0, 1, 1)),
            [0, 1].map(|a| LightModel::fit(&sets[a], 1, 1)),
        )
    }

    /// The table's slopes of pixels at `slopes`, then [`Reach::extend`] on them in one
    /// run; the pixels read by the light model are counted.
    fn read(
        luts: &[Lut; 2],
        light: &[LightModel; 2],
        slopes: &[(f32, f32)],
        lit: bool,
    ) -> (Vec<[f32; 2]>, Vec<[f32; 2]>, usize) {
        let whole = 0..slopes.len();
        read_in_runs(luts, light, slopes, lit, std::slice::from_ref(&whole))
    }

    /// [`read`] with the pixels split into `runs` that share one queue. Each time, a run
    /// past the grids' end is asked for too, and must queue nothing.
    fn read_in_runs(
        luts: &[Lut; 2],
        light: &[LightModel; 2],
        slopes: &[(f32, f32)],
        lit: bool,
        runs: &[std::ops::Range<usize>],
    ) -> (Vec<[f32; 2]>, Vec<[f32; 2]>, usize) {
        let f: Vec<_> = slopes.iter().map(|&(p, q)| features(p, q)).collect();
        let plane = |phase: usize, c: usize| f.iter().map(|f| f[phase][c]).collect::<Vec<_>>();
        let planes = [[plane(0, 0), plane(0, 1)], [plane(1, 0), plane(1, 1)]];
        let table: Vec<[f32; 2]> = f
            .iter()
            .map(|f| [0, 1].map(|a| luts[a].eval(f[a][0], f[a][1], 0.5, 0.5)))
            .collect();
        let (mut p, mut q): (Vec<f32>, Vec<f32>) = table.iter().map(|s| (s[0], s[1])).unzip();
        let n = slopes.len();
        let gains = vec![[1.0f32, 1.0]; n + 8];
        let lit = vec![lit; n + 8];
        let limits = ReachLimits::of([&luts[0], &luts[1]]).unwrap();
        let reach = Reach::new(limits, [&light[0], &light[1]]);
        let mut pending = Pending::default();
        let mut count = 0;
        let past_the_end = n.saturating_sub(2)..n + 5;
        for (k, run) in runs.iter().chain([&past_the_end]).enumerate() {
            // The inputs of the run, beginning at its first pixel (beyond the grids, the
            // run's inputs are there; its slopes are not).
            let r = run.start.min(n)..run.end.min(n);
            let queued = reach.extend(
                &mut pending,
                [&lit[run.clone()], &lit[run.clone()]],
                [
                    [&planes[0][0][r.clone()], &planes[0][1][r.clone()]],
                    [&planes[1][0][r.clone()], &planes[1][1][r]],
                ],
                |_| [0.5, 0.5],
                [&gains[run.clone()], &gains[run.clone()]],
                run.clone(),
                [&mut p, &mut q],
                3.0,
            );
            if k < runs.len() {
                count += queued;
            } else {
                assert_eq!(queued, 0, "a run past the grids queued pixels");
            }
        }
        reach.finish(&mut pending, [&mut p, &mut q], 3.0);
        let after = p.into_iter().zip(q).map(|(p, q)| [p, q]).collect();
        (table, after, count)
    }

    #[test]
    fn walls_past_the_taught_slopes_read_their_slope_and_gentle_ones_are_untouched() {
        let (luts, light) = models(0.8);
        let steep = [(1.31f32, 0.0f32), (-1.31, 0.0), (0.0, 1.6), (0.0, -1.2)];
        let gentle = [(0.3f32, 0.0f32), (-0.2, 0.1), (0.0, 0.0), (0.1, -0.35)];
        let all: Vec<_> = steep.iter().chain(&gentle).copied().collect();
        let (table, after, count) = read(&luts, &light, &all, true);
        for (k, &(p, q)) in steep.iter().enumerate() {
            let (t, s) = (table[k], after[k]);
            let (truth, was, now) = if p != 0.0 {
                (p, t[0], s[0])
            } else {
                (q, t[1], s[1])
            };
            // The table saturates at about the taught 0.8; the light model reads on.
            assert!(was.abs() < 0.9, "({p}, {q}): the table read {was}");
            assert!((now - truth).abs() < 0.05, "({p}, {q}): {was} -> {now}");
        }
        for k in steep.len()..all.len() {
            assert_eq!(after[k], table[k], "{:?}", all[k]);
        }
        assert_eq!(count, steep.len());
    }

    /// Read from feature rows (the perceptron's path), a pixel lit in both phases reads
    /// as [`Reach::extend`] reads it; one lit in one phase only is kept.
    #[test]
    fn rows_read_as_planes_and_one_phase_pixels_are_kept() {
        let (luts, light) = models(0.8);
        let slopes = [
            (1.31f32, 0.0f32),
            (0.2, 0.1),
            (0.0, -1.5),
            (1.4, 0.3),
            (-1.2, 0.0),
        ];
        let (table, want, _) = read(&luts, &light, &slopes, true);
        let rows: Vec<[[f32; 4]; 2]> = slopes
            .iter()
            .map(|&(p, q)| features(p, q).map(|[r, b]| [r, b, 0.5, 0.5]))
            .collect();
        // Pixel 3 is lit by the dx phase only (its dy row is missing).
        let targets = [vec![0, 1, 2, 3, 4], vec![0, 1, 2, 4]];
        let axis_rows = |a: usize| targets[a].iter().map(|&k| rows[k][a]).collect::<Vec<_>>();
        let (rx, ry) = (axis_rows(0), axis_rows(1));
        let (mut p, mut q): (Vec<f32>, Vec<f32>) = table.iter().map(|s| (s[0], s[1])).unzip();
        let limits = ReachLimits::of([&luts[0], &luts[1]]).unwrap();
        let reach = Reach::new(limits, [&light[0], &light[1]]);
        let count = reach.extend_rows(
            [&rx, &ry],
            [&targets[0], &targets[1]],
            [&mut p, &mut q],
            3.0,
        );
        assert_eq!(count, 3);
        for k in 0..slopes.len() {
            let expected = if k == 3 { table[k] } else { want[k] };
            assert_eq!([p[k], q[k]], expected, "{:?}", slopes[k]);
        }
        assert_ne!(
            want[3], table[3],
            "pixel 3 would have been read with both phases"
        );
        // Targets beyond the grids are skipped, never a panic.
        let far = [vec![9], vec![9]];
        let none = reach.extend_rows(
            [&rx[..1], &ry[..1]],
            [&far[0], &far[1]],
            [&mut p, &mut q],
            3.0,
        );
        assert_eq!(none, 0);
    }

    /// A region read run by run with one queue between them reads each pixel as the
    /// region read in one run does, bit for bit, however the runs split the lanes.
    #[test]
    fn runs_sharing_one_queue_read_as_one_run() {
        let (luts, light) = models(0.8);
        let mut rng = crate::rng::Rng::new(11);
        // Mostly steep pixels, so that the queue fills several times over.
        let slopes: Vec<(f32, f32)> = (0..70)
            .map(|k| {
                let steep = if k % 3 == 0 { 0.3 } else { 1.4 };
                let p = rng.range(-1.0, 1.0) as f32 * steep;
                (p, rng.range(-1.0, 1.0) as f32 * (1.7 - p.abs()))
            })
            .collect();
        let (table, whole, count) = read(&luts, &light, &slopes, true);
        assert!(
            count > 2 * crate::tactile::model::light::LANES,
            "{count} pixels read"
        );
        let n = slopes.len();
        let runs = [0..3, 3..4, 4..29, 29..29, 29..n];
        let (_, split, queued) = read_in_runs(&luts, &light, &slopes, true, &runs);
        assert_eq!(queued, count);
        for k in 0..n {
            assert_eq!(
                split[k].map(f32::to_bits),
                whole[k].map(f32::to_bits),
                "pixel {k}: {:?}",
                slopes[k]
            );
        }
        assert_ne!(whole, table, "some pixels were read again");
    }

    /// The chunk's marks in lanes are the pixel-by-pixel rule's: slopes at, under and
    /// over either sign's limit, NaN, ±0 and unlit phases, over a length that is not a
    /// multiple of the lanes.
    #[test]
    fn marks_in_lanes_follow_the_pixel_by_pixel_rule() {
        let (luts, light) = models(0.8);
        let reach = Reach::new(
            ReachLimits::of([&luts[0], &luts[1]]).unwrap(),
            [&light[0], &light[1]],
        );
        let mut rng = crate::rng::Rng::new(7);
        let n = 61;
        let special = [0.0, -0.0, f32::NAN, 0.6, -0.6];
        let mut slope = |k: usize| {
            if k.is_multiple_of(5) {
                special[(k / 5) % special.len()]
            } else {
                rng.range(-1.2, 1.2) as f32
            }
        };
        let p: Vec<f32> = (0..n).map(&mut slope).collect();
        let q: Vec<f32> = (0..n).map(|k| slope(k + 3)).collect();
        let mut gain = || [rng.range(0.5, 1.5) as f32, rng.range(0.5, 1.5) as f32];
        let (gx, gy): (Vec<_>, Vec<_>) = (0..n).map(|_| (gain(), gain())).unzip();
        let lx: Vec<bool> = (0..n).map(|k| k % 7 != 3).collect();
        let ly: Vec<bool> = (0..n).map(|k| k % 11 != 5).collect();
        // A slope exactly at a limit counts as reached.
        let mut p = p;
        p[1] = reach.from[0][0] * gx[1][0];
        let mut marks = vec![false; n];
        mark_reached(reach.from, [&lx, &ly], [&p, &q], [&gx, &gy], &mut marks);
        let mut reached = 0;
        for k in 0..n {
            let want =
                lx[k] && ly[k] && (reach.reached(0, p[k], gx[k]) || reach.reached(1, q[k], gy[k]));
            assert_eq!(marks[k], want, "pixel {k}: p {} q {}", p[k], q[k]);
            reached += usize::from(want);
        }
        assert!(
            marks[1] && reached > 5 && reached < n - 5,
            "{reached} of {n}"
        );
    }

    #[test]
    fn unlit_pixels_other_signs_and_bounds_are_kept() {
        let (luts, light) = models(0.8);
        // Not lit in both phases: as the table read it.
        let (table, after, count) = read(&luts, &light, &[(1.31, 0.0)], false);
        assert_eq!((after, count), (table, 0));
        // The light model's slope is bounded by max_slope (3): past it, 3.
        let (_, after, _) = read(&luts, &light, &[(4.0, 0.0)], true);
        assert!(after[0][0] <= 3.0 && after[0][0] > 2.5, "{:?}", after[0]);
    }

    #[test]
    fn a_table_without_readings_of_a_sign_has_no_reach_there() {
        let flat = Lut {
            bins: 2,
            max_value: 4.0,
            cells_x: 1,
            cells_y: 1,
            table: vec![0.0; 4],
            gain: vec![1.0],
            gain_negative: vec![1.0],
        };
        let light = LightModel {
            cells_x: 1,
            cells_y: 1,
            response: vec![[K, -K]],
        };
        let reach = Reach::new(ReachLimits::of([&flat, &flat]).unwrap(), [&light, &light]);
        assert!(!reach.reached(0, 100.0, [1.0, 1.0]) && !reach.reached(1, -100.0, [1.0, 1.0]));
        let damaged = Lut {
            table: vec![],
            ..flat.clone()
        };
        assert!(ReachLimits::of([&damaged, &flat]).is_none());
    }
}
