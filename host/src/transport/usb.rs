//! USB transport through nusb (pure Rust; no libusb needed).
//!
//! The sensor enumerates with [`USB_VID`]/[`USB_PID`] and a vendor-class interface
//! (class 0xFF, subclass [`USB_SUBCLASS`]) holding one bulk OUT and one bulk IN endpoint;
//! its serial number is the RP2040 flash unique id in upper-case hex. Several sensors can
//! be open at once: each is selected by serial number.
//!
//! [`UsbConnector`] reopens a sensor after it was unplugged and wakes as soon as the
//! OS reports it back (nusb's `watch_devices`, udev on Linux); [`watch`] streams those
//! arrivals and departures for `stereotac devices --watch`.

use std::io::{BufRead, Write};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, Wake, Waker};
use std::time::{Duration, Instant};

use futures_core::Stream;

use nusb::MaybeFuture;
use nusb::descriptors::TransferType;
use nusb::transfer::{Bulk, Direction, In, Out};
use stereotac_protocol::{USB_PID, USB_SUBCLASS, USB_VID};

use super::{BoxedTransport, Connect, OpenError, Transport, TransportError, UsbSensor};
use crate::clock::{HostClock, HostMicros};

fn usb_error(e: nusb::Error, path: &str) -> OpenError {
    match e.kind() {
        nusb::ErrorKind::PermissionDenied => OpenError::PermissionDenied { path: path.into() },
        nusb::ErrorKind::Busy => OpenError::Busy { path: path.into() },
        _ => OpenError::Usb(e.to_string()),
    }
}

fn bus_path(info: &nusb::DeviceInfo) -> String {
    format!("{}:{}", info.bus_id(), info.device_address())
}

fn sensors() -> Result<Vec<nusb::DeviceInfo>, OpenError> {
    Ok(nusb::list_devices()
        .wait()
        .map_err(|e| OpenError::Usb(e.to_string()))?
        .filter(|d| d.vendor_id() == USB_VID && d.product_id() == USB_PID)
        .collect())
}

/// The sensors on the bus.
pub fn list() -> Result<Vec<UsbSensor>, OpenError> {
    Ok(sensors()?.iter().map(describe).collect())
}

fn describe(d: &nusb::DeviceInfo) -> UsbSensor {
    UsbSensor {
        serial: d.serial_number().unwrap_or("").to_string(),
        path: bus_path(d),
        product: d.product_string().map(str::to_string),
        release: d.device_version(),
    }
}

/// An open USB link to one sensor.
pub struct UsbTransport {
    reader: nusb::io::EndpointRead<Bulk>,
    writer: nusb::io::EndpointWrite<Bulk>,
    serial: String,
}

impl std::fmt::Debug for UsbTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UsbTransport")
            .field("serial", &self.serial)
            .finish_non_exhaustive()
    }
}

impl UsbTransport {
    /// Open the sensor with serial number `serial`, or the only one attached.
    pub fn open(serial: Option<&str>) -> Result<Self, OpenError> {
        let found = sensors()?;
        let serials: Vec<String> = found
            .iter()
            .map(|d| d.serial_number().unwrap_or("").to_string())
            .collect();
        let info = match serial {
            Some(s) => found
                .iter()
                .find(|d| d.serial_number().is_some_and(|n| n.eq_ignore_ascii_case(s))),
            None if found.len() > 1 => return Err(OpenError::Ambiguous(serials)),
            None => found.first(),
        };
        let Some(info) = info else {
            return Err(OpenError::NotFound {
                serial: serial.map(str::to_string),
                present: serials,
            });
        };
        let path = bus_path(info);
        let interface_number = info
            .interfaces()
            .find(|i| i.class() == 0xFF && i.subclass() == USB_SUBCLASS)
            .map(|i| i.interface_number())
            .ok_or_else(|| OpenError::NotASensor {
                path: path.clone(),
                detail: format!("no vendor interface with subclass {USB_SUBCLASS:#04x}"),
            })?;
        let device = info.open().wait().map_err(|e| usb_error(e, &path))?;
        let (out_address, in_address) =
            bulk_endpoints(&device, interface_number).ok_or_else(|| OpenError::NotASensor {
                path: path.clone(),
                detail: "the interface lacks a bulk IN/OUT endpoint pair".into(),
            })?;
        let interface = device
            .claim_interface(interface_number)
            .wait()
            .map_err(|e| usb_error(e, &path))?;
        let writer = interface
            .endpoint::<Bulk, Out>(out_address)
            .map_err(|e| usb_error(e, &path))?
            .writer(64)
            .with_write_timeout(Duration::from_secs(1));
        let reader = interface
            .endpoint::<Bulk, In>(in_address)
            .map_err(|e| usb_error(e, &path))?
            .reader(64)
            .with_num_transfers(8);
        Ok(Self {
            reader,
            writer,
            serial: info.serial_number().unwrap_or("").to_string(),
        })
    }

    /// The sensor's serial number.
    pub fn serial(&self) -> &str {
        &self.serial
    }
}

/// The bulk OUT and IN endpoint addresses of the interface's first alternate setting.
fn bulk_endpoints(device: &nusb::Device, interface_number: u8) -> Option<(u8, u8)> {
    let config = device.active_configuration().ok()?;
    let alt = config
        .interface_alt_settings()
        .find(|a| a.interface_number() == interface_number)?;
    let bulk = |dir: Direction| {
        alt.endpoints()
            .find(|e| e.transfer_type() == TransferType::Bulk && e.direction() == dir)
            .map(|e| e.address())
    };
    Some((bulk(Direction::Out)?, bulk(Direction::In)?))
}

