//! USB transport through libusb (`rusb`), behind the opt-in `libusb` feature.
//!
//! The default [`super::usb`] transport (nusb, pure Rust) covers Linux, macOS and
//! Windows; this one is for systems where only libusb works (BSDs, Android with a
//! passed file descriptor, older kernels) and for cross-checking the two stacks. Same
//! device selection, same typed [`OpenError`]s, same framing: bytes in, bytes out.

use std::time::Duration;

use rusb::UsbContext;
use stereotac_protocol::{USB_PID, USB_SUBCLASS, USB_VID};

use super::{BoxedTransport, Connect, OpenError, Transport, TransportError, UsbSensor};

/// Bulk packet size at full speed; a transfer of a multiple of it ends with a
/// zero-length packet so the device sees its end.
const PACKET: usize = 64;
/// Largest read per call.
const READ_CHUNK: usize = 4096;
/// How long a write may wait for the device.
const WRITE_TIMEOUT: Duration = Duration::from_secs(1);

/// How a libusb error met while finding or opening the device at `path` (`bus:address`)
/// reads as the typed error the nusb backend gives for the same cause.
pub fn open_error(e: rusb::Error, path: &str) -> OpenError {
    match e {
        rusb::Error::Access => OpenError::PermissionDenied { path: path.into() },
        rusb::Error::Busy => OpenError::Busy { path: path.into() },
        other => OpenError::Usb(format!("libusb: {other}")),
    }
}

fn bus_path<T: UsbContext>(d: &rusb::Device<T>) -> String {
    format!("{}:{}", d.bus_number(), d.address())
}

/// A sensor found on the bus, with its descriptor.
struct Found {
    device: rusb::Device<rusb::Context>,
    descriptor: rusb::DeviceDescriptor,
}

fn sensors() -> Result<Vec<Found>, OpenError> {
    let context = rusb::Context::new().map_err(|e| open_error(e, "libusb"))?;
    let devices = context.devices().map_err(|e| open_error(e, "libusb"))?;
    Ok(devices
        .iter()
        .filter_map(|device| {
            let descriptor = device.device_descriptor().ok()?;
            (descriptor.vendor_id() == USB_VID && descriptor.product_id() == USB_PID)
                .then_some(Found { device, descriptor })
        })
        .collect())
}

/// Read the serial number and product strings (needs the device to be openable).
fn strings(found: &Found) -> (Option<String>, Option<String>) {
    let Ok(handle) = found.device.open() else {
        return (None, None);
    };
    (
        handle
            .read_serial_number_string_ascii(&found.descriptor)
            .ok(),
        handle.read_product_string_ascii(&found.descriptor).ok(),
    )
}

/// The sensors on the bus (serial numbers are empty where the device cannot be opened).
pub fn list() -> Result<Vec<UsbSensor>, OpenError> {
    Ok(sensors()?
        .iter()
        .map(|found| {
            let (serial, product) = strings(found);
            let v = found.descriptor.device_version();
            UsbSensor {
                serial: serial.unwrap_or_default(),
                path: bus_path(&found.device),
                product,
                release: (u16::from(v.major()) << 8)
                    | (u16::from(v.minor()) << 4)
                    | u16::from(v.sub_minor()),
            }
        })
        .collect())
}

/// An open libusb link to one sensor.
pub struct LibusbTransport {
    handle: rusb::DeviceHandle<rusb::Context>,
    out_address: u8,
    in_address: u8,
    serial: String,
    buffer: Vec<u8>,
}

impl std::fmt::Debug for LibusbTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LibusbTransport")
            .field("serial", &self.serial)
            .finish_non_exhaustive()
    }
}

