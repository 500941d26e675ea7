//! Golden byte vectors: the exact frame of one example of every message kind.
//!
//! Any change to the wire format shows up here as a failing test and, after
//! `STEREOTAC_BLESS=1 cargo test -p stereotac-protocol --test golden`, as a diff of
//! `tests/golden_vectors.txt`. A wire change must bump `PROTOCOL_VERSION`.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use stereotac_protocol::*;

const GOLDEN_FILE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/golden_vectors.txt");

fn status() -> Status {
    Status {
        uptime_us: 12_345_678,
        running: true,
        mode: Mode::Gradient,
        phases: 1000,
        triggers: 998,
        overruns: 2,
        events_dropped: 3,
        frames_received: 400,
        frames_rejected: 1,
        requests_rejected: 4,
        host_timeouts: 0,
    }
}

fn strip(strip: Strip, colour: Rgb, brightness: u8) -> StripSettings {
    StripSettings {
        strip,
        colour,
        brightness,
    }
}

/// Index of a request variant; exhaustive so a new variant cannot be forgotten here.
fn request_kind(r: &Request) -> usize {
    match r {
        Request::GetInfo => 0,
        Request::GetStatus => 1,
        Request::GetConfig => 2,
        Request::SetMode(_) => 3,
        Request::SetTiming(_) => 4,
        Request::SetStrip(_) => 5,
        Request::SetLedCount(_) => 6,
        Request::SetPowerBudget(_) => 7,
        Request::SetHostTimeout(_) => 8,
        Request::Start => 9,
        Request::Stop => 10,
        Request::TimeSync => 11,
        Request::EnterBootloader => 12,
        Request::SetProbe(_) => 13,
        Request::Configure(_) => 14,
    }
}
const REQUEST_KINDS: usize = 15;

/// Index of a device message kind (reply variants, errors and events), exhaustive.
fn device_kind(m: &DeviceMessage) -> usize {
    match m {
        DeviceMessage::Reply { result, .. } => match result {
            Ok(Response::Info(_)) => 0,
            Ok(Response::Ack) => 1,
            Ok(Response::Status(_)) => 2,
            Ok(Response::Config(_)) => 3,
            Ok(Response::Time(_)) => 4,
            Err(DeviceError::Malformed) => 5,
            Err(DeviceError::InvalidValue(_)) => 6,
            Err(DeviceError::TimingInfeasible { .. }) => 7,
            Err(DeviceError::InvalidState) => 8,
        },
        DeviceMessage::Event { event, .. } => match event {
            Event::Heartbeat(_) => 9,
            Event::Phase(PhaseEvent {
                trigger: TriggerOutcome::Fired { .. },
                ..
            }) => 10,
            Event::Phase(PhaseEvent {
                trigger: TriggerOutcome::Overrun { .. },
                ..
            }) => 11,
            Event::Fault(_) => 12,
            Event::Probe(ProbeEvent::TriggerEdge { .. }) => 13,
            Event::Probe(ProbeEvent::StripFrame(_)) => 14,
        },
    }
}
const DEVICE_KINDS: usize = 15;

fn host_examples() -> Vec<(&'static str, HostMessage)> {
    let r = |id, request| HostMessage { id, request };
    vec![
        ("host/get_info", r(1, Request::GetInfo)),
        ("host/get_status", r(2, Request::GetStatus)),
        ("host/get_config", r(3, Request::GetConfig)),
        (
            "host/set_mode_interleaved",
            r(4, Request::SetMode(Mode::Interleaved)),
        ),
        (
            "host/set_timing_default",
            r(5, Request::SetTiming(Timing::DEFAULT)),
        ),
        (
            "host/set_strip_3_red",
            r(
                6,
                Request::SetStrip(strip(Strip::XPlus, Rgb::new(255, 0, 0), 128)),
            ),
        ),
        ("host/set_led_count_8", r(7, Request::SetLedCount(8))),
        (
            "host/set_power_budget_400",
            r(8, Request::SetPowerBudget(400)),
        ),
        (
            "host/set_host_timeout_5000",
            r(9, Request::SetHostTimeout(5000)),
        ),
        ("host/start", r(10, Request::Start)),
        ("host/stop", r(11, Request::Stop)),
        ("host/time_sync", r(0xFFFF_FFFF, Request::TimeSync)),
        ("host/enter_bootloader", r(300, Request::EnterBootloader)),
        ("host/set_probe_on", r(301, Request::SetProbe(true))),
        (
            "host/configure",
            r(
                302,
                Request::Configure(Settings {
                    mode: Mode::Gradient,
                    timing: Timing::DEFAULT,
                    strips: Strip::ALL.map(|s| strip(s, Rgb::new(0, 0, 255), 200)),
                    leds_per_strip: 8,
                    power_budget_ma: 500,
                    host_timeout_ms: 0,
                }),
            ),
        ),
    ]
}

