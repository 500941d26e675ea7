//! Finding a ball press's contact circle: the outline of the touched region, fitted by
//! least squares with outliers dropped, then checked against the ball.
//!
//! The touched region is where the colour departs from flat skin by more than the
//! calibration's contact threshold; the largest connected region is kept and its holes
//! filled, so specks of noise and a dark centre do not matter. Outline pixels on the
//! frame's border are not part of the circle (a press cut by the border is still found).
//! The algebraic fit is repeated three times, each time keeping the outline pixels within
//! 2.5 robust standard deviations (at least 1.5 px) of the last circle.

use serde::{Deserialize, Serialize};

use crate::tactile::contact;

/// A fitted (or given) contact circle, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Circle {
    /// Centre column.
    pub cx: f64,
    /// Centre row.
    pub cy: f64,
    /// Radius.
    pub r: f64,
}

/// Why a file of given circles (`calibrate --overrides`) was refused.
#[derive(Debug, thiserror::Error)]
pub enum OverridesError {
    /// Not JSON of the expected shape (a field misspelt or extra, a value not a number).
    #[error("not {{\"NAME\": {{\"cx\": px, \"cy\": px, \"r\": px}}, ...}}: {0}")]
    Shape(serde_json::Error),
    /// A press named twice: which circle was meant is not guessed.
    #[error("{0:?} is given twice: give each press one circle")]
    Twice(String),
}

/// The circles of an overrides file, `{"NAME": {"cx": px, "cy": px, "r": px}, ...}`: a
/// name given twice or a field other than the three is refused (a JSON reader would keep
/// the last circle, or drop the field, without a word). Whether each circle fits the
/// frames is checked by [`super::calibrate`].
pub fn read_overrides(
    bytes: &[u8],
) -> Result<std::collections::HashMap<String, Circle>, OverridesError> {
    /// A circle as given: exactly its three fields.
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Given {
        cx: f64,
        cy: f64,
        r: f64,
    }
    /// The entries in the file's order, repeats kept.
    struct Entries(Vec<(String, Given)>);
    impl<'de> Deserialize<'de> for Entries {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct Visit;
            impl<'de> serde::de::Visitor<'de> for Visit {
                type Value = Entries;
                fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                    f.write_str("an object of press names")
                }
                fn visit_map<A: serde::de::MapAccess<'de>>(
                    self,
                    mut map: A,
                ) -> Result<Entries, A::Error> {
                    let mut out = Vec::new();
                    while let Some(entry) = map.next_entry::<String, Given>()? {
                        out.push(entry);
                    }
                    Ok(Entries(out))
                }
            }
            d.deserialize_map(Visit)
        }
    }
    let Entries(entries) = serde_json::from_slice(bytes).map_err(OverridesError::Shape)?;
    let mut out = std::collections::HashMap::with_capacity(entries.len());
    for (name, Given { cx, cy, r }) in entries {
        if out.insert(name.clone(), Circle { cx, cy, r }).is_some() {
            return Err(OverridesError::Twice(name));
        }
    }
    Ok(out)
}

/// Why a given circle cannot be a press in a `width × height` frame, if it cannot: not
/// finite, a radius not above 0, or not overlapping the frame (a press centred on the
/// border has its centre at the border, or just past it).
pub fn given_circle_unfit(c: &Circle, width: usize, height: usize) -> Option<&'static str> {
    let (w, h) = (width as f64, height as f64);
    if !(c.cx.is_finite() && c.cy.is_finite() && c.r.is_finite()) {
        Some("is not three finite numbers")
    } else if c.r <= 0.0 {
        Some("has no radius")
    } else if c.cx <= -c.r || c.cx >= w + c.r || c.cy <= -c.r || c.cy >= h + c.r {
        Some("lies outside the frame")
    } else {
        None
    }
}

/// A circle fitted to an outline, with how well it fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutlineFit {
    /// The circle (radius at the rim, half a pixel outside the outermost touched pixels).
    pub circle: Circle,
    /// RMS distance of the inlier outline pixels from the circle (px).
    pub rms_px: f64,
    /// Fraction of the outline pixels kept as inliers.
    pub inlier_fraction: f64,
    /// Outline pixels found.
    pub outline_px: usize,
}

impl OutlineFit {
    /// Whether the outline is a circle: its inliers within 6 % of the radius (at least
    /// 1.5 px) and at least 60 % of it inliers. Two contacts, a sliding ball or a shape
    /// that is not a ball fail it.
    pub fn is_round(&self) -> bool {
        self.rms_px <= (0.06 * self.circle.r).max(1.5) && self.inlier_fraction >= 0.6
    }
}

