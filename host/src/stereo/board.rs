//! Checkerboard calibration targets: their geometry, and built-in views of one seen by
//! a calibrated stereo pair (lens model and all), so calibration runs and is tested on
//! data whose answer is known.
//!
//! A board of `cols × rows` inner corners has `(cols + 1) × (rows + 1)` squares, the
//! top-left one black, and a white margin one square wide around them. Its frame has
//! the origin at the top-left inner corner, `x` along a row of corners, `y` down the
//! board, `z` into it; corner `(i, j)` sits at `(i·s, j·s, 0)`.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::calibration::StereoCalibration;
use super::scene::{self, Membrane, Surface};
use super::synthetic::RawRig;
use crate::grid::Grid;
use crate::rng::Rng;

/// A checkerboard target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Checkerboard {
    /// Inner corners along a row.
    pub cols: usize,
    /// Inner corners down a column.
    pub rows: usize,
    /// Side of one square, mm.
    pub square_mm: f64,
}

impl Default for Checkerboard {
    /// 8 × 6 inner corners, 17 mm squares: OpenCV's sample board printed on A4.
    fn default() -> Self {
        Self {
            cols: 8,
            rows: 6,
            square_mm: 17.0,
        }
    }
}

/// Why a board description is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoardError {
    /// The size is not `COLSxROWS`.
    #[error("board size {0:?} is not COLSxROWS (inner corners, e.g. 8x6)")]
    Size(String),
    /// Too few corners to tell the board's orientation or fit a homography.
    #[error("a board needs at least 3×3 inner corners, got {cols}×{rows}")]
    TooSmall {
        /// Inner corners along a row.
        cols: usize,
        /// Inner corners down a column.
        rows: usize,
    },
    /// A square board (cols = rows) is ambiguous under a quarter turn.
    #[error(
        "a board with as many rows as columns ({0}×{0}) is ambiguous under a quarter turn; use one with different counts"
    )]
    Square(usize),
    /// The square size is not a positive, finite length.
    #[error("square size must be a positive number of mm, got {0}")]
    SquareSize(f64),
}

impl Checkerboard {
    /// A board of `size` (`"8x6"`, inner corners) with `square_mm` squares, validated.
    pub fn parse(size: &str, square_mm: f64) -> Result<Self, BoardError> {
        let bad = || BoardError::Size(size.to_string());
        let (c, r) = size.split_once(['x', 'X', '×']).ok_or_else(bad)?;
        let board = Self {
            cols: c.trim().parse().map_err(|_| bad())?,
            rows: r.trim().parse().map_err(|_| bad())?,
            square_mm,
        };
        board.validate()?;
        Ok(board)
    }

    /// Checks the board can be detected and calibrated with.
    pub fn validate(&self) -> Result<(), BoardError> {
        if self.cols < 3 || self.rows < 3 {
            return Err(BoardError::TooSmall {
                cols: self.cols,
                rows: self.rows,
            });
        }
        if self.cols == self.rows {
            return Err(BoardError::Square(self.cols));
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(BoardError::SquareSize(self.square_mm));
        }
        Ok(())
    }

    /// Number of inner corners.
    pub fn corner_count(&self) -> usize {
        self.cols * self.rows
    }

    /// The inner corners in the board frame (mm), row by row from the top-left.
    pub fn corners(&self) -> Vec<Point3<f64>> {
        (0..self.rows)
            .flat_map(|j| {
                (0..self.cols).map(move |i| {
                    Point3::new(i as f64 * self.square_mm, j as f64 * self.square_mm, 0.0)
                })
            })
            .collect()
    }

    /// The four outer corners of the white margin, board frame (mm).
    pub fn outline(&self) -> [Point3<f64>; 4] {
        let s = self.square_mm;
        let (x0, y0) = (-2.0 * s, -2.0 * s);
        let (x1, y1) = ((self.cols + 1) as f64 * s, (self.rows + 1) as f64 * s);
        [
            Point3::new(x0, y0, 0.0),
            Point3::new(x1, y0, 0.0),
            Point3::new(x0, y1, 0.0),
            Point3::new(x1, y1, 0.0),
        ]
    }

    /// The board's centre, board frame (mm).
    pub fn centre(&self) -> Point3<f64> {
        let s = self.square_mm;
        Point3::new(
            (self.cols - 1) as f64 * s / 2.0,
            (self.rows - 1) as f64 * s / 2.0,
            0.0,
        )
    }

