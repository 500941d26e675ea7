//! One progress-bar style for every long-running command of the CLI, and the long steps
//! more than one command shows a bar for.

use anyhow::Result;
use image::RgbImage;
use indicatif::{ProgressBar, ProgressStyle};
use stereotac::tactile::calibrate::{Calibration, CalibrationProgress, CalibrationSettings};
use stereotac::tactile::render::Optics;
use stereotac::tactile::synthetic::{self, BUILTIN_PRESSES};

/// A bar of `len` steps labelled `what`.
pub fn bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg:>28} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// A counter without a known end (recording), labelled `what`.
pub fn spinner(what: &str) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {prefix} {pos} frames, {elapsed} {msg}")
            .expect("static template"),
    );
    bar.set_prefix(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// The simulated sensor's built-in calibration (the demo's, and `run --sim`'s model when
/// none is given), with a progress bar; `instead` says how to skip it (the command's own
/// flag), when the command has one.
pub fn builtin_calibration(
    optics: &Optics,
    instead: Option<&str>,
) -> Result<(Calibration, (RgbImage, RgbImage))> {
    let epochs = CalibrationSettings::default().mlp.epochs;
    let progress = bar((BUILTIN_PRESSES + 2 * epochs) as u64, "calibrating");
    // Without a terminal the bar is not drawn: say what the wait is (it was ~10 s of
    // silence before the first line).
    let started = std::time::Instant::now();
    if progress.is_hidden() {
        let instead = instead.map(|i| format!(" ({i})")).unwrap_or_default();
        eprintln!(
            "calibrating the simulated sensor's built-in tactile model from {BUILTIN_PRESSES} \
             rendered ball presses{instead}..."
        );
    }
    let calibration = synthetic::builtin_calibration(optics, BUILTIN_PRESSES, |p| match p {
        CalibrationProgress::Circles { done, .. } => progress.set_position(done as u64),
        CalibrationProgress::Mlp {
            axis,
            epoch,
            epochs,
            ..
        } => progress.set_position((BUILTIN_PRESSES + axis * epochs + epoch) as u64),
    });
    progress.finish_and_clear();
    if progress.is_hidden() {
        eprintln!(
            "built-in tactile model calibrated in {:.1} s",
            started.elapsed().as_secs_f64()
        );
    }
    Ok(calibration?)
}
