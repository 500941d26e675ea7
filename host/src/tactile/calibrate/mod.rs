//! Calibration from ball presses: find each contact's circle, derive the true slopes from
//! the sphere's geometry, train the gradient models, report how well they fit.
//!
//! For a ball of radius `R` px touching the skin in a circle of radius `r` around
//! `(cx, cy)`, the imprint is a spherical cap, so at distance `ρ < r` from the centre
//! `∂d/∂x = −(x − cx) / √(R² − ρ²)` (and likewise in y). This is a slope, not the angle
//! `asin((x − cx)/R)` some papers train on, which reads steep imprints shallow.
//!
//! One bad press never costs the calibration: a press whose circle cannot be found or
//! does not fit the ball is set aside with its reason ([`RejectedPress`]) and the others
//! are used, as long as [`CalibrationSettings::min_presses`] remain. The contact
//! threshold comes from the frames' own flat skin ([`threshold`]); circles are fitted to
//! the touched region's outline with outliers dropped ([`circle`]); [`report`] says how
//! well the model fits across the frame and where the presses left gaps.

pub mod circle;
pub mod report;
pub mod shared_departure;
pub mod threshold;

use std::collections::HashMap;
use std::fmt;

use image::RgbImage;
use serde::Serialize;

pub use circle::{Circle, OutlineFit, OverridesError, fit_circle, read_overrides};
pub use report::{CalibrationReport, overlay};

use super::ambient::{self, AmbientEstimate, PhaseFrames, subtracted};
use super::camera_curve::CameraCurve;
use super::colour::{ColourFilter, Reference, median_image};
use super::contact::{self, ContactParams, References};
use super::model::side_light;
use super::model::validate::{
    MAX_SCALE, MAX_SKIN_THICKNESS_MM, MIN_PX_PER_MM, MIN_SKIN_THICKNESS_MM, valid_ball_diameter,
};
use super::model::{
    AxisModel, Background, DEFAULT_SKIN_THICKNESS_MM, FitReport, JointSample, LUT_MAX_COLOUR,
    LightModel, Lut, MODEL_FORMAT, MODEL_VERSION, Mlp, MlpTraining, ModelKind, PhotometricModel,
    Sample, SideLight, TactileModel, colour_features,
};
use super::phase_check::{self, PhaseImageError};

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
    /// RMS distance of the outline pixels from the circle (px).
    pub fit_rms_px: f64,
    /// Diameter of the ball the press was made with (mm).
    pub ball_diameter_mm: f64,
    /// Fraction of the contact's pixels at or near clipping (a channel at or above the
    /// colour filter's `saturation`) in the camera's raw dx and dy frames: their colour
    /// says nothing reliable about the slope. (The filter refuses them on raw frames; with
    /// LEDs-off frames subtracted it refuses only those at 255.)
    pub saturated: [f64; 2],
}

/// Why a press was not used.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Rejection {
    /// Nothing departs from flat skin enough to be a contact.
    NoContact {
        /// The contact threshold in force.
        threshold: f32,
    },
    /// The contact is too large for the ball: deeper than 0.6 of its radius, or the
    /// touched region spreads beyond the imprint.
    TooLarge {
        /// Fitted contact radius (px).
        contact_px: f64,
        /// Largest plausible contact radius (px).
        max_px: f64,
        /// Diameter of the ball given for the press (mm).
        ball_mm: f64,
    },
    /// The contact is too small to teach anything (under 3 px or 0.02 mm deep).
    TooSmall {
        /// Fitted contact radius (px).
        contact_px: f64,
        /// Diameter of the ball given for the press (mm).
        ball_mm: f64,
    },
    /// The circle implies a press deeper than the skin is thick.
    DeeperThanSkin {
        /// Press depth implied by the circle and the ball (mm).
        depth_mm: f64,
        /// The skin's thickness (mm).
        skin_mm: f64,
        /// Diameter of the ball given for the press (mm).
        ball_mm: f64,
    },
    /// The pair does not look like this sensor's dx and dy phases (a frame without LED
    /// light, or the two given the wrong way round): said instead of "no contact".
    NotPhasePair {
        /// What the phase check found.
        why: String,
    },
    /// Inside the circle one phase departs from flat skin far less than the other: the
    /// dx and dy frames show different presses (taken at different moments).
    PhasesApart {
        /// The phase showing (almost) no press there: "dx" or "dy".
        weaker: &'static str,
        /// Its mean departure inside the circle as a share of the other's.
        share: f64,
    },
    /// The outline is not a circle (two contacts, a smear, a ball that slid).
    NotCircular {
        /// RMS distance of the outline from the circle (px).
        rms_px: f64,
        /// Fraction of the outline near the circle.
        inlier_fraction: f64,
    },
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rejection::NotPhasePair { why } => write!(f, "{why}"),
            Rejection::NoContact { threshold } => write!(
                f,
                "no contact found (no region departs from flat skin by more than {threshold:.3}): is the ball pressed in, are the reference frames right?"
            ),
            Rejection::TooLarge {
                contact_px,
                max_px,
                ball_mm,
            } => write!(
                f,
                "contact radius {contact_px:.1} px is larger than a {ball_mm} mm ball can make ({max_px:.1} px at 0.6 of its radius deep): wrong ball diameter (--ball-diameter-mm, or --with-ball for this press's folder; in Python, ball_diameter_mm or press_balls_mm) or pixels per mm (--px-per-mm; px_per_mm), or light spreading beyond the imprint"
            ),
            Rejection::TooSmall {
                contact_px,
                ball_mm,
            } => write!(
                f,
                "contact radius {contact_px:.1} px is too small to calibrate with (under 3 px, or under 0.02 mm deep for a {ball_mm} mm ball): press deeper, or check the ball's diameter"
            ),
            Rejection::DeeperThanSkin {
                depth_mm,
                skin_mm,
                ball_mm,
            } => write!(
                f,
                "with a {ball_mm} mm ball the circle means a press {depth_mm:.2} mm deep, deeper than the {skin_mm} mm skin: wrong skin thickness (--skin-thickness-mm; in Python, skin_thickness_mm), ball diameter (--ball-diameter-mm, or --with-ball for this press's folder; ball_diameter_mm or press_balls_mm) or pixels per mm (--px-per-mm; px_per_mm), or light spreading beyond the imprint"
            ),
            Rejection::PhasesApart { weaker, share } => write!(
                f,
                "its {weaker} frame departs from flat skin inside the press's circle only {:.0} % as much as the other frame: the two show different presses (is each dx frame paired with the dy frame of its own press?)",
                share * 100.0
            ),
            Rejection::NotCircular {
                rms_px,
                inlier_fraction,
            } => write!(
                f,
                "outline is not a circle (RMS {rms_px:.2} px, {:.0}% of it on the circle): two contacts, or the ball slid",
                inlier_fraction * 100.0
            ),
        }
    }
}

