//! The pipeline options of `run` and `process` (tactile model, stereo calibration and
//! settings), the stages they build, and what a recording keeps of them so `process`
//! can build the same stages again.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, Result, anyhow, bail};
use image::RgbImage;
use stereotac::image_file::{self, Need};
use stereotac::live::{StereoStage, TactileStage};
use stereotac::matcher::StampRef;
use stereotac::recording::topics;
use stereotac::recording::writer::{Item, Recorder};
use stereotac::stereo::{LengthUnit, MatcherKind, StereoCalibration, StereoConfig, StereoPipeline};
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;

use crate::args::PipelineArgs;

/// Attachment names of the no-contact reference frames.
pub const REFERENCE_DX: &str = "reference_dx.png";
/// See [`REFERENCE_DX`].
pub const REFERENCE_DY: &str = "reference_dy.png";
/// Metadata record of the stereo settings.
pub const META_STEREO: &str = "stereo_settings";

/// Reads a stereo calibration (`--calib` files, `--units`), printing a warning for each
/// key its format does not have (ignored, but a misspelt key should be seen).
pub fn load_calibration(files: &[PathBuf], units: LengthUnit) -> Result<StereoCalibration> {
    load_calibration_noting(files, units).map(|(calib, _)| calib)
}

/// [`load_calibration`], also returning the warnings it printed.
pub fn load_calibration_noting(
    files: &[PathBuf],
    units: LengthUnit,
) -> Result<(StereoCalibration, Vec<String>)> {
    let (calib, notes) = StereoCalibration::load_noting(files, units)?;
    for note in &notes {
        eprintln!("warning: {note}");
    }
    Ok((calib, notes))
}

/// Model and calibration options.
#[derive(Debug, Clone, clap::Args)]
pub struct StageArgs {
    /// Tactile model from `calibrate` (dx/dy pairs of camera 0 → depth).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Gradient model: lut, mlp, light or photometric (default: lut; `process`: the recording's).
    #[arg(long = "model-kind")]
    pub model_kind: Option<ModelKind>,
    /// Stereo calibration (dark frames of cameras 0 and 1 → depth): one OpenCV stereo
    /// YAML, or two ROS camera_info YAMLs (left, then right).
    #[arg(long = "calib")]
    pub calib: Vec<PathBuf>,
    /// Length unit of an OpenCV calibration's `T` (ROS camera_info files are always
    /// metres): mm (default) or m.
    #[arg(long, default_value = "mm")]
    pub units: LengthUnit,
    /// Accept a tactile model calibrated with LEDs-off frames where the mode takes none:
    /// the ambient light measured at calibration is removed from every pair instead of
    /// each pair's own (wrong as soon as the room's light changes).
    #[arg(long)]
    pub static_ambient: bool,
    /// Keep the model's slopes (lookup table or perceptron) where they reach the
    /// calibration's limit (by default the model file's light model reads steeper walls
    /// there; `process`: as the recording's run).
    #[arg(long)]
    pub no_past_reach: bool,
}

/// What a size mismatch asks the user to change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SizeFix {
    /// Live: calibrate at the cameras' size, or set the cameras to the file's (`--size`).
    Camera,
    /// A recording's frames are what they are: give a file of their size.
    Recording,
}

impl SizeFix {
    fn say(self, what: &str, option: &str, (w, h): (u32, u32)) -> String {
        match self {
            SizeFix::Camera => {
                format!("calibrate at this size, or set the camera to {w}×{h} (--size)")
            }
            SizeFix::Recording => {
                format!("give {what} at the recording's frame size ({option} FILE)")
            }
        }
    }
}

/// A tactile model with the no-contact frames it normalises by, if any.
#[derive(Debug, Clone)]
pub struct TactileSetup {
    /// The model.
    pub model: TactileModel,
    /// No-contact dx and dy frames.
    pub references: Option<(RgbImage, RgbImage)>,
    /// Gradient model.
    pub kind: ModelKind,
    /// The calibration's ambient light accepted in place of LEDs-off frames
    /// (`--static-ambient`; kept in the recording, so `process` does as `run` did).
    pub static_ambient: bool,
    /// The light model reads slopes steeper than the calibration's (not with
    /// `--no-past-reach`; kept in the recording too).
    pub past_reach: bool,
}

impl TactileSetup {
    /// The setup as a recording keeps it (the model's JSON, the references as PNG),
    /// read back: what runs live is exactly what `process` will load.
    pub fn round_trip(self) -> Result<Self> {
        let model = TactileModel::from_json("the model", &self.model.to_json())?;
        Ok(Self { model, ..self })
    }

