//! Gradient models: from the normalised LED colour `(r, b)` of one phase image (made
//! independent of the other axis' slope by [`colour_features`]) and the pixel's position
//! `(x, y)` (both in [0, 1]) to the slope along that phase's axis.
//!
//! [`TactileModel`] is what calibration writes and reconstruction reads: one
//! [`AxisModel`] per phase (each with a lookup table, an MLP and a light-response model),
//! the colour filter and contact thresholds it was calibrated with, and a low-resolution
//! no-contact background used when no reference frames are given. The file is JSON with a format name and a
//! version number checked on load.

mod cells;
pub mod light;
pub mod lut;
pub mod mlp;
pub mod photometric;
pub mod response;
pub mod side_light;
pub mod validate;

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::crosstalk::Unmix;

pub use light::LightModel;
pub use lut::{GainPlanes, Lut};
pub use mlp::{Mlp, MlpTraining};
pub use photometric::{JointSample, PhotometricModel};
pub use side_light::SideLight;

use super::ambient::AmbientEstimate;
use super::colour::{ColourFilter, Reference};
use super::contact::{ContactParams, References};
use super::smooth::bilinear;
use crate::limits::MAX_MODEL_FILE;

/// Colour range covered by the lookup table (cross-normalised units, flat skin = 1).
pub const LUT_MAX_COLOUR: f32 = 4.0;

/// Model inputs `[[red, blue] of dx, of dy]` of a matte skin at slopes `(p, q)`, lit from
/// elevation `cot⁻¹ k` on all four sides, made as reconstruction makes them
/// ([`colour_features`]): the analytic skin of the models' tests.
#[cfg(test)]
pub(crate) fn matte_features(p: f32, q: f32, k: f32) -> [[f32; 2]; 2] {
    let norm = (1.0 + p * p + q * q).sqrt();
    let lit = |s: f32| [(1.0 + k * s).max(0.0) / norm, (1.0 - k * s).max(0.0) / norm];
    let ([rx, bx], [ry, by]) = (lit(p), lit(q));
    let f = colour_features([rx, bx, ry, by]);
    [f[0].expect("lit"), f[1].expect("lit")]
}

/// Model colour inputs of both phases from one pixel's normalised colours
/// `[r_dx, b_dx, r_dy, b_dy]` (NaN where the colour filter rejected that phase).
///
/// Each phase's colour is multiplied by the other phase's `2 / (r + b)`. For matte skin
/// `r + b` of a phase is `2 / |n|` whatever the slope along that phase's axis, so this
/// removes the dependence on the slope along the *other* axis (`|n| = √(1 + p² + q²)`).
/// Without it, a colour in which one LED is shadowed (steep walls) is ambiguous and a
/// model reads steep walls shallow. When the other phase is rejected the factor is 1.
pub fn colour_features(c: [f32; 4]) -> [Option<[f32; 2]>; 2] {
    let (sx, sy) = (cross_factor(c[0], c[1]), cross_factor(c[2], c[3]));
    let phase = |r: f32, b: f32, s: f32| (!r.is_nan() && !b.is_nan()).then_some([r * s, b * s]);
    [phase(c[0], c[1], sy), phase(c[2], c[3], sx)]
}

/// The factor [`colour_features`] multiplies the other phase's colour by, from one
/// phase's normalised `(r, b)`: `2 / (r + b)` within [0.5, 3], or 1 when the sum is not a
/// positive number (a rejected phase is NaN).
#[inline(always)]
pub fn cross_factor(r: f32, b: f32) -> f32 {
    let s = r + b;
    // Both sides made, then one kept: no branch, so it runs in vector lanes.
    let factor = (2.0 / s).clamp(0.5, 3.0);
    if s.is_finite() & (s > 0.0) {
        factor
    } else {
        1.0
    }
}

/// One training example: features `[r, b, x, y]` and the true slope.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Normalised red, normalised blue, x / width, y / height.
    pub features: [f32; 4],
    /// Slope along the phase's axis.
    pub target: f32,
}

/// Which model turns colour into slope.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Lookup table (fast).
    #[default]
    Lut,
    /// Multilayer perceptron (smooth).
    Mlp,
    /// Each strip's light response per cell, inverted (extrapolates past the
    /// calibration's slopes).
    Light,
    /// Four-light photometric stereo: each strip's light direction per cell, inverted
    /// from all four colours at once (extrapolates, reads both axes together).
    Photometric,
}

impl ModelKind {
    /// Every kind.
    pub const ALL: [ModelKind; 4] = [
        ModelKind::Lut,
        ModelKind::Mlp,
        ModelKind::Light,
        ModelKind::Photometric,
    ];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Lut => "lut",
            ModelKind::Mlp => "mlp",
            ModelKind::Light => "light",
            ModelKind::Photometric => "photometric",
        }
    }
}