    /// Brightness at `(x, y)` on the board (mm, board frame): 0 black, 1 white, `None`
    /// off the board.
    pub fn brightness(&self, x: f64, y: f64) -> Option<f64> {
        let s = self.square_mm;
        // Square indices counted from the top-left square (index 0), which is black.
        let i = (x / s).floor() + 1.0;
        let j = (y / s).floor() + 1.0;
        let inside = |v: f64, n: usize| (0.0..=n as f64).contains(&v);
        if inside(i, self.cols) && inside(j, self.rows) {
            return Some(if (i + j) as i64 % 2 == 0 { 0.0 } else { 1.0 });
        }
        let [lo, _, _, hi] = self.outline();
        let on_margin = (lo.x..hi.x).contains(&x) && (lo.y..hi.y).contains(&y);
        on_margin.then_some(1.0)
    }
}

/// A board placed in the world (the left camera's frame).
#[derive(Debug, Clone, Copy)]
pub struct PlacedBoard {
    /// The board.
    pub board: Checkerboard,
    /// Board frame to world.
    pub world_from_board: Isometry3<f64>,
}

impl Surface for PlacedBoard {
    fn shade(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        let normal = self.world_from_board.rotation * Vector3::z();
        let centre = self.world_from_board * Point3::origin();
        let hit = scene::hit_plane(origin, dir, &centre, &normal)?;
        let local = self.world_from_board.inverse_transform_point(&hit);
        self.board.brightness(local.x, local.y)
    }
}

/// A built-in set of checkerboard views, with the corners' true pixels.
#[derive(Debug, Clone)]
pub struct BoardCapture {
    /// The board's pose in each view.
    pub poses: Vec<Isometry3<f64>>,
    /// Left images.
    pub left: Vec<Grid<u8>>,
    /// Right images.
    pub right: Vec<Grid<u8>>,
}

/// Keep every projected board point this far from the image border, pixels.
const BORDER_PX: f64 = 12.0;
/// Steepest view of the board accepted, degrees between its normal and the line of
/// sight (a detector's accuracy falls off beyond this).
const MAX_OBLIQUITY_DEG: f64 = 55.0;

/// `count` board poses that both cameras of `calib` see whole, spread over the images
/// and tilted up to ±35°; `seed` picks them.
pub fn calibration_poses(
    calib: &StereoCalibration,
    board: &Checkerboard,
    count: usize,
    seed: u64,
) -> Vec<Isometry3<f64>> {
    let right_pose = calib.world_from_right();
    let left = &calib.left;
    let f = left.k[(0, 0)];
    let board_width = (board.cols + 3) as f64 * board.square_mm;
    let mut rng = Rng::new(seed ^ 0x0B0A_4D00);
    let mut poses = Vec::with_capacity(count);
    // Enough tries for any sensible rig; a rig that cannot see the board gives fewer.
    for _ in 0..count * 400 {
        if poses.len() == count {
            break;
        }
        // The board spans 30–65 % of the image width on the axis.
        let fraction = rng.range(0.30, 0.65);
        let z = f * board_width / (fraction * left.width as f64);
        let aim = [
            rng.range(0.2, 0.8) * left.width as f64,
            rng.range(0.2, 0.8) * left.height as f64,
        ];
        let Some(ray) = left.unproject(aim) else {
            continue;
        };
        if ray.z < 0.4 {
            continue;
        }
        let rotation = Rotation3::from_euler_angles(
            rng.range(-35.0, 35.0f64).to_radians(),
            rng.range(-35.0, 35.0f64).to_radians(),
            rng.range(-10.0, 10.0f64).to_radians(),
        );
        let centre = Point3::from(ray * (z / ray.z));
        let rotation = UnitQuaternion::from_rotation_matrix(&rotation);
        let translation = centre - rotation * board.centre();
        let pose = Isometry3::from_parts(Translation3::from(translation), rotation);
        let sees_whole = |camera: &super::camera::Camera, camera_pose: &Isometry3<f64>| {
            let to_camera = camera_pose.inverse() * pose;
            let normal = to_camera.rotation * Vector3::z();
            let sight = (to_camera * board.centre()).coords.normalize();
            if normal.dot(&sight).acos().to_degrees() > MAX_OBLIQUITY_DEG {
                return false;
            }
            board
                .outline()
                .iter()
                .chain(board.corners().iter())
                .all(|p| {
                    camera
                        .project(&(to_camera * p).coords)
                        .is_some_and(|[u, v]| {
                            u >= BORDER_PX
                                && v >= BORDER_PX
                                && u <= camera.width as f64 - 1.0 - BORDER_PX
                                && v <= camera.height as f64 - 1.0 - BORDER_PX
                        })
                })
        };
        if sees_whole(left, &Isometry3::identity()) && sees_whole(&calib.right, &right_pose) {
            poses.push(pose);
        }
    }
    poses
}