/// A press set aside, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RejectedPress {
    /// Pair name.
    pub name: String,
    /// The circle that was fitted, when there was one.
    pub circle: Option<Circle>,
    /// Why it was not used.
    pub reason: Rejection,
}

/// Calibration settings; [`Default`] gives the documented defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationSettings {
    /// Ball diameter (mm).
    pub ball_diameter_mm: f64,
    /// Scale (px per mm).
    pub px_per_mm: f64,
    /// Thickness of the skin (mm), stored in the model: no press goes deeper.
    pub skin_thickness_mm: f64,
    /// Colour filter.
    pub filter: ColourFilter,
    /// Contact detection. Its threshold is replaced by the one measured on the frames
    /// unless [`Self::fixed_threshold`] is set.
    pub contact: ContactParams,
    /// Use `contact.threshold` as given instead of measuring it on the frames.
    pub fixed_threshold: bool,
    /// Fewest usable presses to calibrate from.
    pub min_presses: usize,
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
    /// Measure the strips' side light in the cross factor and teach and read the lookup
    /// tables with it taken out ([`SideLight`]; off by default, see its measurements).
    pub side_light: bool,
    /// The camera's response curve, undone on every frame before anything reads it
    /// ([`CameraCurve::measure`] from an all-lit flat frame); `None`: a linear camera.
    /// The model keeps it and undoes it on the frames it reads.
    pub camera_curve: Option<CameraCurve>,
}

impl CalibrationSettings {
    /// Checks the numbers a user gives (ball diameter, px/mm) against the bounds a model
    /// file is held to ([`super::model::validate`]), before any work.
    pub fn check(&self) -> Result<(), CalibrationError> {
        if !valid_ball_diameter(self.ball_diameter_mm) {
            return Err(CalibrationError::Settings(format!(
                "ball diameter (mm) must be a finite number above 0 and up to {MAX_SCALE}, got {}",
                self.ball_diameter_mm
            )));
        }
        let px = self.px_per_mm;
        if !(px.is_finite() && px > MIN_PX_PER_MM && px <= MAX_SCALE) {
            return Err(CalibrationError::Settings(format!(
                "px/mm must be a finite number above {MIN_PX_PER_MM} and up to {MAX_SCALE}, got {px}"
            )));
        }
        let (lo, hi) = (MIN_SKIN_THICKNESS_MM, MAX_SKIN_THICKNESS_MM);
        if !(lo..=hi).contains(&self.skin_thickness_mm) {
            return Err(CalibrationError::Settings(format!(
                "skin thickness must be {lo}–{hi} mm, got {}",
                self.skin_thickness_mm
            )));
        }
        Ok(())
    }
}

impl Default for CalibrationSettings {
    fn default() -> Self {
        Self {
            ball_diameter_mm: 6.0,
            px_per_mm: 15.0,
            skin_thickness_mm: DEFAULT_SKIN_THICKNESS_MM,
            filter: ColourFilter::default(),
            contact: ContactParams::default(),
            fixed_threshold: false,
            min_presses: DEFAULT_MIN_PRESSES,
            lut_bins: 48,
            lut_cells: (4, 3),
            mlp: MlpTraining::default(),
            background_factor: 8,
            overrides: HashMap::new(),
            side_light: false,
            camera_curve: None,
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
    /// The LEDs-off frame exposed with them, if any (see [`crate::tactile::ambient`]).
    pub dark: Option<RgbImage>,
    /// Diameter of the ball this press was made with (mm) when it is not
    /// [`CalibrationSettings::ball_diameter_mm`]: presses of a smaller ball teach the
    /// steeper slopes a larger one cannot make (see [`calibrate`]).
    pub ball_diameter_mm: Option<f64>,
}

/// Why calibration failed.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// No pairs.
    #[error("no calibration pairs given")]
    NoPairs,
    /// Without reference frames the background is a per-pixel median, which needs presses
    /// at three or more places.
    #[error(
        "{0} pair(s) and no reference frames: give reference frames (--ref-dx/--ref-dy; in Python, ref) or at least 3 pairs"
    )]
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
    /// Too few presses were usable.
    #[error(
        "only {good} of {total} presses are usable, at least {needed} are needed{}",
        rejected_list(rejected)
    )]
    TooFewPresses {
        /// Usable presses.
        good: usize,
        /// Presses given.
        total: usize,
        /// The minimum.
        needed: usize,
        /// The others, with reasons.
        rejected: Vec<RejectedPress>,
    },
    /// Invalid settings.
    #[error("invalid setting: {0}")]
    Settings(String),
    /// A circle given for a press (`--overrides`) cannot be one in these frames.
    #[error(
        "the circle given for {name} (cx {cx}, cy {cy}, r {r} px) {why}: give its centre in \
         pixels of the {width}×{height} frames and a radius above 0",
        cx = circle.cx,
        cy = circle.cy,
        r = circle.r
    )]
    GivenCircle {
        /// The press.
        name: String,
        /// Its circle as given.
        circle: Circle,
        /// What is wrong with it.
        why: &'static str,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
    },
    /// The model the presses gave fails the check every model file gets on loading
    /// ([`crate::tactile::model::validate::check`]): saved, it would be refused at once.
    #[error(
        "the calibrated model's `{field}`: {why}. The {presses} press(es) used did not make \
         a model that reads: {}",
        model_fails_hint(*presses)
    )]
    ModelFailsCheck {
        /// The field.
        field: String,
        /// What is wrong with it.
        why: String,
        /// Presses the model was fitted on (training and held out).
        presses: usize,
    },
    /// The references (given, or the median of the presses) do not look like this
    /// sensor's dx and dy phases.
    #[error(transparent)]
    References(#[from] PhaseImageError),
    /// Most presses depart from the references at one place away from themselves (see
    /// [`shared_departure`]).
    #[error(
        "{} presses of {} depart from the {} at px ({x}, {y}), over {area_mm2:.1} mm², away \
         from their own press: {}",
        departs_in.0,
        departs_in.1,
        if *given { "reference frames" } else { "presses' median (the background without reference frames)" },
        if *given {
            "the reference frames show something there the presses do not (a press, debris, \
             a mark, another light); give frames of the skin at rest, or leave out \
             --ref-dx/--ref-dy to use the presses' median"
        } else {
            "most presses were made there; spread them over the skin, or give reference \
             frames of the skin at rest"
        }
    )]
    SharedDeparture {
        /// Pixel column of the place.
        x: f64,
        /// Pixel row.
        y: f64,
        /// Its area (mm²).
        area_mm2: f64,
        /// Presses departing there, of those away from it.
        departs_in: (usize, usize),
        /// Whether reference frames were given (else the presses' median is used).
        given: bool,
    },
}

