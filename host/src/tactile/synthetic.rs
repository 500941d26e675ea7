//! Built-in data from our renderer: ball presses for calibration and reference frames,
//! shared by the demo, the benchmark and the tests.

use image::RgbImage;

use super::calibrate::{
    Calibration, CalibrationError, CalibrationPair, CalibrationProgress, CalibrationSettings,
    calibrate,
};
use super::render::{Optics, Scene, Shape, render};
use crate::rng::Rng;

/// Ball diameter used for the built-in calibration presses (mm).
pub const CALIBRATION_BALL_MM: f64 = 6.0;

/// `count` presses of a ball of `diameter` mm at random places (some near the frame
/// edges), 0.5–1.5 mm deep.
pub fn ball_presses(
    optics: &Optics,
    count: usize,
    diameter: f64,
    seed: u64,
) -> Vec<CalibrationPair> {
    let mut rng = Rng::new(seed);
    let (w, h) = (
        optics.width as f64 / optics.px_per_mm,
        optics.height as f64 / optics.px_per_mm,
    );
    let margin = diameter * 0.2;
    (0..count)
        .map(|k| {
            let scene = Scene {
                shapes: vec![Shape::Ball {
                    cx: rng.range(margin, w - margin),
                    cy: rng.range(margin, h - margin),
                    diameter,
                    depth: rng.range(0.5, 1.5).min(diameter / 2.0 * 0.9),
                }],
            };
            let pair = render(optics, &scene, 1000 + k as u64);
            CalibrationPair {
                name: format!("press{k:02}"),
                dx: pair.dx,
                dy: pair.dy,
                dark: None,
                ball_diameter_mm: None,
            }
        })
        .collect()
}

/// No-contact dx and dy frames, averaged over 8 frames like a real capture would be.
pub fn reference_frames(optics: &Optics) -> (RgbImage, RgbImage) {
    let quiet = Optics {
        noise: optics.noise / 8f64.sqrt(),
        ..optics.clone()
    };
    let pair = render(&quiet, &Scene::default(), 999);
    (pair.dx, pair.dy)
}

/// Presses in the built-in calibration of the demo and `run --sim`.
pub const BUILTIN_PRESSES: usize = 16;

/// The simulated sensor's own calibration: `presses` presses of the
/// [`CALIBRATION_BALL_MM`] ball rendered with `optics`, against its reference frames,
/// which are returned with it. The demo and `run --sim` (with [`BUILTIN_PRESSES`], when
/// no model is given) and the benchmark use it.
pub fn builtin_calibration(
    optics: &Optics,
    presses: usize,
    progress: impl FnMut(CalibrationProgress),
) -> Result<(Calibration, (RgbImage, RgbImage)), CalibrationError> {
    let pairs = ball_presses(optics, presses, CALIBRATION_BALL_MM, 42);
    let refs = reference_frames(optics);
    let settings = CalibrationSettings {
        ball_diameter_mm: CALIBRATION_BALL_MM,
        px_per_mm: optics.px_per_mm,
        ..Default::default()
    };
    let calibration = calibrate(&pairs, Some((&refs.0, &refs.1).into()), &settings, progress)?;
    Ok((calibration, refs))
}
