//! A fitted model's mean reading of each true slope, and its inverse.
//!
//! A model fitted by least squares (the lookup table's mean per colour, the MLP) reads
//! `E[slope | colour]`. With noisy colours that is short of the slope near the top of
//! the slopes the calibration ball made, where the gentler samples whose noise lands on
//! the same colour far outnumber the steep ones (regression dilution). The other
//! direction is not diluted, because the true slope has no noise: `m(t) = E[reading |
//! slope t]`, measured on the training samples, made non-decreasing, and inverted. A
//! reading `v` then becomes `m⁻¹(v)`: on average each slope reads as itself, up to a
//! bounded stretch ([`MAX_STRETCH`]) where the model saturates.

use serde::{Deserialize, Serialize};

/// Width of the slope bins the response is measured in.
const BIN: f32 = 0.05;
/// Fewest samples behind one point (sparse bins are merged towards the middle).
const MIN_SAMPLES: f64 = 30.0;
/// Most bins: wider ones when the slopes span more.
const MAX_BINS: f32 = 4096.0;
/// Steepest `m⁻¹` may be: where a model's reading barely changes with the slope (it
/// saturates near the top of the calibrated slopes), inverting it exactly would turn a
/// little colour noise into a large slope. Chosen on the tuning families (caps 2, 4 and
/// none tried with the table and the MLP; 2 gave the smallest spread over placements
/// and, with the MLP, the smallest error).
const MAX_STRETCH: f32 = 2.0;

/// `m(t)` as points `[reading, slope]`, readings strictly increasing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResponseCurve {
    /// `[mean reading, mean true slope]` of each group of samples.
    pub points: Vec<[f32; 2]>,
}

impl ResponseCurve {
    /// Measures the response from `(true slope, reading)` pairs; non-finite pairs are
    /// skipped. `None` when fewer than two points remain (too few samples, or every
    /// slope alike): the model's readings then stand as they are.
    pub fn fit(pairs: impl IntoIterator<Item = (f32, f32)>) -> Option<Self> {
        let pairs: Vec<(f32, f32)> = pairs
            .into_iter()
            .filter(|(t, v)| t.is_finite() && v.is_finite())
            .collect();
        let lo = pairs.iter().map(|p| p.0).fold(f32::INFINITY, f32::min);
        let hi = pairs.iter().map(|p| p.0).fold(f32::NEG_INFINITY, f32::max);
        if !(hi - lo).is_finite() || hi - lo < 2.0 * BIN {
            return None;
        }
        let width = BIN.max((hi - lo) / MAX_BINS);
        let n = ((hi - lo) / width).ceil() as usize + 1;
        // (Σ slope, Σ reading, count) per bin.
        let mut bins = vec![(0.0f64, 0.0f64, 0.0f64); n];
        for &(t, v) in &pairs {
            let k = (((t - lo) / width) as usize).min(n - 1);
            bins[k].0 += t as f64;
            bins[k].1 += v as f64;
            bins[k].2 += 1.0;
        }
        let add = |a: (f64, f64, f64), b: (f64, f64, f64)| (a.0 + b.0, a.1 + b.1, a.2 + b.2);
        let mut groups: Vec<(f64, f64, f64)> = Vec::new();
        let mut pending = (0.0, 0.0, 0.0);
        for &b in &bins {
            pending = add(pending, b);
            if pending.2 >= MIN_SAMPLES {
                groups.push(pending);
                pending = (0.0, 0.0, 0.0);
            }
        }
        if pending.2 > 0.0
            && let Some(last) = groups.last_mut()
        {
            *last = add(*last, pending);
        }
        // Non-decreasing by pooling adjacent violators (sums pool exactly); equal
        // readings pool too, so the readings end strictly increasing.
        let mut pool: Vec<(f64, f64, f64)> = Vec::new();
        for g in groups {
            let mut cur = g;
            while let Some(&prev) = pool.last() {
                if prev.1 / prev.2 < cur.1 / cur.2 {
                    break;
                }
                pool.pop();
                cur = add(prev, cur);
            }
            pool.push(cur);
        }
        let points: Vec<[f32; 2]> = pool
            .iter()
            .map(|g| [(g.1 / g.2) as f32, (g.0 / g.2) as f32])
            .collect();
        // Rounding to f32 may merge two readings: keep the curve strictly increasing.
        let mut strict: Vec<[f32; 2]> = Vec::with_capacity(points.len());
        for p in points {
            if strict.last().is_none_or(|l| p[0] > l[0]) {
                strict.push(p);
            }
        }
        if strict.len() < 2 {
            return None;
        }
        limit_stretch(&mut strict);
        Some(Self { points: strict })
    }

