//! The HIL checks against a sensor attached over USB: `STEREOTAC_HIL=device cargo test
//! -p stereotac-hil-tests`. They go through nusb and the host library's `Sensor`, the
//! code path users take. `STEREOTAC_HIL_SERIAL` picks one sensor when several are
//! attached. Without `STEREOTAC_HIL=device` they are reported as ignored.
//!
//! These check what the sensor reports of itself (command conformance, the phase
//! events' timing promises, clock sync), and what its pins do, through the firmware's
//! loopback probe: wire GPIO6 (trigger) to GPIO7 and GPIO2 (strip 1 data) to GPIO8
//! (README, "Hardware-in-loop tests"). The emulated tests run the same probe checks.

use std::sync::Arc;
use std::time::Duration;

use stereotac::clock::{HostClock, MonotonicClock};
use stereotac::device::{Sensor, SensorConfig};
use stereotac::transport::usb::UsbConnector;
use stereotac_hil_tests::events::check_events;
use stereotac_hil_tests::probe::{
    ProbeRecord, check_dark_after_fault, check_probe, collect_with_probe,
};
use stereotac_hil_tests::scenarios::{
    check_malformed_frames, probe_on_if_present, run_host_silence, run_not_reading,
    run_period_change,
};
use stereotac_hil_tests::setup::{Target, target};
use stereotac_protocol::{Config, Mode, PhaseEvent, Request, Timing};

const WIRING: &str = "is GPIO6 wired to GPIO7 and GPIO2 to GPIO8 (README)?";

/// The attached sensor. Without `STEREOTAC_HIL=device` these tests are ignored
/// (build.rs); run anyway (`--include-ignored`), they fail rather than pass unrun.
fn sensor() -> Sensor {
    assert!(
        target() == Target::Device,
        "set STEREOTAC_HIL=device to run this against an attached sensor"
    );
    let serial = std::env::var("STEREOTAC_HIL_SERIAL").ok();
    let clock: Arc<dyn HostClock> = Arc::new(MonotonicClock::new());
    Sensor::connect(
        Box::new(UsbConnector::new(serial)),
        clock,
        SensorConfig::default(),
    )
    .unwrap_or_else(|e| panic!("STEREOTAC_HIL=device, but no sensor to test: {e}"))
}