impl fmt::Display for ModelKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ModelKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown model {s:?} (expected lut, mlp, light or photometric)"))
    }
}

/// Both models of one phase.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisModel {
    /// Lookup table.
    pub lut: Lut,
    /// Perceptron.
    pub mlp: Mlp,
    /// Light response (absent from models calibrated before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<LightModel>,
}

impl AxisModel {
    /// Slopes for feature rows with the chosen model.
    pub fn eval(&self, kind: ModelKind, features: &[[f32; 4]], out: &mut [f32]) {
        match kind {
            ModelKind::Lut => self.lut.eval_batch(features, out),
            ModelKind::Mlp => self.mlp.eval_batch(features, out),
            ModelKind::Light => match &self.light {
                Some(light) => light.eval_batch(features, out),
                // Refused when the reconstructor is made; slope 0 if asked anyway.
                None => out.iter_mut().for_each(|o| *o = 0.0),
            },
            // Reads both axes at once ([`TactileModel::photometric`]), never one axis:
            // asked for one, the slopes are unknown.
            ModelKind::Photometric => out.iter_mut().for_each(|o| *o = f32::NAN),
        }
    }
}

/// No-contact LED light at reduced resolution: per block, `[red − green, blue − green,
/// green]` of each phase, averaged over `factor × factor` pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Background {
    /// Block size (px).
    pub factor: usize,
    /// Blocks across.
    pub width: usize,
    /// Blocks down.
    pub height: usize,
    /// dx phase planes.
    pub dx: Vec<[f32; 3]>,
    /// dy phase planes.
    pub dy: Vec<[f32; 3]>,
}

impl Background {
    /// Block-averages two full-resolution references (`[red, blue, green]` planes).
    pub fn from_images(dx: &image::RgbImage, dy: &image::RgbImage, factor: usize) -> Self {
        let (w, h) = (dx.width() as usize, dx.height() as usize);
        let (bw, bh) = (w.div_ceil(factor), h.div_ceil(factor));
        let blocks = |img: &image::RgbImage| {
            let mut acc = vec![[0.0f32; 4]; bw * bh];
            for (x, y, px) in img.enumerate_pixels() {
                let [r, g, b] = px.0.map(f32::from);
                let a = &mut acc[(y as usize / factor) * bw + x as usize / factor];
                a[0] += r - g;
                a[1] += b - g;
                a[2] += g;
                a[3] += 1.0;
            }
            acc.into_iter()
                .map(|a| [a[0] / a[3], a[1] / a[3], a[2] / a[3]])
                .collect()
        };
        Self {
            factor,
            width: bw,
            height: bh,
            dx: blocks(dx),
            dy: blocks(dy),
        }
    }

    /// Planes `[red − green, blue − green, green]` at pixel position `(x, y)` (pixel
    /// centres at `+0.5`), bilinear between block centres.
    fn sample(&self, blocks: &[[f32; 3]], x: f32, y: f32) -> [f32; 3] {
        bilinear(blocks, self.width, self.height, self.factor, x, y)
    }

    /// References at `cell`-pixel resolution over a `width × height` frame: full
    /// resolution with `cell = 1`, detection blocks with `cell = coarse_step`.
    /// Colours are `unmix`ed ([`crate::tactile::crosstalk`]).
    pub fn references_at(
        &self,
        width: usize,
        height: usize,
        cell: usize,
        unmix: Unmix,
    ) -> References {
        let cell = cell.max(1);
        let (cw, ch) = (width.div_ceil(cell), height.div_ceil(cell));
        let plane = |blocks: &[[f32; 3]]| {
            Reference::from_planes(
                cw,
                ch,
                (0..ch).flat_map(move |j| {
                    (0..cw).map(move |i| {
                        // Centre of the cell (of the pixels it has, at the frame's edges).
                        let cx = (i * cell + ((i + 1) * cell).min(width)) as f32 / 2.0;
                        let cy = (j * cell + ((j + 1) * cell).min(height)) as f32 / 2.0;
                        self.sample(blocks, cx, cy)
                    })
                }),
                unmix,
            )
        };
        References {
            dx: plane(&self.dx),
            dy: plane(&self.dy),
        }
    }

    /// Full-resolution references by bilinear interpolation between block centres.
    pub fn references(&self, width: usize, height: usize, unmix: Unmix) -> References {
        self.references_at(width, height, 1, unmix)
    }
}

