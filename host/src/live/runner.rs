//! The live loop of `run` and `bench live`: the session polls the sensor and cameras,
//! each labelled frame is routed, the stage it completes runs at once, its output is
//! recorded and handed to the caller; until the deadline, the stop flag (Ctrl-C and
//! signals), the caller, or a failed recorder says stop. Then the LEDs are stopped and
//! every frame still pending is labelled and processed, so stopping loses nothing.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use stereotac_protocol::Request;

use super::session::Session;
use super::{Output, Pipeline, PipelineError};
use crate::device::{Sensor, SensorError};
use crate::frames::capture::{CaptureError, LabelledFrame};
use crate::recording::writer::Recorder;

/// How long one poll of the sensor waits for events: frames are taken from the cameras
/// between polls, so this bounds how long a finished exposure waits to be labelled.
pub const POLL: Duration = Duration::from_millis(2);

/// Why the loop ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Stopped {
    /// The deadline passed.
    Deadline,
    /// The stop flag was raised.
    Flag,
    /// The caller said stop (e.g. stdout closed).
    Caller,
    /// The recorder failed (its error).
    Recorder(String),
}

/// When to stop.
#[derive(Debug, Clone, Copy)]
pub struct Until<'a> {
    /// Raised by Ctrl-C or a signal.
    pub flag: &'a AtomicBool,
    /// Host time to stop at, µs.
    pub end_us: Option<u64>,
}

/// What the caller sees: each frame before it is routed (to check it), each output
/// (`false`: stop), each warning.
pub trait Hooks {
    /// The caller's error.
    type Error: From<CaptureError> + From<PipelineError> + From<SensorError>;
    /// A frame from camera `camera`, before routing.
    fn frame(&mut self, camera: usize, frame: &LabelledFrame) -> Result<(), Self::Error>;
    /// An output, after it was recorded; `false` stops the loop.
    fn output(&mut self, output: &Output) -> Result<bool, Self::Error>;
    /// A warning (sensor fault, reconnect), already recorded.
    fn warning(&mut self, message: String);
}

/// Runs the loop (see the module documentation); the sequence must be running.
pub fn run<H: Hooks>(
    session: &mut Session,
    sensor: &mut Sensor,
    recorder: &Recorder,
    pipeline: &mut Pipeline,
    until: Until<'_>,
    hooks: &mut H,
) -> Result<Stopped, H::Error> {
    let clock = std::sync::Arc::clone(sensor.clock());
    let now = || Some(clock.now_us() as f64);
    let stopped = loop {
        if until.flag.load(Ordering::SeqCst) {
            break Stopped::Flag;
        }
        if until.end_us.is_some_and(|e| sensor.clock().now_us() >= e) {
            break Stopped::Deadline;
        }
        let keep = session.step(sensor, recorder, POLL, |camera, frame, dropped| {
            handle(hooks, pipeline, recorder, &now, camera, frame, dropped)
        })?;
        for w in session.take_warnings() {
            hooks.warning(w);
        }
        if !keep {
            break Stopped::Caller;
        }
        if let Some(e) = recorder.failure() {
            break Stopped::Recorder(e);
        }
    };
    let stop = sensor.request(Request::Stop);
    if stopped != Stopped::Caller {
        session.finish(recorder, |camera, frame, dropped| {
            handle(hooks, pipeline, recorder, &now, camera, frame, dropped)
        })?;
    }
    stop?;
    Ok(stopped)
}

/// One frame: check, route, run, record, hand on.
fn handle<H: Hooks>(
    hooks: &mut H,
    pipeline: &mut Pipeline,
    recorder: &Recorder,
    now: &impl Fn() -> Option<f64>,
    camera: usize,
    frame: LabelledFrame,
    dropped: u64,
) -> Result<bool, H::Error> {
    hooks.frame(camera, &frame)?;
    let Some(job) = pipeline.route(camera, frame) else {
        return Ok(true);
    };
    let Some(output) = pipeline.run(&job, now, dropped)? else {
        return Ok(true);
    };
    let keep = hooks.output(&output)?;
    recorder.send(output.into_item());
    Ok(keep)
}