/// Fits the contact circle of a touched-pixel mask (`w × h`, consumed); `None` when
/// there is no usable outline. Outline pixels next to an `unknown` pixel (one the colour
/// filter rejected: saturated, too dark) are left out: the outline there is where the
/// measurement stops, not where the contact does.
pub fn fit_outline(
    mut mask: Vec<bool>,
    unknown: Option<&[bool]>,
    w: usize,
    h: usize,
) -> Option<OutlineFit> {
    if w < 3 || h < 3 || mask.len() != w * h || unknown.is_some_and(|u| u.len() != w * h) {
        return None;
    }
    let unknown_at = |i: usize| unknown.is_some_and(|u| u[i]);
    keep_largest_component(&mut mask, w, h);
    contact::fill_holes(&mut mask, w, h);
    let mut points = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let i = y * w + x;
            let neighbours = [i - 1, i + 1, i - w, i + w];
            if mask[i]
                && neighbours.iter().any(|&j| !mask[j])
                && !neighbours.iter().any(|&j| unknown_at(j))
            {
                points.push((x as f64, y as f64));
            }
        }
    }
    if points.len() < 8 {
        return None;
    }
    let mut circle = fit_circle(&points)?;
    let mut inliers = points.clone();
    for _ in 0..3 {
        let residuals: Vec<f64> = points.iter().map(|&p| residual(&circle, p)).collect();
        let mut abs: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
        abs.sort_by(f64::total_cmp);
        let mad = abs[abs.len() / 2];
        let band = (2.5 * 1.4826 * mad).max(1.5);
        let kept: Vec<(f64, f64)> = points
            .iter()
            .zip(&residuals)
            .filter(|(_, r)| r.abs() <= band)
            .map(|(p, _)| *p)
            .collect();
        if kept.len() < 8 {
            break;
        }
        match fit_circle(&kept) {
            Some(c) => {
                circle = c;
                inliers = kept;
            }
            None => break,
        }
    }
    let rms = (inliers
        .iter()
        .map(|&p| residual(&circle, p).powi(2))
        .sum::<f64>()
        / inliers.len() as f64)
        .sqrt();
    Some(OutlineFit {
        // Outline pixels are the outermost touched pixels; the rim lies half a pixel out.
        circle: Circle {
            r: circle.r + 0.5,
            ..circle
        },
        rms_px: rms,
        inlier_fraction: inliers.len() as f64 / points.len() as f64,
        outline_px: points.len(),
    })
}

/// Radial bins per pixel of [`refine_radius`]'s profile.
const BINS_PER_PX: f64 = 4.0;

/// Refines the radius of `circle` (found on smoothed colours, so its outline sits a
/// little outside the true rim) on the unsmoothed deviation: `deviation(x, y)` (NaN:
/// unknown) is averaged over the full circumference in quarter-pixel radial bins, which
/// cancels the noise a single pixel has; the rim is where the profile falls halfway from
/// its peak inside the rim (a ball's steepest slope) to the flat skin outside it.
/// `None` when the profile has no clear step (the caller keeps the outline's radius).
pub fn refine_radius(
    circle: &Circle,
    w: usize,
    h: usize,
    search_px: f64,
    mut deviation: impl FnMut(usize, usize) -> f32,
) -> Option<f64> {
    let inner = (circle.r - search_px).max(1.0);
    let outer = circle.r + search_px;
    let bins = ((outer - inner) * BINS_PER_PX).ceil() as usize + 1;
    let mut sum = vec![0.0f64; bins];
    let mut count = vec![0usize; bins];
    let x0 = (circle.cx - outer).floor().max(0.0) as usize;
    let y0 = (circle.cy - outer).floor().max(0.0) as usize;
    let x1 = ((circle.cx + outer).ceil().max(0.0) as usize).min(w.saturating_sub(1));
    let y1 = ((circle.cy + outer).ceil().max(0.0) as usize).min(h.saturating_sub(1));
    for y in y0..=y1 {
        for x in x0..=x1 {
            let rho = ((x as f64 - circle.cx).powi(2) + (y as f64 - circle.cy).powi(2)).sqrt();
            if rho < inner || rho >= outer {
                continue;
            }
            let d = deviation(x, y);
            if d.is_nan() {
                continue;
            }
            let b = ((rho - inner) * BINS_PER_PX) as usize;
            sum[b] += d as f64;
            count[b] += 1;
        }
    }
    let profile: Vec<Option<f64>> = sum
        .iter()
        .zip(&count)
        .map(|(s, &n)| (n >= 4).then(|| s / n as f64))
        .collect();
    let radius_of = |b: f64| inner + (b + 0.5) / BINS_PER_PX;
    // Flat skin: the outer quarter of the search range.
    let mut flat: Vec<f64> = profile
        .iter()
        .enumerate()
        .filter(|(b, _)| radius_of(*b as f64) > circle.r + 0.5 * search_px)
        .filter_map(|(_, v)| *v)
        .collect();
    if flat.is_empty() {
        return None;
    }
    flat.sort_by(f64::total_cmp);
    let base = flat[flat.len() / 2];
    // The peak inside the outline.
    let (peak_bin, peak) = profile
        .iter()
        .enumerate()
        .filter(|(b, _)| radius_of(*b as f64) <= circle.r)
        .filter_map(|(b, v)| v.map(|v| (b, v)))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    if peak < 2.0 * base.max(1e-6) {
        return None;
    }
    let half = 0.5 * (peak + base);
    let mut last = (peak_bin, peak);
    for (b, v) in profile.iter().enumerate().skip(peak_bin + 1) {
        let Some(v) = *v else { continue };
        if v < half {
            // Linear interpolation between the last bin above and this one.
            let t = (last.1 - half) / (last.1 - v);
            let at = last.0 as f64 + t * (b - last.0) as f64;
            return Some(radius_of(at));
        }
        last = (b, v);
    }
    None
}

