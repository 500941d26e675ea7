//! Stereo calibration from checkerboard pairs (the `calibrate` feature): corners by
//! `calib-targets` (ChESS corners, saddle-point refinement), the solve by
//! `vision-calibration` (Zhang's initialisation per camera, then a bundle adjustment of
//! both cameras and their relative pose), the result as a [`StereoCalibration`], the
//! same type the calibration files give.
//!
//! Only whole boards are used: the detector labels each view's corners from its own
//! top-left, so a partial board would put the labels on the wrong corners. A pair whose
//! two views label the board differently (a board turned near 45°, where "top-left" is
//! ambiguous) is dropped rather than trusted. Distances are solved in metres and
//! written in millimetres, the unit of the files this crate reads.

use calib_targets::chessboard::ChessboardParams;
use calib_targets::detect::{self, DetectError, ImageRefiner};
use calib_targets::image::GrayImage;
use nalgebra::Matrix3;
use vision_calibration_core::{
    CameraModelSpec, CameraParams, CorrespondenceView, DistortionKind, DistortionParams, NoMeta,
    ProjectionKind, Pt2, Pt3, RigDataset, RigView, RigViewObs, SensorKind,
};
use vision_calibration_pipeline::rig_extrinsics::{
    RigExtrinsicsConfig, RigExtrinsicsProblem, run_calibration,
};
use vision_calibration_pipeline::session::CalibrationSession;

use super::board::{BoardError, Checkerboard};
use super::calibration::StereoCalibration;
use super::camera::{Camera, Distortion};
use crate::grid::Grid;

/// The lens model to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LensModel {
    /// Pinhole with Brown–Conrady distortion (`k1 k2 p1 p2`, `k3` held at 0).
    Pinhole,
    /// Kannala–Brandt equidistant fisheye (`k1..k4`), OpenCV's `fisheye` model: for
    /// the sensor's 160° lenses.
    Fisheye,
}

/// What to calibrate with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrateOptions {
    /// The board in the images.
    pub board: Checkerboard,
    /// The lens model of both cameras.
    pub model: LensModel,
    /// Fewest pairs with the whole board in both views.
    pub min_pairs: usize,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        Self {
            board: Checkerboard::default(),
            model: LensModel::Fisheye,
            min_pairs: 6,
        }
    }
}

/// Why a calibration failed.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    /// The board description is invalid.
    #[error(transparent)]
    Board(#[from] BoardError),
    /// Left and right lists differ in length.
    #[error("{left} left images but {right} right images: images are used in pairs")]
    PairCount {
        /// Left images.
        left: usize,
        /// Right images.
        right: usize,
    },
    /// An image's size differs from the first one of its camera.
    #[error(
        "{camera} image {index} is {width}×{height}, but the first {camera} image is {expected_width}×{expected_height}"
    )]
    ImageSize {
        /// `left` or `right`.
        camera: &'static str,
        /// Pair index.
        index: usize,
        /// Its width.
        width: usize,
        /// Its height.
        height: usize,
        /// The first image's width.
        expected_width: usize,
        /// The first image's height.
        expected_height: usize,
    },
    /// Too few pairs show the whole board in both views.
    #[error(
        "only {usable} of {total} pairs show the whole {cols}×{rows} board in both views; at least {needed} are needed (check --board, and that the board is whole, sharp and not turned near 45°)"
    )]
    TooFewPairs {
        /// Usable pairs.
        usable: usize,
        /// All pairs.
        total: usize,
        /// The minimum.
        needed: usize,
        /// Board inner corners along a row.
        cols: usize,
        /// Board inner corners down a column.
        rows: usize,
    },
    /// The corner detector failed (not "no board": that is a [`Detection`]).
    #[error("corner detector: {0}")]
    Detector(String),
    /// The solver failed.
    #[error("calibration solve: {0}")]
    Solver(String),
    /// The solve finished but its result cannot be used.
    #[error("the calibration is unusable: {0}")]
    Unusable(String),
}

