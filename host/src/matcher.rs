//! Which LED phase lit each camera frame.
//!
//! Input: phase events on the host clock ([`HostPhase`], from [`crate::device::Sensor`])
//! and frame timestamps on the same clock (V4L2 stamps buffers with `CLOCK_MONOTONIC`).
//! Each frame's exposure interval is checked against the LED timeline: phase `k` is
//! steady from its latch plus the settle time until the next phase's LED write starts.
//!
//! * **Hardware-triggered cameras**: the exposure must start one trigger latency after a
//!   trigger edge (within a tolerance); the frame gets that trigger's index.
//! * **Free-running cameras**: any exposure that fits inside one steady interval is
//!   labelled with that phase.
//!
//! A frame is never mislabelled: an exposure that overlaps an LED change is
//! [`Label::Straddles`]; one that falls where a phase event was lost, or in the phase
//! before it (whose end is then unknown), is [`Label::EventMissing`]; a triggered frame with no matching edge is
//! [`Label::NoTrigger`]. Dropped frames show as gaps in the camera's sequence numbers and,
//! for triggered cameras, as triggers no frame answered; dropped events as gaps in the
//! phase index. Every interval is widened by a guard for the clock-sync uncertainty.
//!
//! **When a frame is decided.** A frame's light is known once its exposure is known to
//! end before the next LED change. The next phase event proves that, but it comes a
//! whole phase later (250 ms at 4 Hz). The firmware never starts an LED write before its
//! schedule `t0 + k·T` (it may start late, never early), so once two phases of the
//! running sequence give the period, the next write cannot start before the latest
//! phase's schedule plus one period: an exposure that ends a guard before that
//! (mapped to the host clock with 200 ppm of drift allowed and the sync's uncertainty
//! subtracted) is decided as soon as the frame arrives. The host's own Stop comes after
//! every frame it has already received, so stopping cannot change a decided frame.

use std::collections::VecDeque;

use stereotac_protocol::Phase;

use crate::device::HostPhase;

/// One camera frame's timing on the host clock.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameStamp {
    /// The camera's frame sequence number.
    pub sequence: u64,
    /// Timestamp, host µs (see [`StampRef`]).
    pub timestamp_us: f64,
    /// Exposure time, µs.
    pub exposure_us: f64,
}

impl FrameStamp {
    /// Start of the exposure, host µs, for a source whose stamps mark `stamp_ref`.
    pub fn exposure_start_us(&self, stamp_ref: StampRef) -> f64 {
        match stamp_ref {
            StampRef::ExposureStart => self.timestamp_us,
            StampRef::ExposureEnd => self.timestamp_us - self.exposure_us,
        }
    }

    /// End of the exposure, host µs, for a source whose stamps mark `stamp_ref`.
    pub fn exposure_end_us(&self, stamp_ref: StampRef) -> f64 {
        match stamp_ref {
            StampRef::ExposureStart => self.timestamp_us + self.exposure_us,
            StampRef::ExposureEnd => self.timestamp_us,
        }
    }
}

/// What a frame timestamp marks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampRef {
    /// The start of the exposure (V4L2 `TSTAMP_SRC_SOE`).
    ExposureStart,
    /// The end of the exposure / frame (V4L2 `TSTAMP_SRC_EOF`, most UVC cameras).
    ExposureEnd,
}

/// How the camera is clocked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraSync {
    /// One frame per trigger edge; the exposure starts `latency_us` after the edge.
    Triggered {
        /// Edge-to-exposure-start latency, µs.
        latency_us: f64,
        /// Largest accepted deviation from that latency, µs.
        tolerance_us: f64,
    },
    /// The camera runs on its own clock.
    FreeRunning,
}

/// Settings of a [`FrameMatcher`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatcherConfig {
    /// Camera clocking.
    pub sync: CameraSync,
    /// What the frame timestamps mark.
    pub stamp: StampRef,
    /// LED settle time after the latch, µs (the firmware's `led_settle_us`).
    pub settle_us: f64,
    /// Margin on every LED boundary for timestamp and clock-sync error, µs.
    pub guard_us: f64,
}

