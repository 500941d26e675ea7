//! Stereo calibration files: OpenCV stereo YAML (`K1 D1 K2 D2 R T`, or `R1 R2 P1 P2`
//! instead of `R T`) and pairs of ROS `camera_info` YAML, read into one
//! [`StereoCalibration`] and written back in the OpenCV form.
//!
//! Conventions: `R`, `T` take a point from the left camera's frame to the right one's,
//! `X_right = R·X_left + T`, in millimetres once read. OpenCV files carry no unit: `T` is
//! in the unit the board's squares were given in, millimetres unless told otherwise
//! ([`LengthUnit`], `--units m`). A ROS pair carries the same extrinsics inside its
//! rectification, `X_right = R2ᵀ·(R1·X_left + (Tx, 0, 0))` with `Tx = P2[0,3] / P2[0,0]`,
//! in metres as everywhere in ROS. A rig that is not plausible for this sensor (a
//! baseline under 1 mm or over 1 m, a focal length outside 0.1–10× the image width, the
//! cameras turned more than 60° apart) is refused with the number and its likely cause. A
//! rotation written with few digits (up to 1e-3 off) is read as the nearest rotation.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix3, Matrix3x4, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::camera::{Camera, Distortion};
use super::yaml::{self, Value, YamlError};
use crate::limits::{MAX_CALIBRATION_FILE, MAX_FRAME_SIDE};

/// Why a calibration could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibError {
    /// Not the YAML subset calibration files use.
    #[error("{file}: {error}")]
    Yaml {
        /// Which file.
        file: String,
        /// Where and what.
        error: YamlError,
    },
    /// A required field is absent.
    #[error("{file}: missing `{field}`")]
    Missing {
        /// Which file.
        file: String,
        /// The field.
        field: String,
    },
    /// No image size in any of the forms read (OpenCV's own stereo sample writes none).
    #[error(
        "{file}: no image size: add `image_width: W` and `image_height: H` (or \
         `image_size: [W, H]`), the size in pixels of the images the cameras were \
         calibrated with (the rectification is made for that size; OpenCV's stereo_calib \
         sample does not write it)"
    )]
    NoImageSize {
        /// Which file.
        file: String,
    },
    /// A field is present but unusable.
    #[error("{file}: `{field}`: {why}")]
    Invalid {
        /// Which file.
        file: String,
        /// The field.
        field: String,
        /// What is wrong with it.
        why: String,
    },
    /// The fields disagree with each other.
    #[error("{0}")]
    Inconsistent(String),
    /// A calibration file could not be read.
    #[error("reading {file}: {why}")]
    Read {
        /// Which file.
        file: String,
        /// The cause.
        why: String,
    },
    /// Not one OpenCV file nor a ROS pair.
    #[error("{0}")]
    Files(String),
}

/// The length unit of an OpenCV calibration file's `T` (ROS files are always metres).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum LengthUnit {
    /// Millimetres (the board's squares given in mm; our own files).
    #[default]
    Mm,
    /// Metres.
    M,
}

impl std::str::FromStr for LengthUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "mm" => Ok(LengthUnit::Mm),
            "m" => Ok(LengthUnit::M),
            _ => Err(format!("unknown unit {s:?} (expected mm or m)")),
        }
    }
}

impl LengthUnit {
    /// Millimetres per unit.
    pub fn mm(self) -> f64 {
        match self {
            LengthUnit::Mm => 1.0,
            LengthUnit::M => 1000.0,
        }
    }
}

/// Smallest and largest plausible baselines (mm).
pub const BASELINE_RANGE_MM: (f64, f64) = (1.0, 1000.0);
/// The largest turn between a stereo pair's cameras (degrees): toed-in rigs converge by
/// a few tens of degrees at most; more is a rotation of another convention or rig.
pub const MAX_RIG_TURN_DEG: f64 = 60.0;
/// Plausible focal lengths, as multiples of the image width.
pub const FOCAL_RANGE_OF_WIDTH: (f64, f64) = (0.1, 10.0);

/// Largest ratio of the two cameras' focal lengths without a note.
pub const MAX_FOCAL_MISMATCH: f64 = 1.25;
/// Largest ratio of a camera's two focal lengths (`fy / fx` or its inverse): pixels are
/// square or nearly; 2×1 binning and interlaced fields (720×240) give 2.
pub const MAX_PIXEL_ASPECT: f64 = 2.5;
/// Largest skew (`K[0][1]`) as a share of `fx`: calibrations give 0, or nearly.
pub const MAX_SKEW_OF_FOCAL: f64 = 0.05;
/// How near a pixel must come back to itself through the lens model (unprojected to a
/// ray, projected again), px.
const LENS_ROUND_TRIP_PX: f64 = 0.01;

/// Why a camera's intrinsics cannot be a real camera's, if they cannot: pixels far from
/// square, a large skew, the principal point outside the image, or a lens model that does
/// not map the middle of the image (eight pixels a quarter of the image's smaller side
/// from the principal point) to rays and back: coefficients mistyped, scaled or of
/// another model. Nothing farther out is asked for: a circular fisheye's picture ends
/// before the frame's edges, and its model may turn back beyond the lens's field of
/// view.
fn implausible_intrinsics(cam: &Camera) -> Option<String> {
    let k = &cam.k;
    let (fx, fy, skew, cx, cy) = (k[(0, 0)], k[(1, 1)], k[(0, 1)], k[(0, 2)], k[(1, 2)]);
    let (w, h) = (f64::from(cam.width), f64::from(cam.height));
    let aspect = fy / fx;
    if !(1.0 / MAX_PIXEL_ASPECT..=MAX_PIXEL_ASPECT).contains(&aspect) {
        return Some(format!(
            "focal lengths fx = {fx} and fy = {fy} px differ {:.2}×: a camera's pixels are \
             square or nearly (2× with binning or interlaced fields; at most \
             {MAX_PIXEL_ASPECT}× is read); one of them is mistyped, scaled, or of another \
             image size",
            aspect.max(1.0 / aspect)
        ));
    }
    if skew.is_nan() || skew.abs() > MAX_SKEW_OF_FOCAL * fx {
        return Some(format!(
            "skew K[0][1] = {skew} px is {:.0}% of fx: calibrations give 0 or nearly (at most \
             {:.0}%); the camera matrix is mistyped",
            100.0 * skew.abs() / fx,
            100.0 * MAX_SKEW_OF_FOCAL
        ));
    }
    if !((0.0..=w).contains(&cx) && (0.0..=h).contains(&cy)) {
        return Some(format!(
            "principal point ({cx}, {cy}) lies outside the {w}×{h} image: the camera matrix \
             belongs to another image size, or cx and cy are mistyped"
        ));
    }
    let r = w.min(h) / 4.0;
    for k in 0..8 {
        let angle = f64::from(k) * std::f64::consts::FRAC_PI_4;
        let pixel = [cx + r * angle.cos(), cy + r * angle.sin()];
        let back = cam.unproject(pixel).and_then(|ray| cam.project(&ray));
        let ok =
            back.is_some_and(|b| (b[0] - pixel[0]).hypot(b[1] - pixel[1]) <= LENS_ROUND_TRIP_PX);
        if !ok {
            return Some(format!(
                "lens model ({}, coefficients {:?}) does not map pixel ({:.0}, {:.0}), a \
                 quarter of the image from the principal point, to a ray and back: the \
                 coefficients are mistyped, scaled, or of another model",
                cam.distortion.model_label(),
                cam.distortion.coefficients(),
                pixel[0],
                pixel[1]
            ));
        }
    }
    None
}

/// A calibrated stereo pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCalibration {
    /// The left camera.
    pub left: Camera,
    /// The right camera.
    pub right: Camera,
    /// Rotation from the left camera's frame to the right one's.
    pub r: Matrix3<f64>,
    /// Translation from the left camera's frame to the right one's (mm).
    pub t: Vector3<f64>,
}

impl StereoCalibration {
    /// Distance between the optical centres, in the file's unit.
    pub fn baseline(&self) -> f64 {
        self.t.norm()
    }

