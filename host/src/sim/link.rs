//! The in-memory loopback: the firmware's own command handling and sequencer
//! ([`SimulatedSensor`]) behind a simulated USB link and a simulated device clock.
//!
//! What it models, so the host code is exercised as against hardware:
//! * **USB timing**: the host controller serves each transfer at a random point of a 1 ms
//!   full-speed frame (the first such point after it was submitted), with occasional long
//!   scheduling stalls; order is preserved.
//! * **The device clock**: it boots at a configurable host time and runs fast or slow by
//!   a configurable drift (ppm), so clock sync has something real to find.
//! * **Back-pressure**: the host side buffers a bounded number of frames; when the host
//!   does not read, the device's small event queue overflows and it counts drops.
//! * **Unplugging**: a [`PlugHandle`] pulls the cable: every call then fails with
//!   [`TransportError::Disconnected`].
//! * **Ground truth**: what the LEDs really showed, on the host clock ([`LedTimeline`]),
//!   for simulated cameras.
//!
//! Time comes from a [`HostClock`]: with a [`crate::clock::VirtualClock`] the whole link
//! is deterministic; with the monotonic clock it runs in real time (the CLI's `--sim`).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use stereotac_protocol::Phase;

use super::sensor::{LedChange, SimulatedSensor};
use crate::clock::{HostClock, HostMicros};
use crate::device::HostPhase;
use crate::rng::Rng;
use crate::transport::{Transport, TransportError};

/// Simulation step of the device between transfers, µs.
const TICK_US: u64 = 250;

/// Timing of the simulated USB link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UsbTiming {
    /// Frame period (full speed: 1000 µs).
    pub frame_us: u64,
    /// Earliest point in a frame at which a transfer is served, µs.
    pub min_delay_us: u64,
    /// Transfers are served at a uniformly random point this long after that, µs.
    pub jitter_us: u64,
    /// Probability that a transfer is stalled further (host scheduling).
    pub stall_probability: f64,
    /// Mean of the exponentially distributed stall, µs.
    pub stall_mean_us: f64,
}

impl Default for UsbTiming {
    fn default() -> Self {
        Self {
            frame_us: 1000,
            min_delay_us: 20,
            jitter_us: 300,
            stall_probability: 0.1,
            stall_mean_us: 2000.0,
        }
    }
}

impl UsbTiming {
    /// An ideal link: no delay at all.
    pub const INSTANT: UsbTiming = UsbTiming {
        frame_us: 1,
        min_delay_us: 0,
        jitter_us: 0,
        stall_probability: 0.0,
        stall_mean_us: 0.0,
    };

    /// When a transfer submitted at `sent` is done: the host controller serves it at a
    /// random point `u` of a frame, the first such point at or after `sent`, plus a
    /// possible scheduling stall.
    fn arrival(&self, sent: HostMicros, rng: &mut Rng) -> HostMicros {
        let frame = self.frame_us.max(1);
        let u = self.min_delay_us + (rng.uniform() * self.jitter_us as f64) as u64;
        let mut at = sent / frame * frame + u;
        if at < sent {
            at += frame;
        }
        if rng.uniform() < self.stall_probability {
            at += (-self.stall_mean_us * (1.0 - rng.uniform()).ln()) as u64;
        }
        at
    }
}

/// Settings of a [`Loopback`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopbackConfig {
    /// USB timing.
    pub usb: UsbTiming,
    /// Device clock rate error: positive runs fast (ppm).
    pub drift_ppm: f64,
    /// Host time at which the device's clock reads 0 (may be before the clock's start).
    pub boot_at_us: HostMicros,
    /// Random seed of the link's delays.
    pub seed: u64,
    /// Frames the host side buffers before the device's endpoint is back-pressured.
    pub host_buffer_frames: usize,
    /// Events the device queues while back-pressured (the board holds 16).
    pub device_queue_frames: usize,
}

