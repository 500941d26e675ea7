//! The default pin map of the sensor board (Raspberry Pi Pico). One table: the board
//! code checks its peripherals against it at start-up and the README repeats it.

/// GPIO numbers of every signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PinMap {
    /// WS2812 data lines of strips 1..4 (x-, y-, x+, y+).
    pub strips: [u8; 4],
    /// Camera frame-sync trigger output, active high.
    pub trigger: u8,
    /// On-board status LED.
    pub status_led: u8,
    /// Loopback probe input for the trigger: wire it to `trigger` to have the firmware
    /// time its own trigger edges (pulled down when unconnected).
    pub probe_trigger: u8,
    /// Loopback probe input for strip 1's data: wire it to `strips[0]` to have the
    /// firmware decode what it sent (pulled down when unconnected).
    pub probe_strip: u8,
}

/// The board's wiring.
pub const PINS: PinMap = PinMap {
    strips: [2, 3, 4, 5],
    trigger: 6,
    status_led: 25,
    probe_trigger: 7,
    probe_strip: 8,
};
