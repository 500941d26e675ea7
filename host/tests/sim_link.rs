//! The host client against the firmware's real command handling, through real frames.

use std::time::Duration;

use stereotac::client::{Client, ClientError};
use stereotac::sim::sensor::SimulatedSensor;
use stereotac::transport::{Transport, TransportError};
use stereotac_protocol::*;

#[test]
fn handshake_and_gradient_sequence_through_the_simulated_sensor() {
    let mut client = Client::new(SimulatedSensor::new([9; 8]));
    let info = client.handshake().unwrap();
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(info.board_id, [9; 8]);
    client.request(Request::SetHostTimeout(0)).unwrap(); // this host stays silent
    client.request(Request::SetMode(Mode::Gradient)).unwrap();
    client.request(Request::Start).unwrap();
    client.transport_mut().advance_to(10_100_000);
    let phases: Vec<PhaseEvent> = client
        .poll_events()
        .unwrap()
        .into_iter()
        .filter_map(|(_, e)| match e {
            Event::Phase(p) => Some(p),
            _ => None,
        })
        .collect();
    assert_eq!(phases.len(), 41, "phases at 2 ms + k * 250 ms up to 10.1 s");
    for (k, p) in phases.iter().enumerate() {
        assert_eq!(p.phase, if k % 2 == 0 { Phase::Dx } else { Phase::Dy });
        let TriggerOutcome::Fired { index, edge_us } = p.trigger else {
            panic!("overrun")
        };
        assert_eq!(index as usize, k);
        assert_eq!(edge_us, 2000 + 250_000 * k as u64 + 1880);
    }
    assert_eq!(client.lost_events(), 0);
}

#[test]
fn a_silent_host_gets_the_leds_switched_off_with_a_fault() {
    let mut client = Client::new(SimulatedSensor::new([9; 8]));
    client.request(Request::SetMode(Mode::Gradient)).unwrap();
    client.request(Request::Start).unwrap();
    client.transport_mut().advance_to(10_000_000);
    let events = client.poll_events().unwrap();
    let phases = events
        .iter()
        .filter(|(_, e)| matches!(e, Event::Phase(_)))
        .count();
    let faults: Vec<_> = events
        .iter()
        .filter_map(|(_, e)| match e {
            Event::Fault(f) => Some(*f),
            _ => None,
        })
        .collect();
    assert_eq!(phases, 20, "phases before the 5 s timeout");
    assert_eq!(
        faults,
        [Fault {
            at_us: 5_000_000,
            kind: FaultKind::HostTimeout
        }]
    );
}

#[test]
fn device_errors_reach_the_host_typed() {
    let mut client = Client::new(SimulatedSensor::new([0; 8]));
    match client.request(Request::Start) {
        Err(ClientError::Device(DeviceError::InvalidState)) => {}
        other => panic!("{other:?}"),
    }
    match client.request(Request::SetLedCount(1000)) {
        Err(ClientError::Device(DeviceError::InvalidValue(Field::LedCount))) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_host_that_does_not_read_loses_events_visibly() {
    let mut client = Client::new(SimulatedSensor::new([0; 8]));
    client.request(Request::SetMode(Mode::Vision)).unwrap();
    client.request(Request::Start).unwrap();
    client.poll_events().unwrap();
    client.transport_mut().set_event_queue_limit(Some(16));
    client.transport_mut().advance_to(20_000_000); // ~80 phases + 20 heartbeats, queue holds 16
    let events = client.poll_events().unwrap();
    assert_eq!(events.len(), 16);
    client.transport_mut().advance_to(20_300_000);
    client.poll_events().unwrap();
    let Response::Status(status) = client.request(Request::GetStatus).unwrap() else {
        panic!()
    };
    assert!(status.events_dropped > 50, "{status:?}");
    assert_eq!(client.lost_events(), u64::from(status.events_dropped));
}

/// A device that answers GetInfo as a future protocol version would.
struct FutureDevice {
    pending: Vec<u8>,
}

impl Transport for FutureDevice {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        let mut decoder = FrameDecoder::<MAX_FRAME>::new();
        let (frame, _) = decoder.feed(bytes);
        let request: HostMessage = decode(frame.unwrap().unwrap()).unwrap();
        // Stable prefix: Reply(0), id, Ok(0), Info(0), protocol_version 7, then a new layout.
        // postcard writes a tuple as its fields in order, so this is exactly that payload.
        let reply = (0u32, request.id, 0u32, 0u32, 7u16, [0xAAu8; 30]);
        let mut buf = [0u8; MAX_FRAME];
        self.pending
            .extend_from_slice(encode(&reply, &mut buf).unwrap());
        Ok(())
    }

    fn receive(&mut self, _: Duration) -> Result<Vec<u8>, TransportError> {
        Ok(std::mem::take(&mut self.pending))
    }
}

#[test]
fn version_mismatch_is_refused_naming_both_versions() {
    let mut client = Client::new(FutureDevice { pending: vec![] });
    let err = client.handshake().unwrap_err();
    assert!(
        matches!(
            err,
            ClientError::VersionMismatch {
                host: PROTOCOL_VERSION,
                device: 7
            }
        ),
        "{err:?}"
    );
    let text = err.to_string();
    let host = format!("v{PROTOCOL_VERSION}");
    assert!(text.contains(&host) && text.contains("v7"), "{text}");
}
