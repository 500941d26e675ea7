//! Framing: postcard payload + CRC-32C, COBS-encoded, terminated by a zero byte.
//!
//! ```text
//! frame   = cobs(payload ++ crc32c_le(payload)) ++ [0x00]
//! payload = postcard(HostMessage | DeviceMessage)
//! ```
//!
//! The encoder is postcard's own flavour stack (`CrcModifier` over `Cobs` over a slice).
//! The decoder is a small streaming state machine: it accepts bytes in chunks of any
//! size (USB full-speed bulk packets are 64 bytes), hands out each checked payload,
//! and resynchronises on the next zero byte after garbage, a corrupt frame or an
//! oversize one, reporting each as a typed [`FrameError`].

use crc::{CRC_32_ISCSI, Crc};
use postcard::ser_flavors::{Cobs, Slice, crc::CrcModifier};
use serde::{Deserialize, Serialize};

use crate::{DeviceMessage, HostMessage, MaxSize};

/// The checksum: CRC-32C (Castagnoli, as in iSCSI), appended little-endian.
pub static CRC32C: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// Bytes of checksum after the payload.
pub const CRC_LEN: usize = 4;

/// Largest postcard payload of any message in either direction (checked at compile time
/// against every message's worst-case encoded size).
pub const MAX_PAYLOAD: usize = 120;

/// Largest encoded frame on the wire, including the COBS overhead and the zero delimiter.
/// A receiver with a buffer of this size never rejects a valid frame.
pub const MAX_FRAME: usize = cobs_max_encoded_len(MAX_PAYLOAD + CRC_LEN) + 1;

/// Worst-case length of COBS-encoding `n` bytes (one overhead byte per 254, at least one).
pub const fn cobs_max_encoded_len(n: usize) -> usize {
    n + n / 254 + 1
}

const _: () = {
    assert!(HostMessage::POSTCARD_MAX_SIZE <= MAX_PAYLOAD);
    assert!(DeviceMessage::POSTCARD_MAX_SIZE <= MAX_PAYLOAD);
};

/// Why a frame could not be produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The output buffer is smaller than the encoded frame.
    #[error("output buffer too small for the frame")]
    BufferTooSmall,
    /// postcard refused the value (cannot happen for this crate's messages).
    #[error("message could not be serialised")]
    Serialize,
}

/// Why received bytes did not form a valid frame. The decoder has already resynchronised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// More than the decoder's capacity arrived before a delimiter; bytes up to the next
    /// delimiter were discarded.
    #[error("frame longer than the maximum frame size")]
    Oversize,
    /// The bytes between two delimiters are not valid COBS.
    #[error("frame is not valid COBS")]
    Cobs,
    /// The frame is too short to hold a checksum and a payload.
    #[error("frame too short")]
    TooShort,
    /// The checksum does not match: the frame was corrupted.
    #[error("frame checksum mismatch")]
    Crc,
}

/// Why a checked payload did not decode as a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// The payload is not a message of this protocol version.
    #[error("payload does not decode as a message of this protocol version")]
    Malformed,
    /// Bytes were left over after the message.
    #[error("trailing bytes after the message")]
    TrailingBytes,
}

/// Encode `message` as one complete frame (delimiter included) into `out`; returns the
/// frame, a prefix of `out`. `out` of [`MAX_FRAME`] bytes always suffices.
pub fn encode<'a, T: Serialize>(
    message: &T,
    out: &'a mut [u8],
) -> Result<&'a mut [u8], EncodeError> {
    let flavor = CrcModifier::new(
        Cobs::try_new(Slice::new(out)).map_err(|_| EncodeError::BufferTooSmall)?,
        CRC32C.digest(),
    );
    postcard::serialize_with_flavor::<T, _, _>(message, flavor).map_err(|e| match e {
        postcard::Error::SerializeBufferFull => EncodeError::BufferTooSmall,
        _ => EncodeError::Serialize,
    })
}