/// The board as found in one image.
#[derive(Debug, Clone, PartialEq)]
pub enum Detection {
    /// Every inner corner, row by row from the image's top-left (pixels).
    Whole {
        /// The corners.
        corners: Vec<[f64; 2]>,
        /// Corners per row: the board's `cols`, or `rows` when it is seen turned a
        /// quarter.
        across: usize,
    },
    /// Part of the board (not used: see the module docs).
    Partial {
        /// Corners found.
        found: usize,
    },
    /// No board.
    Missing,
}

impl Detection {
    /// The corners, if the board is whole.
    pub fn corners(&self) -> Option<&[[f64; 2]]> {
        match self {
            Detection::Whole { corners, .. } => Some(corners),
            _ => None,
        }
    }

    /// A few words for reports.
    pub fn describe(&self, board: &Checkerboard) -> String {
        match self {
            Detection::Whole { .. } => "whole board".into(),
            Detection::Partial { found } => {
                format!("{found} of {} corners", board.corner_count())
            }
            Detection::Missing => "no board".into(),
        }
    }
}

/// Finds `board` in `image`.
pub fn detect_board(image: &Grid<u8>, board: &Checkerboard) -> Result<Detection, CalibrateError> {
    board.validate()?;
    let (w, h) = (image.width() as u32, image.height() as u32);
    let gray = GrayImage::from_raw(w, h, image.as_slice().to_vec())
        .ok_or_else(|| CalibrateError::Detector("image buffer does not match its size".into()))?;
    let config = detect::default_chess_config().with_refiner(ImageRefiner::saddle_point());
    let params = ChessboardParams::default();
    let found = match detect::detect_chessboard(&gray, &config, &params) {
        Ok(found) => found,
        Err(DetectError::NoDetection { .. }) => return Ok(Detection::Missing),
        Err(e) => return Err(CalibrateError::Detector(e.to_string())),
    };
    let labels: Vec<(i32, i32)> = found.corners.iter().map(|c| (c.grid.u, c.grid.v)).collect();
    let (max_u, max_v) = labels
        .iter()
        .fold((i32::MIN, i32::MIN), |(a, b), &(u, v)| (a.max(u), b.max(v)));
    let (min_u, min_v) = labels
        .iter()
        .fold((i32::MAX, i32::MAX), |(a, b), &(u, v)| (a.min(u), b.min(v)));
    let (cols, rows) = (board.cols as i32, board.rows as i32);
    let span = (max_u - min_u + 1, max_v - min_v + 1);
    // Seen as declared, or turned a quarter: either way the labels run along image x, y.
    let whole = found.corners.len() == board.corner_count()
        && (span == (cols, rows) || span == (rows, cols));
    if !whole {
        return Ok(Detection::Partial {
            found: found.corners.len(),
        });
    }
    let across = span.0 as usize;
    let mut corners = vec![[f64::NAN; 2]; board.corner_count()];
    for c in &found.corners {
        let index = (c.grid.v - min_v) as usize * across + (c.grid.u - min_u) as usize;
        corners[index] = [c.position.x as f64, c.position.y as f64];
    }
    if corners.iter().any(|p| p[0].is_nan()) {
        // Two corners with one label: not a clean grid.
        return Ok(Detection::Partial {
            found: found.corners.len(),
        });
    }
    Ok(Detection::Whole { corners, across })
}

/// What happened to one pair.
#[derive(Debug, Clone, PartialEq)]
pub struct PairOutcome {
    /// Left view.
    pub left: Detection,
    /// Right view.
    pub right: Detection,
    /// Used in the solve.
    pub used: bool,
    /// Why not, if not.
    pub note: Option<String>,
}

/// A stereo calibration and how well it fits.
#[derive(Debug, Clone)]
pub struct CalibrationResult {
    /// The calibration, distances in mm.
    pub calibration: StereoCalibration,
    /// Mean reprojection error over all corners, pixels.
    pub mean_error_px: f64,
    /// Mean reprojection error per camera (left, right), pixels.
    pub camera_error_px: [f64; 2],
    /// Each pair, in input order.
    pub pairs: Vec<PairOutcome>,
}

impl CalibrationResult {
    /// Pairs used in the solve.
    pub fn pairs_used(&self) -> usize {
        self.pairs.iter().filter(|p| p.used).count()
    }
}

