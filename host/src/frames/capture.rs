//! Live capture: a sensor's phase events and a camera's frames in, labelled frames out.
//!
//! Each [`Capture::step`] polls the sensor (which also keeps the clock sync fresh),
//! feeds its phases to the [`FrameMatcher`], takes what frames the camera has, and
//! returns every frame whose light is now known, with its image. [`Capture::finish`]
//! labels whatever is still pending, so stopping never loses a captured frame.

use std::collections::VecDeque;
use std::time::Duration;

use stereotac_protocol::Phase;

use super::{Frame, FrameError, FrameSource};
use crate::clock::HostMicros;
use crate::device::{Sensor, SensorError, SensorEvent};
use crate::matcher::{FrameMatcher, Label, MatchStats, MatchedFrame, MatcherConfig, StampRef};

/// Why a capture step failed.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// The sensor failed.
    #[error(transparent)]
    Sensor(#[from] SensorError),
    /// The camera failed.
    #[error(transparent)]
    Frames(#[from] FrameError),
}

/// A frame with its label.
#[derive(Debug, Clone)]
pub struct LabelledFrame {
    /// The frame.
    pub frame: Frame,
    /// Which phase lit it.
    pub label: Label,
}

/// What one step produced.
#[derive(Debug, Default)]
pub struct Step {
    /// Sensor events (phases, heartbeats, faults, reconnects).
    pub events: Vec<SensorEvent>,
    /// Frames labelled in this step.
    pub frames: Vec<LabelledFrame>,
}

/// A dx frame and the dy frame labelled right after it: one photometric-stereo input.
#[derive(Debug, Clone)]
pub struct GradientPair {
    /// The frame lit by strips 1 and 3.
    pub dx: LabelledFrame,
    /// The frame lit by strips 2 and 4.
    pub dy: LabelledFrame,
    /// The same camera's LEDs-off frame just before the dx frame (interleaved mode;
    /// attached by the live router), the ambient light for the tactile stage.
    pub dark: Option<LabelledFrame>,
}

/// Pairs labelled frames, in the order the matcher decides them, into dx/dy pairs: the
/// last dx frame of a phase and the first dy frame of the next phase. Frames exposed
/// across the LED change between them (free-running cameras take some) are passed
/// over; anything else between them (a dark or all-lit frame, a frame whose light is
/// unknown, a dy of another phase after a dropped frame) starts over.
#[derive(Debug, Default)]
pub struct GradientPairer {
    /// The last dx frame and its phase index.
    dx: Option<(u32, LabelledFrame)>,
}

impl GradientPairer {
    /// Takes the next labelled frame; returns a pair when it completes one.
    pub fn push(&mut self, frame: LabelledFrame) -> Option<GradientPair> {
        let (phase, index) = match frame.label {
            Label::Phase { phase, index, .. } => (phase, index),
            // The light changed during the exposure: the frame says nothing, and what
            // came before and comes after is still known.
            Label::Straddles => return None,
            Label::EventMissing | Label::NoTrigger | Label::Unresolved => {
                self.dx = None;
                return None;
            }
        };
        match (phase, self.dx.take()) {
            (Phase::Dx, _) => {
                self.dx = Some((index, frame));
                None
            }
            (Phase::Dy, Some((dx_index, dx))) if dx_index.wrapping_add(1) == index => {
                Some(GradientPair {
                    dx,
                    dy: frame,
                    dark: None,
                })
            }
            _ => None,
        }
    }
}

/// How often [`Capture::next_gradient_pair`] polls the sensor.
const PAIR_POLL: Duration = Duration::from_millis(20);

/// A live capture (see the module documentation).
#[derive(Debug)]
pub struct Capture<S> {
    source: S,
    matcher: FrameMatcher,
    waiting: VecDeque<Frame>,
}

impl<S: FrameSource> Capture<S> {
    /// Capture from `source`, labelling with `config`.
    pub fn new(source: S, mut config: MatcherConfig) -> Self {
        config.stamp = source.stamp_ref();
        Self {
            source,
            matcher: FrameMatcher::new(config),
            waiting: VecDeque::new(),
        }
    }

    /// The matcher's counters.
    pub fn stats(&self) -> MatchStats {
        self.matcher.stats()
    }

    /// The frame source.
    pub fn source(&self) -> &S {
        &self.source
    }

    /// The frame source, to change its settings while capturing.
    pub fn source_mut(&mut self) -> &mut S {
        &mut self.source
    }

    /// Poll the sensor for at most `wait`, take the camera's frames, label what can be.
    pub fn step(&mut self, sensor: &mut Sensor, wait: Duration) -> Result<Step, CaptureError> {
        let events = sensor.poll(wait)?;
        let frames = self.absorb(&events)?;
        Ok(Step { events, frames })
    }

    /// Feed sensor events polled elsewhere (one sensor, several cameras: poll once,
    /// then absorb the same events into each camera's capture), take the camera's
    /// frames, label what can be.
    pub fn absorb(&mut self, events: &[SensorEvent]) -> Result<Vec<LabelledFrame>, FrameError> {
        for event in events {
            if let SensorEvent::Phase(p) = event {
                self.matcher.add_phase(*p);
            }
        }
        while let Some(frame) = self.source.next_frame(Duration::ZERO)? {
            self.matcher.add_frame(frame.stamp);
            self.waiting.push_back(frame);
        }
        let decided = self.matcher.ready();
        Ok(self.attach(decided))
    }

    /// Capture until the matcher has labelled a dx frame followed directly by a dy
    /// frame, both exposed at or after `since_us` (host clock); `None` when the host
    /// clock reaches `until_us` first. See [`GradientPairer`] for what pairs.
    pub fn next_gradient_pair(
        &mut self,
        sensor: &mut Sensor,
        since_us: HostMicros,
        until_us: HostMicros,
    ) -> Result<Option<GradientPair>, CaptureError> {
        let mut pairer = GradientPairer::default();
        while sensor.clock().now_us() < until_us {
            for frame in self.step(sensor, PAIR_POLL)?.frames {
                if frame.frame.stamp.timestamp_us < since_us as f64 {
                    continue; // exposed before the caller's moment
                }
                if let Some(pair) = pairer.push(frame) {
                    return Ok(Some(pair));
                }
            }
        }
        Ok(None)
    }

    /// What the source's timestamps mark.
    pub fn stamp_ref(&self) -> StampRef {
        self.source.stamp_ref()
    }

    /// Label every frame still pending (end of capture).
    pub fn finish(&mut self) -> Vec<LabelledFrame> {
        let decided = self.matcher.finish();
        self.attach(decided)
    }

    /// Pair decided frames with their images (decisions come in arrival order).
    fn attach(&mut self, decided: Vec<MatchedFrame>) -> Vec<LabelledFrame> {
        decided
            .into_iter()
            .filter_map(|m| {
                let frame = self.waiting.pop_front()?;
                debug_assert_eq!(frame.stamp.sequence, m.frame.sequence);
                Some(LabelledFrame {
                    frame,
                    label: m.label,
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matcher::FrameStamp;

    fn frame(label: Label) -> LabelledFrame {
        LabelledFrame {
            frame: Frame {
                stamp: FrameStamp {
                    sequence: 0,
                    timestamp_us: 0.0,
                    exposure_us: 1.0,
                },
                image: image::RgbImage::new(1, 1),
            },
            label,
        }
    }

    fn lit(phase: Phase, index: u32) -> LabelledFrame {
        frame(Label::Phase {
            index,
            phase,
            trigger: Some(index),
        })
    }

    #[test]
    fn the_last_dx_and_the_next_phases_first_dy_pair_and_unknown_light_between_starts_over() {
        let mut p = GradientPairer::default();
        assert!(p.push(lit(Phase::Dy, 0)).is_none(), "a dy without its dx");
        assert!(p.push(lit(Phase::Dx, 1)).is_none());
        let pair = p.push(lit(Phase::Dy, 2)).expect("dx 1 then dy 2");
        assert_eq!(phase_of(&pair.dx), (Phase::Dx, 1));
        assert_eq!(phase_of(&pair.dy), (Phase::Dy, 2));
        // Interleaved: dark between pairs; a dropped dy leaves a dx followed by dy 2 later.
        assert!(p.push(lit(Phase::Dark, 3)).is_none());
        assert!(p.push(lit(Phase::Dx, 4)).is_none());
        assert!(p.push(lit(Phase::Dy, 8)).is_none(), "not the next phase");
        // Free-running: several dx frames, one across the change, then dy frames: the
        // last dx and the first dy pair.
        for _ in 0..3 {
            assert!(p.push(lit(Phase::Dx, 10)).is_none());
        }
        assert!(p.push(frame(Label::Straddles)).is_none());
        let pair = p
            .push(lit(Phase::Dy, 11))
            .expect("a straddling frame is passed over");
        assert_eq!(phase_of(&pair.dy), (Phase::Dy, 11));
        assert!(
            p.push(lit(Phase::Dy, 11)).is_none(),
            "the second dy of the phase"
        );
        // Unknown light between them starts over.
        assert!(p.push(lit(Phase::Dx, 12)).is_none());
        assert!(p.push(frame(Label::EventMissing)).is_none());
        assert!(p.push(lit(Phase::Dy, 13)).is_none(), "lost event between");
    }

    fn phase_of(f: &LabelledFrame) -> (Phase, u32) {
        match f.label {
            Label::Phase { phase, index, .. } => (phase, index),
            other => panic!("{other:?}"),
        }
    }
}
