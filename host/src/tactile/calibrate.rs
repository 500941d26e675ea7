//! Calibration from ball presses: find each contact's circle, derive the true slopes from
//! the sphere's geometry, train the gradient models, report how well they fit.
//!
//! For a ball of radius `R` px touching the skin in a circle of radius `r` around
//! `(cx, cy)`, the imprint is a spherical cap, so at distance `ρ < r` from the centre
//! `∂d/∂x = −(x − cx) / √(R² − ρ²)` (and likewise in y). This is a slope, not the angle
//! `asin((x − cx)/R)` some papers train on, which reads steep imprints shallow.
//!
//! The contact circle is fitted to the outer boundary of the largest touched region
//! (holes filled, frame-border pixels excluded, a second fit without outliers), so a
//! ball partly outside the frame is still found.

use std::collections::HashMap;

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::colour::{ColourFilter, Reference, median_image};
use super::contact::{self, ContactParams, References};
use super::model::{
    AxisModel, Background, FitReport, LUT_MAX_COLOUR, Lut, MODEL_FORMAT, MODEL_VERSION, Mlp,
    MlpTraining, ModelKind, Sample, TactileModel, colour_features,
};

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

/// One ball press found in the calibration set.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PressFit {
    /// Pair name (file stem before `_dx`/`_dy`).
    pub name: String,
    /// Contact circle.
    pub circle: Circle,
    /// Press depth implied by the circle and the ball (mm).
    pub depth_mm: f64,
    /// Whether the circle came from the override file.
    pub overridden: bool,
    /// RMS distance of boundary pixels from the circle (px).
    pub fit_rms_px: f64,
}

/// Calibration settings; [`Default`] gives the documented defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationSettings {
    /// Ball diameter (mm).
    pub ball_diameter_mm: f64,
    /// Scale (px per mm).
    pub px_per_mm: f64,
    /// Colour filter.
    pub filter: ColourFilter,
    /// Contact detection.
    pub contact: ContactParams,
    /// LUT colour bins per axis.
    pub lut_bins: usize,
    /// LUT spatial cells `(across, down)`.
    pub lut_cells: (usize, usize),
    /// MLP training.
    pub mlp: MlpTraining,
    /// Block size of the stored background (px).
    pub background_factor: usize,
    /// Circles given by hand, by pair name.
    pub overrides: HashMap<String, Circle>,
}

impl Default for CalibrationSettings {
    fn default() -> Self {
        Self {
            ball_diameter_mm: 6.0,
            px_per_mm: 15.0,
            filter: ColourFilter::default(),
            contact: ContactParams::default(),
            lut_bins: 48,
            lut_cells: (4, 3),
            mlp: MlpTraining::default(),
            background_factor: 8,
            overrides: HashMap::new(),
        }
    }
}

/// A named dx/dy pair of a ball press.
#[derive(Debug, Clone)]
pub struct CalibrationPair {
    /// Name (file stem before `_dx`/`_dy`).
    pub name: String,
    /// dx image.
    pub dx: RgbImage,
    /// dy image.
    pub dy: RgbImage,
}

/// Why calibration failed.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// No pairs.
    #[error("no calibration pairs given")]
    NoPairs,
    /// Without reference frames the background is a per-pixel median, which needs presses
    /// at three or more places.
    #[error("{0} pair(s) and no reference frames: give --ref-dx/--ref-dy or at least 3 pairs")]
    TooFewForMedian(usize),
    /// An image differs in size from the first one.
    #[error("{name}: image is {got:?}, expected {want:?} like the first pair")]
    Size {
        /// Pair or reference name.
        name: String,
        /// Its size.
        got: (u32, u32),
        /// Expected size.
        want: (u32, u32),
    },
    /// No touched region in a pair.
    #[error("{0}: no contact found (is the ball pressed in? are the references right?)")]
    NoContact(String),
    /// The contact is not a plausible imprint of the given ball.
    #[error(
        "{name}: contact radius {contact_px:.1} px does not fit a ball of radius {ball_px:.1} px (check --ball-diameter-mm and --px-per-mm)"
    )]
    ImplausibleContact {
        /// Pair name.
        name: String,
        /// Fitted contact radius.
        contact_px: f64,
        /// Ball radius.
        ball_px: f64,
    },
    /// Invalid settings.
    #[error("invalid setting: {0}")]
    Settings(String),
}

