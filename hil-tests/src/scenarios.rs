//! Test runs shared by the emulated and the device HIL tests. Each drives a sensor
//! through the host library, checks what the sensor reports of itself, and returns the
//! events so the caller can add the pin checks it has: the emulator's trace, or the
//! firmware's loopback probe (which every run turns on when the sensor has one).

use std::time::Duration;

use stereotac::device::{Sensor, SensorEvent};
use stereotac_protocol::{
    Capabilities, Config, Fault, FaultKind, Mode, Phase, PhaseEvent, Request, Status,
    TriggerOutcome,
};

use crate::events::{check_events, collect_phases};
use crate::probe::{ProbeRecord, collect_with_probe};

/// Turn `r`'s error into a sentence naming what failed.
fn step<T, E: std::fmt::Display>(what: &str, r: Result<T, E>) -> Result<T, String> {
    r.map_err(|e| format!("{what}: {e}"))
}

/// Turns the loopback probe on if the sensor has one; returns whether it did.
pub fn probe_on_if_present(s: &mut Sensor) -> Result<bool, String> {
    let present = s.info().capabilities.has(Capabilities::LOOPBACK_PROBE);
    if present {
        step("SetProbe", s.request(Request::SetProbe(true)))?;
    }
    Ok(present)
}

/// Start `mode` with phases of `period_us`; returns the configuration in effect.
pub fn start(s: &mut Sensor, mode: Mode, period_us: u32) -> Result<Config, String> {
    let mut config = step("GetConfig", s.config())?;
    config.timing.phase_period_us = period_us;
    step("SetTiming", s.request(Request::SetTiming(config.timing)))?;
    step("SetMode", s.request(Request::SetMode(mode)))?;
    step("Start", s.request(Request::Start))?;
    step("GetConfig", s.config())
}

/// Frames the firmware must drop and count without answering, and keep going: an
/// unknown payload with a bad checksum, a 600-byte run (over the frame limit), and an
/// empty frame. Returns the status afterwards.
pub fn check_malformed_frames(s: &mut Sensor) -> Result<Status, String> {
    let before = step("status", s.status())?;
    for bytes in [&[0x13, 0x37, 0x42, 0x00][..], &[0x01; 600][..], &[0x00][..]] {
        step("sending raw bytes", s.send_raw(bytes))?;
    }
    let after = step("status after the malformed frames", s.status())?;
    if after.frames_rejected < before.frames_rejected + 2 {
        return Err(format!(
            "frames rejected {} → {}: the bad frames were not counted",
            before.frames_rejected, after.frames_rejected
        ));
    }
    if after.requests_rejected != before.requests_rejected {
        return Err("a bad frame was answered as a request".into());
    }
    Ok(after)
}

/// The three stages of [`run_period_change`].
#[derive(Debug, Clone)]
pub struct PeriodChangeRun {
    /// Interleaved mode at 10 Hz.
    pub interleaved: Vec<PhaseEvent>,
    /// The configuration in effect for them.
    pub interleaved_config: Config,
    /// Interleaved mode after the period was halved while running: only the phases
    /// planned with the new period.
    pub changed: Vec<PhaseEvent>,
    /// Vision mode at 20 Hz (strips dark), after its first phase.
    pub vision: Vec<PhaseEvent>,
    /// The configuration in effect for the last two stages.
    pub changed_config: Config,
    /// What the probe saw through all of it (empty without a probe).
    pub probe: ProbeRecord,
}

