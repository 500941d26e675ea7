//! Every message exchanged between the sensor firmware and the host.
//!
//! The host sends [`HostMessage`]s (a request with a request id); the device sends
//! [`DeviceMessage`]s: exactly one [`DeviceMessage::Reply`] per intact request, and
//! [`DeviceMessage::Event`]s numbered by a gap-free sequence number so loss is visible.
//!
//! Stability rule: the first variant of [`Request`] (`GetInfo`), of [`DeviceMessage`]
//! (`Reply`) and of [`Response`] (`Info`), and the first field of [`DeviceInfo`]
//! (`protocol_version`) never move, so a host can always read the version of a device
//! speaking any protocol version (see [`crate::peek_protocol_version`]). New variants are
//! only ever appended; anything else bumps [`crate::PROTOCOL_VERSION`].

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// Identifies a request; the reply carries the same id. Chosen freely by the host.
pub type RequestId = u32;

/// Microseconds on the device's 1 MHz timer since it booted.
pub type DeviceMicros = u64;

/// Nanoseconds on the same clock as [`DeviceMicros`] (the loopback probe resolves
/// edges finer than the timer's microsecond).
pub type DeviceNanos = u64;

macro_rules! wire_type {
    ($(#[$meta:meta])* $vis:vis $kind:ident $name:ident $($body:tt)*) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[cfg_attr(any(test, feature = "arbitrary"), derive(proptest_derive::Arbitrary))]
        $vis $kind $name $($body)*
    };
}

wire_type! {
    /// A frame from the host to the device.
    pub struct HostMessage {
        /// Echoed in the reply.
        pub id: RequestId,
        /// What the host asks for.
        pub request: Request,
    }
}

wire_type! {
    /// What the host can ask of the device. Each gets exactly one reply.
    pub enum Request {
        /// Handshake: answered with [`Response::Info`]. Must stay the first variant.
        GetInfo,
        /// Counters and state: answered with [`Response::Status`].
        GetStatus,
        /// The full current configuration: answered with [`Response::Config`].
        GetConfig,
        /// Select the lighting sequence. Takes effect at the next phase boundary.
        SetMode(Mode),
        /// Phase period, trigger pulse width and LED settle time.
        SetTiming(Timing),
        /// Colour and brightness of one strip.
        SetStrip(StripSettings),
        /// Number of WS2812 pixels on every strip.
        SetLedCount(u16),
        /// Total LED current budget in milliamps; brightness is capped to fit it.
        SetPowerBudget(u16),
        /// Host-silence timeout in milliseconds (0 disables): when lit and no message
        /// arrives in time, the LEDs go dark, triggers stop and a fault is reported.
        SetHostTimeout(u32),
        /// Start the sequence of the current mode (schedule restarts at t0 = now).
        Start,
        /// Stop: LEDs dark, no triggers.
        Stop,
        /// Clock-sync ping: answered with [`Response::Time`], the device clock read as late
        /// as possible before the reply is queued.
        TimeSync,
        /// Reboot into the RP2040's USB mass-storage bootloader (UF2 flashing).
        /// Acknowledged before the reboot.
        EnterBootloader,
        /// Report what the loopback probe inputs see ([`Event::Probe`]): on, or off
        /// (the default). Needs [`Capabilities::LOOPBACK_PROBE`], else
        /// [`DeviceError::InvalidState`].
        SetProbe(bool),
        /// Every setting at once: validated as a whole and applied all together, or
        /// refused with the first bad field and nothing changed (what `set` sends, so a
        /// refused value never leaves the others applied).
        Configure(Settings),
    }
}

wire_type! {
    /// A frame from the device to the host.
    pub enum DeviceMessage {
        /// The one reply to a request. Must stay the first variant.
        Reply {
            /// The request's id.
            id: RequestId,
            /// The result, or why the request was refused.
            result: Result<Response, DeviceError>,
        },
        /// Something the device reports on its own.
        Event {
            /// Increases by one for every event the device produced, including those it
            /// had to drop; a gap on the host means lost events.
            seq: u32,
            /// The event.
            event: Event,
        },
    }
}

wire_type! {
    /// Successful answers to requests.
    pub enum Response {
        /// Answer to [`Request::GetInfo`]. Must stay the first variant.
        Info(DeviceInfo),
        /// The request was carried out.
        Ack,
        /// Answer to [`Request::GetStatus`].
        Status(Status),
        /// Answer to [`Request::GetConfig`].
        Config(Config),
        /// Answer to [`Request::TimeSync`]: the device clock in microseconds.
        Time(DeviceMicros),
    }
}

wire_type! {
    /// Handshake data describing the device.
    pub struct DeviceInfo {
        /// Must stay the first field: see the module's stability rule.
        pub protocol_version: u16,
        /// Firmware semantic version.
        pub firmware_version: FirmwareVersion,
        /// Git commit the firmware was built from (SHA-1; all zero when unknown).
        pub git_hash: [u8; 20],
        /// The build had uncommitted changes.
        pub git_dirty: bool,
        /// The board's unique id (the RP2040's flash unique id).
        pub board_id: [u8; 8],
        /// Number of LED strips.
        pub strips: u8,
        /// Pixels per strip currently configured.
        pub leds_per_strip: u16,
        /// Largest pixel count per strip the firmware supports.
        pub max_leds_per_strip: u16,
        /// What this firmware can do.
        pub capabilities: Capabilities,
        /// Timer frequency of every timestamp, in Hz (1 MHz: microseconds).
        pub timer_hz: u32,
    }
}

wire_type! {
    /// Semantic version of the firmware.
    pub struct FirmwareVersion {
        /// Major.
        pub major: u8,
        /// Minor.
        pub minor: u8,
        /// Patch.
        pub patch: u8,
    }
}

wire_type! {
    /// Capability bit flags (see the associated constants).
    pub struct Capabilities(pub u32);
}

impl Capabilities {
    /// Camera trigger is a hardware pulse (PIO), not a GPIO toggled by software.
    pub const HARDWARE_TRIGGER: u32 = 1 << 0;
    /// LED strips are driven by PIO + DMA concurrently.
    pub const PIO_LEDS: u32 = 1 << 1;
    /// [`Mode::Interleaved`] is supported.
    pub const INTERLEAVED: u32 = 1 << 2;
    /// [`Request::EnterBootloader`] is supported.
    pub const BOOTLOADER: u32 = 1 << 3;
    /// A hardware watchdog resets the MCU if the firmware stalls.
    pub const WATCHDOG: u32 = 1 << 4;
    /// Loopback probe inputs: the trigger and strip 1's data line, wired back to two
    /// spare pins, are timed and decoded by the firmware ([`Request::SetProbe`]).
    pub const LOOPBACK_PROBE: u32 = 1 << 5;

    /// Whether every bit of `flag` is set.
    pub const fn has(self, flag: u32) -> bool {
        self.0 & flag == flag
    }
}

wire_type! {
    /// Lighting sequence.
    pub enum Mode {
        /// Strips dark, no triggers.
        Off,
        /// All strips dark, cameras triggered every phase: stereo vision through the skin.
        Vision,
        /// All strips lit every phase: the contact's outline.
        ContactShape,
        /// Dx, Dy, Dx, ...: photometric stereo gradients.
        Gradient,
        /// Dark, Dx, Dy, Dark, ...: vision and gradients from one stream.
        Interleaved,
    }
}

wire_type! {
    /// What the strips show during one phase.
    pub enum Phase {
        /// All strips off.
        Dark,
        /// All strips lit in their colours.
        All,
        /// Strips 1 (x-) and 3 (x+) lit: the x-gradient image.
        Dx,
        /// Strips 2 (y-) and 4 (y+) lit: the y-gradient image.
        Dy,
    }
}

wire_type! {
    /// Sequencer timing.
    pub struct Timing {
        /// Length of one phase in µs (default 250 000: dx/dy alternate at 4 Hz).
        pub phase_period_us: u32,
        /// Width of the camera trigger pulse in µs (default 100).
        pub trigger_pulse_us: u32,
        /// Extra wait after the WS2812 latch before the trigger, in µs.
        pub led_settle_us: u32,
    }
}

impl Timing {
    /// Defaults: 250 ms phases, 100 µs trigger pulse, 500 µs settle.
    pub const DEFAULT: Timing = Timing {
        phase_period_us: 250_000,
        trigger_pulse_us: 100,
        led_settle_us: 500,
    };
}

impl Default for Timing {
    fn default() -> Self {
        Self::DEFAULT
    }
}

wire_type! {
    /// One of the four strips around the skin.
    pub enum Strip {
        /// Strip 1, x- side (blue in the dx phase).
        XMinus,
        /// Strip 2, y- side (blue in the dy phase).
        YMinus,
        /// Strip 3, x+ side (red in the dx phase).
        XPlus,
        /// Strip 4, y+ side (red in the dy phase).
        YPlus,
    }
}

impl Strip {
    /// All strips in wiring order (strip 1..4).
    pub const ALL: [Strip; 4] = [Strip::XMinus, Strip::YMinus, Strip::XPlus, Strip::YPlus];

    /// Zero-based index in wiring order.
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The strip's number, 1 to 4: its one name on the board, in the docs and the CLI.
    pub const fn number(self) -> u8 {
        self as u8 + 1
    }

    /// The strip numbered `n` (1 to 4).
    pub const fn from_number(n: u8) -> Option<Strip> {
        match n {
            1..=4 => Some(Self::ALL[(n - 1) as usize]),
            _ => None,
        }
    }

    /// The side of the skin it lights: `x−`, `y−`, `x+` or `y+`.
    pub const fn side(self) -> &'static str {
        match self {
            Strip::XMinus => "x−",
            Strip::YMinus => "y−",
            Strip::XPlus => "x+",
            Strip::YPlus => "y+",
        }
    }
}

