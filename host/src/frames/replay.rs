//! Recordings on disk: frames as PNG files plus an index (JSON lines), written by
//! [`Recorder`] and read back, in order, by [`ReplaySource`].
//!
//! `index.jsonl` holds one object per frame, written once the frame's LED phase is
//! known: `file`, `sequence`, `timestamp_us` and `exposure_us` (host clock, exposure
//! start), then the label (`"label": "phase"` with `index`, `phase`, `trigger`, or
//! `straddles`, `event_missing`, `no_trigger`, `unresolved`). Each image is written the
//! moment it arrives, so stopping a recording never loses a captured frame.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::{Frame, FrameError, FrameSource};
use crate::matcher::{FrameStamp, Label, MatchedFrame, StampRef};
use crate::out_dir::{OutDir, Replace};

/// The index file's name inside a recording.
pub const INDEX_FILE: &str = "index.jsonl";

/// One index line.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
struct IndexLine<'a> {
    file: &'a str,
    #[serde(flatten)]
    stamp: FrameStamp,
    #[serde(flatten)]
    label: Label,
}

/// The fields replay needs from an index line. Spelled out rather than a flattened
/// [`FrameStamp`]: serde's flatten buffers numbers, which fails ("invalid type: map,
/// expected f64") whenever serde_json's `arbitrary_precision` is on anywhere in the
/// build (defmt-decoder turns it on in this workspace).
#[derive(Debug, Clone, serde::Deserialize)]
struct ReplayLine {
    file: String,
    sequence: u64,
    timestamp_us: f64,
    exposure_us: f64,
}

impl ReplayLine {
    fn stamp(&self) -> FrameStamp {
        FrameStamp {
            sequence: self.sequence,
            timestamp_us: self.timestamp_us,
            exposure_us: self.exposure_us,
        }
    }
}

fn frame_file(sequence: u64) -> String {
    format!("frame_{sequence:08}.png")
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> FrameError + '_ {
    move |error| FrameError::Io {
        path: path.to_path_buf(),
        error,
    }
}

/// Writes a recording (see the module documentation).
#[derive(Debug)]
pub struct Recorder {
    dir: PathBuf,
    index: BufWriter<File>,
    images: u64,
    indexed: u64,
    /// The folder as [`OutDir`] made it: removed by [`Recorder::discard`], kept
    /// otherwise.
    folder: Option<OutDir>,
}

impl Drop for Recorder {
    fn drop(&mut self) {
        // Frames already written are data: the folder stays unless discarded.
        if let Some(folder) = self.folder.take() {
            folder.keep();
        }
    }
}

impl Recorder {
    /// Start a recording in `dir`: created, or empty; a folder with files in it (an
    /// earlier recording, or anything else) is refused, so no frame is ever overwritten.
    /// The folder stays whatever happens next (frames already written are data), unless
    /// the recording is [discarded](Recorder::discard) before its first frame.
    pub fn create(dir: &Path) -> Result<Self, FrameError> {
        let folder = OutDir::prepare(dir, Replace::Never)?;
        let path = dir.join(INDEX_FILE);
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(io(&path))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            index: BufWriter::new(file),
            images: 0,
            indexed: 0,
            folder: Some(folder),
        })
    }

    /// Undoes a recording that never started (the sensor refused the sequence): its
    /// empty index goes, and the folders [`Recorder::create`] made with it. A recording
    /// with a frame in it is kept.
    pub fn discard(mut self) {
        if self.images > 0 || self.indexed > 0 {
            return;
        }
        let _ = std::fs::remove_file(self.dir.join(INDEX_FILE));
        // Dropped unkept: removes what it made (nothing, for a folder that was there).
        drop(self.folder.take());
    }

    /// Write a frame's image now (its index line follows once it is labelled).
    pub fn write_image(&mut self, frame: &Frame) -> Result<(), FrameError> {
        let path = self.dir.join(frame_file(frame.stamp.sequence));
        frame.image.save(&path).map_err(|e| FrameError::Image {
            path: path.clone(),
            message: e.to_string(),
        })?;
        self.images += 1;
        Ok(())
    }

    /// Append a labelled frame's index line.
    pub fn write_label(&mut self, matched: &MatchedFrame) -> Result<(), FrameError> {
        let file = frame_file(matched.frame.sequence);
        let line = IndexLine {
            file: &file,
            stamp: matched.frame,
            label: matched.label,
        };
        let path = self.dir.join(INDEX_FILE);
        let text = serde_json::to_string(&line).map_err(|e| FrameError::Index {
            path: path.clone(),
            line: self.indexed as usize + 1,
            message: e.to_string(),
        })?;
        // Flushed line by line: a recording killed at any moment (SIGKILL, power) keeps
        // an index of every frame labelled so far.
        writeln!(self.index, "{text}").map_err(io(&path))?;
        self.index.flush().map_err(io(&path))?;
        self.indexed += 1;
        Ok(())
    }

    /// Flush the index to disk.
    pub fn flush(&mut self) -> Result<(), FrameError> {
        let path = self.dir.join(INDEX_FILE);
        self.index.flush().map_err(io(&path))
    }

    /// Images and index lines written.
    pub fn counts(&self) -> (u64, u64) {
        (self.images, self.indexed)
    }
}

/// Replays a recording's frames in index order.
#[derive(Debug)]
pub struct ReplaySource {
    dir: PathBuf,
    lines: Vec<ReplayLine>,
    next: usize,
}

impl ReplaySource {
    /// Open the recording in `dir`.
    pub fn open(dir: &Path) -> Result<Self, FrameError> {
        let path = dir.join(INDEX_FILE);
        let file = File::open(&path).map_err(io(&path))?;
        let mut lines = Vec::new();
        for (n, line) in BufReader::new(file).lines().enumerate() {
            let line = line.map_err(io(&path))?;
            if line.trim().is_empty() {
                continue;
            }
            let parsed: ReplayLine =
                serde_json::from_str(&line).map_err(|e| FrameError::Index {
                    path: path.clone(),
                    line: n + 1,
                    message: e.to_string(),
                })?;
            lines.push(parsed);
        }
        lines.sort_by_key(|l| l.sequence);
        Ok(Self {
            dir: dir.to_path_buf(),
            lines,
            next: 0,
        })
    }

    /// Frames in the recording.
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    /// Whether the recording is empty.
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }
}

impl FrameSource for ReplaySource {
    fn next_frame(&mut self, _timeout: Duration) -> Result<Option<Frame>, FrameError> {
        let Some(line) = self.lines.get(self.next) else {
            return Ok(None);
        };
        self.next += 1;
        let path = self.dir.join(&line.file);
        let image = crate::image_file::read_rgb(&path).map_err(|e| FrameError::Image {
            path: path.clone(),
            message: e.to_string(),
        })?;
        Ok(Some(Frame {
            stamp: line.stamp(),
            image,
        }))
    }

    fn is_finished(&self) -> bool {
        self.next >= self.lines.len()
    }

    fn stamp_ref(&self) -> StampRef {
        StampRef::ExposureStart
    }

    fn describe(&self) -> String {
        format!(
            "replay of {} ({} frames)",
            self.dir.display(),
            self.lines.len()
        )
    }
}
