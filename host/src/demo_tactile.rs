//! The tactile half of `stereotac demo`: for each object, a dx/dy frame pair from a
//! simulated camera triggered by the simulated sensor, through the host path a real
//! sensor uses (loopback USB, clock sync, frame/LED matcher); calibration on simulated
//! ball presses; then reconstruction from the captured frames with accuracy, timings
//! and files.

use std::path::Path;

use std::sync::Arc;
use std::time::Duration;

use crate::progress::bar;
use anyhow::{Context, Result, bail};
use stereotac::clock::{HostClock, VirtualClock};
use stereotac::device::{Sensor, SensorConfig, connect_once};
use stereotac::frames::capture::{Capture, LabelledFrame};
use stereotac::frames::sim::{PhaseImages, SimClocking, SimulatedCamera};
use stereotac::matcher::{CameraSync, Label, MatcherConfig};
use stereotac::tactile::calibrate::{CalibrationProgress, CalibrationSettings, calibrate};
use stereotac::tactile::model::ModelKind;
use stereotac::tactile::output;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;
use stereotac::tactile::render::{Optics, Scene, builtin_scenes};
use stereotac::tactile::synthetic::{CALIBRATION_BALL_MM, ball_presses, reference_frames};
use stereotac::transport::loopback::{LedTimeline, Loopback, LoopbackConfig};
use stereotac_protocol::{Mode, Phase, Request};

/// Presses rendered for the demo's calibration.
const PRESSES: usize = 16;
/// Simulated camera: exposure starts this long after the trigger edge (µs).
const CAMERA_LATENCY_US: f64 = 150.0;
/// Simulated camera exposure (µs).
const EXPOSURE_US: f64 = 8000.0;
/// Give up on a dx/dy pair after this much simulated time (µs).
const PAIR_TIMEOUT_US: u64 = 10_000_000;

/// A dx/dy pair of camera frames, labelled by the matcher.
struct Pair {
    dx: LabelledFrame,
    dy: LabelledFrame,
}

/// The simulated sensor behind the loopback USB link (virtual clock, drifting device
/// clock), connected through the same [`Sensor`] code a real sensor uses.
fn connect_simulated() -> Result<(Sensor, Arc<std::sync::Mutex<LedTimeline>>)> {
    let clock: Arc<dyn HostClock> = Arc::new(VirtualClock::starting_at(1_000_000));
    let link = Loopback::new(
        *b"SIMULATD",
        Arc::clone(&clock),
        LoopbackConfig {
            drift_ppm: 30.0,
            ..LoopbackConfig::default()
        },
    );
    let timeline = link.timeline();
    let sensor = Sensor::connect(connect_once(link), clock, SensorConfig::default())?;
    Ok((sensor, timeline))
}

/// With the camera's current scene pressed into the skin, capture until the matcher has
/// labelled a dx frame followed by a dy frame.
fn capture_pair(sensor: &mut Sensor, capture: &mut Capture<SimulatedCamera>) -> Result<Pair> {
    let pressed_at = sensor.clock().now_us();
    let give_up = pressed_at + PAIR_TIMEOUT_US;
    let mut dx: Option<LabelledFrame> = None;
    while sensor.clock().now_us() < give_up {
        for frame in capture.step(sensor, Duration::from_millis(20))?.frames {
            if frame.frame.stamp.timestamp_us < pressed_at as f64 {
                continue; // exposed before this object was pressed
            }
            match (frame.label, dx.take()) {
                (
                    Label::Phase {
                        phase: Phase::Dx, ..
                    },
                    _,
                ) => dx = Some(frame),
                (
                    Label::Phase {
                        phase: Phase::Dy, ..
                    },
                    Some(first),
                ) => {
                    return Ok(Pair {
                        dx: first,
                        dy: frame,
                    });
                }
                // A dy without its dx, or a frame the matcher could not label: start over.
                _ => {}
            }
        }
    }
    bail!(
        "no labelled dx/dy pair within {} s",
        PAIR_TIMEOUT_US / 1_000_000
    )
}

/// `#trigger@ms` of a labelled frame.
fn frame_tag(f: &LabelledFrame) -> String {
    let trigger = match f.label {
        Label::Phase {
            trigger: Some(t), ..
        } => t.to_string(),
        _ => "-".into(),
    };
    format!("#{trigger}@{:.0}", f.frame.stamp.timestamp_us / 1000.0)
}

