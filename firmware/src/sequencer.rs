//! The lighting sequence on an absolute schedule, and the trigger decision.
//!
//! Phase `k` starts at `t0 + (k - k0)·T` (an *epoch* `(t0, k0, T)` begins at start-up and
//! at every reconfiguration), computed by multiplication, never by adding periods, so
//! the schedule cannot drift. Within a phase the board:
//!
//! 1. waits for the phase start and writes the four strips ([`Sequencer::begin`]);
//! 2. knows when the data has latched: the WS2812 bit stream is clocked by the PIO at a
//!    fixed rate, so its end is `write_start + `[`led_write_us`] and the pixels latch
//!    [`WS2812_RESET_US`] later;
//! 3. asks [`Sequencer::finish`] whether the trigger may fire. The trigger edge is at the
//!    fixed offset [`trigger_offset_us`] after the phase start (so triggers are exactly
//!    `T` apart), and fires only if the LEDs latched and settled before it; otherwise the
//!    phase is an overrun: no trigger, reported, never mislabelled.
//!
//! The trigger pulse must end before the next phase's LED write starts; [`check_timing`]
//! refuses timings where it would not.

use stereotac_protocol::{
    DeviceError, DeviceMicros, Field, Mode, Phase, PhaseEvent, Timing, TriggerOutcome,
};

/// Time one WS2812 bit takes on the wire, in ns (800 kHz).
pub const WS2812_BIT_NS: u32 = 1250;
/// Low time after the last bit before the pixels latch, in µs (WS2812B needs > 280 µs).
pub const WS2812_RESET_US: u32 = 300;
/// Allowance for the start of the LED write after the phase boundary, in µs. The board
/// prepares the write [`PREPARE_LEAD_US`] ahead and starts it on the boundary, so this
/// only matters when the executor was busy; a later start that still latches in time is
/// fine, one that does not becomes an overrun.
pub const WRITE_START_SLACK_US: u32 = 100;
/// How long before a phase boundary the board composes the frame and loads the strips'
/// FIFOs (measured in emulation: ~100 µs, up to ~150 µs when the heartbeat is encoded at
/// the same moment), µs.
pub const PREPARE_LEAD_US: u32 = 300;
/// Margin kept in the schedule for the four strips not ending together, in µs. The board
/// now releases them in one register write (measured: same cycle), so this is headroom,
/// not an expected delay.
pub const STRIP_STAGGER_US: u32 = 20;
// Preparing the next phase pauses the strips, so the previous phase's bits must be out
// by then. Even when the write started the whole slack late, they end stagger + reset +
// settle before the trigger, and `check_timing` keeps the trigger before the next boundary.
const _: () = assert!(PREPARE_LEAD_US <= STRIP_STAGGER_US + WS2812_RESET_US);
/// The trigger must be armed at least this long before its edge, in µs.
pub const MIN_ARM_LEAD_US: u32 = 5;
/// Delay from a start request to the first phase boundary, in µs.
pub const START_DELAY_US: u32 = 2000;

/// Valid range of the phase period, µs.
pub const PERIOD_RANGE_US: core::ops::RangeInclusive<u32> = 1_000..=60_000_000;
/// Valid range of the trigger pulse width, µs.
pub const PULSE_RANGE_US: core::ops::RangeInclusive<u32> = 1..=100_000;
/// Valid range of the LED settle time, µs.
pub const SETTLE_RANGE_US: core::ops::RangeInclusive<u32> = 0..=1_000_000;

/// Upper bound of the time from the start of an LED write until the last bit of every
/// strip is out, for `frame_leds` pixels per strip (24 bits each).
pub const fn led_write_us(frame_leds: u16) -> u32 {
    led_bits_us(frame_leds) + STRIP_STAGGER_US
}

/// Time the bit stream of one strip of `frame_leds` pixels takes on the wire, µs
/// (rounded up).
pub const fn led_bits_us(frame_leds: u16) -> u32 {
    (frame_leds as u32 * 24 * WS2812_BIT_NS).div_ceil(1000)
}

