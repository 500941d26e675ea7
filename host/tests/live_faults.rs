//! The live loop when things go wrong: a camera unplugged mid-run stops the run cleanly
//! (the LEDs off, the failure named, every frame captured before processed and in a
//! finished recording), and a stop flag raised by a signal does the same.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use stereotac::clock::{HostClock, VirtualClock};
use stereotac::device::SensorError;
use stereotac::frames::FrameSource;
use stereotac::frames::capture::{CaptureError, LabelledFrame};
use stereotac::live::runner::{self, Hooks, Stopped, Until};
use stereotac::live::session::Session;
use stereotac::live::{Output, Pipeline, PipelineError};
use stereotac::matcher::{CameraSync, MatcherConfig};
use stereotac::recording::reader::{self, Content};
use stereotac::recording::writer::{Recorder, RecorderOptions};
use stereotac::sim::camera::{PhaseImages, SimClocking, SimulatedCamera};
use stereotac::sim::link::LoopbackConfig;
use stereotac::tactile::render::{Optics, Scene};
use stereotac_protocol::Mode;

#[derive(Debug, thiserror::Error)]
enum TestError {
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error(transparent)]
    Sensor(#[from] SensorError),
}

#[derive(Default)]
struct Count {
    frames: [u64; 2],
}

impl Hooks for Count {
    type Error = TestError;
    fn frame(&mut self, camera: usize, _: &LabelledFrame) -> Result<(), TestError> {
        self.frames[camera] += 1;
        Ok(())
    }
    fn output(&mut self, _: &Output) -> Result<bool, TestError> {
        Ok(true)
    }
    fn warning(&mut self, _: String) {}
}

fn temp(name: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("stereotac-{name}-{}.mcap", std::process::id()));
    let _ = std::fs::remove_file(&p);
    p
}

/// Two triggered simulated cameras on a virtual clock; camera 1 unplugged at `unplug_us`
/// after the start (if any). Runs for 3 s of sensor time or until the flag; returns why
/// it stopped, what the hooks saw and the recording.
fn run_with(unplug_us: Option<f64>, flag: &AtomicBool) -> (Stopped, Count, PathBuf) {
    let clock: Arc<dyn HostClock> = Arc::new(VirtualClock::starting_at(1_000_000));
    let rig = stereotac::sim::connect(*b"FAULTTST", Arc::clone(&clock), LoopbackConfig::default())
        .unwrap();
    let mut sensor = rig.sensor;
    let optics = Optics::sized(96, 64);
    let images = PhaseImages::render(&optics, &Scene::default());
    let start = clock.now_us() as f64;
    let sources: Vec<Box<dyn FrameSource>> = (0..2)
        .map(|camera| {
            let mut cam = SimulatedCamera::new(
                Arc::clone(&rig.timeline),
                Arc::clone(&clock),
                SimClocking::Triggered { latency_us: 40.0 },
                8000.0,
                images.clone(),
            );
            if let (1, Some(at)) = (camera, unplug_us) {
                cam.unplug_at(start + at);
            }
            Box::new(cam) as Box<dyn FrameSource>
        })
        .collect();
    let path = temp(if unplug_us.is_some() {
        "unplug"
    } else {
        "flag"
    });
    let recorder = Recorder::start(RecorderOptions {
        mcap: Some(path.clone()),
        live_view: None,
        queue: 64,
        wait_when_full: true,
        clock_origin_unix_ns: 0,
    })
    .unwrap();
    let mut session = Session::new(
        sources,
        MatcherConfig {
            sync: CameraSync::Triggered {
                latency_us: 40.0,
                tolerance_us: 300.0,
            },
            ..MatcherConfig::default()
        },
    );
    sensor.start_sequence(Mode::Gradient, 100_000).unwrap();
    let mut hooks = Count::default();
    let stopped = runner::run(
        &mut session,
        &mut sensor,
        &recorder,
        &mut Pipeline::default(),
        Until {
            flag,
            end_us: Some(clock.now_us() + 3_000_000),
        },
        &mut hooks,
    );
    recorder.finish().unwrap();
    (stopped, hooks, path)
}

/// Frames per camera in a recording, read through to its summary.
fn recorded_frames(path: &Path) -> [u64; 2] {
    let mut n = [0u64; 2];
    let (_, truncated) = reader::frames(path, |c, _| {
        if let Content::Frame(f) = c {
            n[f.camera] += 1;
        }
        Ok::<_, stereotac::recording::RecordingError>(std::ops::ControlFlow::Continue(()))
    })
    .unwrap();
    assert!(truncated.is_none(), "a finished file: {truncated:?}");
    n
}

#[test]
fn a_camera_unplugged_mid_run_stops_it_cleanly_with_everything_so_far_recorded() {
    let flag = AtomicBool::new(false);
    let (stopped, hooks, path) = run_with(Some(1_000_000.0), &flag);
    let Stopped::Failed(why) = &stopped else {
        panic!("stopped as {stopped:?}")
    };
    assert!(
        why.contains("camera 1") && why.contains("unplugged"),
        "{why}"
    );
    // About 1 s at 10 phases/s: both cameras gave frames until then, and every frame
    // handed on is in the finished file.
    assert!((7..=12).contains(&hooks.frames[1]), "{:?}", hooks.frames);
    assert_eq!(recorded_frames(&path), hooks.frames);
    let _ = std::fs::remove_file(&path);
}

#[test]
fn a_raised_stop_flag_ends_the_run_at_once_and_keeps_what_was_captured() {
    let flag = AtomicBool::new(true);
    let (stopped, hooks, path) = run_with(None, &flag);
    assert_eq!(stopped, Stopped::Flag);
    assert_eq!(recorded_frames(&path), hooks.frames);
    let _ = std::fs::remove_file(&path);
}
