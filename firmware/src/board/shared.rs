//! State and channels shared by the tasks.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use embassy_time::Instant;
use stereotac_firmware::Controller;
use stereotac_protocol::{DeviceMessage, MAX_FRAME, encode};

type Cs = CriticalSectionRawMutex;

static CONTROLLER: Mutex<Cs, RefCell<Option<Controller>>> = Mutex::new(RefCell::new(None));

/// Encoded frames waiting for the bulk IN endpoint.
pub static OUTBOX: Channel<Cs, OutFrame, 16> = Channel::new();
/// The sequence or LED settings changed: the sequencer re-plans.
pub static RECONFIGURED: Signal<Cs, ()> = Signal::new();
/// Reboot into the USB bootloader.
pub static BOOTLOADER: Signal<Cs, ()> = Signal::new();

/// One encoded frame.
pub struct OutFrame {
    len: usize,
    bytes: [u8; MAX_FRAME],
}

impl OutFrame {
    /// The frame's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Install the controller; called once at boot before any task runs.
pub fn init(controller: Controller) {
    CONTROLLER.lock(|c| *c.borrow_mut() = Some(controller));
}

/// Run `f` on the controller inside a critical section.
pub fn with<R>(f: impl FnOnce(&mut Controller) -> R) -> R {
    CONTROLLER.lock(|c| {
        let mut guard = c.borrow_mut();
        let controller = guard.as_mut().expect("controller installed at boot");
        f(controller)
    })
}

/// Device clock in µs.
pub fn now_us() -> u64 {
    Instant::now().as_micros()
}

/// Encode a message; every protocol message fits a frame, so this only fails on a bug.
pub fn frame(message: &DeviceMessage) -> Option<OutFrame> {
    let mut out = OutFrame {
        len: 0,
        bytes: [0; MAX_FRAME],
    };
    let len = encode(message, &mut out.bytes).ok()?.len();
    out.len = len;
    Some(out)
}

/// Queue an event without waiting: if the host is not reading and the queue is full,
/// the event is dropped and counted (its sequence number is spent, so the host sees it).
pub fn post_event(message: DeviceMessage) {
    let queued = frame(&message).is_some_and(|f| OUTBOX.try_send(f).is_ok());
    if !queued {
        with(|c| c.note_event_dropped());
    }
}

/// Queue a reply, waiting for room: replies are never dropped.
pub async fn post_reply(message: DeviceMessage) {
    if let Some(f) = frame(&message) {
        OUTBOX.send(f).await;
    }
}
