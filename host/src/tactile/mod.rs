//! Tactile reconstruction: from the dx and dy images of the lit skin to the depth of the
//! imprint in millimetres.
//!
//! Stages, each in its own module: [`colour`] keeps the LEDs' red and blue light and
//! normalises it by a no-contact reference; [`contact`] finds touched pixels and the region
//! of interest (no contact → no further work); [`features`] gathers the touched pixels'
//! colours as the model's inputs; [`model`] turns colour into slopes (lookup
//! table or small MLP, trained by [`calibrate`]); [`sanitize`] bounds the slopes;
//! [`poisson`] integrates them; [`output`] writes NPY/PNG/PLY/JSON. [`render`] is our own
//! synthetic sensor used by the demo, the benchmark and the tests; [`skins`] draws skins
//! with randomised physics from it and from an independent renderer, to judge the
//! pipeline on skins it was not tuned on.

pub mod ambient;
pub mod bench;
pub mod calibrate;
pub mod camera_curve;
pub mod colour;
pub mod contact;
pub mod crosstalk;
pub mod features;
pub mod images;
pub mod integrable;
pub mod model;
pub mod output;
pub mod past_reach;
pub mod phase_check;
pub mod poisson;
pub mod quiet;
pub mod raw_glance;
pub mod reconstruct;
pub mod reference_check;
pub mod render;
pub mod rgb_planes;
pub mod sanitize;
pub mod shadowed;
pub mod skins;
pub mod smooth;
pub mod synthetic;
pub mod unread;
