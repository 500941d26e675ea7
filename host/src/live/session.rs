//! A capture session: one sensor, its cameras and a [`Recorder`]. Each
//! [`Session::step`] polls the sensor (keeping the clock sync fresh), records its
//! phases, clock-sync states and faults, takes every camera's newly labelled frames,
//! records them, and hands each to the caller in a fixed order (camera 0's, then camera
//! 1's, ...), which is the order the recording holds them in. `run` reconstructs what it
//! is handed; `record` only records.

use std::time::Duration;

use crate::device::{Sensor, SensorEvent};
use crate::frames::FrameSource;
use crate::frames::capture::{Capture, CaptureError, LabelledFrame};
use crate::matcher::{MatchStats, MatcherConfig};
use crate::recording::messages::{ClockInfo, FrameInfo, PhaseInfo};
use crate::recording::writer::{Item, Recorder};

/// The session (see the module documentation).
pub struct Session {
    captures: Vec<Capture<Box<dyn FrameSource>>>,
    warnings: Vec<String>,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("cameras", &self.captures.len())
            .finish_non_exhaustive()
    }
}

impl Session {
    /// A session over `sources`, labelled with `config` (each source's own stamp
    /// reference is used).
    pub fn new(sources: Vec<Box<dyn FrameSource>>, config: MatcherConfig) -> Self {
        Self {
            captures: sources
                .into_iter()
                .map(|s| Capture::new(s, config))
                .collect(),
            warnings: Vec::new(),
        }
    }

    /// The cameras' captures.
    pub fn captures(&self) -> &[Capture<Box<dyn FrameSource>>] {
        &self.captures
    }

    /// Frames lost so far, all cameras.
    pub fn dropped_frames(&self) -> u64 {
        self.captures.iter().map(|c| c.stats().dropped_frames).sum()
    }

    /// Each camera's matcher counters.
    pub fn stats(&self) -> Vec<MatchStats> {
        self.captures.iter().map(Capture::stats).collect()
    }

    /// Warnings since the last call (sensor faults, reconnects): also recorded.
    pub fn take_warnings(&mut self) -> Vec<String> {
        std::mem::take(&mut self.warnings)
    }

    /// One step: poll the sensor for at most `wait`, record, hand on each labelled
    /// frame as `each(camera, frame, frames dropped so far)`.
    pub fn step<E: From<CaptureError>>(
        &mut self,
        sensor: &mut Sensor,
        recorder: &Recorder,
        wait: Duration,
        each: impl FnMut(usize, LabelledFrame, u64) -> Result<(), E>,
    ) -> Result<(), E> {
        let events = sensor.poll(wait).map_err(CaptureError::from)?;
        for event in &events {
            let now = sensor.clock().now_us() as f64;
            match event {
                SensorEvent::Phase(p) => {
                    recorder.send(Item::Phase(PhaseInfo::from(p)));
                }
                SensorEvent::Heartbeat(_) => {
                    recorder.send(Item::Clock(ClockInfo::new(now, sensor.clock_fit())));
                }
                SensorEvent::Fault(f, at) => {
                    self.warn(
                        recorder,
                        *at,
                        format!("sensor fault {:?} at host {at:.0} µs", f.kind),
                    );
                }
                SensorEvent::Reconnected { attempts } => {
                    self.warn(
                        recorder,
                        now,
                        format!("sensor reconnected after {attempts} attempts"),
                    );
                }
                SensorEvent::Probe(_) => {}
            }
        }
        // Every camera's frames are taken and handed on before a failed camera's error
        // is returned: frames the others delivered are never lost to it.
        let mut labelled = Vec::with_capacity(self.captures.len());
        let mut failed = None;
        for (i, capture) in self.captures.iter_mut().enumerate() {
            match capture.absorb(&events) {
                Ok(frames) => labelled.push(frames),
                Err(e) => {
                    labelled.push(Vec::new());
                    failed.get_or_insert(CaptureError::Frames(crate::frames::FrameError::Camera {
                        device: format!("camera {i}"),
                        message: e.to_string(),
                    }));
                }
            }
        }
        self.hand_on(labelled, recorder, each)?;
        match failed {
            Some(e) => Err(e.into()),
            None => Ok(()),
        }
    }

    /// The end: label every frame still pending and hand it on.
    pub fn finish<E>(
        &mut self,
        recorder: &Recorder,
        each: impl FnMut(usize, LabelledFrame, u64) -> Result<(), E>,
    ) -> Result<(), E> {
        let labelled = self.captures.iter_mut().map(Capture::finish).collect();
        self.hand_on(labelled, recorder, each)
    }

    fn hand_on<E>(
        &mut self,
        labelled: Vec<Vec<LabelledFrame>>,
        recorder: &Recorder,
        mut each: impl FnMut(usize, LabelledFrame, u64) -> Result<(), E>,
    ) -> Result<(), E> {
        let dropped = self.dropped_frames();
        for (camera, frames) in labelled.into_iter().enumerate() {
            let stamp_ref = self.captures[camera].stamp_ref();
            for frame in frames {
                if recorder.is_active() {
                    recorder.send(Item::Frame {
                        camera,
                        info: FrameInfo::new(frame.frame.stamp, stamp_ref, frame.label),
                        image: frame.frame.image.clone(),
                    });
                }
                each(camera, frame, dropped + recorder.dropped().frames)?;
            }
        }
        Ok(())
    }

    fn warn(&mut self, recorder: &Recorder, at_us: f64, message: String) {
        recorder.send(Item::Warning {
            at_us,
            message: message.clone(),
        });
        self.warnings.push(message);
    }
}
