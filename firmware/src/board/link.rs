//! The USB link: a vendor-class interface with one bulk OUT and one bulk IN endpoint,
//! MS OS 2.0 descriptors so Windows binds WinUSB without a driver, and the flash unique
//! id as serial number. Frames are COBS-delimited, so they may span USB packets.

use embassy_rp::Peri;
use embassy_rp::peripherals::USB;
use embassy_rp::usb::{Driver, Endpoint, In, Out};
use embassy_usb::driver::{Endpoint as _, EndpointIn as _, EndpointOut as _};
use embassy_usb::msos::{self, windows_version};
use embassy_usb::{Builder, Config, UsbDevice};
use static_cell::StaticCell;
use stereotac_firmware::Effect;
use stereotac_protocol::{
    DeviceMessage, FrameDecoder, USB_PID, USB_PROTOCOL, USB_SUBCLASS, USB_VID,
};

use super::shared::{self, BOOTLOADER, RECONFIGURED};

/// Interface GUID announced to Windows (WinUSB device interface).
const DEVICE_INTERFACE_GUIDS: &[&str] = &["{5B3C7E2A-9D41-4F0B-8E6A-2C1D7F4A9B35}"];
const PACKET: usize = 64;

type UsbDriver = Driver<'static, USB>;

/// The built USB device and its two endpoints.
pub struct Link {
    pub device: UsbDevice<'static, UsbDriver>,
    pub rx: Endpoint<'static, USB, Out>,
    pub tx: Endpoint<'static, USB, In>,
}

/// Build the USB device with the board's unique id as serial number.
pub fn build(usb: Peri<'static, USB>, irqs: super::Irqs, board_id: [u8; 8]) -> Link {
    static SERIAL: StaticCell<[u8; 16]> = StaticCell::new();
    let serial = SERIAL.init([0; 16]);
    const HEX: &[u8; 16] = b"0123456789ABCDEF";
    for (i, b) in board_id.iter().enumerate() {
        serial[2 * i] = HEX[usize::from(b >> 4)];
        serial[2 * i + 1] = HEX[usize::from(b & 0xf)];
    }
    let serial: &'static str = core::str::from_utf8(serial).unwrap_or("0000000000000000");

    let mut config = Config::new(USB_VID, USB_PID);
    config.manufacturer = Some("stereotac");
    config.product = Some("stereotac visuotactile sensor");
    config.serial_number = Some(serial);
    config.max_power = 500;
    config.max_packet_size_0 = 64;

    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static MSOS_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    let mut builder = Builder::new(
        Driver::new(usb, irqs),
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 256]),
        MSOS_DESC.init([0; 256]),
        CONTROL_BUF.init([0; 64]),
    );
    builder.msos_descriptor(windows_version::WIN8_1, 0);
    builder.msos_feature(msos::CompatibleIdFeatureDescriptor::new("WINUSB", ""));
    builder.msos_feature(msos::RegistryPropertyFeatureDescriptor::new(
        "DeviceInterfaceGUIDs",
        msos::PropertyData::RegMultiSz(DEVICE_INTERFACE_GUIDS),
    ));
    let mut function = builder.function(0xFF, USB_SUBCLASS, USB_PROTOCOL);
    let mut interface = function.interface();
    let mut alt = interface.alt_setting(0xFF, USB_SUBCLASS, USB_PROTOCOL, None);
    let rx = alt.endpoint_bulk_out(None, PACKET as u16);
    let tx = alt.endpoint_bulk_in(None, PACKET as u16);
    drop(function);
    Link {
        device: builder.build(),
        rx,
        tx,
    }
}

#[embassy_executor::task]
pub async fn usb_device(mut device: UsbDevice<'static, UsbDriver>) {
    device.run().await
}

/// Frames in, replies out. A bad frame is answered by a fault event (it has no
/// trustworthy request id); every intact request by exactly one reply.
#[embassy_executor::task]
pub async fn link_rx(mut ep: Endpoint<'static, USB, Out>) {
    let mut decoder = FrameDecoder::<{ stereotac_protocol::MAX_FRAME }>::new();
    let mut packet = [0u8; PACKET];
    loop {
        ep.wait_enabled().await;
        decoder.reset();
        defmt::info!("host connected");
        while let Ok(n) = ep.read(&mut packet).await {
            let mut input = &packet[..n];
            while !input.is_empty() {
                let (frame, rest) = decoder.feed(input);
                input = rest;
                let Some(frame) = frame else { continue };
                let (message, effect) = shared::with(|c| c.handle_frame(frame, shared::now_us()));
                match message {
                    DeviceMessage::Reply { .. } => shared::post_reply(message).await,
                    DeviceMessage::Event { .. } => shared::post_event(message),
                }
                match effect {
                    Effect::None => {}
                    Effect::Reconfigured => RECONFIGURED.signal(()),
                    Effect::EnterBootloader => BOOTLOADER.signal(()),
                }
            }
        }
        defmt::info!("host disconnected");
    }
}

/// Queued frames out, in packets of 64 bytes; a frame ending on a packet boundary is
/// followed by a zero-length packet so the host's transfer completes.
#[embassy_executor::task]
pub async fn link_tx(mut ep: Endpoint<'static, USB, In>) {
    loop {
        ep.wait_enabled().await;
        'connected: loop {
            let frame = shared::OUTBOX.receive().await;
            let bytes = frame.as_bytes();
            for chunk in bytes.chunks(PACKET) {
                if ep.write(chunk).await.is_err() {
                    break 'connected;
                }
            }
            if bytes.len() % PACKET == 0 && ep.write(&[]).await.is_err() {
                break 'connected;
            }
        }
    }
}
