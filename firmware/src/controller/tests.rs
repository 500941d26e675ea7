//! Command handling on the host: every request, bad input, timeouts, counters.

use proptest::prelude::*;
use stereotac_protocol::*;

use super::*;
use crate::MAX_LEDS_PER_STRIP;

fn controller() -> Controller {
    Controller::new(
        Identity {
            board_id: [1, 2, 3, 4, 5, 6, 7, 8],
            capabilities: Capabilities(Capabilities::HARDWARE_TRIGGER),
        },
        MAX_LEDS_PER_STRIP,
    )
}

/// Send `request` as a real frame payload; return the reply's result.
fn call(c: &mut Controller, id: u32, request: Request, now: u64) -> Result<Response, DeviceError> {
    let mut buf = [0u8; 256];
    let payload = postcard::to_slice(&HostMessage { id, request }, &mut buf).unwrap();
    match c.handle_frame(Ok(payload), now).0 {
        DeviceMessage::Reply { id: rid, result } => {
            assert_eq!(rid, id);
            result
        }
        other => panic!("expected a reply, got {other:?}"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, ..ProptestConfig::default() })]

    #[test]
    fn every_request_gets_exactly_one_reply_with_its_id(message: HostMessage, now in 0u64..1 << 50) {
        let mut c = controller();
        let mut buf = [0u8; 256];
        let payload = postcard::to_slice(&message, &mut buf).unwrap();
        let (reply, _) = c.handle_frame(Ok(payload), now);
        match reply {
            DeviceMessage::Reply { id, .. } => prop_assert_eq!(id, message.id),
            other => prop_assert!(false, "not a reply: {:?}", other),
        }
    }

    #[test]
    fn arbitrary_payloads_never_panic_and_get_a_malformed_or_valid_reply(
        bytes in prop::collection::vec(any::<u8>(), 0..140),
    ) {
        let mut c = controller();
        let (reply, _) = c.handle_frame(Ok(&bytes), 1000);
        if let DeviceMessage::Reply { result: Err(DeviceError::Malformed), .. } = reply {
            prop_assert!(decode::<HostMessage>(&bytes).is_err());
        }
    }

    #[test]
    fn request_sequences_keep_the_device_consistent(
        requests in prop::collection::vec(any::<Request>(), 1..40),
    ) {
        let mut c = controller();
        let mut now = 0u64;
        for (i, r) in requests.into_iter().enumerate() {
            now += 10_000;
            let _ = call(&mut c, i as u32, r, now);
            // Invariants: config stays valid, running implies a mode that shows something.
            prop_assert!(crate::sequencer::check_timing(&c.config().timing, MAX_LEDS_PER_STRIP).is_ok());
            prop_assert!((1..=MAX_LEDS_PER_STRIP).contains(&c.config().leds_per_strip));
            prop_assert!(!c.is_running() || c.config().mode != Mode::Off);
            if let Some(plan) = c.plan(now) {
                prop_assert!(c.frame(plan.phase).current_ua() <= u64::from(c.config().power_budget_ma) * 1000);
            }
        }
    }
}

#[test]
fn handshake_reports_version_board_and_capabilities() {
    let mut c = controller();
    let Ok(Response::Info(info)) = call(&mut c, 1, Request::GetInfo, 0) else {
        panic!()
    };
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(info.board_id, [1, 2, 3, 4, 5, 6, 7, 8]);
    assert_eq!(info.leds_per_strip, 8);
    assert_eq!(info.max_leds_per_strip, MAX_LEDS_PER_STRIP);
    assert_eq!(info.timer_hz, 1_000_000);
    assert!(info.capabilities.has(Capabilities::HARDWARE_TRIGGER));
}