fn residual(c: &Circle, (x, y): (f64, f64)) -> f64 {
    ((x - c.cx).powi(2) + (y - c.cy).powi(2)).sqrt() - c.r
}

/// Algebraic (Kåsa) least-squares circle through `points`; `None` when degenerate.
pub fn fit_circle(points: &[(f64, f64)]) -> Option<Circle> {
    // Centre the data for conditioning, then solve for x² + y² + D x + E y + F = 0.
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let mut m = [[0.0f64; 3]; 3];
    let mut v = [0.0f64; 3];
    for &(x, y) in points {
        let (x, y) = (x - mx, y - my);
        let row = [x, y, 1.0];
        let rhs = -(x * x + y * y);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
            v[i] += row[i] * rhs;
        }
    }
    let [d, e, f] = solve3(m, v)?;
    let (cx, cy) = (-d / 2.0, -e / 2.0);
    let r2 = cx * cx + cy * cy - f;
    (r2 > 0.0 && r2.is_finite()).then(|| Circle {
        cx: cx + mx,
        cy: cy + my,
        r: r2.sqrt(),
    })
}

/// Solves a 3×3 system by Cramer's rule; `None` when singular.
fn solve3(m: [[f64; 3]; 3], v: [f64; 3]) -> Option<[f64; 3]> {
    let det = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det(m);
    let scale = m.iter().flatten().fold(0.0f64, |s, x| s.max(x.abs()));
    if d.abs() <= 1e-12 * scale.powi(3) || !d.is_finite() {
        return None;
    }
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut a = m;
        for i in 0..3 {
            a[i][k] = v[i];
        }
        *o = det(a) / d;
    }
    Some(out)
}

