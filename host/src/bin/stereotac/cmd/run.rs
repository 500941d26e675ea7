//! `stereotac run`: the sensor and a camera in, tactile depth out, live: every frame is
//! labelled with its LED phase, each dx/dy pair is reconstructed as it completes, and
//! `--jsonl` prints one line per pair for a control loop.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use stereotac::device::SensorEvent;
use stereotac::frames::capture::{Capture, GradientPairer, LabelledFrame};
use stereotac::live::{TactileRecord, TactileStage};
use stereotac::matcher::MatcherConfig;
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;
use stereotac_protocol::Request;

use crate::args::{ModeArg, SequenceArgs};
use crate::cameras::CameraArgs;
use crate::console::{emit, interrupt_flag};
use crate::progress::builtin_calibration;
use crate::sensor_args::{DeviceArgs, open};

/// `stereotac run`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub cameras: CameraArgs,
    /// Sequence settings (gradient or interleaved: the modes with dx/dy phases).
    #[command(flatten)]
    pub sequence: SequenceArgs,
    /// Tactile model from `calibrate`. With --sim and no model, the simulated sensor's
    /// built-in calibration is used.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Gradient model: lut (default) or mlp.
    #[arg(long = "model-kind", default_value = "lut")]
    pub model_kind: ModelKind,
    /// One JSON object per reconstructed pair on stdout: sequence, phase, exposure ends
    /// (host µs), contact, area mm², centroid mm, max depth mm, volume mm³, time per
    /// stage ms, latency ms, frames dropped so far.
    #[arg(long)]
    pub jsonl: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// The latency figures printed at the end: (p50, p99), ms.
fn percentiles(mut v: Vec<f64>) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    Some((at(0.5), at(0.99)))
}

pub fn run(a: Args) -> Result<()> {
    let stop = interrupt_flag()?;
    a.cameras.check()?;
    if !matches!(a.sequence.mode, ModeArg::Gradient | ModeArg::Interleaved) {
        bail!(
            "`run` reconstructs tactile depth from dx/dy phases: use --mode gradient or \
             --mode interleaved"
        );
    }
    match a.cameras.cameras.as_slice() {
        [_] => {}
        many => bail!(
            "`run` takes one camera for now ({} given); record several with `record`",
            many.len()
        ),
    }
    if a.model.is_none() && !a.device.sim {
        bail!("give --model FILE (from `stereotac calibrate`); only --sim has a built-in one");
    }
    // The model first: a bad one is refused before the sensor is touched, and the
    // sensor's clock sync is not left unpolled while a built-in one is calibrated.
    let (model, references) = match &a.model {
        Some(path) => (TactileModel::load(path)?, None),
        None => {
            let (calibration, references) = builtin_calibration(&a.cameras.sim_optics())?;
            (calibration.model, Some(references))
        }
    };
    if a.cameras.cameras[0] == "sim" {
        let optics = a.cameras.sim_optics();
        if (model.width, model.height) != (optics.width, optics.height) {
            bail!(
                "the model was calibrated at {}×{} but the simulated camera is {}×{}: give \
                 --size {}x{} or a model of that size",
                model.width,
                model.height,
                optics.width,
                optics.height,
                model.width,
                model.height
            );
        }
    }
    let px_per_mm = model.px_per_mm;
    let reconstructor = Reconstructor::new(
        model,
        a.model_kind,
        SolverKind::Dct,
        references.as_ref().map(|(x, y)| (x, y)),
    )?;
    let mut opened = open(&a.device)?;
    let camera = a.cameras.open(&a.cameras.cameras[0], &opened)?;
    eprintln!("camera 0: {}", camera.describe());
    let mut capture = Capture::new(
        camera,
        MatcherConfig {
            sync: a.cameras.sync(),
            ..MatcherConfig::default()
        },
    );
    let mut stage = TactileStage::new(reconstructor, px_per_mm, capture.stamp_ref());
    let mut pairer = GradientPairer::default();
    let mut latencies = Vec::new();
    let mut contacts = 0u64;
    let sensor = &mut opened.sensor;
    a.sequence.start(sensor)?;
    let end = a.sequence.deadline(sensor)?;
    let clock = std::sync::Arc::clone(sensor.clock());
    // Reconstruct each pair as it completes; false once stdout is gone.
    let mut handle = |frames: Vec<LabelledFrame>, dropped: u64| -> Result<bool> {
        for frame in frames {
            let Some(pair) = pairer.push(frame) else {
                continue;
            };
            let (_, record) = stage.process(&pair, || clock.now_us() as f64, dropped)?;
            latencies.push(record.latency_ms);
            contacts += u64::from(record.contact);
            if !print(&record, a.jsonl)? {
                return Ok(false);
            }
        }
        Ok(true)
    };
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        let step = capture
            .step(sensor, Duration::from_millis(10))
            .context("capturing")?;
        for event in &step.events {
            match event {
                SensorEvent::Fault(f, at) => eprintln!("fault {:?} at host {at:.0} µs", f.kind),
                SensorEvent::Reconnected { attempts } => {
                    eprintln!("reconnected after {attempts} attempts")
                }
                _ => {}
            }
        }
        if !handle(step.frames, capture.stats().dropped_frames)? {
            stop.store(true, Ordering::SeqCst);
        }
    }
    let stopped = sensor.request(Request::Stop);
    let rest = capture.finish();
    let open_stdout = handle(rest, capture.stats().dropped_frames)?;
    stopped?;
    let s = capture.stats();
    let pairs = stage.pairs();
    let latency = percentiles(latencies).map_or("-".into(), |(p50, p99)| {
        format!("p50 {p50:.2} ms, p99 {p99:.2} ms")
    });
    eprintln!(
        "run: {pairs} dx/dy pairs reconstructed, {contacts} with contact; latency {latency}; \
         frames: {} labelled, {} dropped, {} straddling, {} with a lost event{}",
        s.labelled,
        s.dropped_frames,
        s.straddling,
        s.event_missing,
        if open_stdout { "" } else { "; stdout closed" }
    );
    Ok(())
}

/// Prints one record; `false` once stdout is gone.
fn print(r: &TactileRecord, jsonl: bool) -> Result<bool> {
    if jsonl {
        return Ok(emit(format_args!("{}", serde_json::to_string(r)?)));
    }
    Ok(if r.contact {
        emit(format_args!(
            "pair {:>4} (phase {:>5}): contact {:7.2} mm², max depth {:.3} mm, volume {:.2} mm³; {:.2} ms, latency {:.1} ms",
            r.sequence,
            r.phase,
            r.area_mm2,
            r.max_depth_mm,
            r.volume_mm3,
            r.stage_ms.total_ms,
            r.latency_ms
        ))
    } else {
        emit(format_args!(
            "pair {:>4} (phase {:>5}): no contact; {:.2} ms, latency {:.1} ms",
            r.sequence, r.phase, r.stage_ms.total_ms, r.latency_ms
        ))
    })
}