fn device_examples() -> Vec<(&'static str, DeviceMessage)> {
    let ok = |id, response| DeviceMessage::Reply {
        id,
        result: Ok(response),
    };
    let err = |id, error| DeviceMessage::Reply {
        id,
        result: Err(error),
    };
    let ev = |seq, event| DeviceMessage::Event { seq, event };
    let info = DeviceInfo {
        protocol_version: PROTOCOL_VERSION,
        firmware_version: FirmwareVersion {
            major: 0,
            minor: 1,
            patch: 0,
        },
        git_hash: [0xab; 20],
        git_dirty: false,
        board_id: [0xe6, 0x61, 0x38, 0x52, 0x83, 0x5b, 0x24, 0x2f],
        strips: 4,
        leds_per_strip: 8,
        max_leds_per_strip: 64,
        capabilities: Capabilities(
            Capabilities::HARDWARE_TRIGGER | Capabilities::PIO_LEDS | Capabilities::INTERLEAVED,
        ),
        timer_hz: 1_000_000,
    };
    let config = Config {
        mode: Mode::Gradient,
        timing: Timing::DEFAULT,
        strips: [
            strip(Strip::XMinus, Rgb::new(0, 0, 255), 255),
            strip(Strip::YMinus, Rgb::new(0, 0, 255), 255),
            strip(Strip::XPlus, Rgb::new(255, 0, 0), 255),
            strip(Strip::YPlus, Rgb::new(255, 0, 0), 255),
        ],
        leds_per_strip: 8,
        power_budget_ma: 400,
        host_timeout_ms: 5000,
        power_scale: 255,
        probe: false,
    };
    let phase = |trigger| PhaseEvent {
        index: 41,
        phase: Phase::Dy,
        scheduled_us: 10_250_000,
        write_start_us: 10_250_003,
        latched_us: 10_250_543,
        trigger,
    };
    vec![
        ("device/reply_info", ok(1, Response::Info(info))),
        ("device/reply_ack", ok(10, Response::Ack)),
        ("device/reply_status", ok(2, Response::Status(status()))),
        ("device/reply_config", ok(3, Response::Config(config))),
        (
            "device/reply_time",
            ok(12, Response::Time(1_234_567_890_123)),
        ),
        ("device/error_malformed", err(13, DeviceError::Malformed)),
        (
            "device/error_invalid_value",
            err(14, DeviceError::InvalidValue(Field::LedCount)),
        ),
        (
            "device/error_timing_infeasible",
            err(
                15,
                DeviceError::TimingInfeasible {
                    needed_us: 1200,
                    period_us: 1000,
                },
            ),
        ),
        (
            "device/error_invalid_state",
            err(16, DeviceError::InvalidState),
        ),
        (
            "device/event_heartbeat",
            ev(100, Event::Heartbeat(status())),
        ),
        (
            "device/event_phase_fired",
            ev(
                101,
                Event::Phase(phase(TriggerOutcome::Fired {
                    index: 40,
                    edge_us: 10_251_043,
                })),
            ),
        ),
        (
            "device/event_phase_overrun",
            ev(
                102,
                Event::Phase(phase(TriggerOutcome::Overrun {
                    deadline_us: 10_499_900,
                    ready_us: 10_500_100,
                })),
            ),
        ),
        (
            "device/event_fault_host_timeout",
            ev(
                103,
                Event::Fault(Fault {
                    at_us: 15_000_000,
                    kind: FaultKind::HostTimeout,
                }),
            ),
        ),
        (
            "device/event_probe_trigger_edge",
            ev(
                104,
                Event::Probe(ProbeEvent::TriggerEdge {
                    at_ns: 10_251_043_016,
                }),
            ),
        ),
        (
            "device/event_probe_strip_frame",
            ev(
                105,
                Event::Probe(ProbeEvent::StripFrame(StripFrameProbe {
                    end_ns: 10_250_042_875,
                    pixels: 32,
                    lit: 8,
                    leading_lit: 8,
                    first: Rgb::new(0, 0, 255),
                    mismatched: 0,
                    stray_bits: 0,
                })),
            ),
        ),
    ]
}