/// Offset of the trigger edge from the phase start, µs.
pub const fn trigger_offset_us(timing: &Timing, frame_leds: u16) -> u32 {
    WRITE_START_SLACK_US + led_write_us(frame_leds) + WS2812_RESET_US + timing.led_settle_us
}

/// Check a timing: every field in range, and LED write + latch + settle + trigger pulse
/// fit within one phase.
pub fn check_timing(timing: &Timing, frame_leds: u16) -> Result<(), DeviceError> {
    if !PERIOD_RANGE_US.contains(&timing.phase_period_us) {
        return Err(DeviceError::InvalidValue(Field::PhasePeriod));
    }
    if !PULSE_RANGE_US.contains(&timing.trigger_pulse_us) {
        return Err(DeviceError::InvalidValue(Field::TriggerPulse));
    }
    if !SETTLE_RANGE_US.contains(&timing.led_settle_us) {
        return Err(DeviceError::InvalidValue(Field::LedSettle));
    }
    let needed = trigger_offset_us(timing, frame_leds) + timing.trigger_pulse_us;
    if needed >= timing.phase_period_us {
        return Err(DeviceError::TimingInfeasible {
            needed_us: needed,
            period_us: timing.phase_period_us,
        });
    }
    Ok(())
}

/// The phase shown at position `n` of a mode's sequence; `None` for [`Mode::Off`].
pub const fn phase_of(mode: Mode, n: u32) -> Option<Phase> {
    match mode {
        Mode::Off => None,
        Mode::Vision => Some(Phase::Dark),
        Mode::ContactShape => Some(Phase::All),
        Mode::Gradient => Some(if n.is_multiple_of(2) {
            Phase::Dx
        } else {
            Phase::Dy
        }),
        Mode::Interleaved => Some(match n % 3 {
            0 => Phase::Dark,
            1 => Phase::Dx,
            _ => Phase::Dy,
        }),
    }
}

/// One upcoming phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PhasePlan {
    /// Phase number since the sequence started.
    pub index: u32,
    /// What the strips show.
    pub phase: Phase,
    /// Phase start (the schedule's boundary), device µs.
    pub start_us: DeviceMicros,
    /// Trigger edge time, device µs.
    pub trigger_at_us: DeviceMicros,
    /// Trigger pulse width, µs.
    pub pulse_us: u32,
}

/// Counters kept by the sequencer.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SequenceCounters {
    /// Phases begun.
    pub phases: u32,
    /// Triggers fired.
    pub triggers: u32,
    /// Phases without a trigger because the LEDs were late, plus phases skipped entirely
    /// because the board fell more than a period behind.
    pub overruns: u32,
}

#[derive(Debug, Clone, Copy)]
struct Epoch {
    t0: DeviceMicros,
    k0: u32,
    mode: Mode,
    timing: Timing,
}

impl Epoch {
    fn boundary(&self, k: u32) -> DeviceMicros {
        self.t0 + u64::from(k - self.k0) * u64::from(self.timing.phase_period_us)
    }
}

/// The phase schedule (see the module documentation).
#[derive(Debug, Clone)]
pub struct Sequencer {
    frame_leds: u16,
    epoch: Option<Epoch>,
    next_index: u32,
    counters: SequenceCounters,
}

impl Sequencer {
    /// A stopped sequencer for a board that clocks out `frame_leds` pixels per strip.
    pub const fn new(frame_leds: u16) -> Self {
        Self {
            frame_leds,
            epoch: None,
            next_index: 0,
            counters: SequenceCounters {
                phases: 0,
                triggers: 0,
                overruns: 0,
            },
        }
    }

    /// Pixels clocked out per strip per phase.
    pub const fn frame_leds(&self) -> u16 {
        self.frame_leds
    }

    /// Whether a sequence is running.
    pub const fn is_running(&self) -> bool {
        self.epoch.is_some()
    }

    /// Counters since boot.
    pub const fn counters(&self) -> SequenceCounters {
        self.counters
    }