/// Frame raw payload bytes (checksum, COBS, delimiter) as [`encode`] frames a message:
/// how tests and fuzzers put arbitrary payloads past the checksum and into the message
/// decoders. `out` of [`MAX_FRAME`] bytes suffices for payloads up to [`MAX_PAYLOAD`].
pub fn encode_payload<'a>(payload: &[u8], out: &'a mut [u8]) -> Result<&'a mut [u8], EncodeError> {
    use postcard::ser_flavors::Flavor;
    let mut flavor = CrcModifier::new(
        Cobs::try_new(Slice::new(out)).map_err(|_| EncodeError::BufferTooSmall)?,
        CRC32C.digest(),
    );
    flavor
        .try_extend(payload)
        .map_err(|_| EncodeError::BufferTooSmall)?;
    flavor.finalize().map_err(|_| EncodeError::BufferTooSmall)
}

/// Decode a checked payload (from [`FrameDecoder`]) as a message of type `T`.
pub fn decode<'de, T: Deserialize<'de>>(payload: &'de [u8]) -> Result<T, DecodeError> {
    let (message, rest) = postcard::take_from_bytes(payload).map_err(|_| DecodeError::Malformed)?;
    if rest.is_empty() {
        Ok(message)
    } else {
        Err(DecodeError::TrailingBytes)
    }
}

/// Streaming frame decoder with a fixed buffer of `N` bytes (default [`MAX_FRAME`]).
///
/// Feed it bytes with [`FrameDecoder::feed`] until the input is used up. No allocation;
/// never panics, whatever the input.
#[derive(Debug, Clone)]
pub struct FrameDecoder<const N: usize = MAX_FRAME> {
    buf: [u8; N],
    len: usize,
    overflowed: bool,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            overflowed: false,
        }
    }

    /// Bytes of a partial frame waiting for their delimiter.
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Drop any partial frame (e.g. after a reconnect).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Consume bytes from `input` up to and including the next frame delimiter.
    ///
    /// Returns what that delimiter closed, if anything (a checked payload, or the error of
    /// a bad frame), and the input not yet consumed; call again with the rest until it is
    /// empty. Empty frames (two delimiters in a row) are skipped silently: senders may
    /// emit a leading delimiter to flush garbage on the line.
    pub fn feed<'i>(&mut self, input: &'i [u8]) -> (Option<Result<&[u8], FrameError>>, &'i [u8]) {
        let mut consumed = 0;
        for &byte in input {
            consumed += 1;
            if byte != 0 {
                if self.overflowed {
                    continue;
                }
                if self.len == N {
                    self.overflowed = true;
                    continue;
                }
                self.buf[self.len] = byte;
                self.len += 1;
                continue;
            }
            // Delimiter.
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overflowed) {
                return (Some(Err(FrameError::Oversize)), &input[consumed..]);
            }
            if len == 0 {
                continue;
            }
            return (Some(self.check(len)), &input[consumed..]);
        }
        (None, &input[consumed..])
    }

    fn check(&mut self, len: usize) -> Result<&[u8], FrameError> {
        let decoded = cobs::decode_in_place(&mut self.buf[..len]).map_err(|_| FrameError::Cobs)?;
        if decoded <= CRC_LEN {
            return Err(FrameError::TooShort);
        }
        let (payload, crc) = self.buf[..decoded].split_at(decoded - CRC_LEN);
        let expected = CRC32C.checksum(payload).to_le_bytes();
        if crc != expected {
            return Err(FrameError::Crc);
        }
        Ok(payload)
    }
}

/// The request id of a host payload whose body may not decode (so a device can still
/// answer a malformed request with an error carrying the right id).
pub fn peek_request_id(payload: &[u8]) -> Option<crate::RequestId> {
    postcard::take_from_bytes::<crate::RequestId>(payload)
        .ok()
        .map(|(id, _)| id)
}

/// The protocol version in a device payload that answers `GetInfo`, read from the
/// stable prefix only, so it works even when the rest is of another protocol version.
/// Returns the request id and the version.
pub fn peek_protocol_version(payload: &[u8]) -> Option<(crate::RequestId, u16)> {
    let (tag, rest) = postcard::take_from_bytes::<u32>(payload).ok()?; // DeviceMessage::Reply
    let (id, rest) = postcard::take_from_bytes::<crate::RequestId>(rest).ok()?;
    let (ok, rest) = postcard::take_from_bytes::<u32>(rest).ok()?; // Result::Ok
    let (info, rest) = postcard::take_from_bytes::<u32>(rest).ok()?; // Response::Info
    let (version, _) = postcard::take_from_bytes::<u16>(rest).ok()?;
    (tag == 0 && ok == 0 && info == 0).then_some((id, version))
}
