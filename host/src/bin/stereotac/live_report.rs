//! What `run` and `process` print as depth comes out, and their closing figures.

use anyhow::Result;
use stereotac::live::{Output, Pipeline, StereoRecord, TactileRecord};
use stereotac::tactile::ambient::AmbientSource;
use stereotac::tactile::integrable;
use stereotac::tactile::reconstruct::NO_SKIN_AT_REST;
use stereotac::timing::quantiles;

use crate::console::emit;

/// Said once, at the first pair whose LEDs-off frame was not used.
const DARK_REFUSED: &str = "a LEDs-off frame is brighter than the lit frames after it in \
    more than 5 % of its values, so it cannot be their ambient light: the calibration's \
    ambient light is removed instead (\"ambient\": \"calibration-dark-refused\"). Is \
    the exposure or gain the same in every phase, and is the room's light steady?";

/// The printed report (see the module documentation).
#[derive(Debug)]
pub struct Report {
    jsonl: bool,
    tactile_latency: Vec<f64>,
    stereo_latency: Vec<f64>,
    contacts: u64,
    /// Jobs each stage skipped for a newer one: (tactile, stereo).
    skipped: (u64, u64),
    /// Pairs whose LEDs-off frame was brighter than their lit frames (not used).
    dark_refused: SaidOnce,
    /// Stereo frames with warnings (almost nothing matched, a scene outside the range).
    stereo_warned: SaidOnce,
    /// Tactile pairs whose slopes were not one surface's.
    no_surface: SaidOnce,
    /// Tactile pairs with a contact and no skin at rest around it.
    no_zero: SaidOnce,
}

/// A warning said when it first happens, then counted for the closing figures.
#[derive(Debug, Default)]
struct SaidOnce(u64);

impl SaidOnce {
    /// Counts one more; the first time, says `warning()` on stderr.
    fn count(&mut self, warning: impl FnOnce() -> String) {
        if self.0 == 0 {
            eprintln!("warning: {}", warning());
        }
        self.0 += 1;
    }

    /// At the close, when any was counted: "warning: N pair's (pairs') `what`".
    fn close_pairs(&self, what: &str) {
        let n = self.0;
        if n > 0 {
            let pairs = if n == 1 { "pair's" } else { "pairs'" };
            eprintln!("warning: {n} {pairs} {what}");
        }
    }
}

impl Report {
    /// `jsonl`: one JSON line per tactile pair (nothing else on stdout).
    pub fn new(jsonl: bool) -> Self {
        Self {
            jsonl,
            tactile_latency: Vec::new(),
            stereo_latency: Vec::new(),
            contacts: 0,
            skipped: (0, 0),
            dark_refused: SaidOnce::default(),
            stereo_warned: SaidOnce::default(),
            no_surface: SaidOnce::default(),
            no_zero: SaidOnce::default(),
        }
    }

    /// Prints one output; `false` once stdout is gone.
    pub fn print(&mut self, output: &Output) -> Result<bool> {
        let open = match output {
            Output::Tactile { record, .. } => {
                self.tactile_latency.extend(record.latency_ms);
                self.contacts += u64::from(record.contact);
                self.skipped.0 = self.skipped.0.max(record.jobs_skipped);
                if record.ambient == AmbientSource::CalibrationDarkRefused {
                    self.dark_refused.count(|| DARK_REFUSED.to_string());
                }
                if let Some(note) = integrable::surface_warning(record.unexplained_share) {
                    self.no_surface.count(|| {
                        format!(
                            "tactile pair {}: {note} (said once; the closing figures count such \
                             pairs, each record holds its \"unexplained_share\")",
                            record.sequence
                        )
                    });
                }
                if record.no_skin_at_rest {
                    self.no_zero.count(|| {
                        format!(
                            "tactile pair {}: {NO_SKIN_AT_REST} (said once; the closing figures \
                             count such pairs, each record holds its \"no_skin_at_rest\")",
                            record.sequence
                        )
                    });
                }
                if self.jsonl {
                    emit(format_args!("{}", serde_json::to_string(record)?))
                } else {
                    emit(format_args!("{}", tactile_line(record)))
                }
            }
            Output::Stereo { record, .. } => {
                self.stereo_latency.extend(record.latency_ms);
                self.skipped.1 = self.skipped.1.max(record.jobs_skipped);
                if let Some(first) = record.warnings.first() {
                    self.stereo_warned.count(|| {
                        format!(
                            "stereo frame {}: {first} (said once; the closing figures count the \
                             frames with warnings, each record holds its own)",
                            record.sequence
                        )
                    });
                }
                self.jsonl || emit(format_args!("{}", stereo_line(record)))
            }
        };
        Ok(open)
    }

    /// The closing figures, on stderr.
    pub fn finish(self, pipeline: &Pipeline) {
        let fmt = |v: Vec<f64>| {
            quantiles(v, [0.5, 0.99]).map_or(String::new(), |[p50, p99]| {
                format!("; latency p50 {p50:.2} ms, p99 {p99:.2} ms")
            })
        };
        if let Some(t) = &pipeline.tactile {
            eprintln!(
                "tactile: {} dx/dy pairs reconstructed, {} with contact, {} refused, {} skipped while busy{}",
                t.pairs(),
                self.contacts,
                t.refused(),
                self.skipped.0,
                fmt(self.tactile_latency)
            );
        }
        self.no_surface
            .close_pairs("slopes were not those of one surface (their depth is not reliable)");
        self.no_zero
            .close_pairs("contact had no skin at rest around it (its depth has no zero)");
        self.dark_refused.close_pairs(
            "LEDs-off frames were brighter than their lit frames and were not used (the \
             calibration's ambient light was removed instead)",
        );
        if let Some(s) = &pipeline.stereo {
            eprintln!(
                "stereo: {} frame pairs, {} with warnings, {} skipped while busy{}",
                s.frames(),
                self.stereo_warned.0,
                self.skipped.1,
                fmt(self.stereo_latency)
            );
            if s.frames() == 0 && self.skipped.1 == 0 {
                eprintln!(
                    "warning: no stereo frame pair was made: stereo depth needs LEDs-off \
                     frames of two cameras taken at one phase (vision or interleaved mode, \
                     two cameras, a run long enough for one such phase)"
                );
            }
        }
    }
}

fn latency(ms: Option<f64>) -> String {
    ms.map_or(String::new(), |l| format!(", latency {l:.1} ms"))
}

fn tactile_line(r: &TactileRecord) -> String {
    if r.contact {
        format!(
            "pair {:>4} (phase {:>5}): contact {:7.2} mm², max depth {:.3} mm, volume {:.2} mm³; {:.2} ms{}",
            r.sequence,
            r.phase,
            r.area_mm2,
            r.max_depth_mm,
            r.volume_mm3,
            r.stage_ms.total_ms,
            latency(r.latency_ms)
        )
    } else {
        format!(
            "pair {:>4} (phase {:>5}): no contact; {:.2} ms{}",
            r.sequence,
            r.phase,
            r.stage_ms.total_ms,
            latency(r.latency_ms)
        )
    }
}

fn stereo_line(r: &StereoRecord) -> String {
    format!(
        "stereo {:>4} (phase {:>5}): {:.0}% filled, median depth {}; {:.2} ms{}",
        r.sequence,
        r.phase,
        r.fill * 100.0,
        r.median_depth_mm
            .map_or("-".into(), |d| format!("{d:.1} mm")),
        r.stage_ms.total_ms,
        latency(r.latency_ms)
    )
}