/// `strip N (side)`, e.g. `strip 1 (x−)`.
impl core::fmt::Display for Strip {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "strip {} ({})", self.number(), self.side())
    }
}

wire_type! {
    /// An 8-bit RGB colour.
    pub struct Rgb {
        /// Red.
        pub r: u8,
        /// Green.
        pub g: u8,
        /// Blue.
        pub b: u8,
    }
}

impl Rgb {
    /// Build a colour.
    pub const fn new(r: u8, g: u8, b: u8) -> Self {
        Self { r, g, b }
    }
}

wire_type! {
    /// Colour and brightness of one strip.
    pub struct StripSettings {
        /// Which strip.
        pub strip: Strip,
        /// Colour whenever the strip is lit.
        pub colour: Rgb,
        /// Brightness 0..=255 applied to the colour (further capped by the power budget).
        pub brightness: u8,
    }
}

wire_type! {
    /// Everything [`Request::Configure`] sets: the writable part of [`Config`].
    pub struct Settings {
        /// Lighting mode.
        pub mode: Mode,
        /// Timing.
        pub timing: Timing,
        /// Per-strip colour and brightness, in wiring order (`strips[i].strip` must be
        /// [`Strip::ALL`]`[i]`).
        pub strips: [StripSettings; 4],
        /// Pixels per strip.
        pub leds_per_strip: u16,
        /// LED current budget in mA.
        pub power_budget_ma: u16,
        /// Host-silence timeout in ms (0: disabled).
        pub host_timeout_ms: u32,
    }
}

