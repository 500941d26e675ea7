//! Camera frames with host timestamps, from any source.
//!
//! [`FrameSource`] is what the recorder and the pipelines read: a live camera, a
//! recorded directory ([`replay`]), or the simulated camera ([`sim`]) that renders
//! whatever the LEDs showed during each exposure. Timestamps are on the host clock
//! ([`crate::clock::HostClock`]); what they mark is the source's [`StampRef`].

pub mod capture;
pub mod replay;
#[cfg(all(feature = "v4l2", target_os = "linux"))]
pub mod v4l2;

use std::time::Duration;

use image::RgbImage;

use crate::matcher::{FrameStamp, StampRef};

/// One frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Timing on the host clock.
    pub stamp: FrameStamp,
    /// The pixels.
    pub image: RgbImage,
}

/// Why frames could not be read.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// A file could not be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The cause.
        error: std::io::Error,
    },
    /// The recording's folder cannot be used (it holds files).
    #[error(transparent)]
    Folder(#[from] crate::out_dir::OutDirError),
    /// An image could not be decoded or encoded.
    #[error("{path}: {message}")]
    Image {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A recording's index is malformed.
    #[error("{path} line {line}: {message}")]
    Index {
        /// The index file.
        path: std::path::PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The camera failed.
    #[error("camera {device}: {message}")]
    Camera {
        /// Device name.
        device: String,
        /// What went wrong.
        message: String,
    },
}

/// A source of timestamped frames.
pub trait FrameSource {
    /// The next frame, waiting at most `timeout`; `None` if none came in time.
    fn next_frame(&mut self, timeout: Duration) -> Result<Option<Frame>, FrameError>;
    /// Whether the source has no more frames (a replay at its end).
    fn is_finished(&self) -> bool {
        false
    }
    /// What the timestamps mark.
    fn stamp_ref(&self) -> StampRef;
    /// The size of its frames, when known before the first one arrives (a camera
    /// that negotiated its format).
    fn frame_size(&self) -> Option<(u32, u32)> {
        None
    }
    /// A short description for logs.
    fn describe(&self) -> String;
}

impl<T: FrameSource + ?Sized> FrameSource for Box<T> {
    fn next_frame(&mut self, timeout: Duration) -> Result<Option<Frame>, FrameError> {
        (**self).next_frame(timeout)
    }
    fn is_finished(&self) -> bool {
        (**self).is_finished()
    }
    fn stamp_ref(&self) -> StampRef {
        (**self).stamp_ref()
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
}