    /// Start `mode` with `timing` (already checked); the first phase starts
    /// [`START_DELAY_US`] after `now`. [`Mode::Off`] stops instead.
    pub fn start(&mut self, now: DeviceMicros, mode: Mode, timing: Timing) {
        self.epoch = (mode != Mode::Off).then_some(Epoch {
            t0: now + u64::from(START_DELAY_US),
            k0: self.next_index,
            mode,
            timing,
        });
    }

    /// Stop: no further phases.
    pub fn stop(&mut self) {
        self.epoch = None;
    }

    /// Change mode and timing while running: a new epoch begins at the next phase
    /// boundary of the current schedule (the phase under way is finished as planned).
    /// Does nothing when stopped.
    pub fn reconfigure(&mut self, mode: Mode, timing: Timing) {
        if let Some(epoch) = self.epoch {
            if mode == Mode::Off {
                self.epoch = None;
                return;
            }
            self.epoch = Some(Epoch {
                t0: epoch.boundary(self.next_index),
                k0: self.next_index,
                mode,
                timing,
            });
        }
    }

    /// The next phase to show, without committing to it (call again after a
    /// reconfiguration). If the board has fallen more than a whole period behind, the
    /// plan is for the first boundary not yet passed.
    pub fn plan(&self, now: DeviceMicros) -> Option<PhasePlan> {
        let epoch = self.epoch?;
        let mut k = self.next_index;
        let period = u64::from(epoch.timing.phase_period_us);
        let start = epoch.boundary(k);
        if now > start + period {
            // Skip whole phases that can no longer be shown.
            let behind = (now - start) / period;
            k = k.saturating_add(u32::try_from(behind).unwrap_or(u32::MAX));
        }
        let start_us = epoch.boundary(k);
        let n = k - epoch.k0;
        Some(PhasePlan {
            index: k,
            phase: phase_of(epoch.mode, n)?,
            start_us,
            trigger_at_us: start_us + u64::from(trigger_offset_us(&epoch.timing, self.frame_leds)),
            pulse_us: epoch.timing.trigger_pulse_us,
        })
    }

    /// Commit to `plan` as the LED write starts. Phases skipped since the last one count
    /// as overruns.
    pub fn begin(&mut self, plan: &PhasePlan) {
        let skipped = plan.index.saturating_sub(self.next_index);
        self.counters.overruns = self.counters.overruns.saturating_add(skipped);
        self.counters.phases = self.counters.phases.wrapping_add(1);
        self.next_index = plan.index.wrapping_add(1);
    }

