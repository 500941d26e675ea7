//! Board bring-up and task wiring. One task per peripheral:
//!
//! | task | owns | does |
//! |---|---|---|
//! | `usb_device` | USB controller | enumeration, control requests |
//! | `link_rx` | bulk OUT endpoint | frames in → [`Controller`] → replies out |
//! | `link_tx` | bulk IN endpoint | sends queued replies and events |
//! | `led_strips` | PIO0, 4 state machines, DMA 0..3 | writes the four strips together |
//! | `probe_trigger` | PIO1 state machine 1 | times the trigger looped back to GPIO7 |
//! | `probe_strip` | PIO1 state machine 2 | decodes strip 1 looped back to GPIO8 |
//! | `sequencer` | the schedule | plans phases, asks for LED frames, arms the trigger |
//! | `supervisor` | watchdog, status LED | host-silence timeout, heartbeat, watchdog feed |
//! | `bootloader` | – | reboots into the USB bootloader on request |
//!
//! The camera trigger (PIO1) is armed by the sequencer inside the same critical section in
//! which it decides to fire, so no task switch can slip between decision and arming; the
//! pulse itself is timed by the PIO, not by software.

mod leds;
mod link;
mod probe;
mod sequencing;
mod shared;
mod supervisor;
mod trigger;

use defmt::{info, unwrap};
use embassy_executor::Spawner;
use embassy_rp::flash::{Blocking, Flash};
use embassy_rp::gpio::{Level, Output};
use embassy_rp::peripherals::{DMA_CH0, DMA_CH1, DMA_CH2, DMA_CH3, PIO0, PIO1, USB};
use embassy_rp::pio::{Common, Pio};
use embassy_rp::watchdog::{ResetReason, Watchdog};
use embassy_rp::{bind_interrupts, dma, pio, usb};
use static_cell::StaticCell;
use stereotac_firmware::pins::PINS;
use stereotac_firmware::{Controller, Identity, MAX_LEDS_PER_STRIP};
use stereotac_protocol::Capabilities;
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    USBCTRL_IRQ => usb::InterruptHandler<USB>;
    PIO0_IRQ_0 => pio::InterruptHandler<PIO0>;
    PIO1_IRQ_0 => pio::InterruptHandler<PIO1>;
    DMA_IRQ_0 => dma::InterruptHandler<DMA_CH0>, dma::InterruptHandler<DMA_CH1>,
        dma::InterruptHandler<DMA_CH2>, dma::InterruptHandler<DMA_CH3>;
});

const FLASH_SIZE: usize = 2 * 1024 * 1024;

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_rp::init(Default::default());
    info!("stereotac firmware {} starting", env!("CARGO_PKG_VERSION"));

    let watchdog = Watchdog::new(p.WATCHDOG);
    let watchdog_reset = matches!(watchdog.reset_reason(), Some(ResetReason::TimedOut));

    let mut board_id = [0u8; 8];
    let mut flash = Flash::<_, Blocking, FLASH_SIZE>::new_blocking(p.FLASH);
    if flash.blocking_unique_id(&mut board_id).is_err() {
        defmt::warn!("could not read the flash unique id");
    }

    let capabilities = Capabilities(
        Capabilities::HARDWARE_TRIGGER
            | Capabilities::PIO_LEDS
            | Capabilities::INTERLEAVED
            | Capabilities::BOOTLOADER
            | Capabilities::WATCHDOG
            | Capabilities::LOOPBACK_PROBE,
    );
    shared::init(Controller::new(
        Identity {
            board_id,
            capabilities,
        },
        MAX_LEDS_PER_STRIP,
    ));
    if watchdog_reset {
        defmt::warn!("previous boot ended in a watchdog reset");
        shared::post_event(shared::with(|c| c.watchdog_reset_fault(shared::now_us())));
    }

    // LED strips: PIO0, one state machine and one DMA channel per strip.
    let pio0 = Pio::new(p.PIO0, Irqs);
    let strips = leds::Strips::new(
        pio0,
        (p.DMA_CH0, p.DMA_CH1, p.DMA_CH2, p.DMA_CH3),
        (p.PIN_2, p.PIN_3, p.PIN_4, p.PIN_5),
        Irqs,
    );
    defmt::assert_eq!(
        strips.pins(),
        PINS.strips,
        "pin map and board code disagree"
    );

    // PIO1: the camera trigger (state machine 0, side-set on the trigger pin) and the
    // loopback probe (state machines 1 and 2).
    let Pio {
        common,
        sm0,
        sm1,
        sm2,
        irq1,
        irq2,
        ..
    } = Pio::new(p.PIO1, Irqs);
    // Kept alive for the program's lifetime: in embassy-rp 0.10 dropping one PIO block's
    // `Common` resets the other block's pins.
    static PIO1_COMMON: StaticCell<Common<'static, PIO1>> = StaticCell::new();
    let common = PIO1_COMMON.init(common);
    let trigger = trigger::TriggerPio::new(common, sm0, p.PIN_6);
    defmt::assert_eq!(
        trigger.pin(),
        PINS.trigger,
        "pin map and board code disagree"
    );
    trigger::install(trigger);
    let probe = probe::Probe::new(common, (sm1, irq1), (sm2, irq2), p.PIN_7, p.PIN_8);

    let status_led = Output::new(p.PIN_25, Level::Low);

    let link = link::build(p.USB, Irqs, board_id);

    spawner.spawn(unwrap!(link::usb_device(link.device)));
    spawner.spawn(unwrap!(link::link_rx(link.rx)));
    spawner.spawn(unwrap!(link::link_tx(link.tx)));
    spawner.spawn(unwrap!(leds::led_strips(strips)));
    spawner.spawn(unwrap!(probe::probe_trigger(probe.trigger)));
    spawner.spawn(unwrap!(probe::probe_strip(probe.strip)));
    spawner.spawn(unwrap!(sequencing::sequencer()));
    spawner.spawn(unwrap!(supervisor::supervisor(watchdog, status_led)));
    spawner.spawn(unwrap!(supervisor::bootloader()));
    info!("running; waiting for the host");
}
