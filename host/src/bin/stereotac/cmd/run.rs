//! `stereotac run`: the sensor and one or two cameras in, time-aligned depth out, live.
//! Every frame is labelled with its LED phase; camera 0's dx/dy pairs go to the tactile
//! stage, dark frames of cameras 0 and 1 to the stereo stage. `--jsonl` prints one line
//! per tactile pair for a control loop, `--mcap` records everything, `--foxglove` serves
//! a live view. Ctrl-C, SIGTERM and SIGHUP finish the recording properly.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use stereotac::clock::HostClock;
use stereotac::device::{SensorEvent, firmware_version, serial_number};
use stereotac::frames::FrameSource;
use stereotac::frames::capture::{Capture, LabelledFrame};
use stereotac::live::Pipeline;
use stereotac::matcher::MatcherConfig;
use stereotac::recording::messages::{ClockInfo, FrameInfo, PhaseInfo};
use stereotac::recording::topics;
use stereotac::recording::writer::{Item, Recorder, RecorderOptions, clock_origin_unix_ns};
use stereotac_protocol::Request;

use crate::args::{ModeArg, PipelineArgs, SequenceArgs};
use crate::cameras::CameraArgs;
use crate::console::interrupt_flag;
use crate::live_report::Report;
use crate::progress::builtin_calibration;
use crate::sensor_args::{DeviceArgs, open};
use crate::stages::{StageArgs, StereoSetup, TactileSetup, stamp_ref_name};

/// `stereotac run`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub cameras: CameraArgs,
    /// Sequence settings: gradient (tactile), vision (stereo) or interleaved (both).
    #[command(flatten)]
    pub sequence: SequenceArgs,
    /// Tactile model and stereo calibration. With --sim and simulated cameras, built-in
    /// ones are used when none is given.
    #[command(flatten)]
    pub stages: StageArgs,
    /// Stereo matching settings.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Record everything to this MCAP file (new; opens in Foxglove): raw frames, LED
    /// phases, clock sync, depth, contact, point clouds, model and calibration.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Serve a live view for Foxglove (open ws://ADDR in Foxglove's "Open connection").
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<String>,
    /// One JSON object per reconstructed tactile pair on stdout: sequence, phase,
    /// exposure ends (host µs), contact, area mm², centroid mm, max depth mm, volume mm³,
    /// time per stage ms, latency ms, frames dropped so far.
    #[arg(long)]
    pub jsonl: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// How long one poll of the sensor waits for events.
const POLL: Duration = Duration::from_millis(2);

/// What the mode lights, so which stages can run.
fn stages_of(mode: ModeArg) -> (bool, bool) {
    match mode {
        ModeArg::Gradient => (true, false),
        ModeArg::Vision => (false, true),
        ModeArg::Interleaved => (true, true),
        ModeArg::Off | ModeArg::Contact => (false, false),
    }
}

/// The stages' setups, loaded before the sensor is touched (a bad file is refused
/// first, and the clock sync is not left unpolled while a built-in model calibrates).
fn setups(a: &Args) -> Result<(Option<TactileSetup>, Option<StereoSetup>)> {
    let (gradients, dark) = stages_of(a.sequence.mode);
    let all_sim = a.device.sim && a.cameras.cameras.iter().all(|c| c == "sim");
    let tactile = if gradients {
        let setup = match &a.stages.model {
            Some(path) => TactileSetup {
                model: stereotac::tactile::model::TactileModel::load(path)?,
                references: None,
                kind: a.stages.model_kind.unwrap_or_default(),
            },
            None if all_sim => {
                let (calibration, references) = builtin_calibration(&a.cameras.sim_optics())?;
                TactileSetup {
                    model: calibration.model,
                    references: Some(references),
                    kind: a.stages.model_kind.unwrap_or_default(),
                }
            }
            None => bail!(
                "--mode {:?} reconstructs tactile depth: give --model FILE (from `stereotac \
                 calibrate`); only --sim with simulated cameras has a built-in one",
                a.sequence.mode
            ),
        };
        Some(setup.round_trip()?)
    } else {
        if a.stages.model.is_some() {
            bail!("--model needs dx/dy phases: use --mode gradient or --mode interleaved");
        }
        None
    };
    let two = a.cameras.cameras.len() >= 2;
    let stereo = if dark && two {
        let calib = if !a.stages.calib.is_empty() {
            stereotac::stereo::StereoCalibration::load(&a.stages.calib)?
        } else if let (true, Some(sim)) = (a.device.sim, a.cameras.sim_stereo()) {
            sim.calibration()
        } else {
            bail!(
                "two cameras in --mode {:?} give stereo depth: give --calib stereo.yaml (or \
                 --calib left.yaml --calib right.yaml); only --sim with simulated cameras has \
                 a built-in one",
                a.sequence.mode
            );
        };
        Some(
            StereoSetup {
                calib,
                config: a.pipeline.config(),
            }
            .round_trip()?,
        )
    } else {
        if !a.stages.calib.is_empty() {
            bail!(
                "--calib needs two cameras and dark phases: give --camera twice and --mode \
                 vision or --mode interleaved"
            );
        }
        None
    };
    if tactile.is_none() && stereo.is_none() && a.mcap.is_none() && a.foxglove.is_none() {
        bail!(
            "nothing to do: --mode {:?} with {} camera(s) gives neither tactile nor stereo \
             depth; use --mode gradient or interleaved (tactile), two cameras with --mode \
             vision or interleaved (stereo), or record with --mcap",
            a.sequence.mode,
            a.cameras.cameras.len()
        );
    }
    Ok((tactile, stereo))
}

