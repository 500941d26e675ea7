//! Lookup-table gradient model: slope as a function of the normalised colour `(r, b)`,
//! bilinear in colour, times a gain that varies smoothly over the frame.
//!
//! The gain follows what changes across the frame (the light's elevation is higher near
//! a strip, so the same colour means a smaller slope there). It is one number per spatial
//! cell and sign of the reading, blended bilinearly, fitted by least squares after the
//! colour table. A full colour table per cell was tried first: with a dozen ball presses
//! each cell's table is too sparse, fell back on the all-frame table, and the position
//! effect vanished. The sign matters because the two strips of a phase change elevation
//! in opposite directions across the frame: near one strip its light is steep and the
//! other's shallow, so slopes facing one strip read differently from those facing the
//! other (tuning skins `ours-random` 1–4: mean error of the 1 mm disk 0.022 → 0.015 mm
//! with a gain per sign; 8×6 cells instead of 4×3 changed nothing more).
//!
//! Training averages the samples falling around each table entry (bilinear splatting);
//! colours never seen take the value of the nearest seen ones (iterative neighbour fill),
//! which saturates gracefully instead of extrapolating.
//!
//! An average of slopes per colour reads steep slopes short: the colours are noisy, and
//! near the steepest slope the calibration ball made there are far fewer samples of that
//! slope than of gentler ones whose noise lands in the same entry (regression dilution;
//! on our renderer's tuning skins a 1 mm disk read 0.90–0.97 mm from an 8–10 mm ball).
//! So the table is then *debiased* ([`ResponseCurve`]): every entry `v` is replaced by
//! `m⁻¹(v)`, `m(t)` the table's mean reading of the true slope `t` on the training
//! samples. The gain is fitted in the same direction. Both stay folded into the table
//! and gains: the model file and the evaluation are unchanged.

use serde::{Deserialize, Serialize};

use super::Sample;
use super::cells::{cell_weights, frame_plane, locate};
use super::response::ResponseCurve;

/// The table and its axes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lut {
    /// Entries per colour axis.
    pub bins: usize,
    /// Colour value of the last bin (values above are clamped).
    pub max_value: f32,
    /// Spatial cells across.
    pub cells_x: usize,
    /// Spatial cells down.
    pub cells_y: usize,
    /// `bins(r) × bins(b)` slopes.
    pub table: Vec<f32>,
    /// `cells_y × cells_x` gains (of positive readings, and of negative ones when
    /// [`Self::gain_negative`] is empty).
    pub gain: Vec<f32>,
    /// `cells_y × cells_x` gains of negative readings; empty in model files written
    /// before gains had a sign (then [`Self::gain`] serves both).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gain_negative: Vec<f32>,
}

/// The position gains at every pixel of a frame, row by row: `[positive, negative]`
/// (readings ≥ 0 and < 0) side by side, so the hot loop reads one stream
/// ([`Lut::gain_planes`]; on the 13 mm disk the table's stage took 0.87 ms with two
/// separate planes, 0.66–0.73 with the pairs, 0.57–0.61 with one unsigned plane).
#[derive(Debug, Clone, PartialEq)]
pub struct GainPlanes(pub Vec<[f32; 2]>);

impl Lut {
    /// Fits a table of `bins × bins` colours and `cells_x × cells_y` gains.
    pub fn fit(
        samples: &[Sample],
        bins: usize,
        max_value: f32,
        cells_x: usize,
        cells_y: usize,
    ) -> Self {
        let mut lut = Self::averaged(samples, bins, max_value, cells_x, cells_y);
        lut.table = debias(&lut, samples);
        lut.fit_gains(samples);
        lut
    }

    /// The colour table as the mean slope of the samples around each entry, before
    /// [`debias`], with gain 1 everywhere.
    fn averaged(
        samples: &[Sample],
        bins: usize,
        max_value: f32,
        cells_x: usize,
        cells_y: usize,
    ) -> Self {
        let bins = bins.max(2);
        let (cells_x, cells_y) = (cells_x.max(1), cells_y.max(1));
        let mut sum = vec![0.0f32; bins * bins];
        let mut weight = vec![0.0f32; bins * bins];
        let scale = (bins - 1) as f32 / max_value;
        for s in samples {
            let (ir, fr) = locate(s.features[0] * scale, bins);
            let (ib, fb) = locate(s.features[1] * scale, bins);
            for (dr, wr) in [(0, 1.0 - fr), (1, fr)] {
                for (db, wb) in [(0, 1.0 - fb), (1, fb)] {
                    let entry = (ir + dr) * bins + ib + db;
                    sum[entry] += wr * wb * s.target;
                    weight[entry] += wr * wb;
                }
            }
        }
        Self {
            bins,
            max_value,
            cells_x,
            cells_y,
            table: fill_gaps(&sum, &weight, bins),
            gain: vec![1.0; cells_x * cells_y],
            gain_negative: Vec::new(),
        }
    }

