//! A processed stereo frame's files, as `stereotac stereo` and the demo write them:
//! rectified views (PNG), disparity and depth (`.npy`, 16-bit and false-colour PNG), the
//! point cloud (PLY) and `summary.json`, which [`StereoSummary`] also returns.

use std::path::Path;

use serde::Serialize;

use super::block_match::{Kernel, MatchStats};
use super::pipeline::{StereoConfig, StereoFrame, StereoPipeline, StereoTimings};
use crate::output::{
    OutputError, io, write_false_colour_png, write_grey_png, write_npy, write_png16,
    write_points_ply,
};

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
    /// What to look at twice (see [`super::warnings`]); empty when nothing.
    pub warnings: Vec<String>,
}

/// Writes `frame` (processed by `pipeline` with `config`) into `dir`, which must exist,
/// and returns its summary.
pub fn write_outputs(
    dir: &Path,
    pipeline: &StereoPipeline,
    frame: &StereoFrame,
    config: &StereoConfig,
) -> Result<StereoSummary, OutputError> {
    let rect = pipeline.rectification();
    let params = pipeline.matcher().params();
    write_grey_png(&dir.join("left_rect.png"), &frame.left)?;
    write_grey_png(&dir.join("right_rect.png"), &frame.right)?;
    write_npy(&dir.join("disparity.npy"), &frame.disparity)?;
    write_npy(&dir.join("depth.npy"), &frame.depth_mm)?;
    // 100 counts per mm: 0.01 mm steps up to 655 mm.
    write_png16(&dir.join("depth16.png"), &frame.depth_mm, 100.0)?;
    write_false_colour_png(
        &dir.join("depth_colour.png"),
        &frame.depth_mm,
        config.near_mm as f32,
        config.far_mm as f32,
    )?;
    write_false_colour_png(
        &dir.join("disparity_colour.png"),
        &frame.disparity,
        params.min_disparity as f32,
        params.max_disparity() as f32,
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
    let depths = frame.sorted_valid_depths();
    let (w, h) = (frame.disparity.width(), frame.disparity.height());
    let summary = StereoSummary {
        width: w,
        height: h,
        focal_px: rect.focal(),
        baseline_mm: rect.baseline(),
        disparity_range_px: [params.min_disparity, params.max_disparity()],
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
        files: FILES.to_vec(),
        warnings: super::warnings::of(&frame.stats, &depths, w * h, config.near_mm, config.far_mm),
    };
    let path = dir.join("summary.json");
    let json = serde_json::to_vec_pretty(&summary).expect("the summary serialises");
    std::fs::write(&path, json).map_err(io(&path))?;
    Ok(summary)
}