impl Default for MatcherConfig {
    fn default() -> Self {
        Self {
            sync: CameraSync::Triggered {
                latency_us: 0.0,
                tolerance_us: 1000.0,
            },
            stamp: StampRef::ExposureStart,
            settle_us: 500.0,
            guard_us: 100.0,
        }
    }
}

/// The verdict on one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "label", rename_all = "snake_case")]
pub enum Label {
    /// Lit by one phase from start to end of the exposure.
    Phase {
        /// Phase index k of the sequence.
        index: u32,
        /// What the strips showed.
        #[serde(with = "phase_name")]
        phase: Phase,
        /// The trigger that started the exposure (triggered cameras).
        trigger: Option<u32>,
    },
    /// The exposure overlaps an LED change.
    Straddles,
    /// The frame falls where a phase event was lost: the light is unknown.
    EventMissing,
    /// A triggered frame that no trigger edge explains.
    NoTrigger,
    /// No event after the frame arrived (the sequence stopped or the stream ended).
    Unresolved,
}

mod phase_name {
    use stereotac_protocol::Phase;

    pub fn serialize<S: serde::Serializer>(p: &Phase, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(super::phase_str(*p))
    }
}

/// Lower-case name of a phase, as written in record indexes.
pub fn phase_str(p: Phase) -> &'static str {
    match p {
        Phase::Dark => "dark",
        Phase::All => "all",
        Phase::Dx => "dx",
        Phase::Dy => "dy",
    }
}

/// A frame and its label.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchedFrame {
    /// The frame.
    pub frame: FrameStamp,
    /// Its label.
    pub label: Label,
}

/// What the matcher counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct MatchStats {
    /// Frames decided.
    pub frames: u64,
    /// Frames labelled with a phase.
    pub labelled: u64,
    /// Frames rejected for overlapping an LED change.
    pub straddling: u64,
    /// Frames in a phase whose event was lost.
    pub event_missing: u64,
    /// Triggered frames with no matching trigger.
    pub no_trigger: u64,
    /// Frames left undecided at the end.
    pub unresolved: u64,
    /// Frames the camera dropped (sequence gaps, and triggers no frame answered).
    pub dropped_frames: u64,
    /// Phase events lost (gaps in the phase index).
    pub dropped_events: u64,
}

/// Labels frames against phase events (see the module documentation).
#[derive(Debug, Clone)]
pub struct FrameMatcher {
    config: MatcherConfig,
    /// Phases in time order (a restarted sequence begins again at index 0).
    phases: Vec<HostPhase>,
    /// `gap_before[i]`: events were lost between `phases[i-1]` and `phases[i]`.
    gap_before: Vec<bool>,
    pending: VecDeque<FrameStamp>,
    last_sequence: Option<u64>,
    /// Triggered phases not yet answered by a frame: (trigger index, edge).
    unanswered: VecDeque<(u32, f64)>,
    /// The earliest host time the next LED write can start, when the period is known.
    next_write_floor: Option<f64>,
    stats: MatchStats,
}