    /// Fits the gains per cell and sign of the reading to the table as it stands.
    fn fit_gains(&mut self, samples: &[Sample]) {
        let cells = self.cells_x * self.cells_y;
        if cells <= 1 {
            return;
        }
        // Gain such that the gained table reads a slope `t` as `t` on average: least
        // squares of the table on the noise-free slope, `table ≈ t / gain`, so
        // `gain = Σ w t² / Σ w t · table`. (The other direction, the slope regressed on
        // the noisy table, shrinks the gain.) Sums per cell for positive readings,
        // negative ones, and both.
        let mut num = vec![[0.0f64; 3]; cells];
        let mut den = vec![[0.0f64; 3]; cells];
        for s in samples.iter().filter(|s| s.target.is_finite()) {
            let g = self.colour(s.features[0], s.features[1]) as f64;
            let t = s.target as f64;
            let sign = usize::from(g < 0.0);
            for (cell, w) in cell_weights(s.features[2], s.features[3], self.cells_x, self.cells_y)
            {
                let (w, n, d) = (w as f64, &mut num[cell], &mut den[cell]);
                for k in [sign, 2] {
                    n[k] += w * t * t;
                    d[k] += w * g * t;
                }
            }
        }
        // A cell with little slope signal of one sign takes the cell's gain of both
        // signs, and with little of either, 1.
        let floor = |k: usize| 0.02 * den.iter().map(|d| d[k]).sum::<f64>() / cells as f64;
        let floors = [floor(0), floor(1), floor(2)];
        let gain_of = |cell: usize, k: usize| {
            let (n, d) = (num[cell][k], den[cell][k]);
            (d > floors[k] && d > 0.0).then(|| ((n / d) as f32).clamp(0.5, 2.0))
        };
        let mut positive = vec![1.0; cells];
        let mut negative = vec![1.0; cells];
        for cell in 0..cells {
            let both = gain_of(cell, 2).unwrap_or(1.0);
            positive[cell] = gain_of(cell, 0).unwrap_or(both);
            negative[cell] = gain_of(cell, 1).unwrap_or(both);
        }
        self.gain = positive;
        self.gain_negative = negative;
    }

    /// The colour table alone, bilinear.
    #[inline]
    fn colour(&self, r: f32, b: f32) -> f32 {
        let bins = self.bins;
        let scale = (bins - 1) as f32 / self.max_value;
        let (ir, fr) = locate(r * scale, bins);
        let (ib, fb) = locate(b * scale, bins);
        let t = &self.table;
        let a = t[ir * bins + ib] * (1.0 - fb) + t[ir * bins + ib + 1] * fb;
        let c = t[(ir + 1) * bins + ib] * (1.0 - fb) + t[(ir + 1) * bins + ib + 1] * fb;
        a * (1.0 - fr) + c * fr
    }

    /// Slope for normalised colour `(r, b)` with a pixel's position gains `[positive,
    /// negative]` (one entry of [`Self::gain_planes`]); 0 for a damaged model file.
    #[inline]
    pub fn eval_with_gains(&self, r: f32, b: f32, gains: [f32; 2]) -> f32 {
        let Some(table) = self.checked_table() else {
            return 0.0;
        };
        self.gained_colour(table, r, b, gains)
    }

    /// Slope for normalised colour `(r, b)` at normalised position `(x, y)` ∈ [0, 1]².
    #[inline]
    pub fn eval(&self, r: f32, b: f32, x: f32, y: f32) -> f32 {
        let colour = self.colour(r, b);
        let Some([positive, negative]) = self.checked_gains() else {
            return 0.0;
        };
        let gains = if colour < 0.0 { negative } else { positive };
        colour * blended_gain(gains, x, y, self.cells_x, self.cells_y)
    }

    /// The gains of positive and of negative readings (`gain` for both when there is no
    /// `gain_negative`), `None` when either does not match the cells (a damaged model
    /// file): every evaluation then gives slope 0, whatever the reading's sign.
    #[inline]
    fn checked_gains(&self) -> Option<[&[f32]; 2]> {
        let cells = self.cells_x.max(1) * self.cells_y.max(1);
        let positive = self.gain.as_slice();
        let negative = match self.gain_negative.as_slice() {
            [] => positive,
            negative => negative,
        };
        if positive.len() != cells || negative.len() != cells {
            return None;
        }
        Some([positive, negative])
    }

