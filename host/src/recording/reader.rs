//! Reads a recording back, streaming (constant memory however long the file): the
//! `mcap` crate's sans-io linear reader, fed from the file in pieces.
//!
//! [`RecordingReader`] yields every message, metadata record and attachment in file
//! order. A file that ends early (the writer was killed, the disk filled up, the machine
//! lost power) is read up to where it stops: the end of the last chunk the writer
//! finished (the one it was writing still has its placeholder length), or the last whole
//! record. The reader then reports
//! [`RecordingReader::truncated`] instead of failing, so `process` works on what there
//! is and says so. A damaged chunk (its checksum or decompression fails) is skipped
//! and reading goes on after it, where its length field says it ends ([`layout`]); the
//! note names it. Damage in the summary section, after every message, is a note too.
//! Damage whose end the file's own fields cannot tell (a length field) goes on at the
//! next chunk the summary indexes, or, without one, stops the reading there with a
//! note, as a cut does. A file that holds no record before its damage, or a chunk in a
//! compression this build cannot read, is an error naming the file.
//!
//! [`layout`]: super::layout
//!
//! [`frames`] joins each camera's images with their labels, for `process`, `export` and
//! `calibrate`.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use foxglove::Decode;
use foxglove::messages::RawImage;
use image::RgbImage;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::layout;
use super::messages::{FrameInfo, rgb_from_raw};
use super::{RecordingError, topics};
use crate::frames::Frame;
use crate::frames::capture::LabelledFrame;
use crate::matcher::Label;

/// One record of a recording.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// A message.
    Message {
        /// Its channel's topic.
        topic: String,
        /// Its channel's message encoding (`json`, `protobuf`, ...).
        encoding: String,
        /// Log time, ns since the Unix epoch.
        log_time_ns: u64,
        /// The encoded message.
        data: Vec<u8>,
    },
    /// A metadata record.
    Metadata {
        /// Its name.
        name: String,
        /// Its entries.
        entries: BTreeMap<String, String>,
    },
    /// An attachment.
    Attachment {
        /// File name.
        name: String,
        /// Media type.
        media_type: String,
        /// Contents.
        data: Vec<u8>,
    },
}

/// A streaming reader (see the module documentation).
pub struct RecordingReader {
    path: PathBuf,
    file: File,
    reader: LinearReader,
    channels: HashMap<u16, (String, String)>,
    /// Why the reading stopped before the end, if it did.
    truncated: Option<String>,
    /// What the caller is told once the reading is over: `truncated` and the damaged
    /// chunks skipped.
    note: Option<String>,
    /// The file ends with the closing magic: its writer finished it.
    finished: bool,
    done: bool,
    /// Bytes read so far (for progress); the reader's position in the file.
    read_bytes: u64,
    len: u64,
    /// Records handed out so far: a file that ends before the first holds nothing.
    handed_out: u64,
    /// The start of a top-level record at or before the reader's position (where a walk
    /// over the records' lengths may begin).
    boundary: u64,
    /// The first damaged chunks skipped (at most [`NAMED_SKIPS`]): their bounds and why.
    skipped: Vec<(u64, u64, String)>,
    /// How many damaged chunks were skipped.
    skipped_total: usize,
    /// Messages after a skipped chunk on a channel neither read nor in the summary.
    lost_messages: u64,
    /// The file's summary, once looked up (after damage).
    summary: Option<layout::Summary>,
    /// The data section's end was read: what follows is the summary.
    data_ended: bool,
    /// How the records are read (kept for a reader that goes on after a skip).
    options: LinearReaderOptions,
    /// Bytes read when the last record was handed on: no record of a chunk starting at
    /// or after it has been handed out.
    last_record_end: u64,
}

impl std::fmt::Debug for RecordingReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordingReader")
            .field("path", &self.path)
            .field("read_bytes", &self.read_bytes)
            .finish_non_exhaustive()
    }
}

/// Largest record the reader accepts (a hostile length field cannot make it allocate
/// more): 256 MiB, far above a 4K RGB frame.
const RECORD_LIMIT: usize = 256 << 20;

/// How records are read: a chunk's checksum is checked before any of its records is
/// handed out (checked after, a damaged chunk's records would pass as sound).
fn reader_options() -> LinearReaderOptions {
    LinearReaderOptions::default()
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(RECORD_LIMIT)
}

/// `Ok` unless `body` is an attachment too short for its fields. The mcap crate's
/// parser slices an attachment's body up to its last four bytes (the checksum) before
/// checking that they are there, and panics on a body that ends right after the data's
/// length field: a damaged or hostile file must give an error instead.
fn attachment_fits(opcode: u8, body: &[u8]) -> Result<(), mcap::McapError> {
    if opcode != mcap::records::op::ATTACHMENT {
        return Ok(());
    }
    let too_short = || mcap::McapError::BadAttachmentLength {
        header: 0,
        available: body.len() as u64,
    };
    // Log time and create time, then the name and the media type (u32 length and
    // bytes each), then the data's length (u64), then the data and a u32 checksum.
    let mut at: usize = 16;
    for _ in 0..2 {
        let len = body.get(at..at + 4).ok_or_else(too_short)?;
        let len = u32::from_le_bytes(len.try_into().expect("4 bytes")) as usize;
        at = at.checked_add(4 + len).ok_or_else(too_short)?;
    }
    match at.checked_add(8 + 4) {
        Some(end) if end <= body.len() => Ok(()),
        _ => Err(too_short()),
    }
}

