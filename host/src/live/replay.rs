//! A recording's frames routed as `run` routes them, for those who want the pairs
//! themselves: `export --pairs` writes them as files, `calibrate` takes a recording's
//! ball presses directly.

use std::ops::ControlFlow;
use std::path::Path;

use image::RgbImage;

use super::{Job, Router};
use crate::matcher::Label;
use crate::recording::RecordingError;
use crate::recording::content::{self, Content};

/// A pair from a recording, named after its first frame's phase index.
#[derive(Debug, Clone)]
pub enum RecordedPair {
    /// Camera 0's dx and dy frames.
    Gradient {
        /// `phaseNNNNNN` of the dx frame.
        name: String,
        /// The dx frame.
        dx: RgbImage,
        /// The dy frame.
        dy: RgbImage,
        /// The LEDs-off frame before them (interleaved mode).
        dark: Option<RgbImage>,
    },
    /// Dark frames of one phase from cameras 0 and 1.
    Stereo {
        /// `phaseNNNNNN`.
        name: String,
        /// Camera 0's frame.
        left: RgbImage,
        /// Camera 1's frame.
        right: RgbImage,
    },
}

/// The name of a pair whose first frame has `label`.
fn name(label: &Label) -> String {
    match label {
        Label::Phase { index, .. } => format!("phase{index:06}"),
        _ => "unlabelled".into(),
    }
}

/// Every pair of the recording at `path`, in order, to `each`; returns why the file
/// ended early, if it did.
pub fn pairs<E: From<RecordingError>>(
    path: &Path,
    mut each: impl FnMut(RecordedPair) -> Result<(), E>,
) -> Result<Option<String>, E> {
    let mut router = Router::default();
    let (_, truncated) = content::frames(path, |content, _| -> Result<ControlFlow<()>, E> {
        let Content::Frame(f) = content else {
            return Ok(ControlFlow::Continue(()));
        };
        let camera = f.camera;
        match router.push(camera, f.into_labelled()) {
            Some(Job::Tactile(p)) => each(RecordedPair::Gradient {
                name: name(&p.dx.label),
                dx: p.dx.frame.image,
                dy: p.dy.frame.image,
                dark: p.dark.map(|d| d.frame.image),
            })?,
            Some(Job::Stereo(p)) => each(RecordedPair::Stereo {
                name: name(&p.left.label),
                left: p.left.frame.image,
                right: p.right.frame.image,
            })?,
            None => {}
        }
        Ok(ControlFlow::Continue(()))
    })?;
    Ok(truncated)
}
