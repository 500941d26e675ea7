//! What `run` and `record` share: connect the sensor, start the recorder (MCAP file,
//! live view), open the cameras, write the recording's header, and the closing lines.

use std::path::PathBuf;

use anyhow::{Result, bail};
use stereotac::clock::HostMicros;
use stereotac::frames::FrameSource;
use stereotac::live::session::Session;
use stereotac::matcher::MatcherConfig;
use stereotac::recording::metadata::{self, RunInfo};
use stereotac::recording::topics;
use stereotac::recording::writer::{
    Recorder, RecorderOptions, RecordingSummary, clock_origin_unix_ns,
};

use crate::args::SequenceArgs;
use crate::cameras::CameraArgs;
use crate::sensor_args::{DeviceArgs, Opened, open};

/// A connected sensor, its cameras and the recorder.
pub struct Live {
    /// The sensor.
    pub opened: Opened,
    /// The cameras.
    pub session: Session,
    /// The recorder.
    pub recorder: Recorder,
}

/// Where to record and show.
pub struct Outputs<'a> {
    /// The MCAP file.
    pub mcap: Option<PathBuf>,
    /// The live view's address.
    pub foxglove: Option<&'a str>,
}

/// Connects, opens the cameras, lets `check` refuse them (frame sizes a model or
/// calibration cannot take), starts the recorder and writes the header (`command`: which
/// command is recording). Nothing is created on disk before the checks pass.
pub fn start(
    command: &str,
    device: &DeviceArgs,
    cameras: &CameraArgs,
    sequence: &SequenceArgs,
    outputs: Outputs<'_>,
    check: impl FnOnce(&[Box<dyn FrameSource>]) -> Result<()>,
) -> Result<Live> {
    // Before connecting: an exposure that cannot fit in one phase gives no frame at all,
    // which a run would find out only at its end.
    cameras.setup().check_fits_phase(sequence.period_ms)?;
    let opened = open(device)?;
    let sources = cameras.open_all(&opened)?;
    check(&sources)?;
    let origin_ns = clock_origin_unix_ns(opened.sensor.clock().now_us());
    let recorder = Recorder::start(RecorderOptions {
        mcap: outputs.mcap,
        live_view: outputs.foxglove.map(str::to_string),
        queue: 64,
        wait_when_full: false,
        clock_origin_unix_ns: origin_ns,
    })?;
    if let Some(port) = recorder.live_port() {
        let host = outputs
            .foxglove
            .and_then(|s| s.rsplit_once(':'))
            .map_or("127.0.0.1", |(h, _)| h);
        eprintln!("live view: in Foxglove, Open connection → ws://{host}:{port}");
    }
    for (i, s) in sources.iter().enumerate() {
        eprintln!("camera {i}: {}", s.describe());
    }
    let session = Session::new(
        sources,
        MatcherConfig {
            sync: cameras.sync(),
            ..MatcherConfig::default()
        },
    );
    let live = Live {
        opened,
        session,
        recorder,
    };
    live.header(command, device, sequence, origin_ns)?;
    Ok(live)
}

impl Live {
    /// Starts the LED sequence and gives the run's deadline. When the sensor refuses the
    /// sequence (a phase period it cannot do, say) nothing has been recorded: the
    /// recording's file, holding only its header, is removed again, so the name stays
    /// free for the next try (it was left behind, and refused as existing).
    pub fn start_sequence(mut self, sequence: &SequenceArgs) -> Result<(Self, Option<HostMicros>)> {
        let sensor = &mut self.opened.sensor;
        match sequence
            .start(sensor)
            .and_then(|()| sequence.deadline(sensor))
        {
            Ok(end) => Ok((self, end)),
            Err(e) => {
                self.abandon();
                Err(e)
            }
        }
    }

    /// Undoes a session that never started its sequence (the sensor refused it, or a
    /// stage could not be set up): the recording holds its header alone and goes.
    pub fn abandon(self) {
        if let Ok(RecordingSummary {
            path: Some(path), ..
        }) = self.recorder.finish()
        {
            let _ = std::fs::remove_file(path);
        }
    }

    /// The recording's metadata: what ran, on which sensor, with which cameras.
    fn header(
        &self,
        command: &str,
        device: &DeviceArgs,
        sequence: &SequenceArgs,
        origin_ns: u64,
    ) -> Result<()> {
        let run = RunInfo {
            command: command.into(),
            mode: sequence.mode.into(),
            period_ms: sequence.period_ms,
            clock_origin_unix_ns: origin_ns,
            cameras: self
                .session
                .captures()
                .iter()
                .map(|c| (c.source().describe(), c.stamp_ref()))
                .collect(),
        };
        for item in metadata::header(&run, self.opened.sensor.info(), device.sim) {
            if !self.recorder.send(item) {
                bail!("the recording's writer stopped");
            }
        }
        Ok(())
    }

    /// Prints each camera's counts.
    pub fn print_cameras(&self) {
        for (i, s) in self.session.stats().iter().enumerate() {
            eprintln!(
                "camera {i}: {} frames labelled, {} dropped, {} straddling, {} with a lost \
                 event, {} without trigger, {} unresolved",
                s.labelled,
                s.dropped_frames,
                s.straddling,
                s.event_missing,
                s.no_trigger,
                s.unresolved
            );
        }
    }
}

/// The closing line of a recording.
pub fn print_recorded(summary: &RecordingSummary) {
    let Some(path) = &summary.path else { return };
    let frames: u64 = summary
        .messages
        .iter()
        .filter(|(t, _)| topics::camera_of(t).is_some() && t.ends_with("/image"))
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
