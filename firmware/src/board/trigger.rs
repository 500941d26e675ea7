//! The camera frame-sync trigger: a PIO1 state machine that drives the trigger pin
//! (side-set) high for an exact number of clock cycles after an exact delay.
//!
//! ```text
//! wrap_target:
//!     pull block      side 0   ; pulse width - 1, in cycles
//!     out  y, 32      side 0
//!     pull block      side 0   ; delay, in cycles (see `arm`)
//!     out  x, 32      side 0
//! wait:
//!     jmp  x--, wait  side 0
//! high:
//!     jmp  y--, high  side 1   ; the rising edge is this instruction's first cycle
//! wrap                          ; back to `pull` with side 0: falling edge
//! ```
//!
//! [`arm`] is called inside a critical section right after a 1 MHz timer tick, so the
//! edge lands on the requested microsecond, independent of executor latency.

use core::cell::RefCell;

use embassy_rp::Peri;
use embassy_rp::clocks::clk_sys_freq;
use embassy_rp::gpio::Pin;
use embassy_rp::peripherals::{PIN_6, PIO1};
use embassy_rp::pio::{Common, Config, Direction, StateMachine};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::Instant;

/// Cycles from the timer tick to the countdown's start, beyond the program's own 3
/// (the spin loop's exit, the push, the `pull`): calibrated in the emulated RP2040
/// (hil-tests, gradient test: edges landed 1.01-1.17 µs late with 4), to be re-checked
/// on a real sensor with the trigger looped back.
const ARM_LATENCY_CYCLES: u32 = 140;

static TRIGGER: Mutex<CriticalSectionRawMutex, RefCell<Option<TriggerPio>>> =
    Mutex::new(RefCell::new(None));

/// The trigger state machine.
pub struct TriggerPio {
    sm: StateMachine<'static, PIO1, 0>,
    cycles_per_us: u32,
    pin: u8,
}

impl TriggerPio {
    /// Load the program into PIO1 and drive `pin` low with state machine 0.
    pub fn new(
        common: &mut Common<'static, PIO1>,
        mut sm0: StateMachine<'static, PIO1, 0>,
        pin: Peri<'static, PIN_6>,
    ) -> Self {
        let number = pin.pin();
        let side_set = pio::SideSet::new(false, 1, false);
        let mut a: pio::Assembler<32> = pio::Assembler::new_with_side_set(side_set);
        let mut wrap_target = a.label();
        let mut wrap_source = a.label();
        let mut wait = a.label();
        let mut high = a.label();
        a.bind(&mut wrap_target);
        a.pull_with_side_set(false, true, 0);
        a.out_with_side_set(pio::OutDestination::Y, 32, 0);
        a.pull_with_side_set(false, true, 0);
        a.out_with_side_set(pio::OutDestination::X, 32, 0);
        a.bind(&mut wait);
        a.jmp_with_side_set(pio::JmpCondition::XDecNonZero, &mut wait, 0);
        a.bind(&mut high);
        a.jmp_with_side_set(pio::JmpCondition::YDecNonZero, &mut high, 1);
        a.bind(&mut wrap_source);
        let program = a.assemble_with_wrap(wrap_source, wrap_target);
        let loaded = common.load_program(&program);

        let pin = common.make_pio_pin(pin);
        let mut cfg = Config::default();
        cfg.use_program(&loaded, &[&pin]);
        sm0.set_config(&cfg);
        sm0.set_pin_dirs(Direction::Out, &[&pin]);
        sm0.set_pins(embassy_rp::gpio::Level::Low, &[&pin]);
        sm0.set_enable(true);
        Self {
            sm: sm0,
            cycles_per_us: clk_sys_freq() / 1_000_000,
            pin: number,
        }
    }

    /// GPIO number of the trigger output.
    pub fn pin(&self) -> u8 {
        self.pin
    }
}

/// Make the trigger available to [`arm`].
pub fn install(trigger: TriggerPio) {
    TRIGGER.lock(|t| *t.borrow_mut() = Some(trigger));
}

/// Wait for the next tick of the 1 MHz timer and return its value. Call with interrupts
/// off; takes at most a microsecond.
pub fn next_tick_us() -> u64 {
    let start = Instant::now().as_micros();
    loop {
        let now = Instant::now().as_micros();
        if now != start {
            return now;
        }
    }
}

/// Schedule a pulse of `width_us` whose rising edge is at `edge_us` (timer µs, in the
/// future). Call in a critical section.
///
/// The pulse width is pushed first (the state machine takes it and waits for the
/// delay). The delay is computed for the next timer tick, the code spins until that
/// tick, and pushes it at once: the countdown then starts a fixed number of cycles
/// after the tick, whatever the caller did before (composing the phase event takes
/// about 4 µs, which the first version counted into the edge). If `edge_us` is not
/// after that tick the pulse fires at once; the sequencer's minimum lead prevents it.
pub fn arm(edge_us: u64, width_us: u32) {
    TRIGGER.lock(|t| {
        let mut t = t.borrow_mut();
        let Some(t) = t.as_mut() else { return };
        let width = width_us.saturating_mul(t.cycles_per_us).saturating_sub(1);
        let tick_us = Instant::now().as_micros() + 1;
        let lead_us = u32::try_from(edge_us.saturating_sub(tick_us)).unwrap_or(u32::MAX);
        // Edge = push + ARM_LATENCY_CYCLES + pull + out + (x + 1) jmp cycles.
        let delay = lead_us
            .saturating_mul(t.cycles_per_us)
            .saturating_sub(3 + ARM_LATENCY_CYCLES);
        let tx = t.sm.tx();
        tx.push(width);
        while Instant::now().as_micros() < tick_us {}
        tx.push(delay);
    });
}