/// What to check when the model calibrated from `presses` presses fails the loading check.
/// Under the default minimum the presses are the likelier cause: one press taught a
/// perceptron that read a slope's direction wrongly, and the swapped frames it was sent
/// to look for were fine.
fn model_fails_hint(presses: usize) -> String {
    const CHECK: &str = "check that the dx and dy frames are not swapped, that all frames \
        are this sensor's with its LEDs in their places, and that the presses are deep \
        enough to show slopes; then calibrate again";
    if presses < DEFAULT_MIN_PRESSES {
        format!(
            "{presses} are too few to teach it (the default minimum is {DEFAULT_MIN_PRESSES}: \
             --min-presses; in Python, min_presses): make more presses, all over the frame. \
             If that is not it, {CHECK}"
        )
    } else {
        CHECK.to_string()
    }
}

fn rejected_list(rejected: &[RejectedPress]) -> String {
    let mut s = String::new();
    for r in rejected.iter().take(12) {
        s.push_str(&format!("\n  {}: {}", r.name, r.reason));
    }
    if rejected.len() > 12 {
        s.push_str(&format!("\n  … and {} more", rejected.len() - 12));
    }
    s
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
    /// Every press used.
    pub presses: Vec<PressFit>,
    /// Presses set aside, with reasons.
    pub rejected: Vec<RejectedPress>,
    /// How well the model fits and where the presses left gaps.
    pub report: CalibrationReport,
}

impl Calibration {
    /// The report as JSON: the presses used, those set aside with their reasons, the
    /// report and the model's fit (what `calibrate --report` writes, what Python gets).
    pub fn report_json(&self) -> serde_json::Value {
        serde_json::json!({
            "presses": self.presses,
            "rejected": self.rejected,
            "report": self.report,
            "fit": self.model.fit,
        })
    }
}

/// Fewest usable presses a calibration asks for unless told otherwise
/// ([`CalibrationSettings::min_presses`]).
pub const DEFAULT_MIN_PRESSES: usize = 5;

/// Deepest plausible press, as a fraction of the ball's radius.
const MAX_DEPTH_OF_RADIUS: f64 = 0.6;

/// Calibrates from ball presses. `references` are no-contact dx/dy frames; without them
/// the per-pixel median of the pairs is the background.
///
/// When every press comes with its LEDs-off frame, the model is calibrated on LED light
/// alone (each press minus its own LEDs-off frame; the references minus theirs, or minus
/// the presses' mean ambient light) and keeps that mean for frames without one.
pub fn calibrate(
    pairs: &[CalibrationPair],
    references: Option<PhaseFrames<'_>>,
    settings: &CalibrationSettings,
    mut progress: impl FnMut(CalibrationProgress),
) -> Result<Calibration, CalibrationError> {
    let Some(curve) = settings.camera_curve else {
        return calibrate_dyn(pairs, references, settings, &mut progress);
    };
    // Every frame is read with the camera's curve undone, once, here.
    let table = curve.table();
    let linear = |i: &RgbImage| {
        let mut out = RgbImage::new(0, 0);
        CameraCurve::linearise_into(&table, i, &mut out);
        out
    };
    let pairs: Vec<CalibrationPair> = pairs
        .iter()
        .map(|p| CalibrationPair {
            name: p.name.clone(),
            dx: linear(&p.dx),
            dy: linear(&p.dy),
            dark: p.dark.as_ref().map(linear),
            ball_diameter_mm: p.ball_diameter_mm,
        })
        .collect();
    let refs = references.map(|r| [linear(r.dx), linear(r.dy)]);
    let ref_dark = references.and_then(|r| r.dark).map(linear);
    let references = refs.as_ref().map(|[dx, dy]| PhaseFrames {
        dx,
        dy,
        dark: ref_dark.as_ref(),
    });
    calibrate_dyn(&pairs, references, settings, &mut progress)
}

/// [`calibrate`], once more without the presses whose dx and dy frames showed different
/// presses ([`Rejection::PhasesApart`]) when there were any: each phase's press counted
/// in the flat skin's noise, which raised the contact threshold for all (to its bound in
/// a trial), and without reference frames in the median background. Their rejections
/// are listed with the others, in the presses' order.
fn calibrate_dyn(
    pairs: &[CalibrationPair],
    references: Option<PhaseFrames<'_>>,
    settings: &CalibrationSettings,
    progress: &mut dyn FnMut(CalibrationProgress),
) -> Result<Calibration, CalibrationError> {
    let apart = match calibrate_once(pairs, references, settings, progress) {
        Ok(Attempt::Done(c)) => return Ok(*c),
        Ok(Attempt::Again(apart)) => apart,
        Err(e) => return Err(e),
    };
    let kept_index: Vec<usize> = (0..pairs.len())
        .filter(|i| !apart.iter().any(|(a, _)| a == i))
        .collect();
    let kept: Vec<CalibrationPair> = kept_index.iter().map(|&i| pairs[i].clone()).collect();
    // The others' rejections back at the presses' places, with these.
    let merge = |rejected: Vec<RejectedPress>| -> Vec<RejectedPress> {
        let mut all: Vec<(usize, RejectedPress)> = apart.clone();
        for r in rejected {
            let at = kept
                .iter()
                .position(|p| p.name == r.name)
                .map_or(usize::MAX, |k| kept_index[k]);
            all.push((at, r));
        }
        all.sort_by_key(|(i, _)| *i);
        all.into_iter().map(|(_, r)| r).collect()
    };
    if kept.is_empty() {
        return Err(CalibrationError::TooFewPresses {
            good: 0,
            total: pairs.len(),
            needed: settings.min_presses.max(1),
            rejected: merge(Vec::new()),
        });
    }
    match calibrate_dyn(&kept, references, settings, progress) {
        Ok(mut c) => {
            c.rejected = merge(std::mem::take(&mut c.rejected));
            c.report.count_all(pairs.len(), c.rejected.len());
            Ok(c)
        }
        Err(CalibrationError::TooFewPresses {
            good,
            needed,
            rejected,
            ..
        }) => Err(CalibrationError::TooFewPresses {
            good,
            total: pairs.len(),
            needed,
            rejected: merge(rejected),
        }),
        Err(e) => Err(e),
    }
}