    /// The gains [`Self::eval`] multiplies the colour's slope by at every pixel of a
    /// `width × height` frame, row by row, at the positions reconstruction gives the
    /// model (`x / width`, `y / height`): with them, [`Self::eval_planes`] skips the
    /// blend per pixel. `None` for a damaged table (see [`Self::eval_batch`]).
    pub fn gain_planes(&self, width: usize, height: usize) -> Option<GainPlanes> {
        let (cells_x, cells_y) = (self.cells_x.max(1), self.cells_y.max(1));
        let plane = |gains: &[f32]| {
            frame_plane(width, height, |x, y| {
                blended_gain(gains, x, y, cells_x, cells_y)
            })
        };
        let [positive, negative] = self.checked_gains()?;
        let positive = plane(positive);
        let negative = if self.gain_negative.is_empty() {
            positive.clone()
        } else {
            plane(negative)
        };
        Some(GainPlanes(
            positive
                .into_iter()
                .zip(negative)
                .map(|(p, n)| [p, n])
                .collect(),
        ))
    }
}

/// The table's size and range as its bilinear lookups use them ([`Lut::lookup`]).
struct Lookup {
    /// Entries per colour axis (at least 2).
    bins: usize,
    /// The last bin's position, `bins − 1`.
    top: f32,
    /// Colour to bin position: `top / max_value`.
    scale: f32,
    /// The last bin an entry's lower corner may be (`bins − 2`, or 0).
    last: i32,
}

/// The position gain at normalised position `(x, y)`, bilinear between cells (a single
/// cell's gain as it is).
#[inline]
fn blended_gain(gains: &[f32], x: f32, y: f32, cells_x: usize, cells_y: usize) -> f32 {
    if let [gain] = gains {
        return *gain;
    }
    cell_weights(x, y, cells_x, cells_y)
        .iter()
        .map(|&(cell, w)| gains[cell] * w)
        .sum()
}

impl Lut {
    /// [`Self::eval`] over feature rows `[r, b, x, y]`, with the table's constants
    /// hoisted out of the loop.
    pub fn eval_batch(&self, features: &[[f32; 4]], out: &mut [f32]) {
        let (cells_x, cells_y) = (self.cells_x.max(1), self.cells_y.max(1));
        let Some([positive, negative]) = self.checked_gains() else {
            // Gains that do not match the cells (a damaged model file): slope 0.
            out.iter_mut().for_each(|o| *o = 0.0);
            return;
        };
        self.eval_colours(features, out, |f, colour| {
            let gains = if colour < 0.0 { negative } else { positive };
            blended_gain(gains, f[2], f[3], cells_x, cells_y)
        });
    }

    /// [`Self::eval`] on colour planes: slope `i` from `(red[i], blue[i])` and its pixel's
    /// entry of [`Self::gain_planes`] (the same slopes, bit for bit, without the blend of
    /// the gains per pixel).
    pub fn eval_planes(&self, red: &[f32], blue: &[f32], gains: &[[f32; 2]], out: &mut [f32]) {
        let Some(table) = self.checked_table() else {
            out.iter_mut().for_each(|o| *o = 0.0);
            return;
        };
        let n = out.len().min(red.len()).min(blue.len()).min(gains.len());
        let (red, blue, gains, out) = (&red[..n], &blue[..n], &gains[..n], &mut out[..n]);
        #[allow(unused_mut)]
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if crate::cpu::avx2() && i32::try_from(table.len()).is_ok() {
            // SAFETY: `eval_planes_avx2` only needs AVX2, detected just above; its gathers
            // stay inside `table` (see there), whose length fits its i32 indices.
            #[allow(unsafe_code)]
            {
                done = unsafe { self.eval_planes_avx2(table, red, blue, gains, out) };
            }
        }
        for i in done..n {
            out[i] = self.gained_colour(table, red[i], blue[i], gains[i]);
        }
    }

    /// The colour table at `(r, b)` times the gain of its sign (`[positive, negative]`);
    /// `table` from [`Self::checked_table`].
    #[inline(always)]
    fn gained_colour(&self, table: &[f32], r: f32, b: f32, gains: [f32; 2]) -> f32 {
        let colour = self.table_colour(table, r, b);
        // Indexed rather than branched: on a flat contact the readings' signs are noise,
        // and a branch would be mispredicted on half of them.
        colour * gains[usize::from(colour < 0.0)]
    }