    /// Decide the trigger of a begun phase, at `now`, just before arming it: fire at
    /// `plan.trigger_at_us` if the LEDs latched (`latched_us`) and settled in time and
    /// the edge is far enough ahead to arm; otherwise report an overrun.
    pub fn finish(
        &mut self,
        plan: &PhasePlan,
        settle_us: u32,
        write_start_us: DeviceMicros,
        latched_us: DeviceMicros,
        now: DeviceMicros,
    ) -> PhaseEvent {
        let ready = (latched_us + u64::from(settle_us)).max(now + u64::from(MIN_ARM_LEAD_US));
        let trigger = if ready <= plan.trigger_at_us {
            let index = self.counters.triggers;
            self.counters.triggers = index.wrapping_add(1);
            TriggerOutcome::Fired {
                index,
                edge_us: plan.trigger_at_us,
            }
        } else {
            self.counters.overruns = self.counters.overruns.wrapping_add(1);
            TriggerOutcome::Overrun {
                deadline_us: plan.trigger_at_us,
                ready_us: ready,
            }
        };
        PhaseEvent {
            index: plan.index,
            phase: plan.phase,
            scheduled_us: plan.start_us,
            write_start_us,
            latched_us,
            trigger,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MAX_LEDS_PER_STRIP;
    use proptest::prelude::*;

    const LEDS: u16 = MAX_LEDS_PER_STRIP;

    fn timing_strategy() -> impl Strategy<Value = Timing> {
        (2_000u32..2_000_000, 1u32..2_000, 0u32..5_000)
            .prop_map(|(p, w, s)| Timing {
                phase_period_us: p,
                trigger_pulse_us: w,
                led_settle_us: s,
            })
            .prop_filter("feasible", |t| check_timing(t, LEDS).is_ok())
    }

    fn mode_strategy() -> impl Strategy<Value = Mode> {
        prop_oneof![
            Just(Mode::Vision),
            Just(Mode::ContactShape),
            Just(Mode::Gradient),
            Just(Mode::Interleaved)
        ]
    }

    /// A virtual board: runs `phases` phases with the given write-start latencies and
    /// returns every plan with its event.
    fn run_board(
        seq: &mut Sequencer,
        timing: &Timing,
        mut now: u64,
        phases: usize,
        mut latency: impl FnMut(usize) -> u64,
    ) -> Vec<(PhasePlan, PhaseEvent)> {
        let mut out = Vec::new();
        for i in 0..phases {
            let plan = seq.plan(now).expect("running");
            now = now.max(plan.start_us) + latency(i); // board wakes late by `latency`
            seq.begin(&plan);
            let write_start = now;
            let latched = write_start + u64::from(led_write_us(LEDS) + WS2812_RESET_US);
            // The board arms when the DMA transfer has returned, before the latch.
            now = write_start + u64::from(led_write_us(LEDS));
            let event = seq.finish(&plan, timing.led_settle_us, write_start, latched, now);
            out.push((plan, event));
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

        #[test]
        fn schedule_has_zero_drift_and_triggers_avoid_led_transitions(
            timing in timing_strategy(),
            mode in mode_strategy(),
            t_start in 0u64..1u64 << 40,
            jitter in prop::collection::vec(0u64..WRITE_START_SLACK_US as u64, 1..64),
        ) {
            let mut seq = Sequencer::new(LEDS);
            seq.start(t_start, mode, timing);
            let t0 = t_start + u64::from(START_DELAY_US);
            let period = u64::from(timing.phase_period_us);
            let offset = u64::from(trigger_offset_us(&timing, LEDS));
            let events = run_board(&mut seq, &timing, t_start, 5000, |i| jitter[i % jitter.len()]);
            let mut expected_trigger = 0;
            for (k, (plan, event)) in events.iter().enumerate() {
                let k = k as u64;
                // Zero drift: every boundary is exactly t0 + kT, thousands of phases on.
                prop_assert_eq!(plan.start_us, t0 + k * period);
                prop_assert_eq!(event.index as u64, k);
                prop_assert_eq!(Some(event.phase), phase_of(mode, k as u32));
                match event.trigger {
                    TriggerOutcome::Fired { index, edge_us } => {
                        prop_assert_eq!(index, expected_trigger);
                        expected_trigger += 1;
                        prop_assert_eq!(edge_us, t0 + k * period + offset);
                        // After this phase's LEDs latched and settled ...
                        prop_assert!(edge_us >= event.latched_us + u64::from(timing.led_settle_us));
                        // ... and the pulse ends before the next phase's write begins.
                        prop_assert!(edge_us + u64::from(timing.trigger_pulse_us) < plan.start_us + period);
                    }
                    TriggerOutcome::Overrun { .. } => prop_assert!(false, "latency within slack"),
                }
            }
        }

        #[test]
        fn late_leds_become_overruns_never_early_triggers(
            timing in timing_strategy(),
            latencies in prop::collection::vec(0u64..3_000, 50..200),
        ) {
            let mut seq = Sequencer::new(LEDS);
            seq.start(0, Mode::Gradient, timing);
            let first_index = seq.plan(0).expect("running").index;
            let events = run_board(&mut seq, &timing, 0, latencies.len(), |i| latencies[i]);
            let mut overruns = 0;
            for (plan, event) in &events {
                let ready = event.latched_us + u64::from(timing.led_settle_us);
                match event.trigger {
                    TriggerOutcome::Fired { edge_us, .. } => prop_assert!(edge_us >= ready),
                    TriggerOutcome::Overrun { deadline_us, ready_us } => {
                        overruns += 1;
                        prop_assert_eq!(deadline_us, plan.trigger_at_us);
                        prop_assert!(ready_us > deadline_us);
                    }
                }
            }
            // A board later than a whole period skips phases; the counter includes them.
            let last_index = events.last().expect("at least 50 phases").0.index;
            let skipped = last_index + 1 - first_index - events.len() as u32;
            prop_assert_eq!(seq.counters().overruns, overruns + skipped);
            prop_assert_eq!(seq.counters().triggers + overruns, events.len() as u32);
        }

        #[test]
        fn infeasible_timings_are_refused(
            period in 1_000u32..5_000, pulse in 1u32..5_000, settle in 0u32..5_000,
        ) {
            let timing = Timing { phase_period_us: period, trigger_pulse_us: pulse, led_settle_us: settle };
            let needed = trigger_offset_us(&timing, LEDS) + pulse;
            let result = check_timing(&timing, LEDS);
            if needed >= period {
                prop_assert_eq!(result, Err(DeviceError::TimingInfeasible { needed_us: needed, period_us: period }));
            } else {
                prop_assert_eq!(result, Ok(()));
            }
        }
    }

    #[test]
    fn default_timing_is_feasible_with_room_for_exposure() {
        let t = Timing::DEFAULT;
        check_timing(&t, LEDS).unwrap();
        // slack 100 + write (32 px x 30 µs + 20) 980 + reset 300 + settle 500 = 1880 µs.
        assert_eq!(trigger_offset_us(&t, LEDS), 1880);
    }

    #[test]
    fn falling_far_behind_skips_phases_and_counts_them() {
        let t = Timing::DEFAULT;
        let mut seq = Sequencer::new(LEDS);
        seq.start(0, Mode::Gradient, t);
        let first = seq.plan(0).unwrap();
        seq.begin(&first);
        // The board stalls for 1.1 s: phases 1..4 are gone.
        let now = first.start_us + 1_100_000;
        let plan = seq.plan(now).unwrap();
        assert_eq!(plan.index, 4);
        assert_eq!(plan.start_us, first.start_us + 4 * 250_000);
        assert_eq!(plan.phase, Phase::Dx);
        seq.begin(&plan);
        assert_eq!(seq.counters().overruns, 3);
    }

    #[test]
    fn reconfiguring_starts_a_new_epoch_at_the_next_boundary() {
        let t = Timing::DEFAULT;
        let mut seq = Sequencer::new(LEDS);
        seq.start(0, Mode::Gradient, t);
        for _ in 0..3 {
            let p = seq.plan(0).unwrap();
            seq.begin(&p);
        }
        let next_boundary = 2000 + 3 * 250_000;
        let fast = Timing {
            phase_period_us: 100_000,
            ..t
        };
        seq.reconfigure(Mode::Interleaved, fast);
        let p = seq.plan(0).unwrap();
        assert_eq!(
            (p.index, p.start_us, p.phase),
            (3, next_boundary, Phase::Dark)
        );
        seq.begin(&p);
        let p = seq.plan(0).unwrap();
        assert_eq!((p.start_us, p.phase), (next_boundary + 100_000, Phase::Dx));
        seq.reconfigure(Mode::Off, fast);
        assert!(!seq.is_running());
        assert_eq!(seq.plan(0), None);
    }

    #[test]
    fn modes_cycle_through_their_phases() {
        use Phase::*;
        let seq = |m| (0..6).map(|n| phase_of(m, n).unwrap()).collect::<Vec<_>>();
        assert_eq!(seq(Mode::Gradient), [Dx, Dy, Dx, Dy, Dx, Dy]);
        assert_eq!(seq(Mode::Interleaved), [Dark, Dx, Dy, Dark, Dx, Dy]);
        assert_eq!(seq(Mode::Vision), [Dark; 6]);
        assert_eq!(seq(Mode::ContactShape), [All; 6]);
        assert_eq!(phase_of(Mode::Off, 0), None);
    }
}
