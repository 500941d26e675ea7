//! A first look at a pair as the camera gave it, before any pass over its pixels.
//!
//! A model that undoes the camera's response curve or removes ambient light makes every
//! frame of a pair pass through a table or a subtraction value by value before detection
//! reads it: at 640×480 that was 0.2–0.8 ms a pair, 2–8 times the rest of a pair at rest
//! (`bench skins --dark`: a rest pair 0.33–0.63 ms against 0.10 without the LEDs-off
//! frame), so a skin at rest cost a fifth of a contact. Most pairs of a live stream are
//! at rest. So [`contact::glance`] is taken first on the block means of the frames as
//! they came ([`BlockMeans::of_middle_rows`]): each mean through the curve
//! ([`MeanTable`]), then the LEDs-off frame's means (or the calibration's ambient light)
//! subtracted ([`subtract_means`]). Where it sees a skin at rest, the pair is done.
//! Anywhere else the pair is read as before, every value undone and subtracted, and
//! detection looks again: depth never rests on the approximations here, only a verdict of
//! "at rest" does.
//!
//! Two approximations, both far inside the glance's margin (it asks for 0.9 of the
//! threshold): the curve of a mean is not the mean of the curve (hundredths of a count on
//! flat skin's noise, see [`MeanTable`]), and the ambient light is clamped per block, not
//! per pixel (they differ only where a pixel of the LEDs-off frame is brighter than the
//! lit one). A LEDs-off frame brighter than the lit frames is judged on block means too
//! ([`brighter_fraction_of_means`]); a pair the full read takes needs no such shortcut.

use image::RgbImage;

use super::ambient::{
    AmbientSource, MAX_BRIGHTER_FRACTION, PhaseFrames, brighter_fraction_of_means, subtract_means,
};
use super::camera_curve::{CameraCurve, MeanTable};
use super::colour::ColourFilter;
use super::contact::{self, ContactParams, Detection, References};
use super::smooth::BlockMeans;

/// What the glance needs besides the pair: the curve to undo and the ambient light a
/// pair without a LEDs-off frame is taken to hold.
#[derive(Debug, Clone)]
pub struct RawGlance {
    /// The model's camera curve, on means (`None`: a linear camera).
    curve: Option<MeanTable>,
    /// The calibration's ambient light over the blocks' middle rows, for a model
    /// calibrated on LED light (`None`: the model reads the frames as they are).
    ambient: Option<BlockMeans>,
}

impl RawGlance {
    /// The glance for a model with `curve` whose LED light is the frames less `ambient`
    /// (the calibration's estimate, full size, linear); `None` when there is neither, as
    /// then detection's own glance reads the frames as they came.
    pub fn new(
        curve: Option<&CameraCurve>,
        ambient: Option<&RgbImage>,
        step: usize,
    ) -> Option<Self> {
        if curve.is_none() && ambient.is_none() {
            return None;
        }
        Some(Self {
            curve: curve.map(CameraCurve::mean_table),
            ambient: ambient.map(|a| BlockMeans::of_middle_rows(a, step.max(1))),
        })
    }

    /// The detection of a skin at rest and the ambient light taken out, when the pair's
    /// frames (of the model's size, checked by the caller) show one; `None` when a contact
    /// may be there (or the pair's light is not what the glance can judge), and the pair
    /// must be read in full.
    pub fn at_rest(
        &self,
        frames: PhaseFrames<'_>,
        block_refs: &References,
        filter: &ColourFilter,
        params: &ContactParams,
    ) -> Option<(Detection, AmbientSource)> {
        let step = params.coarse_step.max(1);
        let means = |img: &RgbImage| {
            let mut m = BlockMeans::of_middle_rows(img, step);
            if let Some(curve) = &self.curve {
                curve.undo(&mut m);
            }
            m
        };
        let (mut mx, mut my) = (means(frames.dx), means(frames.dy));
        let source = match &self.ambient {
            None => AmbientSource::ColourFilter,
            Some(estimate) => {
                let dark = frames.dark.map(means);
                let refused = dark.as_ref().is_some_and(|d| {
                    brighter_fraction_of_means(&mx, d).max(brighter_fraction_of_means(&my, d))
                        > MAX_BRIGHTER_FRACTION
                });
                let (ambient, source) = match &dark {
                    Some(d) if !refused => (d, AmbientSource::DarkFrame),
                    Some(_) => (estimate, AmbientSource::CalibrationDarkRefused),
                    None => (estimate, AmbientSource::Calibration),
                };
                if ambient.len() != mx.len() {
                    return None;
                }
                subtract_means(&mut mx, ambient);
                subtract_means(&mut my, ambient);
                source
            }
        };
        contact::glance(&mx, &my, block_refs, filter, params).map(|d| (d, source))
    }
}