    /// The right camera's pose in the left camera's frame: right-camera coordinates to
    /// left-camera coordinates (the inverse of `R`, `T`).
    pub fn world_from_right(&self) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&self.r));
        Isometry3::from_parts(Translation3::from(self.t), rotation).inverse()
    }
}

/// How far one calibration is from another, e.g. a solve from its ground truth.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CalibrationDifference {
    /// Largest focal-length error over `fx` and `fy` of both cameras, %.
    pub focal_error_percent: f64,
    /// Largest principal-point error over `cx` and `cy` of both cameras, pixels.
    pub principal_point_error_px: f64,
    /// Baseline length error, %.
    pub baseline_error_percent: f64,
    /// Angle of the rotation between the two `R`, degrees.
    pub rotation_error_deg: f64,
}

impl StereoCalibration {
    /// How far `self` is from `truth`.
    pub fn difference_from(&self, truth: &StereoCalibration) -> CalibrationDifference {
        let mut focal: f64 = 0.0;
        let mut centre: f64 = 0.0;
        for (g, t) in [(&self.left, &truth.left), (&self.right, &truth.right)] {
            for i in 0..2 {
                focal = focal.max(((g.k[(i, i)] - t.k[(i, i)]) / t.k[(i, i)]).abs() * 100.0);
                centre = centre.max((g.k[(i, 2)] - t.k[(i, 2)]).abs());
            }
        }
        CalibrationDifference {
            focal_error_percent: focal,
            principal_point_error_px: centre,
            baseline_error_percent: (self.baseline() - truth.baseline()).abs() / truth.baseline()
                * 100.0,
            rotation_error_deg: turn_deg(&(self.r.transpose() * truth.r)),
        }
    }
}

/// Keys of an OpenCV stereo file that [`StereoCalibration::from_opencv_yaml_in`] reads.
const OPENCV_KEYS_READ: &[&str] = &[
    "image_width",
    "image_height",
    "image_size",
    "imageSize",
    "K1",
    "K2",
    "M1",
    "M2",
    "D1",
    "D2",
    "R",
    "T",
    "R1",
    "R2",
    "P1",
    "P2",
    "distortion_model",
];
/// Keys OpenCV's stereo calibration and the usual tools write that are not needed here.
const OPENCV_KEYS_UNUSED: &[&str] = &[
    "E",
    "F",
    "Q",
    "rms",
    "avg_reprojection_error",
    "reprojection_error",
    "calibration_time",
    "nframes",
    "nr_of_frames",
    "flags",
    "validRoi1",
    "validRoi2",
    "square_size",
    "board_width",
    "board_height",
    "camera_name",
];
/// Keys of a ROS `camera_info` file, all known (`camera_name` is not needed).
const ROS_KEYS: &[&str] = &[
    "image_width",
    "image_height",
    "camera_name",
    "camera_matrix",
    "distortion_model",
    "distortion_coefficients",
    "rectification_matrix",
    "projection_matrix",
];

/// Reads fields of one parsed file, naming the file in errors.
struct Fields<'a> {
    file: &'a str,
    map: BTreeMap<String, Value>,
}

impl<'a> Fields<'a> {
    fn parse(file: &'a str, text: &str) -> Result<Self, CalibError> {
        let map = yaml::parse(text).map_err(|error| CalibError::Yaml {
            file: file.into(),
            error,
        })?;
        Ok(Self { file, map })
    }

    fn invalid(&self, field: &str, why: impl Into<String>) -> CalibError {
        CalibError::Invalid {
            file: self.file.into(),
            field: field.into(),
            why: why.into(),
        }
    }

    /// A note for each key that is none of `known`: ignored, but said, since a misspelt
    /// key (`k1` for `K1`) would otherwise look like a missing one, or not be missed at all.
    fn unknown_keys(&self, known: &[&[&str]], read: &[&str]) -> Vec<String> {
        self.map
            .keys()
            .filter(|k| !known.iter().any(|list| list.contains(&k.as_str())))
            .map(|k| {
                let hint = read
                    .iter()
                    .find(|r| r.eq_ignore_ascii_case(k))
                    .map_or(String::new(), |r| {
                        format!(" (did you mean `{r}`? keys are case-sensitive)")
                    });
                format!(
                    "{}: key `{k}` is not one this format has; ignored{hint}",
                    self.file
                )
            })
            .collect()
    }

    fn has(&self, field: &str) -> bool {
        self.map.contains_key(field)
    }

    fn get(&self, field: &str) -> Result<&Value, CalibError> {
        self.map.get(field).ok_or_else(|| CalibError::Missing {
            file: self.file.into(),
            field: field.into(),
        })
    }

