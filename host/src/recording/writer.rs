//! The [`Recorder`]: the live pipeline hands it messages; a writer thread encodes them
//! once and sends them to an MCAP file (the `mcap` crate, LZ4 chunks) and to the live
//! view (the `foxglove` crate's WebSocket server), whichever are on.
//!
//! The hand-over is a bounded queue. When it is full (a slow disk), a message is
//! dropped and counted by kind, never waited for: capture and USB are never blocked.
//! Metadata, attachments and the end of the recording do wait, so they are never lost.
//! The live view has its own per-client backlog in the SDK and drops for slow viewers.
//!
//! The MCAP file is created new (never overwritten) and its current chunk is closed
//! every second, so after a crash or SIGKILL everything up to the last second is
//! readable ([`super::reader`] recovers it). [`Recorder::finish`] writes the summary and
//! index; a write error (disk full) stops the writer and is returned, naming the file as
//! incomplete.

use std::collections::{BTreeMap, HashMap};
use std::fs::{File, OpenOptions};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use foxglove::messages::{Log, log::Level};
use foxglove::{Encode, RawChannel, Schema};
use image::RgbImage;
use serde::Serialize;

use super::messages::{
    ClockInfo, FrameInfo, PhaseInfo, StereoRecord, TactileRecord, depth_image, point_cloud,
    rgb_image, timestamp,
};
use super::{RecordingError, topics};
use crate::grid::Grid;
use crate::stereo::reproject::PointCloud;

/// Where the recorder sends, and how much it buffers.
#[derive(Debug, Clone)]
pub struct RecorderOptions {
    /// The MCAP file to create (refused if it exists).
    pub mcap: Option<PathBuf>,
    /// Serve the live view on this address (`host:port`; port 0 picks a free one).
    pub live_view: Option<String>,
    /// Messages the queue holds before it drops (at least 1).
    pub queue: usize,
    /// Wait for room instead of dropping (batch work and simulations, where nothing
    /// should be lost and nothing live can be blocked).
    pub wait_when_full: bool,
    /// Unix time of the host clock's zero, ns (see [`clock_origin_unix_ns`]).
    pub clock_origin_unix_ns: u64,
}

/// Unix time, ns, of the moment a host clock reading `now_us` µs now read zero.
pub fn clock_origin_unix_ns(now_us: u64) -> u64 {
    let unix_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    unix_ns.saturating_sub(now_us.saturating_mul(1000))
}

/// One thing to record. Times are host µs.
#[derive(Debug, Clone)]
pub enum Item {
    /// A camera frame and its label.
    Frame {
        /// Camera number.
        camera: usize,
        /// Its timing and label.
        info: FrameInfo,
        /// Its pixels.
        image: RgbImage,
    },
    /// An LED phase.
    Phase(PhaseInfo),
    /// The clock-sync state.
    Clock(ClockInfo),
    /// A tactile depth map (mm) and its summary; stamped at the dy exposure's end.
    Tactile {
        /// Depth, mm (shared with the reading it came from).
        depth_mm: std::sync::Arc<Grid<f32>>,
        /// The summary.
        record: TactileRecord,
    },
    /// A stereo depth map (mm), its point cloud (mm) and its summary; stamped at the
    /// left exposure's end.
    Stereo {
        /// Depth, mm.
        depth_mm: Grid<f32>,
        /// Points, mm.
        cloud: PointCloud,
        /// The summary.
        record: StereoRecord,
    },
    /// A warning (also printed by the CLI).
    Warning {
        /// Host µs.
        at_us: f64,
        /// The text.
        message: String,
    },
    /// A metadata record (never dropped).
    Metadata {
        /// Record name.
        name: String,
        /// Its entries.
        entries: BTreeMap<String, String>,
    },
    /// An attachment (never dropped).
    Attachment {
        /// File name.
        name: String,
        /// Media type.
        media_type: String,
        /// Contents.
        data: Vec<u8>,
    },
}

