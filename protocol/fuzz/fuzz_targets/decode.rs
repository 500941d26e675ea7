//! Arbitrary bytes, in arbitrary chunks, through the frame decoder and the message
//! decoders: must never panic, and every accepted payload fits the documented maximum.
//! The same bytes also go straight to the message decoders as a payload (random frames
//! almost never pass the checksum, so without this the decoders would rarely be reached).
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereotac_protocol::{DeviceMessage, FrameDecoder, HostMessage, MAX_FRAME, decode};

fuzz_target!(|data: &[u8]| {
    let _ = decode::<HostMessage>(data);
    let _ = decode::<DeviceMessage>(data);
    let Some((&chunk, bytes)) = data.split_first() else { return };
    let chunk = usize::from(chunk).max(1);
    let mut decoder = FrameDecoder::<MAX_FRAME>::new();
    for piece in bytes.chunks(chunk) {
        let mut input = piece;
        while !input.is_empty() {
            let (frame, rest) = decoder.feed(input);
            input = rest;
            if let Some(Ok(payload)) = frame {
                assert!(payload.len() <= MAX_FRAME);
                let _ = decode::<HostMessage>(payload);
                let _ = decode::<DeviceMessage>(payload);
            }
        }
    }
});
