//! What a sensor's own phase events promise, checked without the pins: phases numbered
//! without gaps, boundaries exactly one period apart (the firmware schedules on
//! `t0 + k·T`), each LED write on its boundary, one trigger per phase, numbered without
//! gaps and fired after the latch plus the settle time, and the phase kinds in the
//! mode's order (from whichever kind comes first: after a reconfiguration the sequence
//! may start anywhere in its cycle).
//!
//! [`collect_phases`] gathers the events from any sensor. The emulated tests add what
//! only the pin trace shows (edges, bits, colours); the tests against a real sensor
//! (`STEREOTAC_HIL=device`) run these on their own.

use std::time::Duration;

use stereotac::device::{Sensor, SensorEvent};
use stereotac_protocol::{Mode, Phase, PhaseEvent, Timing, TriggerOutcome};

/// Polls `sensor` until `n` phase events arrived or `limit` of the sensor's host clock
/// passed: the phase events, and every other event seen meanwhile.
pub fn collect_phases(
    sensor: &mut Sensor,
    n: usize,
    limit: Duration,
) -> (Vec<PhaseEvent>, Vec<SensorEvent>) {
    let end = sensor.clock().now_us() + limit.as_micros() as u64;
    let mut phases = Vec::new();
    let mut others = Vec::new();
    while phases.len() < n && sensor.clock().now_us() < end {
        for e in sensor.poll(Duration::from_millis(50)).unwrap() {
            match e {
                SensorEvent::Phase(p) => phases.push(p.event),
                other => others.push(other),
            }
        }
    }
    (phases, others)
}

/// The phase kinds `mode` cycles through.
pub fn cycle(mode: Mode) -> &'static [Phase] {
    match mode {
        Mode::Gradient => &[Phase::Dx, Phase::Dy],
        Mode::Interleaved => &[Phase::Dark, Phase::Dx, Phase::Dy],
        Mode::Vision => &[Phase::Dark],
        Mode::ContactShape => &[Phase::Dx],
        Mode::Off => &[],
    }
}

/// Worst cases over the checked events.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReportedTiming {
    /// Phases checked.
    pub phases: usize,
    /// Latest LED write after its boundary, µs.
    pub write_lag_us: u64,
    /// Smallest margin of a trigger edge after latch + settle, µs.
    pub trigger_margin_us: u64,
}

/// Checks `events` (consecutive, from one run of `mode` with `timing`); the first
/// failure is returned as a sentence.
pub fn check_events(
    events: &[PhaseEvent],
    mode: Mode,
    timing: &Timing,
) -> Result<ReportedTiming, String> {
    let kinds = cycle(mode);
    let period = u64::from(timing.phase_period_us);
    let mut worst = ReportedTiming {
        phases: events.len(),
        trigger_margin_us: u64::MAX,
        ..ReportedTiming::default()
    };
    let offset = match events.first() {
        Some(first) if !kinds.is_empty() => kinds
            .iter()
            .position(|&k| k == first.phase)
            .ok_or_else(|| {
                format!(
                    "phase {} is {:?}, not a phase of {mode:?}",
                    first.index, first.phase
                )
            })?,
        _ => 0,
    };
    let mut previous: Option<(&PhaseEvent, u32)> = None;
    for (k, e) in events.iter().enumerate() {
        let TriggerOutcome::Fired { index, edge_us } = e.trigger else {
            return Err(format!("phase {}: trigger overran", e.index));
        };
        if let Some((p, trigger)) = previous {
            if e.index != p.index + 1 {
                return Err(format!("phase {} follows phase {}", e.index, p.index));
            }
            if e.scheduled_us != p.scheduled_us + period {
                return Err(format!(
                    "phase {} scheduled {} µs after the previous one, period {period} µs",
                    e.index,
                    e.scheduled_us.wrapping_sub(p.scheduled_us)
                ));
            }
            if index != trigger + 1 {
                return Err(format!("trigger {index} follows trigger {trigger}"));
            }
        }
        if !kinds.is_empty() && e.phase != kinds[(k + offset) % kinds.len()] {
            return Err(format!(
                "phase {} is {:?}, {mode:?} cycles {kinds:?}",
                e.index, e.phase
            ));
        }
        let lag = e
            .write_start_us
            .checked_sub(e.scheduled_us)
            .ok_or_else(|| format!("phase {}: LED write before its boundary", e.index))?;
        if lag > 2 {
            return Err(format!("phase {}: LED write {lag} µs late", e.index));
        }
        worst.write_lag_us = worst.write_lag_us.max(lag);
        let ready = e.latched_us + u64::from(timing.led_settle_us);
        let margin = edge_us.checked_sub(ready).ok_or_else(|| {
            format!(
                "phase {}: trigger at {edge_us} µs before latch + settle ({ready} µs)",
                e.index
            )
        })?;
        worst.trigger_margin_us = worst.trigger_margin_us.min(margin);
        if edge_us >= e.scheduled_us + period {
            return Err(format!("phase {}: trigger after the phase ended", e.index));
        }
        previous = Some((e, index));
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn event(index: u32, phase: Phase, trigger: u32) -> PhaseEvent {
        let scheduled_us = 1_000 + u64::from(index) * 250_000;
        PhaseEvent {
            index,
            phase,
            scheduled_us,
            write_start_us: scheduled_us + 1,
            latched_us: scheduled_us + 300,
            trigger: TriggerOutcome::Fired {
                index: trigger,
                edge_us: scheduled_us + 900,
            },
        }
    }

    fn run() -> Vec<PhaseEvent> {
        (0..6)
            .map(|i| event(i, if i % 2 == 0 { Phase::Dx } else { Phase::Dy }, 10 + i))
            .collect()
    }

    #[test]
    fn a_clean_run_passes_and_reports_its_margins() {
        let t = check_events(&run(), Mode::Gradient, &Timing::DEFAULT).unwrap();
        assert_eq!(t.phases, 6);
        assert_eq!(t.write_lag_us, 1);
        assert_eq!(t.trigger_margin_us, 100); // 900 − (300 + 500)
    }

    #[test]
    fn each_broken_promise_is_named() {
        let check = |events: &[PhaseEvent]| check_events(events, Mode::Gradient, &Timing::DEFAULT);
        let mut gap = run();
        gap.remove(3);
        assert!(check(&gap).unwrap_err().contains("follows phase"));
        let mut late = run();
        late[2].write_start_us += 5;
        assert!(check(&late).unwrap_err().contains("6 µs late"));
        let mut early = run();
        early[4].trigger = TriggerOutcome::Fired {
            index: 14,
            edge_us: early[4].latched_us + 100,
        };
        assert!(check(&early).unwrap_err().contains("before latch + settle"));
        let mut drift = run();
        for e in &mut drift[3..] {
            e.scheduled_us += 1;
            e.write_start_us += 1;
        }
        assert!(check(&drift).unwrap_err().contains("250001 µs after"));
        let mut wrong = run();
        wrong[1].phase = Phase::Dx;
        assert!(check(&wrong).unwrap_err().contains("cycles"));
        let mut skipped = run();
        skipped[5].trigger = TriggerOutcome::Fired {
            index: 99,
            edge_us: skipped[5].scheduled_us + 900,
        };
        assert!(check(&skipped).unwrap_err().contains("trigger 99 follows"));
    }
}
