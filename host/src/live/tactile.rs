//! The tactile stage: dx/dy pairs as the capture labels them in, depth and one
//! [`TactileRecord`] per pair out, on the host clock. `stereotac run --jsonl` prints
//! the records for a control loop.

use crate::frames::capture::GradientPair;
use crate::matcher::{Label, StampRef};
pub use crate::recording::messages::TactileRecord;
use crate::tactile::ambient::PhaseFrames;
use crate::tactile::output::Summary;
use crate::tactile::reconstruct::{ReconstructError, Reconstruction, Reconstructor};

/// A reconstruction and when it was ready (none offline).
type Timed = Result<(Reconstruction, Option<f64>), ReconstructError>;

/// The images of `pair`.
fn frames(pair: &GradientPair) -> PhaseFrames<'_> {
    PhaseFrames {
        dx: &pair.dx.frame.image,
        dy: &pair.dy.frame.image,
        dark: pair.dark.as_ref().map(|d| &d.frame.image),
    }
}

/// The tactile stage (see the module documentation).
pub struct TactileStage {
    reconstructor: Reconstructor,
    /// More reconstructors for [`Self::process_batch`], made as needed.
    workers: Vec<Reconstructor>,
    px_per_mm: f64,
    stamp_ref: StampRef,
    pairs: u64,
    refused: u64,
}

impl std::fmt::Debug for TactileStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TactileStage")
            .field("px_per_mm", &self.px_per_mm)
            .field("pairs", &self.pairs)
            .finish_non_exhaustive()
    }
}

impl TactileStage {
    /// A stage reconstructing with `reconstructor` (its model at `px_per_mm`), for a
    /// camera whose timestamps mark `stamp_ref`.
    pub fn new(reconstructor: Reconstructor, px_per_mm: f64, stamp_ref: StampRef) -> Self {
        Self {
            reconstructor,
            workers: Vec::new(),
            px_per_mm,
            stamp_ref,
            pairs: 0,
            refused: 0,
        }
    }

    /// Pairs reconstructed so far.
    pub fn pairs(&self) -> u64 {
        self.pairs
    }

    /// Pairs refused on their own so far (depth that cannot be right: see
    /// [`ReconstructError::refuses_this_pair_only`]).
    pub fn refused(&self) -> u64 {
        self.refused
    }

    fn count_refused<T>(&mut self, r: &Result<T, ReconstructError>) {
        if r.as_ref()
            .is_err_and(ReconstructError::refuses_this_pair_only)
        {
            self.refused += 1;
        }
    }

    /// Reconstructs `pair`; `now_us` reads the host clock when the depth is ready (none
    /// offline), and `frames_dropped` is the run's count so far.
    pub fn process(
        &mut self,
        pair: &GradientPair,
        now_us: impl FnOnce() -> Option<f64>,
        frames_dropped: u64,
    ) -> Result<(Reconstruction, TactileRecord), ReconstructError> {
        let r = self.reconstructor.reconstruct_frames(frames(pair));
        self.count_refused(&r);
        let r = r?;
        let record = self.record(pair, &r, now_us(), frames_dropped);
        Ok((r, record))
    }

    /// Reconstructs `pairs` in parallel (one reconstructor per rayon thread), with the
    /// results and records [`Self::process`] would give one by one, in order.
    pub fn process_batch(
        &mut self,
        pairs: &[&GradientPair],
        now_us: impl Fn() -> Option<f64> + Sync,
        frames_dropped: u64,
    ) -> Vec<Result<(Reconstruction, TactileRecord), ReconstructError>> {
        use rayon::prelude::*;
        let threads = rayon::current_num_threads().clamp(1, pairs.len().max(1));
        while self.workers.len() < threads {
            self.workers.push(self.reconstructor.fresh());
        }
        let chunk = pairs.len().div_ceil(threads).max(1);
        let done: Vec<Vec<Timed>> = self.workers[..threads]
            .par_iter_mut()
            .zip(pairs.par_chunks(chunk))
            .map(|(rec, chunk)| {
                chunk
                    .iter()
                    .map(|p| {
                        let r = rec.reconstruct_frames(frames(p))?;
                        Ok((r, now_us()))
                    })
                    .collect()
            })
            .collect();
        done.into_iter()
            .flatten()
            .zip(pairs)
            .map(|(r, pair)| {
                self.count_refused(&r);
                r.map(|(r, ready_us)| {
                    let record = self.record(pair, &r, ready_us, frames_dropped);
                    (r, record)
                })
            })
            .collect()
    }

    /// The record of `pair` reconstructed as `r`, ready at `ready_us`.
    fn record(
        &mut self,
        pair: &GradientPair,
        r: &Reconstruction,
        ready_us: Option<f64>,
        frames_dropped: u64,
    ) -> TactileRecord {
        let summary = Summary::of(r, self.px_per_mm);
        let end = |f: &crate::frames::capture::LabelledFrame| {
            f.frame.stamp.exposure_end_us(self.stamp_ref)
        };
        let (dx_end, dy_end) = (end(&pair.dx), end(&pair.dy));
        let record = TactileRecord {
            sequence: self.pairs,
            phase: match pair.dx.label {
                Label::Phase { index, .. } => index,
                _ => 0,
            },
            exposure_end_us: [dx_end, dy_end],
            contact: !summary.no_contact,
            unlit: r.unlit(),
            ambient: r.ambient,
            area_mm2: summary.contact_area_mm2,
            centroid_mm: summary.centroid_mm,
            max_depth_mm: summary.max_depth_mm,
            volume_mm3: summary.volume_mm3,
            past_reach_pixels: summary.past_reach_pixels as u64,
            unexplained_share: summary.unexplained_share,
            no_skin_at_rest: r.no_skin_at_rest,
            stage_ms: summary.timings,
            latency_ms: ready_us.map(|t| (t - dy_end) / 1000.0),
            frames_dropped,
            jobs_skipped: 0,
        };
        self.pairs += 1;
        record
    }
}
