//! Outputs people open elsewhere: depth as NumPy `.npy` (f32, H×W, mm), a 16-bit PNG in
//! micrometres, a false-colour PNG with its legend (see [`crate::picture`]), a binary PLY
//! point cloud in mm, and a JSON summary.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use serde::Serialize;

pub use crate::output::{OutputError, colour_map, write_npy};
use crate::output::{io, write_png16};
use crate::picture::{self, ColourRange, RangeChoice};

use super::ambient::AmbientSource;
use super::contact::Roi;
use super::reconstruct::{Reconstruction, StageTimings};
use crate::grid::Grid;

/// Writes depth as a 16-bit grey PNG, one count per micrometre (0 … 65.535 mm, beyond
/// any skin's thickness: deeper depth is refused before it is written); negative depths
/// are written as 0.
pub fn write_depth_png16(path: &Path, depth_mm: &Grid<f32>) -> Result<(), OutputError> {
    write_png16(path, depth_mm, 1000.0).map(drop)
}

/// Writes a binary little-endian PLY with one vertex per pixel: `x`, `y` in mm from the
/// top-left corner, `z = −depth` in mm (the skin surface, pressed in downwards).
pub fn write_ply(path: &Path, depth_mm: &Grid<f32>, px_per_mm: f64) -> Result<(), OutputError> {
    let mut f = BufWriter::new(File::create(path).map_err(io(path))?);
    let n = depth_mm.width() * depth_mm.height();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment stereotac tactile depth, mm\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    );
    f.write_all(header.as_bytes()).map_err(io(path))?;
    let s = 1.0 / px_per_mm as f32;
    let mut buf = Vec::with_capacity(depth_mm.width() * 12);
    for y in 0..depth_mm.height() {
        buf.clear();
        for (x, d) in depth_mm.row(y).iter().enumerate() {
            for v in [(x as f32 + 0.5) * s, (y as f32 + 0.5) * s, -d] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
        }
        f.write_all(&buf).map_err(io(path))?;
    }
    f.flush().map_err(io(path))
}

/// Writes the depth map as a mesh (PLY with two triangles per square of pixels; points
/// as [`write_ply`] places them). Returns the number of triangles.
pub fn write_mesh(path: &Path, depth_mm: &Grid<f32>, px_per_mm: f64) -> Result<usize, OutputError> {
    let s = 1.0 / px_per_mm as f32;
    let w = depth_mm.width();
    let vertices: Vec<Option<[f32; 3]>> = depth_mm
        .as_slice()
        .iter()
        .enumerate()
        .map(|(i, d)| {
            d.is_finite()
                .then(|| [((i % w) as f32 + 0.5) * s, ((i / w) as f32 + 0.5) * s, -d])
        })
        .collect();
    crate::output::write_mesh_ply(
        path,
        w,
        &vertices,
        |_, _| true,
        "stereotac tactile depth mesh, mm",
    )
}

/// Depth above which a pixel counts towards the imprint area (mm).
pub const IMPRINT_MM: f32 = 0.01;

/// Numbers about one reconstruction.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// No contact in the frame.
    pub no_contact: bool,
    /// Deepest point (mm).
    pub max_depth_mm: f32,
    /// Where it is (px).
    pub max_depth_at_px: [usize; 2],
    /// Imprint area (mm²): pixels deeper than [`IMPRINT_MM`].
    pub contact_area_mm2: f64,
    /// Depth-weighted centroid (mm from the top-left corner); `None` without contact.
    pub centroid_mm: Option<[f64; 2]>,
    /// Displaced volume (mm³): sum of positive depth times pixel area.
    pub volume_mm3: f64,
    /// Regions of interest integrated.
    pub regions: Vec<Roi>,
    /// Pixels the colour filter rejected inside the regions.
    pub rejected_pixels: usize,
    /// Slopes the sanitiser replaced or clamped.
    pub sanitized_slopes: usize,
    /// Touched pixels read by the light model past the calibration's slopes (see
    /// [`crate::tactile::past_reach`]; 0 when that is off, or with the light or
    /// photometric model).
    pub past_reach_pixels: usize,
    /// Which ambient light was removed (see [`crate::tactile::ambient`]).
    pub ambient: AmbientSource,
    /// The largest share of a region's slopes its surface does not explain (see
    /// [`crate::tactile::integrable`]).
    pub unexplained_share: f32,
    /// Stage timings (ms).
    pub timings: StageTimings,
}

