//! `stereotac demo`: the main job on built-in data, no hardware. A simulated sensor (the
//! firmware's own logic on a virtual clock) driven through the real wire protocol shows
//! its handshake, phase timeline and counters; then the tactile part captures a dx/dy
//! pair per object from a simulated camera triggered by that sensor (loopback USB,
//! clock sync, matcher), calibrates on simulated ball presses and reconstructs each
//! object; then one vision frame goes through the stereo pipeline; last, two small
//! recordings (`presses.mcap`, `demo.mcap`) for `calibrate` and `process`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use stereotac::out_dir::{OutDir, Replace};

use anyhow::{Context, Result, bail};
use stereotac::client::Client;
use stereotac::clock::{HostClock, VirtualClock};
use stereotac::device::{hex, status_line};
use stereotac::frames::capture::{Capture, GradientPair, LabelledFrame};
use stereotac::live::scripted::{self, Script};
use stereotac::matcher::{CameraSync, Label, MatcherConfig};
use stereotac::recording::writer::{Recorder, RecorderOptions, clock_origin_unix_ns};
use stereotac::sim::camera::{PhaseImages, SimClocking, SimStereo, SimulatedCamera};
use stereotac::sim::link::LoopbackConfig;
use stereotac::sim::sensor::SimulatedSensor;
use stereotac::stereo::StereoPipeline;
use stereotac::stereo::output::{OutputOptions, write_outputs};
use stereotac::stereo::pipeline::StereoConfig;
use stereotac::stereo::synthetic::{Membrane, RawRig, TexturedPlane, wide_fisheye_calibration};
use stereotac::tactile::bench::errors;
use stereotac::tactile::model::ModelKind;
use stereotac::tactile::output;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;
use stereotac::tactile::render::{Optics, Scene, builtin_scenes};
use stereotac::tactile::synthetic::{BUILTIN_PRESSES, CALIBRATION_BALL_MM, ball_presses};
use stereotac_protocol::{Event, Mode, Request, Response, Timing, TriggerOutcome};

use crate::args::ModeArg;
use crate::progress::{bar, builtin_calibration};
use crate::stages::StereoSetup;

/// `stereotac demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Lighting mode to run.
    #[arg(long, value_enum, default_value_t = ModeArg::Gradient)]
    pub mode: ModeArg,
    /// Phase period in milliseconds.
    #[arg(long, default_value_t = 250)]
    pub period_ms: u32,
    /// Number of phases to run.
    #[arg(long, default_value_t = 12)]
    pub phases: u32,
    /// Where the tactile and stereo parts write their outputs. A folder an earlier demo
    /// made is reused; one with other files in it is refused unless --force.
    #[arg(long, default_value = "stereotac-demo-out")]
    pub out: PathBuf,
    /// Write into --out even when it holds files the demo did not make.
    #[arg(long)]
    pub force: bool,
    /// Skip the tactile part (calibration and reconstruction).
    #[arg(long)]
    pub no_tactile: bool,
    /// Skip the stereo part (one vision frame through the wide lenses).
    #[arg(long)]
    pub no_stereo: bool,
    /// Skip the recordings (presses.mcap, demo.mcap) for `calibrate` and `process`.
    #[arg(long)]
    pub no_recordings: bool,
}

/// Simulated camera: exposure starts this long after the trigger edge (µs).
const CAMERA_LATENCY_US: f64 = 150.0;
/// Simulated camera exposure (µs).
const EXPOSURE_US: f64 = 8000.0;
/// Give up on a dx/dy pair after this much simulated time (µs).
const PAIR_TIMEOUT_US: u64 = 10_000_000;
/// Target distance of the stereo frame, mm.
const STEREO_DISTANCE_MM: f64 = 150.0;

