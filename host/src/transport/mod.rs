//! Byte pipes to a sensor.
//!
//! [`Transport`] is deliberately small (send bytes, receive bytes with a timeout) so that
//! every device end fits behind it: USB through nusb ([`usb`]) or, with the `libusb`
//! feature, through libusb (`libusb`, for platforms where nusb falls short), the in-memory
//! [`loopback`] that runs the firmware's own command handling on a simulated clock, the
//! bare [`SimulatedSensor`] (device time stands still while the host talks), and the
//! emulated RP2040 of the hardware-in-loop tests.

#[cfg(feature = "libusb")]
pub mod libusb;
pub mod loopback;
pub mod usb;

use std::time::Duration;

use crate::sim::SimulatedSensor;

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

/// The bare simulated sensor: device time stands still while the host talks and moves
/// only with [`SimulatedSensor::advance_to`].
impl Transport for SimulatedSensor {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.write(bytes);
        Ok(())
    }

    fn receive(&mut self, _timeout: Duration) -> Result<Vec<u8>, TransportError> {
        Ok(self.read())
    }
}
