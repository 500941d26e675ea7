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
