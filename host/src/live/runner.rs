//! The live loop of `run` and `bench live`: the session polls the sensor and cameras,
//! each labelled frame is routed, the job it completes goes to its stage's thread, and
//! outputs are recorded and handed to the caller as they come; until the deadline, the
//! stop flag (Ctrl-C and signals), the caller, or a failed recorder says stop. Then the
//! LEDs are stopped, every frame still pending is labelled and routed, and the stages
//! finish the jobs they hold, so stopping loses nothing.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use stereotac_protocol::Request;

use super::session::Session;
use super::workers::{Produced, Workers};
use super::{Output, Pipeline, PipelineError, Router};
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
    /// A camera, the sensor (unplugged and not back), a stage or the caller's check
    /// failed: the LEDs were stopped and every frame captured so far was processed and
    /// recorded.
    Failed(String),
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
    type Error: From<CaptureError> + From<PipelineError> + From<SensorError> + std::fmt::Display;
    /// A frame from camera `camera`, before routing.
    fn frame(&mut self, camera: usize, frame: &LabelledFrame) -> Result<(), Self::Error>;
    /// An output, after it was recorded; `false` stops the loop.
    fn output(&mut self, output: &Output) -> Result<bool, Self::Error>;
    /// A warning (sensor fault, reconnect), already recorded.
    fn warning(&mut self, message: String);
}

/// Runs the loop (see the module documentation); the sequence must be running. The
/// stages run on their own threads ([`Workers`]): a busy stage skips to the newest job.
/// Whatever fails once the loop runs (a camera, the sensor for good, a stage, a frame
/// the caller refuses) ends it as [`Stopped::Failed`] after the same clean stop, so the
/// caller can always finish its recording.
pub fn run<H: Hooks>(
    session: &mut Session,
    sensor: &mut Sensor,
    recorder: &Recorder,
    pipeline: &mut Pipeline,
    until: Until<'_>,
    hooks: &mut H,
) -> Stopped {
    let (mut router, tactile, stereo) = std::mem::take(pipeline).into_parts();
    let workers = Workers::start(tactile, stereo, std::sync::Arc::clone(sensor.clock()));
    let mut stopped = drive(
        session,
        sensor,
        recorder,
        &mut router,
        &workers,
        until,
        hooks,
    );
    let (rest, tactile, stereo) = workers.finish();
    *pipeline = Pipeline::from_parts(router, tactile, stereo);
    let now = sensor.clock().now_us() as f64;
    if stopped != Stopped::Caller
        && let Err(e) = hand_on(rest, recorder, hooks, now)
        && !matches!(stopped, Stopped::Failed(_))
    {
        stopped = Stopped::Failed(e.to_string());
    }
    stopped
}

fn drive<H: Hooks>(
    session: &mut Session,
    sensor: &mut Sensor,
    recorder: &Recorder,
    router: &mut Router,
    workers: &Workers,
    until: Until<'_>,
    hooks: &mut H,
) -> Stopped {
    let mut stopped = loop {
        if until.flag.load(Ordering::SeqCst) {
            break Stopped::Flag;
        }
        if until.end_us.is_some_and(|e| sensor.clock().now_us() >= e) {
            break Stopped::Deadline;
        }
        let stepped = session.step(sensor, recorder, POLL, |camera, frame, dropped| {
            route(hooks, router, workers, camera, frame, dropped)
        });
        for w in session.take_warnings() {
            hooks.warning(w);
        }
        let now = sensor.clock().now_us() as f64;
        match stepped.and_then(|()| hand_on(workers.ready(), recorder, hooks, now)) {
            Ok(true) => {}
            Ok(false) => break Stopped::Caller,
            Err(e) => break Stopped::Failed(e.to_string()),
        }
        if let Some(e) = recorder.failure() {
            break Stopped::Recorder(e);
        }
    };
    // The clean stop: LEDs off, then every frame still pending labelled and routed.
    let stop = sensor.request(Request::Stop);
    if stopped != Stopped::Caller
        && let Err(e) = session.finish(recorder, |camera, frame, dropped| {
            route(hooks, router, workers, camera, frame, dropped)
        })
        && !matches!(stopped, Stopped::Failed(_))
    {
        stopped = Stopped::Failed(e.to_string());
    }
    if let Err(e) = stop
        && !matches!(stopped, Stopped::Failed(_))
    {
        stopped = Stopped::Failed(format!("stopping the sequence: {e}"));
    }
    stopped
}

/// One frame: check, route, hand the job it completes to its stage.
fn route<H: Hooks>(
    hooks: &mut H,
    router: &mut Router,
    workers: &Workers,
    camera: usize,
    frame: LabelledFrame,
    dropped: u64,
) -> Result<(), H::Error> {
    hooks.frame(camera, &frame)?;
    if let Some(job) = router.push(camera, frame) {
        workers.submit(job, dropped);
    }
    Ok(())
}

/// Outputs to the caller and the recorder; `false` once the caller says stop.
/// Records and hands on each output; a pair refused on its own (its depth cannot be
/// right: see [`crate::tactile::reconstruct::ReconstructError::refuses_this_pair_only`])
/// becomes a warning at host time `now_us` and the run goes on.
fn hand_on<H: Hooks>(
    produced: Vec<Produced>,
    recorder: &Recorder,
    hooks: &mut H,
    now_us: f64,
) -> Result<bool, H::Error> {
    for p in produced {
        let output = match p {
            Err(PipelineError::Tactile(e)) if e.refuses_this_pair_only() => {
                let message = format!("tactile pair refused: {e}");
                recorder.send(crate::recording::writer::Item::Warning {
                    at_us: now_us,
                    message: message.clone(),
                });
                hooks.warning(message);
                continue;
            }
            p => p?,
        };
        let keep = hooks.output(&output)?;
        if recorder.is_active() {
            recorder.send(output.into_item());
        }
        if !keep {
            return Ok(false);
        }
    }
    Ok(true)
}