/// Renders `count` views of `board` seen by `calib` behind `membrane` (4×4 rays per
/// pixel), at poses from [`calibration_poses`].
pub fn render_board_capture(
    calib: &StereoCalibration,
    board: &Checkerboard,
    membrane: &Membrane,
    count: usize,
    seed: u64,
) -> BoardCapture {
    let poses = calibration_poses(calib, board, count, seed);
    let rig = RawRig::new(calib);
    let mut capture = BoardCapture {
        poses: poses.clone(),
        left: Vec::with_capacity(poses.len()),
        right: Vec::with_capacity(poses.len()),
    };
    for (n, pose) in poses.iter().enumerate() {
        let surface = PlacedBoard {
            board: *board,
            world_from_board: *pose,
        };
        let (left, right) = rig.render_sampled(&surface, membrane, 4, n as u64);
        capture.left.push(left);
        capture.right.push(right);
    }
    capture
}

/// Where the corners of `board` at `pose` appear in each camera (row by row), for
/// checking a detector.
pub fn true_corners(
    calib: &StereoCalibration,
    board: &Checkerboard,
    pose: &Isometry3<f64>,
) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let right_from_board = calib.world_from_right().inverse() * pose;
    let project = |camera: &super::camera::Camera, to_camera: &Isometry3<f64>| {
        board
            .corners()
            .iter()
            .map(|p| {
                camera
                    .project(&(to_camera * p).coords)
                    .unwrap_or([f64::NAN; 2])
            })
            .collect()
    };
    (
        project(&calib.left, pose),
        project(&calib.right, &right_from_board),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::synthetic;

    #[test]
    fn board_sizes_parse_and_bad_ones_are_refused() {
        let b = Checkerboard::parse("8x6", 17.0).unwrap();
        assert_eq!((b.cols, b.rows, b.corner_count()), (8, 6, 48));
        assert_eq!(Checkerboard::parse("9 × 7", 20.0).unwrap().cols, 9);
        for bad in ["8", "8x", "x6", "8x6x2", "a x b"] {
            assert!(matches!(
                Checkerboard::parse(bad, 17.0),
                Err(BoardError::Size(_))
            ));
        }
        assert!(matches!(
            Checkerboard::parse("2x6", 17.0),
            Err(BoardError::TooSmall { .. })
        ));
        assert_eq!(Checkerboard::parse("7x7", 17.0), Err(BoardError::Square(7)));
        for s in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Checkerboard::parse("8x6", s),
                Err(BoardError::SquareSize(_))
            ));
        }
    }

    #[test]
    fn squares_alternate_from_a_black_top_left_with_a_white_margin() {
        let b = Checkerboard::default();
        let s = b.square_mm;
        assert_eq!(b.brightness(-0.5 * s, -0.5 * s), Some(0.0)); // top-left square
        assert_eq!(b.brightness(0.5 * s, -0.5 * s), Some(1.0));
        assert_eq!(b.brightness(0.5 * s, 0.5 * s), Some(0.0));
        assert_eq!(b.brightness(-1.5 * s, 0.0), Some(1.0)); // margin
        assert_eq!(b.brightness(-2.5 * s, 0.0), None); // off the board
        // 9 × 7 squares: the bottom-right one, (8, 6), is black too.
        assert_eq!(b.brightness(7.5 * s, 5.5 * s), Some(0.0));
        assert_eq!(b.corners()[9], Point3::new(s, s, 0.0));
    }

    #[test]
    fn every_pose_shows_the_whole_board_to_both_cameras_and_corners_image_sharply() {
        let calib = synthetic::wide_fisheye_calibration();
        let board = Checkerboard::default();
        let poses = calibration_poses(&calib, &board, 12, 1);
        assert_eq!(poses.len(), 12);
        for pose in &poses {
            let (l, r) = true_corners(&calib, &board, pose);
            for [u, v] in l.into_iter().chain(r) {
                assert!(u > BORDER_PX && v > BORDER_PX && u < 628.0 && v < 468.0);
            }
        }
        // At a corner the four squares around it alternate: a rendered view is dark on
        // one diagonal and bright on the other.
        let capture = render_board_capture(&calib, &board, &Membrane::clear(), 1, 1);
        let (l, _) = true_corners(&calib, &board, &capture.poses[0]);
        let [u, v] = l[board.cols + 1];
        let at = |du: f64, dv: f64| {
            capture.left[0].get((u + du).round() as usize, (v + dv).round() as usize)
        };
        let step = 3.0;
        let diagonal = at(-step, -step) as i32 + at(step, step) as i32;
        let anti = at(step, -step) as i32 + at(-step, step) as i32;
        assert!((diagonal - anti).abs() > 250, "{diagonal} vs {anti}");
    }
}