/// `n` consecutive phase events of a run of `mode` at `timing`, what the probe saw of
/// them (nothing unless it was turned on) and the configuration in effect; the sensor's
/// settings are put back afterwards.
fn run(
    sensor: &mut Sensor,
    mode: Mode,
    timing: Timing,
    n: usize,
) -> (Vec<PhaseEvent>, ProbeRecord, Config) {
    let before = sensor.config().unwrap();
    sensor.request(Request::SetMode(mode)).unwrap();
    sensor.request(Request::SetTiming(timing)).unwrap();
    sensor.request(Request::Start).unwrap();
    let config = sensor.config().unwrap();
    let limit = Duration::from_micros(u64::from(timing.phase_period_us) * (n as u64 + 5));
    let (events, probe) = collect_with_probe(sensor, n, limit);
    put_back(sensor, &before);
    assert!(events.len() >= n, "{} of {n} phase events", events.len());
    (events, probe, config)
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn answers_every_command() {
    let mut s = sensor();
    let report = stereotac::selftest::run_command_checks(&mut s).unwrap();
    assert!(
        report.passed(),
        "{:#?}",
        report.failures().collect::<Vec<_>>()
    );
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn gradient_mode_at_4_hz_keeps_its_promises() {
    let mut s = sensor();
    let (events, _, _) = run(&mut s, Mode::Gradient, Timing::DEFAULT, 41);
    let t =
        check_events(&events, Mode::Gradient, &Timing::DEFAULT).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{t:?}");
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn interleaved_mode_at_10_hz_keeps_its_promises() {
    let mut s = sensor();
    let timing = Timing {
        phase_period_us: 100_000,
        ..Timing::DEFAULT
    };
    let (events, _, _) = run(&mut s, Mode::Interleaved, timing, 30);
    check_events(&events, Mode::Interleaved, &timing).unwrap_or_else(|e| panic!("{e}"));
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn the_clock_sync_settles() {
    let mut s = sensor();
    let (events, _, _) = run(&mut s, Mode::Vision, Timing::DEFAULT, 12);
    assert_eq!(events.len(), 12);
    let fit = *s.clock_fit().expect("a clock fit after three seconds");
    // Full-speed USB: 1 ms frames bound the round trip, and the fit narrows below it.
    assert!(fit.uncertainty_us < 1000.0, "{fit:?}");
    assert!(
        (fit.slope - 1.0).abs() < 200e-6,
        "drift {:.1} ppm",
        (fit.slope - 1.0) * 1e6
    );
}

/// Stops the sensor and puts back the probe, host timeout, timing and mode of `before`.
fn put_back(s: &mut Sensor, before: &Config) {
    s.request(Request::Stop).unwrap();
    s.request(Request::SetProbe(before.probe)).unwrap();
    s.request(Request::SetHostTimeout(before.host_timeout_ms))
        .unwrap();
    s.request(Request::SetTiming(before.timing)).unwrap();
    s.request(Request::SetMode(before.mode)).unwrap();
}

/// Runs `f` with the loopback probe on (a firmware without it fails the test), then puts
/// the sensor's settings back, whatever `f` returned.
fn with_probe<R>(s: &mut Sensor, f: impl FnOnce(&mut Sensor) -> R) -> R {
    let before = s.config().unwrap();
    let present = probe_on_if_present(s).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        present,
        "this sensor's firmware has no loopback probe: flash the current firmware"
    );
    let result = f(s);
    put_back(s, &before);
    result
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn the_probed_pins_keep_gradient_mode_at_4_hz_exact_and_lit_right() {
    let mut s = sensor();
    let (events, probe, config) =
        with_probe(&mut s, |s| run(s, Mode::Gradient, Timing::DEFAULT, 41));
    let t = check_probe(&events, &probe, &config, s.info().max_leds_per_strip)
        .unwrap_or_else(|e| panic!("{e}; {WIRING}"));
    eprintln!("{t:?}");
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn host_silence_turns_the_probed_strip_dark() {
    let mut s = sensor();
    // Say nothing for a second: no requests, no clock pings.
    let run = with_probe(&mut s, |s| {
        run_host_silence(s, |_| std::thread::sleep(Duration::from_secs(1)))
    })
    .unwrap_or_else(|e| panic!("{e}"));
    check_dark_after_fault(&run.probe, run.fault.at_us).unwrap_or_else(|e| panic!("{e}; {WIRING}"));
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn malformed_frames_are_counted_and_the_sensor_keeps_answering() {
    let mut s = sensor();
    let status = check_malformed_frames(&mut s).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{status:?}");
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn interleaved_then_vision_with_the_period_changed_while_running() {
    let mut s = sensor();
    let run = with_probe(&mut s, run_period_change).unwrap_or_else(|e| panic!("{e}"));
    let frame_leds = s.info().max_leds_per_strip;
    for (events, config) in [
        (&run.interleaved, &run.interleaved_config),
        (&run.changed, &run.changed_config),
        (&run.vision, &run.changed_config),
    ] {
        check_probe(events, &run.probe, config, frame_leds)
            .unwrap_or_else(|e| panic!("{e}; {WIRING}"));
    }
}

#[test]
#[cfg_attr(
    not(hil_device),
    ignore = "needs an attached sensor: STEREOTAC_HIL=device cargo test -p stereotac-hil-tests"
)]
fn a_host_that_stops_reading_loses_events_not_timing() {
    let mut s = sensor();
    // Neither reading nor writing for 2 s: the host library's few queued USB transfers
    // fill, then the sensor's queue does.
    let run = with_probe(&mut s, |s| {
        run_not_reading(s, |_| std::thread::sleep(Duration::from_secs(2)))
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let frame_leds = s.info().max_leds_per_strip;
    for events in [&run.before, &run.after] {
        check_probe(events, &run.probe, &run.config, frame_leds)
            .unwrap_or_else(|e| panic!("{e}; {WIRING}"));
    }
    eprintln!(
        "{} events dropped on the sensor, {} seen lost",
        run.status.events_dropped, run.lost
    );
}
