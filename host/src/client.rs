//! A protocol client over any byte link: numbered requests matched to their replies,
//! the version-checked handshake, and events with loss detection.
//!
//! [`Link`] is deliberately small (send bytes, receive bytes) so that the in-memory
//! simulated sensor, USB and the emulated RP2040 can all sit behind it.

use std::collections::VecDeque;
use std::time::Duration;

use stereotac_protocol::{
    DeviceError, DeviceInfo, DeviceMessage, Event, FrameDecoder, HostMessage, MAX_FRAME,
    PROTOCOL_VERSION, Request, RequestId, Response, decode, encode, peek_protocol_version,
};

use crate::sim::SimulatedSensor;

/// Why the link failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The device went away.
    #[error("device disconnected")]
    Disconnected,
    /// Another I/O failure.
    #[error("link I/O error: {0}")]
    Io(String),
}

/// A byte pipe to a device.
pub trait Link {
    /// Send bytes to the device.
    fn send(&mut self, bytes: &[u8]) -> Result<(), LinkError>;
    /// Bytes the device sent, waiting at most `timeout` for the first; may be empty.
    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, LinkError>;
}

/// The simulated sensor is a link whose device time stands still while the host talks.
impl Link for SimulatedSensor {
    fn send(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.write(bytes);
        Ok(())
    }

    fn receive(&mut self, _timeout: Duration) -> Result<Vec<u8>, LinkError> {
        Ok(self.read())
    }
}

/// Why a request failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The link failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The device refused the request.
    #[error("device refused the request: {0}")]
    Device(#[from] DeviceError),
    /// The device speaks another protocol version.
    #[error(
        "protocol version mismatch: this host speaks v{host}, the device speaks v{device}; \
         update the {} ",
        if device < host { "firmware (stereotac flash)" } else { "host software" }
    )]
    VersionMismatch {
        /// The host's version.
        host: u16,
        /// The device's version.
        device: u16,
    },
    /// No reply within the timeout.
    #[error("no reply from the device within {0:?}")]
    Timeout(Duration),
    /// A reply of the wrong kind.
    #[error("unexpected reply: {0:?}")]
    UnexpectedReply(Box<Response>),
}

/// A protocol session over a [`Link`].
#[derive(Debug)]
pub struct Client<L> {
    link: L,
    decoder: FrameDecoder,
    next_id: RequestId,
    events: VecDeque<(u32, Event)>,
    last_event_seq: Option<u32>,
    lost_events: u64,
    bad_frames: u64,
    timeout: Duration,
}

impl<L: Link> Client<L> {
    /// A client with a 1 s reply timeout.
    pub fn new(link: L) -> Self {
        Self {
            link,
            decoder: FrameDecoder::new(),
            next_id: 1,
            events: VecDeque::new(),
            last_event_seq: None,
            lost_events: 0,
            bad_frames: 0,
            timeout: Duration::from_secs(1),
        }
    }

    /// The link, e.g. to advance a simulated device's clock.
    pub fn link_mut(&mut self) -> &mut L {
        &mut self.link
    }

    /// Events lost so far (gaps in the device's event sequence numbers).
    pub fn lost_events(&self) -> u64 {
        self.lost_events
    }

    /// Frames that failed their checksum or did not decode.
    pub fn bad_frames(&self) -> u64 {
        self.bad_frames
    }

    /// Handshake: read the device's info and refuse another protocol version.
    pub fn handshake(&mut self) -> Result<DeviceInfo, ClientError> {
        match self.request(Request::GetInfo)? {
            Response::Info(info) => Ok(info),
            other => Err(ClientError::UnexpectedReply(Box::new(other))),
        }
    }

    /// Send `request` and wait for its reply; events arriving meanwhile are kept.
    pub fn request(&mut self, request: Request) -> Result<Response, ClientError> {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        let mut buf = [0u8; MAX_FRAME];
        let frame = encode(&HostMessage { id, request }, &mut buf)
            .map_err(|e| LinkError::Io(e.to_string()))?;
        self.link.send(frame)?;
        let deadline = std::time::Instant::now() + self.timeout;
        loop {
            let bytes = self.link.receive(self.timeout)?;
            if let Some(result) = self.ingest(&bytes, Some(id))? {
                return result.map_err(ClientError::Device);
            }
            if std::time::Instant::now() >= deadline {
                return Err(ClientError::Timeout(self.timeout));
            }
        }
    }

    /// Read what the device sent and return the events received so far.
    pub fn poll_events(&mut self) -> Result<Vec<(u32, Event)>, ClientError> {
        let bytes = self.link.receive(Duration::ZERO)?;
        self.ingest(&bytes, None)?;
        Ok(self.events.drain(..).collect())
    }

    /// Decode bytes; keep events; return the reply to `want` if it arrived.
    fn ingest(
        &mut self,
        mut bytes: &[u8],
        want: Option<RequestId>,
    ) -> Result<Option<Result<Response, DeviceError>>, ClientError> {
        let mut reply = None;
        while !bytes.is_empty() {
            let (frame, rest) = self.decoder.feed(bytes);
            bytes = rest;
            let Some(frame) = frame else { continue };
            let Ok(payload) = frame else {
                self.bad_frames += 1;
                continue;
            };
            let message = match decode::<DeviceMessage>(payload) {
                Ok(m) => m,
                Err(_) => {
                    // A handshake reply of another protocol version still names it.
                    if let Some((id, device)) = peek_protocol_version(payload)
                        && Some(id) == want
                    {
                        return Err(ClientError::VersionMismatch {
                            host: PROTOCOL_VERSION,
                            device,
                        });
                    }
                    self.bad_frames += 1;
                    continue;
                }
            };
            match message {
                DeviceMessage::Reply { id, result } if Some(id) == want => {
                    if let Ok(Response::Info(info)) = &result
                        && info.protocol_version != PROTOCOL_VERSION
                    {
                        return Err(ClientError::VersionMismatch {
                            host: PROTOCOL_VERSION,
                            device: info.protocol_version,
                        });
                    }
                    reply = Some(result);
                }
                DeviceMessage::Reply { .. } => {} // a stale reply to a timed-out request
                DeviceMessage::Event { seq, event } => {
                    if let Some(last) = self.last_event_seq {
                        // A backwards jump is a device restart, not a loss.
                        let gap = seq.wrapping_sub(last).wrapping_sub(1);
                        if gap < u32::MAX / 2 {
                            self.lost_events += u64::from(gap);
                        }
                    }
                    self.last_event_seq = Some(seq);
                    self.events.push_back((seq, event));
                }
            }
        }
        Ok(reply)
    }
}
