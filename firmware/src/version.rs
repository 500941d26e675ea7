//! Firmware version and the git commit it was built from (set by `build.rs`).

use stereotac_protocol::FirmwareVersion;

/// This firmware's version, from the crate version.
pub const FIRMWARE_VERSION: FirmwareVersion = FirmwareVersion {
    major: parse_u8(env!("CARGO_PKG_VERSION_MAJOR")),
    minor: parse_u8(env!("CARGO_PKG_VERSION_MINOR")),
    patch: parse_u8(env!("CARGO_PKG_VERSION_PATCH")),
};

/// SHA-1 of the commit the firmware was built from; all zero when git was unavailable.
pub const GIT_HASH: [u8; 20] = parse_hash(env!("STEREOTAC_GIT_HASH"));

/// Whether the work tree had uncommitted changes at build time.
pub const GIT_DIRTY: bool = matches!(env!("STEREOTAC_GIT_DIRTY").as_bytes(), b"1");

const fn parse_u8(s: &str) -> u8 {
    let bytes = s.as_bytes();
    let mut value: u32 = 0;
    let mut i = 0;
    while i < bytes.len() {
        assert!(
            bytes[i].is_ascii_digit(),
            "version component is not a number"
        );
        value = value * 10 + (bytes[i] - b'0') as u32;
        assert!(value <= 255, "version component exceeds 255");
        i += 1;
    }
    value as u8
}

const fn hex_digit(c: u8) -> u8 {
    match c {
        b'0'..=b'9' => c - b'0',
        b'a'..=b'f' => c - b'a' + 10,
        b'A'..=b'F' => c - b'A' + 10,
        _ => 0,
    }
}

/// 40 hex digits to 20 bytes; anything else gives all zero.
const fn parse_hash(s: &str) -> [u8; 20] {
    let bytes = s.as_bytes();
    let mut out = [0u8; 20];
    if bytes.len() != 40 {
        return out;
    }
    let mut i = 0;
    while i < 20 {
        out[i] = hex_digit(bytes[2 * i]) << 4 | hex_digit(bytes[2 * i + 1]);
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn version_matches_the_crate() {
        let v = FIRMWARE_VERSION;
        let text = format!("{}.{}.{}", v.major, v.minor, v.patch);
        assert_eq!(text, env!("CARGO_PKG_VERSION"));
    }

    #[test]
    fn hash_parsing() {
        let h = parse_hash("00112233445566778899aabbccddeeff01234567");
        assert_eq!(h[0], 0x00);
        assert_eq!(h[1], 0x11);
        assert_eq!(h[10], 0xaa);
        assert_eq!(h[19], 0x67);
        assert_eq!(parse_hash("unknown"), [0; 20]);
    }
}
