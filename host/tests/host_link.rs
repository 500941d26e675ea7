//! The host link against the firmware's real command handling, behind the loopback's
//! simulated USB timing and drifting device clock, on a virtual host clock.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use stereotac::clock::{HostClock, VirtualClock};
use stereotac::device::{Sensor, SensorConfig, SensorError, SensorEvent};
use stereotac::sim::SimulatedRig;
use stereotac::sim::link::{LedTimeline, Loopback, LoopbackConfig, PlugHandle};
use stereotac::transport::{Connector, OpenError};
use stereotac_protocol::*;

const BOARD: [u8; 8] = [0xE6, 0x61, 0x41, 0x04, 0x03, 0x2F, 0x1A, 0x2B];

struct Rig {
    clock: VirtualClock,
    plug: PlugHandle,
    timeline: Arc<Mutex<LedTimeline>>,
    sensor: Sensor,
}

fn rig(config: LoopbackConfig) -> Rig {
    let clock = VirtualClock::starting_at(10_000_000);
    let SimulatedRig {
        sensor,
        timeline,
        plug,
    } = stereotac::sim::connect(BOARD, Arc::new(clock.clone()), config).expect("connect");
    Rig {
        clock,
        plug,
        timeline,
        sensor,
    }
}

/// The loopback's true device → host mapping for `config`.
fn truth(config: &LoopbackConfig, d: u64) -> f64 {
    config.boot_at_us as f64 + d as f64 / (1.0 + config.drift_ppm * 1e-6)
}

fn phases(events: &[SensorEvent]) -> impl Iterator<Item = &stereotac::device::HostPhase> {
    events.iter().filter_map(|e| match e {
        SensorEvent::Phase(p) => Some(p),
        _ => None,
    })
}

fn run_for(rig: &mut Rig, duration_us: u64) -> Vec<SensorEvent> {
    let end = rig.clock.now_us() + duration_us;
    let mut events = Vec::new();
    while rig.clock.now_us() < end {
        events.extend(rig.sensor.poll(Duration::from_millis(20)).unwrap());
    }
    events
}

#[test]
fn clock_sync_is_within_100_us_of_a_drifting_jittery_device_clock() {
    for (drift_ppm, seed) in [(50.0, 1), (-50.0, 2), (20.0, 3)] {
        let config = LoopbackConfig {
            drift_ppm,
            boot_at_us: 3_217_000,
            seed,
            ..LoopbackConfig::default()
        };
        let mut rig = rig(config);
        rig.sensor
            .request(Request::SetMode(Mode::Gradient))
            .unwrap();
        rig.sensor.request(Request::Start).unwrap();
        let events = run_for(&mut rig, 60_000_000);
        let fit = *rig.sensor.clock_fit().unwrap();
        // Over the last phases: device timestamps mapped by the fit against the truth.
        let mut worst: f64 = 0.0;
        for p in phases(&events).skip(200) {
            let (_, edge) = p.trigger.expect("fired");
            let TriggerOutcome::Fired { edge_us, .. } = p.event.trigger else {
                unreachable!()
            };
            worst = worst.max((edge - truth(&config, edge_us)).abs());
        }
        // And now (extrapolating to the present).
        let now = rig.clock.now_us();
        let device_now = ((now - config.boot_at_us) as f64 * (1.0 + drift_ppm * 1e-6)) as u64;
        worst = worst.max((fit.to_host(device_now) - truth(&config, device_now)).abs());
        println!(
            "drift {drift_ppm:+} ppm: fitted {:+.2} ppm, worst error {worst:.1} µs, reported uncertainty {:.1} µs, min RTT {} µs",
            fit.drift_ppm(),
            fit.uncertainty_us,
            fit.min_rtt_us
        );
        assert!(worst <= 100.0, "drift {drift_ppm}: error {worst} µs");
        assert!(
            (fit.drift_ppm() - (-drift_ppm)).abs() < 5.0,
            "{}",
            fit.drift_ppm()
        );
        assert!(fit.uncertainty_us > 0.0 && fit.uncertainty_us < 100.0);
        assert!(rig.sensor.counters().sync_pings > 250);
    }
}

#[test]
fn phase_events_on_the_host_clock_match_what_the_leds_did() {
    let config = LoopbackConfig {
        drift_ppm: -30.0,
        ..LoopbackConfig::default()
    };
    let mut rig = rig(config);
    rig.sensor
        .request(Request::SetMode(Mode::Interleaved))
        .unwrap();
    rig.sensor.request(Request::Start).unwrap();
    let events = run_for(&mut rig, 10_000_000);
    let reported: Vec<_> = phases(&events).collect();
    let truth = rig.timeline.lock().unwrap();
    let spans: Vec<_> = truth
        .spans()
        .iter()
        .filter(|s| s.phase_index.is_some())
        .collect();
    assert!(reported.len() >= 38, "{}", reported.len());
    for (k, p) in reported.iter().enumerate() {
        let span = spans
            .iter()
            .find(|s| s.phase_index == Some(p.event.index))
            .expect("every reported phase happened");
        assert_eq!(span.phase, p.event.phase);
        let (index, edge) = p.trigger.unwrap();
        let (true_index, true_edge) = span.trigger.unwrap();
        assert_eq!(index, true_index);
        // The drift is fitted once the pings span 2 s; before, 30 ppm adds up.
        let tolerance = if k < 12 { 100.0 } else { 50.0 };
        assert!(
            (edge - true_edge).abs() < tolerance,
            "{k}: {edge} vs {true_edge}"
        );
        assert!((p.latched_us - span.from_us).abs() < tolerance);
    }
    let kinds: Vec<Phase> = reported.iter().take(6).map(|p| p.event.phase).collect();
    assert_eq!(
        kinds,
        [
            Phase::Dark,
            Phase::Dx,
            Phase::Dy,
            Phase::Dark,
            Phase::Dx,
            Phase::Dy
        ]
    );
}

