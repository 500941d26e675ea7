//! The stereo stage: dark frames of one phase from the left and right cameras in, depth,
//! a point cloud and one [`StereoRecord`] per pair out, on the host clock.

use crate::frames::capture::LabelledFrame;
use crate::matcher::{Label, StampRef};
use crate::median::median;
use crate::output::grey;
pub use crate::recording::messages::StereoRecord;
use crate::stereo::pipeline::{StereoFrame, StereoPipeline};
use crate::stereo::{StereoError, warnings};

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
        let (left, right) = rayon::join(
            || grey(&pair.left.frame.image),
            || grey(&pair.right.frame.image),
        );
        let frame = self.pipeline.process(&left, &right)?;
        let ready_us = now_us();
        let left_end = pair.left.frame.stamp.exposure_end_us(self.stamp_refs[0]);
        let right_end = pair.right.frame.stamp.exposure_end_us(self.stamp_refs[1]);
        // Unsorted: the median is found by radix select (a sort of 300k depths took a
        // quarter of the stage's time).
        let valid = frame.valid_depths();
        let config = self.pipeline.config();
        let warnings = warnings::of(
            &frame.stats,
            &valid,
            frame.depth_mm.as_slice().len(),
            config.near_mm,
            config.far_mm,
        );
        let record = StereoRecord {
            sequence: self.frames,
            phase: match pair.left.label {
                Label::Phase { index, .. } => index,
                _ => 0,
            },
            exposure_end_us: left_end,
            fill: valid.len() as f64 / frame.depth_mm.as_slice().len().max(1) as f64,
            points: frame.cloud.len(),
            median_depth_mm: median(&valid),
            stage_ms: frame.timings,
            latency_ms: ready_us.map(|t| (t - left_end.max(right_end)) / 1000.0),
            frames_dropped,
            jobs_skipped: 0,
            warnings,
        };
        self.frames += 1;
        Ok((frame, record))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::Frame;
    use crate::matcher::FrameStamp;
    use crate::sim::camera::SimStereo;
    use crate::stereo::StereoConfig;

    fn labelled(image: image::RgbImage) -> LabelledFrame {
        LabelledFrame {
            frame: Frame {
                stamp: FrameStamp {
                    sequence: 0,
                    timestamp_us: 0.0,
                    exposure_us: 1.0,
                },
                image,
            },
            label: Label::Unresolved,
        }
    }

    /// Live records carry the same warnings as `stereo`'s summary: none for the
    /// simulated board in range, some when the working range ends before the board.
    #[test]
    fn records_warn_when_the_working_range_cuts_the_scene() {
        let rig = SimStereo::new(320, 240);
        let (l, r) = rig.dark_views();
        let pair = DarkPair {
            left: labelled(l),
            right: labelled(r),
        };
        let run = |config: StereoConfig| {
            let pipeline = StereoPipeline::new(&rig.calibration(), config).unwrap();
            let mut stage = StereoStage::new(pipeline, [StampRef::ExposureStart; 2]);
            stage.process(&pair, || None, 0).unwrap().1
        };
        let fine = run(StereoConfig::default());
        assert!(fine.warnings.is_empty(), "{:?}", fine.warnings);
        let median = f64::from(fine.median_depth_mm.unwrap());
        let cut = run(StereoConfig {
            far_mm: median * 0.6,
            near_mm: median * 0.3,
            ..StereoConfig::default()
        });
        assert!(!cut.warnings.is_empty(), "{cut:?}");
        let json = serde_json::to_value(&cut).unwrap();
        assert!(json["warnings"].as_array().is_some_and(|w| !w.is_empty()));
        assert!(
            serde_json::to_value(&fine)
                .unwrap()
                .get("warnings")
                .is_none()
        );
    }
}