fn keep_largest_component(mask: &mut [bool], w: usize, h: usize) {
    let (labels, components) = contact::label_components(mask, w, h);
    let best = (0..components.len())
        .max_by_key(|&k| components[k].cells)
        .map_or(0, |k| k as u32 + 1);
    for (m, l) in mask.iter_mut().zip(&labels) {
        *m = best != 0 && *l == best;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Round: inliers within 6 % of the radius (1.5 px for small circles) and 60 % of the
    /// outline inliers; just past either bound is not.
    #[test]
    fn roundness_bounds() {
        let fit = |r: f64, rms_px: f64, inlier_fraction: f64| OutlineFit {
            circle: Circle {
                cx: 0.0,
                cy: 0.0,
                r,
            },
            rms_px,
            inlier_fraction,
            outline_px: 100,
        };
        assert!(fit(50.0, 3.0, 0.6).is_round());
        assert!(!fit(50.0, 3.01, 0.6).is_round());
        assert!(!fit(50.0, 1.0, 0.59).is_round());
        assert!(fit(10.0, 1.5, 0.9).is_round());
        assert!(!fit(10.0, 1.51, 0.9).is_round());
        assert!(!fit(10.0, f64::NAN, 0.9).is_round());
    }

    #[test]
    fn circle_fit_recovers_an_arc() {
        let pts: Vec<(f64, f64)> = (0..40)
            .map(|k| {
                let a = k as f64 * 0.05; // a 2-radian arc only
                (30.0 + 12.5 * a.cos(), -4.0 + 12.5 * a.sin())
            })
            .collect();
        let c = fit_circle(&pts).unwrap();
        assert!(
            (c.cx - 30.0).abs() < 1e-6 && (c.cy + 4.0).abs() < 1e-6 && (c.r - 12.5).abs() < 1e-6
        );
        assert!(
            fit_circle(&[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)]).is_none(),
            "collinear"
        );
    }

    #[test]
    fn the_radius_is_refined_on_the_unsmoothed_profile() {
        // A contact of radius 30.0 whose deviation rises towards its rim, flat skin 0.05
        // around it with alternating noise; the outline said 32.5.
        let c = Circle {
            cx: 60.3,
            cy: 50.7,
            r: 32.5,
        };
        let dev = |x: usize, y: usize| {
            let rho = ((x as f64 - 60.3).powi(2) + (y as f64 - 50.7).powi(2)).sqrt();
            let noise = if (x + y).is_multiple_of(2) {
                0.03
            } else {
                -0.03
            };
            if rho < 30.0 {
                (0.3 + rho / 30.0) as f32
            } else {
                (0.05 + noise) as f32
            }
        };
        let r = refine_radius(&c, 120, 100, 8.0, dev).unwrap();
        assert!((r - 30.0).abs() < 0.3, "{r}");
        // No step (flat everywhere): no refinement.
        assert!(refine_radius(&c, 120, 100, 8.0, |_, _| 0.05).is_none());
        // Unknown pixels are skipped, not read as flat.
        let r = refine_radius(
            &c,
            120,
            100,
            8.0,
            |x, y| if x < 40 { f32::NAN } else { dev(x, y) },
        );
        assert!((r.unwrap() - 30.0).abs() < 0.3);
    }

    #[test]
    fn outliers_on_the_outline_do_not_move_the_circle() {
        // A disk of radius 20 with a blob stuck to its side (a second, smaller touch).
        let (w, h) = (100, 80);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let disk = (x - 45.0).powi(2) + (y - 40.0).powi(2) <= 20.0f64.powi(2);
                let blob = (x - 68.0).powi(2) + (y - 40.0).powi(2) <= 6.0f64.powi(2);
                disk || blob
            })
            .collect();
        let fit = fit_outline(mask.clone(), None, w, h).unwrap();
        let c = fit.circle;
        assert!(
            (c.cx - 45.0).abs() < 0.6 && (c.cy - 40.0).abs() < 0.6,
            "{c:?}"
        );
        assert!((c.r - 20.5).abs() < 0.8, "{c:?}");
        assert!(fit.inlier_fraction < 0.95, "{fit:?}");
        // Nothing touched: no outline.
        assert!(fit_outline(vec![false; w * h], None, w, h).is_none());
        assert!(fit_outline(vec![true; 4], None, 2, 2).is_none());
        // The blob's side is unknown (saturated): its outline there is left out, and
        // the circle is unchanged.
        let unknown: Vec<bool> = (0..w * h).map(|i| i % w >= 66).collect();
        let fit = fit_outline(mask, Some(&unknown), w, h).unwrap();
        assert!((fit.circle.cx - 45.0).abs() < 0.6, "{fit:?}");
    }

    /// An overrides file naming a press twice, or with a field other than the three, is
    /// refused; circles that cannot be a press in the frame are said to be so.
    #[test]
    fn overrides_read_each_press_once_with_its_three_fields() {
        let read = read_overrides(
            br#"{"a": {"cx": 10, "cy": 20.5, "r": 30}, "b": {"cx": -5, "cy": 0, "r": 12}}"#,
        )
        .unwrap();
        assert_eq!(
            read["a"],
            Circle {
                cx: 10.0,
                cy: 20.5,
                r: 30.0
            }
        );
        assert_eq!(read.len(), 2);
        let twice = read_overrides(
            br#"{"a": {"cx": 1, "cy": 2, "r": 3}, "a": {"cx": 4, "cy": 5, "r": 6}}"#,
        );
        assert!(
            matches!(twice, Err(OverridesError::Twice(ref n)) if n == "a"),
            "{twice:?}"
        );
        let extra =
            read_overrides(br#"{"a": {"cx": 1, "cy": 2, "r": 3, "extra": 1}}"#).unwrap_err();
        assert!(extra.to_string().contains("extra"), "{extra}");
        assert!(read_overrides(br#"[1, 2]"#).is_err());
        let at = |cx, cy, r| given_circle_unfit(&Circle { cx, cy, r }, 640, 480);
        assert_eq!(
            at(-1.0, 234.0, 40.0),
            None,
            "a press centred just past the border"
        );
        assert_eq!(at(1e9, 25.0, 38.0), Some("lies outside the frame"));
        assert_eq!(at(100.0, 100.0, -5.0), Some("has no radius"));
        assert_eq!(
            at(f64::NAN, 100.0, 5.0),
            Some("is not three finite numbers")
        );
    }
}
