//! A connected sensor: handshake, clock sync, events on the host clock, and reconnection.
//!
//! [`Sensor`] wraps a [`Client`] over any transport. It keeps the device's clock mapped
//! onto the host's ([`ClockSync`], pinged every [`SensorConfig::sync_interval`]), turns
//! phase events into [`HostPhase`]s with host timestamps, and when the transport reports
//! a disconnect it reconnects with exponential backoff: same board (checked by id),
//! counters carried over, the configuration the host set replayed, and the sequence
//! restarted if it was running.

use std::sync::Arc;
use std::time::Duration;

use stereotac_protocol::{
    Config, DeviceInfo, DeviceMicros, Event, Fault, Mode, PhaseEvent, ProbeEvent, Request,
    Response, Status, Timing, TriggerOutcome,
};

use crate::client::{Client, ClientError, LinkCounters};
use crate::clock::{ClockFit, ClockSync, HostClock, HostMicros};
use crate::transport::{BoxedTransport, Connector, OpenError, Transport, TransportError};

/// Pings start at a random delay below this (one USB full-speed frame), µs.
const PING_DITHER_US: u64 = 1000;

/// Why a sensor operation failed.
#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    /// The sensor could not be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// The protocol exchange failed.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// Reconnecting failed for the whole reconnect period.
    #[error(
        "the sensor disconnected and did not come back within {waited:?} ({attempts} attempts; last: {last})"
    )]
    ReconnectFailed {
        /// Attempts made.
        attempts: u32,
        /// Time spent.
        waited: Duration,
        /// The last attempt's error.
        last: String,
    },
    /// After a reconnect another board answered.
    #[error("reconnected to another board ({found}) than before ({expected})")]
    DifferentBoard {
        /// Board id before.
        expected: String,
        /// Board id now.
        found: String,
    },
}

/// Settings of a [`Sensor`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorConfig {
    /// Time-sync ping period.
    pub sync_interval: Duration,
    /// Pings right after connecting.
    pub initial_pings: u32,
    /// Until the clock-sync window holds this many pings, ping every `settle_interval`.
    pub settle_pings: usize,
    /// Ping period while settling.
    pub settle_interval: Duration,
    /// First reconnect delay; doubles per attempt.
    pub backoff_initial: Duration,
    /// Longest reconnect delay.
    pub backoff_max: Duration,
    /// Give up reconnecting after this long.
    pub reconnect_for: Duration,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            sync_interval: Duration::from_millis(200),
            initial_pings: 16,
            settle_pings: 100,
            settle_interval: Duration::from_millis(20),
            backoff_initial: Duration::from_millis(50),
            backoff_max: Duration::from_secs(2),
            reconnect_for: Duration::from_secs(30),
        }
    }
}

/// A phase event with its times on the host clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HostPhase {
    /// The device's event.
    pub event: PhaseEvent,
    /// LED write start, host µs.
    pub write_start_us: f64,
    /// LED latch, host µs.
    pub latched_us: f64,
    /// Trigger index and rising edge on the host clock.
    pub trigger: Option<(u32, f64)>,
    /// Clock-sync uncertainty when mapped, µs.
    pub uncertainty_us: f64,
}

impl HostPhase {
    /// `event` with its device times put on the host clock by `map`.
    pub fn map(event: PhaseEvent, map: impl Fn(DeviceMicros) -> f64, uncertainty_us: f64) -> Self {
        Self {
            event,
            write_start_us: map(event.write_start_us),
            latched_us: map(event.latched_us),
            trigger: match event.trigger {
                TriggerOutcome::Fired { index, edge_us } => Some((index, map(edge_us))),
                TriggerOutcome::Overrun { .. } => None,
            },
            uncertainty_us,
        }
    }
}