pub fn run(a: Args) -> Result<()> {
    let stop = interrupt_flag()?;
    a.cameras.check()?;
    if a.cameras.cameras.len() > 4 {
        bail!("at most 4 cameras ({} given)", a.cameras.cameras.len());
    }
    let (tactile, stereo) = setups(&a)?;
    if a.cameras.cameras.iter().all(|c| c == "sim") {
        let o = a.cameras.sim_optics();
        let size = (o.width as u32, o.height as u32);
        if let Some(t) = &tactile {
            t.check_size("the simulated camera", size)?;
        }
        if let Some(s) = &stereo {
            s.check_size("the simulated cameras", true, size)?;
            s.check_size("the simulated cameras", false, size)?;
        }
    }
    let mut opened = open(&a.device)?;
    let clock: Arc<dyn HostClock> = Arc::clone(opened.sensor.clock());
    let origin_ns = clock_origin_unix_ns(clock.now_us());
    let recorder = Recorder::start(RecorderOptions {
        mcap: a.mcap.clone(),
        live_view: a.foxglove.clone(),
        queue: 64,
        clock_origin_unix_ns: origin_ns,
    })?;
    if let Some(port) = recorder.live_port() {
        eprintln!(
            "live view: open Foxglove, \"Open connection\", ws://{}:{port}",
            a.foxglove
                .as_deref()
                .and_then(|s| s.rsplit_once(':'))
                .map_or("127.0.0.1", |(h, _)| h)
        );
    }
    let sources = a.cameras.open_all(&opened)?;
    let mut captures: Vec<Capture<Box<dyn FrameSource>>> = Vec::new();
    for (i, source) in sources.into_iter().enumerate() {
        eprintln!("camera {i}: {}", source.describe());
        captures.push(Capture::new(
            source,
            MatcherConfig {
                sync: a.cameras.sync(),
                ..MatcherConfig::default()
            },
        ));
    }
    record_header(&a, &opened.sensor, &captures, origin_ns, &recorder)?;
    if let Some(t) = &tactile {
        t.record(&recorder)?;
    }
    if let Some(s) = &stereo {
        s.record(&recorder)?;
    }
    let tactile_stage = tactile
        .as_ref()
        .map(|t| t.stage(captures[0].stamp_ref()))
        .transpose()?;
    let stereo_stage = stereo
        .as_ref()
        .map(|s| s.stage([captures[0].stamp_ref(), captures[1].stamp_ref()]))
        .transpose()?;
    let mut pipeline = Pipeline::new(tactile_stage, stereo_stage);
    let mut report = Report::new(a.jsonl);
    let mut sizes_checked = vec![false; captures.len()];

    let sensor = &mut opened.sensor;
    a.sequence.start(sensor)?;
    let end = a.sequence.deadline(sensor)?;
    let mut handle = |camera: usize,
                      frames: Vec<LabelledFrame>,
                      stamp_ref,
                      dropped: u64,
                      report: &mut Report|
     -> Result<bool> {
        for frame in frames {
            if !std::mem::replace(&mut sizes_checked[camera], true) {
                let size = frame.frame.image.dimensions();
                let name = format!("camera {camera} ({})", a.cameras.cameras[camera]);
                if camera == 0
                    && let Some(t) = &tactile
                {
                    t.check_size(&name, size)?;
                }
                if camera < 2
                    && let Some(s) = &stereo
                {
                    s.check_size(&name, camera == 0, size)?;
                }
            }
            recorder.send(Item::Frame {
                camera,
                info: FrameInfo::new(frame.frame.stamp, stamp_ref, frame.label),
                image: frame.frame.image.clone(),
            });
            let Some(job) = pipeline.route(camera, frame) else {
                continue;
            };
            let dropped = dropped + recorder.dropped().frames;
            let Some(output) = pipeline.run(&job, || Some(clock.now_us() as f64), dropped)? else {
                continue;
            };
            let open = report.print(&output)?;
            recorder.send(output.into_item());
            if !open {
                return Ok(false);
            }
        }
        Ok(true)
    };
    let mut failure = None;
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        // A short wait: frames are taken from the cameras between polls, so this bounds
        // how long a finished exposure can sit before it is labelled.
        let events = sensor.poll(POLL).context("polling the sensor")?;
        for event in &events {
            match event {
                SensorEvent::Phase(p) => {
                    recorder.send(Item::Phase(PhaseInfo::from(p)));
                }
                SensorEvent::Heartbeat(_) => {
                    let now = sensor.clock().now_us() as f64;
                    recorder.send(Item::Clock(ClockInfo::new(now, sensor.clock_fit())));
                }
                SensorEvent::Fault(f, at) => warn(
                    &recorder,
                    *at,
                    format!("sensor fault {:?} at host {at:.0} µs", f.kind),
                ),
                SensorEvent::Reconnected { attempts } => warn(
                    &recorder,
                    sensor.clock().now_us() as f64,
                    format!("sensor reconnected after {attempts} attempts"),
                ),
                SensorEvent::Probe(_) => {}
            }
        }
        let dropped: u64 = captures.iter().map(|c| c.stats().dropped_frames).sum();
        let mut open = true;
        for (i, capture) in captures.iter_mut().enumerate() {
            let frames = capture
                .absorb(&events)
                .with_context(|| format!("camera {i}"))?;
            open &= handle(i, frames, capture.stamp_ref(), dropped, &mut report)?;
        }
        if !open {
            eprintln!("stdout closed: stopping");
            break;
        }
        if let Some(e) = recorder.failure() {
            failure = Some(e);
            break;
        }
    }
    // The end, Ctrl-C or a signal: stop the LEDs, label and process every captured frame.
    let stopped = sensor.request(Request::Stop);
    let dropped: u64 = captures.iter().map(|c| c.stats().dropped_frames).sum();
    for (i, capture) in captures.iter_mut().enumerate() {
        let rest = capture.finish();
        if report.stdout_open() {
            handle(i, rest, capture.stamp_ref(), dropped, &mut report)?;
        }
    }
    let summary = recorder.finish();
    stopped.context("stopping the sequence")?;
    report.finish(&pipeline);
    for (i, c) in captures.iter().enumerate() {
        let s = c.stats();
        eprintln!(
            "camera {i}: {} frames labelled, {} dropped, {} straddling, {} with a lost event",
            s.labelled, s.dropped_frames, s.straddling, s.event_missing
        );
    }
    let summary = summary?;
    if let Some(path) = &summary.path {
        let frames: u64 = summary
            .messages
            .iter()
            .filter(|(t, _)| t.ends_with("/image") && t.contains("/cam"))
            .map(|(_, n)| n)
            .sum();
        eprintln!(
            "recorded {} ({:.1} MiB): {frames} frames, {} messages in all; {} dropped at the \
             queue (frames {}, results {}, events {})",
            path.display(),
            summary.bytes as f64 / (1 << 20) as f64,
            summary.messages.values().sum::<u64>(),
            summary.dropped.total(),
            summary.dropped.frames,
            summary.dropped.results,
            summary.dropped.events
        );
    }
    if let Some(e) = failure {
        bail!("recording failed: {e}");
    }
    Ok(())
}