/// How well the models fit, in slope units (RMS).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitReport {
    /// Pairs used for training.
    pub training_pairs: usize,
    /// Pairs held out for validation.
    pub validation_pairs: usize,
    /// Training samples per axis.
    pub samples_per_axis: usize,
    /// LUT RMS on the training pairs.
    pub lut_train_rms: f32,
    /// LUT RMS on the held-out pairs.
    pub lut_validation_rms: f32,
    /// MLP RMS on the training pairs.
    pub mlp_train_rms: f32,
    /// MLP RMS on the held-out pairs.
    pub mlp_validation_rms: f32,
    /// Light model RMS on the training pairs.
    #[serde(default)]
    pub light_train_rms: f32,
    /// Light model RMS on the held-out pairs.
    #[serde(default)]
    pub light_validation_rms: f32,
    /// Photometric model RMS on the training pairs (both axes' slopes, over the samples
    /// it reads).
    #[serde(default)]
    pub photometric_train_rms: f32,
    /// Photometric model RMS on the held-out pairs.
    #[serde(default)]
    pub photometric_validation_rms: f32,
    /// Share of the held-out samples the photometric model reads (the RMS is over these;
    /// the others are filled from their neighbours in use).
    #[serde(default)]
    pub photometric_validation_read: f32,
}

/// Format name stored in every model file.
pub const MODEL_FORMAT: &str = "stereotac-tactile-model";
/// Current model file version.
pub const MODEL_VERSION: u32 = 1;

/// Skin thickness assumed when none is given (mm): the simulated sensor's, and within
/// the 1.5–4 mm of the elastomer skins of camera-based tactile sensors.
pub const DEFAULT_SKIN_THICKNESS_MM: f64 = 3.0;

fn default_skin_thickness_mm() -> f64 {
    DEFAULT_SKIN_THICKNESS_MM
}

/// A calibrated sensor: everything reconstruction needs besides the frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TactileModel {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// File version ([`MODEL_VERSION`]).
    pub version: u32,
    /// Frame width the model was calibrated at.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Scale (px per mm).
    pub px_per_mm: f64,
    /// Ball used for calibration (mm); when presses of other balls were added, the
    /// first one's (each press's ball is in the calibration report).
    pub ball_diameter_mm: f64,
    /// The other balls (mm) whose presses taught the model, smallest first; empty (and
    /// left out of the file) when every press was of [`Self::ball_diameter_mm`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub other_balls_mm: Vec<f64>,
    /// Thickness of the sensor's skin (mm): nothing presses deeper, so a reconstruction
    /// deeper than this is refused ([`crate::tactile::reconstruct::ReconstructError::DepthBeyondSkin`]).
    /// Files written before it existed read as [`DEFAULT_SKIN_THICKNESS_MM`].
    #[serde(default = "default_skin_thickness_mm")]
    pub skin_thickness_mm: f64,
    /// Colour filter thresholds.
    pub filter: ColourFilter,
    /// Contact detection thresholds.
    pub contact: ContactParams,
    /// No-contact background (used when no reference frames are given).
    pub background: Background,
    /// Calibrated on LED light alone (LEDs-off frames subtracted): the calibration's mean
    /// ambient light, subtracted from frames that come without a LEDs-off frame. `None`:
    /// the model works on raw frames (see [`super::ambient`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ambient: Option<AmbientEstimate>,
    /// dx phase: slope along x.
    pub dx: AxisModel,
    /// dy phase: slope along y.
    pub dy: AxisModel,
    /// Both phases at once: four-light photometric stereo (absent from models calibrated
    /// before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub photometric: Option<PhotometricModel>,
    /// The side light of the strips in the cross factor, per cell of the frame
    /// ([`side_light`]): the lookup tables were taught on colours corrected by it and
    /// read corrected. `None` (left out of the file): none measured, as in model files
    /// written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub side_light: Option<SideLight>,
    /// The camera's response curve, undone on every frame before it is read
    /// ([`crate::tactile::camera_curve`]). `None` (left out of the file): a linear
    /// camera, as in model files written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_curve: Option<crate::tactile::camera_curve::CameraCurve>,
    /// Fit quality.
    pub fit: FitReport,
}

/// Why a model file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Reading or writing failed.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Not valid JSON for a model: not one at all (nothing read), or a model file damaged
    /// at `field` (a key gone, a cut file, a number of the wrong kind, a fixed-size list
    /// of another length).
    #[error("{path}: {}", parse_message(field, source))]
    Parse {
        /// File.
        path: String,
        /// Where in the model (`dx.lut.table[12]`; empty at the top).
        field: String,
        /// Cause.
        source: serde_json::Error,
    },
    /// Another format, or a version this build cannot read.
    #[error(
        "{path}: format {format:?} version {version}, this build reads {MODEL_FORMAT:?} version {MODEL_VERSION}"
    )]
    Version {
        /// File.
        path: String,
        /// Format found.
        format: String,
        /// Version found.
        version: u32,
    },
    /// A field that cannot be right (see [`validate`]).
    #[error("{path}: `{field}`: {why}; the file was edited or damaged: recalibrate, or restore it")]
    Invalid {
        /// File.
        path: String,
        /// The field.
        field: String,
        /// What is wrong with it.
        why: String,
    },
}

