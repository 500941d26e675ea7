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
use stereotac::recording::content::{self, Content};
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
    let (_, truncated) = content::frames(path, |c, _| {
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

/// Runs `stereotac --sim run` (simulated camera, gradient mode) for `seconds`, recording
/// to `rec`, under `shell_prefix` (shell commands run before the `exec`), and returns
/// (success, stdout, stderr).
fn cli_run(shell_prefix: &str, rec: &Path, seconds: &str) -> (bool, String, String) {
    captured(
        std::process::Command::new("bash")
            .args([
                "-c",
                &format!("{shell_prefix}; exec \"$0\" \"$@\""),
                env!("CARGO_BIN_EXE_stereotac"),
            ])
            .args(run_args(rec))
            .args(["--duration-s", seconds]),
    )
}

/// The arguments of a simulated `run` (one simulated camera, gradient mode) that records
/// to `rec` and prints JSON lines.
fn run_args(rec: &Path) -> [&str; 9] {
    [
        "--sim",
        "run",
        "--camera",
        "sim",
        "--mode",
        "gradient",
        "--mcap",
        rec.to_str().unwrap(),
        "--jsonl",
    ]
}

fn cli(args: &[&str]) -> (bool, String, String) {
    captured(std::process::Command::new(env!("CARGO_BIN_EXE_stereotac")).args(args))
}

/// Runs `command` to the end: (success, stdout, stderr).
fn captured(command: &mut std::process::Command) -> (bool, String, String) {
    let out = command.output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The pairs `process` reads back from a recording cut short, checked against the pairs
/// the live run printed: the same depth, in order, and no more of them.
fn processed_prefix(rec: &Path, live: &str) -> usize {
    let (ok, out, err) = cli(&["process", rec.to_str().unwrap(), "--jsonl"]);
    assert!(ok, "a cut recording is processed up to the cut: {err}");
    assert!(err.contains("never finished"), "the cut is reported: {err}");
    let n = out.lines().count();
    assert!(n <= live.lines().count(), "{n} pairs processed: {out}");
    for (a, b) in out.lines().zip(live.lines()) {
        let a: serde_json::Value = serde_json::from_str(a).unwrap();
        let b: serde_json::Value = serde_json::from_str(b).unwrap();
        assert_eq!(a["max_depth_mm"], b["max_depth_mm"]);
    }
    n
}

/// A disk that fills up mid-run (a file-size limit makes writes fail as a full disk
/// does): the run stops with an error naming the file as incomplete, and the file is
/// readable up to the last chunk the writer finished, not refused for the chunk it was
/// writing when the disk filled.
#[test]
fn a_full_disk_stops_the_run_and_leaves_a_recording_readable_up_to_its_last_chunk() {
    let rec = temp("disk-full");
    // 8 MB: the metadata and a few seconds of frames fit, not 12 seconds.
    let (ok, out, err) = cli_run("trap '' XFSZ; ulimit -f 8000", &rec, "12");
    assert!(!ok, "a write error is a failure: {err}");
    assert!(
        err.contains("disk-full") && err.contains("incomplete"),
        "the error names the file as incomplete: {err}"
    );
    assert!(out.lines().count() >= 1, "pairs were made before: {err}");
    let n = processed_prefix(&rec, &out);
    assert!(n >= 1, "the finished chunks hold pairs");
    let _ = std::fs::remove_file(&rec);
}

/// SIGKILL mid-run: no summary, no index, a chunk left unfinished; everything in the
/// chunks before it is read back.
#[test]
fn a_killed_run_leaves_a_recording_readable_up_to_its_last_chunk() {
    let rec = temp("killed");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(run_args(&rec))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    // Chunks are closed every second: 2.5 s after the first pair, at least one is
    // finished (the clock starts at the first pair: starting up takes its own time).
    let mut live = String::new();
    std::io::BufRead::read_line(&mut stdout, &mut live).unwrap();
    let start = std::time::Instant::now();
    while start.elapsed() < std::time::Duration::from_millis(2500) {
        let mut line = String::new();
        if std::io::BufRead::read_line(&mut stdout, &mut line).unwrap() == 0 {
            break;
        }
        live.push_str(&line);
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let bytes = std::fs::read(&rec).unwrap();
    assert!(
        mcap::Summary::read(&bytes).map_or(true, |s| s.is_none()),
        "a killed writer leaves no summary"
    );
    let n = processed_prefix(&rec, &live);
    assert!(n >= 1, "the finished chunks hold pairs");
    let _ = std::fs::remove_file(&rec);
}
