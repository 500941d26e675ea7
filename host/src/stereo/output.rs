//! A processed stereo frame's files, as `stereotac stereo` and the demo write them:
//! rectified views (PNG), disparity and depth (`.npy`, 16-bit and false-colour PNG), the
//! point cloud (PLY) and `summary.json`, which [`StereoSummary`] also returns.

use std::path::Path;

use serde::Serialize;

use super::block_match::{Kernel, MatchStats};
use super::matcher::MatcherKind;
use super::pipeline::{StereoConfig, StereoFrame, StereoPipeline, StereoTimings};
use super::sgm::Paths;
use crate::output::{OutputError, io, write_grey_png, write_npy, write_png16, write_points_ply};
use crate::picture::{self, ColourRange, RangeChoice};

/// The files [`write_outputs`] writes, in order.
pub const FILES: [&str; 9] = [
    "left_rect.png",
    "right_rect.png",
    "disparity.npy",
    "depth.npy",
    "depth16.png",
    "depth_colour.png",
    "disparity_colour.png",
    "cloud.ply",
    "summary.json",
];

/// What one frame gave (also written as `summary.json`).
#[derive(Debug, Clone, Serialize)]
pub struct StereoSummary {
    /// Rectified width, px.
    pub width: usize,
    /// Rectified height, px.
    pub height: usize,
    /// Rectified focal length, px.
    pub focal_px: f64,
    /// Baseline, mm.
    pub baseline_mm: f64,
    /// Disparities searched, px (inclusive).
    pub disparity_range_px: [u32; 2],
    /// The matcher that ran: `bm` or `sgm`.
    pub matcher: MatcherKind,
    /// Paths semi-global matching aggregated along (`sgm` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sgm_paths: Option<usize>,
    /// Side of the matching window, px: block matching's blocks, semi-global matching's
    /// sub-pixel refinement window (`--block-size`).
    pub window_px: u32,
    /// The matching kernel that ran.
    pub kernel: Kernel,
    /// Why pixels were rejected.
    pub stats: MatchStats,
    /// Share of pixels with a finite depth.
    pub fill_rate: f64,
    /// Points in the cloud.
    pub points: usize,
    /// Points the outlier filter removed.
    pub outliers_removed: usize,
    /// Pixels the hole filler filled.
    pub holes_filled: usize,
    /// Minimum, median and maximum depth, mm (none when no pixel is valid).
    pub depth_mm: Option<[f32; 3]>,
    /// Time per stage.
    pub timings: StereoTimings,
    /// The files written, in `dir`.
    pub files: Vec<&'static str>,
    /// Triangles in `mesh.ply`, when it was written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh_triangles: Option<usize>,
    /// The ranges `depth_colour.png` and `disparity_colour.png` show (also in their
    /// legends).
    pub colour_ranges: ColourRanges,
    /// What to look at twice (see [`super::warnings`]); empty when nothing.
    pub warnings: Vec<String>,
}

/// The ranges of the false-colour pictures.
#[derive(Debug, Clone, Serialize)]
pub struct ColourRanges {
    /// `depth_colour.png`, mm.
    pub depth: ColourRange,
    /// `disparity_colour.png`, px.
    pub disparity: ColourRange,
}

/// What [`write_outputs`] writes beyond the usual files.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputOptions<'a> {
    /// How the pictures' ranges are chosen.
    pub colour_range: PictureRange,
    /// Also write `mesh.ply` ([`write_mesh`]).
    pub mesh: bool,
    /// Files the caller wrote into the folder before (the inputs of a built-in capture):
    /// listed first among the summary's files.
    pub written_before: &'static [&'static str],
    /// Warnings from before the frame (the calibration's notes, see
    /// [`super::StereoCalibration::load_noting`]): the summary's warnings start with them.
    pub earlier_warnings: &'a [String],
}

impl Default for OutputOptions<'_> {
    fn default() -> Self {
        Self {
            colour_range: PictureRange::Auto,
            mesh: false,
            written_before: &[],
            earlier_warnings: &[],
        }
    }
}

/// How the pictures' ranges are chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PictureRange {
    /// The data's 2nd to 98th percentiles (depth and disparity alike).
    Auto,
    /// The depths searched (`near_mm`–`far_mm`) and the disparities searched.
    Searched,
    /// This depth range (mm); disparity from the data.
    DepthMm(f32, f32),
}

/// Largest depth step between neighbouring pixels a mesh joins, as a share of their
/// depth: a bigger step is an object's edge in front of what is behind it.
pub const MESH_MAX_STEP: f32 = 0.05;

/// Writes `frame`'s point cloud as a mesh (PLY): neighbouring pixels' points joined in
/// triangles unless their depths differ by more than [`MESH_MAX_STEP`]. Returns the
/// number of triangles.
pub fn write_mesh(path: &Path, frame: &StereoFrame) -> Result<usize, OutputError> {
    let w = frame.disparity.width();
    let mut vertices = vec![None; w * frame.disparity.height()];
    for (&px, p) in frame.cloud.pixels.iter().zip(&frame.cloud.points) {
        if let Some(v) = vertices.get_mut(px as usize) {
            *v = Some(*p);
        }
    }
    crate::output::write_mesh_ply(
        path,
        w,
        &vertices,
        |a, b| (a[2] - b[2]).abs() <= MESH_MAX_STEP * a[2].min(b[2]),
        "stereotac stereo mesh, mm, rectified left camera frame",
    )
}

