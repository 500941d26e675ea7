//! Requests in, replies and events out: the device's whole behaviour towards the host.
//!
//! The board's USB task hands every received frame (or framing error) to
//! [`Controller::handle_frame`], which always produces a reply for an intact request and
//! never panics, whatever the bytes. The sequencer task asks the same controller for the
//! next phase, its LED colours and the trigger decision; the watchdog task asks it
//! whether the host has gone silent. The host's in-memory loopback transport drives this
//! very type, so the host is tested against the firmware's real command handling.

use stereotac_protocol::{
    Capabilities, Config, DeviceError, DeviceInfo, DeviceMessage, DeviceMicros, Event, Fault,
    FaultKind, Field, FrameError, HostMessage, Mode, PROTOCOL_VERSION, Phase, PhaseEvent,
    ProbeEvent, Request, Response, Settings, Status, Strip, Timing, decode, peek_request_id,
};

use crate::leds::{DEFAULT_STRIPS, PhaseFrame, compose_phase};
use crate::sequencer::{PhasePlan, Sequencer, check_timing};
use crate::version;

/// Default LED current budget, mA (5 V supply).
pub const DEFAULT_POWER_BUDGET_MA: u16 = 400;
/// Valid LED current budgets, mA.
pub const POWER_BUDGET_RANGE_MA: core::ops::RangeInclusive<u16> = 1..=10_000;
/// Default host-silence timeout, ms.
pub const DEFAULT_HOST_TIMEOUT_MS: u32 = 5000;
/// Valid non-zero host-silence timeouts, ms (0 disables the timeout).
pub const HOST_TIMEOUT_RANGE_MS: core::ops::RangeInclusive<u32> = 100..=3_600_000;
/// Default pixels per strip.
pub const DEFAULT_LEDS_PER_STRIP: u16 = 8;

/// What is fixed about this board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Identity {
    /// The flash unique id.
    pub board_id: [u8; 8],
    /// Capability flags.
    pub capabilities: Capabilities,
}

/// What the board must do after a request, besides sending the reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Effect {
    /// Nothing.
    None,
    /// The sequence or the LED colours changed: re-plan and redraw.
    Reconfigured,
    /// Reboot into the USB bootloader once the reply has gone out.
    EnterBootloader,
}

/// Counters of the link (the sequencer keeps its own).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct LinkCounters {
    events_dropped: u32,
    frames_received: u32,
    frames_rejected: u32,
    requests_rejected: u32,
    host_timeouts: u32,
}

/// The device's state and behaviour (see the module documentation).
#[derive(Debug, Clone)]
pub struct Controller {
    identity: Identity,
    config: Config,
    sequencer: Sequencer,
    link: LinkCounters,
    next_event_seq: u32,
    last_host_message_us: DeviceMicros,
}

impl Controller {
    /// A controller in Off mode with default settings, for a board that clocks out
    /// `frame_leds` pixels per strip.
    pub fn new(identity: Identity, frame_leds: u16) -> Self {
        let mut config = Config {
            mode: Mode::Off,
            timing: Timing::DEFAULT,
            strips: DEFAULT_STRIPS,
            leds_per_strip: DEFAULT_LEDS_PER_STRIP.min(frame_leds),
            power_budget_ma: DEFAULT_POWER_BUDGET_MA,
            host_timeout_ms: DEFAULT_HOST_TIMEOUT_MS,
            power_scale: 255,
            probe: false,
        };
        config.power_scale = lowest_power_scale(&config);
        Self {
            identity,
            config,
            sequencer: Sequencer::new(frame_leds),
            link: LinkCounters::default(),
            next_event_seq: 0,
            last_host_message_us: 0,
        }
    }

    /// The current configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Whether the sequence runs.
    pub fn is_running(&self) -> bool {
        self.sequencer.is_running()
    }

