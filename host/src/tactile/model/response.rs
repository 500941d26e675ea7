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
/// Fewest samples behind one point: a sparse bin joins the next one up, and sparse
/// bins left at the top join the last point.
const MIN_SAMPLES: f64 = 30.0;
/// Most points a curve has (bins are wider when the slopes span more); a model file's
/// curve is refused beyond it ([`ResponseCurve::check`]).
pub const MAX_POINTS: usize = 1024;
/// Largest magnitude of a point's reading or slope a model file may hold.
const MAX_VALUE: f32 = 1.0e4;
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
            .filter(|(t, v)| t.abs() <= MAX_VALUE && v.abs() <= MAX_VALUE)
            .collect();
        let lo = pairs.iter().map(|p| p.0).fold(f32::INFINITY, f32::min);
        let hi = pairs.iter().map(|p| p.0).fold(f32::NEG_INFINITY, f32::max);
        if !(hi - lo).is_finite() || hi - lo < 2.0 * BIN {
            return None;
        }
        let width = BIN.max((hi - lo) / (MAX_POINTS - 2) as f32);
        let n = (((hi - lo) / width).ceil() as usize + 1).min(MAX_POINTS);
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
        // In f32 a stretch-limited step may vanish: keep the slopes strictly increasing.
        strict.dedup_by(|b, a| b[1] <= a[1]);
        (strict.len() >= 2).then_some(Self { points: strict })
    }

    /// The slope whose mean reading is `v`: linear between points; beyond them the
    /// differences are kept as they are (slope 1), so a model that saturates past the
    /// calibrated slopes still saturates, only no longer short of them. NaN stays NaN.
    /// A curve [`Self::check`] refuses (fewer than two points) leaves `v` as it is.
    #[inline]
    pub fn invert(&self, v: f32) -> f32 {
        let p = &self.points;
        if p.len() < 2 {
            return v;
        }
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

impl ResponseCurve {
    /// Why a curve read from a file cannot be used: a point count outside
    /// `2..=MAX_POINTS`, values that are not finite or beyond ±[`MAX_VALUE`], readings or
    /// slopes that do not increase strictly.
    pub fn check(&self) -> Result<(), String> {
        let p = &self.points;
        if !(2..=MAX_POINTS).contains(&p.len()) {
            return Err(format!("{} points, expected 2..={MAX_POINTS}", p.len()));
        }
        if p.iter()
            .flatten()
            .any(|v| !v.is_finite() || v.abs() > MAX_VALUE)
        {
            return Err(format!(
                "holds a value that is not finite or beyond ±{MAX_VALUE}"
            ));
        }
        if p.windows(2)
            .any(|w| w[1][0] <= w[0][0] || w[1][1] <= w[0][1])
        {
            return Err("readings and slopes must both increase strictly".into());
        }
        Ok(())
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
        c.check().unwrap();
        // One slope, too few samples, non-finite values: no curve, no panic.
        assert!(ResponseCurve::fit((0..500).map(|_| (0.4, 0.3))).is_none());
        assert!(ResponseCurve::fit((0..20).map(|i| (i as f32 * 0.1, i as f32))).is_none());
        assert!(ResponseCurve::fit([(f32::NAN, 1.0), (1.0, f32::INFINITY)]).is_none());
        let huge = (0..100).map(|i| (if i % 2 == 0 { -3e38 } else { 3e38 }, i as f32));
        assert!(ResponseCurve::fit(huge).is_none());
        // A wide spread of slopes stays within the points a model file may hold.
        let wide = ResponseCurve::fit((0..200_000).map(|i| {
            let t = -500.0 + i as f32 * 5e-3;
            (t, t)
        }))
        .unwrap();
        assert!(wide.points.len() <= MAX_POINTS);
        wide.check().unwrap();
        // A curve no fit makes (as a hand-edited file might hold) never panics.
        for points in [vec![], vec![[0.5, 0.5]]] {
            let c = ResponseCurve { points };
            assert!(c.check().is_err());
            assert_eq!(c.invert(0.25), 0.25);
            assert!(c.invert(f32::NAN).is_nan());
        }
    }
}