impl LibusbTransport {
    /// Open the sensor with serial number `serial`, or the only one attached.
    pub fn open(serial: Option<&str>) -> Result<Self, OpenError> {
        let found = sensors()?;
        let serials: Vec<String> = found
            .iter()
            .map(|f| strings(f).0.unwrap_or_default())
            .collect();
        let index = match serial {
            Some(s) => serials.iter().position(|n| n.eq_ignore_ascii_case(s)),
            None if found.len() > 1 => return Err(OpenError::Ambiguous(serials)),
            None => (!found.is_empty()).then_some(0),
        };
        let Some(index) = index else {
            return Err(OpenError::NotFound {
                serial: serial.map(str::to_string),
                present: serials,
            });
        };
        let device = &found[index].device;
        let path = bus_path(device);
        let (interface, out_address, in_address) = vendor_interface(device, &path)?;
        let handle = device.open().map_err(|e| open_error(e, &path))?;
        handle
            .claim_interface(interface)
            .map_err(|e| open_error(e, &path))?;
        Ok(Self {
            handle,
            out_address,
            in_address,
            serial: serials[index].clone(),
            buffer: vec![0; READ_CHUNK],
        })
    }

    /// The sensor's serial number.
    pub fn serial(&self) -> &str {
        &self.serial
    }
}

/// The vendor interface's number and its bulk OUT and IN endpoint addresses.
fn vendor_interface(
    device: &rusb::Device<rusb::Context>,
    path: &str,
) -> Result<(u8, u8, u8), OpenError> {
    let config = device
        .active_config_descriptor()
        .map_err(|e| open_error(e, path))?;
    let not_a_sensor = |detail: &str| OpenError::NotASensor {
        path: path.into(),
        detail: detail.into(),
    };
    let alt = config
        .interfaces()
        .filter_map(|i| i.descriptors().next())
        .find(|a| a.class_code() == 0xFF && a.sub_class_code() == USB_SUBCLASS)
        .ok_or_else(|| not_a_sensor("no vendor interface with the stereotac subclass"))?;
    let bulk = |dir: rusb::Direction| {
        alt.endpoint_descriptors()
            .find(|e| e.transfer_type() == rusb::TransferType::Bulk && e.direction() == dir)
            .map(|e| e.address())
    };
    match (bulk(rusb::Direction::Out), bulk(rusb::Direction::In)) {
        (Some(out), Some(inp)) => Ok((alt.interface_number(), out, inp)),
        _ => Err(not_a_sensor(
            "the interface lacks a bulk IN/OUT endpoint pair",
        )),
    }
}

/// How a libusb error met during a transfer reads as a [`TransportError`]: a device that
/// went away is [`TransportError::Disconnected`] (so callers reconnect, as with nusb).
pub fn transfer_error(e: rusb::Error) -> TransportError {
    match e {
        rusb::Error::NoDevice | rusb::Error::Io | rusb::Error::NotFound => {
            TransportError::Disconnected
        }
        other => TransportError::Io(format!("libusb: {other}")),
    }
}

impl Transport for LibusbTransport {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        let mut sent = 0;
        while sent < bytes.len() {
            sent += self
                .handle
                .write_bulk(self.out_address, &bytes[sent..], WRITE_TIMEOUT)
                .map_err(transfer_error)?;
        }
        if bytes.len().is_multiple_of(PACKET) {
            // A zero-length packet ends the transfer.
            self.handle
                .write_bulk(self.out_address, &[], WRITE_TIMEOUT)
                .map_err(transfer_error)?;
        }
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, TransportError> {
        // libusb reads a zero timeout as "forever": wait at least 1 ms.
        let timeout = timeout.max(Duration::from_millis(1));
        match self
            .handle
            .read_bulk(self.in_address, &mut self.buffer, timeout)
        {
            Ok(n) => Ok(self.buffer[..n].to_vec()),
            Err(rusb::Error::Timeout) => Ok(Vec::new()),
            Err(e) => Err(transfer_error(e)),
        }
    }
}

/// Opens (and reopens) a sensor through libusb.
#[derive(Debug, Clone)]
pub struct LibusbConnector {
    serial: Option<String>,
}

impl LibusbConnector {
    /// A connector for the sensor with `serial`, or the only one attached.
    pub fn new(serial: Option<String>) -> Self {
        Self { serial }
    }
}

impl Connect for LibusbConnector {
    fn open(&mut self) -> Result<BoxedTransport, OpenError> {
        Ok(Box::new(LibusbTransport::open(self.serial.as_deref())?))
    }
}
