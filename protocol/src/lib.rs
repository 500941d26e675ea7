//! # stereotac-protocol
//!
//! Every message between the stereotac sensor firmware (RP2040) and the host, defined
//! once and shared by both sides: serde types encoded with postcard, carried in
//! CRC-checked COBS frames. `no_std`, no allocation.
//!
//! ## Wire format
//!
//! * **Frame**: `cobs(payload ++ crc32c_le(payload)) ++ 0x00`. At most [`MAX_FRAME`] bytes
//!   on the wire, payload at most [`MAX_PAYLOAD`] bytes. See [`frame`].
//! * **Payload**: postcard encoding of [`HostMessage`] (host → device) or
//!   [`DeviceMessage`] (device → host). postcard writes integers as LEB128 varints,
//!   enum variants as a varint index, structs as their fields in order.
//! * **Requests** carry a [`RequestId`]; the device answers every intact request with
//!   exactly one [`DeviceMessage::Reply`] carrying the same id: a [`Response`] or a
//!   [`DeviceError`]. A frame whose checksum fails is dropped (its id cannot be trusted)
//!   and reported as a [`FaultKind::CorruptFrame`] event.
//! * **Events** ([`DeviceMessage::Event`]) carry a sequence number that increases by
//!   one per event produced, so dropped events show as gaps.
//! * **Handshake**: the host sends [`Request::GetInfo`] and checks
//!   [`DeviceInfo::protocol_version`] against [`PROTOCOL_VERSION`]; the version can be
//!   read from any protocol version's answer with [`peek_protocol_version`].
//! * **Time**: every timestamp is in microseconds of the device's 1 MHz timer since boot.
//!
//! Any change to the bytes on the wire shows up as a diff of the golden vectors in
//! `tests/golden_vectors.txt`; such a change must bump [`PROTOCOL_VERSION`].
#![cfg_attr(not(any(test, feature = "arbitrary")), no_std)]
#![warn(missing_docs)]

pub mod frame;
mod messages;

pub use frame::{
    DecodeError, EncodeError, FrameDecoder, FrameError, MAX_FRAME, MAX_PAYLOAD, decode, encode,
    encode_payload, peek_protocol_version, peek_request_id,
};
pub use messages::*;
pub use postcard::experimental::max_size::MaxSize;

/// Version of this wire protocol. A host refuses a device with another version.
pub const PROTOCOL_VERSION: u16 = 3;

/// USB vendor id of the sensor (pid.codes open-source VID).
pub const USB_VID: u16 = 0x1209;
/// USB product id of the sensor (in the pid.codes test range until one is assigned).
pub const USB_PID: u16 = 0x0001;
/// USB vendor-class interface subclass identifying the stereotac link.
pub const USB_SUBCLASS: u8 = 0x53;
/// USB vendor-class interface protocol number (follows [`PROTOCOL_VERSION`]'s major line).
pub const USB_PROTOCOL: u8 = 0x01;

#[cfg(test)]
mod tests;