/// The warning for `beyond` of `valid` depths past what `depth16.png` holds.
fn depth16_warning(beyond: usize, valid: usize) -> String {
    format!(
        "{beyond} pixels ({:.1}% of the depths) are deeper than 655.35 mm, the most \
         depth16.png holds (0.01 mm a count): they are 65535 there; depth.npy and depth.ply \
         hold their depth",
        100.0 * beyond as f64 / valid.max(1) as f64
    )
}

/// Writes `frame` (processed by `pipeline` with `config`) into `dir`, which must exist,
/// with its pictures and mesh as `options` say, and returns its summary.
pub fn write_outputs(
    dir: &Path,
    pipeline: &StereoPipeline,
    frame: &StereoFrame,
    config: &StereoConfig,
    options: OutputOptions<'_>,
) -> Result<StereoSummary, OutputError> {
    let rect = pipeline.rectification();
    let (d_lo, d_hi) = pipeline.matcher().disparity_range();
    write_grey_png(&dir.join("left_rect.png"), &frame.left)?;
    write_grey_png(&dir.join("right_rect.png"), &frame.right)?;
    write_npy(&dir.join("disparity.npy"), &frame.disparity)?;
    write_npy(&dir.join("depth.npy"), &frame.depth_mm)?;
    // 100 counts per mm: 0.01 mm steps up to 655.35 mm; deeper pixels are counted and
    // warned about below (depth.npy holds them).
    let beyond_png16 = write_png16(&dir.join("depth16.png"), &frame.depth_mm, 100.0)?;
    let searched = (
        RangeChoice::Fixed {
            lo: config.near_mm as f32,
            hi: config.far_mm as f32,
        },
        RangeChoice::Fixed {
            lo: d_lo as f32,
            hi: d_hi as f32,
        },
    );
    let (depth_choice, disparity_choice) = match options.colour_range {
        PictureRange::Auto => (RangeChoice::AUTO, RangeChoice::AUTO),
        PictureRange::Searched => searched,
        PictureRange::DepthMm(lo, hi) => (RangeChoice::Fixed { lo, hi }, RangeChoice::AUTO),
    };
    let colour_ranges = ColourRanges {
        depth: depth_choice.resolve(&frame.depth_mm, 1.0, "mm"),
        disparity: disparity_choice.resolve(&frame.disparity, 1.0, "px"),
    };
    let given_range_warning = match options.colour_range {
        PictureRange::DepthMm(..) => {
            picture::none_within(&colour_ranges.depth, &frame.depth_mm, "depth_colour.png")
        }
        PictureRange::Auto | PictureRange::Searched => None,
    };
    picture::write_png(
        &dir.join("depth_colour.png"),
        &frame.depth_mm,
        &colour_ranges.depth,
    )?;
    picture::write_png(
        &dir.join("disparity_colour.png"),
        &frame.disparity,
        &colour_ranges.disparity,
    )?;
    let grey: Vec<u8> = frame
        .cloud
        .pixels
        .iter()
        .map(|&i| frame.left.as_slice()[i as usize])
        .collect();
    write_points_ply(
        &dir.join("cloud.ply"),
        &frame.cloud.points,
        Some(&grey),
        "stereotac stereo point cloud, mm, rectified left camera frame",
    )?;
    let mut files: Vec<&'static str> = options.written_before.to_vec();
    files.extend(FILES);
    let mesh_triangles = if options.mesh {
        files.insert(files.len() - 1, "mesh.ply");
        Some(write_mesh(&dir.join("mesh.ply"), frame)?)
    } else {
        None
    };
    let depths = frame.sorted_valid_depths();
    let (w, h) = (frame.disparity.width(), frame.disparity.height());
    let summary = StereoSummary {
        width: w,
        height: h,
        focal_px: rect.focal(),
        baseline_mm: rect.baseline(),
        disparity_range_px: [d_lo, d_hi],
        matcher: pipeline.matcher().kind(),
        sgm_paths: pipeline.matcher().sgm_paths().map(Paths::count),
        window_px: pipeline.matcher().window(),
        kernel: pipeline.matcher().kernel(),
        stats: frame.stats,
        fill_rate: depths.len() as f64 / (w * h).max(1) as f64,
        points: frame.cloud.len(),
        outliers_removed: frame.outliers_removed,
        holes_filled: frame.holes_filled,
        depth_mm: (!depths.is_empty()).then(|| {
            [
                depths[0],
                depths[depths.len() / 2],
                depths[depths.len() - 1],
            ]
        }),
        timings: frame.timings,
        files,
        mesh_triangles,
        colour_ranges,
        warnings: (options.earlier_warnings.iter().cloned())
            .chain(super::warnings::of(
                &frame.stats,
                &depths,
                w * h,
                config.near_mm,
                config.far_mm,
            ))
            .chain((beyond_png16 > 0).then(|| depth16_warning(beyond_png16, depths.len())))
            .chain(given_range_warning)
            .collect(),
    };
    let path = dir.join("summary.json");
    let json = serde_json::to_vec_pretty(&summary).expect("the summary serialises");
    std::fs::write(&path, json).map_err(io(&path))?;
    Ok(summary)
}