    fn number(&self, field: &str, text: &str) -> Result<f64, CalibError> {
        let v: f64 = text
            .parse()
            .map_err(|_| self.invalid(field, format!("{text:?} is not a number")))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.invalid(field, format!("{text} is not finite")))
        }
    }

    fn scalar(&self, field: &str) -> Result<&str, CalibError> {
        match self.get(field)? {
            Value::Scalar(s) => Ok(s),
            _ => Err(self.invalid(field, "expected a single value")),
        }
    }

    fn size(&self, field: &str) -> Result<u32, CalibError> {
        let s = self.scalar(field)?;
        s.parse::<u32>()
            .ok()
            .filter(|&v| v > 0 && v as usize <= MAX_FRAME_SIDE)
            .ok_or_else(|| {
                self.invalid(
                    field,
                    format!("{s:?} is not a size in pixels from 1 to {MAX_FRAME_SIDE}"),
                )
            })
    }

    /// A matrix: a mapping with `rows`, `cols` and `data` (OpenCV and ROS), or a bare
    /// list; returns (rows, cols, row-major data).
    fn matrix(&self, field: &str) -> Result<(usize, usize, Vec<f64>), CalibError> {
        let (rows, cols, data) = match self.get(field)? {
            Value::Map(m) => {
                let dim = |k: &str| -> Result<usize, CalibError> {
                    match m.get(k) {
                        Some(Value::Scalar(s)) => s
                            .parse()
                            .map_err(|_| self.invalid(field, format!("{k} {s:?}"))),
                        _ => Err(self.invalid(field, format!("no `{k}`"))),
                    }
                };
                let Some(Value::List(data)) = m.get("data") else {
                    return Err(self.invalid(field, "no `data` list"));
                };
                (dim("rows")?, dim("cols")?, data)
            }
            Value::List(data) => (1, data.len(), data),
            Value::Scalar(_) => return Err(self.invalid(field, "expected a matrix")),
        };
        if rows.checked_mul(cols) != Some(data.len()) {
            return Err(self.invalid(field, format!("{rows}×{cols} but {} values", data.len())));
        }
        let values = data
            .iter()
            .map(|d| self.number(field, d))
            .collect::<Result<_, _>>()?;
        Ok((rows, cols, values))
    }

    fn matrix3(&self, field: &str) -> Result<Matrix3<f64>, CalibError> {
        match self.matrix(field)? {
            (3, 3, d) => Ok(Matrix3::from_row_slice(&d)),
            (r, c, _) => Err(self.invalid(field, format!("expected 3×3, found {r}×{c}"))),
        }
    }

    fn matrix3x4(&self, field: &str) -> Result<Matrix3x4<f64>, CalibError> {
        match self.matrix(field)? {
            (3, 4, d) => Ok(Matrix3x4::from_row_slice(&d)),
            (r, c, _) => Err(self.invalid(field, format!("expected 3×4, found {r}×{c}"))),
        }
    }

    fn vector3(&self, field: &str) -> Result<Vector3<f64>, CalibError> {
        let (_, _, d) = self.matrix(field)?;
        if d.len() == 3 {
            Ok(Vector3::from_row_slice(&d))
        } else {
            Err(self.invalid(field, format!("expected 3 values, found {}", d.len())))
        }
    }

    fn camera_matrix(&self, field: &str) -> Result<Matrix3<f64>, CalibError> {
        let k = self.matrix3(field)?;
        let ok = k[(0, 0)] > 0.0
            && k[(1, 1)] > 0.0
            && k[(1, 0)] == 0.0
            && k[(2, 0)] == 0.0
            && k[(2, 1)] == 0.0
            && k[(2, 2)] == 1.0;
        if ok {
            Ok(k)
        } else {
            Err(self.invalid(
                field,
                "not a camera matrix [fx s cx; 0 fy cy; 0 0 1] with fx, fy > 0",
            ))
        }
    }

    /// Distortion coefficients under a named model (`plumb_bob`, `rational_polynomial`,
    /// `equidistant`/`fisheye`/`kannala_brandt`).
    fn distortion(&self, field: &str, model: &str) -> Result<Distortion, CalibError> {
        let (_, _, d) = self.matrix(field)?;
        match model {
            "plumb_bob" | "rational_polynomial" | "brown_conrady" | "pinhole" => {
                if !matches!(d.len(), 4 | 5 | 8) {
                    return Err(self.invalid(
                        field,
                        format!("{model} takes 4, 5 or 8 coefficients, found {}", d.len()),
                    ));
                }
                let mut k = [0.0; 8];
                k[..d.len()].copy_from_slice(&d);
                Ok(Distortion::BrownConrady(k))
            }
            "equidistant" | "fisheye" | "kannala_brandt" => {
                let k: [f64; 4] = d.as_slice().try_into().map_err(|_| {
                    self.invalid(
                        field,
                        format!("{model} takes 4 coefficients, found {}", d.len()),
                    )
                })?;
                Ok(Distortion::KannalaBrandt(k))
            }
            other => Err(self.invalid(
                "distortion_model",
                format!(
                    "unknown model {other:?} (plumb_bob, rational_polynomial, equidistant, fisheye)"
                ),
            )),
        }
    }

    fn model(&self) -> Result<String, CalibError> {
        Ok(if self.has("distortion_model") {
            self.scalar("distortion_model")?.to_ascii_lowercase()
        } else {
            "plumb_bob".into()
        })
    }

    /// Image size: `image_width`/`image_height`, or `image_size`/`imageSize` `[w, h]`.
    fn image_size(&self) -> Result<(u32, u32), CalibError> {
        // Every form the file gives, which must agree.
        let mut found: Vec<(&str, (u32, u32))> = Vec::new();
        if self.has("image_width") || self.has("image_height") {
            found.push((
                "image_width/image_height",
                (self.size("image_width")?, self.size("image_height")?),
            ));
        }
        for field in ["image_size", "imageSize"] {
            if self.has(field) {
                let (_, _, d) = self.matrix(field)?;
                let side = 1.0..=MAX_FRAME_SIDE as f64;
                let ok = d.len() == 2 && d.iter().all(|v| side.contains(v) && v.fract() == 0.0);
                if !ok {
                    return Err(self.invalid(
                        field,
                        format!("expected [width, height], 1 to {MAX_FRAME_SIDE} px each"),
                    ));
                }
                found.push((field, (d[0] as u32, d[1] as u32)));
            }
        }
        let Some(&(first, size)) = found.first() else {
            return Err(CalibError::NoImageSize {
                file: self.file.into(),
            });
        };
        if let Some(&(other, (w, h))) = found.iter().find(|(_, s)| *s != size) {
            return Err(self.invalid(
                other,
                format!(
                    "{w}×{h}, but `{first}` in the same file says {}×{}: give one image size",
                    size.0, size.1
                ),
            ));
        }
        Ok(size)
    }
}

/// A calibration file's text, refused unread when it is larger than any calibration
/// ([`MAX_CALIBRATION_FILE`]) or not UTF-8.
fn read_bounded(path: &std::path::Path) -> Result<String, String> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut text = String::new();
    file.take(MAX_CALIBRATION_FILE + 1)
        .read_to_string(&mut text)
        .map_err(|e| e.to_string())?;
    if text.len() as u64 > MAX_CALIBRATION_FILE {
        return Err(format!(
            "larger than {MAX_CALIBRATION_FILE} bytes: not a calibration file"
        ));
    }
    Ok(text)
}

/// How far `RᵀR` may be from the identity, and `det R` from 1, for `R` to be read as a
/// rotation written with fewer digits (four decimals are up to about 1e-4 off); it is then
/// taken as the nearest rotation (within about 0.03° of what was written).
const ROTATION_ROUNDING: f64 = 1e-3;

/// The angle (degrees) rotation `r` turns by: `atan2(sin, cos)` with the cosine from the
/// trace and the sine from the antisymmetric part (`|R − Rᵀ|`'s axial vector / 2). The
/// arc cosine of the trace alone loses half the digits near the identity (round-off of
/// 1e-16 in the trace reads as a turn of 1e-6°), where stereo rigs are. NaN only for a
/// matrix that is not finite.
fn turn_deg(r: &Matrix3<f64>) -> f64 {
    let cos = (r.trace() - 1.0) / 2.0;
    let axial = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    );
    (axial.norm() / 2.0).atan2(cos).to_degrees()
}

/// `r`'s distance from a rotation: the largest entry of `RᵀR − I` and `|det R − 1|`.
fn rotation_error(r: &Matrix3<f64>) -> f64 {
    let orthonormal = (r.transpose() * r - Matrix3::identity()).abs().max();
    orthonormal.max((r.determinant() - 1.0).abs())
}

/// `r` as a rotation: as it is, or the nearest rotation when it is one written with fewer
/// digits ([`ROTATION_ROUNDING`]); otherwise an error with how far off it is.
fn rotation(f: &Fields<'_>, field: &str, r: Matrix3<f64>) -> Result<Matrix3<f64>, CalibError> {
    let error = rotation_error(&r);
    if error <= 1e-9 {
        return Ok(r);
    }
    if error <= ROTATION_ROUNDING {
        // The nearest rotation (polar decomposition): U·Vᵀ of the SVD.
        let svd = r.svd(true, true);
        if let (Some(u), Some(v_t)) = (svd.u, svd.v_t) {
            let nearest = u * v_t;
            if rotation_error(&nearest) <= 1e-9 {
                return Ok(nearest);
            }
        }
    }
    Err(f.invalid(
        field,
        format!(
            "not a rotation matrix: RᵀR is off the identity or det R off 1 by {error:.1e} \
             (rounding up to {ROTATION_ROUNDING:.0e} is read as rotation; det R = {:.6})",
            r.determinant()
        ),
    ))
}

/// Extrinsics from a rectification: `X_right = R2ᵀ·(R1·X_left + (Tx, 0, 0))`.
fn extrinsics_from_rectification(
    r1: &Matrix3<f64>,
    r2: &Matrix3<f64>,
    p2: &Matrix3x4<f64>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let tx = p2[(0, 3)] / p2[(0, 0)];
    (
        r2.transpose() * r1,
        r2.transpose() * Vector3::new(tx, 0.0, 0.0),
    )
}

impl StereoCalibration {
    /// Reads one OpenCV stereo YAML file (`T` in mm), or a ROS `camera_info` pair (left,
    /// then right).
    pub fn load(files: &[std::path::PathBuf]) -> Result<Self, CalibError> {
        Self::load_in(files, LengthUnit::Mm)
    }

    /// [`Self::load`] with an OpenCV file's `T` in `unit`.
    pub fn load_in(files: &[std::path::PathBuf], unit: LengthUnit) -> Result<Self, CalibError> {
        Self::load_noting(files, unit).map(|(c, _)| c)
    }