/// Damaged chunks the note names by their bytes (the others are counted).
const NAMED_SKIPS: usize = 5;

/// The note for damage found in the summary section (after every message).
fn summary_damaged(error: &impl std::fmt::Display) -> String {
    format!(
        "the file's summary section after its data is damaged ({error}); every message \
         before it was read"
    )
}

/// `true` when `file` ends with the closing magic (its writer finished it).
fn ends_with_magic(file: &mut File, len: u64) -> std::io::Result<bool> {
    use std::io::{Seek, SeekFrom};
    let magic = mcap::MAGIC;
    if len < magic.len() as u64 {
        return Ok(false);
    }
    file.seek(SeekFrom::End(-(magic.len() as i64)))?;
    let mut tail = vec![0u8; magic.len()];
    file.read_exact(&mut tail)?;
    file.seek(SeekFrom::Start(0))?;
    Ok(tail == magic)
}

impl RecordingReader {
    /// Opens `path`.
    pub fn open(path: &Path) -> Result<Self, RecordingError> {
        let io = |error| RecordingError::Io {
            path: path.to_path_buf(),
            error,
        };
        let mut file = File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let finished = ends_with_magic(&mut file, len).map_err(io)?;
        Ok(Self {
            finished,
            path: path.to_path_buf(),
            file,
            reader: LinearReader::new_with_options(reader_options()),
            options: reader_options(),
            last_record_end: 0,
            channels: HashMap::new(),
            truncated: None,
            note: None,
            done: false,
            read_bytes: 0,
            len,
            handed_out: 0,
            boundary: mcap::MAGIC.len() as u64,
            skipped: Vec::new(),
            skipped_total: 0,
            lost_messages: 0,
            summary: None,
            data_ended: false,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes read so far, and the file's length.
    pub fn progress(&self) -> (u64, u64) {
        (self.read_bytes, self.len)
    }

    /// Why the file ended early, or which damaged chunks were skipped, if any (after the
    /// last record was read).
    pub fn truncated(&self) -> Option<&str> {
        self.note.as_deref()
    }

    /// How many damaged chunks were skipped so far (their messages are lost).
    pub fn skipped_chunks(&self) -> usize {
        self.skipped_total
    }

    /// The note for the caller: why the reading stopped and what was skipped.
    fn compose_note(&self) -> Option<String> {
        let mut parts: Vec<String> = Vec::new();
        if self.skipped_total > 0 {
            let places: Vec<String> = self
                .skipped
                .iter()
                .map(|(start, end, why)| format!("bytes {start}–{end} ({why})"))
                .collect();
            let more = self.skipped_total - places.len();
            let one = self.skipped_total == 1;
            parts.push(format!(
                "{} damaged chunk{} skipped, {}{}: the messages in {} not read before the \
                 damage was found are lost, the reading went on after {}",
                self.skipped_total,
                if one { "" } else { "s" },
                places.join(", "),
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                },
                if one { "it" } else { "them" },
                if one { "it" } else { "them" },
            ));
        }
        if self.lost_messages > 0 {
            parts.push(format!(
                "{} later messages were on channels declared only in a damaged chunk (and \
                 not in the file's summary) and were skipped",
                self.lost_messages
            ));
        }
        parts.extend(self.truncated.clone());
        (!parts.is_empty()).then(|| parts.join("; "))
    }

    /// After `error` while reading: when the damage lies in a chunk whose length field
    /// is sound, goes on reading after that chunk (`true`). The chunk is the top-level
    /// record holding the last byte read.
    fn skip_damaged_chunk(&mut self, error: &impl std::fmt::Display) -> bool {
        use std::io::{Seek, SeekFrom};
        let Some(at) = self.read_bytes.checked_sub(1) else {
            return false;
        };
        let Ok(Some(span)) = layout::record_holding(&mut self.file, self.len, self.boundary, at)
        else {
            return false;
        };
        let sound = span.opcode == mcap::records::op::CHUNK
            && layout::chunk_is_consistent(&mut self.file, self.len, span).unwrap_or(false);
        if !sound || self.file.seek(SeekFrom::Start(span.end)).is_err() {
            return false;
        }
        self.skip_to(span.start, span.end, error);
        true
    }

    /// After damage [`Self::skip_damaged_chunk`] could not skip: `true` when the reading
    /// goes on at the next chunk the summary indexes; otherwise the reading ends with a
    /// note (damage in the summary itself, after every message, or no place to go on).
    fn go_on_after_damage(&mut self, error: &impl std::fmt::Display) -> bool {
        if self.data_ended {
            self.truncated = Some(summary_damaged(error));
            return false;
        }
        if self.resume_at_indexed_chunk(error) {
            return true;
        }
        self.stop_at_damage(error);
        false
    }

    /// Damage whose end cannot be told (a length field itself damaged, a record that
    /// cannot be one): the reading stops there, and what came before is kept, as with a
    /// file cut short. A file damaged before its first record is refused instead
    /// ([`RecordingReader::next_record`]).
    fn stop_at_damage(&mut self, error: &impl std::fmt::Display) {
        self.truncated = Some(format!(
            "the file is damaged at byte {} of {} ({error}) and where the damage ends cannot \
             be told: everything before it was read, nothing after",
            self.read_bytes, self.len
        ));
    }

    /// The channel of a message read after a skipped chunk that declared it: from the
    /// file's summary.
    fn channel_from_summary(&mut self, id: u16) -> Option<(String, String)> {
        let found = self.summary()?.channels.get(&id).cloned()?;
        self.channels.insert(id, found.clone());
        Some(found)
    }

    /// The file's summary (read once; empty when it has none or it is not sound), with
    /// the file left where the reader is.
    fn summary(&mut self) -> Option<&layout::Summary> {
        use std::io::{Seek, SeekFrom};
        if self.summary.is_none() {
            let found = layout::summary(&mut self.file, self.len, RECORD_LIMIT);
            self.summary = Some(found.unwrap_or_default());
            self.file.seek(SeekFrom::Start(self.read_bytes)).ok()?;
        }
        self.summary.as_ref()
    }

    /// After damage whose end cannot be told from the file's own fields: goes on at the
    /// first chunk the summary indexes that starts where no record was handed out yet
    /// (at or after the end of the last one; a chunk length field made larger swallows
    /// the chunks after it without an error, so the damage may be found far past them)
    /// and that is a whole chunk at that place (`true`); what lies between is skipped.
    fn resume_at_indexed_chunk(&mut self, error: &impl std::fmt::Display) -> bool {
        use std::io::{Seek, SeekFrom};
        let (from, after, len) = (self.last_record_end, self.boundary, self.len);
        let candidates: Vec<layout::Span> = match self.summary() {
            Some(s) => s
                .chunks
                .iter()
                .filter(|c| c.start >= from && c.start > after)
                .copied()
                .collect(),
            None => return false,
        };
        for next in candidates {
            if layout::is_chunk_at(&mut self.file, len, next).unwrap_or(false)
                && self.file.seek(SeekFrom::Start(next.start)).is_ok()
            {
                self.skip_to(from.max(after), next.start, error);
                return true;
            }
        }
        false
    }

    /// Records a skip of bytes `from..to` and goes on reading at `to`.
    fn skip_to(&mut self, from: u64, to: u64, error: &impl std::fmt::Display) {
        if self.skipped.len() < NAMED_SKIPS {
            self.skipped.push((from, to, error.to_string()));
        }
        self.skipped_total += 1;
        self.reader =
            LinearReader::new_with_options(self.options.clone().with_skip_start_magic(true));
        self.read_bytes = to;
        self.boundary = to;
        // Said even to a caller that stops reading before the end.
        self.note = self.compose_note();
    }

    fn format(&self, message: impl Into<String>) -> RecordingError {
        RecordingError::Format {
            path: self.path.clone(),
            message: message.into(),
        }
    }

    /// The next record; `None` at the end (or where a truncated file stops).
    pub fn next_record(&mut self) -> Option<Result<Record, RecordingError>> {
        if self.done {
            return None;
        }
        let r = self.advance();
        if matches!(r, Some(Ok(_))) {
            self.handed_out += 1;
        } else {
            self.done = true;
            self.note = self.compose_note();
        }
        if r.is_none() && self.handed_out == 0 && self.note.is_some() {
            // Cut before anything was read: nothing to go on, so not a warning.
            let why = self.note.take().unwrap_or_default();
            return Some(Err(self.format(format!(
                "holds no message, metadata or attachment ({} bytes): an empty or cut file, \
                 or not an MCAP recording ({why})",
                self.len
            ))));
        }
        r
    }

    fn advance(&mut self) -> Option<Result<Record, RecordingError>> {
        loop {
            let Some(event) = self.reader.next_event() else {
                // The end. Bytes left after the closing magic are another file appended
                // to this one (`cat a.mcap b.mcap`): said, as nothing of them is read.
                if self.read_bytes < self.len && self.truncated.is_none() {
                    self.truncated = Some(format!(
                        "the recording ends at byte {} of {}: the {} bytes after its closing \
                         magic (another file appended to it?) were not read",
                        self.read_bytes,
                        self.len,
                        self.len - self.read_bytes
                    ));
                }
                return None;
            };
            let event = match event {
                Ok(e) => e,
                Err(e @ mcap::McapError::UnexpectedEof) => {
                    // In a finished file the end comes after the closing magic: a record
                    // running past it has a damaged length (a chunk's, made larger).
                    if self.finished && self.resume_at_indexed_chunk(&e) {
                        continue;
                    }
                    self.truncated = Some(if self.finished {
                        format!(
                            "a record runs past the end of the file after {} bytes (its \
                             length is damaged: the file was finished); everything before \
                             was read",
                            self.read_bytes
                        )
                    } else {
                        format!(
                            "the file ends inside a record after {} bytes (the writer was \
                             stopped before finishing it); everything before was read",
                            self.read_bytes
                        )
                    });
                    return None;
                }
                // A chunk is started with a placeholder length that is filled in when it
                // is finished: a writer stopped mid-chunk (killed, disk full) leaves one
                // that claims to run past the end of the file. In a file without its
                // closing magic, that is where the writer stopped.
                Err(
                    mcap::McapError::UnexpectedEoc
                    | mcap::McapError::RecordTooLarge {
                        opcode: mcap::records::op::CHUNK,
                        ..
                    },
                ) if !self.finished => {
                    self.truncated = Some(format!(
                        "the file ends inside a chunk the writer never finished, after {} \
                         bytes (it was stopped mid-chunk: killed, or the disk was full); \
                         everything before that chunk was read",
                        self.read_bytes
                    ));
                    return None;
                }
                Err(e) => {
                    // A chunk whose bytes are not the ones written (a damaged disk or
                    // copy): skipped whole (none of its records is handed out: its
                    // checksum is checked first), and the reading goes on after it.
                    // Not a chunk this reader cannot read (another compression).
                    let damage = matches!(
                        e,
                        mcap::McapError::BadChunkCrc { .. }
                            | mcap::McapError::DecompressionError(_)
                            | mcap::McapError::BadChunkLength { .. }
                            | mcap::McapError::UnexpectedEoc
                            | mcap::McapError::Io(_)
                    );
                    if damage && self.skip_damaged_chunk(&e) {
                        continue;
                    }
                    // A chunk in a compression this build cannot read is not damage:
                    // refused (past the data's end it is the summary's damage). A name
                    // no MCAP writer uses is a damaged header.
                    if let mcap::McapError::UnsupportedCompression(name) = &e
                        && !self.data_ended
                        && ["zstd", "lz4", ""].contains(&name.as_str())
                    {
                        return Some(Err(self.format(e.to_string())));
                    }
                    if self.go_on_after_damage(&e) {
                        continue;
                    }
                    return None;
                }
            };
            let (opcode, data) = match event {
                LinearReadEvent::ReadRequest(n) => {
                    let buf = self.reader.insert(n);
                    match self.file.read(buf) {
                        Ok(got) => {
                            self.reader.notify_read(got);
                            self.read_bytes += got as u64;
                        }
                        Err(error) => {
                            return Some(Err(RecordingError::Io {
                                path: self.path.clone(),
                                error,
                            }));
                        }
                    }
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => {
                    self.last_record_end = self.read_bytes;
                    (opcode, data)
                }
            };
            let parsed =
                attachment_fits(opcode, data).and_then(|()| mcap::parse_record(opcode, data));
            let record = match parsed {
                Ok(r) => r,
                Err(e) => {
                    let e = e.to_string();
                    if self.skip_damaged_chunk(&e) || self.go_on_after_damage(&e) {
                        continue;
                    }
                    return None;
                }
            };
            use mcap::records::Record as R;
            match record {
                R::Channel(c) => {
                    self.channels
                        .insert(c.id, (c.topic.to_string(), c.message_encoding.to_string()));
                }
                R::DataEnd(_) => self.data_ended = true,
                R::Message { header, data } => {
                    let data = data.into_owned();
                    let known = self.channels.get(&header.channel_id).cloned();
                    let Some((topic, encoding)) = known.or_else(|| {
                        // Declared in a chunk that was skipped: the summary repeats it.
                        (self.skipped_total > 0)
                            .then(|| self.channel_from_summary(header.channel_id))
                            .flatten()
                    }) else {
                        if self.skipped_total > 0 {
                            self.lost_messages += 1;
                            self.note = self.compose_note();
                            continue;
                        }
                        return Some(Err(self.format(format!(
                            "message on channel {} before that channel was declared",
                            header.channel_id
                        ))));
                    };
                    return Some(Ok(Record::Message {
                        topic,
                        encoding,
                        log_time_ns: header.log_time,
                        data,
                    }));
                }
                R::Metadata(m) => {
                    return Some(Ok(Record::Metadata {
                        name: m.name,
                        entries: m.metadata,
                    }));
                }
                R::Attachment { header, data, .. } => {
                    return Some(Ok(Record::Attachment {
                        name: header.name,
                        media_type: header.media_type,
                        data: data.into_owned(),
                    }));
                }
                _ => {}
            }
        }
    }
}

impl Iterator for RecordingReader {
    type Item = Result<Record, RecordingError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_record()
    }
}

/// A recorded camera frame with its label.
#[derive(Debug, Clone)]
pub struct RecordedFrame {
    /// Camera number.
    pub camera: usize,
    /// Timing and label, as recorded.
    pub info: FrameInfo,
    /// The label, read from `info` (checked).
    pub label: Label,
    /// Pixels.
    pub image: RgbImage,
}

impl RecordedFrame {
    /// The frame as the live pipeline takes it.
    pub fn into_labelled(self) -> LabelledFrame {
        LabelledFrame {
            frame: Frame {
                stamp: self.info.stamp(),
                image: self.image,
            },
            label: self.label,
        }
    }
}

/// What a recording says about itself: metadata records and attachments, by name.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordingHeader {
    /// Metadata records.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Attachments.
    pub attachments: BTreeMap<String, Vec<u8>>,
    /// Why the file ended early, when [`header`] found it so (its tactile model or
    /// stereo calibration may be in the part that is missing).
    pub truncated: Option<String>,
}

/// Everything in a recording by kind, in order: frames (image joined with its label),
/// other messages, and the header (metadata, attachments) as it is met.
#[derive(Debug, Clone)]
pub enum Content {
    /// A labelled frame.
    Frame(RecordedFrame),
    /// Any other message.
    Other(Record),
}

/// Most frame labels kept waiting for their images. A recording from `record` or `run`
/// writes each image right after its label, so a handful wait at a time; this bounds the
/// memory a damaged or hostile file can take.
pub const MAX_PENDING_LABELS: usize = 4096;

/// Reads `path` through, joining frames: `each` gets every labelled frame and every
/// other message in file order (and may break off); the header is returned with how the
/// file ended.
/// A frame's image and label are joined by camera and timestamp (the label comes
/// first); an image whose label never came is reported, not guessed.
pub fn frames<E: From<RecordingError>>(
    path: &Path,
    mut each: impl FnMut(Content, (u64, u64)) -> Result<ControlFlow<()>, E>,
) -> Result<(RecordingHeader, Option<String>), E> {
    let mut reader = RecordingReader::open(path)?;
    let mut header = RecordingHeader::default();
    let mut labels: HashMap<(usize, u64), (FrameInfo, Label)> = HashMap::new();
    let mut unlabelled = 0u64;
    let bad = |topic: &str, log_time_ns, message: String| RecordingError::Message {
        path: path.to_path_buf(),
        topic: topic.to_string(),
        log_time_ns,
        message,
    };
    while let Some(record) = reader.next_record() {
        let record = record?;
        let progress = reader.progress();
        match &record {
            Record::Message {
                topic,
                log_time_ns,
                data,
                ..
            } => match topics::camera_of(topic) {
                Some(camera) if *topic == topics::camera_frame(camera) => {
                    let info: FrameInfo = serde_json::from_slice(data)
                        .map_err(|e| bad(topic, *log_time_ns, e.to_string()))?;
                    let label = info.label().map_err(|e| bad(topic, *log_time_ns, e))?;
                    labels.insert((camera, *log_time_ns), (info, label));
                    if labels.len() > MAX_PENDING_LABELS {
                        return Err(bad(
                            topic,
                            *log_time_ns,
                            format!(
                                "more than {MAX_PENDING_LABELS} frame labels without their images: \
                                 not a recording `record` or `run` writes (each label is followed by its image)"
                            ),
                        )
                        .into());
                    }
                }
                Some(camera) if *topic == topics::camera_image(camera) => {
                    let raw = RawImage::decode(data.as_slice())
                        .map_err(|e| bad(topic, *log_time_ns, e.to_string()))?;
                    let image = rgb_from_raw(&raw).map_err(|e| bad(topic, *log_time_ns, e))?;
                    let Some((info, label)) = labels.remove(&(camera, *log_time_ns)) else {
                        // Its label may have been in a damaged chunk that was skipped:
                        // the image is skipped too, and counted.
                        if reader.skipped_chunks() > 0 {
                            unlabelled += 1;
                            continue;
                        }
                        return Err(bad(
                            topic,
                            *log_time_ns,
                            format!(
                                "no label on {} for this image (same log time)",
                                topics::camera_frame(camera)
                            ),
                        )
                        .into());
                    };
                    if each(
                        Content::Frame(RecordedFrame {
                            camera,
                            info,
                            label,
                            image,
                        }),
                        progress,
                    )?
                    .is_break()
                    {
                        break;
                    }
                }
                _ => {
                    if each(Content::Other(record), progress)?.is_break() {
                        break;
                    }
                }
            },
            Record::Metadata { name, entries } => {
                header.metadata.insert(name.clone(), entries.clone());
                if each(Content::Other(record), progress)?.is_break() {
                    break;
                }
            }
            Record::Attachment { name, data, .. } => {
                header.attachments.insert(name.clone(), data.clone());
                if each(Content::Other(record), progress)?.is_break() {
                    break;
                }
            }
        }
    }
    let mut note = reader.truncated().map(str::to_string);
    if unlabelled > 0 {
        let lost = if unlabelled == 1 {
            "1 image whose label was in a damaged chunk was skipped".to_string()
        } else {
            format!("{unlabelled} images whose labels were in a damaged chunk were skipped")
        };
        note = Some(note.map_or(lost.clone(), |n| format!("{n}; {lost}")));
    }
    Ok((header, note))
}

/// The header alone: a pass over the file that skips the chunks undecompressed.
pub fn header(path: &Path) -> Result<RecordingHeader, RecordingError> {
    let mut reader = RecordingReader::open(path)?;
    reader.options = LinearReaderOptions::default()
        .with_emit_chunks(true)
        .with_record_length_limit(RECORD_LIMIT);
    reader.reader = LinearReader::new_with_options(reader.options.clone());
    let mut header = RecordingHeader::default();
    while let Some(record) = reader.next_record() {
        match record? {
            Record::Metadata { name, entries } => {
                header.metadata.insert(name, entries);
            }
            Record::Attachment { name, data, .. } => {
                header.attachments.insert(name, data);
            }
            Record::Message { .. } => {}
        }
    }
    header.truncated = reader.truncated().map(str::to_string);
    Ok(header)
}

/// What [`stream`] hands on.
#[derive(Debug)]
enum Fed {
    Content(Box<Content>),
    End(Option<String>),
    Failed(RecordingError),
}

/// [`frames`] as an iterator (pull instead of push), for callers that take one item at a
/// time (the Python package): a thread reads ahead by at most `ahead` items; dropping
/// the iterator stops it.
pub struct ContentStream {
    rx: std::sync::mpsc::Receiver<Fed>,
    truncated: Option<String>,
    done: bool,
}

impl std::fmt::Debug for ContentStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContentStream")
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

/// Streams `path`'s contents in file order (see [`frames`]); opening errors come as the
/// first item.
pub fn stream(path: &Path, ahead: usize) -> ContentStream {
    let (tx, rx) = std::sync::mpsc::sync_channel(ahead.max(1));
    let path = path.to_path_buf();
    std::thread::spawn(move || {
        let read = frames::<RecordingError>(&path, |content, _| {
            Ok(match tx.send(Fed::Content(Box::new(content))) {
                Ok(()) => ControlFlow::Continue(()),
                Err(_) => ControlFlow::Break(()),
            })
        });
        // The receiver may be gone: nothing left to tell.
        let _ = tx.send(match read {
            Ok((_, truncated)) => Fed::End(truncated),
            Err(e) => Fed::Failed(e),
        });
    });
    ContentStream {
        rx,
        truncated: None,
        done: false,
    }
}

impl ContentStream {
    /// Why the file ended early, once the stream has ended (see
    /// [`RecordingReader::truncated`]).
    pub fn truncated(&self) -> Option<&str> {
        self.truncated.as_deref()
    }
}

impl Iterator for ContentStream {
    type Item = Result<Content, RecordingError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        match self.rx.recv() {
            Ok(Fed::Content(c)) => Some(Ok(*c)),
            Ok(Fed::Failed(e)) => {
                self.done = true;
                Some(Err(e))
            }
            Ok(Fed::End(truncated)) => {
                self.done = true;
                self.truncated = truncated;
                None
            }
            // The reading thread panicked: say so rather than end quietly.
            Err(_) => {
                self.done = true;
                Some(Err(RecordingError::Format {
                    path: PathBuf::new(),
                    message: "the reading thread stopped unexpectedly (a bug: please report it)"
                        .into(),
                }))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    /// A file of frame labels whose images never come is refused once too many wait,
    /// instead of growing without bound.
    #[test]
    fn labels_without_images_are_bounded() {
        let path =
            std::env::temp_dir().join(format!("stereotac-labels-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new().create(file).unwrap();
        let topic = topics::camera_frame(0);
        let channel = w.add_channel(0, &topic, "json", &BTreeMap::new()).unwrap();
        let label = br#"{"sequence": 0, "timestamp_us": 0.0, "exposure_us": 1.0, "stamp_ref": "exposure_start", "label": "unresolved", "index": null, "phase": null, "trigger": null}"#;
        for i in 0..(MAX_PENDING_LABELS as u64 + 10) {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, label).unwrap();
        }
        w.finish().unwrap();
        drop(w);
        let mut frames_seen = 0;
        let result = frames::<RecordingError>(&path, |content, _| {
            if let Content::Frame(_) = content {
                frames_seen += 1;
            }
            Ok(ControlFlow::Continue(()))
        });
        let e = result.unwrap_err().to_string();
        assert!(e.contains("without their images"), "{e}");
        assert_eq!(frames_seen, 0);
        let _ = std::fs::remove_file(&path);
    }

    /// Frames whose labels were in a skipped chunk: their images are skipped and
    /// counted, every other frame is read; without a skipped chunk, an image with no
    /// label is an error.
    #[test]
    fn images_whose_labels_were_lost_are_skipped_and_counted() {
        use foxglove::Encode;
        let path = std::env::temp_dir().join(format!("stereotac-lost-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(2048))
            .create(file)
            .unwrap();
        let meta = BTreeMap::new();
        let labels = w
            .add_channel(0, &topics::camera_frame(0), "json", &meta)
            .unwrap();
        let images = w
            .add_channel(0, &topics::camera_image(0), "protobuf", &meta)
            .unwrap();
        let label = br#"{"sequence": 0, "timestamp_us": 0.0, "exposure_us": 1.0, "stamp_ref": "exposure_start", "label": "unresolved", "index": null, "phase": null, "trigger": null}"#;
        let image = RgbImage::from_pixel(16, 16, image::Rgb([10, 20, 30]));
        let mut label_at = Vec::new();
        for i in 0..40u64 {
            let header = |channel_id| mcap::records::MessageHeader {
                channel_id,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header(labels), label).unwrap();
            label_at.push(i);
            let mut raw = Vec::new();
            super::super::messages::rgb_image(&image, i, "cam0")
                .encode(&mut raw)
                .unwrap();
            // One chunk ends between each label and its image.
            w.flush().unwrap();
            w.write_to_known_channel(&header(images), &raw).unwrap();
        }
        w.finish().unwrap();
        drop(w);
        let read = |p: &Path| {
            let mut n = 0;
            let r = frames::<RecordingError>(p, |c, _| {
                n += usize::from(matches!(c, Content::Frame(_)));
                Ok(ControlFlow::Continue(()))
            });
            (n, r)
        };
        let (n, r) = read(&path);
        assert_eq!((n, r.unwrap().1), (40, None));
        // A byte of the label chunk of frame 20 (the label is its only message).
        let mut bytes = std::fs::read(&path).unwrap();
        let labels_at: Vec<usize> = bytes
            .windows(label.len())
            .enumerate()
            .filter(|(_, w)| *w == label)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(labels_at.len(), 40);
        bytes[labels_at[20] + 10] ^= 0x10;
        std::fs::write(&path, &bytes).unwrap();
        let (n, r) = read(&path);
        let note = r.unwrap().1.expect("said");
        // That chunk held frame 19's image and frame 20's label: both frames lost.
        assert_eq!(n, 38, "{note}");
        assert!(note.contains("1 damaged chunk skipped"), "{note}");
        assert!(
            note.contains("1 image whose label was in a damaged chunk"),
            "{note}"
        );
        let _ = std::fs::remove_file(&path);
    }

    /// An attachment whose body ends right after its data's length field (the mcap
    /// parser would panic on it) is an error; one with its fields whole parses.
    #[test]
    fn short_attachments_are_refused_not_a_panic() {
        let mut body = Vec::new();
        body.extend_from_slice(&[0u8; 16]);
        for text in ["a", "b"] {
            body.extend_from_slice(&(text.len() as u32).to_le_bytes());
            body.extend_from_slice(text.as_bytes());
        }
        body.extend_from_slice(&0u64.to_le_bytes());
        let op = mcap::records::op::ATTACHMENT;
        for cut in [body.len(), 3, 0, 20] {
            assert!(attachment_fits(op, &body[..cut]).is_err(), "{cut}");
        }
        let mut whole = body.clone();
        whole.extend_from_slice(&0u32.to_le_bytes());
        attachment_fits(op, &whole).unwrap();
        assert!(mcap::parse_record(op, &whole).is_ok());
        // Other records are not looked at.
        attachment_fits(mcap::records::op::MESSAGE, &[]).unwrap();
    }

    /// A recording of `n` JSON messages on the LED phase topic, log times 0..n.
    fn json_recording(name: &str, n: u64) -> PathBuf {
        json_recording_with(name, n, mcap::WriteOptions::new())
    }

    /// [`json_recording`] written with `options`.
    fn json_recording_with(name: &str, n: u64, options: mcap::WriteOptions) -> PathBuf {
        let path =
            std::env::temp_dir().join(format!("stereotac-{name}-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = options.create(file).unwrap();
        let channel = w
            .add_channel(0, topics::LED_PHASE, "json", &BTreeMap::new())
            .unwrap();
        for i in 0..n {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, format!("{{\"i\": {i}}}").as_bytes())
                .unwrap();
        }
        w.finish().unwrap();
        path
    }

    /// The stream gives what `frames` gives, in order; a missing file is its first item;
    /// a file cut short ends the stream and says so.
    #[test]
    fn stream_pulls_in_file_order() {
        let path = json_recording("stream", 50);
        let times: Vec<u64> = stream(&path, 4)
            .map(|c| match c.unwrap() {
                Content::Other(Record::Message { log_time_ns, .. }) => log_time_ns,
                other => panic!("unexpected {other:?}"),
            })
            .collect();
        assert_eq!(times, (0..50).collect::<Vec<_>>());
        // Dropped after two items: the reading thread stops (the test would hang on a
        // full channel otherwise only if the thread blocked forever; it must not).
        let mut s = stream(&path, 1);
        assert!(s.next().unwrap().is_ok());
        drop(s);
        // Uncompressed, in chunks of 4 kB (a chunk is read whole, its checksum checked,
        // before any of its messages is handed out; a flipped byte fails the checksum
        // rather than the decompression).
        let options = || {
            mcap::WriteOptions::new()
                .compression(None)
                .chunk_size(Some(4096))
        };
        let chunked = json_recording_with("chunked", 2000, options());
        let bytes = std::fs::read(&chunked).unwrap();
        let cut = path.with_extension("cut.mcap");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let mut s = stream(&cut, 4);
        assert!(s.by_ref().map(Result::unwrap).count() > 0);
        assert!(s.truncated().is_some(), "a cut file is reported");
        // Cut before any message, or empty: an error, not a warning.
        for end in [0, 8, 40] {
            std::fs::write(&cut, &bytes[..end]).unwrap();
            let e = stream(&cut, 4).find_map(Result::err).expect("refused");
            assert!(e.to_string().contains("holds no message"), "{end}: {e}");
        }
        let _ = std::fs::remove_file(chunked);
        // A damaged chunk: skipped whole, the damage said, and the chunks after it read.
        let damaged = json_recording_with("damaged", 2000, options());
        let mut bytes = std::fs::read(&damaged).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0x10;
        std::fs::write(&damaged, &bytes).unwrap();
        let read_times = |path: &Path| {
            let mut s = stream(path, 4);
            let times: Vec<u64> = s
                .by_ref()
                .map(|c| match c.unwrap() {
                    Content::Other(Record::Message { log_time_ns, .. }) => log_time_ns,
                    other => panic!("unexpected {other:?}"),
                })
                .collect();
            (times, s.truncated().map(str::to_string))
        };
        let (times, note) = read_times(&damaged);
        let note = note.expect("the damage is said");
        assert!(
            note.contains("Chunk CRC") && note.contains("1 damaged chunk skipped"),
            "{note}"
        );
        // In order, one gap: the damaged chunk's messages, none of them handed out (the
        // first one missing lies before the damage; checked after its records, the chunk
        // would have handed them all out), and every message after the chunk read.
        assert!(times.windows(2).all(|w| w[0] < w[1]));
        let gap = times
            .windows(2)
            .position(|w| w[1] != w[0] + 1)
            .expect("a gap");
        let (first_lost, first_after) = (times[gap] + 1, times[gap + 1]);
        assert_eq!(times[0], 0);
        assert_eq!(*times.last().unwrap(), 1999);
        assert!(first_after - first_lost < 200, "one 4 kB chunk lost");
        let place = |i: u64| {
            let text = format!("{{\"i\": {i}}}");
            bytes
                .windows(text.len())
                .position(|w| w == text.as_bytes())
                .expect("in the file")
        };
        assert!(place(first_lost) < middle && middle < place(first_after));
        // The first chunk damaged (it declares the channel): the summary names it, and
        // the rest is read; the summary itself damaged: every message read, and said.
        let mut first = std::fs::read(&damaged).unwrap();
        first[middle] ^= 0x10;
        first[200] ^= 0x10;
        std::fs::write(&damaged, &first).unwrap();
        let (times, note) = read_times(&damaged);
        assert!(times.len() > 1500 && times[0] > 0, "{}", times.len());
        assert!(note.unwrap().contains("1 damaged chunk skipped"));
        let mut summary = std::fs::read(&damaged).unwrap();
        summary[200] ^= 0x10;
        // The topic's length field in the summary's channel record, beyond the record.
        let topic = topics::LED_PHASE.as_bytes();
        let last = summary
            .windows(topic.len())
            .rposition(|w| w == topic)
            .expect("the summary repeats the channel");
        summary[last - 4..last].copy_from_slice(&u32::MAX.to_le_bytes());
        std::fs::write(&damaged, &summary).unwrap();
        let (times, note) = read_times(&damaged);
        assert_eq!(times, (0..2000).collect::<Vec<_>>());
        let note = note.unwrap_or_default();
        assert!(note.contains("summary section"), "{note}");
        // A chunk's length field damaged (one less, or 4096 more): where the chunk ends
        // cannot be trusted, so the reading goes on at the next chunk the summary indexes
        // (it was an error, and the pairs before were lost); without a summary, it stops
        // there with a note, keeping what came before.
        let mut walk = 8usize;
        let mut chunks = Vec::new();
        while walk + 9 <= bytes.len() && bytes[walk] != mcap::records::op::FOOTER {
            if bytes[walk] == mcap::records::op::CHUNK {
                chunks.push(walk);
            }
            let len = u64::from_le_bytes(bytes[walk + 1..walk + 9].try_into().unwrap());
            walk += 9 + len as usize;
        }
        assert!(chunks.len() > 10, "{} chunks", chunks.len());
        let fresh = json_recording_with("length", 2000, options());
        let whole = std::fs::read(&fresh).unwrap();
        let _ = std::fs::remove_file(fresh);
        for change in [-1i64, 4096, 1 << 40] {
            let mut broken = whole.clone();
            let at = chunks[chunks.len() / 2] + 1;
            let len = u64::from_le_bytes(broken[at..at + 8].try_into().unwrap());
            let len = len.wrapping_add_signed(change);
            broken[at..at + 8].copy_from_slice(&len.to_le_bytes());
            std::fs::write(&damaged, &broken).unwrap();
            let (times, note) = read_times(&damaged);
            let note = note.expect("said");
            assert!(
                note.contains("1 damaged chunk skipped"),
                "change {change}: {note}"
            );
            assert!(times.windows(2).all(|w| w[0] < w[1]));
            // One less: the chunk's records were whole and all read before its end was
            // found wrong; 4096 more: the next chunk was swallowed as padding without an
            // error, and is read again from the summary's index; past the file's end.
            assert!(times.len() > 1700, "change {change}: {}", times.len());
            assert_eq!((times[0], times[times.len() - 1]), (0, 1999));
            // No summary (the footer points at none): the reading stops there.
            let footer = broken.len() - 8 - 29;
            assert_eq!(broken[footer], mcap::records::op::FOOTER);
            broken[footer + 9..footer + 17].fill(0);
            std::fs::write(&damaged, &broken).unwrap();
            let (times, note) = read_times(&damaged);
            let note = note.expect("said");
            assert!(note.contains("damaged at byte"), "change {change}: {note}");
            let read = times.len() as u64;
            assert!(read > 500 && read < 2000, "change {change}: {read}");
            assert_eq!(times, (0..read).collect::<Vec<_>>());
        }
        let _ = std::fs::remove_file(damaged);
        // Two recordings one after the other: the first is read whole, and the bytes
        // after it are said (`cat` of two files was read as the first with no word).
        let whole = std::fs::read(&path).unwrap();
        let twice = path.with_extension("twice.mcap");
        std::fs::write(&twice, [whole.as_slice(), whole.as_slice()].concat()).unwrap();
        let mut s = stream(&twice, 4);
        assert_eq!(s.by_ref().map(Result::unwrap).count(), 50);
        let note = s.truncated().expect("the appended file is said");
        assert!(note.contains("were not read"), "{note}");
        let mut s = stream(&path, 4);
        assert_eq!(s.by_ref().count(), 50);
        assert_eq!(s.truncated(), None, "a whole file has no note");
        let _ = std::fs::remove_file(twice);
        let e = stream(&path.with_extension("missing.mcap"), 4)
            .next()
            .unwrap()
            .unwrap_err();
        assert!(matches!(e, RecordingError::Io { .. }), "{e}");
        for p in [path, cut] {
            let _ = std::fs::remove_file(p);
        }
    }
}