/// Something the sensor reported, with host times where it carries device times.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEvent {
    /// A phase of the sequence.
    Phase(HostPhase),
    /// A periodic status.
    Heartbeat(Status),
    /// A fault, with its host time.
    Fault(Fault, f64),
    /// What the loopback probe saw (device time: it is checked against the device's
    /// own phase events).
    Probe(ProbeEvent),
    /// The link dropped and came back (after `attempts` tries).
    Reconnected {
        /// Attempts it took.
        attempts: u32,
    },
}

/// Host-side counters of a sensor session (kept across reconnects).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SessionCounters {
    /// What the link counted.
    pub link: LinkCounters,
    /// Reconnections.
    pub reconnects: u32,
    /// Time-sync pings answered.
    pub sync_pings: u64,
}

/// A connected sensor (see the module documentation).
pub struct Sensor {
    client: Client<BoxedTransport>,
    connector: Connector,
    config: SensorConfig,
    info: DeviceInfo,
    sync: ClockSync,
    /// Configuration requests the host made, replayed after a reconnect (last of each kind).
    applied: Vec<Request>,
    running: bool,
    reconnects: u32,
    sync_pings: u64,
    next_sync_us: HostMicros,
    dither: u64,
    pending: Vec<SensorEvent>,
}

impl std::fmt::Debug for Sensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sensor")
            .field("board_id", &serial_number(&self.info.board_id))
            .field("running", &self.running)
            .field("reconnects", &self.reconnects)
            .finish_non_exhaustive()
    }
}

/// The device's counters in one line, for logs and the CLI.
pub fn status_line(s: &Status) -> String {
    format!(
        "uptime {:.3} s, phases {}, triggers {}, overruns {}, events dropped {}, frames received {}, rejected {}, requests rejected {}, host timeouts {}",
        s.uptime_us as f64 / 1e6,
        s.phases,
        s.triggers,
        s.overruns,
        s.events_dropped,
        s.frames_received,
        s.frames_rejected,
        s.requests_rejected,
        s.host_timeouts
    )
}

/// Bytes as lower-case hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A board's serial number as its USB descriptor shows it: the board id in upper-case
/// hex (what `--serial` takes and `devices` lists).
pub fn serial_number(board_id: &[u8; 8]) -> String {
    hex(board_id).to_uppercase()
}

/// The firmware version and build of `info`: `MAJOR.MINOR.PATCH (githash10[+dirty])`.
pub fn firmware_version(info: &DeviceInfo) -> String {
    let v = info.firmware_version;
    format!(
        "{}.{}.{} ({}{})",
        v.major,
        v.minor,
        v.patch,
        &hex(&info.git_hash)[..10],
        if info.git_dirty { "+dirty" } else { "" }
    )
}

impl Sensor {
    /// Open through `connector`, handshake (refusing another protocol version) and
    /// synchronise the clocks.
    pub fn connect(
        mut connector: Connector,
        clock: Arc<dyn HostClock>,
        config: SensorConfig,
    ) -> Result<Self, SensorError> {
        let transport = connector.open()?;
        let mut client = Client::with_clock(transport, clock);
        let info = client.handshake()?;
        let mut sensor = Self {
            client,
            connector,
            config,
            info,
            sync: ClockSync::default(),
            applied: Vec::new(),
            running: false,
            reconnects: 0,
            sync_pings: 0,
            next_sync_us: 0,
            dither: 0x5EED,
            pending: Vec::new(),
        };
        sensor.sync_burst()?;
        Ok(sensor)
    }

    /// Handshake data.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// The host clock.
    pub fn clock(&self) -> &Arc<dyn HostClock> {
        self.client.clock()
    }