    /// [`Self::load_in`], with a note for each key of the files that is not one of their
    /// format's (ignored, for forward compatibility, but a typo should be seen).
    pub fn load_noting(
        files: &[std::path::PathBuf],
        unit: LengthUnit,
    ) -> Result<(Self, Vec<String>), CalibError> {
        let read = |path: &std::path::Path| {
            let file = path.display().to_string();
            match read_bounded(path) {
                Ok(text) => Ok((file, text)),
                Err(why) => Err(CalibError::Read { file, why }),
            }
        };
        let (c, mut notes) = match files {
            [one] => {
                let (name, text) = read(one)?;
                let mut notes = Vec::new();
                let c = Self::opencv_noting(&name, &text, unit, &mut notes)?;
                (c, notes)
            }
            [left, right] => {
                let (l, r) = (read(left)?, read(right)?);
                let mut notes = Vec::new();
                let c = Self::ros_noting((&l.0, &l.1), (&r.0, &r.1), &mut notes)?;
                (c, notes)
            }
            [] => {
                return Err(CalibError::Files(
                    "give --calib FILE (OpenCV stereo YAML) or --calib LEFT --calib RIGHT (ROS); \
                     in Python, one path or a pair (left, right)"
                        .into(),
                ));
            }
            _ => {
                return Err(CalibError::Files(format!(
                    "--calib takes one OpenCV file or two ROS files (in Python, one path or \
                     a pair (left, right)), found {}",
                    files.len()
                )));
            }
        };
        notes.extend(c.swapped_note());
        notes.extend(c.unmatched_focal_note());
        Ok((c, notes))
    }

    /// A note when the two cameras' focal lengths differ by more than
    /// [`MAX_FOCAL_MISMATCH`]: rectification brings them to one, but a stereo pair is
    /// nearly always two cameras of one model, so the files may belong to two rigs.
    fn unmatched_focal_note(&self) -> Option<String> {
        let (l, r) = (self.left.k[(0, 0)], self.right.k[(0, 0)]);
        let ratio = (l / r).max(r / l);
        (ratio > MAX_FOCAL_MISMATCH).then(|| {
            format!(
                "the cameras' focal lengths differ {ratio:.2}× (fx {l} px left, {r} px right): \
                 a stereo pair is nearly always two cameras of one model; check that both \
                 cameras' numbers come from one calibration of this rig"
            )
        })
    }

    /// A note when the camera called right sits left of the one called left (`T`'s x
    /// positive, in the left camera's turned frame): depth is computed either way, but
    /// if the images are named as the calibration names them, nothing will match.
    fn swapped_note(&self) -> Option<String> {
        // Where the right camera's centre is, in the left camera's frame: −Rᵀ·T.
        let centre = -(self.r.transpose() * self.t);
        (centre.x < 0.0).then(|| {
            format!(
                "the calibration puts the right camera {:.1} mm to the left of the left one \
                 (`T` x is {:+.3} mm as read; a right camera to the right has it negative): if \
                 depth comes out empty, the images (or the files) are given the wrong way round",
                -centre.x, self.t.x
            )
        })
    }

    /// Read an OpenCV stereo YAML with `T` in mm (see [`Self::from_opencv_yaml_in`]).
    pub fn from_opencv_yaml(file: &str, text: &str) -> Result<Self, CalibError> {
        Self::from_opencv_yaml_in(file, text, LengthUnit::Mm)
    }

    /// Read an OpenCV stereo YAML: `K1 D1 K2 D2` (or OpenCV's sample names `M1 D1 M2
    /// D2`) and `R T` (or `R1 R2 P1 P2`), the image size, and optionally
    /// `distortion_model` (default `plumb_bob`); `T` (or `P2`'s baseline) in `unit`.
    pub fn from_opencv_yaml_in(
        file: &str,
        text: &str,
        unit: LengthUnit,
    ) -> Result<Self, CalibError> {
        Self::opencv_noting(file, text, unit, &mut Vec::new())
    }

    fn opencv_noting(
        file: &str,
        text: &str,
        unit: LengthUnit,
        notes: &mut Vec<String>,
    ) -> Result<Self, CalibError> {
        if text.trim().is_empty() {
            return Err(CalibError::Read {
                file: file.into(),
                why: "the file is empty".into(),
            });
        }
        let f = Fields::parse(file, text)?;
        // One camera_info file alone: say so instead of missing OpenCV's keys.
        if f.has("camera_matrix") && f.has("projection_matrix") && !f.has("K1") && !f.has("M1") {
            return Err(CalibError::Files(format!(
                "{file} is a ROS camera_info file, one camera's: give the left and the right \
                 camera's files, --calib LEFT --calib RIGHT (in Python, a pair (left, right))"
            )));
        }
        notes.extend(f.unknown_keys(&[OPENCV_KEYS_READ, OPENCV_KEYS_UNUSED], OPENCV_KEYS_READ));
        let (width, height) = f.image_size()?;
        let model = f.model()?;
        let camera = |k: &str, d: &str| -> Result<Camera, CalibError> {
            Ok(Camera {
                width,
                height,
                k: f.camera_matrix(k)?,
                distortion: f.distortion(d, &model)?,
            })
        };
        let name = |k: &'static str, m: &'static str| if f.has(k) || !f.has(m) { k } else { m };
        // Both names of one matrix given (OpenCV's samples use M, others K): they must
        // agree, or which one is meant cannot be told.
        for (k, m) in [("K1", "M1"), ("K2", "M2")] {
            if f.has(k) && f.has(m) && f.camera_matrix(k)? != f.camera_matrix(m)? {
                return Err(f.invalid(
                    m,
                    format!(
                        "differs from `{k}` in the same file: give one camera matrix per camera"
                    ),
                ));
            }
        }
        let (left, right) = (
            camera(name("K1", "M1"), "D1")?,
            camera(name("K2", "M2"), "D2")?,
        );
        let (r, t) = if f.has("R") || f.has("T") || !f.has("R1") {
            let r = rotation(&f, "R", f.matrix3("R")?)?;
            let t = f.vector3("T")?;
            // The rectification too, when given: it must describe the same rig.
            if f.has("R1") && f.has("R2") && f.has("P2") {
                let r1 = rotation(&f, "R1", f.matrix3("R1")?)?;
                let r2 = rotation(&f, "R2", f.matrix3("R2")?)?;
                let (r_rect, t_rect) = extrinsics_from_rectification(&r1, &r2, &f.matrix3x4("P2")?);
                let turn = turn_deg(&(r.transpose() * r_rect));
                let (b, b_rect) = (t.norm(), t_rect.norm());
                if turn.is_nan()
                    || turn > 0.1
                    || b_rect.is_nan()
                    || (b - b_rect).abs() > 0.01 * b.max(b_rect)
                {
                    return Err(CalibError::Inconsistent(format!(
                        "{file}: `R`/`T` and `R1`/`R2`/`P2` describe different rigs (baseline \
                         {b:.3} against {b_rect:.3}, turns {turn:.2}° apart): give one, or \
                         both from one calibration"
                    )));
                }
            }
            (r, t)
        } else {
            let r1 = rotation(&f, "R1", f.matrix3("R1")?)?;
            let r2 = rotation(&f, "R2", f.matrix3("R2")?)?;
            let p2 = f.matrix3x4("P2")?;
            extrinsics_from_rectification(&r1, &r2, &p2)
        };
        let hint = match unit {
            LengthUnit::Mm => "pass --units m (in Python, units=\"m\") if the file is in metres",
            LengthUnit::M => {
                "pass --units mm (in Python, units=\"mm\") if the file is in millimetres"
            }
        };
        Self::checked(
            left,
            right,
            r,
            t * unit.mm(),
            [file, file],
            &format!("{file}: {hint}"),
        )
    }

    /// Read a left and a right ROS `camera_info` YAML.
    pub fn from_ros_pair(left: (&str, &str), right: (&str, &str)) -> Result<Self, CalibError> {
        Self::ros_noting(left, right, &mut Vec::new())
    }

