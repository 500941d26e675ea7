//! `stereotac record`: camera frames with their LED phases, from one or several
//! cameras. By default one MCAP file (raw frames, labels, LED phases, clock sync, sensor
//! identity) that `process`, `export` and `calibrate` read and Foxglove opens; with
//! `--png`, PNG frames plus an index (`index.jsonl`) per camera. Ctrl-C, SIGTERM and
//! SIGHUP finish cleanly without losing a captured frame.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Result, bail};
use stereotac::device::SensorEvent;
use stereotac::frames::FrameSource;
use stereotac::frames::capture::{Capture, LabelledFrame};
use stereotac::frames::replay::Recorder;
use stereotac::live::runner::{self, Hooks, Stopped, Until};
use stereotac::live::{Output, Pipeline};
use stereotac::matcher::{MatchedFrame, MatcherConfig, phase_str};
use stereotac_protocol::Request;

use crate::args::SequenceArgs;
use crate::cameras::CameraArgs;
use crate::console::interrupt_flag;
use crate::live_session::{self, Outputs, print_recorded};
use crate::progress::spinner;
use crate::sensor_args::{DeviceArgs, open};

/// `stereotac record`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Output: a new MCAP file; with --png a directory (must not hold a recording
    /// already; with several cameras each records into DIR/cam0, DIR/cam1, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// PNG frames plus index.jsonl per camera instead of one MCAP file.
    #[arg(long)]
    pub png: bool,
    /// Serve a live view for Foxglove while recording (MCAP only; default address
    /// 127.0.0.1:8765).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<String>,
    #[command(flatten)]
    pub cameras: CameraArgs,
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
    a.cameras.check()?;
    if !a.png {
        return record_mcap(a, &stop);
    }
    if a.foxglove.is_some() {
        bail!("--foxglove shows an MCAP recording as it is made: drop --png");
    }
    let mut opened = open(&a.device)?;
    let sync = a.cameras.sync();
    let mut cameras = Vec::new();
    for (i, source) in a.cameras.open_all(&opened)?.into_iter().enumerate() {
        let dir = if a.cameras.cameras.len() == 1 {
            a.out.clone()
        } else {
            a.out.join(format!("cam{i}"))
        };
        eprintln!("camera {i}: {} -> {}", source.describe(), dir.display());
        // Its errors name the folder.
        let recorder = Recorder::create(&dir)?;
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
    let started = a
        .sequence
        .start(sensor)
        .and_then(|()| a.sequence.deadline(sensor));
    let end = match started {
        Ok(end) => end,
        Err(e) => {
            // Nothing was recorded: the folders and empty indexes made for it go.
            // The last first: the first camera's folder holds the others'.
            for camera in cameras.into_iter().rev() {
                camera.recorder.discard();
            }
            return Err(e);
        }
    };
    let progress = spinner("recording");
    let mut failure = None;
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| sensor.clock().now_us() < e) {
        let step = (|| -> Result<()> {
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
            Ok(())
        })();
        if let Err(e) = step {
            failure = Some(e);
            break;
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
    if let Some(e) = failure {
        return Err(e.context("stopped (every frame captured before is written)"));
    }
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

/// The default: one MCAP file, through the live loop with no stage on (the same clean
/// stop as `run` on a signal or a failed camera).
fn record_mcap(a: Args, stop: &AtomicBool) -> Result<()> {
    let live = live_session::start(
        "record",
        &a.device,
        &a.cameras,
        &a.sequence,
        Outputs {
            mcap: Some(a.out.clone()),
            foxglove: a.foxglove.as_deref(),
        },
        |_| Ok(()),
    )?;
    let (mut live, end_us) = live.start_sequence(&a.sequence)?;
    let sensor = &mut live.opened.sensor;
    let until = Until { flag: stop, end_us };
    let mut hooks = Progress {
        bar: spinner("recording"),
        frames: 0,
    };
    let stopped = runner::run(
        &mut live.session,
        sensor,
        &live.recorder,
        &mut Pipeline::default(),
        until,
        &mut hooks,
    );
    hooks.bar.finish_and_clear();
    live.print_cameras();
    print_recorded(&live.recorder.finish()?);
    match stopped {
        Stopped::Recorder(e) => bail!("recording failed: {e}"),
        Stopped::Failed(e) => {
            bail!("stopped: {e} (everything captured before is in the recording)")
        }
        _ => Ok(()),
    }
}

/// `record`'s view of the live loop: a frame count on the spinner.
struct Progress {
    bar: indicatif::ProgressBar,
    frames: u64,
}

impl Hooks for Progress {
    type Error = anyhow::Error;

    fn frame(&mut self, _: usize, _: &LabelledFrame) -> Result<()> {
        self.frames += 1;
        if self.frames.is_multiple_of(8) {
            self.bar.set_message(format!("{} frames", self.frames));
        }
        Ok(())
    }

    fn output(&mut self, _: &Output) -> Result<bool> {
        Ok(true)
    }

    fn warning(&mut self, message: String) {
        self.bar.suspend(|| eprintln!("warning: {message}"));
    }
}
