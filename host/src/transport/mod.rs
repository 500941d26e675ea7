//! Byte pipes to a sensor.
//!
//! [`Transport`] is deliberately small (send bytes, receive bytes with a timeout) so that
//! every device end fits behind it: USB through nusb ([`usb`]) or, with the `libusb`
//! feature, through libusb (`libusb`, for platforms where nusb falls short), the in-memory
//! loopback ([`crate::sim::link`]) that runs the firmware's own command handling on a simulated clock, the
//! bare [`crate::sim::sensor::SimulatedSensor`] (device time stands still while the host talks), and the
//! emulated RP2040 of the hardware-in-loop tests.

#[cfg(feature = "libusb")]
pub mod libusb;
pub mod usb;

use std::time::Duration;

use stereotac_protocol::{USB_PID, USB_VID};

use crate::clock::{HostClock, HostMicros};

/// Why a transport failed.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The device went away (unplugged, rebooted, emulator stopped).
    #[error("device disconnected")]
    Disconnected,
    /// Another I/O failure.
    #[error("transport I/O error: {0}")]
    Io(String),
}

/// A byte pipe to a device.
pub trait Transport {
    /// Send bytes to the device.
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError>;
    /// Bytes the device sent, waiting at most `timeout` for the first; may be empty.
    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, TransportError>;
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        (**self).send(bytes)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, TransportError> {
        (**self).receive(timeout)
    }
}

/// A boxed transport, so one [`Sensor`](crate::device::Sensor) type serves USB, loopback and emulation.
pub type BoxedTransport = Box<dyn Transport + Send>;

/// Opens (and reopens) the transport to one sensor.
///
/// Any `FnMut() -> Result<BoxedTransport, OpenError>` closure is a `Connect`; a USB
/// connector ([`usb::UsbConnector`]) also wakes the reconnect loop as
/// soon as the operating system reports the sensor back (hotplug) instead of sleeping
/// through the whole backoff delay.
pub trait Connect: Send {
    /// Open the transport.
    fn open(&mut self) -> Result<BoxedTransport, OpenError>;
    /// Wait before the next reconnect attempt: until `deadline` (host µs), or earlier
    /// when the device is known to be back. The default sleeps on `clock`.
    fn wait_for_device(&mut self, clock: &dyn HostClock, deadline: HostMicros) {
        clock.sleep_until(deadline);
    }
}

impl<F> Connect for F
where
    F: FnMut() -> Result<BoxedTransport, OpenError> + Send,
{
    fn open(&mut self) -> Result<BoxedTransport, OpenError> {
        self()
    }
}

/// A boxed [`Connect`].
pub type Connector = Box<dyn Connect>;

/// A connector that hands out `transport` once; later opens find no sensor, as after
/// an unplug with nothing coming back (simulations, emulation, tests).
pub fn connect_once(transport: impl Transport + Send + 'static) -> Connector {
    let mut transport = Some(transport);
    Box::new(move || {
        transport
            .take()
            .map(|t| Box::new(t) as BoxedTransport)
            .ok_or(OpenError::NotFound {
                serial: None,
                present: vec![],
            })
    })
}

/// Where the udev rules live, for the permission-denied hint.
pub const UDEV_RULES: &str = "udev/99-stereotac.rules";

/// A sensor seen on the bus (not opened).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct UsbSensor {
    /// USB serial number (the board id in hex).
    pub serial: String,
    /// Bus and address, e.g. `1-4` / `3:12`.
    pub path: String,
    /// Product string.
    pub product: Option<String>,
    /// Device release number (bcdDevice).
    pub release: u16,
}

/// Why a sensor could not be found or opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// No sensor (with that serial number) on the bus.
    #[error("{}", not_found_message(.serial.as_deref(), .present))]
    NotFound {
        /// The serial asked for, if any.
        serial: Option<String>,
        /// Serial numbers of the sensors that are present.
        present: Vec<String>,
    },
    /// Several sensors and no serial number to choose.
    #[error(
        "{} sensors attached ({}); choose one with --serial (in Python, Sensor(serial=...))",
        .0.len(),
        .0.join(", ")
    )]
    Ambiguous(Vec<String>),
    /// The OS refused access.
    #[error(
        "permission denied opening the sensor at {path}: install the udev rules \
         (sudo cp {UDEV_RULES} /etc/udev/rules.d/ && sudo udevadm control --reload && \
         sudo udevadm trigger), then replug"
    )]
    PermissionDenied {
        /// Bus path of the device.
        path: String,
    },
    /// Another program holds the interface.
    #[error("the sensor at {path} is in use by another program")]
    Busy {
        /// Bus path of the device.
        path: String,
    },
    /// The device does not look like a stereotac sensor.
    #[error("the device at {path} has no stereotac interface ({detail})")]
    NotASensor {
        /// Bus path.
        path: String,
        /// What was missing.
        detail: String,
    },
    /// Another USB failure.
    #[error("USB error: {0}")]
    Usb(String),
}

fn not_found_message(serial: Option<&str>, present: &[String]) -> String {
    let wanted = serial.map_or_else(
        || format!("no stereotac sensor found (USB {USB_VID:04x}:{USB_PID:04x})"),
        |s| format!("no stereotac sensor with serial {s}"),
    );
    if present.is_empty() {
        format!("{wanted}; is it plugged in? (`lsusb` should list {USB_VID:04x}:{USB_PID:04x})")
    } else {
        format!("{wanted}; present: {}", present.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_tell_the_user_what_to_do() {
        let none = OpenError::NotFound {
            serial: None,
            present: vec![],
        };
        assert!(none.to_string().contains("1209:0001"), "{none}");
        let other = OpenError::NotFound {
            serial: Some("E66".into()),
            present: vec!["ABCD".into()],
        };
        assert!(other.to_string().contains("E66") && other.to_string().contains("ABCD"));
        let denied = OpenError::PermissionDenied { path: "1:5".into() };
        assert!(denied.to_string().contains(UDEV_RULES));
        let many = OpenError::Ambiguous(vec!["A".into(), "B".into()]);
        assert!(many.to_string().contains("--serial") && many.to_string().contains("serial=..."));
    }
}