impl Default for LoopbackConfig {
    fn default() -> Self {
        Self {
            usb: UsbTiming::default(),
            drift_ppm: 0.0,
            boot_at_us: 0,
            seed: 1,
            host_buffer_frames: 64,
            device_queue_frames: 16,
        }
    }
}

/// What the strips showed from `from_us` (host clock) until the next span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LitSpan {
    /// What the strips show ([`Phase::Dark`] also after a stop).
    pub phase: Phase,
    /// Host time the LED data started going out.
    pub write_start_us: f64,
    /// Host time the new colours latched: the span's light starts here.
    pub from_us: f64,
    /// The phase's trigger: index and rising edge on the host clock.
    pub trigger: Option<(u32, f64)>,
    /// The phase index k of the sequence (`None` for a stop).
    pub phase_index: Option<u32>,
}

/// Ground truth of the LEDs on the host clock, filled by the loopback as the device runs.
#[derive(Debug, Default)]
pub struct LedTimeline {
    spans: Vec<LitSpan>,
    known_until_us: f64,
}

impl LedTimeline {
    /// Every span so far, in time order.
    pub fn spans(&self) -> &[LitSpan] {
        &self.spans
    }

    /// Host time up to which the truth is complete.
    pub fn known_until_us(&self) -> f64 {
        self.known_until_us
    }

    /// How long each phase lit the interval `[start, end)`: (phase, µs) in time order;
    /// before the first span the strips are dark.
    pub fn exposure(&self, start: f64, end: f64) -> Vec<(Phase, f64)> {
        let mut out: Vec<(Phase, f64)> = Vec::new();
        let first = self.spans.partition_point(|s| s.from_us <= start);
        let mut current = first
            .checked_sub(1)
            .map_or(Phase::Dark, |i| self.spans[i].phase);
        let mut t = start;
        for span in self.spans[first..].iter().take_while(|s| s.from_us < end) {
            push_light(&mut out, current, span.from_us - t);
            current = span.phase;
            t = span.from_us;
        }
        push_light(&mut out, current, end - t);
        out
    }
}

fn push_light(out: &mut Vec<(Phase, f64)>, phase: Phase, us: f64) {
    if us <= 0.0 {
        return;
    }
    match out.last_mut() {
        Some((p, d)) if *p == phase => *d += us,
        _ => out.push((phase, us)),
    }
}

/// Pulls and replugs the simulated cable from outside the transport.
#[derive(Debug, Clone)]
pub struct PlugHandle(Arc<AtomicBool>);

impl PlugHandle {
    /// Pull the cable (or put it back).
    pub fn set_plugged(&self, plugged: bool) {
        self.0.store(plugged, Ordering::SeqCst);
    }

