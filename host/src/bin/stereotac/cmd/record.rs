//! `stereotac record`: camera frames as PNG plus an index (`index.jsonl`) of phase,
//! trigger and timestamps, from one or several cameras; Ctrl-C finishes cleanly without
//! losing a captured frame.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use stereotac::device::SensorEvent;
use stereotac::frames::FrameSource;
use stereotac::frames::capture::{Capture, LabelledFrame};
use stereotac::frames::replay::Recorder;
use stereotac::matcher::{CameraSync, MatchedFrame, MatcherConfig, phase_str};
use stereotac::sim::camera::{PhaseImages, SimClocking, SimulatedCamera};
use stereotac::tactile::render::{Optics, builtin_scenes};
use stereotac_protocol::Request;

use crate::args::{SequenceArgs, parse_size};
use crate::console::interrupt_flag;
use crate::progress::spinner;
use crate::sensor_args::{DeviceArgs, Opened, open};

/// `stereotac record`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Output directory (must not hold a recording already). With several cameras each
    /// records into DIR/cam0, DIR/cam1, ...
    #[arg(long)]
    pub out: PathBuf,
    /// Camera: `sim` (the simulated camera; needs --sim) or a V4L2 device such as
    /// /dev/video0 (needs a build with `--features v4l2`). Repeat for several cameras.
    #[arg(long = "camera", default_value = "sim")]
    pub cameras: Vec<String>,
    /// Exposure time, µs: the simulated camera's, and the one assumed for a V4L2 camera
    /// that does not report its own.
    #[arg(long, default_value_t = 8000.0)]
    pub exposure_us: f64,
    /// The cameras run on their own clock instead of the sensor's trigger output.
    #[arg(long)]
    pub free_running: bool,
    /// Delay from the trigger edge to the start of the exposure, µs (triggered cameras).
    #[arg(long, default_value_t = 40.0)]
    pub trigger_latency_us: f64,
    /// Frame size to ask V4L2 cameras for, WxH (default: the camera's current size).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Sequence settings.
    #[command(flatten)]
    pub sequence: SequenceArgs,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// One camera's capture and its recording.
struct CameraRecording {
    capture: Capture<Box<dyn FrameSource>>,
    recorder: Recorder,
    dir: PathBuf,
}

impl CameraRecording {
    /// Write labelled frames: images first, then their index lines.
    fn write(&mut self, frames: Vec<LabelledFrame>) -> Result<u64> {
        let n = frames.len() as u64;
        for f in frames {
            self.recorder.write_image(&f.frame)?;
            self.recorder.write_label(&MatchedFrame {
                frame: f.frame.stamp,
                label: f.label,
            })?;
        }
        Ok(n)
    }
}

