//! The sequencer task: phase after phase on the controller's absolute schedule.
//!
//! For each phase: wait until [`PREPARE_LEAD_US`] before its start (or a reconfiguration,
//! which re-plans), commit to it, have the LED task load its colours and start them on
//! the boundary, then — in one critical section, right after a
//! timer tick — let the controller decide the trigger and arm the PIO. The phase event is
//! queued without waiting: the sequencer never waits on USB.

use embassy_futures::select::{Either, select};
use embassy_time::{Instant, Timer};
use stereotac_firmware::sequencer::{PREPARE_LEAD_US, WS2812_RESET_US, led_bits_us};
use stereotac_firmware::{MAX_LEDS_PER_STRIP, PhaseFrame};
use stereotac_protocol::TriggerOutcome;

use super::leds::{DRAW, DRAWN, Draw, Drawn};
use super::shared::{self, RECONFIGURED};
use super::trigger;

/// Write `frame` to the strips, starting at `at_us`; returns when the write started.
async fn draw(frame: PhaseFrame, at_us: u64) -> Drawn {
    DRAWN.reset();
    DRAW.signal(Draw { frame, at_us });
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
                draw(PhaseFrame::DARK, 0).await;
                dark = true;
            }
            RECONFIGURED.wait().await;
            continue;
        };
        // Wake early enough to compose the frame and load the strips before the boundary.
        let prepare_us = plan.start_us.saturating_sub(u64::from(PREPARE_LEAD_US));
        let start = Timer::at(Instant::from_micros(prepare_us));
        if let Either::Second(()) = select(start, RECONFIGURED.wait()).await {
            continue; // re-plan with the new settings
        }
        let frame = shared::with(|c| {
            c.begin(&plan);
            c.frame(plan.phase)
        });
        dark = false;
        let drawn = draw(frame, plan.start_us).await;
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