    /// Whether the cable is in.
    pub fn is_plugged(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

/// The loopback transport (see the module documentation).
#[derive(Debug)]
pub struct Loopback {
    sensor: SimulatedSensor,
    clock: Arc<dyn HostClock>,
    config: LoopbackConfig,
    rng: Rng,
    to_device: VecDeque<(HostMicros, Vec<u8>)>,
    to_host: VecDeque<(HostMicros, Vec<u8>)>,
    simulated_to: HostMicros,
    plugged: PlugHandle,
    timeline: Arc<Mutex<LedTimeline>>,
}

impl Loopback {
    /// A loopback to a fresh simulated sensor `board_id`, on `clock`.
    pub fn new(board_id: [u8; 8], clock: Arc<dyn HostClock>, config: LoopbackConfig) -> Self {
        let mut sensor = SimulatedSensor::new(board_id);
        sensor.set_event_queue_limit(Some(config.device_queue_frames));
        let now = clock.now_us();
        let mut link = Self {
            sensor,
            clock,
            config,
            rng: Rng::new(config.seed),
            to_device: VecDeque::new(),
            to_host: VecDeque::new(),
            simulated_to: now.max(config.boot_at_us),
            plugged: PlugHandle(Arc::new(AtomicBool::new(true))),
            timeline: Arc::default(),
        };
        let start = link.device_time(link.simulated_to);
        link.sensor.advance_to(start);
        link
    }

    /// The simulated sensor, e.g. to inspect its counters.
    pub fn sensor(&self) -> &SimulatedSensor {
        &self.sensor
    }

    /// The handle that pulls the cable.
    pub fn plug_handle(&self) -> PlugHandle {
        self.plugged.clone()
    }

    /// The LED ground truth, shared with simulated cameras.
    pub fn timeline(&self) -> Arc<Mutex<LedTimeline>> {
        Arc::clone(&self.timeline)
    }

    /// The host clock this link runs on.
    pub fn clock(&self) -> Arc<dyn HostClock> {
        Arc::clone(&self.clock)
    }

    /// The device clock at host time `h` (the simulation's truth).
    pub fn device_time(&self, h: HostMicros) -> u64 {
        let since_boot = h.saturating_sub(self.config.boot_at_us) as f64;
        (since_boot * (1.0 + self.config.drift_ppm * 1e-6)) as u64
    }

    /// The host time at which the device clock reads `d` (the simulation's truth).
    pub fn host_time(&self, d: u64) -> f64 {
        self.config.boot_at_us as f64 + d as f64 / (1.0 + self.config.drift_ppm * 1e-6)
    }

    /// Run the device up to host time `t`: deliver the host's transfers, run phases and
    /// timers, and move the device's output onto the link.
    pub fn run_until(&mut self, t: HostMicros) {
        while self.simulated_to < t {
            let mut step = (self.simulated_to + TICK_US).min(t);
            if let Some(&(arrival, _)) = self.to_device.front() {
                step = step.min(arrival.max(self.simulated_to + 1));
            }
            let device_now = self.device_time(step);
            self.sensor.advance_to(device_now);
            while self.to_device.front().is_some_and(|(a, _)| *a <= step) {
                let (_, bytes) = self.to_device.pop_front().expect("front checked");
                self.sensor.write(&bytes);
            }
            self.simulated_to = step;
            self.record_leds();
            self.drain_device(step);
        }
        self.lock_timeline().known_until_us = t as f64;
    }

    fn lock_timeline(&self) -> MutexGuard<'_, LedTimeline> {
        // A panic elsewhere while holding the lock leaves plain data; keep using it.
        self.timeline.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn record_leds(&mut self) {
        let changes = self.sensor.take_led_log();
        if changes.is_empty() {
            return;
        }
        let spans: Vec<LitSpan> = changes
            .iter()
            .map(|change| match *change {
                LedChange::Phase(p) => {
                    // The truth is exact: no sync uncertainty.
                    let host = HostPhase::map(p, |d| self.host_time(d), 0.0);
                    LitSpan {
                        phase: p.phase,
                        write_start_us: host.write_start_us,
                        from_us: host.latched_us,
                        trigger: host.trigger,
                        phase_index: Some(p.index),
                    }
                }
                LedChange::Dark { at_us } => LitSpan {
                    phase: Phase::Dark,
                    write_start_us: self.host_time(at_us),
                    from_us: self.host_time(at_us),
                    trigger: None,
                    phase_index: None,
                },
            })
            .collect();
        self.lock_timeline().spans.extend(spans);
    }

    /// Move the device's output onto the link while the host side has room.
    fn drain_device(&mut self, produced_at: HostMicros) {
        if self.to_host.len() >= self.config.host_buffer_frames {
            return; // back-pressure: the device keeps (and eventually drops) its events
        }
        // The device's frames end in a zero byte (COBS): one USB transfer per frame.
        for frame in self.sensor.read().split_inclusive(|&b| b == 0) {
            self.push_to_host(produced_at, frame.to_vec());
        }
    }

    fn push_to_host(&mut self, produced_at: HostMicros, bytes: Vec<u8>) {
        let arrival = self.ordered_arrival(produced_at, self.to_host.back().map(|b| b.0));
        self.to_host.push_back((arrival, bytes));
    }

    fn ordered_arrival(&mut self, sent: HostMicros, previous: Option<HostMicros>) -> HostMicros {
        let arrival = self.config.usb.arrival(sent, &mut self.rng);
        previous.map_or(arrival, |p| arrival.max(p))
    }

    fn check_plugged(&self) -> Result<(), TransportError> {
        if self.plugged.is_plugged() {
            Ok(())
        } else {
            Err(TransportError::Disconnected)
        }
    }
}

impl Transport for Loopback {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.check_plugged()?;
        let now = self.clock.now_us();
        self.run_until(now);
        let arrival = self.ordered_arrival(now, self.to_device.back().map(|b| b.0));
        self.to_device.push_back((arrival, bytes.to_vec()));
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, TransportError> {
        let deadline = self
            .clock
            .now_us()
            .saturating_add(timeout.as_micros() as u64);
        loop {
            self.check_plugged()?;
            let now = self.clock.now_us();
            self.run_until(now);
            let mut out = Vec::new();
            while self.to_host.front().is_some_and(|(a, _)| *a <= now) {
                out.extend(self.to_host.pop_front().expect("front checked").1);
            }
            if !out.is_empty() || now >= deadline {
                return Ok(out);
            }
            let step = if self.clock.is_virtual() {
                TICK_US
            } else {
                1000
            };
            let mut wake = deadline.min(now + step);
            // Wake exactly when a transfer lands on either side, so replies are timed
            // to the microsecond, not to the simulation step.
            for &(arrival, _) in self
                .to_host
                .front()
                .into_iter()
                .chain(self.to_device.front())
            {
                wake = wake.min(arrival);
            }
            self.clock.sleep_until(wake.max(now + 1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn span(phase: Phase, from: f64) -> LitSpan {
        LitSpan {
            phase,
            write_start_us: from - 1000.0,
            from_us: from,
            trigger: None,
            phase_index: None,
        }
    }

    #[test]
    fn exposure_splits_an_interval_by_the_lit_phase() {
        let timeline = LedTimeline {
            spans: vec![
                span(Phase::Dx, 100.0),
                span(Phase::Dy, 200.0),
                span(Phase::Dark, 300.0),
            ],
            known_until_us: 1000.0,
        };
        assert_eq!(timeline.exposure(0.0, 50.0), vec![(Phase::Dark, 50.0)]);
        assert_eq!(
            timeline.exposure(150.0, 250.0),
            vec![(Phase::Dx, 50.0), (Phase::Dy, 50.0)]
        );
        assert_eq!(
            timeline.exposure(50.0, 350.0),
            vec![
                (Phase::Dark, 50.0),
                (Phase::Dx, 100.0),
                (Phase::Dy, 100.0),
                (Phase::Dark, 50.0)
            ]
        );
        assert_eq!(timeline.exposure(210.0, 220.0), vec![(Phase::Dy, 10.0)]);
    }

    #[test]
    fn usb_transfers_are_served_at_a_point_of_a_frame_and_keep_order() {
        let usb = UsbTiming {
            stall_probability: 0.0,
            ..UsbTiming::default()
        };
        let mut rng = Rng::new(3);
        for sent in [0u64, 1, 319, 321, 999, 1000, 1500] {
            let a = usb.arrival(sent, &mut rng);
            assert!(a >= sent, "{sent} -> {a}");
            assert!((20..=320).contains(&(a % 1000)), "{sent} -> {a}");
            assert!(a - sent <= 1320, "{sent} -> {a}");
        }
        let mut link = Loopback::new(
            [1; 8],
            Arc::new(crate::clock::VirtualClock::default()),
            LoopbackConfig::default(),
        );
        let mut last = 0;
        for t in 0..200 {
            let a = link.ordered_arrival(t * 10, Some(last));
            assert!(a >= last);
            last = a;
        }
    }
}