/// Interleaved mode at 10 Hz (12 phases), the period halved while it runs (at least 10
/// phases at the new period), then vision mode (7 phases). Every stage keeps the
/// events' promises ([`check_events`]); no overruns, no events lost. Leaves the sensor
/// stopped.
pub fn run_period_change(s: &mut Sensor) -> Result<PeriodChangeRun, String> {
    let mut probe = ProbeRecord::default();
    let interleaved_config = start(s, Mode::Interleaved, 100_000)?;
    let mut config = interleaved_config;
    let (interleaved, p) = collect_with_probe(s, 12, Duration::from_secs(20));
    probe.extend_from(&p);
    if interleaved.len() < 12 {
        return Err(format!("{} of 12 interleaved phases", interleaved.len()));
    }
    check_events(&interleaved, Mode::Interleaved, &interleaved_config.timing)?;

    config.timing.phase_period_us = 50_000;
    step("SetTiming", s.request(Request::SetTiming(config.timing)))?;
    let changed_config = step("GetConfig", s.config())?;
    let (after, p) = collect_with_probe(s, 14, Duration::from_secs(5));
    probe.extend_from(&p);
    // The phases that started after the change (the first may still be the old plan).
    let changed: Vec<PhaseEvent> = after
        .iter()
        .skip_while(|e| {
            after
                .iter()
                .any(|n| n.index == e.index + 1 && n.scheduled_us - e.scheduled_us != 50_000)
        })
        .copied()
        .collect();
    if changed.len() < 10 {
        return Err(format!("{} phases at the new period", changed.len()));
    }
    check_events(&changed, Mode::Interleaved, &changed_config.timing)?;

    step("SetMode", s.request(Request::SetMode(Mode::Vision)))?;
    step("Start", s.request(Request::Start))?;
    let (events, p) = collect_with_probe(s, 8, Duration::from_secs(5));
    probe.extend_from(&p);
    let vision: Vec<PhaseEvent> = events
        .iter()
        .skip_while(|e| e.phase != Phase::Dark)
        .skip(1) // the first may follow the mode change at any time
        .copied()
        .collect();
    if vision.len() < 6 || vision.iter().any(|e| e.phase != Phase::Dark) {
        return Err(format!("vision phases: {vision:?}"));
    }
    check_events(&vision, Mode::Vision, &changed_config.timing)?;
    step("Stop", s.request(Request::Stop))?;
    let status = step("status", s.status())?;
    if status.overruns != 0 {
        return Err(format!("{} overruns", status.overruns));
    }
    let lost = s.counters().link.lost_events;
    if lost != 0 {
        return Err(format!("{lost} events lost"));
    }
    Ok(PeriodChangeRun {
        interleaved,
        interleaved_config,
        changed,
        vision,
        changed_config,
        probe,
    })
}

/// Polls for the first `n` phases that began after `resumed_us` on the host clock (when
/// the host read again: the events it missed are behind them), and the probe events
/// that came with them. Too few within `limit` is an error.
fn collect_phases_after(
    s: &mut Sensor,
    resumed_us: u64,
    n: usize,
    limit: Duration,
) -> Result<(Vec<PhaseEvent>, ProbeRecord), String> {
    let end = s.clock().now_us() + limit.as_micros() as u64;
    let mut after = Vec::new();
    let mut probe = ProbeRecord::default();
    // One more phase than asked for: its event comes after the last checked phase's
    // probe events.
    while after.len() <= n {
        if s.clock().now_us() >= end {
            return Err(format!(
                "{} phases began after the host read again, within {limit:?}",
                after.len()
            ));
        }
        for e in step("poll", s.poll(Duration::from_millis(50)))? {
            match e {
                SensorEvent::Phase(p) => {
                    let began = s.to_host(p.event.scheduled_us);
                    if began.is_some_and(|h| h >= resumed_us as f64) {
                        after.push(p.event);
                    }
                }
                other => probe.extend([&other]),
            }
        }
    }
    after.truncate(n);
    Ok((after, probe))
}

/// What [`run_not_reading`] saw.
#[derive(Debug, Clone)]
pub struct NotReadingRun {
    /// Phases before the host stopped reading.
    pub before: Vec<PhaseEvent>,
    /// Phases after it read again.
    pub after: Vec<PhaseEvent>,
    /// The configuration of the run (gradient at 50 Hz).
    pub config: Config,
    /// The device's status afterwards.
    pub status: Status,
    /// Events the host saw missing (sequence gaps).
    pub lost: u64,
    /// What the probe saw before and after (its events in between were dropped too).
    pub probe: ProbeRecord,
}