impl Summary {
    /// Summarises a reconstruction at `px_per_mm`.
    pub fn of(r: &Reconstruction, px_per_mm: f64) -> Self {
        let px_area = 1.0 / (px_per_mm * px_per_mm);
        let (mut best, mut at) = (0.0f32, [0usize, 0usize]);
        let (mut volume, mut wx, mut wy) = (0.0f64, 0.0f64, 0.0f64);
        let w = r.depth_mm.width();
        for (i, &d) in r.depth_mm.as_slice().iter().enumerate() {
            if d > best {
                best = d;
                at = [i % w, i / w];
            }
            if d > 0.0 {
                let d = d as f64;
                volume += d;
                wx += d * ((i % w) as f64 + 0.5);
                wy += d * ((i / w) as f64 + 0.5);
            }
        }
        let touched = r
            .depth_mm
            .as_slice()
            .iter()
            .filter(|&&d| d > IMPRINT_MM)
            .count();
        Self {
            no_contact: r.no_contact(),
            max_depth_mm: best,
            max_depth_at_px: at,
            contact_area_mm2: touched as f64 * px_area,
            centroid_mm: (volume > 0.0).then(|| [wx / volume / px_per_mm, wy / volume / px_per_mm]),
            volume_mm3: volume * px_area,
            regions: r.regions.clone(),
            rejected_pixels: r.rejected_pixels,
            sanitized_slopes: r.sanitized_slopes,
            past_reach_pixels: r.past_reach_pixels,
            ambient: r.ambient,
            unexplained_share: r.unexplained_share,
            timings: r.timings,
        }
    }
}

/// Shallowest range an automatic tactile picture shows (mm): a skin at rest is one
/// colour, not noise stretched over the whole map.
pub const MIN_PICTURE_SPAN_MM: f32 = 0.5;

/// The range of a tactile depth picture: `choice` when fixed; automatically, from flat
/// skin (0, or the most raised point) to the deepest point, at least
/// [`MIN_PICTURE_SPAN_MM`] deep.
pub fn picture_range(depth_mm: &Grid<f32>, choice: Option<RangeChoice>) -> ColourRange {
    match choice {
        Some(c) => c.resolve(depth_mm, 0.01, "mm"),
        None => {
            // Flat skin (0) is the first colour: slightly negative depth (noise, a
            // bulge beside a press) shows as flat rather than moving the scale.
            let lo = 0.0f32;
            let hi = depth_mm
                .as_slice()
                .iter()
                .filter(|d| d.is_finite())
                .fold(0.0f32, |hi, &d| hi.max(d));
            ColourRange {
                lo,
                hi: hi.max(lo + MIN_PICTURE_SPAN_MM),
                unit: "mm",
                from: format!("flat skin to the deepest point, at least {MIN_PICTURE_SPAN_MM} mm"),
            }
        }
    }
}

/// What [`write_all`] wrote, as `summary.json` holds it: the summary, the picture's range
/// and what the outputs should make their reader look twice at.
#[derive(Debug, Clone, Serialize)]
pub struct Written {
    /// The reconstruction's summary.
    #[serde(flatten)]
    pub summary: Summary,
    /// The range `depth_colour.png` shows (also in its legend).
    pub colour_range: ColourRange,
    /// Warnings: the caller's (`earlier`), the reconstruction's own
    /// ([`Reconstruction::warnings`]), then a given colour range that shows none of the
    /// depths.
    pub warnings: Vec<String>,
}

/// Writes every output into `dir` (created if missing): `depth.npy`, `depth16.png`,
/// `depth_colour.png` (over `range`, see [`picture_range`]), `depth.ply`,
/// `summary.json` (with the `earlier` warnings and a given `range` that shows none of the
/// depths). Returns what `summary.json` holds.
pub fn write_all(
    dir: &Path,
    r: &Reconstruction,
    px_per_mm: f64,
    range: Option<RangeChoice>,
    earlier: Vec<String>,
) -> Result<Written, OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let summary = Summary::of(r, px_per_mm);
    write_npy(&dir.join("depth.npy"), &r.depth_mm)?;
    write_depth_png16(&dir.join("depth16.png"), &r.depth_mm)?;
    let colour_range = picture_range(&r.depth_mm, range);
    picture::write_png(&dir.join("depth_colour.png"), &r.depth_mm, &colour_range)?;
    // The automatic range always shows the depths; a given one may miss them all.
    let mut warnings = earlier;
    warnings.extend(r.warnings());
    warnings.extend(
        range.and_then(|_| picture::none_within(&colour_range, &r.depth_mm, "depth_colour.png")),
    );
    write_ply(&dir.join("depth.ply"), &r.depth_mm, px_per_mm)?;
    let json_path = dir.join("summary.json");
    let file = Written {
        summary,
        colour_range,
        warnings,
    };
    let json = serde_json::to_vec_pretty(&file).map_err(|e| OutputError::Io {
        path: json_path.clone(),
        source: std::io::Error::other(e),
    })?;
    std::fs::write(&json_path, json).map_err(io(&json_path))?;
    Ok(file)
}