pub fn run(a: Args) -> Result<()> {
    let stop = interrupt_flag()?;
    if !(a.exposure_us.is_finite() && a.exposure_us > 0.0) {
        bail!("--exposure-us must be positive");
    }
    if !(a.trigger_latency_us.is_finite() && a.trigger_latency_us >= 0.0) {
        bail!("--trigger-latency-us must be zero or positive");
    }
    check_cameras(&a.cameras)?;
    let mut opened = open(&a.device)?;
    let sync = if a.free_running {
        CameraSync::FreeRunning
    } else {
        CameraSync::Triggered {
            latency_us: a.trigger_latency_us,
            tolerance_us: 500.0,
        }
    };
    let mut cameras = Vec::new();
    for (i, name) in a.cameras.iter().enumerate() {
        let source = open_camera(name, &a, &opened)?;
        let dir = if a.cameras.len() == 1 {
            a.out.clone()
        } else {
            a.out.join(format!("cam{i}"))
        };
        eprintln!("camera {i}: {} -> {}", source.describe(), dir.display());
        let recorder = Recorder::create(&dir)
            .with_context(|| format!("starting a recording in {}", dir.display()))?;
        let capture = Capture::new(
            source,
            MatcherConfig {
                sync,
                ..MatcherConfig::default()
            },
        );
        cameras.push(CameraRecording {
            capture,
            recorder,
            dir,
        });
    }
    let sensor = &mut opened.sensor;
    a.sequence.start(sensor)?;
    let end = a.sequence.deadline(sensor)?;
    let progress = spinner("recording");
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        let events = sensor.poll(Duration::from_millis(20))?;
        for event in &events {
            if let SensorEvent::Phase(p) = event {
                progress.set_message(format!(
                    "phase {} ({})",
                    p.event.index,
                    phase_str(p.event.phase)
                ));
            }
        }
        for camera in &mut cameras {
            let frames = camera.capture.absorb(&events)?;
            progress.inc(camera.write(frames)?);
        }
    }
    // Ctrl-C or the end: stop the LEDs, then label and write every captured frame.
    let stopped = sensor.request(Request::Stop);
    for camera in &mut cameras {
        let frames = camera.capture.finish();
        camera.write(frames)?;
        camera.recorder.flush()?;
    }
    progress.finish_and_clear();
    stopped?;
    for camera in &cameras {
        let s = camera.capture.stats();
        let (images, lines) = camera.recorder.counts();
        println!(
            "recorded {images} frames ({lines} index lines) in {}: {} labelled, {} straddling, {} with a lost event, {} without trigger, {} unresolved; {} frames dropped, {} events lost",
            camera.dir.display(),
            s.labelled,
            s.straddling,
            s.event_missing,
            s.no_trigger,
            s.unresolved,
            s.dropped_frames,
            s.dropped_events
        );
    }
    Ok(())
}

/// Open one `--camera`.
fn open_camera(name: &str, a: &Args, opened: &Opened) -> Result<Box<dyn FrameSource>> {
    if name == "sim" {
        let Some(timeline) = opened.timeline.clone() else {
            bail!("--camera sim renders the simulated sensor's LEDs: add --sim");
        };
        let optics = Optics::sized(320, 240);
        let scene = builtin_scenes(&optics).swap_remove(0).1;
        let clocking = if a.free_running {
            SimClocking::FreeRunning {
                period_us: 33_333.0,
                first_us: opened.sensor.clock().now_us() as f64,
            }
        } else {
            SimClocking::Triggered {
                latency_us: a.trigger_latency_us,
            }
        };
        return Ok(Box::new(SimulatedCamera::new(
            timeline,
            Arc::clone(opened.sensor.clock()),
            clocking,
            a.exposure_us,
            PhaseImages::render(&optics, &scene),
        )));
    }
    open_v4l2(name, a)
}

#[cfg(all(feature = "v4l2", target_os = "linux"))]
fn open_v4l2(name: &str, a: &Args) -> Result<Box<dyn FrameSource>> {
    use stereotac::frames::v4l2::{V4l2Camera, V4l2Settings};
    let camera = V4l2Camera::open(
        std::path::Path::new(name),
        &V4l2Settings {
            size: a.size,
            exposure_us: a.exposure_us,
            ..V4l2Settings::default()
        },
    )?;
    Ok(Box::new(camera))
}

#[cfg(not(all(feature = "v4l2", target_os = "linux")))]
fn open_v4l2(name: &str, _a: &Args) -> Result<Box<dyn FrameSource>> {
    Err(no_v4l2(name))
}

/// Refuse V4L2 cameras in a build without V4L2, before anything is connected.
fn check_cameras(cameras: &[String]) -> Result<()> {
    match cameras.iter().find(|c| *c != "sim") {
        Some(name) if !cfg!(all(feature = "v4l2", target_os = "linux")) => Err(no_v4l2(name)),
        _ => Ok(()),
    }
}

fn no_v4l2(name: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "camera {name}: this build has no V4L2 capture; rebuild with `--features v4l2` \
         (Linux; needs libclang-dev), or use --sim --camera sim"
    )
}