/// What is dropped when the queue is full, by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Drops {
    /// Camera frames.
    pub frames: u64,
    /// Depth maps, point clouds and summaries.
    pub results: u64,
    /// Phases, clock states and warnings.
    pub events: u64,
}

impl Drops {
    /// All drops.
    pub fn total(&self) -> u64 {
        self.frames + self.results + self.events
    }
}

/// What a finished recording holds.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RecordingSummary {
    /// The file, if one was written.
    pub path: Option<PathBuf>,
    /// Messages written, per topic.
    pub messages: BTreeMap<String, u64>,
    /// Drops at the queue.
    pub dropped: Drops,
    /// Bytes in the file.
    pub bytes: u64,
}

#[derive(Debug, Default)]
struct DropCounters {
    frames: AtomicU64,
    results: AtomicU64,
    events: AtomicU64,
}

/// The recorder (see the module documentation).
#[derive(Debug)]
pub struct Recorder {
    tx: Option<SyncSender<Item>>,
    thread: Option<JoinHandle<Result<RecordingSummary, RecordingError>>>,
    drops: Arc<DropCounters>,
    failed: Arc<Mutex<Option<String>>>,
    live_port: Option<u16>,
    wait_when_full: bool,
    active: bool,
    origin_ns: u64,
}

impl Recorder {
    /// Creates the file and starts the live view now (so a wrong path or a busy port
    /// is reported before anything runs), then the writer thread.
    pub fn start(options: RecorderOptions) -> Result<Self, RecordingError> {
        let file = options.mcap.as_deref().map(McapOut::create).transpose()?;
        let active = file.is_some() || options.live_view.is_some();
        let live = options
            .live_view
            .as_deref()
            .map(LiveOut::start)
            .transpose()?;
        let live_port = live.as_ref().map(|l| l.port);
        let (tx, rx) = std::sync::mpsc::sync_channel(options.queue.max(1));
        let drops = Arc::new(DropCounters::default());
        let failed = Arc::new(Mutex::new(None));
        let mut out = Outputs {
            mcap: file,
            live,
            channels: HashMap::new(),
            origin_ns: options.clock_origin_unix_ns,
            summary: RecordingSummary {
                path: options.mcap.clone(),
                ..RecordingSummary::default()
            },
        };
        let thread_failed = Arc::clone(&failed);
        let thread = std::thread::Builder::new()
            .name("stereotac-recorder".into())
            .spawn(move || {
                let result = out.run(rx);
                if let Err(e) = &result {
                    *thread_failed.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.to_string());
                }
                result
            })
            .map_err(|error| RecordingError::Io {
                path: options.mcap.clone().unwrap_or_default(),
                error,
            })?;
        Ok(Self {
            tx: Some(tx),
            thread: Some(thread),
            drops,
            failed,
            live_port,
            wait_when_full: options.wait_when_full,
            active,
            origin_ns: options.clock_origin_unix_ns,
        })
    }

    /// Unix time of the host clock's zero, ns, as it was given.
    pub fn clock_origin_unix_ns(&self) -> u64 {
        self.origin_ns
    }

    /// Whether anything is written or shown (no file and no live view: messages are
    /// not worth preparing).
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// The live view's port, if it runs.
    pub fn live_port(&self) -> Option<u16> {
        self.live_port
    }

    /// Queues `item`; `false` if it was dropped (queue full) or the writer is gone.
    /// Metadata and attachments wait for room instead, as everything does with
    /// [`RecorderOptions::wait_when_full`].
    pub fn send(&self, item: Item) -> bool {
        let Some(tx) = &self.tx else { return false };
        if !self.active {
            return true;
        }
        if self.wait_when_full || matches!(item, Item::Metadata { .. } | Item::Attachment { .. }) {
            return tx.send(item).is_ok();
        }
        let counter = match &item {
            Item::Frame { .. } => &self.drops.frames,
            Item::Tactile { .. } | Item::Stereo { .. } => &self.drops.results,
            _ => &self.drops.events,
        };
        match tx.try_send(item) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                counter.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Drops so far.
    pub fn dropped(&self) -> Drops {
        Drops {
            frames: self.drops.frames.load(Ordering::Relaxed),
            results: self.drops.results.load(Ordering::Relaxed),
            events: self.drops.events.load(Ordering::Relaxed),
        }
    }

    /// The writer's error, if it stopped (a full disk): the caller should stop too.
    pub fn failure(&self) -> Option<String> {
        self.failed
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Writes what is queued, the drop counts (metadata `drops`), the summary and the
    /// index; stops the live view.
    pub fn finish(mut self) -> Result<RecordingSummary, RecordingError> {
        let dropped = self.dropped();
        let counts = BTreeMap::from([
            ("frames".to_string(), dropped.frames.to_string()),
            ("results".to_string(), dropped.results.to_string()),
            ("events".to_string(), dropped.events.to_string()),
        ]);
        self.send(Item::Metadata {
            name: "drops".into(),
            entries: counts,
        });
        drop(self.tx.take());
        let thread = self.thread.take().ok_or(RecordingError::WriterGone)?;
        let mut summary = thread.join().map_err(|_| RecordingError::WriterGone)??;
        summary.dropped = dropped;
        Ok(summary)
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        drop(self.tx.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The MCAP file being written.
struct McapOut {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    last_flush: Instant,
}

/// How often the current chunk is closed (what a crash can lose at most).
const FLUSH_EVERY: Duration = Duration::from_secs(1);

impl McapOut {
    fn create(path: &Path) -> Result<Self, RecordingError> {
        let io = |error: std::io::Error| RecordingError::Io {
            path: path.to_path_buf(),
            error,
        };
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| {
                if e.kind() == std::io::ErrorKind::AlreadyExists {
                    RecordingError::Exists(path.to_path_buf())
                } else {
                    io(e)
                }
            })?;
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .profile("")
            .library(format!("stereotac {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| mcap_error(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            last_flush: Instant::now(),
        })
    }
}

fn mcap_error(path: &Path, e: mcap::McapError) -> RecordingError {
    match e {
        mcap::McapError::Io(error) => RecordingError::Io {
            path: path.to_path_buf(),
            error: std::io::Error::new(
                error.kind(),
                format!("{error} (the recording is incomplete: readable up to its last chunk)"),
            ),
        },
        other => RecordingError::Format {
            path: path.to_path_buf(),
            message: other.to_string(),
        },
    }
}

/// The live view: a Foxglove WebSocket server on its own context.
struct LiveOut {
    context: Arc<foxglove::Context>,
    server: Option<foxglove::WebSocketServerHandle>,
    port: u16,
}

impl LiveOut {
    fn start(addr: &str) -> Result<Self, RecordingError> {
        let bad = |message: String| RecordingError::Foxglove {
            context: format!("live view on {addr}"),
            message,
        };
        let (host, port) = addr
            .rsplit_once(':')
            .and_then(|(h, p)| Some((h.trim_matches(['[', ']']), p.parse::<u16>().ok()?)))
            .ok_or_else(|| bad("give HOST:PORT, e.g. 127.0.0.1:8765".into()))?;
        let context = foxglove::Context::new();
        let server = context
            .websocket_server()
            .name("stereotac")
            .bind(host, port)
            .start_blocking()
            .map_err(|e| bad(e.to_string()))?;
        let port = server.port();
        Ok(Self {
            context,
            server: Some(server),
            port,
        })
    }
}

impl Drop for LiveOut {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
    }
}

/// A topic's schema and encoding.
struct TopicKind {
    schema: Option<Schema>,
    encoding: String,
}

impl TopicKind {
    fn of<T: Encode>() -> Self {
        Self {
            schema: T::get_schema(),
            encoding: T::get_message_encoding(),
        }
    }

    /// A JSON topic; `name` is its schema's title.
    fn json(name: &str) -> Self {
        let schema = format!(r#"{{"title":"{name}","type":"object"}}"#);
        Self {
            schema: Some(Schema::new(name, "jsonschema", schema.into_bytes())),
            encoding: "json".into(),
        }
    }
}

/// One topic's channel in each output.
struct OutChannel {
    mcap_id: Option<u16>,
    live: Option<Arc<RawChannel>>,
    sequence: u32,
}

/// The writer thread's state.
struct Outputs {
    mcap: Option<McapOut>,
    live: Option<LiveOut>,
    channels: HashMap<String, OutChannel>,
    origin_ns: u64,
    summary: RecordingSummary,
}

impl Outputs {
    fn run(&mut self, rx: Receiver<Item>) -> Result<RecordingSummary, RecordingError> {
        loop {
            // Wake at least once a second, so the chunk is closed on time even when no
            // message comes.
            match rx.recv_timeout(FLUSH_EVERY) {
                Ok(item) => self.item(item)?,
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            if let Some(m) = &mut self.mcap
                && m.last_flush.elapsed() >= FLUSH_EVERY
            {
                m.writer.flush().map_err(|e| mcap_error(&m.path, e))?;
                m.last_flush = Instant::now();
            }
        }
        if let Some(mut m) = self.mcap.take() {
            m.writer.finish().map_err(|e| mcap_error(&m.path, e))?;
            let file = m.writer.into_inner();
            let file = file.into_inner().map_err(|e| RecordingError::Io {
                path: m.path.clone(),
                error: e.into_error(),
            })?;
            file.sync_all().map_err(|error| RecordingError::Io {
                path: m.path.clone(),
                error,
            })?;
            self.summary.bytes = file.metadata().map_or(0, |md| md.len());
        }
        Ok(std::mem::take(&mut self.summary))
    }

    /// Host µs on the Unix epoch, ns.
    fn ns(&self, host_us: f64) -> u64 {
        self.origin_ns
            .saturating_add((host_us.max(0.0) * 1000.0).round() as u64)
    }

    fn item(&mut self, item: Item) -> Result<(), RecordingError> {
        match item {
            Item::Frame {
                camera,
                info,
                image,
            } => {
                // Stamped at the start of the exposure, whatever the camera's stamps mark.
                let at = self.ns(info.stamp().exposure_start_us(info.stamp_ref()));
                let frame_id = format!("cam{camera}");
                self.json(
                    &topics::camera_frame(camera),
                    "stereotac.FrameInfo",
                    at,
                    &info,
                )?;
                let msg = rgb_image(&image, at, &frame_id);
                self.encoded(&topics::camera_image(camera), at, &msg)?;
            }
            Item::Phase(p) => {
                let at = self.ns(p.write_start_us);
                self.json(topics::LED_PHASE, "stereotac.PhaseInfo", at, &p)?;
            }
            Item::Clock(c) => {
                let at = self.ns(c.host_us);
                self.json(topics::CLOCK, "stereotac.ClockInfo", at, &c)?;
            }
            Item::Tactile { depth_mm, record } => {
                let at = self.ns(record.exposure_end_us[1]);
                let msg = depth_image(&depth_mm, at, "cam0");
                self.encoded(topics::TACTILE_DEPTH, at, &msg)?;
                self.json(
                    topics::TACTILE_CONTACT,
                    "stereotac.TactileRecord",
                    at,
                    &record,
                )?;
            }
            Item::Stereo {
                depth_mm,
                cloud,
                record,
            } => {
                let at = self.ns(record.exposure_end_us);
                self.encoded(
                    topics::STEREO_DEPTH,
                    at,
                    &depth_image(&depth_mm, at, "cam0"),
                )?;
                self.encoded(topics::STEREO_POINTS, at, &point_cloud(&cloud, at, "cam0"))?;
                self.json(
                    topics::STEREO_SUMMARY,
                    "stereotac.StereoRecord",
                    at,
                    &record,
                )?;
            }
            Item::Warning { at_us, message } => {
                let at = self.ns(at_us);
                let log = Log {
                    timestamp: Some(timestamp(at)),
                    level: Level::Warning as i32,
                    message,
                    name: "stereotac".into(),
                    file: String::new(),
                    line: 0,
                };
                self.encoded(topics::LOG, at, &log)?;
            }
            Item::Metadata { name, entries } => {
                if let Some(m) = &mut self.mcap {
                    m.writer
                        .write_metadata(&mcap::records::Metadata {
                            name,
                            metadata: entries,
                        })
                        .map_err(|e| mcap_error(&m.path, e))?;
                }
            }
            Item::Attachment {
                name,
                media_type,
                data,
            } => {
                if let Some(m) = &mut self.mcap {
                    m.writer
                        .attach(&mcap::Attachment {
                            log_time: self.origin_ns,
                            create_time: self.origin_ns,
                            name,
                            media_type,
                            data: data.into(),
                        })
                        .map_err(|e| mcap_error(&m.path, e))?;
                }
            }
        }
        Ok(())
    }

    fn json<T: Serialize>(
        &mut self,
        topic: &str,
        schema: &str,
        at: u64,
        msg: &T,
    ) -> Result<(), RecordingError> {
        let bytes = serde_json::to_vec(msg).map_err(|e| RecordingError::Message {
            path: self.summary.path.clone().unwrap_or_default(),
            topic: topic.into(),
            log_time_ns: at,
            message: e.to_string(),
        })?;
        self.write(topic, || TopicKind::json(schema), at, &bytes)
    }

    fn encoded<T: Encode>(&mut self, topic: &str, at: u64, msg: &T) -> Result<(), RecordingError> {
        let mut bytes = Vec::with_capacity(msg.encoded_len().unwrap_or(1024));
        msg.encode(&mut bytes)
            .map_err(|e| RecordingError::Message {
                path: self.summary.path.clone().unwrap_or_default(),
                topic: topic.into(),
                log_time_ns: at,
                message: e.to_string(),
            })?;
        self.write(topic, TopicKind::of::<T>, at, &bytes)
    }

    fn write(
        &mut self,
        topic: &str,
        kind: impl FnOnce() -> TopicKind,
        at: u64,
        bytes: &[u8],
    ) -> Result<(), RecordingError> {
        if !self.channels.contains_key(topic) {
            let channel = self.open_channel(topic, kind())?;
            self.channels.insert(topic.to_string(), channel);
        }
        let channel = self.channels.get_mut(topic).expect("inserted above");
        if let (Some(id), Some(m)) = (channel.mcap_id, &mut self.mcap) {
            m.writer
                .write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: id,
                        sequence: channel.sequence,
                        log_time: at,
                        publish_time: at,
                    },
                    bytes,
                )
                .map_err(|e| mcap_error(&m.path, e))?;
        }
        if let Some(live) = &channel.live {
            live.log_with_meta(bytes, foxglove::PartialMetadata { log_time: Some(at) });
        }
        channel.sequence = channel.sequence.wrapping_add(1);
        *self.summary.messages.entry(topic.to_string()).or_default() += 1;
        Ok(())
    }

    fn open_channel(&mut self, topic: &str, kind: TopicKind) -> Result<OutChannel, RecordingError> {
        let mcap_id = match &mut self.mcap {
            Some(m) => {
                let schema_id = match &kind.schema {
                    Some(s) => m
                        .writer
                        .add_schema(&s.name, &s.encoding, &s.data)
                        .map_err(|e| mcap_error(&m.path, e))?,
                    None => 0,
                };
                Some(
                    m.writer
                        .add_channel(schema_id, topic, &kind.encoding, &BTreeMap::new())
                        .map_err(|e| mcap_error(&m.path, e))?,
                )
            }
            None => None,
        };
        let live = match &self.live {
            Some(l) => Some(
                l.context
                    .channel_builder(topic)
                    .message_encoding(kind.encoding.as_str())
                    .schema(kind.schema)
                    .build_raw()
                    .map_err(|e| RecordingError::Foxglove {
                        context: format!("live view channel {topic}"),
                        message: e.to_string(),
                    })?,
            ),
            None => None,
        };
        Ok(OutChannel {
            mcap_id,
            live,
            sequence: 0,
        })
    }
}
