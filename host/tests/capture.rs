//! Frames from the simulated camera, labelled against the sensor's phase events through
//! the whole host path: loopback USB, clock sync, matcher, recorder and replay.

use std::sync::Arc;
use std::time::Duration;

use stereotac::clock::{HostClock, VirtualClock};
use stereotac::frames::FrameSource;
use stereotac::frames::capture::{Capture, LabelledFrame};
use stereotac::frames::replay::{Recorder, ReplaySource};
use stereotac::matcher::{CameraSync, Label, MatcherConfig};
use stereotac::sim::camera::{PhaseImages, SimClocking, SimulatedCamera};
use stereotac::sim::link::LoopbackConfig;
use stereotac::tactile::render::{Optics, builtin_scenes};
use stereotac_protocol::{Mode, Phase, Request};

/// A triggered camera 40 µs after the edge, and the matcher that expects it.
const TRIGGERED: (SimClocking, CameraSync) = (
    SimClocking::Triggered { latency_us: 40.0 },
    CameraSync::Triggered {
        latency_us: 40.0,
        tolerance_us: 300.0,
    },
);

fn images() -> PhaseImages {
    let optics = Optics::sized(64, 48);
    let scenes = builtin_scenes(&optics);
    PhaseImages::render(&optics, &scenes[0].1)
}

struct Run {
    frames: Vec<LabelledFrame>,
    stats: stereotac::matcher::MatchStats,
    images: PhaseImages,
}

fn run(mode: Mode, (clocking, sync): (SimClocking, CameraSync), drop_every: Option<u64>) -> Run {
    let clock = VirtualClock::starting_at(5_000_000);
    let rig = stereotac::sim::connect(
        [3; 8],
        Arc::new(clock.clone()),
        LoopbackConfig {
            drift_ppm: 40.0,
            ..LoopbackConfig::default()
        },
    )
    .unwrap();
    let (mut sensor, timeline) = (rig.sensor, rig.timeline);
    let images = images();
    let mut camera = SimulatedCamera::new(
        timeline,
        Arc::new(clock.clone()),
        clocking,
        8000.0,
        images.clone(),
    );
    if let Some(n) = drop_every {
        camera.drop_every(n);
    }
    let mut capture = Capture::new(
        camera,
        MatcherConfig {
            sync,
            ..MatcherConfig::default()
        },
    );
    sensor.request(Request::SetMode(mode)).unwrap();
    sensor.request(Request::Start).unwrap();
    let mut frames = Vec::new();
    let end = clock.now_us() + 8_000_000;
    while clock.now_us() < end {
        frames.extend(
            capture
                .step(&mut sensor, Duration::from_millis(10))
                .unwrap()
                .frames,
        );
    }
    sensor.request(Request::Stop).unwrap();
    frames.extend(capture.finish());
    Run {
        frames,
        stats: capture.stats(),
        images,
    }
}

#[test]
fn triggered_frames_are_labelled_with_the_light_they_saw() {
    let r = run(Mode::Interleaved, TRIGGERED, None);
    assert!(r.frames.len() >= 30, "{}", r.frames.len());
    let mut triggers = Vec::new();
    for f in &r.frames {
        match f.label {
            Label::Phase { phase, trigger, .. } => {
                assert_eq!(&f.frame.image, r.images.of(phase), "image of {phase:?}");
                triggers.push(trigger.unwrap());
            }
            Label::Unresolved => {}
            other => panic!("{other:?}"),
        }
    }
    assert!(
        triggers.windows(2).all(|w| w[1] == w[0] + 1),
        "{triggers:?}"
    );
    let kinds: Vec<Phase> = r
        .frames
        .iter()
        .take(3)
        .filter_map(|f| match f.label {
            Label::Phase { phase, .. } => Some(phase),
            _ => None,
        })
        .collect();
    assert_eq!(kinds, [Phase::Dark, Phase::Dx, Phase::Dy]);
    assert_eq!(r.stats.dropped_frames, 0);
}

#[test]
fn dropped_triggered_frames_are_counted() {
    let r = run(Mode::Gradient, TRIGGERED, Some(5));
    let taken = r.frames.len() as u64;
    assert!(r.stats.dropped_frames >= 5, "{:?}", r.stats);
    assert_eq!(r.stats.dropped_frames, (taken + r.stats.dropped_frames) / 5);
}

#[test]
fn free_running_frames_across_an_led_change_are_rejected_never_mislabelled() {
    let r = run(
        Mode::Gradient,
        (
            SimClocking::FreeRunning {
                period_us: 33_333.0,
                first_us: 5_010_000.0,
            },
            CameraSync::FreeRunning,
        ),
        None,
    );
    let mut straddling = 0;
    for f in &r.frames {
        match f.label {
            Label::Phase { phase, trigger, .. } => {
                assert_eq!(&f.frame.image, r.images.of(phase));
                assert_eq!(trigger, None);
            }
            Label::Straddles => straddling += 1,
            Label::Unresolved => {}
            other => panic!("{other:?}"),
        }
    }
    assert!(r.stats.labelled >= 180, "{:?}", r.stats);
    // 8 ms exposures every 33 ms against 32 LED changes (each ~2 ms plus guards): about
    // a third of the changes fall inside an exposure.
    assert!(straddling >= 8, "{:?}", r.stats);
}

#[test]
fn a_recording_replays_frame_for_frame() {
    let r = run(Mode::Gradient, TRIGGERED, None);
    let dir = std::env::temp_dir().join(format!("stereotac-replay-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut recorder = Recorder::create(&dir).unwrap();
    for f in &r.frames {
        recorder.write_image(&f.frame).unwrap();
        recorder
            .write_label(&stereotac::matcher::MatchedFrame {
                frame: f.frame.stamp,
                label: f.label,
            })
            .unwrap();
    }
    recorder.flush().unwrap();
    assert!(
        Recorder::create(&dir).is_err(),
        "an existing recording is never overwritten"
    );
    // A recording with frames is never discarded.
    recorder.discard();
    assert!(dir.join("index.jsonl").exists());
    let mut replay = ReplaySource::open(&dir).unwrap();
    assert_eq!(replay.len(), r.frames.len());
    for f in &r.frames {
        let back = replay.next_frame(Duration::ZERO).unwrap().unwrap();
        assert_eq!(back.stamp, f.frame.stamp);
        assert_eq!(back.image, f.frame.image);
    }
    assert!(replay.is_finished());
    let index = std::fs::read_to_string(dir.join("index.jsonl")).unwrap();
    assert!(
        index
            .lines()
            .next()
            .unwrap()
            .contains("\"label\":\"phase\""),
        "{index}"
    );
    std::fs::write(dir.join("index.jsonl"), "{\"file\": 3}\n").unwrap();
    let err = ReplaySource::open(&dir).unwrap_err().to_string();
    assert!(err.contains("line 1"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