    /// The stage for a camera stamping `stamp_ref`.
    pub fn stage(&self, stamp_ref: StampRef) -> Result<TactileStage> {
        let mut reconstructor = Reconstructor::new(
            self.model.clone(),
            self.kind,
            SolverKind::Dct,
            self.references.as_ref().map(|(dx, dy)| (dx, dy).into()),
        )?;
        reconstructor.set_past_reach(self.past_reach);
        Ok(TactileStage::new(
            reconstructor,
            self.model.px_per_mm,
            stamp_ref,
        ))
    }

    /// Refuses a model of another frame size than the camera's; `fix` says what to do
    /// (it depends on the command).
    pub fn check_size(&self, camera: &str, size: (u32, u32), fix: SizeFix) -> Result<()> {
        let m = (self.model.width as u32, self.model.height as u32);
        if m != size {
            bail!(
                "the tactile model was calibrated at {}×{} but {camera} gives {}×{} frames: \
                 {}",
                m.0,
                m.1,
                size.0,
                size.1,
                fix.say("a model calibrated", "--model", m)
            );
        }
        Ok(())
    }

    /// Puts the model and references into the recording.
    pub fn record(&self, recorder: &Recorder) -> Result<()> {
        let mut items = vec![Item::Attachment {
            name: topics::MODEL_ATTACHMENT.into(),
            media_type: "application/json".into(),
            data: self.model.to_json(),
        }];
        if let Some((dx, dy)) = &self.references {
            for (name, img) in [(REFERENCE_DX, dx), (REFERENCE_DY, dy)] {
                items.push(Item::Attachment {
                    name: name.into(),
                    media_type: "image/png".into(),
                    data: png(img)?,
                });
            }
        }
        items.push(Item::Metadata {
            name: "tactile_settings".into(),
            entries: BTreeMap::from([
                ("model_kind".into(), self.kind.to_string()),
                ("static_ambient".into(), self.static_ambient.to_string()),
                ("past_reach".into(), self.past_reach.to_string()),
            ]),
        });
        for item in items {
            if !recorder.send(item) {
                bail!("the recording's writer stopped");
            }
        }
        Ok(())
    }
}

/// A stereo calibration with the pipeline settings.
#[derive(Debug, Clone)]
pub struct StereoSetup {
    /// The calibration.
    pub calib: StereoCalibration,
    /// The settings.
    pub config: StereoConfig,
}

impl StereoSetup {
    /// The setup as a recording keeps it (OpenCV YAML), read back.
    pub fn round_trip(self) -> Result<Self> {
        let calib =
            StereoCalibration::from_opencv_yaml("the calibration", &self.calib.to_opencv_yaml())?;
        Ok(Self { calib, ..self })
    }

    /// The stage for cameras stamping `stamp_refs`.
    pub fn stage(&self, stamp_refs: [StampRef; 2]) -> Result<StereoStage> {
        let pipeline = StereoPipeline::new(&self.calib, self.config)
            .context("setting up the stereo pipeline")?;
        Ok(StereoStage::new(pipeline, stamp_refs))
    }

    /// Refuses a calibration of another frame size than the cameras'.
    pub fn check_size(
        &self,
        camera: &str,
        left: bool,
        size: (u32, u32),
        fix: SizeFix,
    ) -> Result<()> {
        let c = if left {
            &self.calib.left
        } else {
            &self.calib.right
        };
        if (c.width, c.height) != size {
            bail!(
                "the stereo calibration's {} camera is {}×{} but {camera} gives {}×{} frames: \
                 {}",
                if left { "left" } else { "right" },
                c.width,
                c.height,
                size.0,
                size.1,
                fix.say("a stereo calibration made", "--calib", (c.width, c.height))
            );
        }
        Ok(())
    }

    /// Puts the calibration and settings into the recording.
    pub fn record(&self, recorder: &Recorder) -> Result<()> {
        let c = &self.config;
        let items = [
            Item::Attachment {
                name: topics::CALIBRATION_ATTACHMENT.into(),
                media_type: "application/yaml".into(),
                data: self.calib.to_opencv_yaml().into_bytes(),
            },
            Item::Metadata {
                name: META_STEREO.into(),
                entries: BTreeMap::from([
                    ("near_mm".into(), c.near_mm.to_string()),
                    ("far_mm".into(), c.far_mm.to_string()),
                    ("scale".into(), c.rectify_scale.to_string()),
                    ("block_size".into(), c.window().to_string()),
                    ("matcher".into(), c.matcher.name().into()),
                    ("sgm_paths".into(), c.sgm_paths.count().to_string()),
                ]),
            },
        ];
        for item in items {
            if !recorder.send(item) {
                bail!("the recording's writer stopped");
            }
        }
        Ok(())
    }
}

