//! A protocol client over any [`Transport`]: numbered requests matched to their replies,
//! the version-checked handshake, time-sync pings, and events with loss detection.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use stereotac_protocol::{
    DeviceError, DeviceInfo, DeviceMessage, Event, FrameDecoder, HostMessage, MAX_FRAME,
    PROTOCOL_VERSION, Request, RequestId, Response, decode, encode, peek_protocol_version,
};

use crate::clock::{HostClock, HostMicros, MonotonicClock, TimeSample};
use crate::transport::{Transport, TransportError};

/// Why a request failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The transport failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The device refused the request.
    #[error("device refused the request: {0}")]
    Device(DeviceError),
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

impl From<DeviceError> for ClientError {
    fn from(e: DeviceError) -> Self {
        Self::Device(e)
    }
}

/// What the host counted on a link; kept across reconnects by [`crate::device::Sensor`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkCounters {
    /// Events received.
    pub events: u64,
    /// Events lost (gaps in the device's event sequence numbers).
    pub lost_events: u64,
    /// Frames that failed their checksum or did not decode.
    pub bad_frames: u64,
    /// Requests that got no reply in time.
    pub timeouts: u64,
}

/// A protocol session over a [`Transport`].
#[derive(Debug)]
pub struct Client<T> {
    transport: T,
    clock: Arc<dyn HostClock>,
    decoder: FrameDecoder,
    next_id: RequestId,
    events: VecDeque<(u32, Event)>,
    last_event_seq: Option<u32>,
    counters: LinkCounters,
    timeout: Duration,
}

impl<T: Transport> Client<T> {
    /// A client on the system's monotonic clock with a 1 s reply timeout.
    pub fn new(transport: T) -> Self {
        Self::with_clock(transport, Arc::new(MonotonicClock::new()))
    }

    /// A client whose timestamps and timeouts use `clock`.
    pub fn with_clock(transport: T, clock: Arc<dyn HostClock>) -> Self {
        Self {
            transport,
            clock,
            decoder: FrameDecoder::new(),
            next_id: 1,
            events: VecDeque::new(),
            last_event_seq: None,
            counters: LinkCounters::default(),
            timeout: Duration::from_secs(1),
        }
    }

    /// Change the reply timeout.
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// The transport, e.g. to advance a simulated device's clock.
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    /// The host clock.
    pub fn clock(&self) -> &Arc<dyn HostClock> {
        &self.clock
    }

    /// Host time now.
    pub fn now_us(&self) -> HostMicros {
        self.clock.now_us()
    }

    /// What this client counted.
    pub fn counters(&self) -> LinkCounters {
        self.counters
    }

    /// Continue counting from `counters` (after a reconnect).
    pub fn set_counters(&mut self, counters: LinkCounters) {
        self.counters = counters;
    }

    /// Events lost so far (gaps in the device's event sequence numbers).
    pub fn lost_events(&self) -> u64 {
        self.counters.lost_events
    }

    /// Frames that failed their checksum or did not decode.
    pub fn bad_frames(&self) -> u64 {
        self.counters.bad_frames
    }

    /// One clock-sync ping: host time before sending, the device's clock, host time
    /// after the reply.
    pub fn time_sync(&mut self) -> Result<TimeSample, ClientError> {
        let host_send_us = self.clock.now_us();
        let reply = self.request(Request::TimeSync)?;
        let host_recv_us = self.clock.now_us();
        match reply {
            Response::Time(device_us) => Ok(TimeSample {
                host_send_us,
                device_us,
                host_recv_us,
            }),
            other => Err(ClientError::UnexpectedReply(Box::new(other))),
        }
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
            .map_err(|e| TransportError::Io(e.to_string()))?;
        self.transport.send(frame)?;
        let deadline = self.clock.now_us() + self.timeout.as_micros() as u64;
        loop {
            let left = deadline.saturating_sub(self.clock.now_us());
            let bytes = self.transport.receive(Duration::from_micros(left))?;
            if let Some(result) = self.ingest(&bytes, Some(id))? {
                return result.map_err(ClientError::Device);
            }
            if self.clock.now_us() >= deadline {
                self.counters.timeouts += 1;
                return Err(ClientError::Timeout(self.timeout));
            }
        }
    }

    /// Read what the device sent and return the events received so far.
    pub fn poll_events(&mut self) -> Result<Vec<(u32, Event)>, ClientError> {
        self.wait_events(Duration::ZERO)
    }

    /// Wait at most `timeout` for the device to send something; return the events
    /// received so far.
    pub fn wait_events(&mut self, timeout: Duration) -> Result<Vec<(u32, Event)>, ClientError> {
        let bytes = self.transport.receive(timeout)?;
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
                self.counters.bad_frames += 1;
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
                    self.counters.bad_frames += 1;
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
                            self.counters.lost_events += u64::from(gap);
                        }
                    }
                    self.last_event_seq = Some(seq);
                    self.counters.events += 1;
                    self.events.push_back((seq, event));
                }
            }
        }
        Ok(reply)
    }
}