/// Progress of a calibration, for a progress bar.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CalibrationProgress {
    /// Fitting circles: `done` of `total` pairs.
    Circles {
        /// Done.
        done: usize,
        /// Total.
        total: usize,
    },
    /// Training the MLP of an axis (0 = x, 1 = y): epoch and training RMS.
    Mlp {
        /// Axis.
        axis: usize,
        /// Epoch done.
        epoch: usize,
        /// Of.
        epochs: usize,
        /// Current RMS.
        rms: f32,
    },
}

/// The calibration result.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// The model to save.
    pub model: TactileModel,
    /// Every press found.
    pub presses: Vec<PressFit>,
}

/// Calibrates from ball presses. `references` are no-contact dx/dy frames; without them
/// the per-pixel median of the pairs is the background.
pub fn calibrate(
    pairs: &[CalibrationPair],
    references: Option<(&RgbImage, &RgbImage)>,
    settings: &CalibrationSettings,
    mut progress: impl FnMut(CalibrationProgress),
) -> Result<Calibration, CalibrationError> {
    let first = pairs.first().ok_or(CalibrationError::NoPairs)?;
    if !(settings.ball_diameter_mm > 0.0 && settings.px_per_mm > 0.0) {
        return Err(CalibrationError::Settings(
            "ball diameter and px/mm must be positive".into(),
        ));
    }
    let want = first.dx.dimensions();
    let check = |name: &str, img: &RgbImage| {
        if img.dimensions() == want {
            Ok(())
        } else {
            Err(CalibrationError::Size {
                name: name.to_string(),
                got: img.dimensions(),
                want,
            })
        }
    };
    for p in pairs {
        check(&format!("{}_dx", p.name), &p.dx)?;
        check(&format!("{}_dy", p.name), &p.dy)?;
    }
    let (ref_dx, ref_dy) = match references {
        Some((dx, dy)) => {
            check("reference dx", dx)?;
            check("reference dy", dy)?;
            (dx.clone(), dy.clone())
        }
        None => {
            if pairs.len() < 3 {
                return Err(CalibrationError::TooFewForMedian(pairs.len()));
            }
            let dxs: Vec<&RgbImage> = pairs.iter().map(|p| &p.dx).collect();
            let dys: Vec<&RgbImage> = pairs.iter().map(|p| &p.dy).collect();
            (
                median_image(&dxs).expect("sizes checked"),
                median_image(&dys).expect("sizes checked"),
            )
        }
    };
    let refs = References {
        dx: Reference::from_image(&ref_dx),
        dy: Reference::from_image(&ref_dy),
    };
    let (w, h) = (want.0 as usize, want.1 as usize);
    let ball_px = settings.ball_diameter_mm / 2.0 * settings.px_per_mm;

    let mut presses = Vec::with_capacity(pairs.len());
    let mut per_pair: Vec<[Vec<Sample>; 2]> = Vec::with_capacity(pairs.len());
    for (done, pair) in pairs.iter().enumerate() {
        let (circle, overridden, fit_rms_px) = match settings.overrides.get(&pair.name) {
            Some(c) => (*c, true, 0.0),
            None => {
                let (c, rms) = find_circle(pair, &refs, settings)?;
                (c, false, rms)
            }
        };
        if !(circle.r > 2.0 && circle.r < ball_px) {
            return Err(CalibrationError::ImplausibleContact {
                name: pair.name.clone(),
                contact_px: circle.r,
                ball_px,
            });
        }
        let depth_px = ball_px - (ball_px * ball_px - circle.r * circle.r).sqrt();
        presses.push(PressFit {
            name: pair.name.clone(),
            circle,
            depth_mm: depth_px / settings.px_per_mm,
            overridden,
            fit_rms_px,
        });
        per_pair.push(samples(
            pair,
            &refs,
            &settings.filter,
            circle,
            ball_px,
            w,
            h,
        ));
        progress(CalibrationProgress::Circles {
            done: done + 1,
            total: pairs.len(),
        });
    }

    // Hold out every fifth pair for validation when there are enough.
    let holdout = |i: usize| pairs.len() >= 5 && i % 5 == 4;
    let mut axes = Vec::with_capacity(2);
    let mut report = FitReport {
        training_pairs: (0..pairs.len()).filter(|&i| !holdout(i)).count(),
        validation_pairs: (0..pairs.len()).filter(|&i| holdout(i)).count(),
        ..Default::default()
    };
    for axis in 0..2 {
        let train: Vec<Sample> = per_pair
            .iter()
            .enumerate()
            .filter(|(i, _)| !holdout(*i))
            .flat_map(|(_, s)| s[axis].iter().copied())
            .collect();
        let valid: Vec<Sample> = per_pair
            .iter()
            .enumerate()
            .filter(|(i, _)| holdout(*i))
            .flat_map(|(_, s)| s[axis].iter().copied())
            .collect();
        let lut = Lut::fit(
            &train,
            settings.lut_bins,
            LUT_MAX_COLOUR,
            settings.lut_cells.0,
            settings.lut_cells.1,
        );
        let epochs = settings.mlp.epochs;
        let mlp = Mlp::fit(&train, &settings.mlp, |epoch, rms| {
            progress(CalibrationProgress::Mlp {
                axis,
                epoch,
                epochs,
                rms,
            })
        });
        let model = AxisModel { lut, mlp };
        let rms = |kind, set: &[Sample]| rms_error(&model, kind, set);
        report.samples_per_axis = report.samples_per_axis.max(train.len());
        if axis == 0 {
            report.lut_train_rms = rms(ModelKind::Lut, &train);
            report.mlp_train_rms = rms(ModelKind::Mlp, &train);
            report.lut_validation_rms = rms(ModelKind::Lut, &valid);
            report.mlp_validation_rms = rms(ModelKind::Mlp, &valid);
        } else {
            // Report the worse of the two axes.
            report.lut_train_rms = report.lut_train_rms.max(rms(ModelKind::Lut, &train));
            report.mlp_train_rms = report.mlp_train_rms.max(rms(ModelKind::Mlp, &train));
            report.lut_validation_rms = report.lut_validation_rms.max(rms(ModelKind::Lut, &valid));
            report.mlp_validation_rms = report.mlp_validation_rms.max(rms(ModelKind::Mlp, &valid));
        }
        axes.push(model);
    }
    let dy = axes.pop().expect("two axes");
    let dx = axes.pop().expect("two axes");
    let model = TactileModel {
        format: MODEL_FORMAT.to_string(),
        version: MODEL_VERSION,
        width: w,
        height: h,
        px_per_mm: settings.px_per_mm,
        ball_diameter_mm: settings.ball_diameter_mm,
        filter: settings.filter,
        contact: settings.contact,
        background: Background::from_images(&ref_dx, &ref_dy, settings.background_factor.max(1)),
        dx,
        dy,
        fit: report,
    };
    Ok(Calibration { model, presses })
}

