//! Pin traces from the emulator: every level change of the traced pins, in simulated
//! nanoseconds since reset.

use stereotac_firmware::pins::PINS;

/// One level change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Edge {
    /// Simulated time, ns since reset.
    pub t_ns: u64,
    /// GPIO number.
    pub pin: u8,
    /// New level.
    pub high: bool,
}

/// The edges of the traced pins, in time order.
#[derive(Debug, Clone, Default)]
pub struct PinTrace {
    edges: Vec<Edge>,
}

impl PinTrace {
    /// Append edges (already in time order, after the ones held).
    pub fn extend(&mut self, edges: impl IntoIterator<Item = Edge>) {
        self.edges.extend(edges);
    }

    /// All edges.
    pub fn edges(&self) -> &[Edge] {
        &self.edges
    }

    /// The edges of one pin.
    pub fn pin(&self, pin: u8) -> Vec<Edge> {
        self.edges
            .iter()
            .filter(|e| e.pin == pin)
            .copied()
            .collect()
    }

    /// Rising edges of the camera trigger pin, ns.
    pub fn trigger_rises(&self) -> Vec<u64> {
        self.pin(PINS.trigger)
            .iter()
            .filter(|e| e.high)
            .map(|e| e.t_ns)
            .collect()
    }

    /// Rising edges of the camera trigger pin within `range` (ns).
    pub fn trigger_rises_in(&self, range: std::ops::Range<u64>) -> Vec<u64> {
        self.trigger_rises()
            .into_iter()
            .filter(|r| range.contains(r))
            .collect()
    }

    /// Forget everything before `t_ns`.
    pub fn clear_before(&mut self, t_ns: u64) {
        self.edges.retain(|e| e.t_ns >= t_ns);
    }
}

/// Checks that every interval between consecutive `rises` (ns) is `period_ns` within
/// 1 µs; returns the shortest and longest interval ((`i64::MAX`, `i64::MIN`) for fewer
/// than two edges), or the first interval that is off. For traced and probed edges alike.
pub fn check_periods(rises: &[u64], period_ns: i64) -> Result<(i64, i64), String> {
    let mut range = (i64::MAX, i64::MIN);
    for w in rises.windows(2) {
        let d = w[1] as i64 - w[0] as i64;
        if (d - period_ns).abs() > 1_000 {
            return Err(format!("trigger period {d} ns, not {period_ns} ns"));
        }
        range = (range.0.min(d), range.1.max(d));
    }
    Ok(range)
}

/// Checks that the span of `rises` (ns) is (edges − 1) periods within 1 µs: no drift.
/// Returns the drift (span minus the periods, ns; 0 without edges).
pub fn check_no_drift(rises: &[u64], period_ns: i64) -> Result<i64, String> {
    let (Some(first), Some(last)) = (rises.first(), rises.last()) else {
        return Ok(0);
    };
    let drift = (*last as i64 - *first as i64) - (rises.len() as i64 - 1) * period_ns;
    if drift.abs() > 1_000 {
        return Err(format!(
            "trigger drift {drift} ns over {} edges",
            rises.len()
        ));
    }
    Ok(drift)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edge_trains_are_checked_interval_by_interval_and_end_to_end() {
        let exact: Vec<u64> = (0..5).map(|k| 1_000 + k * 50_000).collect();
        assert_eq!(check_periods(&exact, 50_000), Ok((50_000, 50_000)));
        assert_eq!(check_no_drift(&exact, 50_000), Ok(0));
        // Each interval 900 ns long: every one passes, the span drifts 3.6 µs.
        let creeping: Vec<u64> = (0..5).map(|k| k * 50_900).collect();
        assert_eq!(check_periods(&creeping, 50_000), Ok((50_900, 50_900)));
        assert!(
            check_no_drift(&creeping, 50_000)
                .unwrap_err()
                .contains("3600 ns")
        );
        // One interval 1.1 µs long.
        let jump = [0, 50_000, 101_100];
        assert!(
            check_periods(&jump, 50_000)
                .unwrap_err()
                .contains("51100 ns")
        );
        assert_eq!(check_periods(&[7], 50_000), Ok((i64::MAX, i64::MIN)));
        assert_eq!(check_no_drift(&[], 50_000), Ok(0));
    }
}
