//! What `run` and `record` share: connect the sensor, start the recorder (MCAP file,
//! live view), open the cameras, write the recording's header, and the closing lines.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Result, bail};
use stereotac::device::{firmware_version, serial_number};
use stereotac::live::session::Session;
use stereotac::matcher::MatcherConfig;
use stereotac::recording::topics;
use stereotac::recording::writer::{
    Item, Recorder, RecorderOptions, RecordingSummary, clock_origin_unix_ns,
};

use crate::args::SequenceArgs;
use crate::cameras::CameraArgs;
use crate::sensor_args::{DeviceArgs, Opened, open};
use crate::stages::stamp_ref_name;

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

/// Connects, starts the recorder, opens the cameras and writes the header (`command`:
/// which command is recording).
pub fn start(
    command: &str,
    device: &DeviceArgs,
    cameras: &CameraArgs,
    sequence: &SequenceArgs,
    outputs: Outputs<'_>,
) -> Result<Live> {
    let opened = open(device)?;
    let origin_ns = clock_origin_unix_ns(opened.sensor.clock().now_us());
    let recorder = Recorder::start(RecorderOptions {
        mcap: outputs.mcap,
        live_view: outputs.foxglove.map(str::to_string),
        queue: 64,
        clock_origin_unix_ns: origin_ns,
    })?;
    if let Some(port) = recorder.live_port() {
        let host = outputs
            .foxglove
            .and_then(|s| s.rsplit_once(':'))
            .map_or("127.0.0.1", |(h, _)| h);
        eprintln!("live view: in Foxglove, Open connection → ws://{host}:{port}");
    }
    let sources = cameras.open_all(&opened)?;
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
    /// The recording's metadata: what ran, on which sensor, with which cameras.
    fn header(
        &self,
        command: &str,
        device: &DeviceArgs,
        sequence: &SequenceArgs,
        origin_ns: u64,
    ) -> Result<()> {
        let info = self.opened.sensor.info();
        let captures = self.session.captures();
        let mut run = BTreeMap::from([
            ("version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
            ("command".to_string(), command.to_string()),
            (
                "mode".to_string(),
                format!("{:?}", sequence.mode).to_lowercase(),
            ),
            ("period_ms".to_string(), sequence.period_ms.to_string()),
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
        let sensor = BTreeMap::from([
            ("serial".to_string(), serial_number(&info.board_id)),
            ("firmware".to_string(), firmware_version(info)),
            (
                "protocol_version".to_string(),
                info.protocol_version.to_string(),
            ),
            ("simulated".to_string(), device.sim.to_string()),
        ]);
        for (name, entries) in [(topics::META_RECORDING, run), (topics::META_SENSOR, sensor)] {
            if !self.recorder.send(Item::Metadata {
                name: name.into(),
                entries,
            }) {
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
