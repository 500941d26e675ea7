//! The loopback probe on PIO1 (arithmetic and rationale in `stereotac_firmware::probe`):
//! state machine 1 times the trigger looped back to GPIO7, state machine 2 decodes strip
//! 1's data looped back to GPIO8. Both share one program's stamping tail:
//!
//! ```text
//! frame:   mov y, ~null        ; decoder (SM2) entry: bit counter
//!          wait 1 pin 0        ; first bit of a frame
//! bit:     nop [6]             ; 8 cycles of 64 ns: the middle of the data part
//!          in pins, 1          ; autopush every 24 bits: one GRB pixel
//!          wait 0 pin 0
//!          jmp y--, counted
//! counted: set x, 31
//! low:     jmp pin, bit        ; the next bit starts within 1 µs...
//!          jmp x--, low
//!          in y, 32            ; ...else the frame ended (4.1 µs low): the bit count
//! stamp:   irq nowait 0 rel    ; tell the CPU, then count until its token arrives
//!          mov x, ~null
//! count:   mov y, status       ; all ones while the TX FIFO is empty
//!          jmp !y, stamped
//!          jmp x--, count
//! stamped: in x, 32            ; the count
//!          pull block          ; take the token; wrap to this machine's entry
//! edge:    wait 0 pin 0        ; trigger timer (SM1) entry
//!          wait 1 pin 0        ; rising edge
//!          jmp stamp
//! ```
//!
//! Each machine has its own task; events go out only while the host has the probe on.
//! Unconnected inputs are pulled down and stay silent.

use embassy_futures::select::{Either, select};
use embassy_rp::Peri;
use embassy_rp::clocks::clk_sys_freq;
use embassy_rp::gpio::Pull;
use embassy_rp::pac;
use embassy_rp::peripherals::{PIN_7, PIN_8, PIO1};
use embassy_rp::pio::{
    Common, Config, Direction, Irq, LoadedProgram, Pin, PioPin, ShiftConfig, ShiftDirection,
    StateMachine, StatusSource,
};
use stereotac_firmware::probe::{FrameTally, StampClock, bits_from_count_word, is_pixel_word};
use stereotac_protocol::ProbeEvent;

use super::shared;

/// Clock divider of the strip decoder: 64 ns cycles at 125 MHz.
const DECODER_DIVIDER: u8 = 8;
/// Decoder cycles from seeing the line low after a frame's last bit to the stamp loop's
/// first status check: `jmp y--`, `set`, 32 × (`jmp pin`, `jmp x--`), `in`, `irq`, `mov`.
const DECODER_FIXED_CYCLES: u64 = 1 + 1 + 64 + 1 + 1 + 1 + 1;
/// Trigger-timer cycles from the edge to the first status check: the input synchroniser
/// (2), then `jmp stamp`, `irq`, `mov`, and the check itself.
const EDGE_FIXED_CYCLES: u64 = 2 + 4;
/// From the timer tick to the token in the TX FIFO: the spin loop's exit and the store,
/// about 16 cycles, ns. Calibrated against the emulator's pin trace (hil-tests, probe
/// test: with 64 the probed edges came 53..135 ns early); to be re-checked on a sensor
/// with a scope, though an error here is a fixed offset of well under a microsecond.
const TOKEN_LATENCY_NS: u64 = 128;

/// The two probe state machines, configured and running.
pub struct Probe {
    pub trigger: TriggerTimer,
    pub strip: StripDecoder,
}

/// Times the looped-back trigger's rising edges.
pub struct TriggerTimer {
    sm: StateMachine<'static, PIO1, 1>,
    irq: Irq<'static, PIO1, 1>,
    clock: StampClock,
}

/// Decodes the looped-back strip 1 data.
pub struct StripDecoder {
    sm: StateMachine<'static, PIO1, 2>,
    irq: Irq<'static, PIO1, 2>,
    clock: StampClock,
}

impl Probe {
    /// Load the program into PIO1 and start both machines on GPIO7 and GPIO8.
    ///
    /// Two `unsafe` calls, because embassy-rp offers no safe way to start a machine
    /// elsewhere than at its program's origin: the trigger timer's wrap bottom and its
    /// first instruction are set to its entry, `edge`, inside the loaded program.
    #[allow(unsafe_code)]
    pub fn new(
        common: &mut Common<'static, PIO1>,
        (mut timer_sm, timer_irq): (StateMachine<'static, PIO1, 1>, Irq<'static, PIO1, 1>),
        (mut decoder_sm, decoder_irq): (StateMachine<'static, PIO1, 2>, Irq<'static, PIO1, 2>),
        trigger_in: Peri<'static, PIN_7>,
        strip_in: Peri<'static, PIN_8>,
    ) -> Self {
        let program = pio::pio_asm!(
            ".wrap_target",
            "public frame:",
            "    mov y, ~null",
            "    wait 1 pin 0",
            "bit:",
            "    nop [6]",
            "    in pins, 1",
            "    wait 0 pin 0",
            "    jmp y--, counted",
            "counted:",
            "    set x, 31",
            "low:",
            "    jmp pin, bit",
            "    jmp x--, low",
            "    in y, 32",
            "stamp:",
            "    irq nowait 0 rel",
            "    mov x, ~null",
            "count:",
            "    mov y, status",
            "    jmp !y, stamped",
            "    jmp x--, count",
            "stamped:",
            "    in x, 32",
            "    pull block",
            ".wrap",
            "public edge:",
            "    wait 0 pin 0",
            "    wait 1 pin 0",
            "    jmp stamp",
        );
        let loaded = common.load_program(&program.program);
        let edge = loaded.origin + program.public_defines.edge as u8;
        let cycle_ps = 1_000_000_000_000 / u64::from(clk_sys_freq());

        let trigger_in = probe_input(common, trigger_in);
        let mut cfg = stamping_config(&loaded, &trigger_in, 32);
        let mut exec = cfg.get_exec();
        exec.wrap_bottom = edge;
        // SAFETY: the wrap stays inside the loaded program.
        unsafe { cfg.set_exec(exec) };
        timer_sm.set_config(&cfg);
        timer_sm.set_pin_dirs(Direction::In, &[&trigger_in]);
        let jump = pio::InstructionOperands::JMP {
            condition: pio::JmpCondition::Always,
            address: edge,
        };
        // SAFETY: the machine is stopped; the jump lands on its entry.
        unsafe { timer_sm.exec_instr(jump.encode()) };
        timer_sm.set_enable(true);

        let strip_in = probe_input(common, strip_in);
        let mut cfg = stamping_config(&loaded, &strip_in, 24);
        cfg.set_jmp_pin(&strip_in);
        cfg.clock_divider = DECODER_DIVIDER.into();
        decoder_sm.set_config(&cfg);
        decoder_sm.set_pin_dirs(Direction::In, &[&strip_in]);
        decoder_sm.set_enable(true);

        Self {
            trigger: TriggerTimer {
                sm: timer_sm,
                irq: timer_irq,
                clock: StampClock {
                    cycle_ps,
                    fixed_cycles: EDGE_FIXED_CYCLES,
                    token_latency_ns: TOKEN_LATENCY_NS,
                },
            },
            strip: StripDecoder {
                sm: decoder_sm,
                irq: decoder_irq,
                clock: StampClock {
                    cycle_ps: cycle_ps * u64::from(DECODER_DIVIDER),
                    fixed_cycles: DECODER_FIXED_CYCLES,
                    token_latency_ns: TOKEN_LATENCY_NS,
                },
            },
        }
    }
}