fn io_error(e: std::io::Error) -> TransportError {
    match e.kind() {
        std::io::ErrorKind::NotConnected | std::io::ErrorKind::BrokenPipe => {
            TransportError::Disconnected
        }
        _ => TransportError::Io(e.to_string()),
    }
}

impl Transport for UsbTransport {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.writer.write_all(bytes).map_err(io_error)?;
        // End the transfer with a short packet so the device sees it at once.
        self.writer.submit_end();
        self.writer.flush().map_err(io_error)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Vec<u8>, TransportError> {
        self.reader
            .set_read_timeout(timeout.max(Duration::from_micros(1)));
        match self.reader.fill_buf() {
            Ok(data) => {
                let out = data.to_vec();
                self.reader.consume(out.len());
                Ok(out)
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(Vec::new()),
            Err(e) => Err(io_error(e)),
        }
    }
}

/// A sensor arrived or left (see [`HotplugWatch`]).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Hotplug {
    /// A stereotac sensor was plugged in.
    Arrived(UsbSensor),
    /// A USB device left (nusb reports only an opaque id for departures, so this may
    /// be any device; compare with [`list`] to see which sensors remain).
    Left {
        /// The OS's id of the device, for logs.
        id: String,
    },
}

/// Wakes the thread parked in [`HotplugWatch::next`].
struct Unpark(std::thread::Thread);

impl Wake for Unpark {
    fn wake(self: Arc<Self>) {
        self.0.unpark();
    }
}

/// Arrivals and departures of USB devices, filtered to stereotac sensors.
pub struct HotplugWatch {
    watch: nusb::hotplug::HotplugWatch,
}

impl std::fmt::Debug for HotplugWatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HotplugWatch").finish_non_exhaustive()
    }
}

/// Start watching the bus.
pub fn watch() -> Result<HotplugWatch, OpenError> {
    let watch = nusb::watch_devices().map_err(|e| OpenError::Usb(e.to_string()))?;
    Ok(HotplugWatch { watch })
}

impl HotplugWatch {
    /// The next sensor arrival or device departure, or `None` at `deadline`.
    pub fn next(&mut self, deadline: Instant) -> Option<Hotplug> {
        let waker = Waker::from(Arc::new(Unpark(std::thread::current())));
        let mut cx = Context::from_waker(&waker);
        loop {
            match Pin::new(&mut self.watch).poll_next(&mut cx) {
                Poll::Ready(Some(nusb::hotplug::HotplugEvent::Connected(d)))
                    if d.vendor_id() == USB_VID && d.product_id() == USB_PID =>
                {
                    return Some(Hotplug::Arrived(describe(&d)));
                }
                Poll::Ready(Some(nusb::hotplug::HotplugEvent::Disconnected(id))) => {
                    return Some(Hotplug::Left {
                        id: format!("{id:?}"),
                    });
                }
                // Another device arrived: keep waiting.
                Poll::Ready(Some(_)) => continue,
                Poll::Ready(None) => return None,
                Poll::Pending => {}
            }
            let now = Instant::now();
            if now >= deadline {
                return None;
            }
            std::thread::park_timeout(deadline - now);
        }
    }
}

/// Opens one sensor (by serial number, or the only one) and, between reconnect
/// attempts, waits for the OS to report a sensor arriving rather than sleeping blindly.
#[derive(Debug)]
pub struct UsbConnector {
    serial: Option<String>,
    watch: Option<HotplugWatch>,
}

impl UsbConnector {
    /// A connector for the sensor with `serial`, or the only one attached.
    pub fn new(serial: Option<String>) -> Self {
        Self {
            serial,
            watch: None,
        }
    }
}

impl Connect for UsbConnector {
    fn open(&mut self) -> Result<BoxedTransport, OpenError> {
        let transport = UsbTransport::open(self.serial.as_deref())?;
        // Connected again: stop listening to the bus until the next disconnect.
        self.watch = None;
        Ok(Box::new(transport))
    }

    fn wait_for_device(&mut self, clock: &dyn HostClock, deadline: HostMicros) {
        let remaining = Duration::from_micros(deadline.saturating_sub(clock.now_us()));
        if self.watch.is_none() {
            // Without a hotplug socket (no udev, sandbox) fall back to sleeping.
            self.watch = watch().ok();
        }
        let Some(watch) = self.watch.as_mut() else {
            clock.sleep_until(deadline);
            return;
        };
        let until = Instant::now() + remaining;
        while let Some(event) = watch.next(until) {
            if let Hotplug::Arrived(sensor) = event {
                let wanted = self
                    .serial
                    .as_deref()
                    .is_none_or(|s| s.eq_ignore_ascii_case(&sensor.serial));
                if wanted {
                    return;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listing_without_sensors_is_not_an_error() {
        // No sensor is attached to CI machines; listing must still work (or say why).
        match list() {
            Ok(found) => assert!(found.iter().all(|s| !s.path.is_empty())),
            Err(OpenError::Usb(message)) => assert!(!message.is_empty()),
            Err(other) => panic!("unexpected {other}"),
        }
    }

    #[test]
    fn hotplug_wait_ends_at_its_deadline_when_nothing_arrives() {
        // No sensor is plugged in here, so the wait must end by its deadline (through
        // the hotplug socket where udev's netlink is available, else by sleeping).
        let clock = crate::clock::MonotonicClock::new();
        let mut connector = UsbConnector::new(Some("NO-SUCH-SENSOR".into()));
        let start = clock.now_us();
        connector.wait_for_device(&clock, start + 50_000);
        let waited = clock.now_us() - start;
        assert!((45_000..2_000_000).contains(&waited), "waited {waited} µs");
        assert!(matches!(
            connector.open(),
            Err(OpenError::NotFound { .. } | OpenError::Usb(_))
        ));
    }
}