impl FrameMatcher {
    /// An empty matcher.
    pub fn new(config: MatcherConfig) -> Self {
        Self {
            config,
            phases: Vec::new(),
            gap_before: Vec::new(),
            pending: VecDeque::new(),
            last_sequence: None,
            unanswered: VecDeque::new(),
            next_write_floor: None,
            stats: MatchStats::default(),
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> MatchStats {
        self.stats
    }

    /// A phase event arrived (in time order).
    pub fn add_phase(&mut self, phase: HostPhase) {
        let gap = match self.phases.last() {
            Some(last) if phase.event.index > last.event.index => {
                let missing = phase.event.index - last.event.index - 1;
                self.stats.dropped_events += u64::from(missing);
                missing > 0
            }
            // The first event of a (re)started sequence: nothing known to be missing.
            _ => false,
        };
        if let Some(t) = phase.trigger {
            self.unanswered.push_back(t);
        }
        self.next_write_floor = self
            .phases
            .last()
            .and_then(|prev| next_write_floor(prev, &phase));
        self.phases.push(phase);
        self.gap_before.push(gap);
    }

    /// A frame arrived (in sequence order).
    pub fn add_frame(&mut self, frame: FrameStamp) {
        // Triggered cameras count drops as unanswered triggers instead.
        let free_running = self.config.sync == CameraSync::FreeRunning;
        if let Some(last) = self.last_sequence
            && free_running
            && frame.sequence > last + 1
        {
            self.stats.dropped_frames += frame.sequence - last - 1;
        }
        self.last_sequence = Some(frame.sequence);
        self.pending.push_back(frame);
    }

    /// Frames whose light is now known: their exposure ends before a reported LED
    /// change, or before the earliest the next one can come (module documentation).
    pub fn ready(&mut self) -> Vec<MatchedFrame> {
        let reported = self
            .phases
            .last()
            .map_or(f64::NEG_INFINITY, |p| p.write_start_us);
        let horizon = self.next_write_floor.map_or(reported, |f| f.max(reported));
        let mut out = Vec::new();
        while let Some(frame) = self.pending.front().copied() {
            let (_, end) = self.exposure(&frame);
            if end + self.config.guard_us > horizon {
                break;
            }
            self.pending.pop_front();
            out.push(self.decide(frame, false));
        }
        self.count_unanswered(out.last().map(|m| self.exposure(&m.frame).0));
        out
    }

    /// Decide every pending frame (end of the stream). Triggers after the last frame are
    /// not counted as dropped: the stream ended before their frames could arrive.
    pub fn finish(&mut self) -> Vec<MatchedFrame> {
        let out: Vec<MatchedFrame> = std::mem::take(&mut self.pending)
            .into_iter()
            .map(|f| self.decide(f, true))
            .collect();
        self.count_unanswered(out.last().map(|m| self.exposure(&m.frame).0));
        out
    }

    /// Triggers older than the newest decided frame that no frame answered were dropped.
    fn count_unanswered(&mut self, decided_until: Option<f64>) {
        let CameraSync::Triggered { tolerance_us, .. } = self.config.sync else {
            self.unanswered.clear();
            return;
        };
        let Some(until) = decided_until else { return };
        while self
            .unanswered
            .front()
            .is_some_and(|(_, edge)| *edge + tolerance_us < until)
        {
            self.unanswered.pop_front();
            self.stats.dropped_frames += 1;
        }
    }

    fn exposure(&self, f: &FrameStamp) -> (f64, f64) {
        (
            f.exposure_start_us(self.config.stamp),
            f.exposure_end_us(self.config.stamp),
        )
    }

    fn decide(&mut self, frame: FrameStamp, at_end: bool) -> MatchedFrame {
        let label = self.label(&frame, at_end);
        let s = &mut self.stats;
        s.frames += 1;
        match label {
            Label::Phase { .. } => s.labelled += 1,
            Label::Straddles => s.straddling += 1,
            Label::EventMissing => s.event_missing += 1,
            Label::NoTrigger => s.no_trigger += 1,
            Label::Unresolved => s.unresolved += 1,
        }
        MatchedFrame { frame, label }
    }

    fn label(&mut self, frame: &FrameStamp, at_end: bool) -> Label {
        let (start, end) = self.exposure(frame);
        let guard = self.config.guard_us;
        let mut trigger = None;
        if let CameraSync::Triggered {
            latency_us,
            tolerance_us,
        } = self.config.sync
        {
            let edge_time = start - latency_us;
            // A phase's edge lies between its latch and the next phase's write, so the
            // nearest edge belongs to one of the phases around the latch before it.
            let k = self.phases.partition_point(|p| p.latched_us <= edge_time);
            // The edge's host time is known to within the clock sync's uncertainty when
            // it was mapped (large right after connecting), so that widens the match.
            let best = self.phases[k.saturating_sub(2)..(k + 1).min(self.phases.len())]
                .iter()
                .filter_map(|p| p.trigger.map(|t| (t, p.uncertainty_us)))
                .min_by(|(a, _), (b, _)| {
                    (a.1 - edge_time).abs().total_cmp(&(b.1 - edge_time).abs())
                });
            match best {
                Some(((index, edge), uncertainty))
                    if (edge - edge_time).abs() <= tolerance_us + uncertainty.max(0.0) =>
                {
                    trigger = Some(index);
                    self.unanswered.retain(|(i, _)| *i != index);
                }
                _ => {
                    return if self.in_gap(start) {
                        Label::EventMissing
                    } else {
                        Label::NoTrigger
                    };
                }
            }
        }
        // The phase whose light was on when the exposure started.
        let k = self.phases.partition_point(|p| p.latched_us <= start);
        let Some(i) = k.checked_sub(1) else {
            return Label::Straddles; // before the first known LED change: unknown light
        };
        let phase = self.phases[i];
        if i + 1 < self.phases.len() && self.gap_before[i + 1] {
            return Label::EventMissing;
        }
        let steady_from = phase.latched_us + self.config.settle_us;
        let steady_until = match self.phases.get(i + 1) {
            Some(next) => next.write_start_us,
            None if at_end => return Label::Unresolved,
            None => f64::INFINITY,
        };
        // A trigger only fires once the LEDs have settled (the firmware's promise); a
        // free-running exposure must start a guard after the settle.
        let starts_steady = trigger.is_some() || start >= steady_from + guard;
        if !starts_steady || end > steady_until - guard {
            return Label::Straddles;
        }
        Label::Phase {
            index: phase.event.index,
            phase: phase.event.phase,
            trigger,
        }
    }

    /// Whether host time `t` lies in a stretch where phase events were lost.
    fn in_gap(&self, t: f64) -> bool {
        let k = self.phases.partition_point(|p| p.latched_us <= t);
        k < self.phases.len() && self.gap_before[k]
    }
}

/// Largest device clock drift the early decision allows for, ppm (crystals are within
/// ±50; the fit's own figure is not trusted for this).
const DRIFT_BOUND_PPM: f64 = 200.0;

/// The earliest host time the LED write after `latest` can start, given the phase
/// before it in the same running sequence; `None` when the two do not give a period (a
/// restart, a repeated index, schedules out of order).
fn next_write_floor(prev: &HostPhase, latest: &HostPhase) -> Option<f64> {
    let steps = latest.event.index.checked_sub(prev.event.index)?;
    let span = latest
        .event
        .scheduled_us
        .checked_sub(prev.event.scheduled_us)?;
    if steps == 0 || span == 0 {
        return None;
    }
    let period_dev = span as f64 / f64::from(steps);
    // Device µs from the latest write's start to the next schedule (the write may have
    // started late; the next schedule does not move).
    let next_dev = latest.event.scheduled_us as f64 + period_dev;
    let ahead_dev = next_dev - latest.event.write_start_us as f64;
    if !(ahead_dev.is_finite() && ahead_dev > 0.0) {
        return None;
    }
    let slope_min = 1.0 - DRIFT_BOUND_PPM * 1e-6;
    Some(latest.write_start_us + ahead_dev * slope_min - 2.0 * latest.uncertainty_us.max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereotac_protocol::{PhaseEvent, TriggerOutcome};

    const T: f64 = 250_000.0;

    /// Phase k of a gradient sequence on the host clock; `fired` = trigger index.
    fn phase(k: u32, fired: Option<u32>) -> HostPhase {
        let write_start_us = 1_000_000.0 + f64::from(k) * T + 103.0;
        let latched_us = write_start_us + 1280.0;
        HostPhase {
            event: PhaseEvent {
                index: k,
                phase: if k.is_multiple_of(2) {
                    Phase::Dx
                } else {
                    Phase::Dy
                },
                scheduled_us: 0,
                write_start_us: 0,
                latched_us: 0,
                trigger: TriggerOutcome::Overrun {
                    deadline_us: 0,
                    ready_us: 0,
                },
            },
            write_start_us,
            latched_us,
            trigger: fired.map(|i| (i, latched_us + 500.0)),
            uncertainty_us: 5.0,
        }
    }

    fn triggered() -> MatcherConfig {
        MatcherConfig {
            sync: CameraSync::Triggered {
                latency_us: 40.0,
                tolerance_us: 300.0,
            },
            ..MatcherConfig::default()
        }
    }

    fn frame(sequence: u64, timestamp_us: f64) -> FrameStamp {
        FrameStamp {
            sequence,
            timestamp_us,
            exposure_us: 8000.0,
        }
    }

    #[test]
    fn a_trigger_is_matched_within_the_tolerance_plus_the_sync_uncertainty() {
        // 700 µs off: beyond the 300 µs tolerance, within it plus an 800 µs uncertainty.
        for (uncertainty, matched) in [(5.0, false), (800.0, true)] {
            let mut m = FrameMatcher::new(triggered());
            let mut out = Vec::new();
            for k in 0..3u32 {
                let p = HostPhase {
                    uncertainty_us: uncertainty,
                    ..phase(k, Some(k))
                };
                m.add_phase(p);
                out.extend(m.ready());
                if k == 0 {
                    m.add_frame(frame(0, p.trigger.unwrap().1 + 40.0 + 700.0));
                }
            }
            out.extend(m.finish());
            let want = if matched {
                Label::Phase {
                    index: 0,
                    phase: Phase::Dx,
                    trigger: Some(0),
                }
            } else {
                Label::NoTrigger
            };
            assert_eq!(out[0].label, want, "uncertainty {uncertainty} µs");
        }
    }

    fn jitter(k: u64) -> f64 {
        ((k * 7919) % 101) as f64 - 50.0
    }

    #[test]
    fn triggered_frames_get_their_phase_and_trigger() {
        let mut m = FrameMatcher::new(triggered());
        let mut out = Vec::new();
        for k in 0..20u32 {
            let p = phase(k, Some(k));
            m.add_phase(p);
            out.extend(m.ready());
            let edge = p.trigger.unwrap().1;
            m.add_frame(frame(u64::from(k), edge + 40.0 + jitter(u64::from(k))));
        }
        out.extend(m.finish());
        assert_eq!(out.len(), 20);
        for (k, f) in out.iter().enumerate().take(19) {
            let k = k as u32;
            let want = if k.is_multiple_of(2) {
                Phase::Dx
            } else {
                Phase::Dy
            };
            assert_eq!(
                f.label,
                Label::Phase {
                    index: k,
                    phase: want,
                    trigger: Some(k)
                }
            );
        }
        assert_eq!(
            out[19].label,
            Label::Unresolved,
            "no event after the last frame"
        );
        let s = m.stats();
        assert_eq!((s.labelled, s.unresolved, s.dropped_frames), (19, 1, 0));
    }

    #[test]
    fn dropped_frames_events_and_overruns_are_counted_never_mislabelled() {
        let mut m = FrameMatcher::new(triggered());
        let mut out = Vec::new();
        let mut trigger = 0;
        for k in 0..30u32 {
            let overrun = k == 11;
            let p = phase(k, (!overrun).then_some(trigger));
            if k != 17 {
                m.add_phase(p); // event 17 is lost on the link
            }
            out.extend(m.ready());
            if let Some((i, edge)) = p.trigger {
                trigger += 1;
                if k != 5 && k != 23 {
                    // frames 5 and 23 are dropped by the camera
                    m.add_frame(frame(u64::from(i), edge + 40.0 + jitter(u64::from(k))));
                }
            }
        }
        m.add_phase(phase(30, Some(trigger)));
        out.extend(m.ready());
        let s = m.stats();
        assert_eq!(s.dropped_frames, 2, "{s:?}");
        assert_eq!(s.dropped_events, 1);
        // The frame of the lost phase, and the one before it: when its light ended is
        // unknown without the next event.
        assert_eq!(s.event_missing, 2, "{s:?}");
        assert_eq!(s.labelled, 25);
        for f in &out {
            if let Label::Phase { index, phase, .. } = f.label {
                assert_eq!(
                    phase,
                    if index.is_multiple_of(2) {
                        Phase::Dx
                    } else {
                        Phase::Dy
                    }
                );
                assert!(index != 17 && index != 11);
            }
        }
    }

    #[test]
    fn free_running_exposures_across_an_led_change_are_rejected() {
        let config = MatcherConfig {
            sync: CameraSync::FreeRunning,
            stamp: StampRef::ExposureEnd,
            ..MatcherConfig::default()
        };
        let mut m = FrameMatcher::new(config);
        for k in 0..10 {
            m.add_phase(phase(k, Some(k)));
        }
        // 30 fps, 8 ms exposures stamped at their end.
        let mut out = Vec::new();
        for n in 0..70u64 {
            let end = 1_000_000.0 + n as f64 * 33_333.0 + 9000.0;
            m.add_frame(frame(n, end));
        }
        out.extend(m.ready());
        out.extend(m.finish());
        let mut straddling = 0;
        for f in &out {
            let (start, end) = (f.frame.timestamp_us - 8000.0, f.frame.timestamp_us);
            // The truth: which LED changes the exposure overlaps.
            let k = ((start - 1_000_000.0) / T).floor() as u32;
            let change_start = |k: u32| phase(k, None).write_start_us - 100.0;
            let steady = |k: u32| phase(k, None).latched_us + 500.0 + 100.0;
            let clean = start >= steady(k) && end <= change_start(k + 1);
            match f.label {
                Label::Phase { index, trigger, .. } => {
                    assert!(clean, "{f:?}");
                    assert_eq!(index, k);
                    assert_eq!(trigger, None);
                }
                Label::Straddles => {
                    straddling += 1;
                    assert!(!clean, "{f:?}");
                }
                Label::Unresolved => assert!(k >= 9),
                other => panic!("{other:?}"),
            }
        }
        assert!(straddling >= 2, "some exposures straddle a change");
        assert_eq!(m.stats().dropped_frames, 0);
        m.add_frame(frame(75, 4_000_000.0));
        assert_eq!(m.stats().dropped_frames, 5, "sequence gap 70..74");
    }

    #[test]
    fn a_frame_with_no_trigger_is_flagged() {
        let mut m = FrameMatcher::new(triggered());
        m.add_phase(phase(0, Some(0)));
        m.add_phase(phase(1, Some(1)));
        m.add_frame(frame(0, 1_100_000.0)); // mid-phase: no edge near
        m.add_phase(phase(2, Some(2)));
        let out = m.ready();
        assert_eq!(out[0].label, Label::NoTrigger);
    }

    /// Phase k with its device schedule (`t0 + k·T`, write 103 µs late), the device
    /// clock equal to the host's.
    fn scheduled(k: u32) -> HostPhase {
        let p = phase(k, Some(k));
        let scheduled = 1_000_000 + u64::from(k) * T as u64;
        HostPhase {
            event: PhaseEvent {
                scheduled_us: scheduled,
                write_start_us: scheduled + 103,
                ..p.event
            },
            ..p
        }
    }

    #[test]
    fn a_frame_is_decided_when_it_arrives_once_the_schedule_bounds_the_next_change() {
        let mut m = FrameMatcher::new(triggered());
        let edge = |p: &HostPhase| p.trigger.unwrap().1;
        // One phase: the period is unknown, so its frame waits for the next event.
        let p0 = scheduled(0);
        m.add_phase(p0);
        m.add_frame(frame(0, edge(&p0) + 40.0));
        assert!(m.ready().is_empty(), "no period yet");
        let p1 = scheduled(1);
        m.add_phase(p1);
        assert_eq!(m.ready().len(), 1, "phase 1's event decides frame 0");
        // From now on a frame is decided as soon as it arrives, with no event after it.
        m.add_frame(frame(1, edge(&p1) + 40.0));
        let out = m.ready();
        assert_eq!(
            out.first().map(|f| f.label),
            Some(Label::Phase {
                index: 1,
                phase: Phase::Dy,
                trigger: Some(1)
            })
        );
        // An exposure running up to the next schedule is not: it might straddle.
        let late = HostPhase { ..scheduled(2) };
        m.add_phase(late);
        m.add_frame(FrameStamp {
            sequence: 2,
            timestamp_us: edge(&late) + 40.0,
            exposure_us: T - 1500.0,
        });
        assert!(
            m.ready().is_empty(),
            "ends within the guard of the next write"
        );
        m.add_phase(scheduled(3));
        assert_eq!(
            m.ready().first().map(|f| f.label),
            Some(Label::Straddles),
            "and the next event shows it does"
        );
        // A restarted sequence (index back to 0) forgets the period.
        m.add_phase(scheduled(0));
        m.add_frame(frame(3, edge(&scheduled(0)) + 40.0));
        assert!(m.ready().is_empty(), "restart: no period");
    }
}
