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
//! [`content`](super::content) joins each camera's images with their labels, for
//! `process`, `export`, `calibrate` and the Python package.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::RecordingError;
use super::layout;

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

/// Up to `n` bytes from the start of `file`, leaving it at the start.
fn read_start(file: &mut File, n: usize) -> std::io::Result<Vec<u8>> {
    let mut start = Vec::with_capacity(n);
    (&mut *file).take(n as u64).read_to_end(&mut start)?;
    file.seek(SeekFrom::Start(0))?;
    Ok(start)
}

/// What a file that is not an MCAP recording looks like from its first bytes, for the
/// message (" (it looks like a JSON file)"), or nothing when it cannot be told.
fn looks_like(start: &[u8]) -> &'static str {
    let text = start.trim_ascii_start();
    if start.starts_with(b"\x89PNG") {
        " (it is a PNG image)"
    } else if start.starts_with(&[0xff, 0xd8, 0xff]) {
        " (it is a JPEG image)"
    } else if start.starts_with(b"\x7fELF") {
        " (it is an ELF binary)"
    } else if start.starts_with(b"UF2\n") {
        " (it is a UF2 firmware image)"
    } else if text.starts_with(b"{") || text.starts_with(b"[") {
        " (it looks like a JSON file)"
    } else if text.starts_with(b"%YAML") {
        " (it looks like a YAML file)"
    } else {
        ""
    }
}

impl RecordingReader {
    /// Opens `path`; a file that does not start with MCAP's magic bytes is refused here
    /// (one shorter than them, an empty or cut recording, is read and reported as such).
    pub fn open(path: &Path) -> Result<Self, RecordingError> {
        let io = |error| RecordingError::Io {
            path: path.to_path_buf(),
            error,
        };
        let mut file = File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let finished = ends_with_magic(&mut file, len).map_err(io)?;
        let start = read_start(&mut file, mcap::MAGIC.len()).map_err(io)?;
        if !mcap::MAGIC.starts_with(&start) {
            return Err(RecordingError::Format {
                path: path.to_path_buf(),
                message: format!(
                    "it does not start with MCAP's magic bytes{}",
                    looks_like(&start)
                ),
            });
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A file that does not start with MCAP's magic is refused at opening, saying what
    /// it looks like; a cut one (a prefix of the magic, or empty) opens and is read as cut.
    #[test]
    fn what_is_not_a_recording_is_refused_at_opening() {
        let dir = std::env::temp_dir().join(format!("stereotac-not-mcap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes, says) in [
            ("model.json", &b"  {\"width\": 640}"[..], "JSON"),
            ("frame.mcap", b"\x89PNG\r\n\x1a\n....", "PNG"),
            ("notes.mcap", b"this is not an MCAP file", "magic bytes"),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let e = RecordingReader::open(&path).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains(says), "{e}");
        }
        for (name, bytes) in [("empty.mcap", &b""[..]), ("cut.mcap", &mcap::MAGIC[..5])] {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let mut reader = RecordingReader::open(&path).unwrap();
            let e = reader.next_record().unwrap().unwrap_err().to_string();
            assert!(e.contains("empty or cut"), "{e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
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
}
