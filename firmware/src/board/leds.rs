//! The four WS2812 strips on PIO0: embassy-rp's WS2812 PIO program on state machines 0..3,
//! each fed by its own DMA channel, written together.
//!
//! Every write clocks out [`MAX_LEDS_PER_STRIP`] pixels per strip (pixels past the
//! configured strip length are dark), so a write always takes the same time; its end is
//! computed from the bit rate (see `stereotac_firmware::sequencer::led_write_us`), because
//! `PioWs2812::write` returns while the last words may still be in the PIO FIFO.

use embassy_futures::join::join4;
use embassy_rp::Peri;
use embassy_rp::gpio::Pin;
use embassy_rp::peripherals::{
    DMA_CH0, DMA_CH1, DMA_CH2, DMA_CH3, PIN_2, PIN_3, PIN_4, PIN_5, PIO0,
};
use embassy_rp::pio::{Common, Pio};
use embassy_rp::pio_programs::ws2812::{Grb, PioWs2812, PioWs2812Program};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use smart_leds::RGB8;
use static_cell::StaticCell;
use stereotac_firmware::{MAX_LEDS_PER_STRIP, PhaseFrame};

use super::shared;

const N: usize = MAX_LEDS_PER_STRIP as usize;

type Strip<const S: usize> = PioWs2812<'static, PIO0, S, N, Grb>;

/// A frame to show.
pub static DRAW: Signal<CriticalSectionRawMutex, PhaseFrame> = Signal::new();
/// A frame has been written; carries the write start time (device µs).
pub static DRAWN: Signal<CriticalSectionRawMutex, u64> = Signal::new();

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

    async fn write(&mut self, frame: &PhaseFrame) {
        let strip = |i: usize| -> [RGB8; N] { core::array::from_fn(|px| frame.pixel(i, px)) };
        let (c1, c2, c3, c4) = (strip(0), strip(1), strip(2), strip(3));
        join4(
            self.s1.write(&c1),
            self.s2.write(&c2),
            self.s3.write(&c3),
            self.s4.write(&c4),
        )
        .await;
    }
}

/// Writes every frame it is given and reports when the write started.
#[embassy_executor::task]
pub async fn led_strips(mut strips: Strips) {
    loop {
        let frame = DRAW.wait().await;
        let start = shared::now_us();
        strips.write(&frame).await;
        DRAWN.signal(start);
    }
}
