//! The live pipeline, shared by `stereotac run` (frames as they are captured) and
//! `stereotac process` (frames from a recording): labelled frames in, routed by
//! [`Router`] to the stages, depth and records out.
//!
//! - camera 0's dx/dy pairs → [`tactile::TactileStage`] (photometric stereo);
//! - dark frames of the same phase from cameras 0 (left) and 1 (right) →
//!   [`stereo::StereoStage`] (stereo depth and point cloud).
//!
//! Routing depends only on the labelled frames and their order, so a recording fed in
//! file order gives `process` exactly the pairs `run` reconstructed. [`cameras`] opens
//! the cameras (simulated or V4L2); [`session`] is the
//! live source (a sensor, its cameras and the recorder), [`runner`] the live loop and
//! [`workers`] the stages' threads; [`replay`] reads pairs back from a recording,
//! [`scripted`] records simulated sessions, [`bench`] measures the loop under load.

pub mod bench;
pub mod cameras;
pub mod replay;
pub mod runner;
pub mod scripted;
pub mod session;
pub mod stereo;
pub mod tactile;
pub mod workers;

pub use stereo::{DarkPair, StereoRecord, StereoStage};
pub use tactile::{TactileRecord, TactileStage};

use stereotac_protocol::{Mode, Phase};

use crate::frames::capture::{GradientPair, GradientPairer, LabelledFrame};
use crate::matcher::Label;
use crate::recording::writer::Item;
use crate::stereo::{StereoError, StereoFrame};
use crate::tactile::reconstruct::{ReconstructError, Reconstruction};

/// A tactile model calibrated with LEDs-off frames (it removes each pair's own ambient
/// light) in a mode with dx/dy phases but no dark ones. The caller adds how to go on
/// (its own option names): another mode, a model calibrated without LEDs-off frames, or
/// accepting the calibration's ambient light.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "the tactile model was calibrated with LEDs-off frames (it removes each pair's own \
     ambient light), but the {mode} mode takes none"
)]
pub struct NeedsDarkFrames {
    /// The mode's name.
    pub mode: &'static str,
}

/// Refuses a model calibrated with LEDs-off frames when `mode` gives dx/dy pairs but no
/// dark phases, unless `static_ambient` accepts the calibration's ambient light in their
/// place. (A mode without dx/dy pairs never uses the model.)
pub fn check_ambient(
    model: &crate::tactile::model::TactileModel,
    mode: Mode,
    static_ambient: bool,
) -> Result<(), NeedsDarkFrames> {
    if model.ambient.is_some() && stages_of(mode) == (true, false) && !static_ambient {
        return Err(NeedsDarkFrames {
            mode: crate::describe::mode(mode),
        });
    }
    Ok(())
}

/// Which stages a sequence mode can feed: `(tactile, stereo)`. Tactile needs dx/dy
/// phases (gradient, interleaved), stereo dark ones (vision, interleaved).
pub fn stages_of(mode: Mode) -> (bool, bool) {
    match mode {
        Mode::Gradient => (true, false),
        Mode::Vision => (false, true),
        Mode::Interleaved => (true, true),
        Mode::Off | Mode::ContactShape => (false, false),
    }
}

/// What a stage produced.
#[derive(Debug)]
pub enum Output {
    /// A tactile depth map and its record.
    Tactile {
        /// The reconstruction.
        reconstruction: Reconstruction,
        /// Its record.
        record: TactileRecord,
    },
    /// A stereo frame and its record.
    Stereo {
        /// The frame (boxed: it holds its point cloud and images inline).
        frame: Box<StereoFrame>,
        /// Its record.
        record: StereoRecord,
    },
}

impl Output {
    /// What the recorder writes of it.
    pub fn into_item(self) -> Item {
        match self {
            Output::Tactile {
                reconstruction,
                record,
            } => Item::Tactile {
                depth_mm: reconstruction.depth_mm,
                record,
            },
            Output::Stereo { frame, record } => Item::Stereo {
                depth_mm: frame.depth_mm,
                cloud: frame.cloud,
                record,
            },
        }
    }
}

