//! The sequencer task: phase after phase on the controller's absolute schedule.
//!
//! For each phase: wait for its start (or a reconfiguration, which re-plans), commit to
//! it, have the LED task write its colours, then — in one critical section, right after a
//! timer tick — let the controller decide the trigger and arm the PIO. The phase event is
//! queued without waiting: the sequencer never waits on USB.

use embassy_futures::select::{Either, select};
use embassy_time::{Instant, Timer};
use stereotac_firmware::sequencer::{WS2812_RESET_US, led_write_us};
use stereotac_firmware::{MAX_LEDS_PER_STRIP, PhaseFrame};
use stereotac_protocol::TriggerOutcome;

use super::leds::{DRAW, DRAWN};
use super::shared::{self, RECONFIGURED};
use super::trigger;

/// Write `frame` to the strips; returns the write start (device µs).
async fn draw(frame: PhaseFrame) -> u64 {
    DRAWN.reset();
    DRAW.signal(frame);
    DRAWN.wait().await
}

#[embassy_executor::task]
pub async fn sequencer() {
    let write_and_latch_us = u64::from(led_write_us(MAX_LEDS_PER_STRIP) + WS2812_RESET_US);
    let mut dark = false;
    loop {
        let Some(plan) = shared::with(|c| c.plan(shared::now_us())) else {
            // Stopped: strips dark, no triggers, until something changes.
            if !dark {
                draw(PhaseFrame::DARK).await;
                dark = true;
            }
            RECONFIGURED.wait().await;
            continue;
        };
        let start = Timer::at(Instant::from_micros(plan.start_us));
        if let Either::Second(()) = select(start, RECONFIGURED.wait()).await {
            continue; // re-plan with the new settings
        }
        let frame = shared::with(|c| {
            c.begin(&plan);
            c.frame(plan.phase)
        });
        dark = false;
        let write_start = draw(frame).await;
        let latched = write_start + write_and_latch_us;
        let message = critical_section::with(|_| {
            let tick = trigger::next_tick_us();
            let (event, message) = shared::with(|c| c.finish(&plan, write_start, latched, tick));
            if let TriggerOutcome::Fired { edge_us, .. } = event.trigger {
                trigger::arm(edge_us, plan.pulse_us);
            }
            message
        });
        shared::post_event(message);
    }
}
