//! Recordings and the live view: what `run`, `record`, `process` and the demo write to
//! MCAP files and show in Foxglove, on one documented set of topics.
//!
//! - [`topics`]: the topic names and what each carries.
//! - [`messages`]: the JSON messages (frame labels, LED phases, clock sync) and the
//!   conversions between our images, depth maps and point clouds and Foxglove's
//!   well-known schemas (`foxglove.RawImage`, `foxglove.PointCloud`, `foxglove.Log`).
//! - [`writer`]: the [`Recorder`](writer::Recorder): a bounded queue and a writer
//!   thread, so a slow disk or viewer never blocks capture (what it drops is counted).
//! - [`metadata`]: the header records (what ran, which sensor).
//! - [`decoded`]: messages decoded by topic (depth, points in mm; JSON; log lines).
//! - [`reader`]: reads a recording back, streaming, and recovers what a killed writer
//!   left (everything up to the last complete chunk); a damaged chunk is skipped and the
//!   rest read (`layout` walks the records' lengths to find where it ends).
//! - [`content`]: frames joined with their labels, pushed ([`content::frames`]) or
//!   pulled from a reading thread ([`content::stream`]).
//!
//! Time: every message's log time is the host clock (`HostClock`, µs since the run
//! began) placed on the Unix epoch by the wall-clock time of the host clock's origin,
//! which the `stereotac` metadata record keeps (`clock_origin_unix_ns`). The JSON
//! messages carry the host µs themselves, so nothing is lost to the conversion.

pub mod content;
pub mod decoded;
mod layout;
pub mod messages;
pub mod metadata;
pub mod reader;
pub mod topics;
pub mod writer;

use std::path::PathBuf;

/// Why a recording could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The file could not be created, written or read.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
    /// The file exists already (recordings are never overwritten).
    #[error("{0}: exists already; give a new file name (recordings are never overwritten)")]
    Exists(PathBuf),
    /// The file is not an MCAP file, or is damaged.
    #[error("{path}: not a readable MCAP recording: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A message does not decode as its topic's schema says it should.
    #[error("{path}: message on {topic} at log time {log_time_ns} ns: {message}")]
    Message {
        /// The file.
        path: PathBuf,
        /// Its topic.
        topic: String,
        /// Its log time.
        log_time_ns: u64,
        /// What is wrong.
        message: String,
    },
    /// The Foxglove SDK refused (the live view's address in use, the MCAP sink closed).
    #[error("{context}: {message}")]
    Foxglove {
        /// What was being done.
        context: String,
        /// The SDK's message.
        message: String,
    },
    /// The writer thread is gone (it failed earlier; its error was reported then).
    #[error("the recording's writer thread stopped")]
    WriterGone,
}