/// Prints a warning and records it.
fn warn(recorder: &Recorder, at_us: f64, message: String) {
    eprintln!("warning: {message}");
    recorder.send(Item::Warning { at_us, message });
}

/// The recording's metadata: what ran, on which sensor, with which cameras.
fn record_header(
    a: &Args,
    sensor: &stereotac::device::Sensor,
    captures: &[Capture<Box<dyn FrameSource>>],
    origin_ns: u64,
    recorder: &Recorder,
) -> Result<()> {
    let info = sensor.info();
    let mut run = BTreeMap::from([
        ("version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("command".to_string(), "run".to_string()),
        (
            "mode".to_string(),
            format!("{:?}", a.sequence.mode).to_lowercase(),
        ),
        ("period_ms".to_string(), a.sequence.period_ms.to_string()),
        ("cameras".to_string(), captures.len().to_string()),
        ("clock_origin_unix_ns".to_string(), origin_ns.to_string()),
    ]);
    for (i, c) in captures.iter().enumerate() {
        run.insert(format!("camera{i}"), c.source().describe());
        run.insert(
            format!("camera{i}_stamp"),
            stamp_ref_name(c.stamp_ref()).to_string(),
        );
    }
    let sensor_meta = BTreeMap::from([
        ("serial".to_string(), serial_number(&info.board_id)),
        ("firmware".to_string(), firmware_version(info)),
        (
            "protocol_version".to_string(),
            info.protocol_version.to_string(),
        ),
        ("simulated".to_string(), a.device.sim.to_string()),
    ]);
    for (name, entries) in [
        (topics::META_RECORDING, run),
        (topics::META_SENSOR, sensor_meta),
    ] {
        if !recorder.send(Item::Metadata {
            name: name.into(),
            entries,
        }) {
            bail!("the recording's writer stopped");
        }
    }
    Ok(())
}