    /// Handshake data.
    pub fn info(&self) -> DeviceInfo {
        DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: version::FIRMWARE_VERSION,
            git_hash: version::GIT_HASH,
            git_dirty: version::GIT_DIRTY,
            board_id: self.identity.board_id,
            strips: 4,
            leds_per_strip: self.config.leds_per_strip,
            max_leds_per_strip: self.sequencer.frame_leds(),
            capabilities: self.identity.capabilities,
            timer_hz: 1_000_000,
        }
    }

    /// Counters and state at `now`.
    pub fn status(&self, now: DeviceMicros) -> Status {
        let seq = self.sequencer.counters();
        Status {
            uptime_us: now,
            running: self.sequencer.is_running(),
            mode: self.config.mode,
            phases: seq.phases,
            triggers: seq.triggers,
            overruns: seq.overruns,
            events_dropped: self.link.events_dropped,
            frames_received: self.link.frames_received,
            frames_rejected: self.link.frames_rejected,
            requests_rejected: self.link.requests_rejected,
            host_timeouts: self.link.host_timeouts,
        }
    }

    /// Handle what the frame decoder produced at `now`: a checked payload or a framing
    /// error. Returns the message to send (a reply, or a fault event for a bad frame) and
    /// what the board must do.
    pub fn handle_frame(
        &mut self,
        frame: Result<&[u8], FrameError>,
        now: DeviceMicros,
    ) -> (DeviceMessage, Effect) {
        let payload = match frame {
            Ok(payload) => payload,
            Err(error) => {
                self.link.frames_rejected = self.link.frames_rejected.wrapping_add(1);
                let kind = match error {
                    FrameError::Oversize => FaultKind::OversizeFrame,
                    FrameError::Cobs | FrameError::TooShort | FrameError::Crc => {
                        FaultKind::CorruptFrame
                    }
                };
                return (self.fault(now, kind), Effect::None);
            }
        };
        self.link.frames_received = self.link.frames_received.wrapping_add(1);
        self.last_host_message_us = now;
        let (id, result, effect) = match decode::<HostMessage>(payload) {
            Ok(message) => {
                let (result, effect) = self.handle_request(message.request, now);
                (message.id, result, effect)
            }
            Err(_) => {
                self.link.frames_rejected = self.link.frames_rejected.wrapping_add(1);
                let id = peek_request_id(payload).unwrap_or(0);
                (id, Err(DeviceError::Malformed), Effect::None)
            }
        };
        if result.is_err() {
            self.link.requests_rejected = self.link.requests_rejected.wrapping_add(1);
        }
        (DeviceMessage::Reply { id, result }, effect)
    }

    /// Carry out one request at `now`.
    pub fn handle_request(
        &mut self,
        request: Request,
        now: DeviceMicros,
    ) -> (Result<Response, DeviceError>, Effect) {
        let frame_leds = self.sequencer.frame_leds();
        let ack = |effect| (Ok(Response::Ack), effect);
        match request {
            Request::GetInfo => (Ok(Response::Info(self.info())), Effect::None),
            Request::GetStatus => (Ok(Response::Status(self.status(now))), Effect::None),
            Request::GetConfig => (Ok(Response::Config(self.config)), Effect::None),
            Request::TimeSync => (Ok(Response::Time(now)), Effect::None),
            Request::SetMode(mode) => {
                self.config.mode = mode;
                self.sequencer.reconfigure(mode, self.config.timing);
                ack(Effect::Reconfigured)
            }
            Request::SetTiming(timing) => match check_timing(&timing, frame_leds) {
                Ok(()) => {
                    self.config.timing = timing;
                    self.sequencer.reconfigure(self.config.mode, timing);
                    ack(Effect::Reconfigured)
                }
                Err(e) => (Err(e), Effect::None),
            },
            Request::SetStrip(settings) => {
                self.config.strips[settings.strip.index()] = settings;
                self.refresh_power_scale();
                ack(Effect::Reconfigured)
            }
            Request::SetLedCount(n) => match check_led_count(n, frame_leds) {
                Ok(()) => {
                    self.config.leds_per_strip = n;
                    self.refresh_power_scale();
                    ack(Effect::Reconfigured)
                }
                Err(e) => (Err(e), Effect::None),
            },
            Request::SetPowerBudget(ma) => match check_power_budget(ma) {
                Ok(()) => {
                    self.config.power_budget_ma = ma;
                    self.refresh_power_scale();
                    ack(Effect::Reconfigured)
                }
                Err(e) => (Err(e), Effect::None),
            },
            Request::SetHostTimeout(ms) => match check_host_timeout(ms) {
                Ok(()) => {
                    self.config.host_timeout_ms = ms;
                    ack(Effect::None)
                }
                Err(e) => (Err(e), Effect::None),
            },
            Request::Configure(settings) => match check_settings(&settings, frame_leds) {
                Ok(()) => {
                    let c = &mut self.config;
                    c.mode = settings.mode;
                    c.timing = settings.timing;
                    c.strips = settings.strips;
                    c.leds_per_strip = settings.leds_per_strip;
                    c.power_budget_ma = settings.power_budget_ma;
                    c.host_timeout_ms = settings.host_timeout_ms;
                    self.sequencer
                        .reconfigure(self.config.mode, self.config.timing);
                    self.refresh_power_scale();
                    ack(Effect::Reconfigured)
                }
                Err(e) => (Err(e), Effect::None),
            },
            Request::Start if self.config.mode == Mode::Off => {
                (Err(DeviceError::InvalidState), Effect::None)
            }
            Request::Start => {
                self.sequencer
                    .start(now, self.config.mode, self.config.timing);
                ack(Effect::Reconfigured)
            }
            Request::Stop => {
                self.sequencer.stop();
                ack(Effect::Reconfigured)
            }
            Request::EnterBootloader => {
                self.sequencer.stop();
                ack(Effect::EnterBootloader)
            }
            Request::SetProbe(_)
                if !self.identity.capabilities.has(Capabilities::LOOPBACK_PROBE) =>
            {
                (Err(DeviceError::InvalidState), Effect::None)
            }
            Request::SetProbe(on) => {
                self.config.probe = on;
                ack(Effect::None)
            }
        }
    }

    fn refresh_power_scale(&mut self) {
        self.config.power_scale = lowest_power_scale(&self.config);
    }

    /// Wrap `event` with the next sequence number.
    pub fn event(&mut self, event: Event) -> DeviceMessage {
        let seq = self.next_event_seq;
        self.next_event_seq = seq.wrapping_add(1);
        DeviceMessage::Event { seq, event }
    }

    fn fault(&mut self, at_us: DeviceMicros, kind: FaultKind) -> DeviceMessage {
        self.event(Event::Fault(Fault { at_us, kind }))
    }

    /// A fault event for the start-up after a watchdog reset.
    pub fn watchdog_reset_fault(&mut self, now: DeviceMicros) -> DeviceMessage {
        self.fault(now, FaultKind::WatchdogReset)
    }

    /// A heartbeat event.
    pub fn heartbeat(&mut self, now: DeviceMicros) -> DeviceMessage {
        let status = self.status(now);
        self.event(Event::Heartbeat(status))
    }

    /// The event for what the loopback probe saw, if the host asked for probe events.
    pub fn probe_event(&mut self, probe: ProbeEvent) -> Option<DeviceMessage> {
        self.config.probe.then(|| self.event(Event::Probe(probe)))
    }

    /// The board could not queue an event (the host is not reading): count it. Its
    /// sequence number is already spent, so the host sees the gap.
    pub fn note_event_dropped(&mut self) {
        self.link.events_dropped = self.link.events_dropped.wrapping_add(1);
    }

    /// Host-silence check at `now`: when the LEDs are lit by a running sequence and the
    /// host has sent nothing for the timeout, stop (LEDs dark, no triggers) and return the
    /// fault event to send.
    pub fn check_host_timeout(&mut self, now: DeviceMicros) -> Option<DeviceMessage> {
        let timeout_us = u64::from(self.config.host_timeout_ms) * 1000;
        let lit = matches!(
            self.config.mode,
            Mode::ContactShape | Mode::Gradient | Mode::Interleaved
        );
        if timeout_us == 0 || !lit || !self.sequencer.is_running() {
            return None;
        }
        if now.saturating_sub(self.last_host_message_us) < timeout_us {
            return None;
        }
        self.sequencer.stop();
        self.link.host_timeouts = self.link.host_timeouts.wrapping_add(1);
        Some(self.fault(now, FaultKind::HostTimeout))
    }

    /// The next phase to show (see [`Sequencer::plan`]).
    pub fn plan(&self, now: DeviceMicros) -> Option<PhasePlan> {
        self.sequencer.plan(now)
    }

    /// The LED colours of `phase` under the current settings and power budget.
    pub fn frame(&self, phase: Phase) -> PhaseFrame {
        compose_phase(
            phase,
            &self.config.strips,
            self.config.leds_per_strip,
            self.config.power_budget_ma,
        )
    }

    /// Commit to `plan` as its LED write starts (see [`Sequencer::begin`]).
    pub fn begin(&mut self, plan: &PhasePlan) {
        self.sequencer.begin(plan);
    }

    /// Decide the trigger of a begun phase and produce its event (see
    /// [`Sequencer::finish`]).
    pub fn finish(
        &mut self,
        plan: &PhasePlan,
        write_start_us: DeviceMicros,
        latched_us: DeviceMicros,
        now: DeviceMicros,
    ) -> (PhaseEvent, DeviceMessage) {
        let settle = self.config.timing.led_settle_us;
        let event = self
            .sequencer
            .finish(plan, settle, write_start_us, latched_us, now);
        (event, self.event(Event::Phase(event)))
    }
}

