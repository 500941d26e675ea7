//! What the firmware's loopback probe saw on its own pins, checked against the phase
//! events: the checks the emulator makes from its pin trace, for a sensor on the bench
//! with the trigger and strip 1's data wired back to the probe inputs (README,
//! "Hardware-in-loop tests"). The emulated tests run them too, next to the trace, so
//! they are known to agree with the real pins.
//!
//! Per fired phase: one trigger edge, within 2 µs of the event's `edge_us`, after the
//! strip's last bit + WS2812 reset + settle; one strip 1 frame of the firmware's full
//! length, ending within 2 µs of what `latched_us` claims, in the phase's colour on the
//! configured pixels and dark beyond. Over the run: edges one period apart within 1 µs,
//! and no drift.

use std::time::Duration;

use stereotac::device::{Sensor, SensorEvent};
use stereotac_firmware::compose_phase;
use stereotac_firmware::sequencer::WS2812_RESET_US;
use stereotac_protocol::{
    Config, DeviceMicros, PhaseEvent, ProbeEvent, Rgb, StripFrameProbe, TriggerOutcome,
};

use crate::events::collect_phases;
use crate::trace::{check_no_drift, check_periods};

/// Everything the probe reported, in order.
#[derive(Debug, Clone, Default)]
pub struct ProbeRecord {
    /// Trigger rising edges, device ns.
    pub edges: Vec<u64>,
    /// Decoded strip 1 frames.
    pub frames: Vec<StripFrameProbe>,
}

impl ProbeRecord {
    /// Add what is in `events` (other events are ignored).
    pub fn extend<'a>(&mut self, events: impl IntoIterator<Item = &'a SensorEvent>) {
        for e in events {
            match e {
                SensorEvent::Probe(ProbeEvent::TriggerEdge { at_ns }) => self.edges.push(*at_ns),
                SensorEvent::Probe(ProbeEvent::StripFrame(f)) => self.frames.push(*f),
                _ => {}
            }
        }
    }

    /// Add another record's events after these.
    pub fn extend_from(&mut self, other: &ProbeRecord) {
        self.edges.extend_from_slice(&other.edges);
        self.frames.extend_from_slice(&other.frames);
    }

    /// The trigger edges within `range` (ns).
    pub fn edges_in(&self, range: std::ops::Range<u64>) -> Vec<u64> {
        self.edges
            .iter()
            .copied()
            .filter(|t| range.contains(t))
            .collect()
    }

    /// The frames that ended within `range` (ns).
    pub fn frames_in(&self, range: std::ops::Range<u64>) -> Vec<StripFrameProbe> {
        self.frames
            .iter()
            .copied()
            .filter(|f| range.contains(&f.end_ns))
            .collect()
    }
}

/// Polls `sensor` for `n` phase events and the probe events of those phases (it waits
/// for one more phase, whose LED write comes after the last checked phase's probe
/// events). Returns the `n` phases and the probe record; other events are dropped.
pub fn collect_with_probe(
    sensor: &mut Sensor,
    n: usize,
    limit: Duration,
) -> (Vec<PhaseEvent>, ProbeRecord) {
    let (mut phases, others) = collect_phases(sensor, n + 1, limit);
    phases.truncate(n);
    let mut probe = ProbeRecord::default();
    probe.extend(&others);
    (phases, probe)
}

/// Worst cases over the checked phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProbeTiming {
    /// Phases checked.
    pub phases: usize,
    /// Shortest and longest trigger period, ns.
    pub period_ns: (i64, i64),
    /// Last edge minus first, against (edges − 1) periods, ns.
    pub drift_ns: i64,
    /// Largest distance of a probed edge from its event's `edge_us`, ns.
    pub edge_vs_event_ns: u64,
    /// Largest distance of the probed latch (frame end + reset) from `latched_us`, ns.
    pub latch_vs_event_ns: u64,
    /// Smallest margin of a trigger edge after the probed frame end + reset + settle, ns.
    pub trigger_margin_ns: i64,
}

/// Strip 1's expected colour in `event`'s phase under `config` (black when dark).
pub fn expected_strip1(event: &PhaseEvent, config: &Config) -> Rgb {
    let frame = compose_phase(
        event.phase,
        &config.strips,
        config.leds_per_strip,
        config.power_budget_ma,
    );
    let c = frame.pixel(0, 0);
    Rgb::new(c.r, c.g, c.b)
}