/// A probe input handed to PIO1, pulled down so an unwired input stays low.
fn probe_input(
    common: &mut Common<'static, PIO1>,
    pin: Peri<'static, impl PioPin + 'static>,
) -> Pin<'static, PIO1> {
    let mut pin = common.make_pio_pin(pin);
    pin.set_pull(Pull::Down);
    pin
}

/// What both machines share: the program, `input` as their IN pin, shifting left (the
/// first bit ends up most significant) with autopush every `push_bits` bits, and STATUS
/// all ones while the TX FIFO is empty (the stamp loop's test).
fn stamping_config(
    loaded: &LoadedProgram<'static, PIO1>,
    input: &Pin<'static, PIO1>,
    push_bits: u8,
) -> Config<'static, PIO1> {
    let mut cfg = Config::default();
    cfg.use_program(loaded, &[]);
    cfg.set_in_pins(&[input]);
    cfg.shift_in = ShiftConfig {
        threshold: push_bits,
        direction: ShiftDirection::Left,
        auto_fill: true,
    };
    cfg.status_sel = StatusSource::TxFifoLevel;
    cfg.status_n = 1;
    cfg
}

/// Push the stamp token right after the next tick of the 1 MHz timer, with interrupts
/// off; returns that tick (device µs).
fn push_token_after_tick<const SM: usize>(sm: &mut StateMachine<'static, PIO1, SM>) -> u64 {
    critical_section::with(|_| {
        let tick = shared::now_us() + 1;
        let tick_low = tick as u32;
        // Wrapping comparison of the timer's low word: a few cycles per turn.
        while (pac::TIMER.timerawl().read().wrapping_sub(tick_low) as i32) < 0 {}
        sm.tx().push(0);
        tick
    })
}

fn post(probe: ProbeEvent) {
    if let Some(message) = shared::with(|c| c.probe_event(probe)) {
        shared::post_event(message);
    }
}

/// Stamps every looped-back trigger edge.
#[embassy_executor::task]
pub async fn probe_trigger(mut timer: TriggerTimer) {
    loop {
        timer.irq.wait().await;
        let tick = push_token_after_tick(&mut timer.sm);
        let word = timer.sm.rx().wait_pull().await;
        match timer.clock.event_ns(tick, word) {
            Some(at_ns) => post(ProbeEvent::TriggerEdge { at_ns }),
            None => defmt::warn!("probe: trigger stamp {=u32:x} not believable", word),
        }
    }
}

/// Decodes every frame on the looped-back strip 1 data line.
#[embassy_executor::task]
pub async fn probe_strip(mut decoder: StripDecoder) {
    let mut tally = FrameTally::default();
    let mut bits = None;
    loop {
        let ended = {
            let StripDecoder { sm, irq, .. } = &mut decoder;
            select(sm.rx().wait_pull(), irq.wait()).await
        };
        match ended {
            // Pixels, and the bit count if it comes before the frame's IRQ is seen.
            Either::First(word) if bits.is_none() && is_pixel_word(word) => tally.push(word),
            Either::First(word) if bits.is_none() => bits = Some(bits_from_count_word(word)),
            Either::First(word) => defmt::warn!("probe: stray strip word {=u32:x}", word),
            Either::Second(()) => {
                let tick = push_token_after_tick(&mut decoder.sm);
                let bits = match bits.take() {
                    Some(bits) => bits,
                    None => loop {
                        let word = decoder.sm.rx().wait_pull().await;
                        if !is_pixel_word(word) {
                            break bits_from_count_word(word);
                        }
                        tally.push(word);
                    },
                };
                let word = decoder.sm.rx().wait_pull().await;
                match decoder.clock.event_ns(tick, word) {
                    Some(end_ns) => post(ProbeEvent::StripFrame(tally.finish(end_ns, bits))),
                    None => defmt::warn!("probe: strip stamp {=u32:x} not believable", word),
                }
                tally = FrameTally::default();
            }
        }
    }
}
