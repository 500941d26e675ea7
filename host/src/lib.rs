//! # stereotac (host library)
//!
//! The host side of the stereotac visuotactile sensor. The `stereotac` CLI
//! (`src/bin/stereotac/`) is a thin layer over it: one command a file, parsing arguments
//! and printing; everything else lives here.
//!
//! From the foundations up (a module uses only those above it in this list):
//!
//! * Shared foundations: [`limits`] (bounds every reader of outside files checks),
//!   [`grid`] (row-major 2-D arrays), [`image_file`] (image files read within bounds),
//!   [`out_dir`] (an output directory per run: nothing replaced without `--force`, no
//!   folder left by a failed run), [`rng`] (a deterministic random generator),
//!   [`timing`] (median timings for the benchmarks), [`cpu`] (vector instructions
//!   the kernels may use), [`union_find`] (disjoint sets, for regions joined run by run), [`output`] (NPY, PNG, PLY files), [`clock`] (host clocks and the device→host clock sync), [`uf2`]
//!   (firmware ELF to UF2 image, flash and RAM footprint).
//! * The link: [`transport`] (byte pipes to a sensor: USB through nusb or libusb; owns
//!   [`transport::Transport`] and the connectors), [`client`] (the protocol client:
//!   request/reply matching, handshake, time-sync pings, event collection), [`device`]
//!   (a connected sensor: events on the host clock, reconnect with backoff),
//!   [`describe`] (protocol values in plain words and JSON), [`selftest`] (command
//!   conformance of any connected sensor).
//! * Frames: [`matcher`] (which LED phase lit each camera frame), [`frames`] (frame
//!   sources, live capture, recording and replay).
//! * Pipelines: [`tactile`] (photometric stereo: dx/dy images to depth of the imprint),
//!   [`stereo`] (stereo depth through the skin: calibration, rectification, matching,
//!   point clouds, evaluation).
//! * [`sim`]: the simulated sensor, its USB link and its cameras, one place: test
//!   inputs and the demo's data, reached through the same code paths as hardware.
//!   [`sensors`]: which sensor (USB by serial, or the simulated one) and opening it.
//! * [`recording`]: MCAP recordings and the Foxglove live view (topics, messages, the
//!   recorder, the streaming reader).
//! * [`live`]: the live pipeline (router, tactile and stereo stages on their threads,
//!   the capture session and loop of `run` and `record`, pairs from a recording, scripted
//!   simulated sessions, `bench live`).
#![warn(missing_docs)]

pub mod client;
pub mod clock;
pub mod cpu;
pub mod describe;
pub mod device;
pub mod frames;
pub mod grid;
pub mod image_file;
pub mod limits;
pub mod live;
pub mod matcher;
pub mod median;
pub mod out_dir;
pub mod output;
pub mod picture;
pub mod recording;
pub mod rng;
pub mod selftest;
pub mod sensors;
pub mod sim;
pub mod stereo;
pub mod tactile;
pub mod timing;
pub mod transport;
pub mod uf2;
pub mod union_find;
