//! The four WS2812 strips on PIO0: embassy-rp's WS2812 PIO program on state machines 0..3,
//! each fed by its own DMA channel, written together.
//!
//! Every write clocks out [`MAX_LEDS_PER_STRIP`] pixels per strip (pixels past the
//! configured strip length are dark, so a longer physical strip shows no stale colours),
//! so a write always takes the same time. Its end is computed from the bit rate (see
//! `stereotac_firmware::sequencer::led_bits_us`), because `PioWs2812::write` returns
//! while the last words may still be in the PIO FIFO.
//!
//! Timing: the frame is prepared ahead of the phase boundary and the four state machines
//! are released together on it, right after the timer is read (see [`Strips::write`]):
//! every strip's first bit follows the reported start by under 1.5 µs (measured in
//! emulation), whatever else the executor was doing, and all four end together.

use core::future::{Future, poll_fn};
use core::pin::pin;
use core::task::Poll;

use embassy_futures::join::join4;
use embassy_rp::Peri;
use embassy_rp::gpio::Pin;
use embassy_rp::pac;
use embassy_rp::peripherals::{
    DMA_CH0, DMA_CH1, DMA_CH2, DMA_CH3, PIN_2, PIN_3, PIN_4, PIN_5, PIO0,
};
use embassy_rp::pio::{Common, Pio};
use embassy_rp::pio_programs::ws2812::{Grb, PioWs2812, PioWs2812Program};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use smart_leds::RGB8;
use static_cell::StaticCell;
use stereotac_firmware::{MAX_LEDS_PER_STRIP, PhaseFrame};

use super::shared;

const N: usize = MAX_LEDS_PER_STRIP as usize;
/// The last stretch before a write's start is spun with interrupts off (the executor's
/// wake-up is not that exact), µs.
const SPIN_US: u64 = 20;
/// SM_ENABLE bits of state machines 0..3 (strips 1..4).
const ALL_STRIPS: u8 = 0b1111;

type Strip<const S: usize> = PioWs2812<'static, PIO0, S, N, Grb>;

/// A frame to show.
pub static DRAW: Signal<CriticalSectionRawMutex, Draw> = Signal::new();
/// A frame has been written; carries when its write started.
pub static DRAWN: Signal<CriticalSectionRawMutex, Drawn> = Signal::new();

/// What to show, and when.
#[derive(Debug, Clone, Copy)]
pub struct Draw {
    /// The colours.
    pub frame: PhaseFrame,
    /// When the bits should start (device µs).
    pub at_us: u64,
}

/// The four strips and the PIO block they run on.
pub struct Strips {
    // Kept alive for the program's lifetime: in embassy-rp 0.10 dropping one PIO block's
    // `Common` resets the other block's pins.
    _common: Common<'static, PIO0>,
    s1: Strip<0>,
    s2: Strip<1>,
    s3: Strip<2>,
    s4: Strip<3>,
    pins: [u8; 4],
}

impl Strips {
    /// Set up strips 1..4 on GPIO2..5, with DMA channels 0..3.
    pub fn new(
        pio: Pio<'static, PIO0>,
        dma: (
            Peri<'static, DMA_CH0>,
            Peri<'static, DMA_CH1>,
            Peri<'static, DMA_CH2>,
            Peri<'static, DMA_CH3>,
        ),
        pins: (
            Peri<'static, PIN_2>,
            Peri<'static, PIN_3>,
            Peri<'static, PIN_4>,
            Peri<'static, PIN_5>,
        ),
        irqs: super::Irqs,
    ) -> Self {
        let Pio {
            mut common,
            sm0,
            sm1,
            sm2,
            sm3,
            ..
        } = pio;
        let numbers = [pins.0.pin(), pins.1.pin(), pins.2.pin(), pins.3.pin()];
        // One program in PIO0's instruction memory, shared by the four state machines.
        // It must outlive the strips: leak it into a static cell.
        static PROGRAM: StaticCell<PioWs2812Program<'static, PIO0>> = StaticCell::new();
        let program = PROGRAM.init(PioWs2812Program::new(&mut common));
        let s1 = PioWs2812::new(&mut common, sm0, dma.0, irqs, pins.0, program);
        let s2 = PioWs2812::new(&mut common, sm1, dma.1, irqs, pins.1, program);
        let s3 = PioWs2812::new(&mut common, sm2, dma.2, irqs, pins.2, program);
        let s4 = PioWs2812::new(&mut common, sm3, dma.3, irqs, pins.3, program);
        Self {
            _common: common,
            s1,
            s2,
            s3,
            s4,
            pins: numbers,
        }
    }

    /// GPIO numbers of strips 1..4.
    pub fn pins(&self) -> [u8; 4] {
        self.pins
    }

    /// Write `frame` to the four strips at once, starting at `at_us` (device µs; at once
    /// if that has passed); returns when the last word has been handed to the PIO.
    ///
    /// The four state machines are paused while the DMA transfers start and fill their
    /// FIFOs; then, with interrupts off, the code spins to `at_us`, reads the timer and
    /// releases all four with one register write: the bit streams begin together, 3 PIO
    /// cycles (375 ns) after the reported start.
    async fn write(&mut self, frame: &PhaseFrame, at_us: u64) -> Drawn {
        let strip = |i: usize| -> [RGB8; N] { core::array::from_fn(|px| frame.pixel(i, px)) };
        let (c1, c2, c3, c4) = (strip(0), strip(1), strip(2), strip(3));
        // Between phases every machine is stalled on its empty FIFO with the line low,
        // so pausing it here changes nothing on the wire.
        set_strips_enabled(false);
        let mut writes = pin!(join4(
            self.s1.write(&c1),
            self.s2.write(&c2),
            self.s3.write(&c3),
            self.s4.write(&c4),
        ));
        // The first poll packs the colours and starts all four DMA transfers.
        let done = poll_fn(|cx| Poll::Ready(writes.as_mut().poll(cx).is_ready())).await;
        Timer::at(Instant::from_micros(at_us.saturating_sub(SPIN_US))).await;
        let start_us = critical_section::with(|_| {
            let mut now = shared::now_us();
            while now < at_us {
                now = shared::now_us();
            }
            set_strips_enabled(true);
            now
        });
        if !done {
            writes.await;
        }
        Drawn { start_us }
    }
}

/// Pause or release the four strip state machines together (one register write; the
/// restart bits read as zero, so the read-modify-write touches nothing else).
fn set_strips_enabled(on: bool) {
    critical_section::with(|_| {
        pac::PIO0.ctrl().modify(|w| {
            let others = w.sm_enable() & !ALL_STRIPS;
            w.set_sm_enable(if on { others | ALL_STRIPS } else { others });
        })
    });
}

/// When a frame's write started.
#[derive(Debug, Clone, Copy)]
pub struct Drawn {
    /// Read just before the four state machines were released (device µs): the first
    /// bit of every strip follows within a microsecond.
    pub start_us: u64,
}

/// Writes every frame it is given and reports when the write started.
#[embassy_executor::task]
pub async fn led_strips(mut strips: Strips) {
    loop {
        let draw = DRAW.wait().await;
        let drawn = strips.write(&draw.frame, draw.at_us).await;
        DRAWN.signal(drawn);
    }
}