wire_type! {
    /// The device's complete configuration.
    pub struct Config {
        /// Current mode.
        pub mode: Mode,
        /// Current timing.
        pub timing: Timing,
        /// Per-strip colour and brightness, in wiring order.
        pub strips: [StripSettings; 4],
        /// Pixels per strip.
        pub leds_per_strip: u16,
        /// LED current budget in mA.
        pub power_budget_ma: u16,
        /// Host-silence timeout in ms (0: disabled).
        pub host_timeout_ms: u32,
        /// Brightness scale 0..=255 actually applied after the power budget (255: uncapped).
        pub power_scale: u8,
        /// Whether loopback probe events are sent ([`Request::SetProbe`]).
        pub probe: bool,
    }
}

wire_type! {
    /// Counters and state, sent on request and as a periodic heartbeat.
    pub struct Status {
        /// Device clock.
        pub uptime_us: DeviceMicros,
        /// Whether the sequencer runs.
        pub running: bool,
        /// Current mode.
        pub mode: Mode,
        /// Phases started since boot.
        pub phases: u32,
        /// Trigger pulses fired since boot.
        pub triggers: u32,
        /// Phases whose trigger was skipped because the LEDs were not ready in time.
        pub overruns: u32,
        /// Events dropped because the host was not reading.
        pub events_dropped: u32,
        /// Intact frames received.
        pub frames_received: u32,
        /// Frames rejected (corrupt, oversize, undecodable).
        pub frames_rejected: u32,
        /// Requests answered with an error.
        pub requests_rejected: u32,
        /// Times the host-silence timeout fired.
        pub host_timeouts: u32,
    }
}

wire_type! {
    /// What the device reports on its own.
    pub enum Event {
        /// Periodic status.
        Heartbeat(Status),
        /// One phase of the lighting sequence.
        Phase(PhaseEvent),
        /// Something went wrong.
        Fault(Fault),
        /// What a loopback probe input saw (only while [`Config::probe`] is on).
        Probe(ProbeEvent),
    }
}

wire_type! {
    /// What the loopback probe saw on the wires looped back to its inputs: the camera
    /// trigger, and strip 1's WS2812 data. Times come from the probe's own PIO counter,
    /// not from the code that drives the outputs, so they check that code.
    pub enum ProbeEvent {
        /// A rising edge of the looped-back trigger.
        TriggerEdge {
            /// When the edge reached the probe input.
            at_ns: DeviceNanos,
        },
        /// One WS2812 frame on the looped-back strip 1 data line, decoded.
        StripFrame(StripFrameProbe),
    }
}

