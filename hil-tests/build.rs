//! Which HIL tests this build runs, from `STEREOTAC_HIL` (read again when it changes), so
//! the ones that do not apply are reported as ignored, not as passed: `device` runs
//! `tests/device.rs` against an attached sensor, `off` runs neither, anything else (the
//! default) the emulated RP2040 of `tests/emulated.rs`.

fn main() {
    println!("cargo::rerun-if-env-changed=STEREOTAC_HIL");
    println!("cargo::rustc-check-cfg=cfg(hil_device)");
    println!("cargo::rustc-check-cfg=cfg(hil_emulator)");
    match std::env::var("STEREOTAC_HIL").as_deref() {
        Ok("device") => println!("cargo::rustc-cfg=hil_device"),
        Ok("off") => {}
        _ => println!("cargo::rustc-cfg=hil_emulator"),
    }
}
