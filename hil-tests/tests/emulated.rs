//! The release firmware in the emulated RP2040, through the host library's own code.
//!
//! Each test boots a fresh emulator (about a second). `STEREOTAC_HIL=off` skips them.

use std::time::Duration;

use stereotac::device::{Sensor, SensorConfig, serial_number};
use stereotac_firmware::pins::PINS;
use stereotac_firmware::sequencer::WS2812_RESET_US;
use stereotac_hil_tests::emulator::{ControlOutcome, lock};
use stereotac_hil_tests::events::{check_events, collect_phases};
use stereotac_hil_tests::probe::{
    ProbeRecord, check_dark_after_fault, check_probe, collect_with_probe,
};
use stereotac_hil_tests::scenarios::{
    HostSilenceRun, check_malformed_frames, probe_on_if_present, run_host_silence, run_not_reading,
    run_period_change, start,
};
use stereotac_hil_tests::setup::{HOST_OFFSET_US, HOST_PPM, Rig, Target, target};
use stereotac_hil_tests::trace::{check_no_drift, check_periods};
use stereotac_hil_tests::ws2812::{Ws2812Frame, decode};
use stereotac_protocol::{
    Config, Mode, PROTOCOL_VERSION, Phase, PhaseEvent, Request, Response, Rgb, TriggerOutcome,
    USB_PID, USB_VID,
};

/// The emulated sensor. Under `STEREOTAC_HIL=device` or `off` these tests are ignored
/// (build.rs); run anyway (`--include-ignored`), they fail rather than pass unrun.
fn rig() -> Rig {
    assert!(
        target() == Target::Emulator,
        "STEREOTAC_HIL is device or off, so the emulated RP2040 is not run: unset it to run this test"
    );
    Rig::boot().unwrap_or_else(|e| panic!("{e}"))
}

/// Every frame each strip received so far, decoded from the trace.
fn strip_frames(rig: &Rig) -> [Vec<Ws2812Frame>; 4] {
    let emulator = lock(&rig.emulator);
    PINS.strips.map(|pin| decode(&emulator.trace().pin(pin)))
}

/// The frame each strip received for a phase whose LED write started at `write_us`.
fn frames_at(strips: &[Vec<Ws2812Frame>; 4], write_us: u64) -> [Ws2812Frame; 4] {
    let window = write_us * 1000..write_us * 1000 + 1_000_000;
    std::array::from_fn(|i| {
        strips[i]
            .iter()
            .find(|f| window.contains(&f.start_ns))
            .cloned()
            .unwrap_or_else(|| panic!("no frame on GPIO{} after {write_us} µs", PINS.strips[i]))
    })
}