    /// [`Self::eval_planes`] eight pixels at a time in AVX2 lanes, the table's four
    /// entries around each pixel gathered: the same operations in the same order as
    /// [`Self::gained_colour`], so the same slopes. Returns how many pixels it did (the
    /// whole groups of eight); `red`, `blue`, `gains` and `out` are as long as each
    /// other and `table` is the checked table.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    fn eval_planes_avx2(
        &self,
        table: &[f32],
        red: &[f32],
        blue: &[f32],
        gains: &[[f32; 2]],
        out: &mut [f32],
    ) -> usize {
        use std::arch::x86_64::*;
        let n = out.len().min(red.len()).min(blue.len()).min(gains.len()) / 8 * 8;
        let Lookup {
            bins,
            top,
            scale,
            last,
        } = self.lookup();
        let scale = _mm256_set1_ps(scale);
        let (zero, one, top) = (
            _mm256_setzero_ps(),
            _mm256_set1_ps(1.0),
            _mm256_set1_ps(top),
        );
        let last = _mm256_set1_epi32(last);
        let stride = _mm256_set1_epi32(bins as i32);
        // As `table_colour`'s split: `max` first with the value as its first operand, so
        // NaN becomes 0 as `f32::max` makes it; then within [0, top], an exact conversion.
        let split = |v: __m256| {
            let v = _mm256_min_ps(_mm256_max_ps(v, zero), top);
            let i = _mm256_min_epi32(_mm256_cvttps_epi32(v), last);
            (i, _mm256_sub_ps(v, _mm256_cvtepi32_ps(i)))
        };
        let blend = |a: __m256, b: __m256, f: __m256| {
            _mm256_add_ps(_mm256_mul_ps(a, _mm256_sub_ps(one, f)), _mm256_mul_ps(b, f))
        };
        // `[a0 a2 a1 a3]` (64-bit halves) back to `[a0 a1 a2 a3]`.
        let in_order = |v: __m256| {
            _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)))
        };
        for k in (0..n).step_by(8) {
            // SAFETY: `k + 8 <= n` for every plane (gains are two floats a pixel); every
            // entry read (an index and the one after it) is at most `(bins − 2)·bins +
            // (bins − 2) + bins + 1 = bins² − 1`, inside the checked table (`bins²`
            // entries).
            unsafe {
                let r = _mm256_mul_ps(_mm256_loadu_ps(red.as_ptr().add(k)), scale);
                let b = _mm256_mul_ps(_mm256_loadu_ps(blue.as_ptr().add(k)), scale);
                let ((ir, fr), (ib, fb)) = (split(r), split(b));
                let row = _mm256_add_epi32(_mm256_mullo_epi32(ir, stride), ib);
                let below = _mm256_add_epi32(row, stride);
                // Each entry with its neighbour along blue in one 64-bit gather (half the
                // elements of gathering the two apart), split into the two again.
                let pairs = |i: __m256i| {
                    let base = table.as_ptr().cast::<i64>();
                    let low = _mm256_i32gather_epi64::<4>(base, _mm256_castsi256_si128(i));
                    let high = _mm256_i32gather_epi64::<4>(base, _mm256_extracti128_si256::<1>(i));
                    let (low, high) = (_mm256_castsi256_ps(low), _mm256_castsi256_ps(high));
                    (
                        in_order(_mm256_shuffle_ps::<0b10_00_10_00>(low, high)),
                        in_order(_mm256_shuffle_ps::<0b11_01_11_01>(low, high)),
                    )
                };
                let ((a, a_next), (c, c_next)) = (pairs(row), pairs(below));
                let upper = blend(a, a_next, fb);
                let lower = blend(c, c_next, fb);
                let colour = blend(upper, lower, fr);
                let g = gains.as_ptr().add(k).cast::<f32>();
                let (g0, g1) = (_mm256_loadu_ps(g), _mm256_loadu_ps(g.add(8)));
                let positive = in_order(_mm256_shuffle_ps::<0b10_00_10_00>(g0, g1));
                let negative = in_order(_mm256_shuffle_ps::<0b11_01_11_01>(g0, g1));
                let below_zero = _mm256_cmp_ps::<_CMP_LT_OQ>(colour, zero);
                let gain = _mm256_blendv_ps(positive, negative, below_zero);
                _mm256_storeu_ps(out.as_mut_ptr().add(k), _mm256_mul_ps(colour, gain));
            }
        }
        n
    }

    /// The table's largest reading and its most negative one, as magnitudes
    /// `[positive, negative]` (0 for a sign it never reads), before the position gains;
    /// `None` for a damaged model file.
    pub fn extremes(&self) -> Option<[f32; 2]> {
        let table = self.checked_table()?;
        let finite = table.iter().copied().filter(|v| v.is_finite());
        let most = finite.clone().fold(0.0f32, f32::max);
        let least = finite.fold(0.0f32, f32::min);
        Some([most, -least])
    }

    /// The table when it matches its size (`None` for a damaged model file).
    #[inline]
    fn checked_table(&self) -> Option<&[f32]> {
        let bins = self.bins.max(2);
        self.table.get(..bins * bins)
    }

    /// What the bilinear lookups need of the table's size and range (one place for
    /// the scalar and the vector lookups, which must read the same entries).
    #[inline(always)]
    fn lookup(&self) -> Lookup {
        let bins = self.bins.max(2);
        let top = (bins - 1) as f32;
        Lookup {
            bins,
            top,
            scale: top / self.max_value,
            last: (top as i32 - 1).max(0),
        }
    }

    /// The colour table at `(r, b)`, bilinear; `table` from [`Self::checked_table`].
    #[inline(always)]
    fn table_colour(&self, table: &[f32], r: f32, b: f32) -> f32 {
        let Lookup {
            bins,
            top,
            scale,
            last,
        } = self.lookup();
        // `f32::max` drops NaN, so NaN features land on the first entry like `locate`.
        // `v` is within [0, top] here, so the (cheaper) i32 conversion is exact.
        let split = |v: f32| {
            let v = v.max(0.0).min(top);
            let i = (v as i32).min(last);
            (i as usize, v - i as f32)
        };
        let (ir, fr) = split(r * scale);
        let (ib, fb) = split(b * scale);
        let row = ir * bins + ib;
        let a = table[row] * (1.0 - fb) + table[row + 1] * fb;
        let c = table[row + bins] * (1.0 - fb) + table[row + bins + 1] * fb;
        a * (1.0 - fr) + c * fr
    }

    /// The colour table, bilinear, times `gain(feature row)`.
    #[inline(always)]
    fn eval_colours(
        &self,
        features: &[[f32; 4]],
        out: &mut [f32],
        mut gain: impl FnMut(&[f32; 4], f32) -> f32,
    ) {
        let Some(table) = self.checked_table() else {
            // A table that does not match its size (a damaged model file): slope 0.
            out.iter_mut().for_each(|o| *o = 0.0);
            return;
        };
        for (f, o) in features.iter().zip(out.iter_mut()) {
            let colour = self.table_colour(table, f[0], f[1]);
            *o = colour * gain(f, colour);
        }
    }
}