/// Calibrates a stereo pair from images of `options.board` (`left[i]` and `right[i]`
/// taken at the same time); `progress` is called after each pair's detection.
pub fn calibrate_stereo(
    left: &[Grid<u8>],
    right: &[Grid<u8>],
    options: &CalibrateOptions,
    mut progress: impl FnMut(usize),
) -> Result<CalibrationResult, CalibrateError> {
    options.board.validate()?;
    if left.len() != right.len() {
        return Err(CalibrateError::PairCount {
            left: left.len(),
            right: right.len(),
        });
    }
    check_sizes("left", left)?;
    check_sizes("right", right)?;
    let mut pairs = Vec::with_capacity(left.len());
    for (n, (l, r)) in left.iter().zip(right).enumerate() {
        let (l, r) = rayon::join(
            || detect_board(l, &options.board),
            || detect_board(r, &options.board),
        );
        pairs.push(pair_outcome(l?, r?, &options.board));
        progress(n + 1);
    }
    let usable = pairs.iter().filter(|p| p.used).count();
    if usable < options.min_pairs.max(3) {
        return Err(CalibrateError::TooFewPairs {
            usable,
            total: pairs.len(),
            needed: options.min_pairs.max(3),
            cols: options.board.cols,
            rows: options.board.rows,
        });
    }
    let sizes = [
        (left[0].width() as u32, left[0].height() as u32),
        (right[0].width() as u32, right[0].height() as u32),
    ];
    solve(&pairs, sizes, options).map(|(calibration, mean, per_camera)| CalibrationResult {
        calibration,
        mean_error_px: mean,
        camera_error_px: per_camera,
        pairs,
    })
}

fn check_sizes(camera: &'static str, images: &[Grid<u8>]) -> Result<(), CalibrateError> {
    let Some(first) = images.first() else {
        return Ok(());
    };
    for (index, image) in images.iter().enumerate() {
        if (image.width(), image.height()) != (first.width(), first.height()) {
            return Err(CalibrateError::ImageSize {
                camera,
                index,
                width: image.width(),
                height: image.height(),
                expected_width: first.width(),
                expected_height: first.height(),
            });
        }
    }
    Ok(())
}

/// Whether a pair can be used: both boards whole and labelled alike.
fn pair_outcome(left: Detection, right: Detection, board: &Checkerboard) -> PairOutcome {
    let note = match (&left, &right) {
        (
            Detection::Whole {
                corners: l,
                across: a,
            },
            Detection::Whole {
                corners: r,
                across: b,
            },
        ) if a == b && labels_agree(l, r) => None,
        (Detection::Whole { .. }, Detection::Whole { .. }) => {
            Some("the two views label the board differently".to_string())
        }
        _ => Some(format!(
            "left: {}, right: {}",
            left.describe(board),
            right.describe(board)
        )),
    };
    PairOutcome {
        used: note.is_none(),
        left,
        right,
        note,
    }
}

/// The same label names the same physical corner in both views: the shift from left
/// to right is then nearly the same for every corner (it varies with depth only),
/// while a board labelled from different corners gives shifts as large as the board.
fn labels_agree(left: &[[f64; 2]], right: &[[f64; 2]]) -> bool {
    let shift = |i: usize| [right[i][0] - left[i][0], right[i][1] - left[i][1]];
    let n = left.len();
    let mean = (0..n).fold([0.0, 0.0], |m, i| {
        let s = shift(i);
        [m[0] + s[0] / n as f64, m[1] + s[1] / n as f64]
    });
    let spread = (0..n)
        .map(|i| {
            let s = shift(i);
            (s[0] - mean[0]).hypot(s[1] - mean[1])
        })
        .fold(0.0, f64::max);
    let extent = (left[0][0] - left[n - 1][0]).hypot(left[0][1] - left[n - 1][1]);
    spread < 0.4 * extent
}