/// What one pass of calibration came to.
enum Attempt {
    /// The calibration.
    Done(Box<Calibration>),
    /// Presses whose phases showed different presses, by index: calibrate again without
    /// them.
    Again(Vec<(usize, RejectedPress)>),
}

/// One pass of [`calibrate`]: the calibration, or the presses to leave out of another.
fn calibrate_once(
    pairs: &[CalibrationPair],
    references: Option<PhaseFrames<'_>>,
    settings: &CalibrationSettings,
    progress: &mut dyn FnMut(CalibrationProgress),
) -> Result<Attempt, CalibrationError> {
    let first = pairs.first().ok_or(CalibrationError::NoPairs)?;
    settings.check()?;
    if let Some((name, d)) = pairs.iter().find_map(|p| {
        p.ball_diameter_mm
            .filter(|d| !valid_ball_diameter(*d))
            .map(|d| (&p.name, d))
    }) {
        return Err(CalibrationError::Settings(format!(
            "press {name}: its ball diameter (mm) must be a finite number above 0 and up to {MAX_SCALE}, got {d}"
        )));
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
        if let Some(d) = &p.dark {
            check(&format!("{}_dark", p.name), d)?;
        }
    }
    if let Some(r) = &references {
        check("reference dx", r.dx)?;
        check("reference dy", r.dy)?;
        if let Some(d) = r.dark {
            check("reference dark", d)?;
        }
    }
    // Saturation is judged on the frames as the camera gave them.
    let raw_pairs = pairs;
    // LED light alone when every press has its LEDs-off frame.
    let light = led_light(pairs, references);
    let (ambient, ambient_warning) = (light.ambient, light.warning);
    let led_only: Vec<CalibrationPair>;
    let pairs: &[CalibrationPair] = match light.led_pairs {
        Some(led) => {
            led_only = led;
            &led_only
        }
        None => pairs,
    };
    let (ref_dx, ref_dy) = match (references, &ambient) {
        (Some(r), Some(estimate)) => {
            let dark = match r.dark {
                Some(d) => d.clone(),
                None => estimate.image(want.0, want.1),
            };
            (subtracted(r.dx, &dark), subtracted(r.dy, &dark))
        }
        (Some(r), None) => (r.dx.clone(), r.dy.clone()),
        (None, _) => {
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
    phase_check::check_pair(
        &ref_dx,
        &ref_dy,
        &settings.filter,
        if references.is_some() {
            "reference frames"
        } else {
            "median of the presses (the background without reference frames)"
        },
    )?;
    let refs = References {
        dx: Reference::from_image(&ref_dx, settings.filter.unmix),
        dy: Reference::from_image(&ref_dy, settings.filter.unmix),
    };
    let (w, h) = (want.0 as usize, want.1 as usize);
    // Names in order, so the same file always reports the same circle first.
    let mut given: Vec<_> = settings.overrides.iter().collect();
    given.sort_by(|a, b| a.0.cmp(b.0));
    for (name, circle) in given {
        if let Some(why) = circle::given_circle_unfit(circle, w, h) {
            return Err(CalibrationError::GivenCircle {
                name: name.clone(),
                circle: *circle,
                why,
                width: w,
                height: h,
            });
        }
    }
    let ball_mm =
        |pair: &CalibrationPair| pair.ball_diameter_mm.unwrap_or(settings.ball_diameter_mm);
    let ball_px_of = |pair: &CalibrationPair| ball_mm(pair) / 2.0 * settings.px_per_mm;

    // A press with a frame without LED light, or its phases swapped, is set aside first,
    // saying so: its colours would otherwise count in the flat skin's noise below, and
    // it would be rejected as "no contact found" or "larger than the ball".
    // Each set-aside press with its index, to list them in the presses' order (names
    // may repeat).
    let mut set_aside: Vec<(usize, RejectedPress)> = Vec::new();
    let mut candidates = Vec::with_capacity(pairs.len());
    for (i, pair) in pairs.iter().enumerate() {
        match phase_check::check_pair(&pair.dx, &pair.dy, &settings.filter, "press") {
            Ok(()) => candidates.push(i),
            Err(e) => set_aside.push((
                i,
                RejectedPress {
                    name: pair.name.clone(),
                    circle: None,
                    reason: Rejection::NotPhasePair { why: e.to_string() },
                },
            )),
        }
    }

    // Press outlines, on box means around each pixel, with a threshold measured on the
    // frames' flat skin.
    let maps: Vec<Vec<f32>> = candidates
        .iter()
        .map(|&i| threshold::outline_map(&pairs[i], &refs, &settings.filter))
        .collect();
    let fit_all = |t: f32| -> Vec<Option<OutlineFit>> {
        maps.iter()
            .map(|m| {
                let unknown: Vec<bool> = m.iter().map(|d| d.is_nan()).collect();
                circle::fit_outline(m.iter().map(|&d| d > t).collect(), Some(&unknown), w, h)
            })
            .collect()
    };
    let circles_of = |fits: &[Option<OutlineFit>]| -> Vec<Option<Circle>> {
        fits.iter().map(|f| f.map(|f| f.circle)).collect()
    };
    let first_threshold = threshold::provisional(&maps);
    let first = fit_all(first_threshold);
    let outline_noise = threshold::from_flat_skin(
        &maps,
        &circles_of(&first),
        w,
        h,
        threshold::FLAT_CLEARANCE_PX,
    );
    let outline_threshold = outline_noise.map_or(first_threshold, |n| n.threshold);
    let fits = fit_all(outline_threshold);
    drop(maps);

    // The detection threshold, on block means; measured also when it is fixed, to warn
    // when the one given is within the flat skin's noise.
    let mut contact_params = settings.contact;
    let step = contact_params.coarse_step.max(1);
    let block_refs = contact::block_references(&ref_dx, &ref_dy, step, settings.filter.unmix);
    let blocks: Vec<Vec<f32>> = candidates
        .iter()
        .map(|&i| threshold::block_map(&pairs[i], &block_refs, &settings.filter, step))
        .collect();
    let circles: Vec<Option<Circle>> = circles_of(&fits)
        .iter()
        .map(|c| c.map(|c| threshold::in_blocks(&c, step)))
        .collect();
    let measured = threshold::from_flat_skin(
        &blocks,
        &circles,
        w.div_ceil(step),
        h.div_ceil(step),
        threshold::FLAT_CLEARANCE_PX / step as f64,
    );
    // Something the references show and the presses do not (or every press made at one
    // place) departs in most presses at the same place: refused, or every frame the
    // model reads would show it as a contact.
    // (A press whose circle was given votes with that circle.)
    let voting: Vec<Option<Circle>> = candidates
        .iter()
        .zip(&circles)
        .map(|(&i, c)| {
            settings
                .overrides
                .get(&pairs[i].name)
                .map(|given| threshold::in_blocks(given, step))
                .or(*c)
        })
        .collect();
    if let Some(shared) = shared_departure::find(
        &blocks,
        &voting,
        w.div_ceil(step),
        h.div_ceil(step),
        // The flat skin's own threshold, also when another is given.
        measured.map_or(contact_params.threshold, |n| n.threshold),
        contact_params.min_cells,
    ) {
        let px = |b: f64| ((b + 0.5) * step as f64).round();
        let mm2 = (shared.cells * step * step) as f64 / settings.px_per_mm.powi(2);
        return Err(CalibrationError::SharedDeparture {
            x: px(shared.centre.0),
            y: px(shared.centre.1),
            area_mm2: mm2,
            departs_in: shared.departs_in,
            given: references.is_some(),
        });
    }
    drop(blocks);
    let mut noise = None;
    let mut fixed_warning = None;
    match measured {
        Some(n) if !settings.fixed_threshold => {
            contact_params.threshold = n.threshold;
            noise = measured;
        }
        Some(n) if contact_params.threshold < n.p9999 => {
            let fix = if n.threshold > n.p9999 {
                format!(
                    "give at least {:.3} (the threshold measured here), or leave it to be \
                     measured",
                    n.threshold
                )
            } else {
                // The measured one is held at the bound, itself within the noise.
                "this skin is noisier than any threshold up to the bound: check the \
                 reference frames and the light"
                    .to_string()
            };
            fixed_warning = Some(format!(
                "the contact threshold given ({:.3}) is below how far flat skin departs from \
                 the references in these frames ({:.3}, 99.99th percentile): a skin at rest \
                 will read as contact in places; {fix}",
                contact_params.threshold, n.p9999
            ));
        }
        _ => {}
    }

    let mut presses = Vec::with_capacity(pairs.len());
    let mut used = Vec::with_capacity(pairs.len());
    for (&index, fit) in candidates.iter().zip(&fits) {
        let pair = &pairs[index];
        progress(CalibrationProgress::Circles {
            done: index + 1,
            total: pairs.len(),
        });
        let (circle, overridden, fit_rms_px) = match (settings.overrides.get(&pair.name), fit) {
            (Some(c), _) => (*c, true, 0.0),
            (None, Some(f)) => {
                // The outline came from smoothed colours; the rim is refined on the
                // pixels' own colours, averaged around the circumference.
                let refined = circle::refine_radius(
                    &f.circle,
                    w,
                    h,
                    2.0 * threshold::OUTLINE_BOX_RADIUS as f64 + 4.0,
                    |x, y| {
                        let (c, d) = contact::pixel_colours(
                            &refs,
                            &settings.filter,
                            &pair.dx,
                            &pair.dy,
                            x,
                            y,
                        );
                        if c.iter().any(|v| v.is_nan()) {
                            f32::NAN
                        } else {
                            d
                        }
                    },
                );
                let circle = Circle {
                    r: refined.unwrap_or(f.circle.r),
                    ..f.circle
                };
                (circle, false, f.rms_px)
            }
            (None, None) => {
                set_aside.push((
                    index,
                    RejectedPress {
                        name: pair.name.clone(),
                        circle: None,
                        reason: Rejection::NoContact {
                            threshold: outline_threshold,
                        },
                    },
                ));
                continue;
            }
        };
        let (ball_px, ball_mm) = (ball_px_of(pair), ball_mm(pair));
        let max_contact_px =
            ball_px * (1.0 - (1.0 - MAX_DEPTH_OF_RADIUS) * (1.0 - MAX_DEPTH_OF_RADIUS)).sqrt();
        // How deep a ball of this size went to leave this circle (the sagitta); NaN when
        // the circle is larger than the ball, which the first check sets aside.
        let depth_px = ball_px - (ball_px * ball_px - circle.r * circle.r).sqrt();
        let depth_mm = depth_px / settings.px_per_mm;
        let reason = if !(circle.r.is_finite() && circle.r <= max_contact_px) {
            Some(Rejection::TooLarge {
                contact_px: circle.r,
                max_px: max_contact_px,
                ball_mm,
            })
        } else if circle.r < 3.0 || depth_px < 0.02 * settings.px_per_mm {
            Some(Rejection::TooSmall {
                contact_px: circle.r,
                ball_mm,
            })
        } else {
            match fit {
                Some(f) if !overridden && !f.is_round() => Some(Rejection::NotCircular {
                    rms_px: f.rms_px,
                    inlier_fraction: f.inlier_fraction,
                }),
                _ => None,
            }
        };
        // dx and dy of different presses: each phase departs at its own press, and the
        // circle found is one of them (a pair of two presses among 16 read every depth
        // of the model it made 10–15 % deep). Said before what its circle looks like
        // (two presses' outline is often no circle): the calibration is made again
        // without such pairs (see `calibrate_dyn`).
        let apart = circle.r.is_finite().then(|| {
            let [dx, dy] = phase_departures_inside(&refs, &settings.filter, pair, &circle);
            let (weaker, share) = if dx < dy {
                ("dx", dx / dy)
            } else {
                ("dy", dy / dx)
            };
            // Neither phase read inside (saturated, unlit): said by other checks.
            (dx.max(dy) > 0.0 && share < MIN_PHASE_SHARE)
                .then_some(Rejection::PhasesApart { weaker, share })
        });
        let reason = apart.flatten().or(reason);
        let reason = reason.or_else(|| {
            (depth_mm > settings.skin_thickness_mm).then_some(Rejection::DeeperThanSkin {
                depth_mm,
                skin_mm: settings.skin_thickness_mm,
                ball_mm,
            })
        });
        if let Some(reason) = reason {
            set_aside.push((
                index,
                RejectedPress {
                    name: pair.name.clone(),
                    circle: Some(circle),
                    reason,
                },
            ));
            continue;
        }
        presses.push(PressFit {
            name: pair.name.clone(),
            circle,
            depth_mm,
            overridden,
            fit_rms_px,
            ball_diameter_mm: ball_mm,
            saturated: saturated_in_contact(&raw_pairs[index], &circle, settings.filter.saturation),
        });
        used.push(pair);
    }
    // In the presses' order (those without LED light were set aside first).
    set_aside.sort_by_key(|(index, _)| *index);
    let apart: Vec<(usize, RejectedPress)> = set_aside
        .iter()
        .filter(|(_, r)| matches!(r.reason, Rejection::PhasesApart { .. }))
        .cloned()
        .collect();
    if !apart.is_empty() {
        return Ok(Attempt::Again(apart));
    }
    let rejected: Vec<RejectedPress> = set_aside.into_iter().map(|(_, r)| r).collect();
    if presses.len() < settings.min_presses.max(1) {
        return Err(CalibrationError::TooFewPresses {
            good: presses.len(),
            total: pairs.len(),
            needed: settings.min_presses.max(1),
            rejected,
        });
    }
    let joint: Vec<Vec<JointSample>> = used
        .iter()
        .zip(&presses)
        .map(|(pair, press)| {
            let ball_px = ball_px_of(pair);
            samples(pair, &refs, &settings.filter, press.circle, ball_px, w, h)
        })
        .collect();

    // Hold out every fifth press for validation when there are enough.
    let count = joint.len();
    let holdout = |i: usize| count >= 5 && i % 5 == 4;
    let mut axes = Vec::with_capacity(2);
    let mut fit_report = FitReport {
        training_pairs: (0..count).filter(|&i| !holdout(i)).count(),
        validation_pairs: (0..count).filter(|&i| holdout(i)).count(),
        ..Default::default()
    };
    // Both phases at once, from the same presses.
    let split = |keep: bool| -> Vec<JointSample> {
        joint
            .iter()
            .enumerate()
            .filter(|(i, _)| holdout(*i) == keep)
            .flat_map(|(_, s)| s.iter().copied())
            .collect()
    };
    let (joint_train, joint_valid) = (split(false), split(true));
    // Each axis' samples, as the models read them.
    let [plain_train, plain_valid] =
        [&joint_train, &joint_valid].map(|set| table_samples(set, None));
    // The strips' side light in the cross factor, and the tables' samples corrected by
    // it when there is one (every training and held-out sample: the report's fit per
    // region is the table's).
    let side_light = settings
        .side_light
        .then(|| SideLight::fit(&joint_train))
        .flatten();
    let corrected = side_light
        .as_ref()
        .map(|side| [&joint_train, &joint_valid].map(|set| table_samples(set, Some(side))));
    let [lut_train, lut_valid] = match &corrected {
        Some([train, valid]) => [train, valid],
        None => [&plain_train, &plain_valid],
    };
    let mut all_samples: [Vec<Sample>; 2] = [Vec::new(), Vec::new()];
    for (axis, all) in all_samples.iter_mut().enumerate() {
        let (train, valid) = (&plain_train[axis], &plain_valid[axis]);
        let lut = Lut::fit(
            &lut_train[axis],
            settings.lut_bins,
            LUT_MAX_COLOUR,
            settings.lut_cells.0,
            settings.lut_cells.1,
        );
        let epochs = settings.mlp.epochs;
        let mlp = Mlp::fit(train, &settings.mlp, |epoch, rms| {
            progress(CalibrationProgress::Mlp {
                axis,
                epoch,
                epochs,
                rms,
            })
        });
        let light = LightModel::fit(train, settings.lut_cells.0, settings.lut_cells.1);
        let model = AxisModel {
            lut,
            mlp,
            light: Some(light),
        };
        // The table is measured on its own (corrected) samples.
        let rms = |kind, set: &[Sample], table: &[Sample]| {
            rms_error(
                &model,
                kind,
                if kind == ModelKind::Lut { table } else { set },
            )
        };
        fit_report.samples_per_axis = fit_report.samples_per_axis.max(train.len());
        // The worse of the two axes.
        for (kind, train_rms, validation_rms) in [
            (
                ModelKind::Lut,
                &mut fit_report.lut_train_rms,
                &mut fit_report.lut_validation_rms,
            ),
            (
                ModelKind::Mlp,
                &mut fit_report.mlp_train_rms,
                &mut fit_report.mlp_validation_rms,
            ),
            (
                ModelKind::Light,
                &mut fit_report.light_train_rms,
                &mut fit_report.light_validation_rms,
            ),
        ] {
            *train_rms = train_rms.max(rms(kind, train, &lut_train[axis]));
            *validation_rms = validation_rms.max(rms(kind, valid, &lut_valid[axis]));
        }
        all.extend_from_slice(&lut_train[axis]);
        all.extend_from_slice(&lut_valid[axis]);
        axes.push(model);
    }
    let dy = axes.pop().expect("two axes");
    let dx = axes.pop().expect("two axes");
    let photometric =
        PhotometricModel::fit(&joint_train, settings.lut_cells.0, settings.lut_cells.1);
    fit_report.photometric_train_rms = photometric_rms(&photometric, &joint_train).0;
    (
        fit_report.photometric_validation_rms,
        fit_report.photometric_validation_read,
    ) = photometric_rms(&photometric, &joint_valid);
    // The other balls of the presses used, smallest first, each once.
    let mut other_balls_mm: Vec<f64> = presses
        .iter()
        .map(|p| p.ball_diameter_mm)
        .filter(|&d| d != settings.ball_diameter_mm)
        .collect();
    other_balls_mm.sort_by(f64::total_cmp);
    other_balls_mm.dedup();
    let mut model = TactileModel {
        format: MODEL_FORMAT.to_string(),
        version: MODEL_VERSION,
        width: w,
        height: h,
        px_per_mm: settings.px_per_mm,
        ball_diameter_mm: settings.ball_diameter_mm,
        other_balls_mm,
        skin_thickness_mm: settings.skin_thickness_mm,
        filter: settings.filter,
        contact: contact_params,
        background: Background::from_images(&ref_dx, &ref_dy, settings.background_factor.max(1)),
        ambient,
        dx,
        dy,
        photometric: Some(photometric),
        side_light,
        camera_curve: settings.camera_curve,
        fit: fit_report,
    };
    let left_out = model.leave_out_misdirected();
    crate::tactile::model::validate::check(&model).map_err(|(field, why)| {
        CalibrationError::ModelFailsCheck {
            field,
            why,
            presses: presses.len(),
        }
    })?;
    let mut report = CalibrationReport::new(
        &model,
        &presses,
        &rejected,
        pairs.len(),
        settings.min_presses,
        (outline_threshold, noise),
        &all_samples,
    );
    report.warnings.extend(ambient_warning);
    report.warnings.extend(fixed_warning);
    report.warnings.extend(left_out);
    Ok(Attempt::Done(Box::new(Calibration {
        model,
        presses,
        rejected,
        report,
    })))
}

/// Presses in the light the model will work on (see [`calibrate`]).
struct Light {
    /// The presses minus their own LEDs-off frames, when the model works on LED light.
    led_pairs: Option<Vec<CalibrationPair>>,
    /// The mean ambient light the model keeps (with `led_pairs`).
    ambient: Option<AmbientEstimate>,
    /// Why LEDs-off frames that were given are not used.
    warning: Option<String>,
}

/// LED light alone when every press (and the references, if they have one) comes with a
/// LEDs-off frame that is not brighter than its lit frames; raw frames otherwise, with
/// the reason when LEDs-off frames were given.
fn led_light(pairs: &[CalibrationPair], references: Option<PhaseFrames<'_>>) -> Light {
    let ignored = |why: String| Light {
        led_pairs: None,
        ambient: None,
        warning: Some(format!(
            "LEDs-off frames ignored: {why}; the model works on raw frames"
        )),
    };
    let with_dark = pairs.iter().filter(|p| p.dark.is_some()).count();
    if pairs.is_empty() || with_dark < pairs.len() {
        if with_dark > 0 || references.is_some_and(|r| r.dark.is_some()) {
            return ignored(format!(
                "{with_dark} of {} presses have one (all or none)",
                pairs.len()
            ));
        }
        return Light {
            led_pairs: None,
            ambient: None,
            warning: None,
        };
    }
    // LEDs only add light: a LEDs-off frame brighter than its lit frames does not show
    // their scene light.
    let too_bright = |name: &str, fraction: f64| {
        ignored(format!(
            "{name}'s is brighter than its lit frames in {:.0}% of the frame (the LEDs only \
             add light: it shows other light, such as another exposure or another camera's \
             view)",
            fraction * 100.0
        ))
    };
    if let Some(r) = references
        && let Some(dark) = r.dark
    {
        let fraction =
            ambient::brighter_fraction(r.dx, dark).max(ambient::brighter_fraction(r.dy, dark));
        if fraction > ambient::MAX_BRIGHTER_FRACTION {
            return too_bright("reference", fraction);
        }
    }
    let mut led = Vec::with_capacity(pairs.len());
    for p in pairs {
        let dark = p.dark.as_ref().expect("every press has one");
        let (mut dx, mut dy) = (RgbImage::new(0, 0), RgbImage::new(0, 0));
        let fraction = ambient::subtract_into(&p.dx, dark, &mut dx)
            .max(ambient::subtract_into(&p.dy, dark, &mut dy));
        if fraction > ambient::MAX_BRIGHTER_FRACTION {
            return too_bright(&p.name, fraction);
        }
        led.push(CalibrationPair {
            name: p.name.clone(),
            dx,
            dy,
            dark: None,
            ball_diameter_mm: p.ball_diameter_mm,
        });
    }
    let mut darks: Vec<&RgbImage> = pairs.iter().filter_map(|p| p.dark.as_ref()).collect();
    darks.extend(references.and_then(|r| r.dark));
    Light {
        ambient: AmbientEstimate::of(&darks),
        led_pairs: Some(led),
        warning: None,
    }
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

/// Below this share of the other phase's mean departure inside a press's circle, one
/// phase shows no press there ([`Rejection::PhasesApart`]). Over three skins of every
/// skin family (539 presses) the smaller phase's share was at least 0.29 (a press
/// centred on the frame's edge, half of it seen); a dx and a dy frame of two different
/// presses read 0.02.
const MIN_PHASE_SHARE: f64 = 0.12;

/// Mean departure from flat skin of the dx and of the dy frame (each phase's weighted
/// `Σ w·|colour − 1|`, see [`contact::colours_of`]) over the pixels inside circle `c`
/// that the colour filter reads in that phase (every other pixel of every other row);
/// 0 for a phase with none.
fn phase_departures_inside(
    refs: &References,
    filter: &ColourFilter,
    pair: &CalibrationPair,
    c: &Circle,
) -> [f64; 2] {
    let (w, h) = (pair.dx.width() as f64, pair.dx.height() as f64);
    let x0 = (c.cx - c.r).floor().clamp(0.0, w) as usize;
    let x1 = (c.cx + c.r).ceil().clamp(0.0, w) as usize;
    let y0 = (c.cy - c.r).floor().clamp(0.0, h) as usize;
    let y1 = (c.cy + c.r).ceil().clamp(0.0, h) as usize;
    let (mut sum, mut count) = ([0.0f64; 2], [0usize; 2]);
    for y in (y0..y1).step_by(2) {
        for x in (x0..x1).step_by(2) {
            let (dx, dy) = (x as f64 + 0.5 - c.cx, y as f64 + 0.5 - c.cy);
            if dx * dx + dy * dy >= c.r * c.r {
                continue;
            }
            let (colour, _) = contact::pixel_colours(refs, filter, &pair.dx, &pair.dy, x, y);
            let i = y * pair.dx.width() as usize + x;
            for (phase, reference) in [&refs.dx, &refs.dy].into_iter().enumerate() {
                let (r, b) = (colour[2 * phase], colour[2 * phase + 1]);
                if r.is_nan() {
                    continue;
                }
                let (wr, wb) = reference.weights(i);
                sum[phase] += f64::from(wr * (r - 1.0).abs() + wb * (b - 1.0).abs());
                count[phase] += 1;
            }
        }
    }
    [0, 1].map(|p| {
        if count[p] > 0 {
            sum[p] / count[p] as f64
        } else {
            0.0
        }
    })
}

/// Fraction of the pixels inside circle `c` with a channel at or above `saturation`, in
/// the dx and in the dy frame (0 for a circle with no pixel inside the frame).
fn saturated_in_contact(pair: &CalibrationPair, c: &Circle, saturation: u8) -> [f64; 2] {
    let (w, h) = (pair.dx.width() as f64, pair.dx.height() as f64);
    let x0 = (c.cx - c.r).floor().clamp(0.0, w) as u32;
    let x1 = (c.cx + c.r).ceil().clamp(0.0, w) as u32;
    let y0 = (c.cy - c.r).floor().clamp(0.0, h) as u32;
    let y1 = (c.cy + c.r).ceil().clamp(0.0, h) as u32;
    let mut inside = 0usize;
    let mut saturated = [0usize; 2];
    for y in y0..y1 {
        for x in x0..x1 {
            let (dx, dy) = (x as f64 + 0.5 - c.cx, y as f64 + 0.5 - c.cy);
            if dx * dx + dy * dy >= c.r * c.r {
                continue;
            }
            inside += 1;
            for (count, img) in saturated.iter_mut().zip([&pair.dx, &pair.dy]) {
                *count += usize::from(img.get_pixel(x, y).0.iter().any(|&v| v >= saturation));
            }
        }
    }
    saturated.map(|n| n as f64 / inside.max(1) as f64)
}

/// RMS slope error of the photometric model over the samples of `set` it reads (both
/// axes; 0 when it reads none), and the share of `set` it reads (the others are filled
/// from their neighbours in use; 0 for an empty set).
pub fn photometric_rms(model: &PhotometricModel, set: &[JointSample]) -> (f32, f32) {
    let (mut sq, mut n) = (0.0f64, 0usize);
    for s in set {
        if let Some(read) = model.read(s.colours, s.position[0], s.position[1]) {
            for (r, t) in read.iter().zip(s.slope) {
                sq += (f64::from(*r) - f64::from(t)).powi(2);
                n += 1;
            }
        }
    }
    let rms = if n == 0 {
        0.0
    } else {
        (sq / n as f64).sqrt() as f32
    };
    (rms, (n / 2) as f32 / set.len().max(1) as f32)
}

/// Training samples of one pair: pixels inside the contact with the sphere's slopes, and
/// a ring of flat skin around it with slope 0, both axes at once (each axis' samples:
/// [`table_samples`]).
fn samples(
    pair: &CalibrationPair,
    refs: &References,
    filter: &ColourFilter,
    c: Circle,
    ball_px: f64,
    w: usize,
    h: usize,
) -> Vec<JointSample> {
    let mut joint = Vec::new();
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
            joint.push(JointSample {
                colours: colour,
                position,
                slope: slopes.map(|s| s as f32),
            });
        }
    }
    joint
}

/// The models' samples of `joint` per axis: each phase's model colours
/// ([`colour_features`]) where it was read; with `side`, times the side light's factor
/// with the true slopes where both phases were read (the lookup tables' samples).
fn table_samples(joint: &[JointSample], side: Option<&SideLight>) -> [Vec<Sample>; 2] {
    let mut out = [Vec::new(), Vec::new()];
    for s in joint {
        let [x, y] = s.position;
        let features = colour_features(s.colours);
        let factors = match (side, features) {
            (Some(side), [Some(_), Some(_)]) => {
                side_light::factors(side.at(x, y), s.slope[0], s.slope[1])
            }
            _ => [1.0; 2],
        };
        for (axis, f) in features.into_iter().enumerate() {
            if let Some([r, b]) = f {
                out[axis].push(Sample {
                    features: [r * factors[axis], b * factors[axis], x, y],
                    target: s.slope[axis],
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_from_too_few_presses_says_so_before_suspecting_the_frames() {
        let fails = |presses| {
            CalibrationError::ModelFailsCheck {
                field: "dx.mlp".into(),
                why: "reads the slope's direction wrongly".into(),
                presses,
            }
            .to_string()
        };
        let one = fails(1);
        assert!(
            one.contains("1 press(es) used")
                && one.contains("too few")
                && one.contains("--min-presses")
                && one.contains("min_presses")
                && one.contains("If that is not it, check that the dx and dy frames"),
            "{one}"
        );
        let many = fails(30);
        assert!(
            many.contains("30 press(es) used")
                && !many.contains("too few")
                && many.contains("reads: check that the dx and dy frames are not swapped"),
            "{many}"
        );
    }

    #[test]
    fn saturation_inside_the_contact_is_a_share_of_its_pixels() {
        // A 40×30 pair: the dx frame saturated (one channel at the line) on the left half
        // of the frame, the dy frame one channel short of it everywhere.
        let dx = RgbImage::from_fn(40, 30, |x, _| {
            if x < 20 {
                image::Rgb([10, 250, 10])
            } else {
                image::Rgb([200, 20, 90])
            }
        });
        let dy = RgbImage::from_pixel(40, 30, image::Rgb([249, 249, 249]));
        let pair = CalibrationPair {
            name: "p".into(),
            dx,
            dy,
            dark: None,
            ball_diameter_mm: None,
        };
        // Centred on the boundary: half of the pixel centres inside lie left of it.
        let c = Circle {
            cx: 20.0,
            cy: 15.0,
            r: 8.0,
        };
        let [sx, sy] = saturated_in_contact(&pair, &c, 250);
        assert_eq!(sx, 0.5);
        assert_eq!(sy, 0.0);
        // Wholly inside the saturated half, partly outside the frame, and outside it.
        let left = Circle { cx: 2.0, ..c };
        assert_eq!(saturated_in_contact(&pair, &left, 250), [1.0, 0.0]);
        assert_eq!(saturated_in_contact(&pair, &left, 251), [0.0, 0.0]);
        let gone = Circle { cx: -50.0, ..c };
        assert_eq!(saturated_in_contact(&pair, &gone, 250), [0.0, 0.0]);
        let nan = Circle { r: f64::NAN, ..c };
        assert_eq!(saturated_in_contact(&pair, &nan, 250), [0.0, 0.0]);
    }
}
