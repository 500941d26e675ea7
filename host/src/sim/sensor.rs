//! A simulated sensor: the firmware's [`Controller`] on a virtual clock, reached through
//! the same COBS/CRC frames as the real USB link.
//!
//! The board is modelled as the real one behaves: each phase's LED write starts a few
//! microseconds after the boundary, lasts the computed write time, the pixels latch
//! [`WS2812_RESET_US`] later, and the trigger is armed when the DMA transfer returns.
//! Time only moves when the caller says so ([`SimulatedSensor::advance_to`]), so runs
//! are deterministic.

use std::collections::VecDeque;
use std::time::Duration;

use stereotac_firmware::sequencer::{WS2812_RESET_US, led_write_us};
use stereotac_firmware::{Controller, Effect, Identity, MAX_LEDS_PER_STRIP};
use stereotac_protocol::{
    Capabilities, DeviceMessage, FrameDecoder, MAX_FRAME, PhaseEvent, encode,
};

use crate::transport::{Transport, TransportError};

/// Wake-up latency of the simulated LED task after a phase boundary, µs.
pub const SIM_WRITE_LATENCY_US: u64 = 3;
/// Heartbeat period of the simulated board, µs (as the firmware's supervisor).
pub const SIM_HEARTBEAT_US: u64 = 1_000_000;
/// Supervisor tick of the simulated board, µs.
pub const SIM_SUPERVISOR_TICK_US: u64 = 100_000;

/// A change of what the strips show, on the device clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LedChange {
    /// A phase ran: its LED write, latch and trigger.
    Phase(PhaseEvent),
    /// The sequence stopped: strips dark from `at_us`.
    Dark {
        /// Device time, µs.
        at_us: u64,
    },
}

/// A simulated sensor (see the module documentation).
#[derive(Debug)]
pub struct SimulatedSensor {
    controller: Controller,
    decoder: FrameDecoder,
    now_us: u64,
    next_tick_us: u64,
    ticks: u64,
    to_host: VecDeque<u8>,
    /// Capacity of the device's event queue, in frames; `None` = unbounded.
    event_queue_limit: Option<usize>,
    queued_events: usize,
    bootloader_requested: bool,
    /// What the LEDs really did, whether the host heard of it or not.
    led_log: Vec<LedChange>,
}

impl SimulatedSensor {
    /// A sensor with board id `board_id`, powered on at device time 0.
    pub fn new(board_id: [u8; 8]) -> Self {
        let identity = Identity {
            board_id,
            capabilities: Capabilities(
                Capabilities::HARDWARE_TRIGGER
                    | Capabilities::PIO_LEDS
                    | Capabilities::INTERLEAVED
                    | Capabilities::BOOTLOADER,
            ),
        };
        Self {
            controller: Controller::new(identity, MAX_LEDS_PER_STRIP),
            decoder: FrameDecoder::new(),
            now_us: 0,
            next_tick_us: SIM_SUPERVISOR_TICK_US,
            ticks: 0,
            to_host: VecDeque::new(),
            event_queue_limit: None,
            queued_events: 0,
            bootloader_requested: false,
            led_log: Vec::new(),
        }
    }

    /// Device clock, µs.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Whether the host asked for the bootloader.
    pub fn bootloader_requested(&self) -> bool {
        self.bootloader_requested
    }

    /// Limit the event queue to `frames` (the real board holds 16), to simulate a host
    /// that does not read; `None` lifts the limit.
    pub fn set_event_queue_limit(&mut self, frames: Option<usize>) {
        self.event_queue_limit = frames;
    }

    /// Take what the LEDs did since the last call, whether the host heard of it or not:
    /// the ground truth for simulated cameras.
    pub fn take_led_log(&mut self) -> Vec<LedChange> {
        std::mem::take(&mut self.led_log)
    }

    fn note_if_stopped(&mut self, was_running: bool) {
        if was_running && !self.controller.is_running() {
            self.led_log.push(LedChange::Dark { at_us: self.now_us });
        }
    }

    /// Whether the sequence runs.
    pub fn is_running(&self) -> bool {
        self.controller.is_running()
    }

    /// Bytes from the host arrive at the current device time.
    pub fn write(&mut self, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let (frame, rest) = self.decoder.feed(bytes);
            bytes = rest;
            let Some(frame) = frame else { continue };
            let was_running = self.controller.is_running();
            let (message, effect) = self.controller.handle_frame(frame, self.now_us);
            self.note_if_stopped(was_running);
            match message {
                DeviceMessage::Reply { .. } => self.send(&message),
                DeviceMessage::Event { .. } => self.post_event(&message),
            }
            if effect == Effect::EnterBootloader {
                self.bootloader_requested = true;
            }
        }
    }

    /// Take every byte the device has sent so far. Reading frees the event queue.
    pub fn read(&mut self) -> Vec<u8> {
        self.queued_events = 0;
        self.to_host.drain(..).collect()
    }

    /// Run the board until device time `t_us`: phases, heartbeats, host timeout.
    pub fn advance_to(&mut self, t_us: u64) {
        let write_us = u64::from(led_write_us(MAX_LEDS_PER_STRIP));
        let latch_us = u64::from(WS2812_RESET_US);
        loop {
            let plan = self.controller.plan(self.now_us);
            let phase_at = plan.map(|p| p.start_us.max(self.now_us) + SIM_WRITE_LATENCY_US);
            let tick_at = self.next_tick_us;
            match phase_at {
                Some(at) if at <= tick_at && at <= t_us => {
                    let plan = plan.expect("phase_at implies a plan");
                    self.now_us = at;
                    self.controller.begin(&plan);
                    let write_start = at;
                    let armed_at = write_start + write_us;
                    let latched = write_start + write_us + latch_us;
                    let (event, message) =
                        self.controller
                            .finish(&plan, write_start, latched, armed_at);
                    self.led_log.push(LedChange::Phase(event));
                    // The LED task waits for the write; the device clock (and USB) do not.
                    self.now_us = at;
                    self.post_event(&message);
                }
                _ if tick_at <= t_us => {
                    self.now_us = self.now_us.max(tick_at);
                    self.next_tick_us += SIM_SUPERVISOR_TICK_US;
                    self.ticks += 1;
                    let was_running = self.controller.is_running();
                    if let Some(fault) = self.controller.check_host_timeout(self.now_us) {
                        self.note_if_stopped(was_running);
                        self.post_event(&fault);
                    }
                    if self
                        .ticks
                        .is_multiple_of(SIM_HEARTBEAT_US / SIM_SUPERVISOR_TICK_US)
                    {
                        let hb = self.controller.heartbeat(self.now_us);
                        self.post_event(&hb);
                    }
                }
                _ => break,
            }
        }
        self.now_us = self.now_us.max(t_us);
    }

    fn send(&mut self, message: &DeviceMessage) {
        let mut buf = [0u8; MAX_FRAME];
        if let Ok(frame) = encode(message, &mut buf) {
            self.to_host.extend(frame.iter());
        }
    }

    fn post_event(&mut self, message: &DeviceMessage) {
        if self
            .event_queue_limit
            .is_some_and(|limit| self.queued_events >= limit)
        {
            self.controller.note_event_dropped();
            return;
        }
        self.queued_events += 1;
        self.send(message);
    }
}

/// The bare simulated sensor: device time stands still while the host talks and moves
/// only with [`SimulatedSensor::advance_to`].
impl Transport for SimulatedSensor {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.write(bytes);
        Ok(())
    }

    fn receive(&mut self, _timeout: Duration) -> Result<Vec<u8>, TransportError> {
        Ok(self.read())
    }
}
