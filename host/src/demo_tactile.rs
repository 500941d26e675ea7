//! The tactile half of `stereotac demo`: gradient frames captured at the simulated
//! sensor's trigger edges and labelled by its phase events, calibration on simulated
//! ball presses, then reconstruction of a few objects with accuracy, timings and files.

use std::path::Path;

use crate::progress::bar;
use anyhow::{Context, Result, bail};
use stereotac::client::Client;
use stereotac::sim::SimulatedSensor;
use stereotac::tactile::calibrate::{CalibrationProgress, CalibrationSettings, calibrate};
use stereotac::tactile::model::ModelKind;
use stereotac::tactile::output;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;
use stereotac::tactile::render::{Optics, Scene, builtin_scenes, render};
use stereotac::tactile::synthetic::{CALIBRATION_BALL_MM, ball_presses, reference_frames};
use stereotac_protocol::{Event, Mode, Phase, PhaseEvent, Request, TriggerOutcome};

/// Presses rendered for the demo's calibration.
const PRESSES: usize = 16;
/// Simulated camera: frame timestamp = trigger edge + this latency (µs).
const CAMERA_LATENCY_US: u64 = 150;

/// One simulated camera frame: when it was exposed, and what lit it.
struct Frame {
    timestamp_us: u64,
    phase: Phase,
    trigger: u32,
}

/// Runs gradient mode for `pairs` dx/dy pairs and returns camera frames labelled with the
/// phase whose trigger edge precedes each frame's timestamp by the camera latency.
fn capture_labelled_frames(
    client: &mut Client<SimulatedSensor>,
    pairs: usize,
) -> Result<Vec<Frame>> {
    client.request(Request::SetMode(Mode::Gradient))?;
    client.request(Request::Start)?;
    let mut events: Vec<PhaseEvent> = Vec::new();
    let mut t = client.transport_mut().now_us();
    let mut polls = 0u32;
    while events.len() < 2 * pairs + 1 {
        t += 50_000;
        polls += 1;
        if polls.is_multiple_of(20) {
            // Keep the host-silence watchdog (5 s) fed, as a real client does.
            client.request(Request::GetStatus)?;
        }
        client.transport_mut().advance_to(t);
        for (_, e) in client.poll_events()? {
            if let Event::Phase(p) = e {
                events.push(p);
            }
        }
    }
    client.request(Request::Stop)?;
    // The camera sees the trigger edges; the host only knows frame timestamps. Match each
    // frame to the phase event whose edge is CAMERA_LATENCY_US before it.
    let frames: Vec<u64> = events
        .iter()
        .filter_map(|p| match p.trigger {
            TriggerOutcome::Fired { edge_us, .. } => Some(edge_us + CAMERA_LATENCY_US),
            TriggerOutcome::Overrun { .. } => None,
        })
        .collect();
    let mut labelled = Vec::new();
    for ts in frames {
        let matched = events.iter().find_map(|p| match p.trigger {
            TriggerOutcome::Fired { index, edge_us } if edge_us + CAMERA_LATENCY_US == ts => {
                Some((p.phase, index))
            }
            _ => None,
        });
        let Some((phase, trigger)) = matched else {
            bail!("frame at {ts} µs matches no trigger");
        };
        labelled.push(Frame {
            timestamp_us: ts,
            phase,
            trigger,
        });
    }
    Ok(labelled)
}

pub fn run(client: &mut Client<SimulatedSensor>, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let optics = Optics::standard();
    let scenes: Vec<(&str, Scene)> = builtin_scenes(&optics);
    println!("\n--- tactile: photometric stereo on the simulated skin ---");
    let frames = capture_labelled_frames(client, scenes.len())?;
    // Consecutive (dx, dy) frames form one pair.
    let pairs: Vec<(&Frame, &Frame)> = frames
        .windows(2)
        .filter(|w| w[0].phase == Phase::Dx && w[1].phase == Phase::Dy)
        .map(|w| (&w[0], &w[1]))
        .collect();
    println!(
        "captured {} frames at trigger edges + {CAMERA_LATENCY_US} µs, labelled by phase events: {} dx/dy pairs",
        frames.len(),
        pairs.len()
    );
    if pairs.len() < scenes.len() {
        bail!(
            "only {} dx/dy pairs for {} objects",
            pairs.len(),
            scenes.len()
        );
    }

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
    for ((name, scene), (fx, fy)) in scenes.iter().zip(&pairs) {
        // The simulated camera renders whatever the labelled phase lit.
        let image = render(&optics, scene, u64::from(fx.trigger));
        let r = reconstructor.reconstruct(&image.dx, &image.dy)?;
        let truth = scene
            .truth(optics.width, optics.height, optics.px_per_mm)
            .depth;
        let e = stereotac::tactile::bench::errors(&r.depth_mm, &truth);
        output::write_all(&out.join(name), &r, px_per_mm)?;
        println!(
            "{:<11} {:>10} {:>10} | {:>9.3} {:>9.3} {:>9.4} | {:>8.2}",
            name,
            format!("#{}@{}", fx.trigger, fx.timestamp_us / 1000),
            format!("#{}@{}", fy.trigger, fy.timestamp_us / 1000),
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