impl TactileModel {
    /// Leaves out the optional parts that read a slope's direction wrongly at the frame's
    /// centre ([`validate::misdirected`]) and says why, one line each: calibration's step,
    /// so that on a skin whose presses these simpler models fit badly the table and the
    /// perceptron still make a calibration (a file with such a part is refused).
    pub fn leave_out_misdirected(&mut self) -> Vec<String> {
        use validate::OptionalPart;
        let mut warnings = Vec::new();
        for (part, field, why) in validate::misdirected(self) {
            let without = match part {
                OptionalPart::Light { dx } => {
                    let axis = if dx { &mut self.dx } else { &mut self.dy };
                    axis.light = None;
                    "slopes past the table's reach are read by the table alone, and the light \
                     model (--model-kind light) cannot be used"
                }
                OptionalPart::Photometric => {
                    self.photometric = None;
                    "the photometric model (--model-kind photometric) cannot be used"
                }
            };
            warnings.push(format!(
                "{field} {why}; it is left out of the model: {without}"
            ));
        }
        warnings
    }

    /// Writes the model as JSON.
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let io = |source| ModelError::Io {
            path: path.display().to_string(),
            source,
        };
        crate::output::write_atomic(path, &self.to_json()).map_err(io)
    }

    /// The model as JSON, as [`Self::save`] writes it (and recordings attach it).
    pub fn to_json(&self) -> Vec<u8> {
        serde_json::to_vec(self).expect("a model always serialises")
    }

    /// Reads and checks a model file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        use std::io::Read;
        let name = path.display().to_string();
        let io = |source| ModelError::Io {
            path: name.clone(),
            source,
        };
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_MODEL_FILE + 1).read_to_end(&mut bytes))
            .map_err(io)?;
        if bytes.len() as u64 > MAX_MODEL_FILE {
            return Err(ModelError::Invalid {
                path: name,
                field: "(file)".into(),
                why: format!(
                    "larger than {MAX_MODEL_FILE} bytes, more than a model of the largest frame holds"
                ),
            });
        }
        Self::from_json(&name, &bytes)
    }

    /// The model read with the path of the field being read, so an error names it (a key
    /// missing deep inside, a NaN written by hand into a table).
    fn read_with_path(name: &str, bytes: &[u8]) -> Result<Self, ModelError> {
        let reader = &mut serde_json::Deserializer::from_slice(bytes);
        serde_path_to_error::deserialize(reader).map_err(|e| {
            let field = e.path().to_string();
            ModelError::Parse {
                path: name.to_string(),
                // Only a named field is inside a model: "." is the top, "?" a place the
                // parser could not name (not JSON), "[0]" a list where a model goes.
                field: if field.starts_with(|c: char| c.is_ascii_alphabetic()) {
                    field
                } else {
                    String::new()
                },
                source: e.into_inner(),
            }
        })
    }

    /// Reads and checks a model's JSON; `name` says where it came from in errors.
    pub fn from_json(name: &str, bytes: &[u8]) -> Result<Self, ModelError> {
        // (Header first: another format or version is said as such, not as its fields.)
        #[derive(Deserialize)]
        struct Header {
            format: String,
            version: u32,
        }
        let header: Header = match serde_json::from_slice(bytes) {
            Ok(h) => h,
            // Not JSON (a NaN typed in, a cut file): the full read says where.
            Err(source) => {
                return Err(Self::read_with_path(name, bytes)
                    .err()
                    .unwrap_or(ModelError::Parse {
                        path: name.to_string(),
                        field: String::new(),
                        source,
                    }));
            }
        };
        if header.format != MODEL_FORMAT || header.version != MODEL_VERSION {
            return Err(ModelError::Version {
                path: name.to_string(),
                format: header.format,
                version: header.version,
            });
        }
        let model = Self::read_with_path(name, bytes)?;
        validate::check(&model).map_err(|(field, why)| ModelError::Invalid {
            path: name.to_string(),
            field,
            why,
        })?;
        Ok(model)
    }
}

/// [`ModelError::Parse`]'s words: a failure deep inside a model's fields is a model file
/// that was edited or damaged, not another kind of file.
fn parse_message(field: &str, source: &serde_json::Error) -> String {
    if field.is_empty() {
        format!("not a stereotac model file: {source}")
    } else {
        format!("a model file edited or damaged at `{field}`: {source}; recalibrate, or restore it")
    }
}