#[test]
fn powers_on_off_and_refuses_to_start_without_a_mode() {
    let mut c = controller();
    assert_eq!(c.config().mode, Mode::Off);
    assert!(!c.is_running());
    assert_eq!(
        call(&mut c, 1, Request::Start, 0),
        Err(DeviceError::InvalidState)
    );
    assert_eq!(
        call(&mut c, 2, Request::SetMode(Mode::Gradient), 0),
        Ok(Response::Ack)
    );
    assert_eq!(call(&mut c, 3, Request::Start, 1000), Ok(Response::Ack));
    assert!(c.is_running());
    let plan = c.plan(1000).unwrap();
    assert_eq!(plan.phase, Phase::Dx);
    assert_eq!(call(&mut c, 4, Request::Stop, 2000), Ok(Response::Ack));
    assert!(!c.is_running());
}

#[test]
fn bad_values_get_typed_errors_and_change_nothing() {
    let mut c = controller();
    let before = *c.config();
    let cases = [
        (
            Request::SetLedCount(0),
            DeviceError::InvalidValue(Field::LedCount),
        ),
        (
            Request::SetLedCount(MAX_LEDS_PER_STRIP + 1),
            DeviceError::InvalidValue(Field::LedCount),
        ),
        (
            Request::SetPowerBudget(0),
            DeviceError::InvalidValue(Field::PowerBudget),
        ),
        (
            Request::SetHostTimeout(50),
            DeviceError::InvalidValue(Field::HostTimeout),
        ),
        (
            Request::SetTiming(Timing {
                phase_period_us: 10,
                ..Timing::DEFAULT
            }),
            DeviceError::InvalidValue(Field::PhasePeriod),
        ),
        (
            Request::SetTiming(Timing {
                trigger_pulse_us: 0,
                ..Timing::DEFAULT
            }),
            DeviceError::InvalidValue(Field::TriggerPulse),
        ),
        (
            Request::SetTiming(Timing {
                led_settle_us: 2_000_000,
                ..Timing::DEFAULT
            }),
            DeviceError::InvalidValue(Field::LedSettle),
        ),
        (
            Request::SetTiming(Timing {
                phase_period_us: 1500,
                ..Timing::DEFAULT
            }),
            DeviceError::TimingInfeasible {
                needed_us: 1980,
                period_us: 1500,
            },
        ),
    ];
    for (i, (request, error)) in cases.into_iter().enumerate() {
        assert_eq!(
            call(&mut c, i as u32, request, 0),
            Err(error),
            "{request:?}"
        );
    }
    assert_eq!(*c.config(), before);
    let Ok(Response::Status(s)) = call(&mut c, 99, Request::GetStatus, 5) else {
        panic!()
    };
    assert_eq!(s.requests_rejected, 8);
    assert_eq!(s.frames_received, 9);
}

#[test]
fn configure_applies_everything_or_nothing() {
    let mut c = controller();
    let before = *c.config();
    let mut s = before.settings();
    s.mode = Mode::Gradient;
    s.timing.phase_period_us = 100_000;
    s.strips[1].brightness = 7;
    s.power_budget_ma = 300;
    // Every value good but one: refused with that field, and nothing changed.
    for (bad, field) in [
        (
            Settings {
                leds_per_strip: 0,
                ..s
            },
            Field::LedCount,
        ),
        (
            Settings {
                power_budget_ma: 0,
                ..s
            },
            Field::PowerBudget,
        ),
        (
            Settings {
                host_timeout_ms: 5,
                ..s
            },
            Field::HostTimeout,
        ),
        (
            Settings {
                strips: [s.strips[1], s.strips[0], s.strips[2], s.strips[3]],
                ..s
            },
            Field::StripOrder,
        ),
    ] {
        assert_eq!(
            call(&mut c, 1, Request::Configure(bad), 0),
            Err(DeviceError::InvalidValue(field))
        );
        assert_eq!(*c.config(), before, "{field:?} refused, nothing applied");
    }
    let slow = Settings {
        timing: Timing {
            phase_period_us: 10,
            ..s.timing
        },
        ..s
    };
    assert!(call(&mut c, 2, Request::Configure(slow), 0).is_err());
    assert_eq!(*c.config(), before);
    // All good: all applied at once, the power scale recomputed.
    assert_eq!(call(&mut c, 3, Request::Configure(s), 0), Ok(Response::Ack));
    assert_eq!(c.config().settings(), s);
}

