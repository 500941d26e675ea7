//! Skin families: simulated sensors with randomised physics, to tune the tactile pipeline
//! on some and judge it on others it was never tuned on.
//!
//! Two renderers with different physics draw the skins: [`render`](super::render) (ours:
//! directional strip light, cosine law, optional Blinn–Phong) with randomised optics, and
//! [`physical`] (independent: point LEDs with inverse-square fall-off, Oren–Nayar diffuse
//! plus a GGX microfacet lobe seen by a pinhole camera, its own camera model and MJPG
//! compression). [`families`] names them and splits them into tuning and evaluation sets;
//! [`evaluate`] measures the goal table on each.

pub mod evaluate;
pub mod families;
pub mod physical;

use image::RgbImage;

/// The three images of one LED cycle: the two gradient phases and a LEDs-off frame.
#[derive(Debug, Clone)]
pub struct SkinFrames {
    /// Strips 1 (blue, x−) and 3 (red, x+) lit.
    pub dx: RgbImage,
    /// Strips 2 (blue, y−) and 4 (red, y+) lit.
    pub dy: RgbImage,
    /// LEDs off: only the ambient light through the skin.
    pub dark: RgbImage,
}

/// Ambient light of each of the three exposures, relative to the family's nominal level
/// (1.0): scene light that changes between frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmbientScale {
    /// During the dx exposure.
    pub dx: f64,
    /// During the dy exposure.
    pub dy: f64,
    /// During the dark exposure.
    pub dark: f64,
}

impl AmbientScale {
    /// The same ambient light in all three exposures.
    pub const STEADY: AmbientScale = AmbientScale {
        dx: 1.0,
        dy: 1.0,
        dark: 1.0,
    };
}
