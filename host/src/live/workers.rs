//! The stages on their own threads, for the live loop. Each stage has a slot that holds
//! at most one job: a new job replaces one still waiting (the newest frames win; the
//! stale job is counted as dropped by that stage and reported in its records), so a
//! slow stage never holds up capture or the other stage, and depth is never more than
//! one job behind. Outputs come back over a channel as each stage finishes them.
//!
//! Batch work (`process`) does not drop: it uses [`super::Pipeline::run_batch`].

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;

use super::{Job, Output, PipelineError, StereoStage, TactileStage};
use crate::clock::HostClock;

/// A job waiting for its stage, and whether the slot is closed.
#[derive(Default)]
struct SlotState {
    job: Option<(Job, u64)>,
    closed: bool,
}

/// One stage's slot.
#[derive(Default)]
struct Slot {
    state: Mutex<SlotState>,
    ready: Condvar,
    dropped: AtomicU64,
}

impl Slot {
    fn lock(&self) -> std::sync::MutexGuard<'_, SlotState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Puts `job` in, replacing (and counting) one still waiting.
    fn put(&self, job: Job, frames_dropped: u64) {
        let mut s = self.lock();
        if s.job.replace((job, frames_dropped)).is_some() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
        self.ready.notify_one();
    }

    /// The next job; `None` once closed and empty.
    fn take(&self) -> Option<(Job, u64)> {
        let mut s = self.lock();
        loop {
            if let Some(job) = s.job.take() {
                return Some(job);
            }
            if s.closed {
                return None;
            }
            s = self.ready.wait(s).unwrap_or_else(|p| p.into_inner());
        }
    }

    fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_one();
    }
}

/// A stage's thread and slot.
struct Worker<S> {
    slot: Arc<Slot>,
    thread: JoinHandle<S>,
}

/// What a worker sends back.
pub type Produced = Result<Output, PipelineError>;

impl<S: Send + 'static> Worker<S> {
    fn spawn(
        name: &str,
        mut stage: S,
        tx: Sender<Produced>,
        mut run: impl FnMut(&mut S, &Job, u64) -> Option<Produced> + Send + 'static,
    ) -> Self {
        let slot = Arc::new(Slot::default());
        let mine = Arc::clone(&slot);
        let thread = std::thread::Builder::new()
            .name(format!("stereotac-{name}"))
            .spawn(move || {
                while let Some((job, frames_dropped)) = mine.take() {
                    let Some(mut produced) = run(&mut stage, &job, frames_dropped) else {
                        continue;
                    };
                    if let Ok(output) = &mut produced {
                        let skipped = mine.dropped.load(Ordering::Relaxed);
                        match output {
                            Output::Tactile { record, .. } => record.jobs_skipped = skipped,
                            Output::Stereo { record, .. } => record.jobs_skipped = skipped,
                        }
                    }
                    if tx.send(produced).is_err() {
                        break;
                    }
                }
                stage
            })
            .expect("spawning a stage thread");
        Self { slot, thread }
    }

    /// Closes the slot and waits for the thread; a stage that panicked is an error.
    fn finish(self, name: &'static str) -> Result<S, PipelineError> {
        self.slot.close();
        self.thread
            .join()
            .map_err(|_| PipelineError::Panicked(name))
    }
}

/// The stages on their threads (see the module documentation).
pub struct Workers {
    tactile: Option<Worker<TactileStage>>,
    stereo: Option<Worker<StereoStage>>,
    outputs: Receiver<Produced>,
}

impl std::fmt::Debug for Workers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Workers")
            .field("tactile", &self.tactile.is_some())
            .field("stereo", &self.stereo.is_some())
            .finish()
    }
}