#[test]
fn settings_are_applied_and_reported() {
    let mut c = controller();
    let red = StripSettings {
        strip: Strip::YMinus,
        colour: Rgb::new(10, 20, 30),
        brightness: 128,
    };
    let timing = Timing {
        phase_period_us: 100_000,
        trigger_pulse_us: 50,
        led_settle_us: 200,
    };
    for (i, r) in [
        Request::SetStrip(red),
        Request::SetLedCount(12),
        Request::SetPowerBudget(250),
        Request::SetHostTimeout(0),
        Request::SetTiming(timing),
        Request::SetMode(Mode::Interleaved),
    ]
    .into_iter()
    .enumerate()
    {
        assert_eq!(call(&mut c, i as u32, r, 0), Ok(Response::Ack));
    }
    let Ok(Response::Config(cfg)) = call(&mut c, 10, Request::GetConfig, 0) else {
        panic!()
    };
    assert_eq!(cfg.strips[1], red);
    assert_eq!(cfg.leds_per_strip, 12);
    assert_eq!(cfg.power_budget_ma, 250);
    assert_eq!(cfg.host_timeout_ms, 0);
    assert_eq!(cfg.timing, timing);
    assert_eq!(cfg.mode, Mode::Interleaved);
    assert!(
        cfg.power_scale < 255,
        "12 px x 2 strips x 20 mA exceed 250 mA"
    );
}

#[test]
fn time_sync_returns_the_device_clock() {
    let mut c = controller();
    assert_eq!(
        call(&mut c, 5, Request::TimeSync, 123_456_789),
        Ok(Response::Time(123_456_789))
    );
}

#[test]
fn bootloader_request_stops_and_asks_the_board_to_reboot() {
    let mut c = controller();
    call(&mut c, 1, Request::SetMode(Mode::Gradient), 0).unwrap();
    call(&mut c, 2, Request::Start, 0).unwrap();
    let mut buf = [0u8; 64];
    let payload = postcard::to_slice(
        &HostMessage {
            id: 3,
            request: Request::EnterBootloader,
        },
        &mut buf,
    )
    .unwrap();
    let (reply, effect) = c.handle_frame(Ok(payload), 10);
    assert_eq!(
        reply,
        DeviceMessage::Reply {
            id: 3,
            result: Ok(Response::Ack)
        }
    );
    assert_eq!(effect, Effect::EnterBootloader);
    assert!(!c.is_running());
}

#[test]
fn malformed_requests_are_answered_with_their_id() {
    let mut c = controller();
    // id 77 as a varint, then an unknown request variant 200.
    let payload = [77u8, 0xc8, 0x01];
    let (reply, _) = c.handle_frame(Ok(&payload), 0);
    assert_eq!(
        reply,
        DeviceMessage::Reply {
            id: 77,
            result: Err(DeviceError::Malformed)
        }
    );
}

#[test]
fn bad_frames_become_fault_events_and_counters() {
    let mut c = controller();
    let (m, effect) = c.handle_frame(Err(FrameError::Crc), 42);
    assert_eq!(effect, Effect::None);
    assert_eq!(
        m,
        DeviceMessage::Event {
            seq: 0,
            event: Event::Fault(Fault {
                at_us: 42,
                kind: FaultKind::CorruptFrame
            })
        }
    );
    let (m, _) = c.handle_frame(Err(FrameError::Oversize), 43);
    assert!(matches!(
        m,
        DeviceMessage::Event {
            seq: 1,
            event: Event::Fault(Fault {
                kind: FaultKind::OversizeFrame,
                ..
            })
        }
    ));
    assert_eq!(c.status(50).frames_rejected, 2);
}

