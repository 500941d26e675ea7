//! The sequencer task: phase after phase on the controller's absolute schedule.
//!
//! For each phase: wait for its start (or a reconfiguration, which re-plans), commit to
//! it, have the LED task write its colours, then — in one critical section, right after a
//! timer tick — let the controller decide the trigger and arm the PIO. The phase event is
//! queued without waiting: the sequencer never waits on USB.

use embassy_futures::select::{Either, select};
use embassy_time::{Instant, Timer};
use stereotac_firmware::sequencer::{WS2812_RESET_US, led_bits_us};
use stereotac_firmware::{MAX_LEDS_PER_STRIP, PhaseFrame};
use stereotac_protocol::TriggerOutcome;

use super::leds::{DRAW, DRAWN, Drawn};
use super::shared::{self, RECONFIGURED};
use super::trigger;

/// Write `frame` to the strips; returns when the write started.
async fn draw(frame: PhaseFrame) -> Drawn {
    DRAWN.reset();
    DRAW.signal(frame);
    DRAWN.wait().await
}

#[embassy_executor::task]
pub async fn sequencer() {
    // From the release of the four strips to their latch; +1 for the timer read's
    // rounding.
    let bits_and_latch_us = u64::from(led_bits_us(MAX_LEDS_PER_STRIP) + WS2812_RESET_US + 1);
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
        let drawn = draw(frame).await;
        let write_start = drawn.start_us;
        let latched = write_start + bits_and_latch_us;
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