impl Workers {
    /// Starts a thread for each stage given; `clock` stamps when depth is ready.
    pub fn start(
        tactile: Option<TactileStage>,
        stereo: Option<StereoStage>,
        clock: Arc<dyn HostClock>,
    ) -> Self {
        let (tx, outputs) = std::sync::mpsc::channel();
        let now = move |clock: &Arc<dyn HostClock>| Some(clock.now_us() as f64);
        let c = Arc::clone(&clock);
        let tactile = tactile.map(|stage| {
            Worker::spawn("tactile", stage, tx.clone(), move |stage, job, dropped| {
                let Job::Tactile(pair) = job else { return None };
                Some(
                    stage
                        .process(pair, || now(&c), dropped)
                        .map(|(reconstruction, record)| Output::Tactile {
                            reconstruction,
                            record,
                        })
                        .map_err(PipelineError::from),
                )
            })
        });
        let stereo = stereo.map(|stage| {
            Worker::spawn("stereo", stage, tx, move |stage, job, dropped| {
                let Job::Stereo(pair) = job else { return None };
                Some(
                    stage
                        .process(pair, || now(&clock), dropped)
                        .map(|(frame, record)| Output::Stereo {
                            frame: Box::new(frame),
                            record,
                        })
                        .map_err(PipelineError::from),
                )
            })
        });
        Self {
            tactile,
            stereo,
            outputs,
        }
    }

    /// Hands `job` to its stage (dropped if that stage is off).
    pub fn submit(&self, job: Job, frames_dropped: u64) {
        match (&job, &self.tactile, &self.stereo) {
            (Job::Tactile(_), Some(w), _) => w.slot.put(job, frames_dropped),
            (Job::Stereo(_), _, Some(w)) => w.slot.put(job, frames_dropped),
            _ => {}
        }
    }

    /// Outputs ready now.
    pub fn ready(&self) -> Vec<Produced> {
        self.outputs.try_iter().collect()
    }

    /// Lets each stage finish the job it holds, stops the threads, and returns the
    /// outputs still to hand on with the stages.
    pub fn finish(self) -> (Vec<Produced>, Option<TactileStage>, Option<StereoStage>) {
        let tactile = self.tactile.map(|w| w.finish("tactile"));
        let stereo = self.stereo.map(|w| w.finish("stereo"));
        let mut rest: Vec<Produced> = self.outputs.try_iter().collect();
        let tactile = stage_or_error(tactile, &mut rest);
        let stereo = stage_or_error(stereo, &mut rest);
        (rest, tactile, stereo)
    }
}

/// A finished stage, or its failure added to the outputs still to hand on.
fn stage_or_error<S>(
    stage: Option<Result<S, PipelineError>>,
    rest: &mut Vec<Produced>,
) -> Option<S> {
    match stage? {
        Ok(s) => Some(s),
        Err(e) => {
            rest.push(Err(e));
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::Frame;
    use crate::frames::capture::{GradientPair, LabelledFrame};
    use crate::matcher::{FrameStamp, Label};

    fn job(sequence: u64) -> Job {
        let frame = LabelledFrame {
            frame: Frame {
                stamp: FrameStamp {
                    sequence,
                    timestamp_us: 0.0,
                    exposure_us: 1.0,
                },
                image: image::RgbImage::new(1, 1),
            },
            label: Label::Unresolved,
        };
        Job::Tactile(GradientPair {
            dx: frame.clone(),
            dy: frame,
            dark: None,
        })
    }

    fn sequence(j: &Job) -> u64 {
        match j {
            Job::Tactile(p) => p.dx.frame.stamp.sequence,
            Job::Stereo(p) => p.left.frame.stamp.sequence,
        }
    }

    #[test]
    fn the_newest_job_wins_and_a_closed_slot_still_hands_out_what_it_holds() {
        let slot = Slot::default();
        slot.put(job(1), 0);
        slot.put(job(2), 0);
        slot.put(job(3), 5);
        assert_eq!(slot.dropped.load(Ordering::Relaxed), 2, "two replaced");
        let (j, dropped) = slot.take().expect("a job");
        assert_eq!((sequence(&j), dropped), (3, 5));
        slot.put(job(4), 0);
        slot.close();
        assert_eq!(
            slot.take().map(|(j, _)| sequence(&j)),
            Some(4),
            "held before closing"
        );
        assert!(slot.take().is_none(), "closed and empty");
    }

    #[test]
    fn a_waiting_worker_wakes_for_a_job_and_for_closing() {
        let slot = Arc::new(Slot::default());
        let s = Arc::clone(&slot);
        let taker = std::thread::spawn(move || {
            let mut got = Vec::new();
            while let Some((j, _)) = s.take() {
                got.push(sequence(&j));
            }
            got
        });
        std::thread::sleep(std::time::Duration::from_millis(20));
        slot.put(job(7), 0);
        std::thread::sleep(std::time::Duration::from_millis(20));
        slot.close();
        assert_eq!(taker.join().unwrap(), vec![7]);
    }
}