pub fn run(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let optics = Optics::standard();
    let scenes: Vec<(&str, Scene)> = builtin_scenes(&optics);
    println!("\n--- tactile: photometric stereo on the simulated skin ---");
    // The host path of a real sensor: loopback USB, clock sync, triggered camera, matcher.
    let (mut sensor, timeline) = connect_simulated()?;
    sensor.request(Request::SetMode(Mode::Gradient))?;
    sensor.request(Request::Start)?;
    let camera = SimulatedCamera::new(
        timeline,
        Arc::clone(sensor.clock()),
        SimClocking::Triggered {
            latency_us: CAMERA_LATENCY_US,
        },
        EXPOSURE_US,
        PhaseImages::render(&optics, &scenes[0].1),
    );
    let mut capture = Capture::new(
        camera,
        MatcherConfig {
            sync: CameraSync::Triggered {
                latency_us: CAMERA_LATENCY_US,
                tolerance_us: 300.0,
            },
            ..MatcherConfig::default()
        },
    );
    let progress = bar(scenes.len() as u64, "capturing");
    let mut pairs = Vec::new();
    for (_, scene) in &scenes {
        // Press the next object; the frames after the switch show it.
        capture
            .source_mut()
            .set_images(PhaseImages::render(&optics, scene));
        pairs.push(capture_pair(&mut sensor, &mut capture)?);
        progress.inc(1);
    }
    sensor.request(Request::Stop)?;
    progress.finish_and_clear();
    let stats = capture.stats();
    let labelled = stats.labelled;
    let rejected = stats.straddling + stats.event_missing + stats.no_trigger;
    let fit = sensor.clock_fit();
    println!(
        "captured {} dx/dy pairs from a camera triggered by the sensor (exposure {EXPOSURE_US} µs starting {CAMERA_LATENCY_US} µs after each edge): {labelled} frames labelled by the matcher, {rejected} rejected; clock sync ±{:.1} µs, device drift {:+.1} ppm",
        pairs.len(),
        fit.map_or(f64::NAN, |f| f.uncertainty_us),
        fit.map_or(f64::NAN, |f| f.drift_ppm()),
    );

    let presses = ball_presses(&optics, PRESSES, CALIBRATION_BALL_MM, 42);
    let refs = reference_frames(&optics);
    let settings = CalibrationSettings {
        ball_diameter_mm: CALIBRATION_BALL_MM,
        px_per_mm: optics.px_per_mm,
        ..Default::default()
    };
    let progress = bar((PRESSES + 2 * settings.mlp.epochs) as u64, "calibrating");
    let calibration = calibrate(&presses, Some((&refs.0, &refs.1)), &settings, |p| match p {
        CalibrationProgress::Circles { done, .. } => progress.set_position(done as u64),
        CalibrationProgress::Mlp {
            axis,
            epoch,
            epochs,
            ..
        } => progress.set_position((PRESSES + axis * epochs + epoch) as u64),
    })?;
    progress.finish_and_clear();
    let fit = calibration.model.fit;
    println!(
        "calibrated on {PRESSES} simulated {CALIBRATION_BALL_MM} mm ball presses: slope RMS lut {:.3} (held-out {:.3}), mlp {:.3} (held-out {:.3})",
        fit.lut_train_rms, fit.lut_validation_rms, fit.mlp_train_rms, fit.mlp_validation_rms
    );
    calibration.model.save(&out.join("model.json"))?;
    let px_per_mm = calibration.model.px_per_mm;
    let mut reconstructor = Reconstructor::new(
        calibration.model,
        ModelKind::Lut,
        SolverKind::Dct,
        Some((&refs.0, &refs.1)),
    )?;

    println!(
        "\n{:<11} {:>10} {:>10} | {:>9} {:>9} {:>9} | {:>8}",
        "object", "dx frame", "dy frame", "true mm", "read mm", "rms mm", "time ms"
    );
    for ((name, scene), pair) in scenes.iter().zip(&pairs) {
        // Reconstruct from the frames the camera delivered, as labelled by the matcher.
        let r = reconstructor.reconstruct(&pair.dx.frame.image, &pair.dy.frame.image)?;
        let truth = scene
            .truth(optics.width, optics.height, optics.px_per_mm)
            .depth;
        let e = stereotac::tactile::bench::errors(&r.depth_mm, &truth);
        output::write_all(&out.join(name), &r, px_per_mm)?;
        println!(
            "{:<11} {:>10} {:>10} | {:>9.3} {:>9.3} {:>9.4} | {:>8.2}",
            name,
            frame_tag(&pair.dx),
            frame_tag(&pair.dy),
            e.true_peak_mm,
            e.reading_mm,
            e.rms_mm,
            r.timings.total_ms
        );
    }
    println!(
        "\n(read = median depth where the truth is ≥ 95 % of its peak; frames as #trigger@ms)\noutputs (depth.npy, depth16.png, depth_colour.png, depth.ply, summary.json per object, model.json) in {}",
        out.display()
    );
    Ok(())
}
