//! A host's byte stream into the firmware's controller: each input byte pair is a time
//! step and a chunk length, the rest arbitrary bytes; every payload is also framed with a
//! valid checksum so requests of any shape reach the command handler. Between chunks
//! the device's phase loop runs (plan, begin, finish) as the board's main loop does.
//! Checked: no panic; every reply is to a request; the LED current never exceeds the
//! budget; a running device has a mode that shows something.
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereotac_firmware::{Controller, Identity, MAX_LEDS_PER_STRIP};
use stereotac_protocol::{
    Capabilities, DeviceMessage, FrameDecoder, MAX_FRAME, MAX_PAYLOAD, Mode, encode_payload,
};

fuzz_target!(|data: &[u8]| {
    let mut c = Controller::new(
        Identity {
            board_id: [1; 8],
            capabilities: Capabilities(Capabilities::HARDWARE_TRIGGER),
        },
        MAX_LEDS_PER_STRIP,
    );
    let mut decoder = FrameDecoder::<MAX_FRAME>::new();
    let mut now = 0u64;
    let mut rest = data;
    while let [step, len, tail @ ..] = rest {
        now += u64::from(*step) * 997;
        let n = usize::from(*len).min(tail.len());
        let (chunk, after) = tail.split_at(n);
        rest = after;
        // The chunk as raw wire bytes...
        let mut input = chunk;
        while !input.is_empty() {
            let (frame, left) = decoder.feed(input);
            input = left;
            if let Some(frame) = frame {
                let (reply, _) = c.handle_frame(frame, now);
                assert!(matches!(reply, DeviceMessage::Reply { .. } | DeviceMessage::Event { .. }));
            }
        }
        // ...and as a payload that passes the checksum.
        if (1..=MAX_PAYLOAD).contains(&chunk.len()) {
            let mut buf = [0u8; MAX_FRAME];
            let frame = encode_payload(chunk, &mut buf).expect("fits").to_vec();
            let mut framed = FrameDecoder::<MAX_FRAME>::new();
            if let (Some(Ok(payload)), _) = framed.feed(&frame) {
                let (reply, _) = c.handle_frame(Ok(payload), now);
                assert!(matches!(reply, DeviceMessage::Reply { .. }));
            }
        }
        let _ = c.check_host_timeout(now);
        // The board's loop: at a phase's start, begin it, write the LEDs (they latch
        // 30 µs later) and decide its trigger; time only moves forward.
        if let Some(plan) = c.plan(now).filter(|p| p.start_us <= now) {
            let frame = c.frame(plan.phase);
            assert!(frame.current_ua() <= u64::from(c.config().power_budget_ma) * 1000);
            c.begin(&plan);
            let _ = c.finish(&plan, now, now + 30, now + 40);
            now += 40;
        }
        assert!(!c.is_running() || c.config().mode != Mode::Off);
    }
});