    fn ros_noting(
        (left_file, left_text): (&str, &str),
        (right_file, right_text): (&str, &str),
        notes: &mut Vec<String>,
    ) -> Result<Self, CalibError> {
        let mut read = |file: &str,
                        text: &str|
         -> Result<(Camera, Matrix3<f64>, Matrix3x4<f64>), CalibError> {
            if text.trim().is_empty() {
                return Err(CalibError::Read {
                    file: file.into(),
                    why: "the file is empty".into(),
                });
            }
            let f = Fields::parse(file, text)?;
            notes.extend(f.unknown_keys(&[ROS_KEYS], ROS_KEYS));
            let (width, height) = f.image_size()?;
            let camera = Camera {
                width,
                height,
                k: f.camera_matrix("camera_matrix")?,
                distortion: f.distortion("distortion_coefficients", &f.model()?)?,
            };
            let r = rotation(
                &f,
                "rectification_matrix",
                f.matrix3("rectification_matrix")?,
            )?;
            Ok((camera, r, f.matrix3x4("projection_matrix")?))
        };
        let (left, r1, p1) = read(left_file, left_text)?;
        let (right, r2, p2) = read(right_file, right_text)?;
        if p1[(0, 3)] != 0.0 {
            return Err(CalibError::Inconsistent(format!(
                "{left_file} is not the left camera (its projection has Tx = {})",
                p1[(0, 3)]
            )));
        }
        if p2[(0, 3)] == 0.0 {
            return Err(CalibError::Inconsistent(format!(
                "{right_file} carries no baseline (projection_matrix[0][3] is 0): not the right camera of a stereo pair"
            )));
        }
        // A rectified pair shares its focal lengths and rows. The baseline is read from
        // the right file alone, `-P2[0,3] / P2[0,0]`: a right file whose fx was edited,
        // or that belongs to another calibration, gives another baseline (or another
        // rig's), and every depth off by the same factor.
        for ((i, j), name) in [((0, 0), "fx"), ((1, 1), "fy"), ((1, 2), "cy")] {
            let (a, b) = (p1[(i, j)], p2[(i, j)]);
            if (a - b).is_nan() || (a - b).abs() > 1e-4 * a.abs().max(b.abs()).max(1.0) {
                return Err(CalibError::Inconsistent(format!(
                    "{left_file} and {right_file}: the projection matrices disagree on {name} \
                     ({a} left, {b} right, projection_matrix[{i}][{j}]): a rectified pair \
                     shares fx, fy and cy, and the baseline is read from the right one's \
                     Tx / fx; give the two camera_info files of one stereo calibration"
                )));
            }
        }
        let (r, t) = extrinsics_from_rectification(&r1, &r2, &p2);
        Self::checked(
            left,
            right,
            r,
            t * LengthUnit::M.mm(),
            [left_file, right_file],
            &format!(
                "{right_file}: ROS camera_info is in metres (projection_matrix[0][3] = -fx·baseline)"
            ),
        )
    }

    /// The calibration if it is a plausible rig; `files` are where the left and the
    /// right camera were read from (one file twice for OpenCV's), `hint` says where the
    /// numbers came from and how to read them otherwise.
    fn checked(
        left: Camera,
        right: Camera,
        r: Matrix3<f64>,
        t: Vector3<f64>,
        files: [&str; 2],
        hint: &str,
    ) -> Result<Self, CalibError> {
        let both = if files[0] == files[1] {
            files[0].to_string()
        } else {
            format!("{} and {}", files[0], files[1])
        };
        if (left.width, left.height) != (right.width, right.height) {
            return Err(CalibError::Inconsistent(format!(
                "{both}: the cameras' image sizes differ ({}×{} left, {}×{} right): calibrate \
                 both at the size of the frames they will match",
                left.width, left.height, right.width, right.height
            )));
        }
        if std::mem::discriminant(&left.distortion) != std::mem::discriminant(&right.distortion) {
            return Err(CalibError::Inconsistent(format!(
                "{both}: the cameras use different lens models (left {}, right {}): calibrate \
                 both with one model",
                left.distortion.model_label(),
                right.distortion.model_label()
            )));
        }
        if !t.iter().all(|v| v.is_finite()) || t.norm() == 0.0 {
            return Err(CalibError::Inconsistent(format!(
                "{both}: the baseline must be finite and non-zero, found T = {:?}",
                t.as_slice()
            )));
        }
        // A rotation far from the identity is no stereo pair (and half of a half turn, which
        // rectification takes, has no one answer).
        let turn = turn_deg(&r);
        if turn.is_nan() || turn > MAX_RIG_TURN_DEG {
            return Err(CalibError::Inconsistent(format!(
                "{both}: `R` turns the right camera {turn:.1}° from the left: a stereo pair's cameras \
                 look the same way (within {MAX_RIG_TURN_DEG}°); R may be in another \
                 convention (a camera's pose in the world) or belong to another rig"
            )));
        }
        let baseline = t.norm();
        let (lo, hi) = BASELINE_RANGE_MM;
        if baseline < lo || baseline > hi {
            let likely = if baseline < lo {
                "T looks like metres read as millimetres"
            } else {
                "T looks like millimetres read as metres, or another unit"
            };
            return Err(CalibError::Inconsistent(format!(
                "implausible baseline {baseline:.6} mm (a stereo rig is {lo}–{hi} mm): {likely}; {hint}"
            )));
        }
        let (flo, fhi) = FOCAL_RANGE_OF_WIDTH;
        for (side, cam, file) in [("left", &left, files[0]), ("right", &right, files[1])] {
            let w = f64::from(cam.width);
            for (axis, f) in [("fx", cam.k[(0, 0)]), ("fy", cam.k[(1, 1)])] {
                if !(f >= flo * w && f <= fhi * w) {
                    return Err(CalibError::Inconsistent(format!(
                        "{file}: implausible {side} focal length {axis} = {f} px for an image {w} px wide \
                         (expected {}–{} px): the camera matrix may belong to another image size \
                         or be scaled",
                        flo * w,
                        fhi * w
                    )));
                }
            }
            if let Some(why) = implausible_intrinsics(cam) {
                return Err(CalibError::Inconsistent(format!(
                    "{file}: the {side} camera's {why}"
                )));
            }
        }
        Ok(Self { left, right, r, t })
    }

