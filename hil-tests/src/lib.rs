//! Hardware-in-loop tests of the stereotac firmware.
//!
//! Planned (issue "Hardware-in-loop tests"): the release firmware ELF running in an
//! emulated RP2040 (rp2040js, driven in lock-step from Rust) in CI, and the same tests
//! against a real sensor when `STEREOTAC_HIL=device` is set. Nothing is implemented here
//! yet; the crate exists so the workspace has its final shape.