/// The table's entries mapped through the inverse of its mean reading of each true
/// slope ([`ResponseCurve`]); unchanged when the samples give no curve.
fn debias(lut: &Lut, samples: &[Sample]) -> Vec<f32> {
    let readings = samples
        .iter()
        .map(|s| (s.target, lut.colour(s.features[0], s.features[1])));
    match ResponseCurve::fit(readings) {
        Some(curve) => lut.table.iter().map(|&v| curve.invert(v)).collect(),
        None => lut.table.clone(),
    }
}

/// Mean per entry where samples fell; elsewhere the mean of already-filled neighbours,
/// spreading outwards until the table is full. An empty table is all zero.
fn fill_gaps(sum: &[f32], weight: &[f32], bins: usize) -> Vec<f32> {
    const SEEN: f32 = 1e-3;
    let mut value: Vec<f32> = sum
        .iter()
        .zip(weight)
        .map(|(s, w)| if *w > SEEN { s / w } else { 0.0 })
        .collect();
    let mut known: Vec<bool> = weight.iter().map(|w| *w > SEEN).collect();
    if !known.iter().any(|&k| k) {
        return value;
    }
    while known.iter().any(|&k| !k) {
        let snapshot = known.clone();
        for i in 0..bins {
            for j in 0..bins {
                let e = i * bins + j;
                if snapshot[e] {
                    continue;
                }
                let mut acc = 0.0;
                let mut n = 0;
                for (di, dj) in [(-1i32, 0i32), (1, 0), (0, -1), (0, 1)] {
                    let (ni, nj) = (i as i32 + di, j as i32 + dj);
                    if ni < 0 || nj < 0 || ni >= bins as i32 || nj >= bins as i32 {
                        continue;
                    }
                    let ne = ni as usize * bins + nj as usize;
                    if snapshot[ne] {
                        acc += value[ne];
                        n += 1;
                    }
                }
                if n > 0 {
                    value[e] = acc / n as f32;
                    known[e] = true;
                }
            }
        }
    }
    value
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_read_as_one_pixel_at_a_time_in_every_lane_and_the_tail() {
        // A table with entries of both signs and a few extreme values, colours inside,
        // below and past its range, NaN and infinite, gains that differ by sign.
        let mut rng = crate::rng::Rng::new(31);
        for bins in [2usize, 3, 24, 61] {
            let lut = Lut {
                bins,
                max_value: 2.5,
                cells_x: 1,
                cells_y: 1,
                table: (0..bins * bins)
                    .map(|_| rng.range(-2.0, 2.0) as f32)
                    .collect(),
                gain: vec![1.0],
                gain_negative: Vec::new(),
            };
            let table = lut.checked_table().expect("a whole table");
            for n in [0usize, 1, 7, 8, 9, 16, 100] {
                let mut pick = |k: usize| match k % 13 {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => -0.5,
                    3 => 3.7,
                    4 => 0.0,
                    5 => 2.5,
                    _ => rng.range(0.0, 2.6) as f32,
                };
                let red: Vec<f32> = (0..n).map(&mut pick).collect();
                let blue: Vec<f32> = (0..n).map(|k| pick(k + 5)).collect();
                let gains: Vec<[f32; 2]> = (0..n)
                    .map(|k| [1.0 + k as f32 * 0.01, 0.5 + k as f32 * 0.02])
                    .collect();
                let mut out = vec![f32::NAN; n];
                lut.eval_planes(&red, &blue, &gains, &mut out);
                for k in 0..n {
                    let want = lut.gained_colour(table, red[k], blue[k], gains[k]);
                    assert_eq!(
                        out[k].to_bits(),
                        want.to_bits(),
                        "{bins} bins, {n} pixels, pixel {k} ({}, {}): {} vs {want}",
                        red[k],
                        blue[k],
                        out[k]
                    );
                }
            }
        }
    }

    #[test]
    fn batch_evaluation_equals_one_by_one_including_nan_and_out_of_range() {
        let samples: Vec<Sample> = (0..4000)
            .map(|i| {
                let (a, b) = ((i as f32 * 0.618).fract(), (i as f32 * 0.377).fract());
                Sample {
                    features: [0.3 + 1.4 * a, 0.3 + 1.4 * b, a, b],
                    target: (a - b) * (1.0 + a),
                }
            })
            .collect();
        for cells in [(1, 1), (4, 3)] {
            let lut = Lut::fit(&samples, 24, 2.5, cells.0, cells.1);
            let mut features: Vec<[f32; 4]> = samples.iter().map(|s| s.features).collect();
            features.extend([
                [f32::NAN, 1.0, 0.5, 0.5],
                [1.0, f32::NAN, f32::NAN, 0.5],
                [-3.0, 9.0, 1.5, -0.2],
                [f32::INFINITY, f32::NEG_INFINITY, 0.0, 1.0],
            ]);
            let mut batch = vec![0.0; features.len()];
            lut.eval_batch(&features, &mut batch);
            for (f, got) in features.iter().zip(&batch) {
                let want = lut.eval(f[0], f[1], f[2], f[3]);
                assert_eq!(got.to_bits(), want.to_bits(), "{f:?}: {got} vs {want}");
            }
        }
        // A damaged table gives slope 0, never an index out of bounds.
        let mut broken = Lut::fit(&samples, 24, 2.5, 4, 3);
        broken.table.truncate(10);
        let mut out = vec![1.0; 3];
        broken.eval_batch(&[[1.0, 1.0, 0.5, 0.5]; 3], &mut out);
        assert_eq!(out, [0.0; 3]);
    }

    #[test]
    fn learns_a_smooth_function_and_saturates_outside_the_data() {
        // slope = (r − b) / (r + b) · 1.7, sampled on a grid of colours in [0.3, 1.7].
        let f = |r: f32, b: f32| 1.7 * (r - b) / (r + b);
        let mut samples = Vec::new();
        for i in 0..=140 {
            for j in 0..=140 {
                let (r, b) = (0.3 + i as f32 * 0.01, 0.3 + j as f32 * 0.01);
                samples.push(Sample {
                    features: [r, b, (i % 7) as f32 / 7.0, (j % 5) as f32 / 5.0],
                    target: f(r, b),
                });
            }
        }
        let lut = Lut::fit(&samples, 64, 3.0, 2, 2);
        let mut worst = 0.0f32;
        for (r, b) in [(0.5, 0.9), (1.0, 1.0), (1.6, 0.4), (0.77, 1.31)] {
            worst = worst.max((lut.eval(r, b, 0.4, 0.6) - f(r, b)).abs());
        }
        assert!(worst < 0.01, "max error {worst}");
        // Beyond the data (r = 2.5) the value stays near the edge of the data.
        let far = lut.eval(2.5, 0.3, 0.5, 0.5);
        assert!((far - f(1.7, 0.3)).abs() < 0.05, "{far}");
        assert!(lut.eval(f32::NAN, 1.0, 0.5, 0.5).is_finite());
    }

    /// Samples of a ball-like slope distribution (slopes up to `max_slope`, most of them
    /// gentle, few near the top) whose colours answer `1 ± a·t` with noise of `sigma`,
    /// `a` going linearly from `response[0]` at the left edge of the frame to
    /// `response[1]` at the right.
    fn noisy_ball(
        count: usize,
        max_slope: f64,
        response: [f64; 2],
        sigma: f64,
        seed: u64,
    ) -> Vec<Sample> {
        let mut rng = crate::rng::Rng::new(seed);
        let rho_max = max_slope / (1.0 + max_slope * max_slope).sqrt();
        (0..count)
            .map(|_| {
                // ρ uniform over a disk (unit sphere): t = ρ / √(1 − ρ²).
                let rho = rho_max * rng.uniform().sqrt();
                let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
                let t = sign * rho / (1.0 - rho * rho).sqrt();
                let (x, y) = (rng.uniform(), rng.uniform());
                let a = response[0] + (response[1] - response[0]) * x;
                let r = 1.0 + a * t + sigma * rng.gaussian();
                let b = 1.0 - a * t + sigma * rng.gaussian();
                Sample {
                    features: [r as f32, b as f32, x as f32, y as f32],
                    target: t as f32,
                }
            })
            .collect()
    }

    /// Mean reading of fresh noisy samples whose true slope lies in `lo..hi` and whose
    /// x lies in `xs`, over their true mean: 1 when unbiased.
    fn reading_ratio(
        lut: &Lut,
        samples: &[Sample],
        lo: f32,
        hi: f32,
        xs: std::ops::Range<f32>,
    ) -> f32 {
        let (mut read, mut truth) = (0.0, 0.0);
        for s in samples
            .iter()
            .filter(|s| s.target.abs() >= lo && s.target.abs() < hi && xs.contains(&s.features[2]))
        {
            let f = s.features;
            read += lut.eval(f[0], f[1], f[2], f[3]) * s.target.signum();
            truth += s.target.abs();
        }
        read / truth
    }

    #[test]
    fn steep_slopes_are_not_read_short_from_noisy_colours() {
        // The analytic answer is the slope itself. With colour noise 0.08 against a
        // response of 0.5 per unit slope, the plain mean per colour reads slopes near the
        // top of the ball's range short; the debiased table must not.
        let train = noisy_ball(200_000, 0.9, [0.5, 0.5], 0.08, 1);
        let test = noisy_ball(200_000, 0.9, [0.5, 0.5], 0.08, 2);
        let plain = Lut::averaged(&train, 48, 4.0, 1, 1);
        let lut = Lut::fit(&train, 48, 4.0, 1, 1);
        let short = reading_ratio(&plain, &test, 0.7, 0.85, 0.0..1.0);
        let top = reading_ratio(&lut, &test, 0.7, 0.85, 0.0..1.0);
        let middle = reading_ratio(&lut, &test, 0.3, 0.6, 0.0..1.0);
        // The plain table must be measurably short for the test to mean anything.
        assert!(short < 0.95, "the plain table reads {short} of the slope");
        assert!(
            (top - 1.0).abs() < 0.03,
            "steep slopes read {top} of the truth"
        );
        assert!(
            (middle - 1.0).abs() < 0.03,
            "gentle slopes read {middle} of the truth"
        );
    }

    #[test]
    fn the_position_gain_reads_each_part_of_the_frame_to_scale() {
        // The colours answer 0.6 per unit slope at the left edge and 0.4 at the right
        // (the light's elevation changes across the frame); near each cell's centre the
        // gains must bring the reading to the true slope.
        let train = noisy_ball(200_000, 0.9, [0.6, 0.4], 0.05, 3);
        let test = noisy_ball(200_000, 0.9, [0.6, 0.4], 0.05, 4);
        let lut = Lut::fit(&train, 48, 4.0, 4, 1);
        let mut flat = lut.clone();
        flat.gain = vec![1.0; 4];
        flat.gain_negative.clear();
        for centre in [0.125f32, 0.375, 0.625, 0.875] {
            let xs = centre - 0.05..centre + 0.05;
            let middle = reading_ratio(&lut, &test, 0.2, 0.6, xs.clone());
            let top = reading_ratio(&lut, &test, 0.6, 0.85, xs.clone());
            assert!(
                (middle - 1.0).abs() < 0.04,
                "x {centre}: gentle slopes read {middle}"
            );
            assert!(
                (top - 1.0).abs() < 0.04,
                "x {centre}: steep slopes read {top}"
            );
            // Without the gains the frame's sides read off: the gains carry the test.
            if centre == 0.125 || centre == 0.875 {
                let ungained = reading_ratio(&flat, &test, 0.2, 0.6, xs);
                assert!(
                    (ungained - 1.0).abs() > 0.08,
                    "x {centre}: {ungained} without gains"
                );
            }
        }
    }

    #[test]
    fn slopes_facing_either_strip_read_to_scale_across_the_frame() {
        // Slopes facing one strip answer 0.65 per unit at the left edge and 0.35 at the
        // right; those facing the other strip the reverse (each strip's light is steep
        // near it). Over the frame both average 0.5, so a gain per cell alone cannot
        // tell them apart: the gain per sign must.
        let asymmetric = |seed: u64| -> Vec<Sample> {
            let mut rng = crate::rng::Rng::new(seed);
            (0..200_000)
                .map(|_| {
                    let t = rng.range(-0.8, 0.8);
                    let x = rng.uniform();
                    let a = if t >= 0.0 {
                        0.65 - 0.3 * x
                    } else {
                        0.35 + 0.3 * x
                    };
                    let r = 1.0 + a * t + 0.03 * rng.gaussian();
                    let b = 1.0 - a * t + 0.03 * rng.gaussian();
                    Sample {
                        features: [r as f32, b as f32, x as f32, rng.uniform() as f32],
                        target: t as f32,
                    }
                })
                .collect()
        };
        let (train, test) = (asymmetric(7), asymmetric(8));
        let lut = Lut::fit(&train, 48, 4.0, 4, 1);
        assert_eq!(lut.gain_negative.len(), 4);
        let ratio = |lut: &Lut, positive: bool, xs: std::ops::Range<f32>| {
            let (mut read, mut truth) = (0.0, 0.0);
            for s in test.iter().filter(|s| {
                (s.target > 0.2) == positive
                    && (s.target < -0.2) != positive
                    && xs.contains(&s.features[2])
            }) {
                let f = s.features;
                read += lut.eval(f[0], f[1], f[2], f[3]);
                truth += s.target;
            }
            read / truth
        };
        let mut unsigned = lut.clone();
        unsigned.gain_negative.clear();
        for centre in [0.125f32, 0.875] {
            let xs = centre - 0.05..centre + 0.05;
            for positive in [true, false] {
                let got = ratio(&lut, positive, xs.clone());
                assert!(
                    (got - 1.0).abs() < 0.05,
                    "x {centre}, positive {positive}: {got}"
                );
            }
            // One gain for both signs reads one of them off by far more.
            let off =
                [true, false].map(|positive| (ratio(&unsigned, positive, xs.clone()) - 1.0).abs());
            assert!(
                off[0].max(off[1]) > 0.15,
                "x {centre}: {off:?} with one gain"
            );
        }
        // The gain planes give the same slopes as the blend per pixel, both signs.
        let planes = lut.gain_planes(64, 8).expect("a whole table");
        let (red, blue): (Vec<f32>, Vec<f32>) = (0..64)
            .map(|x| {
                let t = if x % 2 == 0 { 0.5 } else { -0.5 };
                (1.0 + 0.5 * t, 1.0 - 0.5 * t)
            })
            .unzip();
        let row = 3;
        let span = row * 64..(row + 1) * 64;
        let mut out = vec![0.0; 64];
        lut.eval_planes(&red, &blue, &planes.0[span], &mut out);
        for (x, got) in out.iter().enumerate() {
            let want = lut.eval(red[x], blue[x], x as f32 / 64.0, row as f32 / 8.0);
            assert_eq!(got.to_bits(), want.to_bits(), "x {x}: {got} vs {want}");
        }
        // An older model file (no negative gains) reads both signs with `gain`.
        let planes = unsigned.gain_planes(64, 8).expect("a whole table");
        assert!(planes.0.iter().all(|[p, n]| p == n));
        // Negative gains that do not match the cells: slope 0, never a panic.
        let mut broken = lut.clone();
        broken.gain_negative.truncate(2);
        assert!(broken.gain_planes(8, 8).is_none());
        // Readings of both signs (r > b reads positive here), one by one and in a batch.
        let rows = [[0.8, 1.2, 0.5, 0.5], [1.2, 0.8, 0.5, 0.5]];
        assert!(lut.eval(1.2, 0.8, 0.5, 0.5) > 0.1 && lut.eval(0.8, 1.2, 0.5, 0.5) < -0.1);
        let mut out = vec![1.0; 2];
        broken.eval_batch(&rows, &mut out);
        assert_eq!(out, [0.0; 2]);
        for f in rows {
            assert_eq!(broken.eval(f[0], f[1], f[2], f[3]), 0.0);
        }
    }

    #[test]
    fn degenerate_training_sets_leave_the_table_as_averaged() {
        // One slope only, non-finite slopes, huge slopes: no panic, finite tables.
        let one: Vec<Sample> = (0..100)
            .map(|i| Sample {
                features: [1.0 + i as f32 * 1e-3, 1.0, 0.5, 0.5],
                target: 0.4,
            })
            .collect();
        let lut = Lut::fit(&one, 16, 4.0, 2, 2);
        assert_eq!(lut.table, Lut::averaged(&one, 16, 4.0, 2, 2).table);
        assert!((lut.eval(1.05, 1.0, 0.5, 0.5) - 0.4).abs() < 1e-5);
        let mut wild = one.clone();
        wild.extend([
            Sample {
                features: [2.0, 0.5, 0.1, 0.1],
                target: f32::NAN,
            },
            Sample {
                features: [2.0, 0.5, 0.9, 0.9],
                target: f32::INFINITY,
            },
            Sample {
                features: [0.5, 2.0, 0.9, 0.1],
                target: -3.0e38,
            },
            Sample {
                features: [0.5, 2.0, 0.1, 0.9],
                target: 3.0e38,
            },
        ]);
        let lut = Lut::fit(&wild, 16, 4.0, 2, 2);
        assert!(lut.gain.iter().all(|g| g.is_finite()), "{:?}", lut.gain);
        assert!(
            lut.gain_negative.iter().all(|g| g.is_finite()),
            "{:?}",
            lut.gain_negative
        );
        assert!(lut.eval(1.05, 1.0, 0.5, 0.5).is_finite());
    }

    #[test]
    fn an_empty_training_set_gives_zero_slopes() {
        let lut = Lut::fit(&[], 8, 3.0, 1, 1);
        assert_eq!(lut.eval(1.2, 0.8, 0.5, 0.5), 0.0);
    }
}
