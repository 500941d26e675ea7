//! The stereo stage: dark frames of one phase from the left and right cameras in, depth,
//! a point cloud and one [`StereoRecord`] per pair out, on the host clock.

use crate::frames::capture::LabelledFrame;
use crate::matcher::{Label, StampRef};
use crate::output::grey;
pub use crate::recording::messages::StereoRecord;
use crate::stereo::StereoError;
use crate::stereo::pipeline::{StereoFrame, StereoPipeline};

/// Dark frames of one phase from camera 0 (left) and camera 1 (right).
#[derive(Debug, Clone)]
pub struct DarkPair {
    /// Camera 0's frame.
    pub left: LabelledFrame,
    /// Camera 1's frame.
    pub right: LabelledFrame,
}

/// The stereo stage (see the module documentation).
#[derive(Debug)]
pub struct StereoStage {
    pipeline: StereoPipeline,
    stamp_refs: [StampRef; 2],
    frames: u64,
}

impl StereoStage {
    /// A stage running `pipeline` on cameras whose timestamps mark `stamp_refs`.
    pub fn new(pipeline: StereoPipeline, stamp_refs: [StampRef; 2]) -> Self {
        Self {
            pipeline,
            stamp_refs,
            frames: 0,
        }
    }

    /// Stereo frames processed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Processes `pair`; `now_us` reads the host clock when the depth is ready (none
    /// offline).
    pub fn process(
        &mut self,
        pair: &DarkPair,
        now_us: impl FnOnce() -> Option<f64>,
        frames_dropped: u64,
    ) -> Result<(StereoFrame, StereoRecord), StereoError> {
        let frame = self.pipeline.process(
            &grey(&pair.left.frame.image),
            &grey(&pair.right.frame.image),
        )?;
        let ready_us = now_us();
        let left_end = pair.left.frame.stamp.exposure_end_us(self.stamp_refs[0]);
        let right_end = pair.right.frame.stamp.exposure_end_us(self.stamp_refs[1]);
        let valid = frame.sorted_valid_depths();
        let record = StereoRecord {
            sequence: self.frames,
            phase: match pair.left.label {
                Label::Phase { index, .. } => index,
                _ => 0,
            },
            exposure_end_us: left_end,
            fill: valid.len() as f64 / frame.depth_mm.as_slice().len().max(1) as f64,
            points: frame.cloud.len(),
            median_depth_mm: valid.get(valid.len() / 2).copied(),
            stage_ms: frame.timings,
            latency_ms: ready_us.map(|t| (t - left_end.max(right_end)) / 1000.0),
            frames_dropped,
            jobs_skipped: 0,
        };
        self.frames += 1;
        Ok((frame, record))
    }
}