/// The stereo settings a recording's metadata names (defaults for what it does not).
pub fn stereo_settings(entries: Option<&BTreeMap<String, String>>) -> Result<PipelineArgs> {
    let mut a = PipelineArgs::default();
    let Some(entries) = entries else {
        return Ok(a);
    };
    let get = |key: &str| -> Result<Option<f64>> {
        entries
            .get(key)
            .map(|v| {
                v.parse::<f64>().with_context(|| {
                    format!("metadata `{META_STEREO}` entry `{key}`: {v:?} is not a number")
                })
            })
            .transpose()
    };
    if let Some(v) = get("near_mm")? {
        a.near_mm = v;
    }
    if let Some(v) = get("far_mm")? {
        a.far_mm = v;
    }
    if let Some(v) = get("scale")? {
        a.scale = v;
    }
    if let Some(v) = get("block_size")? {
        a.block_size = Some(v as u32);
    }
    // Recordings made before these entries matched with the default: block matching.
    if let Some(v) = entries.get("matcher") {
        a.matcher = v
            .parse()
            .map_err(|e| anyhow!("metadata `{META_STEREO}` entry `matcher`: {e}"))?;
    }
    if let (MatcherKind::Sgm, Some(v)) = (a.matcher, entries.get("sgm_paths")) {
        a.sgm_paths = Some(
            v.parse()
                .map_err(|e| anyhow!("metadata `{META_STEREO}` entry `sgm_paths`: {e}"))?,
        );
    }
    Ok(a)
}

/// `img` as PNG bytes.
pub fn png(img: &RgbImage) -> Result<Vec<u8>> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .context("encoding a PNG")?;
    Ok(out.into_inner())
}

/// An RGB image from PNG bytes; `name` says which in errors.
pub fn from_png(name: &str, bytes: &[u8]) -> Result<RgbImage> {
    Ok(image_file::decode_bytes(name, bytes, image::ImageFormat::Png, Need::Colour)?.into_rgb8())
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereotac::stereo::Paths;

    /// The metadata `record` writes, as `stereo_settings` reads it back.
    fn entries(matcher: &str, paths: &str) -> BTreeMap<String, String> {
        BTreeMap::from([
            ("near_mm".into(), "80".into()),
            ("matcher".into(), matcher.into()),
            ("sgm_paths".into(), paths.into()),
        ])
    }

    #[test]
    fn the_matcher_and_its_paths_come_back_from_a_recording() {
        let sgm = stereo_settings(Some(&entries("sgm", "3"))).unwrap();
        let c = sgm.config().unwrap();
        assert_eq!(
            (c.matcher, c.sgm_paths, c.near_mm),
            (MatcherKind::Sgm, Paths::Three, 80.0)
        );
        // No window entry: the matcher's own; a recorded one is kept (recordings made
        // before semi-global matching's default became 11 say 9).
        assert_eq!(c.window(), 11);
        let mut nine = entries("sgm", "8");
        nine.insert("block_size".into(), "9".into());
        let c = stereo_settings(Some(&nine)).unwrap().config().unwrap();
        assert_eq!(c.window(), 9);
        // Block matching: the paths entry (written for every recording) is not an error.
        let bm = stereo_settings(Some(&entries("bm", "8"))).unwrap();
        assert_eq!(bm.config().unwrap().matcher, MatcherKind::Bm);
        // A recording from before these entries: block matching.
        let old = BTreeMap::from([("near_mm".to_string(), "80".to_string())]);
        let c = stereo_settings(Some(&old)).unwrap().config().unwrap();
        assert_eq!((c.matcher, c.sgm_paths), (MatcherKind::Bm, Paths::Eight));
        for (m, p, words) in [
            ("census", "8", "\"census\": not bm"),
            ("sgm", "6", "not 3, 4, 5 or 8"),
        ] {
            let e = stereo_settings(Some(&entries(m, p)))
                .unwrap_err()
                .to_string();
            assert!(e.contains(words), "{e}");
        }
    }
}
