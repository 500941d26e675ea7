//! stereotac sensor firmware for the RP2040 (Raspberry Pi Pico).
//!
//! Build with `cargo fw`; flash with `cargo fw-run` (probe-rs) or drag the UF2 onto the
//! RP2040 boot drive. The board code lives in `board/`; the logic it runs is the
//! `stereotac_firmware` library, which is also tested on the host.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod board;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "stereotac-firmware runs on the RP2040, not on this machine.\n\
         Build it with `cargo fw` (target thumbv6m-none-eabi); its logic is tested on the \
         host with `cargo test -p stereotac-firmware`."
    );
    std::process::exit(2);
}