    /// The slope whose mean reading is `v`: linear between points; beyond them the
    /// differences are kept as they are (slope 1), so a model that saturates past the
    /// calibrated slopes still saturates, only no longer short of them. NaN stays NaN.
    #[inline]
    pub fn invert(&self, v: f32) -> f32 {
        let p = &self.points;
        let (first, last) = (p[0], p[p.len() - 1]);
        if v <= first[0] {
            return first[1] + (v - first[0]);
        }
        if v >= last[0] {
            return last[1] + (v - last[0]);
        }
        let k = p.partition_point(|q| q[0] <= v).clamp(1, p.len() - 1);
        let (a, b) = (p[k - 1], p[k]);
        a[1] + (v - a[0]) * (b[1] - a[1]) / (b[0] - a[0])
    }
}

/// Bounds the curve's slope `Δt/Δv` to [`MAX_STRETCH`], working outwards from the
/// point nearest slope 0 (which keeps its place), so gentle slopes read as measured and
/// the steepest are stretched at most that much.
fn limit_stretch(points: &mut [[f32; 2]]) {
    let anchor = points
        .iter()
        .enumerate()
        .min_by(|a, b| a.1[1].abs().total_cmp(&b.1[1].abs()))
        .map_or(0, |(i, _)| i);
    let measured = points.to_vec();
    for k in anchor + 1..points.len() {
        let dt = measured[k][1] - measured[k - 1][1];
        let dv = measured[k][0] - measured[k - 1][0];
        points[k][1] = points[k - 1][1] + dt.min(MAX_STRETCH * dv);
    }
    for k in (0..anchor).rev() {
        let dt = measured[k + 1][1] - measured[k][1];
        let dv = measured[k + 1][0] - measured[k][0];
        points[k][1] = points[k + 1][1] - dt.min(MAX_STRETCH * dv);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scaled_response_is_undone_exactly() {
        // Readings 0.8·t: the inverse gives t back between the points, and keeps
        // differences beyond them.
        let pairs = (0..2000).map(|i| {
            let t = -1.0 + i as f32 * 1e-3;
            (t, 0.8 * t)
        });
        let c = ResponseCurve::fit(pairs).unwrap();
        for t in [-0.9f32, -0.3, 0.0, 0.42, 0.9] {
            assert!(
                (c.invert(0.8 * t) - t).abs() < 2e-3,
                "{t}: {}",
                c.invert(0.8 * t)
            );
        }
        let top = c.points.last().unwrap();
        assert!((c.invert(top[0] + 0.5) - (top[1] + 0.5)).abs() < 1e-5);
        assert!(c.invert(f32::NAN).is_nan());
    }

    #[test]
    fn a_saturating_response_is_stretched_at_most_max_stretch() {
        // Readings follow the slope up to 0.6 and then flatten (0.1 per unit slope): the
        // exact inverse would stretch tenfold there; it stretches MAX_STRETCH-fold.
        let m = |t: f32| if t <= 0.6 { t } else { 0.6 + 0.1 * (t - 0.6) };
        let c = ResponseCurve::fit((0..2000).map(|i| {
            let t = i as f32 * 5e-4;
            (t, m(t))
        }))
        .unwrap();
        assert!((c.invert(0.3) - 0.3).abs() < 2e-3, "{}", c.invert(0.3));
        let top = m(0.95);
        let got = c.invert(top) - c.invert(0.6);
        assert!((got - MAX_STRETCH * (top - 0.6)).abs() < 5e-3, "{got}");
        for w in c.points.windows(2) {
            let stretch = (w[1][1] - w[0][1]) / (w[1][0] - w[0][0]);
            assert!(
                stretch <= MAX_STRETCH * 1.0001 && stretch > 0.0,
                "{stretch}"
            );
        }
    }

    #[test]
    fn non_monotone_and_degenerate_responses() {
        // A response that dips is pooled into a non-decreasing one.
        let pairs = (0..3000).map(|i| {
            let t = i as f32 * 1e-3;
            (t, t + 0.3 * (t * 9.0).sin())
        });
        let c = ResponseCurve::fit(pairs).unwrap();
        assert!(
            c.points
                .windows(2)
                .all(|w| w[1][0] > w[0][0] && w[1][1] > w[0][1])
        );
        // One slope, too few samples, non-finite values: no curve, no panic.
        assert!(ResponseCurve::fit((0..500).map(|_| (0.4, 0.3))).is_none());
        assert!(ResponseCurve::fit((0..20).map(|i| (i as f32 * 0.1, i as f32))).is_none());
        assert!(ResponseCurve::fit([(f32::NAN, 1.0), (1.0, f32::INFINITY)]).is_none());
        let huge = (0..100).map(|i| (if i % 2 == 0 { -3e38 } else { 3e38 }, i as f32));
        assert!(ResponseCurve::fit(huge).is_none());
    }
}