/// Checks consecutive, fired `events` of one run against `probe` (see the module
/// documentation). `frame_leds` is the pixel count the firmware clocks out per strip
/// ([`stereotac_protocol::DeviceInfo::max_leds_per_strip`]). The first failure is
/// returned as a sentence.
pub fn check_probe(
    events: &[PhaseEvent],
    probe: &ProbeRecord,
    config: &Config,
    frame_leds: u16,
) -> Result<ProbeTiming, String> {
    let period_ns = u64::from(config.timing.phase_period_us) * 1000;
    let reset_ns = u64::from(WS2812_RESET_US) * 1000;
    let settle_ns = u64::from(config.timing.led_settle_us) * 1000;
    let mut t = ProbeTiming {
        phases: events.len(),
        period_ns: (i64::MAX, i64::MIN),
        drift_ns: 0,
        edge_vs_event_ns: 0,
        latch_vs_event_ns: 0,
        trigger_margin_ns: i64::MAX,
    };
    let mut rises = Vec::with_capacity(events.len());
    for e in events {
        let TriggerOutcome::Fired { edge_us, .. } = e.trigger else {
            return Err(format!("phase {}: trigger overran", e.index));
        };
        let phase = ns(e.scheduled_us)..ns(e.scheduled_us) + period_ns;
        let edge = match probe.edges_in(phase.clone())[..] {
            [edge] => edge,
            ref edges => {
                return Err(format!(
                    "phase {}: {} trigger edges probed, not one",
                    e.index,
                    edges.len()
                ));
            }
        };
        let off = edge.abs_diff(ns(edge_us));
        if off > 2_000 {
            return Err(format!(
                "phase {}: trigger probed at {edge} ns, reported at {edge_us} µs",
                e.index
            ));
        }
        t.edge_vs_event_ns = t.edge_vs_event_ns.max(off);
        let frame = match probe.frames_in(phase)[..] {
            [frame] => frame,
            ref frames => {
                return Err(format!(
                    "phase {}: {} strip 1 frames probed, not one",
                    e.index,
                    frames.len()
                ));
            }
        };
        check_frame(e, &frame, config, frame_leds)?;
        let latched = frame.end_ns + reset_ns;
        let off = latched.abs_diff(ns(e.latched_us));
        if off > 2_000 {
            return Err(format!(
                "phase {}: strip 1 latched at {latched} ns (probed), reported {} µs",
                e.index, e.latched_us
            ));
        }
        t.latch_vs_event_ns = t.latch_vs_event_ns.max(off);
        let margin = edge as i64 - (latched + settle_ns) as i64;
        if margin < 0 {
            return Err(format!(
                "phase {}: trigger at {edge} ns, {} ns before latch + settle",
                e.index, -margin
            ));
        }
        t.trigger_margin_ns = t.trigger_margin_ns.min(margin);
        rises.push(edge);
    }
    let period = period_ns as i64;
    t.period_ns = check_periods(&rises, period)?;
    t.drift_ns = check_no_drift(&rises, period)?;
    Ok(t)
}

/// One frame: full length, whole pixels, the phase's colour on the configured pixels
/// and dark beyond.
fn check_frame(
    e: &PhaseEvent,
    f: &StripFrameProbe,
    config: &Config,
    frame_leds: u16,
) -> Result<(), String> {
    let what = format!("phase {} ({:?}) strip 1", e.index, e.phase);
    if f.pixels != frame_leds || f.stray_bits != 0 {
        return Err(format!(
            "{what}: {} pixels and {} stray bits, expected {frame_leds} pixels",
            f.pixels, f.stray_bits
        ));
    }
    let expected = expected_strip1(e, config);
    if expected == Rgb::new(0, 0, 0) {
        if f.lit != 0 {
            return Err(format!("{what}: {} pixels lit, expected dark", f.lit));
        }
        return Ok(());
    }
    let leds = config.leds_per_strip;
    if f.first != expected || f.mismatched != 0 || f.lit != leds || f.leading_lit != leds {
        return Err(format!(
            "{what}: expected {leds} pixels of {expected:?} then dark, probed {f:?}"
        ));
    }
    Ok(())
}

/// After a host-silence fault at `fault_us`: strip 1's last probed frame came after it
/// and is dark, the one before was lit, and no trigger edge followed the fault.
pub fn check_dark_after_fault(probe: &ProbeRecord, fault_us: DeviceMicros) -> Result<(), String> {
    let fault = ns(fault_us);
    let late = probe.edges_in(fault + 1..u64::MAX);
    if !late.is_empty() {
        return Err(format!("trigger edges after the fault: {late:?}"));
    }
    let [.., before, last] = probe.frames[..] else {
        return Err(format!("{} strip 1 frames probed", probe.frames.len()));
    };
    if last.end_ns < fault || last.lit != 0 {
        return Err(format!(
            "the last frame ({last:?}) is not a dark one after the fault at {fault} ns"
        ));
    }
    if before.lit == 0 {
        return Err("strip 1 was not lit before the fault".into());
    }
    Ok(())
}

fn ns(us: u64) -> u64 {
    us * 1000
}
