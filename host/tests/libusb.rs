//! The libusb transport (built with the `libusb` feature): its errors read as the same
//! typed errors as nusb's, and listing or opening with no sensor attached (CI machines,
//! which may have no usbfs at all) gives typed answers, never a panic.

#[cfg(feature = "libusb")]
mod with_the_feature {
    use stereotac::transport::libusb::{LibusbTransport, list, open_error, transfer_error};
    use stereotac::transport::{OpenError, TransportError};

    #[test]
    fn errors_map_to_the_same_typed_errors_as_nusb() {
        assert!(matches!(
            open_error(rusb::Error::Access, "1:2"),
            OpenError::PermissionDenied { path } if path == "1:2"
        ));
        assert!(matches!(
            open_error(rusb::Error::Busy, "1:2"),
            OpenError::Busy { .. }
        ));
        assert!(matches!(
            open_error(rusb::Error::Pipe, "1:2"),
            OpenError::Usb(message) if message.starts_with("libusb")
        ));
        assert!(matches!(
            transfer_error(rusb::Error::NoDevice),
            TransportError::Disconnected
        ));
        assert!(matches!(
            transfer_error(rusb::Error::Overflow),
            TransportError::Io(_)
        ));
    }

    #[test]
    fn listing_and_opening_without_sensors_give_typed_answers() {
        match list() {
            Ok(found) => assert!(found.is_empty() || found.iter().all(|s| !s.path.is_empty())),
            Err(OpenError::Usb(message)) => assert!(message.starts_with("libusb")),
            Err(other) => panic!("unexpected {other}"),
        }
        match LibusbTransport::open(Some("NO-SUCH-SENSOR")) {
            Err(OpenError::NotFound { serial, .. }) => {
                assert_eq!(serial.as_deref(), Some("NO-SUCH-SENSOR"))
            }
            Err(OpenError::Usb(message)) => assert!(message.starts_with("libusb")),
            other => panic!("unexpected {other:?}"),
        }
    }
}