/// The colour of the strip's `leds` pixels when they all show one lit colour; the
/// firmware sends its whole buffer, and pixels beyond the strip must be dark.
fn lit(frame: &Ws2812Frame, leds: usize) -> Option<Rgb> {
    let first = *frame.pixels.first()?;
    let (strip, beyond) = frame.pixels.split_at(leds.min(frame.pixels.len()));
    let beyond_dark = beyond.iter().all(|p| (p.r, p.g, p.b) == (0, 0, 0));
    (strip.iter().all(|p| *p == first) && beyond_dark && (first.r, first.g, first.b) != (0, 0, 0))
        .then_some(first)
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn enumerates_handshakes_and_answers_every_command() {
    let rig = rig();
    {
        let emulator = lock(&rig.emulator);
        let usb = emulator.enumeration();
        assert_eq!(usb.vid_pid(), (USB_VID, USB_PID));
        assert_eq!(usb.serial.len(), 16, "{:?}", usb.serial);
    }
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    assert_eq!(s.info().protocol_version, PROTOCOL_VERSION);
    assert_eq!(
        serial_number(&s.info().board_id),
        lock(&rig.emulator).enumeration().serial
    );
    let report = stereotac::selftest::run_command_checks(&mut s).unwrap();
    assert!(
        report.passed(),
        "{:#?}",
        report.failures().collect::<Vec<_>>()
    );
    // Malformed frames: counted, not answered, and the firmware keeps answering.
    check_malformed_frames(&mut s).unwrap_or_else(|e| panic!("{e}"));
    // A descriptor the device does not have is stalled, and the host model sees it.
    let other_speed = [0x80, 6, 0x00, 0x07, 0, 0, 9, 0];
    assert_eq!(
        lock(&rig.emulator).control(other_speed, &[]).unwrap(),
        ControlOutcome::Stall
    );
    assert!(s.status().is_ok(), "still answering after the stall");
    assert_eq!(s.request(Request::EnterBootloader).unwrap(), Response::Ack);
    let mut emulator = lock(&rig.emulator);
    let later = emulator.now_ns() + 50_000_000;
    emulator.run_until(later, false).unwrap();
    assert!(emulator.bootloader_requested());
    // The defmt log over RTT, decoded with the ELF, tells the same story.
    let log = emulator.log().unwrap();
    for expected in [
        "stereotac firmware",
        "host connected",
        "rebooting into the USB bootloader",
    ] {
        assert!(
            log.iter().any(|l| l.contains(expected)),
            "{expected:?} not in {log:#?}"
        );
    }
}

/// What [`check_phases`] measured, worst case over the phases.
#[derive(Debug, Default)]
struct Measured {
    /// Shortest and longest trigger period, ns.
    period_ns: (i64, i64),
    /// Traced trigger edge vs the event's `edge_us`.
    edge_error_ns: u64,
    /// First WS2812 bit after the event's `write_start_us`.
    write_lag_ns: i64,
    /// Write start after the phase boundary, µs.
    boundary_lag_us: u64,
    /// Real latch (last bit + reset) vs the event's `latched_us`.
    latch_error_ns: u64,
}

/// Expected strip colours of a phase: for each strip, `None` (dark) or the one colour
/// channel ('r' or 'b') it shows.
fn expected_channels(phase: Phase) -> [Option<char>; 4] {
    match phase {
        Phase::Dark => [None; 4],
        Phase::Dx => [Some('b'), None, Some('r'), None],
        Phase::Dy => [None, Some('b'), None, Some('r')],
        Phase::All => [Some('b'), Some('b'), Some('r'), Some('r')],
    }
}

/// Check every phase event against the pins: its trigger edge is on the trace within
/// 2 µs, after the real latch + settle; its strips started together within 2 µs of the
/// reported write start and latched within 2 µs of the reported latch; each strip shows
/// the phase's colour on its `leds` pixels (dark beyond); trigger periods are `period_us`
/// within 1 µs, and the span shows no drift. Events must be consecutive and all fired.
fn check_phases(rig: &Rig, events: &[PhaseEvent], config: &Config, period_us: u64) -> Measured {
    let indices: Vec<u32> = events.iter().map(|e| e.index).collect();
    assert!(indices.windows(2).all(|w| w[1] == w[0] + 1), "{indices:?}");
    let first_ns = events[0].write_start_us * 1000;
    let last_ns = events.last().unwrap().write_start_us * 1000 + period_us * 1000;
    let rises = lock(&rig.emulator)
        .trace()
        .trigger_rises_in(first_ns..last_ns);
    assert_eq!(rises.len(), events.len(), "one trigger edge per phase");
    let period_ns = period_us as i64 * 1000;
    let mut m = Measured {
        period_ns: check_periods(&rises, period_ns).unwrap_or_else(|e| panic!("{e}")),
        ..Measured::default()
    };
    check_no_drift(&rises, period_ns).unwrap_or_else(|e| panic!("{e}"));
    let settle_ns = u64::from(config.timing.led_settle_us) * 1000;
    let leds = usize::from(config.leds_per_strip);
    let strips = strip_frames(rig);
    let mut trigger_index = None;
    for (e, rise) in events.iter().zip(&rises) {
        let TriggerOutcome::Fired { index, edge_us } = e.trigger else {
            panic!("phase {} overran", e.index)
        };
        if let Some(previous) = trigger_index {
            assert_eq!(index, previous + 1, "trigger numbers");
        }
        trigger_index = Some(index);
        // Device µs = simulated µs.
        let edge_error_ns = rise.abs_diff(edge_us * 1000);
        assert!(
            edge_error_ns <= 2_000,
            "edge {rise} ns vs event {edge_us} µs"
        );
        m.edge_error_ns = m.edge_error_ns.max(edge_error_ns);
        let frames = frames_at(&strips, e.write_start_us);
        let first_bit = frames.iter().map(|f| f.start_ns).min().unwrap();
        let lag_ns = first_bit as i64 - e.write_start_us as i64 * 1000;
        assert!(
            (0..=2_000).contains(&lag_ns),
            "write start {} µs, first bit {first_bit} ns",
            e.write_start_us
        );
        assert!(
            frames.iter().all(|f| f.start_ns == first_bit),
            "strips started apart"
        );
        m.write_lag_ns = m.write_lag_ns.max(lag_ns);
        // The write starts on the phase boundary itself.
        let late_us = e.write_start_us - e.scheduled_us;
        assert!(late_us <= 2, "phase {} written {late_us} µs late", e.index);
        m.boundary_lag_us = m.boundary_lag_us.max(late_us);
        let last_bit = frames.iter().map(|f| f.end_ns).max().unwrap();
        let latched_ns = last_bit + u64::from(WS2812_RESET_US) * 1000;
        let latch_error_ns = latched_ns.abs_diff(e.latched_us * 1000);
        assert!(
            latch_error_ns <= 2_000,
            "latch {latched_ns} ns vs event {} µs",
            e.latched_us
        );
        m.latch_error_ns = m.latch_error_ns.max(latch_error_ns);
        assert!(
            *rise >= latched_ns + settle_ns,
            "trigger {rise} ns before latch + settle"
        );
        for (strip, (frame, channel)) in frames.iter().zip(expected_channels(e.phase)).enumerate() {
            assert!(frame.stray_bits == 0 && frame.pixels.len() >= leds);
            let what = format!("phase {} ({:?}) strip {}", e.index, e.phase, strip + 1);
            match channel {
                None => assert!(frame.is_dark(), "{what}: not dark"),
                Some(c) => {
                    let colour = lit(frame, leds).unwrap_or_else(|| panic!("{what}: not lit"));
                    let (on, others) = match c {
                        'b' => (colour.b, colour.r | colour.g),
                        _ => (colour.r, colour.b | colour.g),
                    };
                    assert!(on > 0 && others == 0, "{what}: {colour:?}");
                }
            }
        }
    }
    m
}

/// Start `mode`, collect `n` phases and let the last trigger fire.
fn run_mode(s: &mut Sensor, mode: Mode, n: usize) -> Vec<PhaseEvent> {
    s.request(Request::SetMode(mode)).unwrap();
    s.request(Request::Start).unwrap();
    let (events, _) = collect_phases(s, n, Duration::from_secs(20));
    assert!(events.len() >= n, "{mode:?}: {} phases", events.len());
    events
}

/// Run the emulator `us` of host time without any host traffic.
fn idle_for(s: &Sensor, us: u64) {
    let later = s.clock().now_us() + us;
    s.clock().sleep_until(later);
}

fn config(s: &mut Sensor) -> Config {
    let Response::Config(config) = s.request(Request::GetConfig).unwrap() else {
        panic!("no config")
    };
    config
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn gradient_mode_at_4_hz_is_exact_lit_right_and_reported_truthfully() {
    let rig = rig();
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    let config = config(&mut s);
    assert_eq!(config.timing.phase_period_us, 250_000, "4 Hz by default");
    let events = run_mode(&mut s, Mode::Gradient, 42);
    assert_eq!(s.counters().link.lost_events, 0);
    idle_for(&s, 300_000);
    let m = check_phases(&rig, &events, &config, 250_000);
    // What the events promise on their own: the checks a real sensor gets too.
    check_events(&events, Mode::Gradient, &config.timing).unwrap_or_else(|e| panic!("{e}"));
    eprintln!(
        "gradient: {} phases, trigger period {}..{} ns, edge vs event ≤ {} ns, write start after boundary ≤ {} µs, first bit after write start ≤ {} ns, latch error ≤ {} ns",
        events.len(),
        m.period_ns.0,
        m.period_ns.1,
        m.edge_error_ns,
        m.boundary_lag_us,
        m.write_lag_ns,
        m.latch_error_ns
    );
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn interleaved_then_vision_with_the_period_changed_while_running() {
    let rig = rig();
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    assert!(probe_on_if_present(&mut s).unwrap());
    let run = run_period_change(&mut s).unwrap_or_else(|e| panic!("{e}"));
    let frame_leds = s.info().max_leds_per_strip;
    let stages = [
        (
            "interleaved at 10 Hz",
            &run.interleaved,
            &run.interleaved_config,
        ),
        (
            "interleaved at 20 Hz after the change",
            &run.changed,
            &run.changed_config,
        ),
        ("vision at 20 Hz", &run.vision, &run.changed_config),
    ];
    for (name, events, config) in stages {
        let m = check_phases(&rig, events, config, config.timing.phase_period_us.into());
        check_probe(events, &run.probe, config, frame_leds)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        eprintln!("{name}: period {:?} ns", m.period_ns);
    }
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn the_loopback_probe_sees_what_the_pins_show() {
    let rig = rig();
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    assert_eq!(s.request(Request::SetProbe(true)).unwrap(), Response::Ack);
    let config = start(&mut s, Mode::Gradient, 50_000).unwrap_or_else(|e| panic!("{e}"));
    assert!(config.probe);
    let (events, probe) = collect_with_probe(&mut s, 16, Duration::from_secs(5));
    assert_eq!(events.len(), 16);
    let frame_leds = s.info().max_leds_per_strip;
    // The checks a bench sensor gets, from the probe alone.
    let t = check_probe(&events, &probe, &config, frame_leds).unwrap_or_else(|e| panic!("{e}"));
    // The probe against the pins themselves.
    let emulator = lock(&rig.emulator);
    let trace = emulator.trace();
    let first_ns = events[0].scheduled_us * 1000;
    let last_ns = events.last().unwrap().scheduled_us * 1000 + 50_000_000;
    let rises = trace.trigger_rises_in(first_ns..last_ns);
    let probed = probe.edges_in(first_ns..last_ns);
    assert_eq!(probed.len(), rises.len());
    let edge_error = rises
        .iter()
        .zip(&probed)
        .map(|(r, p)| *p as i64 - *r as i64)
        .collect::<Vec<_>>();
    let frames: Vec<Ws2812Frame> = decode(&trace.pin(PINS.strips[0]))
        .into_iter()
        .filter(|f| (first_ns..last_ns).contains(&f.end_ns))
        .collect();
    let probed_frames = probe.frames_in(first_ns..last_ns);
    assert_eq!(probed_frames.len(), frames.len());
    let mut end_error = Vec::new();
    for (traced, probed) in frames.iter().zip(&probed_frames) {
        assert_eq!(usize::from(probed.pixels), traced.pixels.len());
        assert_eq!(probed.first, traced.pixels[0]);
        let lit = traced.pixels.iter().filter(|p| **p != Rgb::new(0, 0, 0));
        assert_eq!(usize::from(probed.lit), lit.count());
        end_error.push(probed.end_ns as i64 - traced.end_ns as i64);
    }
    drop(emulator);
    let range = |v: &[i64]| (*v.iter().min().unwrap(), *v.iter().max().unwrap());
    let (edge_lo, edge_hi) = range(&edge_error);
    let (end_lo, end_hi) = range(&end_error);
    eprintln!(
        "probe: {} phases, probed edge − traced edge {edge_lo}..{edge_hi} ns, probed frame end − traced last edge {end_lo}..{end_hi} ns; {t:?}",
        events.len()
    );
    // Edges are timed to a few PIO cycles; a frame's end is seen when the decoder
    // samples the last bit (up to 0.5 µs after a short 0-bit pulse falls).
    assert!(edge_lo >= -100 && edge_hi <= 100, "{edge_error:?}");
    assert!(end_lo >= -100 && end_hi <= 600, "{end_error:?}");

    // The same checks fail on a sensor that does not do what it was told.
    let mut wrong_colour = config;
    wrong_colour.strips[0].colour = Rgb::new(0, 255, 0);
    let e = check_probe(&events, &probe, &wrong_colour, frame_leds).unwrap_err();
    assert!(e.contains("expected"), "{e}");
    let mut wrong_period = config;
    wrong_period.timing.phase_period_us = 50_001;
    assert!(check_probe(&events, &probe, &wrong_period, frame_leds).is_err());
    let missing = ProbeRecord {
        edges: probe.edges[1..].to_vec(),
        frames: probe.frames.clone(),
    };
    let e = check_probe(&events, &missing, &config, frame_leds).unwrap_err();
    assert!(e.contains("0 trigger edges"), "{e}");
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn host_silence_turns_the_leds_dark_and_reports_a_fault() {
    let rig = rig();
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    assert!(probe_on_if_present(&mut s).unwrap());
    let mut silent_from_ns = 0;
    let HostSilenceRun { fault, probe } = run_host_silence(&mut s, |s| {
        // From here on the host says nothing.
        silent_from_ns = lock(&rig.emulator).now_ns();
        idle_for(s, 1_500_000);
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let fault_ns = fault.at_us * 1000;
    // Checked every 100 ms: the timeout fires 300..400 ms after the last host message.
    assert!(
        (silent_from_ns + 300_000_000..=silent_from_ns + 400_000_000).contains(&fault_ns),
        "fault at {fault_ns} ns, silent from {silent_from_ns} ns"
    );
    let emulator = lock(&rig.emulator);
    let trace = emulator.trace();
    // The strips' last frames went out after the fault and are dark; nothing after.
    for pin in PINS.strips {
        let frames = decode(&trace.pin(pin));
        let last = frames.last().unwrap();
        assert!(
            last.start_ns >= fault_ns && last.start_ns < fault_ns + 1_000_000,
            "GPIO{pin}"
        );
        assert!(last.is_dark(), "GPIO{pin} still lit");
        let before = &frames[frames.len() - 2];
        assert!(!before.is_dark(), "GPIO{pin} was lit before the fault");
    }
    // No trigger after the fault.
    let late = trace.trigger_rises_in(fault_ns + 1..u64::MAX);
    assert!(late.is_empty(), "triggers after the fault: {late:?}");
    drop(emulator);
    let status = s.status().unwrap();
    assert_eq!(
        (status.host_timeouts, status.running),
        (1, false),
        "{status:?}"
    );
    // The defmt log says why.
    let log = lock(&rig.emulator).log().unwrap();
    assert!(log.iter().any(|l| l.contains("host silent")), "{log:?}");
    // The probe, which is what a bench sensor has, saw the same.
    check_dark_after_fault(&probe, fault.at_us).unwrap_or_else(|e| panic!("{e}"));
    let mut still_lit = probe.clone();
    still_lit.frames.pop();
    assert!(check_dark_after_fault(&still_lit, fault.at_us).is_err());
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn a_host_that_stops_reading_loses_events_not_timing() {
    let rig = rig();
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    assert!(probe_on_if_present(&mut s).unwrap());
    let run = run_not_reading(&mut s, |s| {
        lock(&rig.emulator).set_reading(false).unwrap();
        // 2 s of phases (100) with bulk IN stalled: the device's queue fills.
        idle_for(s, 2_000_000);
        lock(&rig.emulator).set_reading(true).unwrap();
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let frame_leds = s.info().max_leds_per_strip;
    for events in [&run.before, &run.after] {
        check_probe(events, &run.probe, &run.config, frame_leds).unwrap_or_else(|e| panic!("{e}"));
    }
    // The trigger kept its 20 ms period through it all, not one edge missing.
    let from = run.before[0].write_start_us * 1000;
    let to = run.after.last().unwrap().write_start_us * 1000;
    let rises = lock(&rig.emulator).trace().trigger_rises_in(from..to);
    let expected = (to - from) / 20_000_000;
    assert_eq!(rises.len() as u64, expected, "trigger edges");
    check_periods(&rises, 20_000_000).unwrap_or_else(|e| panic!("{e}"));
    eprintln!(
        "not reading for 2 s: {} events dropped on the device, {} seen lost by the host, {} trigger edges at 20 ms",
        run.status.events_dropped,
        run.lost,
        rises.len()
    );
}

#[test]
#[cfg_attr(
    not(hil_emulator),
    ignore = "STEREOTAC_HIL is device or off: the emulated RP2040 is not run"
)]
fn clock_sync_against_the_emulated_clock() {
    let rig = rig();
    let mut s = rig.sensor(SensorConfig::default()).unwrap();
    s.request(Request::SetMode(Mode::Vision)).unwrap();
    s.request(Request::Start).unwrap();
    let _ = collect_phases(&mut s, 24, Duration::from_secs(8));
    let fit = *s.clock_fit().expect("a clock fit");
    // Truth: host = offset + sim · (1 + 30 ppm); the device timer counts simulated µs.
    let mut worst: f64 = 0.0;
    for device_us in [1_000_000u64, 3_000_000, 6_000_000] {
        let truth = HOST_OFFSET_US as f64 + device_us as f64 * (1.0 + HOST_PPM * 1e-6);
        worst = worst.max((fit.to_host(device_us) - truth).abs());
    }
    eprintln!(
        "clock sync: worst error {worst:.2} µs, ±{:.2} µs, drift {:+.2} ppm",
        fit.uncertainty_us,
        fit.drift_ppm()
    );
    assert!(worst <= 20.0, "mapping error {worst} µs");
    assert!(
        (fit.drift_ppm().abs() - HOST_PPM).abs() < 3.0,
        "drift {} ppm",
        fit.drift_ppm()
    );
}