/// RMS slope error of `model` on `set` (0 for an empty set).
pub fn rms_error(model: &AxisModel, kind: ModelKind, set: &[Sample]) -> f32 {
    if set.is_empty() {
        return 0.0;
    }
    let features: Vec<[f32; 4]> = set.iter().map(|s| s.features).collect();
    let mut out = vec![0.0; set.len()];
    model.eval(kind, &features, &mut out);
    let sq: f64 = out
        .iter()
        .zip(set)
        .map(|(o, s)| ((o - s.target) as f64).powi(2))
        .sum();
    (sq / set.len() as f64).sqrt() as f32
}

/// Fits the contact circle of one pair; returns it and the boundary RMS residual.
fn find_circle(
    pair: &CalibrationPair,
    refs: &References,
    settings: &CalibrationSettings,
) -> Result<(Circle, f64), CalibrationError> {
    let (w, h) = (pair.dx.width() as usize, pair.dx.height() as usize);
    let mut mask: Vec<bool> = (0..w * h)
        .map(|i| {
            contact::deviation(refs, &settings.filter, &pair.dx, &pair.dy, i % w, i / w)
                > settings.contact.threshold
        })
        .collect();
    keep_largest_component(&mut mask, w, h);
    fill_holes(&mut mask, w, h);
    let mut points = Vec::new();
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            if mask[i] && (!mask[i - 1] || !mask[i + 1] || !mask[i - w] || !mask[i + w]) {
                points.push((x as f64, y as f64));
            }
        }
    }
    if points.len() < 8 {
        return Err(CalibrationError::NoContact(pair.name.clone()));
    }
    let circle =
        fit_circle(&points).ok_or_else(|| CalibrationError::NoContact(pair.name.clone()))?;
    // Refit without points far from the first circle (noise specks, hole rims).
    let inliers: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|&(x, y)| {
            (((x - circle.cx).powi(2) + (y - circle.cy).powi(2)).sqrt() - circle.r).abs() < 3.0
        })
        .collect();
    let circle = if inliers.len() >= 8 {
        fit_circle(&inliers).unwrap_or(circle)
    } else {
        circle
    };
    let rms = (inliers
        .iter()
        .map(|&(x, y)| {
            (((x - circle.cx).powi(2) + (y - circle.cy).powi(2)).sqrt() - circle.r).powi(2)
        })
        .sum::<f64>()
        / inliers.len().max(1) as f64)
        .sqrt();
    // Boundary pixels are the outermost touched pixels; the rim lies half a pixel out.
    Ok((
        Circle {
            r: circle.r + 0.5,
            ..circle
        },
        rms,
    ))
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
    (r2 > 0.0).then(|| Circle {
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

/// Sets every unset pixel not 4-connected to the frame border through unset pixels.
fn fill_holes(mask: &mut [bool], w: usize, h: usize) {
    let mut outside = vec![false; mask.len()];
    let mut stack: Vec<usize> = (0..mask.len())
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            (x == 0 || y == 0 || x == w - 1 || y == h - 1) && !mask[i]
        })
        .collect();
    for &i in &stack {
        outside[i] = true;
    }
    while let Some(i) = stack.pop() {
        let (x, y) = (i % w, i / w);
        let mut visit = |j: usize| {
            if !mask[j] && !outside[j] {
                outside[j] = true;
                stack.push(j);
            }
        };
        if x > 0 {
            visit(i - 1);
        }
        if x + 1 < w {
            visit(i + 1);
        }
        if y > 0 {
            visit(i - w);
        }
        if y + 1 < h {
            visit(i + w);
        }
    }
    for (m, o) in mask.iter_mut().zip(&outside) {
        *m = !*o;
    }
}