/// The bundle adjustment over the usable pairs.
fn solve(
    pairs: &[PairOutcome],
    sizes: [(u32, u32); 2],
    options: &CalibrateOptions,
) -> Result<(StereoCalibration, f64, [f64; 2]), CalibrateError> {
    let metres = options.board.square_mm / 1000.0;
    let solver = |e: &dyn std::fmt::Display| CalibrateError::Solver(e.to_string());
    let view = |corners: &[[f64; 2]], across: usize| {
        let world = (0..corners.len())
            .map(|i| {
                Pt3::new(
                    (i % across) as f64 * metres,
                    (i / across) as f64 * metres,
                    0.0,
                )
            })
            .collect();
        let image = corners.iter().map(|p| Pt2::new(p[0], p[1])).collect();
        CorrespondenceView::new(world, image).map_err(|e| solver(&e))
    };
    let mut views = Vec::new();
    for pair in pairs.iter().filter(|p| p.used) {
        let (Detection::Whole { corners: l, across }, Some(r)) = (&pair.left, pair.right.corners())
        else {
            continue;
        };
        let across = *across;
        views.push(RigView {
            obs: RigViewObs {
                cameras: vec![Some(view(l, across)?), Some(view(r, across)?)],
            },
            meta: NoMeta,
        });
    }
    let dataset = RigDataset::new(views, 2).map_err(|e| solver(&e))?;
    let mut config = RigExtrinsicsConfig::default();
    if options.model == LensModel::Fisheye {
        config.camera.model = CameraModelSpec::new(
            ProjectionKind::Equidistant,
            DistortionKind::KannalaBrandt4,
            SensorKind::Identity,
        );
    }
    let mut session = CalibrationSession::<RigExtrinsicsProblem>::new();
    session.set_config(config).map_err(|e| solver(&e))?;
    session.set_input(dataset).map_err(|e| solver(&e))?;
    run_calibration(&mut session).map_err(|e| solver(&e))?;
    let export = session.export().map_err(|e| solver(&e))?;
    let (Some(left), Some(right), Some(pose)) = (
        export.cameras.first(),
        export.cameras.get(1),
        // cam_se3_rig[1] maps the left camera's (rig) coordinates into the right
        // camera's: OpenCV's R and T.
        export.cam_se3_rig.get(1),
    ) else {
        return Err(CalibrateError::Unusable(format!(
            "the solver returned {} cameras and {} poses for a pair",
            export.cameras.len(),
            export.cam_se3_rig.len()
        )));
    };
    let (left, right) = (camera(left, sizes[0])?, camera(right, sizes[1])?);
    let r = *pose.rotation.to_rotation_matrix().matrix();
    let t = pose.translation.vector * 1000.0;
    let calibration = StereoCalibration { left, right, r, t };
    let finite = r.iter().chain(t.iter()).all(|v| v.is_finite());
    if !finite || calibration.baseline() == 0.0 {
        return Err(CalibrateError::Unusable(format!(
            "non-finite or zero baseline T = {:?}",
            t.as_slice()
        )));
    }
    let errors = &export.per_cam_reproj_errors;
    Ok((
        calibration,
        export.mean_reproj_error,
        [
            errors.first().copied().unwrap_or(f64::NAN),
            errors.get(1).copied().unwrap_or(f64::NAN),
        ],
    ))
}

/// Our camera from the solver's parameters.
fn camera(params: &CameraParams, (width, height): (u32, u32)) -> Result<Camera, CalibrateError> {
    let i = &params.intrinsics;
    let k = Matrix3::new(i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0);
    let distortion = match &params.distortion {
        DistortionParams::None => Distortion::NONE,
        DistortionParams::BrownConrady5 { params: p } => {
            Distortion::BrownConrady([p.k1, p.k2, p.p1, p.p2, p.k3, 0.0, 0.0, 0.0])
        }
        DistortionParams::KannalaBrandt4 { params: p } => {
            Distortion::KannalaBrandt([p.k1, p.k2, p.k3, p.k4])
        }
        other => {
            return Err(CalibrateError::Unusable(format!(
                "the solver returned a lens model this crate does not read: {:?}",
                other.kind()
            )));
        }
    };
    let camera = Camera {
        width,
        height,
        k,
        distortion,
    };
    if !(k.iter().all(|v| v.is_finite()) && distortion.is_finite() && i.fx > 0.0 && i.fy > 0.0) {
        return Err(CalibrateError::Unusable(format!(
            "camera parameters out of range: {camera:?}"
        )));
    }
    Ok(camera)
}
