//! Supervision: feeds the hardware watchdog, enforces the host-silence timeout, sends the
//! heartbeat, shows the state on the status LED, and reboots into the bootloader on request.

use embassy_rp::gpio::Output;
use embassy_rp::watchdog::Watchdog;
use embassy_time::{Duration, Ticker, Timer};

use super::shared::{self, BOOTLOADER, RECONFIGURED};

const TICK: Duration = Duration::from_millis(100);
const WATCHDOG_TIMEOUT: Duration = Duration::from_millis(1000);
const HEARTBEAT_EVERY_TICKS: u32 = 10;

#[embassy_executor::task]
pub async fn supervisor(mut watchdog: Watchdog, mut status_led: Output<'static>) {
    watchdog.pause_on_debug(true);
    watchdog.start(WATCHDOG_TIMEOUT);
    let mut ticker = Ticker::every(TICK);
    let mut ticks: u32 = 0;
    loop {
        ticker.next().await;
        watchdog.feed(WATCHDOG_TIMEOUT);
        ticks = ticks.wrapping_add(1);
        let now = shared::now_us();
        if let Some(fault) = shared::with(|c| c.check_host_timeout(now)) {
            defmt::warn!("host silent: LEDs off");
            shared::post_event(fault);
            RECONFIGURED.signal(());
        }
        if ticks.is_multiple_of(HEARTBEAT_EVERY_TICKS) {
            shared::post_event(shared::with(|c| c.heartbeat(now)));
        }
        // Running: steady on. Idle: short blink once a second.
        let running = shared::with(|c| c.is_running());
        status_led.set_level((running || ticks.is_multiple_of(HEARTBEAT_EVERY_TICKS)).into());
    }
}

#[embassy_executor::task]
pub async fn bootloader() {
    BOOTLOADER.wait().await;
    defmt::info!("rebooting into the USB bootloader");
    // Let the acknowledgement leave first.
    Timer::after_millis(50).await;
    embassy_rp::rom_data::reset_to_usb_boot(1 << stereotac_firmware::pins::PINS.status_led, 0);
}