    /// Send `bytes` down the link exactly as given, not framed: for link tests that
    /// check how the firmware handles corrupt or oversize frames. Whatever the device
    /// answers arrives through [`Sensor::poll`] and the requests that follow.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), SensorError> {
        self.client
            .transport_mut()
            .send(bytes)
            .map_err(|e| SensorError::Client(e.into()))
    }

    /// The current device→host clock fit.
    pub fn clock_fit(&self) -> Option<&ClockFit> {
        self.sync.fit()
    }

    /// Host-side counters.
    pub fn counters(&self) -> SessionCounters {
        SessionCounters {
            link: self.client.counters(),
            reconnects: self.reconnects,
            sync_pings: self.sync_pings,
        }
    }

    /// Device time on the host clock (exact line; `None` before any sync).
    pub fn to_host(&self, d: DeviceMicros) -> Option<f64> {
        self.sync.to_host(d)
    }

    fn sync_burst(&mut self) -> Result<(), ClientError> {
        for _ in 0..self.config.initial_pings {
            self.ping()?;
        }
        Ok(())
    }

    fn ping(&mut self) -> Result<(), ClientError> {
        // Start each ping at a random point of the 1 ms USB frame: a ping sent right after
        // a reply arrives is always at the same frame phase, and never sees a fast request.
        self.dither = self
            .dither
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        let wait = (self.dither >> 33) % PING_DITHER_US;
        let clock = Arc::clone(self.client.clock());
        clock.sleep_until(clock.now_us() + wait);
        let sample = self.client.time_sync()?;
        self.sync.add(sample);
        self.sync_pings += 1;
        // Ping fast until the window holds enough pings to pin the drift down.
        let settled = self
            .sync
            .fit()
            .is_some_and(|f| f.samples >= self.config.settle_pings);
        let interval = if settled {
            self.config.sync_interval
        } else {
            self.config.settle_interval
        };
        self.next_sync_us = sample.host_recv_us + interval.as_micros() as u64;
        Ok(())
    }

    /// Send a request (reconnecting if the link dropped). Configuration requests are
    /// remembered and replayed after a reconnect.
    pub fn request(&mut self, request: Request) -> Result<Response, SensorError> {
        let response = self.with_reconnect(|s| s.client.request(request))?;
        self.remember(request);
        Ok(response)
    }

    fn remember(&mut self, request: Request) {
        match request {
            Request::Start => self.running = true,
            Request::Stop | Request::EnterBootloader => self.running = false,
            Request::SetMode(_)
            | Request::SetTiming(_)
            | Request::SetLedCount(_)
            | Request::SetPowerBudget(_)
            | Request::SetHostTimeout(_)
            | Request::SetProbe(_) => {
                let kind = std::mem::discriminant(&request);
                self.applied.retain(|r| std::mem::discriminant(r) != kind);
                self.applied.push(request);
            }
            Request::SetStrip(s) => {
                self.applied
                    .retain(|r| !matches!(r, Request::SetStrip(o) if o.strip == s.strip));
                self.applied.push(request);
            }
            // Sets everything but the probe: earlier settings are replaced by it.
            Request::Configure(_) => {
                self.applied.retain(|r| matches!(r, Request::SetProbe(_)));
                self.applied.push(request);
            }
            Request::GetInfo | Request::GetStatus | Request::GetConfig | Request::TimeSync => {}
        }
    }

    /// Wait at most `timeout` for events; pings the clock when due. Phase and fault
    /// times are mapped to the host clock.
    pub fn poll(&mut self, timeout: Duration) -> Result<Vec<SensorEvent>, SensorError> {
        if self.client.now_us() >= self.next_sync_us {
            self.with_reconnect(Self::ping)?;
        }
        let raw = self.with_reconnect(|s| s.client.wait_events(timeout))?;
        let mut out = std::mem::take(&mut self.pending);
        let fit = self.sync.fit().copied();
        let map = |d: u64| fit.map_or(d as f64, |f| f.to_host(d));
        let uncertainty_us = fit.map_or(f64::INFINITY, |f| f.uncertainty_us);
        for (_, event) in raw {
            out.push(match event {
                Event::Phase(p) => SensorEvent::Phase(HostPhase::map(p, map, uncertainty_us)),
                Event::Heartbeat(s) => SensorEvent::Heartbeat(s),
                Event::Fault(f) => SensorEvent::Fault(f, map(f.at_us)),
                Event::Probe(p) => SensorEvent::Probe(p),
            });
        }
        Ok(out)
    }

    /// Run `op`; on a disconnect, reconnect and run it once more.
    fn with_reconnect<R>(
        &mut self,
        mut op: impl FnMut(&mut Self) -> Result<R, ClientError>,
    ) -> Result<R, SensorError> {
        match op(self) {
            Err(ClientError::Transport(TransportError::Disconnected)) => {
                self.reconnect()?;
                Ok(op(self)?)
            }
            other => Ok(other?),
        }
    }

    /// Reopen with exponential backoff, check it is the same board, restore counters,
    /// replay the configuration and restart the sequence if it ran.
    pub fn reconnect(&mut self) -> Result<(), SensorError> {
        let clock = Arc::clone(self.client.clock());
        let started = clock.now_us();
        let limit = self.config.reconnect_for.as_micros() as u64;
        let mut delay = self.config.backoff_initial;
        let mut attempts = 0u32;
        loop {
            let deadline = clock.now_us() + delay.as_micros() as u64;
            self.connector.wait_for_device(&*clock, deadline);
            attempts += 1;
            let error = match self.connector.open() {
                Ok(transport) => match self.resume(transport) {
                    Ok(()) => {
                        self.reconnects += 1;
                        self.pending.push(SensorEvent::Reconnected { attempts });
                        return Ok(());
                    }
                    Err(e @ SensorError::DifferentBoard { .. }) => return Err(e),
                    Err(e) => e.to_string(),
                },
                Err(e) => e.to_string(),
            };
            let waited = clock.now_us() - started;
            if waited >= limit {
                return Err(SensorError::ReconnectFailed {
                    attempts,
                    waited: Duration::from_micros(waited),
                    last: error,
                });
            }
            delay = (delay * 2).min(self.config.backoff_max);
        }
    }

    fn resume(&mut self, transport: BoxedTransport) -> Result<(), SensorError> {
        let counters = self.client.counters();
        let mut client = Client::with_clock(transport, Arc::clone(self.client.clock()));
        client.set_counters(counters);
        let info = client.handshake()?;
        if info.board_id != self.info.board_id {
            return Err(SensorError::DifferentBoard {
                expected: serial_number(&self.info.board_id),
                found: serial_number(&info.board_id),
            });
        }
        self.client = client;
        self.info = info;
        for request in self.applied.clone() {
            self.client.request(request)?;
        }
        if self.running {
            self.client.request(Request::Start)?;
        }
        self.sync_burst()?;
        Ok(())
    }

    /// The device's configuration.
    pub fn config(&mut self) -> Result<Config, SensorError> {
        match self.request(Request::GetConfig)? {
            Response::Config(c) => Ok(c),
            other => Err(ClientError::UnexpectedReply(Box::new(other)).into()),
        }
    }

    /// The device's status.
    pub fn status(&mut self) -> Result<Status, SensorError> {
        match self.request(Request::GetStatus)? {
            Response::Status(s) => Ok(s),
            other => Err(ClientError::UnexpectedReply(Box::new(other)).into()),
        }
    }

    /// Starts the lighting sequence in `mode` with phases `period_us` long (the trigger
    /// pulse and LED settle time stay as the device has them), after refreshing the
    /// clock sync if it is due.
    pub fn start_sequence(&mut self, mode: Mode, period_us: u32) -> Result<(), SensorError> {
        // A sensor left unpolled since it connected (a model calibrated, cameras opened)
        // has a clock fit from one burst of pings, whose drift is loose: the first phases
        // would be mapped far from where they happened. A second burst pins it down.
        if self.client.now_us() >= self.next_sync_us {
            self.sync_burst()?;
        }
        let timing = Timing {
            phase_period_us: period_us,
            ..self.config()?.timing
        };
        self.request(Request::SetTiming(timing))?;
        self.request(Request::SetMode(mode))?;
        self.request(Request::Start)?;
        Ok(())
    }
}