/// Training samples of one pair: pixels inside the contact with the sphere's slopes, and
/// a ring of flat skin around it with slope 0.
fn samples(
    pair: &CalibrationPair,
    refs: &References,
    filter: &ColourFilter,
    c: Circle,
    ball_px: f64,
    w: usize,
    h: usize,
) -> [Vec<Sample>; 2] {
    let mut out = [Vec::new(), Vec::new()];
    let outer = c.r + 15.0;
    let x0 = (c.cx - outer).floor().max(0.0) as usize;
    let x1 = ((c.cx + outer).ceil() as usize).min(w - 1);
    let y0 = (c.cy - outer).floor().max(0.0) as usize;
    let y1 = ((c.cy + outer).ceil() as usize).min(h - 1);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (dx, dy) = (x as f64 - c.cx, y as f64 - c.cy);
            let rho = (dx * dx + dy * dy).sqrt();
            let slopes = if rho < c.r - 1.0 {
                let s = (ball_px * ball_px - rho * rho).sqrt();
                [-dx / s, -dy / s]
            } else if rho > c.r + 3.0 && (x + y) % 3 == 0 {
                [0.0, 0.0]
            } else {
                continue;
            };
            let position = [x as f32 / w as f32, y as f32 / h as f32];
            let (colour, _) = contact::pixel_colours(refs, filter, &pair.dx, &pair.dy, x, y);
            for (axis, f) in colour_features(colour).into_iter().enumerate() {
                if let Some([r, b]) = f {
                    out[axis].push(Sample {
                        features: [r, b, position[0], position[1]],
                        target: slopes[axis] as f32,
                    });
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn holes_fill_but_border_bays_stay_open() {
        let (w, h) = (7, 5);
        let mut m = vec![false; w * h];
        for y in 1..4 {
            for x in 1..4 {
                m[y * w + x] = !(x == 2 && y == 2);
            }
        }
        fill_holes(&mut m, w, h);
        assert!(m[2 * w + 2]);
        assert!(!m[0] && !m[2 * w + 5]);
    }
}
