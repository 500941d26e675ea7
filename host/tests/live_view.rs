//! The live view speaks Foxglove's WebSocket protocol: a client (a bare WebSocket over
//! a TCP socket here, as Foxglove's app is one) gets the server's info, the channel
//! advertisements, and after subscribing, the messages the recorder is handed.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use stereotac::recording::messages::PhaseInfo;
use stereotac::recording::writer::{Item, Recorder, RecorderOptions};

/// One WebSocket frame from the server: (opcode, payload). Server frames are unmasked.
fn read_frame(s: &mut TcpStream) -> std::io::Result<(u8, Vec<u8>)> {
    let mut head = [0u8; 2];
    s.read_exact(&mut head)?;
    let mut len = u64::from(head[1] & 0x7f);
    if len == 126 {
        let mut b = [0u8; 2];
        s.read_exact(&mut b)?;
        len = u64::from(u16::from_be_bytes(b));
    } else if len == 127 {
        let mut b = [0u8; 8];
        s.read_exact(&mut b)?;
        len = u64::from_be_bytes(b);
    }
    let mut payload = vec![0u8; len as usize];
    s.read_exact(&mut payload)?;
    Ok((head[0] & 0x0f, payload))
}

/// A masked text frame from the client.
fn write_text(s: &mut TcpStream, text: &str) {
    let data = text.as_bytes();
    assert!(data.len() < 126);
    let mask = [0x12u8, 0x34, 0x56, 0x78];
    let mut frame = vec![0x81, 0x80 | data.len() as u8];
    frame.extend_from_slice(&mask);
    frame.extend(data.iter().enumerate().map(|(i, b)| b ^ mask[i % 4]));
    s.write_all(&frame).unwrap();
}

fn phase(index: u32) -> Item {
    Item::Phase(PhaseInfo {
        index,
        phase: "dx".into(),
        write_start_us: 1000.0 * f64::from(index),
        latched_us: 1000.0 * f64::from(index) + 1280.0,
        trigger: Some(index),
        trigger_us: Some(1000.0 * f64::from(index) + 1900.0),
        uncertainty_us: 3.0,
    })
}

#[test]
fn a_foxglove_client_sees_the_channels_and_gets_the_messages_it_subscribes_to() {
    let recorder = Recorder::start(RecorderOptions {
        mcap: None,
        live_view: Some("127.0.0.1:0".into()),
        queue: 16,
        wait_when_full: true,
        clock_origin_unix_ns: 1_700_000_000_000_000_000,
    })
    .expect("live view starts");
    let port = recorder.live_port().expect("a port");
    assert!(
        recorder.send(phase(0)),
        "the channel exists once a message went out"
    );
    std::thread::sleep(Duration::from_millis(100));

    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    )
    .unwrap();
    let mut response = Vec::new();
    while !response.ends_with(b"\r\n\r\n") {
        let mut b = [0u8; 1];
        s.read_exact(&mut b).unwrap();
        response.push(b[0]);
    }
    let response = String::from_utf8_lossy(&response);
    assert!(response.starts_with("HTTP/1.1 101"), "{response}");

    // serverInfo, then the advertisement of /stereotac/leds/phase with its schema.
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut channel_id = None;
    let mut server_name = None;
    while channel_id.is_none() && Instant::now() < deadline {
        let (op, payload) = read_frame(&mut s).unwrap();
        if op != 1 {
            continue;
        }
        let msg: serde_json::Value = serde_json::from_slice(&payload).unwrap();
        match msg["op"].as_str() {
            Some("serverInfo") => server_name = msg["name"].as_str().map(str::to_string),
            Some("advertise") => {
                for c in msg["channels"].as_array().unwrap() {
                    if c["topic"] == "/stereotac/leds/phase" {
                        assert_eq!(c["encoding"], "json", "{c}");
                        assert_eq!(c["schemaName"], "stereotac.PhaseInfo", "{c}");
                        channel_id = c["id"].as_u64();
                    }
                }
            }
            _ => {}
        }
    }
    assert_eq!(server_name.as_deref(), Some("stereotac"));
    let channel_id = channel_id.expect("the phase channel is advertised");

    write_text(
        &mut s,
        &format!(r#"{{"op":"subscribe","subscriptions":[{{"id":7,"channelId":{channel_id}}}]}}"#),
    );
    std::thread::sleep(Duration::from_millis(100));
    assert!(recorder.send(phase(42)));
    // messageData: opcode byte 1, subscription id (u32 LE), log time (u64 LE), payload.
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut got = None;
    while got.is_none() && Instant::now() < deadline {
        let (op, payload) = read_frame(&mut s).unwrap();
        if op == 2 && payload.first() == Some(&1) {
            let sub = u32::from_le_bytes(payload[1..5].try_into().unwrap());
            let log_time = u64::from_le_bytes(payload[5..13].try_into().unwrap());
            got = Some((sub, log_time, payload[13..].to_vec()));
        }
    }
    let (sub, log_time, data) = got.expect("a message after subscribing");
    assert_eq!(sub, 7);
    assert_eq!(
        log_time,
        1_700_000_000_000_000_000 + 42_000_000,
        "host µs on the epoch"
    );
    let info: serde_json::Value = serde_json::from_slice(&data).unwrap();
    assert_eq!(info["index"], 42);
    recorder.finish().unwrap();
}