fn frame_hex<T: serde::Serialize>(message: &T) -> String {
    let mut buf = [0u8; MAX_FRAME];
    hex::encode(encode(message, &mut buf).expect("fits"))
}

fn current_vectors() -> BTreeMap<String, String> {
    let mut map = BTreeMap::new();
    for (name, m) in host_examples() {
        map.insert(name.to_string(), frame_hex(&m));
    }
    for (name, m) in device_examples() {
        map.insert(name.to_string(), frame_hex(&m));
    }
    map
}

fn stored_vectors() -> BTreeMap<String, String> {
    let text = std::fs::read_to_string(GOLDEN_FILE).unwrap_or_default();
    text.lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .filter_map(|l| l.split_once(' '))
        .map(|(name, hex)| (name.to_string(), hex.trim().to_string()))
        .collect()
}

#[test]
fn examples_cover_every_message_kind() {
    let mut seen = [false; REQUEST_KINDS];
    for (_, m) in host_examples() {
        seen[request_kind(&m.request)] = true;
    }
    assert!(
        seen.iter().all(|&s| s),
        "a request kind has no golden vector: {seen:?}"
    );
    let mut seen = [false; DEVICE_KINDS];
    for (_, m) in device_examples() {
        seen[device_kind(&m)] = true;
    }
    assert!(
        seen.iter().all(|&s| s),
        "a device message kind has no golden vector: {seen:?}"
    );
}

#[test]
fn wire_bytes_match_the_golden_vectors() {
    let current = current_vectors();
    if std::env::var_os("STEREOTAC_BLESS").is_some() {
        let mut text = format!(
            "# stereotac wire protocol v{PROTOCOL_VERSION}: golden frames (COBS + CRC-32C, \
             delimiter included), hex.\n# Regenerate: STEREOTAC_BLESS=1 cargo test -p \
             stereotac-protocol --test golden\n"
        );
        for (name, hex) in &current {
            writeln!(text, "{name} {hex}").unwrap();
        }
        std::fs::write(GOLDEN_FILE, text).expect("write golden file");
        return;
    }
    let stored = stored_vectors();
    let mut problems = Vec::new();
    for (name, hex) in &current {
        match stored.get(name) {
            None => problems.push(format!("{name}: no stored vector")),
            Some(s) if s != hex => {
                problems.push(format!("{name}:\n  stored  {s}\n  current {hex}"))
            }
            Some(_) => {}
        }
    }
    for name in stored.keys().filter(|n| !current.contains_key(*n)) {
        problems.push(format!("{name}: stored but no longer produced"));
    }
    assert!(
        problems.is_empty(),
        "the wire format changed (bump PROTOCOL_VERSION if deliberate, then bless):\n{}",
        problems.join("\n")
    );
}

#[test]
fn golden_frames_decode_back_to_their_messages() {
    let stored = stored_vectors();
    for (name, m) in host_examples() {
        let bytes = hex::decode(&stored[name]).unwrap();
        let mut decoder = FrameDecoder::<MAX_FRAME>::new();
        let (payload, rest) = decoder.feed(&bytes);
        assert!(rest.is_empty());
        assert_eq!(
            decode::<HostMessage>(payload.unwrap().unwrap()),
            Ok(m),
            "{name}"
        );
    }
    for (name, m) in device_examples() {
        let bytes = hex::decode(&stored[name]).unwrap();
        let mut decoder = FrameDecoder::<MAX_FRAME>::new();
        let (payload, _) = decoder.feed(&bytes);
        let payload = payload.unwrap().unwrap();
        assert_eq!(decode::<DeviceMessage>(payload), Ok(m), "{name}");
        if name == "device/reply_info" {
            assert_eq!(peek_protocol_version(payload), Some((1, PROTOCOL_VERSION)));
        }
    }
}