/// Gradient mode at 50 Hz; after 5 phases the host stops reading for as long as
/// `stall` takes (it must not send anything either), then reads again and takes the
/// first 5 phases that began after that, past the dropped events. The device
/// must have dropped and counted events, the host must see at least as many lost,
/// with no overrun, and the phases after must sit on the same `t0 + k·T` grid as the
/// ones before with one trigger per phase in between. Leaves the sensor stopped.
pub fn run_not_reading(
    s: &mut Sensor,
    stall: impl FnOnce(&mut Sensor),
) -> Result<NotReadingRun, String> {
    let config = start(s, Mode::Gradient, 20_000)?;
    let (before, mut probe) = collect_with_probe(s, 5, Duration::from_secs(5));
    stall(s);
    let resumed_us = s.clock().now_us();
    let (after, p) = collect_phases_after(s, resumed_us, 5, Duration::from_secs(5))?;
    probe.extend_from(&p);
    step("Stop", s.request(Request::Stop))?;
    let status = step("status", s.status())?;
    let lost = s.counters().link.lost_events;
    let (Some(first), Some(last)) = (before.first(), after.last()) else {
        return Err(format!(
            "{} phases before, {} after",
            before.len(),
            after.len()
        ));
    };
    if status.events_dropped == 0 {
        return Err(format!("nothing dropped: {status:?}"));
    }
    if lost < u64::from(status.events_dropped) {
        return Err(format!(
            "host saw {lost} lost, device dropped {}",
            status.events_dropped
        ));
    }
    if status.overruns != 0 {
        return Err(format!("{} overruns", status.overruns));
    }
    check_events(&before, Mode::Gradient, &config.timing)?;
    check_events(&after, Mode::Gradient, &config.timing)?;
    let phases = u64::from(last.index - first.index);
    let period = u64::from(config.timing.phase_period_us);
    if last.scheduled_us - first.scheduled_us != phases * period {
        return Err(format!(
            "phase {} is {} µs after phase {}, not {} periods",
            last.index,
            last.scheduled_us - first.scheduled_us,
            first.index,
            phases
        ));
    }
    let trigger = |e: &PhaseEvent| match e.trigger {
        TriggerOutcome::Fired { index, .. } => Some(index),
        TriggerOutcome::Overrun { .. } => None,
    };
    if let (Some(a), Some(b)) = (trigger(first), trigger(last))
        && u64::from(b - a) != phases
    {
        return Err(format!("{} triggers over {phases} phases", b - a));
    }
    Ok(NotReadingRun {
        before,
        after,
        config,
        status,
        lost,
        probe,
    })
}

/// What [`run_host_silence`] saw.
#[derive(Debug, Clone)]
pub struct HostSilenceRun {
    /// The host-timeout fault.
    pub fault: Fault,
    /// What the probe saw, before and after the fault (empty without a probe).
    pub probe: ProbeRecord,
}

/// Contact-shape mode (all strips lit) with a 300 ms host timeout; after 2 phases the
/// host says nothing for as long as `silence` takes (no requests, no clock pings), then
/// reads for 300 ms of its clock. The sensor must have reported a host-timeout fault.
/// The host timeout stays at 300 ms; the sequencer is stopped by the fault.
pub fn run_host_silence(
    s: &mut Sensor,
    silence: impl FnOnce(&mut Sensor),
) -> Result<HostSilenceRun, String> {
    step("SetHostTimeout", s.request(Request::SetHostTimeout(300)))?;
    step("SetMode", s.request(Request::SetMode(Mode::ContactShape)))?;
    step("Start", s.request(Request::Start))?;
    let (_, others) = collect_phases(s, 2, Duration::from_secs(20));
    let mut probe = ProbeRecord::default();
    probe.extend(&others);
    silence(s);
    let mut events = Vec::new();
    let end = s.clock().now_us() + 300_000;
    while s.clock().now_us() < end {
        events.extend(step("poll", s.poll(Duration::from_millis(50)))?);
    }
    probe.extend(&events);
    let fault = events
        .iter()
        .find_map(|e| match e {
            SensorEvent::Fault(f, _) if f.kind == FaultKind::HostTimeout => Some(*f),
            _ => None,
        })
        .ok_or("no host-timeout fault after the silence")?;
    Ok(HostSilenceRun { fault, probe })
}
