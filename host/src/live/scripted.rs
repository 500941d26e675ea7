//! A scripted session of the simulated sensor, recorded: the sensor on a virtual clock
//! (it runs as fast as the frames render, and the same every time), one or two
//! simulated cameras showing a list of scenes in turn, one scene per LED cycle (so a
//! dx/dy pair never shows two), captured through the live session into a
//! [`Recorder`]. `demo` writes its recordings with it.

use std::sync::Arc;
use std::time::Duration;

use stereotac_protocol::{Mode, Request};

use super::session::Session;
use crate::clock::{HostClock, VirtualClock};
use crate::device::SensorError;
use crate::frames::FrameSource;
use crate::frames::capture::CaptureError;
use crate::matcher::{CameraSync, MatchStats, MatcherConfig};
use crate::recording::metadata::{self, RunInfo};
use crate::recording::writer::Recorder;
use crate::sim::camera::{PhaseImages, SimClocking, SimStereo, SimulatedCamera};
use crate::sim::link::LoopbackConfig;

/// What to record.
#[derive(Debug, Clone)]
pub struct Script {
    /// `gradient`, `interleaved` or `vision`.
    pub mode: Mode,
    /// Phase period, µs.
    pub period_us: u32,
    /// Camera exposure, µs.
    pub exposure_us: f64,
    /// What camera 0 (and camera 1) show, one scene per LED cycle.
    pub scenes: Vec<PhaseImages>,
    /// Two cameras, whose dark phases show this stereo pair's views; `None`: one camera.
    pub stereo: Option<SimStereo>,
    /// The command named in the recording's metadata.
    pub command: String,
}

/// Why a scripted session failed.
#[derive(Debug, thiserror::Error)]
pub enum ScriptError {
    /// The simulated sensor.
    #[error(transparent)]
    Sensor(#[from] SensorError),
    /// Capture.
    #[error(transparent)]
    Capture(#[from] CaptureError),
    /// The recorder stopped.
    #[error("the recording's writer stopped: {0}")]
    Recorder(String),
    /// A mode with nothing to film.
    #[error("a scripted session runs gradient, interleaved or vision, not {0}")]
    Mode(&'static str),
}

/// Where the session's virtual host clock starts, µs (give the recorder
/// `clock_origin_unix_ns(START_US)` to date the recording now).
pub const START_US: u64 = 1_000_000;

/// Delay from trigger edge to exposure start of the scripted cameras, µs.
const LATENCY_US: f64 = 150.0;

/// Phases in one cycle of `mode`.
fn cycle(mode: Mode) -> Option<u32> {
    match mode {
        Mode::Vision => Some(1),
        Mode::Gradient => Some(2),
        Mode::Interleaved => Some(3),
        Mode::Off | Mode::ContactShape => None,
    }
}

/// Runs `script` into `recorder` (header included); `progress(done, total)` counts
/// scenes. Returns each camera's matcher counts.
pub fn record(
    script: &Script,
    recorder: &Recorder,
    mut progress: impl FnMut(usize, usize),
) -> Result<Vec<MatchStats>, ScriptError> {
    let per_scene =
        cycle(script.mode).ok_or(ScriptError::Mode(crate::describe::mode(script.mode)))?;
    let clock: Arc<dyn HostClock> = Arc::new(VirtualClock::starting_at(START_US));
    let rig = crate::sim::connect(
        *b"SCRIPTED",
        Arc::clone(&clock),
        LoopbackConfig {
            drift_ppm: 30.0,
            ..LoopbackConfig::default()
        },
    )?;
    let mut sensor = rig.sensor;
    let views = script.stereo.map(|s| s.dark_views());
    let cameras = if views.is_some() { 2 } else { 1 };
    let mut sources: Vec<Box<dyn FrameSource>> = Vec::new();
    for camera in 0..cameras {
        let scenes: Vec<PhaseImages> = script
            .scenes
            .iter()
            .map(|s| match &views {
                Some((l, r)) => s.clone().with_dark(if camera == 0 { l } else { r }.clone()),
                None => s.clone(),
            })
            .collect();
        let Some(first) = scenes.first().cloned() else {
            return Ok(Vec::new());
        };
        let mut cam = SimulatedCamera::new(
            Arc::clone(&rig.timeline),
            Arc::clone(&clock),
            SimClocking::Triggered {
                latency_us: LATENCY_US,
            },
            script.exposure_us,
            first,
        );
        cam.cycle_scenes_by_phase(scenes, per_scene);
        sources.push(Box::new(cam));
    }
    let run = RunInfo {
        command: script.command.clone(),
        mode: script.mode,
        period_ms: script.period_us / 1000,
        clock_origin_unix_ns: recorder.clock_origin_unix_ns(),
        cameras: sources
            .iter()
            .map(|s| (s.describe(), s.stamp_ref()))
            .collect(),
    };
    for item in metadata::header(&run, sensor.info(), true) {
        if !recorder.send(item) {
            return Err(ScriptError::Recorder(
                recorder.failure().unwrap_or_default(),
            ));
        }
    }
    let mut session = Session::new(
        sources,
        MatcherConfig {
            sync: CameraSync::Triggered {
                latency_us: LATENCY_US,
                tolerance_us: 300.0,
            },
            ..MatcherConfig::default()
        },
    );
    sensor.start_sequence(script.mode, script.period_us)?;
    // Until every camera has decided one frame per scene phase (a timeout of twice the
    // script's length guards against a camera that stops answering).
    let frames = script.scenes.len() as u64 * u64::from(per_scene);
    let length_us = (frames + 2) * u64::from(script.period_us);
    let end = clock.now_us() + 2 * length_us;
    let total = script.scenes.len();
    let mut keep = |_: usize, _, _| Ok::<_, CaptureError>(());
    while clock.now_us() < end && session.stats().iter().any(|s| s.frames < frames) {
        session.step(&mut sensor, recorder, Duration::from_millis(20), &mut keep)?;
        let done = session.stats().iter().map(|s| s.frames).min().unwrap_or(0);
        progress((done / u64::from(per_scene)) as usize, total);
        if let Some(e) = recorder.failure() {
            return Err(ScriptError::Recorder(e));
        }
    }
    sensor.request(Request::Stop)?;
    session.finish(recorder, &mut keep)?;
    Ok(session.stats())
}