fn check_led_count(n: u16, frame_leds: u16) -> Result<(), DeviceError> {
    if (1..=frame_leds).contains(&n) {
        Ok(())
    } else {
        Err(DeviceError::InvalidValue(Field::LedCount))
    }
}

fn check_power_budget(ma: u16) -> Result<(), DeviceError> {
    if POWER_BUDGET_RANGE_MA.contains(&ma) {
        Ok(())
    } else {
        Err(DeviceError::InvalidValue(Field::PowerBudget))
    }
}

fn check_host_timeout(ms: u32) -> Result<(), DeviceError> {
    if ms == 0 || HOST_TIMEOUT_RANGE_MS.contains(&ms) {
        Ok(())
    } else {
        Err(DeviceError::InvalidValue(Field::HostTimeout))
    }
}

/// Every field of a [`Request::Configure`], checked as its single `Set…` request checks
/// it, before any is applied.
fn check_settings(s: &Settings, frame_leds: u16) -> Result<(), DeviceError> {
    check_timing(&s.timing, frame_leds)?;
    if s.strips
        .iter()
        .zip(Strip::ALL)
        .any(|(got, want)| got.strip != want)
    {
        return Err(DeviceError::InvalidValue(Field::StripOrder));
    }
    check_led_count(s.leds_per_strip, frame_leds)?;
    check_power_budget(s.power_budget_ma)?;
    check_host_timeout(s.host_timeout_ms)
}

/// Lowest brightness scale of any phase (255: no phase is capped).
fn lowest_power_scale(config: &Config) -> u8 {
    [Phase::All, Phase::Dx, Phase::Dy]
        .iter()
        .map(|&p| {
            compose_phase(
                p,
                &config.strips,
                config.leds_per_strip,
                config.power_budget_ma,
            )
            .power_scale
        })
        .min()
        .unwrap_or(255)
}

#[cfg(test)]
mod tests;
