//! `stereotac record`: camera frames as PNG plus an index (`index.jsonl`) of phase,
//! trigger and timestamps, from one or several cameras; Ctrl-C finishes cleanly without
//! losing a captured frame.

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result};
use stereotac::device::SensorEvent;
use stereotac::frames::FrameSource;
use stereotac::frames::capture::{Capture, LabelledFrame};
use stereotac::frames::replay::Recorder;
use stereotac::matcher::{MatchedFrame, MatcherConfig, phase_str};
use stereotac_protocol::Request;

use crate::args::SequenceArgs;
use crate::cameras::CameraArgs;
use crate::console::interrupt_flag;
use crate::progress::spinner;
use crate::sensor_args::{DeviceArgs, open};

/// `stereotac record`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Output directory (must not hold a recording already). With several cameras each
    /// records into DIR/cam0, DIR/cam1, ...
    #[arg(long)]
    pub out: PathBuf,
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