/// A stage failed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The tactile stage.
    #[error("tactile: {0}")]
    Tactile(#[from] ReconstructError),
    /// The stereo stage.
    #[error("stereo: {0}")]
    Stereo(#[from] StereoError),
    /// A stage's thread panicked (a bug: please report it).
    #[error("the {0} stage stopped unexpectedly (a bug: please report it)")]
    Panicked(&'static str),
}

/// The router and whichever stages are on.
#[derive(Debug, Default)]
pub struct Pipeline {
    router: Router,
    /// The tactile stage, if a model was given.
    pub tactile: Option<TactileStage>,
    /// The stereo stage, if a calibration was given.
    pub stereo: Option<StereoStage>,
}

impl Pipeline {
    /// A pipeline with these stages.
    pub fn new(tactile: Option<TactileStage>, stereo: Option<StereoStage>) -> Self {
        Self {
            router: Router::default(),
            tactile,
            stereo,
        }
    }

    /// The router and the stages, apart (the live loop runs the stages on threads).
    pub fn into_parts(self) -> (Router, Option<TactileStage>, Option<StereoStage>) {
        (self.router, self.tactile, self.stereo)
    }

    /// Put back together.
    pub fn from_parts(
        router: Router,
        tactile: Option<TactileStage>,
        stereo: Option<StereoStage>,
    ) -> Self {
        Self {
            router,
            tactile,
            stereo,
        }
    }

    /// Routes camera `camera`'s next frame; returns the job it completes for a stage
    /// that is on.
    pub fn route(&mut self, camera: usize, frame: LabelledFrame) -> Option<Job> {
        match self.router.push(camera, frame)? {
            Job::Tactile(p) if self.tactile.is_some() => Some(Job::Tactile(p)),
            Job::Stereo(p) if self.stereo.is_some() => Some(Job::Stereo(p)),
            Job::Tactile(_) => {
                self.router.unrouted.0 += 1;
                None
            }
            Job::Stereo(_) => {
                self.router.unrouted.1 += 1;
                None
            }
        }
    }

    /// Pairs completed for a stage that is off (no model, no calibration): (dx/dy pairs,
    /// stereo pairs).
    pub fn unrouted(&self) -> (u64, u64) {
        self.router.unrouted
    }

    /// Runs one job now; `now_us` reads the host clock.
    pub fn run(
        &mut self,
        job: &Job,
        now_us: impl Fn() -> Option<f64>,
        frames_dropped: u64,
    ) -> Result<Option<Output>, PipelineError> {
        Ok(match (job, &mut self.tactile, &mut self.stereo) {
            (Job::Tactile(p), Some(t), _) => {
                let (reconstruction, record) = t.process(p, now_us, frames_dropped)?;
                Some(Output::Tactile {
                    reconstruction,
                    record,
                })
            }
            (Job::Stereo(p), _, Some(s)) => {
                let (frame, record) = s.process(p, now_us, frames_dropped)?;
                Some(Output::Stereo {
                    frame: Box::new(frame),
                    record,
                })
            }
            _ => None,
        })
    }

    /// Runs `jobs` for batch work: the tactile pairs in parallel, the stereo frames in
    /// order (the temporal filter has state); outputs in the order of `jobs`, exactly
    /// what [`Self::run`] gives one by one.
    pub fn run_batch(
        &mut self,
        jobs: &[Job],
        now_us: impl Fn() -> Option<f64> + Sync,
        frames_dropped: u64,
    ) -> Vec<Result<Option<Output>, PipelineError>> {
        let pairs: Vec<&GradientPair> = jobs
            .iter()
            .filter_map(|j| match j {
                Job::Tactile(p) => Some(p),
                Job::Stereo(_) => None,
            })
            .collect();
        let mut tactile = match &mut self.tactile {
            Some(t) => t.process_batch(&pairs, &now_us, frames_dropped),
            None => Vec::new(),
        }
        .into_iter();
        let mut out = Vec::with_capacity(jobs.len());
        for job in jobs {
            out.push(match job {
                Job::Tactile(_) => match tactile.next() {
                    Some(Ok((reconstruction, record))) => Ok(Some(Output::Tactile {
                        reconstruction,
                        record,
                    })),
                    Some(Err(e)) => Err(e.into()),
                    None => Ok(None),
                },
                Job::Stereo(_) => self.run(job, &now_us, frames_dropped),
            });
        }
        out
    }
}

/// Work for a stage.
#[derive(Debug, Clone)]
pub enum Job {
    /// A dx/dy pair from camera 0.
    Tactile(GradientPair),
    /// Dark frames of one phase from cameras 0 and 1.
    Stereo(DarkPair),
}

/// Routes labelled frames to the stages (see the module documentation).
#[derive(Debug, Default)]
pub struct Router {
    gradients: GradientPairer,
    /// The latest dark frame of each stereo camera, by phase index.
    dark: [Option<LabelledFrame>; 2],
    /// Camera 0's latest dark frame and its phase index: the ambient light of the
    /// tactile pair that follows it.
    ambient: Option<(u32, LabelledFrame)>,
    /// Pairs completed for a stage that was off (counted by [`Pipeline::route`]).
    unrouted: (u64, u64),
}

impl Router {
    /// Takes camera `camera`'s next labelled frame; returns a job when it completes one.
    /// Cameras beyond 1 are recorded but not processed.
    pub fn push(&mut self, camera: usize, frame: LabelledFrame) -> Option<Job> {
        let dark_index = match frame.label {
            Label::Phase {
                phase: Phase::Dark,
                index,
                ..
            } => Some(index),
            _ => None,
        };
        match (camera, dark_index) {
            (0, None) => {
                let mut pair = self.gradients.push(frame)?;
                // Interleaved: dark n, dx n+1, dy n+2.
                if let (Label::Phase { index, .. }, Some((dark_index, dark))) =
                    (&pair.dx.label, &self.ambient)
                    && dark_index.wrapping_add(1) == *index
                {
                    pair.dark = Some(dark.clone());
                }
                Some(Job::Tactile(pair))
            }
            (0 | 1, Some(index)) => {
                if camera == 0 {
                    // A dark frame between dx and dy would break a pair: tell the pairer.
                    let _ = self.gradients.push(frame.clone());
                    self.ambient = Some((index, frame.clone()));
                }
                let other = 1 - camera;
                let matches = |f: &Option<LabelledFrame>| matches!(f, Some(LabelledFrame { label: Label::Phase { index: i, .. }, .. }) if *i == index);
                if matches(&self.dark[other]) {
                    let partner = self.dark[other].take().expect("matched");
                    let (left, right) = if camera == 0 {
                        (frame, partner)
                    } else {
                        (partner, frame)
                    };
                    return Some(Job::Stereo(DarkPair { left, right }));
                }
                self.dark[camera] = Some(frame);
                None
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::Frame;
    use crate::matcher::FrameStamp;

    fn lit(phase: Phase, index: u32) -> LabelledFrame {
        LabelledFrame {
            frame: Frame {
                stamp: FrameStamp {
                    sequence: u64::from(index),
                    timestamp_us: f64::from(index),
                    exposure_us: 1.0,
                },
                image: image::RgbImage::new(1, 1),
            },
            label: Label::Phase {
                index,
                phase,
                trigger: Some(index),
            },
        }
    }

    #[test]
    fn interleaved_frames_make_tactile_pairs_on_camera_0_and_stereo_pairs_of_one_phase() {
        let mut r = Router::default();
        // Interleaved: dark 0, dx 1, dy 2, dark 3 ... from both cameras.
        assert!(r.push(0, lit(Phase::Dark, 0)).is_none());
        let Some(Job::Stereo(p)) = r.push(1, lit(Phase::Dark, 0)) else {
            panic!("dark 0 from both cameras pair")
        };
        assert_eq!(p.left.frame.stamp.sequence, 0);
        assert!(r.push(0, lit(Phase::Dx, 1)).is_none());
        assert!(
            r.push(1, lit(Phase::Dx, 1)).is_none(),
            "camera 1's gradients are only recorded"
        );
        let Some(Job::Tactile(pair)) = r.push(0, lit(Phase::Dy, 2)) else {
            panic!("dx 1, dy 2 pair")
        };
        assert_eq!(
            pair.dark.map(|d| d.frame.stamp.sequence),
            Some(0),
            "camera 0's dark 0 is the ambient light of the pair after it"
        );
        // Camera 1 lost dark 3: camera 0's dark 3 waits, then camera 1's dark 6 does
        // not pair with it; camera 0's dark 6 pairs (camera 1 first this time).
        assert!(r.push(0, lit(Phase::Dark, 3)).is_none());
        assert!(r.push(1, lit(Phase::Dark, 6)).is_none());
        let Some(Job::Stereo(p)) = r.push(0, lit(Phase::Dark, 6)) else {
            panic!("dark 6 pairs")
        };
        assert_eq!(
            (p.left.frame.stamp.sequence, p.right.frame.stamp.sequence),
            (6, 6)
        );
        assert!(r.push(0, lit(Phase::Dx, 7)).is_none());
        let Some(Job::Tactile(pair)) = r.push(0, lit(Phase::Dy, 8)) else {
            panic!("dx 7, dy 8 pair")
        };
        assert_eq!(pair.dark.map(|d| d.frame.stamp.sequence), Some(6));
        // A dark frame between dx and dy breaks the tactile pair.
        assert!(r.push(0, lit(Phase::Dx, 10)).is_none());
        assert!(r.push(0, lit(Phase::Dark, 11)).is_none());
        assert!(r.push(0, lit(Phase::Dy, 11)).is_none());
        assert!(
            r.push(2, lit(Phase::Dark, 11)).is_none(),
            "a third camera is not routed"
        );
        // A pair whose LEDs-off frame was lost (dark 12 never came) has none.
        assert!(r.push(0, lit(Phase::Dx, 13)).is_none());
        let Some(Job::Tactile(pair)) = r.push(0, lit(Phase::Dy, 14)) else {
            panic!("dx 13, dy 14 pair")
        };
        assert!(pair.dark.is_none(), "dark 11 belongs to another cycle");
    }
}