#[test]
fn host_silence_turns_the_leds_off_with_a_fault() {
    let mut c = controller();
    call(&mut c, 1, Request::SetMode(Mode::Gradient), 0).unwrap();
    call(&mut c, 2, Request::Start, 1_000_000).unwrap();
    assert_eq!(c.check_host_timeout(5_999_999), None);
    let fault = c.check_host_timeout(6_000_000).expect("timed out");
    assert!(matches!(
        fault,
        DeviceMessage::Event {
            event: Event::Fault(Fault {
                kind: FaultKind::HostTimeout,
                at_us: 6_000_000
            }),
            ..
        }
    ));
    assert!(!c.is_running());
    assert_eq!(c.plan(6_000_000), None);
    assert_eq!(c.status(0).host_timeouts, 1);
    // Reported once.
    assert_eq!(c.check_host_timeout(9_000_000), None);
}

#[test]
fn vision_mode_and_a_zero_timeout_never_time_out() {
    let mut c = controller();
    call(&mut c, 1, Request::SetMode(Mode::Vision), 0).unwrap();
    call(&mut c, 2, Request::Start, 0).unwrap();
    assert_eq!(c.check_host_timeout(100_000_000), None);
    call(&mut c, 3, Request::SetMode(Mode::Gradient), 0).unwrap();
    call(&mut c, 4, Request::SetHostTimeout(0), 0).unwrap();
    assert_eq!(c.check_host_timeout(100_000_000), None);
    assert!(c.is_running());
}

#[test]
fn events_are_numbered_without_gaps_and_drops_are_counted() {
    let mut c = controller();
    let seqs: Vec<u32> = (0..5)
        .map(|i| match c.heartbeat(i) {
            DeviceMessage::Event { seq, .. } => seq,
            _ => unreachable!(),
        })
        .collect();
    assert_eq!(seqs, [0, 1, 2, 3, 4]);
    c.note_event_dropped();
    assert_eq!(c.status(0).events_dropped, 1);
}

#[test]
fn a_phase_runs_through_plan_begin_finish() {
    let mut c = controller();
    call(&mut c, 1, Request::SetMode(Mode::Gradient), 0).unwrap();
    call(&mut c, 2, Request::Start, 0).unwrap();
    let plan = c.plan(0).unwrap();
    c.begin(&plan);
    let write = plan.start_us + 3;
    let latched = write + 1000;
    let (event, message) = c.finish(&plan, write, latched, latched);
    assert_eq!(
        event.trigger,
        TriggerOutcome::Fired {
            index: 0,
            edge_us: plan.trigger_at_us
        }
    );
    assert!(matches!(
        message,
        DeviceMessage::Event {
            event: Event::Phase(_),
            ..
        }
    ));
    let s = c.status(0);
    assert_eq!((s.phases, s.triggers, s.overruns), (1, 1, 0));
}

#[test]
fn probe_events_are_sent_only_when_asked_for_and_only_with_a_probe() {
    let edge = ProbeEvent::TriggerEdge { at_ns: 1_234 };
    // A board without the probe refuses to turn it on, and sends nothing.
    let mut c = controller();
    assert_eq!(
        call(&mut c, 1, Request::SetProbe(true), 0),
        Err(DeviceError::InvalidState)
    );
    assert!(!c.config().probe);
    assert_eq!(c.probe_event(edge), None);

    let mut c = Controller::new(
        Identity {
            board_id: [0; 8],
            capabilities: Capabilities(Capabilities::LOOPBACK_PROBE),
        },
        MAX_LEDS_PER_STRIP,
    );
    assert_eq!(c.probe_event(edge), None, "off by default");
    assert_eq!(
        call(&mut c, 2, Request::SetProbe(true), 0),
        Ok(Response::Ack)
    );
    assert!(c.config().probe);
    let first = c.probe_event(edge).unwrap();
    let second = c.probe_event(edge).unwrap();
    assert_eq!(
        first,
        DeviceMessage::Event {
            seq: 0,
            event: Event::Probe(edge)
        }
    );
    assert!(matches!(second, DeviceMessage::Event { seq: 1, .. }));
    assert_eq!(
        call(&mut c, 3, Request::SetProbe(false), 0),
        Ok(Response::Ack)
    );
    assert_eq!(c.probe_event(edge), None);
}