wire_type! {
    /// One decoded WS2812 frame (a burst of bits ended by the line staying low).
    pub struct StripFrameProbe {
        /// The falling edge that ended the frame's last bit.
        pub end_ns: DeviceNanos,
        /// Whole 24-bit pixels received.
        pub pixels: u16,
        /// Pixels that were not black.
        pub lit: u16,
        /// Lit pixels in an unbroken run from the first pixel.
        pub leading_lit: u16,
        /// Colour of the first pixel.
        pub first: Rgb,
        /// Lit pixels whose colour differs from the first pixel's.
        pub mismatched: u16,
        /// Bits after the last whole pixel (0 for a well-formed frame).
        pub stray_bits: u8,
    }
}

wire_type! {
    /// Timestamps of one phase of the sequence, all on the device clock (µs).
    pub struct PhaseEvent {
        /// Phase number since the sequence started (k in t0 + k·T).
        pub index: u32,
        /// What the strips showed.
        pub phase: Phase,
        /// Scheduled phase boundary t0 + k·T.
        pub scheduled_us: DeviceMicros,
        /// When the LED data started going out.
        pub write_start_us: DeviceMicros,
        /// When every strip had latched its new colours (last bit + WS2812 reset time).
        pub latched_us: DeviceMicros,
        /// Whether and when the camera was triggered.
        pub trigger: TriggerOutcome,
    }
}

wire_type! {
    /// The camera trigger of one phase.
    pub enum TriggerOutcome {
        /// The pulse's rising edge.
        Fired {
            /// Trigger pulses since boot, counting this one from zero.
            index: u32,
            /// Rising edge time.
            edge_us: DeviceMicros,
        },
        /// Skipped: the LEDs would not have been stable before the phase's deadline.
        Overrun {
            /// Latest allowed trigger time.
            deadline_us: DeviceMicros,
            /// When the LEDs would have been ready.
            ready_us: DeviceMicros,
        },
    }
}

wire_type! {
    /// A fault report.
    pub struct Fault {
        /// When it happened.
        pub at_us: DeviceMicros,
        /// What happened.
        pub kind: FaultKind,
    }
}

wire_type! {
    /// Kinds of fault.
    pub enum FaultKind {
        /// The host was silent past the timeout while lit: LEDs dark, triggers stopped.
        HostTimeout,
        /// A frame failed its COBS decoding or checksum and was dropped (no reply).
        CorruptFrame,
        /// A frame exceeded the maximum frame size and was dropped (no reply).
        OversizeFrame,
        /// The previous boot ended in a watchdog reset.
        WatchdogReset,
    }
}

wire_type! {
    /// Why a request was refused.
    #[derive(thiserror::Error)]
    pub enum DeviceError {
        /// The frame was intact but its body did not decode as a request of this protocol.
        #[error("malformed request (unknown request or wrong field layout)")]
        Malformed,
        /// A field was out of range.
        #[error("invalid value for {0}")]
        InvalidValue(Field),
        /// The timing cannot be met: LED write + latch + settle + trigger need more than
        /// one phase.
        #[error("timing infeasible: a phase needs {needed_us} µs but the period is {period_us} µs")]
        TimingInfeasible {
            /// Time one phase needs.
            needed_us: u32,
            /// Phase period requested.
            period_us: u32,
        },
        /// The request cannot be served in the current state.
        #[error("not possible in the current state")]
        InvalidState,
    }
}

wire_type! {
    /// Names a field in [`DeviceError::InvalidValue`].
    pub enum Field {
        /// [`Timing::phase_period_us`].
        PhasePeriod,
        /// [`Timing::trigger_pulse_us`].
        TriggerPulse,
        /// [`Timing::led_settle_us`].
        LedSettle,
        /// [`Request::SetLedCount`].
        LedCount,
        /// [`Request::SetPowerBudget`].
        PowerBudget,
        /// [`Request::SetHostTimeout`].
        HostTimeout,
        /// [`Settings::strips`] not in wiring order.
        StripOrder,
    }
}

impl core::fmt::Display for Field {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Field::PhasePeriod => "phase period",
            Field::TriggerPulse => "trigger pulse width",
            Field::LedSettle => "LED settle time",
            Field::LedCount => "LED count per strip",
            Field::PowerBudget => "power budget",
            Field::HostTimeout => "host timeout",
            Field::StripOrder => "strip order (strips 1 to 4, in wiring order)",
        })
    }
}

impl Config {
    /// The writable part, to change some of it and send back as [`Request::Configure`].
    pub const fn settings(&self) -> Settings {
        Settings {
            mode: self.mode,
            timing: self.timing,
            strips: self.strips,
            leds_per_strip: self.leds_per_strip,
            power_budget_ma: self.power_budget_ma,
            host_timeout_ms: self.host_timeout_ms,
        }
    }
}