#[test]
fn every_command_and_bad_value_through_the_loopback() {
    let mut rig = rig(LoopbackConfig::default());
    let s = &mut rig.sensor;
    assert_eq!(s.info().board_id, BOARD);
    let report = stereotac::selftest::run_command_checks(s).unwrap();
    assert!(
        report.passed(),
        "{:#?}",
        report.failures().collect::<Vec<_>>()
    );
    assert!(report.checks.len() >= 17, "{report:#?}");
    assert_eq!(
        s.request(Request::EnterBootloader).unwrap(),
        Response::Ack,
        "acknowledged before the reboot"
    );
}

#[test]
fn a_host_that_does_not_read_keeps_the_timing_and_sees_the_drops() {
    let mut rig = rig(LoopbackConfig {
        host_buffer_frames: 8,
        ..LoopbackConfig::default()
    });
    rig.sensor
        .request(Request::SetTiming(Timing {
            phase_period_us: 20_000,
            ..Timing::DEFAULT
        }))
        .unwrap();
    rig.sensor.request(Request::SetMode(Mode::Vision)).unwrap();
    rig.sensor.request(Request::Start).unwrap();
    rig.clock.advance(2_000_000); // the host looks away for 2 s: 100 phases
    let events = run_for(&mut rig, 1_000_000);
    let status = rig.sensor.status().unwrap();
    assert!(status.events_dropped >= 60, "{status:?}");
    assert_eq!(
        rig.sensor.counters().link.lost_events,
        u64::from(status.events_dropped)
    );
    let truth = rig.timeline.lock().unwrap();
    let edges: Vec<f64> = truth
        .spans()
        .iter()
        .filter_map(|s| s.trigger.map(|t| t.1))
        .collect();
    assert!(edges.len() >= 140);
    for pair in edges.windows(2) {
        assert!((pair[1] - pair[0] - 20_000.0).abs() < 0.01, "{pair:?}");
    }
    assert!(phases(&events).count() >= 45);
}

#[test]
fn reconnects_after_an_unplug_with_counters_config_and_sequence_restored() {
    let clock = VirtualClock::starting_at(1_000_000);
    let attempts = Arc::new(AtomicU32::new(0));
    let first = Loopback::new(BOARD, Arc::new(clock.clone()), LoopbackConfig::default());
    let plug = first.plug_handle();
    let mut first = Some(first);
    let (c, a) = (clock.clone(), Arc::clone(&attempts));
    let connector: Connector = Box::new(move || {
        if let Some(link) = first.take() {
            return Ok(Box::new(link) as _);
        }
        // The board re-enumerates after three failed attempts, rebooted: fresh state and a
        // device clock that starts again from zero.
        if a.fetch_add(1, Ordering::SeqCst) < 3 {
            return Err(OpenError::NotFound {
                serial: None,
                present: vec![],
            });
        }
        let config = LoopbackConfig {
            boot_at_us: c.now_us(),
            seed: 9,
            ..LoopbackConfig::default()
        };
        Ok(Box::new(Loopback::new(BOARD, Arc::new(c.clone()), config)) as _)
    });
    let mut sensor =
        Sensor::connect(connector, Arc::new(clock.clone()), SensorConfig::default()).unwrap();
    let timing = Timing {
        phase_period_us: 50_000,
        ..Timing::DEFAULT
    };
    sensor.request(Request::SetTiming(timing)).unwrap();
    sensor.request(Request::SetMode(Mode::Gradient)).unwrap();
    sensor.request(Request::Start).unwrap();
    let mut rig = Rig {
        clock: clock.clone(),
        plug,
        timeline: Arc::default(),
        sensor,
    };
    let before = run_for(&mut rig, 1_000_000);
    let counted = rig.sensor.counters().link.events;
    assert!(phases(&before).count() >= 18);
    rig.plug.set_plugged(false);
    let after = run_for(&mut rig, 2_000_000);
    assert_eq!(attempts.load(Ordering::SeqCst), 4);
    let reconnected = after
        .iter()
        .find_map(|e| match e {
            SensorEvent::Reconnected { attempts } => Some(*attempts),
            _ => None,
        })
        .expect("reconnected event");
    assert_eq!(reconnected, 4);
    let counters = rig.sensor.counters();
    assert_eq!(counters.reconnects, 1);
    assert!(counters.link.events > counted, "counters carried over");
    assert_eq!(rig.sensor.clock_fit().map(|f| f.samples > 0), Some(true));
    let Response::Config(config) = rig.sensor.request(Request::GetConfig).unwrap() else {
        panic!()
    };
    assert_eq!(config.timing, timing, "configuration replayed");
    assert_eq!(config.mode, Mode::Gradient);
    let resumed: Vec<_> = phases(&after).collect();
    assert!(resumed.len() >= 20, "sequence restarted: {}", resumed.len());
    assert_eq!(
        resumed[0].event.index, 0,
        "the rebooted board starts from phase 0"
    );
}

#[test]
fn giving_up_reconnecting_is_a_clear_error() {
    let mut rig = rig(LoopbackConfig::default());
    rig.sensor.request(Request::SetMode(Mode::Vision)).unwrap();
    rig.plug.set_plugged(false);
    let err = rig.sensor.poll(Duration::from_millis(10)).unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(err, SensorError::ReconnectFailed { attempts, .. } if attempts > 5),
        "{text}"
    );
    assert!(text.contains("did not come back"), "{text}");
}