    /// The calibration as OpenCV stereo YAML (what [`Self::from_opencv_yaml`] reads).
    pub fn to_opencv_yaml(&self) -> String {
        let matrix = yaml::opencv_matrix;
        let row_major = |m: &Matrix3<f64>| -> Vec<f64> { m.transpose().as_slice().to_vec() };
        let model = self.left.distortion.model_name();
        let d1 = self.left.distortion.coefficients();
        let d2 = self.right.distortion.coefficients();
        let mut out = format!(
            "%YAML:1.0\n---\nimage_width: {}\nimage_height: {}\ndistortion_model: {model}\n",
            self.left.width, self.left.height
        );
        out += &matrix("K1", 3, 3, &row_major(&self.left.k));
        out += &matrix("D1", 1, d1.len(), &d1);
        out += &matrix("K2", 3, 3, &row_major(&self.right.k));
        out += &matrix("D2", 1, d2.len(), &d2);
        out += &matrix("R", 3, 3, &row_major(&self.r));
        out += &matrix("T", 3, 1, self.t.as_slice());
        out
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use nalgebra::Rotation3;

    use super::*;

    /// No calibration file, or three, is refused naming the CLI flag and what Python takes.
    #[test]
    fn no_file_or_three_name_both_the_flag_and_pythons_argument() {
        let none = StereoCalibration::load(&[]).unwrap_err().to_string();
        assert!(
            none.contains("--calib FILE") && none.contains("in Python, one path or a pair"),
            "{none}"
        );
        let three: Vec<std::path::PathBuf> = ["a.yaml", "b.yaml", "c.yaml"].map(Into::into).into();
        let three = StereoCalibration::load(&three).unwrap_err().to_string();
        assert!(
            three.contains("found 3") && three.contains("in Python, one path or a"),
            "{three}"
        );
    }

    /// A calibration whose right camera sits to the left says so (the images are likely
    /// given the wrong way round); the usual one says nothing.
    #[test]
    fn a_right_camera_on_the_left_is_noted() {
        let dir = std::env::temp_dir().join(format!("stereotac-swapped-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("c.yaml");
        let mut c = sensor_pair(Distortion::NONE);
        std::fs::write(&file, c.to_opencv_yaml()).unwrap();
        let (_, notes) =
            StereoCalibration::load_noting(std::slice::from_ref(&file), LengthUnit::Mm).unwrap();
        assert!(notes.is_empty(), "{notes:?}");
        c.t = -c.t;
        std::fs::write(&file, c.to_opencv_yaml()).unwrap();
        let (_, notes) = StereoCalibration::load_noting(&[file], LengthUnit::Mm).unwrap();
        assert!(
            notes.len() == 1 && notes[0].contains("to the left of the left one"),
            "{notes:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A rotation written with five decimals is read as the nearest rotation; a half turn
    /// (a valid rotation, but no stereo pair: it used to read as no turn at all) and a
    /// quarter turn are refused naming `R` and the angle.
    #[test]
    fn rotations_rounded_are_read_and_turned_rigs_refused() {
        let mut c = sensor_pair(Distortion::NONE);
        c.r = *Rotation3::from_euler_angles(0.01, 0.087, -0.02).matrix();
        let exact = c.r;
        for decimals in [1e5, 1e4] {
            c.r = exact.map(|v| (v * decimals).round() / decimals);
            assert!(rotation_error(&c.r) > 1e-7, "the rounding changed it");
            let read = StereoCalibration::from_opencv_yaml("c.yaml", &c.to_opencv_yaml()).unwrap();
            assert!(rotation_error(&read.r) < 1e-9);
            assert!(
                (read.r - exact).abs().max() < 2.0 / decimals,
                "{}",
                read.r - exact
            );
        }
        // Within round-off of no turn, the trace can pass 3: the angle is 0, not NaN.
        let mut over = Matrix3::identity();
        over[(0, 0)] = 1.0 + f64::EPSILON;
        assert_eq!(turn_deg(&over), 0.0);
        assert!(turn_deg(&Matrix3::from_element(f64::NAN)).is_nan());
        for (axis, angle, says) in [
            (Vector3::x_axis(), 180.0f64, "180.0°"),
            (Vector3::y_axis(), 180.0, "180.0°"),
            (Vector3::z_axis(), 90.0, "90.0°"),
        ] {
            c.r = *Rotation3::from_axis_angle(&axis, angle.to_radians()).matrix();
            let e = StereoCalibration::from_opencv_yaml("c.yaml", &c.to_opencv_yaml())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("`R` turns the right camera") && e.contains(says),
                "{e}"
            );
        }
        c.r = *Rotation3::from_axis_angle(&Vector3::y_axis(), 20f64.to_radians()).matrix();
        assert!(StereoCalibration::from_opencv_yaml("c.yaml", &c.to_opencv_yaml()).is_ok());
    }

    /// A pair like the sensor's: 14 mm baseline, slightly rotated and offset.
    pub(crate) fn sensor_pair(distortion: Distortion) -> StereoCalibration {
        let k = Matrix3::new(420.0, 0.0, 322.5, 0.0, 421.0, 238.0, 0.0, 0.0, 1.0);
        let k2 = Matrix3::new(425.0, 0.0, 318.0, 0.0, 424.0, 243.5, 0.0, 0.0, 1.0);
        StereoCalibration {
            left: Camera {
                width: 640,
                height: 480,
                k,
                distortion,
            },
            right: Camera {
                width: 640,
                height: 480,
                k: k2,
                distortion,
            },
            r: *Rotation3::from_euler_angles(0.01, -0.02, 0.005).matrix(),
            t: Vector3::new(-14.0, 0.3, -0.2),
        }
    }

    #[test]
    fn opencv_yaml_round_trips_exactly() {
        for d in [
            Distortion::BrownConrady([-0.3, 0.1, 0.001, -0.002, -0.01, 0.0, 0.0, 0.0]),
            Distortion::BrownConrady([-0.3, 0.1, 0.001, -0.002, -0.01, 0.2, 0.01, 0.001]),
            Distortion::KannalaBrandt([0.05, -0.01, 0.002, -0.0003]),
        ] {
            let c = sensor_pair(d);
            let text = c.to_opencv_yaml();
            assert_eq!(
                StereoCalibration::from_opencv_yaml("c.yaml", &text),
                Ok(c),
                "{text}"
            );
        }
    }

    #[test]
    fn reads_an_opencv_file_with_a_rectification_instead_of_r_t() {
        let c = sensor_pair(Distortion::NONE);
        let rect = crate::stereo::rectify::Rectification::bouguet(&c, 1.0).unwrap();
        let m =
            |name: &str, rows, cols, data: Vec<f64>| yaml::opencv_matrix(name, rows, cols, &data);
        let rm = |r: &Matrix3<f64>| r.transpose().as_slice().to_vec();
        let text = format!(
            "%YAML:1.0\n---\nimageSize: [ 640, 480 ]\n{}{}{}{}{}{}{}{}",
            m("K1", 3, 3, rm(&c.left.k)),
            m("D1", 1, 5, vec![0.0; 5]),
            m("K2", 3, 3, rm(&c.right.k)),
            m("D2", 1, 5, vec![0.0; 5]),
            m("R1", 3, 3, rm(&rect.r1)),
            m("R2", 3, 3, rm(&rect.r2)),
            m("P1", 3, 4, rect.p1.transpose().as_slice().to_vec()),
            m("P2", 3, 4, rect.p2.transpose().as_slice().to_vec()),
        );
        let read = StereoCalibration::from_opencv_yaml("r.yaml", &text).unwrap();
        assert!((read.r - c.r).abs().max() < 1e-12);
        assert!((read.t - c.t).abs().max() < 1e-9, "{:?}", read.t);
        // With R and T beside the rectification (as OpenCV writes them): they must agree.
        let with = |t: Vector3<f64>| {
            format!(
                "{text}{}{}",
                m("R", 3, 3, rm(&c.r)),
                m("T", 3, 1, t.as_slice().to_vec())
            )
        };
        assert!(StereoCalibration::from_opencv_yaml("r.yaml", &with(c.t)).is_ok());
        let e = StereoCalibration::from_opencv_yaml("r.yaml", &with(c.t * 1.5))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("describe different rigs") && e.contains("r.yaml"),
            "{e}"
        );
        // Two image sizes, or two names of one camera matrix, that disagree.
        let e = StereoCalibration::from_opencv_yaml(
            "r.yaml",
            &format!("{}image_size: [ 320, 240 ]\n", with(c.t)),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("image_size") && e.contains("640×480"), "{e}");
        let mut k = c.left.k;
        k[(0, 0)] *= 1.1;
        let e = StereoCalibration::from_opencv_yaml(
            "r.yaml",
            &format!("{}{}", with(c.t), m("M1", 3, 3, rm(&k))),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("M1") && e.contains("differs from `K1`"), "{e}");
    }

    #[test]
    fn reads_a_ros_pair() {
        let c = sensor_pair(Distortion::KannalaBrandt([0.05, -0.01, 0.002, -0.0003]));
        let rect = crate::stereo::rectify::Rectification::bouguet(&c, 1.0).unwrap();
        let info = |cam: &Camera, r: &Matrix3<f64>, p: &Matrix3x4<f64>| {
            format!(
                "image_width: {}\nimage_height: {}\ncamera_name: x\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: {}\ndistortion_model: equidistant\ndistortion_coefficients:\n  rows: 1\n  cols: 4\n  data: {}\nrectification_matrix:\n  rows: 3\n  cols: 3\n  data: {}\nprojection_matrix:\n  rows: 3\n  cols: 4\n  data: {}\n",
                cam.width,
                cam.height,
                yaml::list(cam.k.transpose().as_slice()),
                yaml::list(&cam.distortion.coefficients()),
                yaml::list(r.transpose().as_slice()),
                yaml::list(p.transpose().as_slice()),
            )
        };
        // ROS writes Tx = -fx·B with B in metres.
        let mut p2_m = rect.p2;
        p2_m[(0, 3)] /= 1000.0;
        let left = info(&c.left, &rect.r1, &rect.p1);
        let right = info(&c.right, &rect.r2, &p2_m);
        let read = StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &right)).unwrap();
        assert_eq!((read.left, read.right), (c.left, c.right));
        assert!((read.r - c.r).abs().max() < 1e-12);
        assert!((read.t - c.t).abs().max() < 1e-9, "{:?} mm", read.t);
        assert!((read.baseline() - 14.0).abs() < 0.5, "{}", read.baseline());
        // A pair written in millimetres (not ROS's unit) is refused with the cause.
        let in_mm = info(&c.right, &rect.r2, &rect.p2);
        let e = StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &in_mm))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("implausible baseline") && e.contains("metres"),
            "{e}"
        );
        // Cameras that disagree on the image size or the lens model: both files named,
        // with what each says.
        let mut small = c.right;
        (small.width, small.height) = (320, 240);
        let e = StereoCalibration::from_ros_pair(
            ("l.yaml", &left),
            ("r.yaml", &info(&small, &rect.r2, &p2_m)),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("l.yaml and r.yaml: ") && e.contains("320×240 right"),
            "{e}"
        );
        let mut matte = c.right;
        matte.distortion = Distortion::NONE;
        let plumb = info(&matte, &rect.r2, &p2_m)
            .replace("equidistant", "plumb_bob")
            .replace(
                "coefficients:\n  rows: 1\n  cols: 4",
                "coefficients:\n  rows: 1\n  cols: 5",
            );
        let e = StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &plumb))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("l.yaml and r.yaml: ")
                && e.contains("left Kannala–Brandt (fisheye, equidistant), right Brown–Conrady"),
            "{e}"
        );
        // Swapped files are refused.
        let e =
            StereoCalibration::from_ros_pair(("r.yaml", &right), ("l.yaml", &left)).unwrap_err();
        assert!(e.to_string().contains("not the left camera"), "{e}");
        // Every key is one ROS writes: no notes; a key ROS does not have gets one.
        let mut notes = Vec::new();
        StereoCalibration::ros_noting(("l.yaml", &left), ("r.yaml", &right), &mut notes).unwrap();
        assert_eq!(notes, Vec::<String>::new());
        let odd = format!("{right}Camera_Matrix: 1\n");
        StereoCalibration::ros_noting(("l.yaml", &left), ("r.yaml", &odd), &mut notes).unwrap();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(
            notes[0].starts_with("r.yaml: key `Camera_Matrix`")
                && notes[0].contains("did you mean `camera_matrix`?"),
            "{notes:?}"
        );
    }

    #[test]
    fn keys_a_format_does_not_have_are_noted_not_refused() {
        let good = sensor_pair(Distortion::NONE).to_opencv_yaml();
        // OpenCV's own extra results (E, F, Q, rms) are known: no notes.
        let with_extras = format!("{good}E: [1, 2]\nrms: 0.3\n");
        let mut notes = Vec::new();
        let read =
            StereoCalibration::opencv_noting("c.yaml", &with_extras, LengthUnit::Mm, &mut notes)
                .unwrap();
        assert_eq!(notes, Vec::<String>::new());
        // A misspelt key is read as the file would be without it, and said.
        let typo = format!("{good}t: [1, 0, 0]\nbaseline_mm: 14\n");
        let same =
            StereoCalibration::opencv_noting("c.yaml", &typo, LengthUnit::Mm, &mut notes).unwrap();
        assert_eq!(same, read);
        assert_eq!(notes.len(), 2, "{notes:?}");
        assert!(notes[0].contains("`baseline_mm`") && notes[0].contains("ignored"));
        assert!(notes[1].contains("`t`") && notes[1].contains("did you mean `T`?"));
    }

    #[test]
    fn opencv_files_in_metres_and_with_the_sample_names_read_in_millimetres() {
        let c = sensor_pair(Distortion::NONE);
        let mm = c.to_opencv_yaml();
        // The same rig with T in metres.
        let mut in_m = c;
        in_m.t /= 1000.0;
        let m_text = in_m.to_opencv_yaml();
        let e = StereoCalibration::from_opencv_yaml("m.yaml", &m_text)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("implausible baseline 0.014")
                && e.contains("--units m")
                && e.contains("units=\"m\""),
            "{e}"
        );
        let read =
            StereoCalibration::from_opencv_yaml_in("m.yaml", &m_text, LengthUnit::M).unwrap();
        assert!((read.t - c.t).abs().max() < 1e-9);
        // Millimetres read as metres: 14 m.
        let e = StereoCalibration::from_opencv_yaml_in("mm.yaml", &mm, LengthUnit::M)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("implausible baseline") && e.contains("--units mm"),
            "{e}"
        );
        // OpenCV's sample names.
        let sample = mm.replace("K1:", "M1:").replace("K2:", "M2:");
        assert_eq!(
            StereoCalibration::from_opencv_yaml("s.yaml", &sample).unwrap(),
            StereoCalibration::from_opencv_yaml("mm.yaml", &mm).unwrap()
        );
        // A focal length for another image size.
        let mut wide = c;
        wide.left.k[(0, 0)] *= 40.0;
        let e = StereoCalibration::from_opencv_yaml("f.yaml", &wide.to_opencv_yaml())
            .unwrap_err()
            .to_string();
        assert!(e.contains("implausible left focal length fx"), "{e}");
        assert_eq!("M".parse::<LengthUnit>(), Ok(LengthUnit::M));
        assert!("km".parse::<LengthUnit>().is_err());
    }

    #[test]
    fn missing_and_inconsistent_fields_get_clear_errors() {
        let good = sensor_pair(Distortion::NONE).to_opencv_yaml();
        let without_k1 = good.replace("K1:", "K9:");
        assert_eq!(
            StereoCalibration::from_opencv_yaml("c.yaml", &without_k1)
                .unwrap_err()
                .to_string(),
            "c.yaml: missing `K1`"
        );
        let short = good.replacen("rows: 3\n   cols: 3", "rows: 3\n   cols: 2", 1);
        let e = StereoCalibration::from_opencv_yaml("c.yaml", &short).unwrap_err();
        assert!(e.to_string().contains("3×2 but 9 values"), "{e}");
        let nan = good.replacen("data: [420.0", "data: [NaN", 1);
        let e = StereoCalibration::from_opencv_yaml("c.yaml", &nan).unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
        let fisheye5 = good.replace("distortion_model: plumb_bob", "distortion_model: fisheye");
        let e = StereoCalibration::from_opencv_yaml("c.yaml", &fisheye5).unwrap_err();
        assert!(e.to_string().contains("takes 4 coefficients"), "{e}");
        let mut c = sensor_pair(Distortion::NONE);
        c.r[(0, 0)] = 2.0;
        let e = StereoCalibration::from_opencv_yaml("c.yaml", &c.to_opencv_yaml()).unwrap_err();
        assert!(
            e.to_string().contains("not a rotation") && e.to_string().contains("off the identity"),
            "{e}"
        );
        let e = StereoCalibration::from_opencv_yaml("c.yaml", "K1: [1, 2\n").unwrap_err();
        assert!(matches!(e, CalibError::Yaml { .. }), "{e}");
        // OpenCV's stereo sample writes no image size: the hint says how to add one.
        let sizeless: String = good
            .lines()
            .filter(|l| !l.starts_with("image_"))
            .map(|l| format!("{l}\n"))
            .collect();
        assert_ne!(sizeless, good);
        let e = StereoCalibration::from_opencv_yaml("c.yaml", &sizeless).unwrap_err();
        assert!(
            matches!(e, CalibError::NoImageSize { .. })
                && e.to_string()
                    .contains("add `image_width: W` and `image_height: H`"),
            "{e}"
        );
    }

    /// Camera matrices and lens models no camera has are refused naming the camera, the
    /// number and the likely cause (they used to give depth a few per cent off, or none,
    /// with exit 0); the sensor's own rigs, pinhole and fisheye, pass.
    #[test]
    fn intrinsics_no_camera_has_are_refused() {
        let refused = |c: &StereoCalibration| {
            StereoCalibration::from_opencv_yaml("c.yaml", &c.to_opencv_yaml())
                .map(|_| ())
                .unwrap_err()
                .to_string()
        };
        for distortion in [
            Distortion::NONE,
            Distortion::BrownConrady([-0.3, 0.1, 0.001, -0.002, -0.02, 0.0, 0.0, 0.0]),
            Distortion::KannalaBrandt([0.05, -0.01, 0.002, -0.0003]),
        ] {
            let c = sensor_pair(distortion);
            StereoCalibration::from_opencv_yaml("c.yaml", &c.to_opencv_yaml()).unwrap();
        }
        // A circular fisheye (a 190° lens whose picture is a 600 px circle in a 1280×720
        // frame; its polynomial turns back beyond the picture) reads.
        let mut wide = sensor_pair(Distortion::KannalaBrandt([0.0, -0.006, 0.0, 0.0]));
        for cam in [&mut wide.left, &mut wide.right] {
            (cam.width, cam.height) = (1280, 720);
            cam.k = Matrix3::new(190.0, 0.0, 640.0, 0.0, 190.0, 360.0, 0.0, 0.0, 1.0);
        }
        StereoCalibration::from_opencv_yaml("c.yaml", &wide.to_opencv_yaml()).unwrap();
        // Binned pixels (2×1) read.
        let mut binned = sensor_pair(Distortion::NONE);
        binned.left.k[(1, 1)] = 210.0;
        binned.right.k[(1, 1)] = 212.0;
        StereoCalibration::from_opencv_yaml("c.yaml", &binned.to_opencv_yaml()).unwrap();
        let mut c = sensor_pair(Distortion::NONE);
        c.right.k[(0, 1)] = 500.0;
        let e = refused(&c);
        assert!(
            e.contains("right camera's skew") && e.contains("500"),
            "{e}"
        );
        let mut c = sensor_pair(Distortion::NONE);
        c.left.k[(1, 1)] = 3000.0;
        let e = refused(&c);
        assert!(
            e.contains("left camera's focal lengths") && e.contains("7.14×"),
            "{e}"
        );
        let mut c = sensor_pair(Distortion::NONE);
        (c.left.k[(0, 2)], c.left.k[(1, 2)]) = (5000.0, -3000.0);
        let e = refused(&c);
        assert!(
            e.contains("principal point (5000, -3000) lies outside"),
            "{e}"
        );
        for k in [
            Distortion::BrownConrady([1e30, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            Distortion::BrownConrady([-40.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            Distortion::KannalaBrandt([-30.0, 0.0, 0.0, 0.0]),
        ] {
            let c = sensor_pair(k);
            let e = refused(&c);
            assert!(
                e.contains("lens model") && e.contains("to a ray and back"),
                "{e}"
            );
        }
    }

    /// A ROS pair whose projection matrices disagree on the focal length (the right
    /// file's fx edited, its Tx kept) is refused: its baseline, read as `-Tx / fx`, was
    /// off by their ratio (14 mm read as 11.8, every depth 16 % short, exit 0).
    #[test]
    fn a_ros_pair_whose_focal_lengths_disagree_is_refused() {
        let c = sensor_pair(Distortion::NONE);
        let (left, right) = crate::stereo::ros_info::camera_info_pair(&c).unwrap();
        StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &right)).unwrap();
        let p = |text: &str| -> Vec<f64> {
            let line = text
                .lines()
                .skip_while(|l| !l.starts_with("projection_matrix"))
                .find_map(|l| l.trim().strip_prefix("data: ["))
                .unwrap();
            let line = line.trim_end_matches(']');
            line.split(',').map(|v| v.trim().parse().unwrap()).collect()
        };
        let p2 = p(&right);
        let mut edited = p2.clone();
        edited[0] *= 1.19;
        let fmt = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:?}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let other = right.replace(&fmt(&p2), &fmt(&edited));
        assert_ne!(other, right, "the test must change the right projection");
        let e = StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &other))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("l.yaml and r.yaml") && e.contains("disagree on fx"),
            "{e}"
        );
    }

    /// An empty file, and one camera_info file given alone, are named as such (they
    /// used to read as a missing image size and a missing `K1`).
    #[test]
    fn an_empty_file_and_a_lone_camera_info_file_are_named() {
        let e = StereoCalibration::from_opencv_yaml("c.yaml", " \n").unwrap_err();
        assert_eq!(e.to_string(), "reading c.yaml: the file is empty");
        let (left, _) =
            crate::stereo::ros_info::camera_info_pair(&sensor_pair(Distortion::NONE)).unwrap();
        let e = StereoCalibration::from_opencv_yaml("left.yaml", &left).unwrap_err();
        assert!(
            e.to_string()
                .contains("left.yaml is a ROS camera_info file")
                && e.to_string().contains("--calib LEFT --calib RIGHT")
                && e.to_string().contains("in Python, a pair (left, right)"),
            "{e}"
        );
        let e = StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", "")).unwrap_err();
        assert_eq!(e.to_string(), "reading r.yaml: the file is empty");
    }

    /// Cameras of very different focal lengths are read, with a note.
    #[test]
    fn cameras_of_different_focal_lengths_are_noted() {
        let dir = std::env::temp_dir().join(format!("stereotac-focal-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("c.yaml");
        let mut c = sensor_pair(Distortion::NONE);
        c.right.k[(0, 0)] *= 1.5;
        c.right.k[(1, 1)] *= 1.5;
        std::fs::write(&file, c.to_opencv_yaml()).unwrap();
        let (_, notes) = StereoCalibration::load_noting(&[file], LengthUnit::Mm).unwrap();
        assert!(
            notes.len() == 1 && notes[0].contains("focal lengths differ 1.52×"),
            "{notes:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn hostile_sizes_and_repeated_keys_are_refused_before_any_allocation() {
        let good = sensor_pair(Distortion::NONE).to_opencv_yaml();
        let read = |text: &str| {
            StereoCalibration::from_opencv_yaml("c.yaml", text)
                .unwrap_err()
                .to_string()
        };
        let e = read(&good.replace("image_width: 640", "image_width: 4294967295"));
        assert!(
            e.contains("`image_width`") && e.contains("1 to 8192"),
            "{e}"
        );
        let e = read(&good.replace("image_height: 480", "image_height: 100000"));
        assert!(e.contains("`image_height`"), "{e}");
        let huge = good.replacen(
            "rows: 3\n   cols: 3",
            "rows: 18446744073709551615\n   cols: 2",
            1,
        );
        assert!(read(&huge).contains("but 9 values"));
        // A second `T` would double the baseline if it silently replaced the first.
        let t = good.lines().skip_while(|l| !l.starts_with("T:")).take(5);
        let doubled = format!("{good}{}\n", t.collect::<Vec<_>>().join("\n"));
        let e = read(&doubled);
        assert!(e.contains("`T` is given twice"), "{e}");
    }

    #[test]
    fn differences_are_measured_as_documented() {
        let truth = sensor_pair(Distortion::NONE);
        let zero = truth.difference_from(&truth);
        assert_eq!(zero.focal_error_percent, 0.0);
        assert_eq!(zero.principal_point_error_px, 0.0);
        assert_eq!(zero.baseline_error_percent, 0.0);
        assert!(zero.rotation_error_deg < 1e-6);
        let mut other = truth;
        other.right.k[(1, 1)] *= 1.02;
        other.left.k[(0, 2)] += 3.0;
        other.t *= 1.01;
        other.r =
            *Rotation3::from_axis_angle(&Vector3::y_axis(), 0.5f64.to_radians()).matrix() * truth.r;
        let d = other.difference_from(&truth);
        assert!((d.focal_error_percent - 2.0).abs() < 1e-9, "{d:?}");
        assert!((d.principal_point_error_px - 3.0).abs() < 1e-9, "{d:?}");
        assert!((d.baseline_error_percent - 1.0).abs() < 1e-9, "{d:?}");
        assert!((d.rotation_error_deg - 0.5).abs() < 1e-6, "{d:?}");
    }
}