pub fn run(a: Args) -> Result<()> {
    if a.phases == 0 {
        bail!("--phases must be at least 1");
    }
    if a.mode == ModeArg::Off {
        bail!(
            "--mode off lights nothing and fires no trigger: the demo shows vision, contact, \
             gradient or interleaved"
        );
    }
    let mode: Mode = a.mode.into();
    let out = OutDir::prepare(
        &a.out,
        Replace::OwnEarlierRun {
            command: "demo",
            force: a.force,
        },
    )?;
    timeline(mode, a.period_ms, a.phases)?;
    if !a.no_tactile {
        match mode {
            Mode::Gradient | Mode::Interleaved => tactile(out.path(), mode)?,
            _ => println!(
                "\n(tactile part skipped: --mode {} has no dx/dy phases; use gradient or \
                 interleaved)",
                stereotac::describe::mode(mode)
            ),
        }
    }
    if !a.no_stereo {
        stereo(out.path())?;
    }
    if !a.no_recordings {
        recordings(out.path(), a.period_ms)?;
    }
    out.keep();
    Ok(())
}

/// The protocol part: handshake, the phase timeline and the device's counters, from the
/// bare simulated sensor (device time moves only when the demo says so).
fn timeline(mode: Mode, period_ms: u32, phases: u32) -> Result<()> {
    println!(
        "stereotac demo: simulated sensor (firmware logic on a virtual clock, real wire frames)\n"
    );
    let mut client = Client::new(SimulatedSensor::new(*b"SIMULATD"));
    let info = client.handshake()?;
    let v = info.firmware_version;
    println!(
        "handshake: protocol v{}, firmware {}.{}.{} ({}{}), board {}, {} strips x {} LEDs (max {}), timer {} Hz",
        info.protocol_version,
        v.major,
        v.minor,
        v.patch,
        &hex(&info.git_hash)[..10],
        if info.git_dirty { "+dirty" } else { "" },
        hex(&info.board_id),
        info.strips,
        info.leds_per_strip,
        info.max_leds_per_strip,
        info.timer_hz
    );
    let period_us = period_ms.saturating_mul(1000);
    client.request(Request::SetTiming(Timing {
        phase_period_us: period_us,
        ..Timing::DEFAULT
    }))?;
    client.request(Request::SetMode(mode))?;
    client.request(Request::Start)?;
    println!("mode {mode:?}, phase period {period_ms} ms\n");
    println!(
        "{:>5} {:>5} {:>14} {:>14} {:>14} {:>14} {:>9}",
        "phase", "kind", "scheduled µs", "LED write µs", "latched µs", "trigger µs", "trigger#"
    );
    let mut shown = 0;
    let mut t = client.transport_mut().now_us();
    let mut previous_edge: Option<u64> = None;
    let mut periods = Vec::new();
    while shown < phases {
        t += u64::from(period_us);
        client.transport_mut().advance_to(t);
        for (_, event) in client.poll_events()? {
            let Event::Phase(p) = event else { continue };
            if shown == phases {
                break;
            }
            let (edge, index) = match p.trigger {
                TriggerOutcome::Fired { index, edge_us } => {
                    if let Some(prev) = previous_edge.replace(edge_us) {
                        periods.push(edge_us - prev);
                    }
                    (edge_us.to_string(), index.to_string())
                }
                TriggerOutcome::Overrun { .. } => ("overrun".into(), "-".into()),
            };
            println!(
                "{:>5} {:>5} {:>14} {:>14} {:>14} {:>14} {:>9}",
                p.index,
                format!("{:?}", p.phase),
                p.scheduled_us,
                p.write_start_us,
                p.latched_us,
                edge,
                index
            );
            shown += 1;
        }
    }
    client.request(Request::Stop)?;
    let status = match client.request(Request::GetStatus)? {
        Response::Status(s) => s,
        other => bail!("unexpected reply {other:?}"),
    };
    if let (Some(min), Some(max)) = (periods.iter().min(), periods.iter().max()) {
        println!(
            "\ntrigger period: min {min} µs, max {max} µs (nominal {period_us} µs, {} intervals)",
            periods.len()
        );
    }
    println!(
        "counters: {}; host saw {} lost events",
        status_line(&status),
        client.lost_events()
    );
    Ok(())
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

/// The tactile part: for each object, a dx/dy frame pair from a simulated camera
/// triggered by the simulated sensor in `mode` (gradient or interleaved), through the
/// host path a real sensor uses;
/// calibration on simulated ball presses; reconstruction from the captured frames with
/// accuracy, timings and files.
fn tactile(out: &Path, mode: Mode) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let optics = Optics::standard();
    let scenes: Vec<(&str, Scene)> = builtin_scenes(&optics);
    println!("\n--- tactile: photometric stereo on the simulated skin ---");
    // The host path of a real sensor: loopback USB, clock sync, triggered camera, matcher.
    let clock: Arc<dyn HostClock> = Arc::new(VirtualClock::starting_at(1_000_000));
    let rig = stereotac::sim::connect(
        *b"SIMULATD",
        clock,
        LoopbackConfig {
            drift_ppm: 30.0,
            ..LoopbackConfig::default()
        },
    )?;
    let mut sensor = rig.sensor;
    sensor.request(Request::SetMode(mode))?;
    sensor.request(Request::Start)?;
    let camera = SimulatedCamera::new(
        rig.timeline,
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
    let mut pairs: Vec<GradientPair> = Vec::new();
    for (_, scene) in &scenes {
        // Press the next object; the frames after the switch show it.
        capture
            .source_mut()
            .set_images(PhaseImages::render(&optics, scene));
        let pressed_at = sensor.clock().now_us();
        let pair = capture
            .next_gradient_pair(&mut sensor, pressed_at, pressed_at + PAIR_TIMEOUT_US)?
            .with_context(|| {
                format!(
                    "no labelled dx/dy pair within {} s",
                    PAIR_TIMEOUT_US / 1_000_000
                )
            })?;
        pairs.push(pair);
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

    let (calibration, refs) = builtin_calibration(&optics, None)?;
    let fit = calibration.model.fit;
    println!(
        "calibrated on {BUILTIN_PRESSES} simulated {CALIBRATION_BALL_MM} mm ball presses: slope RMS lut {:.3} (held-out {:.3}), mlp {:.3} (held-out {:.3}), light {:.3} (held-out {:.3})",
        fit.lut_train_rms,
        fit.lut_validation_rms,
        fit.mlp_train_rms,
        fit.mlp_validation_rms,
        fit.light_train_rms,
        fit.light_validation_rms
    );
    calibration.model.save(&out.join("model.json"))?;
    let px_per_mm = calibration.model.px_per_mm;
    let mut reconstructor = Reconstructor::new(
        calibration.model,
        ModelKind::Lut,
        SolverKind::Dct,
        Some((&refs.0, &refs.1).into()),
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
        let e = errors(&r.depth_mm, &truth);
        output::write_all(&out.join(name), &r, px_per_mm, None, Vec::new())?;
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

/// The stereo part: one vision frame of a built-in textured target, raw through the
/// sensor's 160° lenses, rectified, matched and reprojected like a real frame, written
/// as the `stereo` command writes it.
fn stereo(out: &Path) -> Result<()> {
    let dir = out.join("stereo");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    println!(
        "\nstereo: a vision frame (LEDs dark) of a textured target {STEREO_DISTANCE_MM} mm away, \
         tilted 15°, raw through the 160° lenses"
    );
    let rig = RawRig::new(&wide_fisheye_calibration());
    let tilt = 15f64.to_radians();
    let target = TexturedPlane {
        point: nalgebra::Point3::new(0.0, 0.0, STEREO_DISTANCE_MM),
        normal: nalgebra::Vector3::new(tilt.sin(), 0.0, tilt.cos()),
    };
    let (left, right) = rig.render(&target, &Membrane::sensor(), 1);
    let config = StereoConfig::default();
    let mut pipeline = StereoPipeline::new(rig.calibration(), config)?;
    let frame = pipeline.process(&left, &right)?;
    let summary = write_outputs(&dir, &pipeline, &frame, &config, OutputOptions::default())?;
    let t = &frame.timings;
    println!(
        "depth at the centre {:.1} mm (true {STEREO_DISTANCE_MM}), {:.1} % of pixels valid, {} points; \
         rectify {:.1} ms, match {:.1} ms, whole frame {:.1} ms",
        frame
            .depth_mm
            .get(frame.depth_mm.width() / 2, frame.depth_mm.height() / 2),
        100.0 * summary.fill_rate,
        summary.points,
        t.rectify_ms,
        t.match_ms,
        t.total_ms
    );
    println!(
        "wrote {} (depth .npy and PNGs, cloud.ply, summary.json)",
        dir.display()
    );
    Ok(())
}

/// The recordings a newcomer feeds to `calibrate` and `process`: `presses.mcap` (ball
/// presses, gradient mode, one camera) and `demo.mcap` (the skin at rest, then each
/// object; interleaved mode, two cameras 14 mm apart whose dark frames see a textured
/// board; the stereo calibration attached).
fn recordings(out: &Path, period_ms: u32) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let optics = Optics::standard();
    println!(
        "
--- recordings: the live path's files, for calibrate and process ---"
    );
    let presses: Vec<PhaseImages> = ball_presses(&optics, BUILTIN_PRESSES, CALIBRATION_BALL_MM, 7)
        .into_iter()
        .map(|p| PhaseImages::from_gradients(p.dx, p.dy))
        .collect();
    let mut objects = vec![PhaseImages::render(&optics, &Scene::default())];
    objects.extend(
        builtin_scenes(&optics)
            .iter()
            .map(|(_, scene)| PhaseImages::render(&optics, scene)),
    );
    let stereo_rig = SimStereo::new(optics.width as u32, optics.height as u32);
    let period_us = period_ms.saturating_mul(1000);
    for (file, script, what) in [
        (
            "presses.mcap",
            Script {
                mode: Mode::Gradient,
                period_us,
                exposure_us: EXPOSURE_US,
                scenes: presses,
                stereo: None,
                command: "demo".into(),
            },
            format!(
                "{BUILTIN_PRESSES} presses of a {CALIBRATION_BALL_MM} mm ball, one camera, gradient mode"
            ),
        ),
        (
            "demo.mcap",
            Script {
                mode: Mode::Interleaved,
                period_us,
                exposure_us: EXPOSURE_US,
                scenes: objects,
                stereo: Some(stereo_rig),
                command: "demo".into(),
            },
            "the skin at rest, then each object; two cameras, interleaved mode".to_string(),
        ),
    ] {
        let path = out.join(file);
        if path.exists() {
            std::fs::remove_file(&path)
                .with_context(|| format!("replacing the demo's own {}", path.display()))?;
        }
        let recorder = Recorder::start(RecorderOptions {
            mcap: Some(path.clone()),
            live_view: None,
            queue: 16,
            wait_when_full: true,
            clock_origin_unix_ns: clock_origin_unix_ns(scripted::START_US),
        })?;
        if let Some(rig) = script.stereo {
            StereoSetup {
                calib: rig.calibration(),
                config: StereoConfig::default(),
            }
            .record(&recorder)?;
        }
        let progress = bar(script.scenes.len() as u64, file);
        let stats = scripted::record(&script, &recorder, |done, _| {
            progress.set_position(done as u64)
        })?;
        progress.finish_and_clear();
        let summary = recorder.finish()?;
        let labelled: u64 = stats.iter().map(|s| s.labelled).sum();
        println!(
            "{}: {what}: {labelled} frames labelled, {:.1} MiB",
            path.display(),
            summary.bytes as f64 / (1 << 20) as f64
        );
    }
    println!(
        "next: stereotac calibrate {0}/presses.mcap --ball-diameter-mm {CALIBRATION_BALL_MM} --out model.json\n      stereotac process {0}/demo.mcap --model model.json --mcap processed.mcap",
        out.display()
    );
    Ok(())
}
