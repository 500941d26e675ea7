//! Live capture: a sensor's phase events and a camera's frames in, labelled frames out.
//!
//! Each [`Capture::step`] polls the sensor (which also keeps the clock sync fresh),
//! feeds its phases to the [`FrameMatcher`], takes what frames the camera has, and
//! returns every frame whose light is now known, with its image. [`Capture::finish`]
//! labels whatever is still pending, so stopping never loses a captured frame.

use std::collections::VecDeque;
use std::time::Duration;

use super::{Frame, FrameError, FrameSource};
use crate::device::{Sensor, SensorError, SensorEvent};
use stereotac_protocol::Phase;

use crate::clock::HostMicros;
use crate::matcher::{FrameMatcher, Label, MatchStats, MatchedFrame, MatcherConfig};

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
    /// clock reaches `until_us` first. A dy without its dx, or a frame the matcher could
    /// not label, starts the search over.
    pub fn next_gradient_pair(
        &mut self,
        sensor: &mut Sensor,
        since_us: HostMicros,
        until_us: HostMicros,
    ) -> Result<Option<GradientPair>, CaptureError> {
        let mut dx: Option<LabelledFrame> = None;
        while sensor.clock().now_us() < until_us {
            for frame in self.step(sensor, PAIR_POLL)?.frames {
                if frame.frame.stamp.timestamp_us < since_us as f64 {
                    continue; // exposed before the caller's moment
                }
                let phase = match frame.label {
                    Label::Phase { phase, .. } => Some(phase),
                    _ => None,
                };
                match (phase, dx.take()) {
                    (Some(Phase::Dx), _) => dx = Some(frame),
                    (Some(Phase::Dy), Some(first)) => {
                        return Ok(Some(GradientPair {
                            dx: first,
                            dy: frame,
                        }));
                    }
                    _ => {}
                }
            }
        }
        Ok(None)
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
