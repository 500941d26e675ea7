//! Outputs people open elsewhere: depth as NumPy `.npy` (f32, H×W, mm), a 16-bit PNG in
//! micrometres, a false-colour PNG, a binary PLY point cloud in mm, and a JSON summary.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::contact::Roi;
use super::grid::Grid;
use super::reconstruct::{Reconstruction, StageTimings};

/// Why an output could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// File system error.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// PNG encoding error.
    #[error("{path}: {source}")]
    Image {
        /// File.
        path: PathBuf,
        /// Cause.
        source: image::ImageError,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `grid` as a little-endian f32 `.npy` array of shape `(height, width)`.
pub fn write_npy(path: &Path, grid: &Grid<f32>) -> Result<(), OutputError> {
    let mut f = BufWriter::new(File::create(path).map_err(io(path))?);
    let mut header = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}",
        grid.height(),
        grid.width()
    );
    // Magic (6) + version (2) + length (2) + header + '\n' is a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + grid.as_slice().len() * 4);
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in grid.as_slice() {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    f.write_all(&bytes).map_err(io(path))?;
    f.flush().map_err(io(path))
}

/// Writes depth as a 16-bit grey PNG, one count per micrometre (0 … 65.535 mm);
/// negative depths are written as 0.
pub fn write_depth_png16(path: &Path, depth_mm: &Grid<f32>) -> Result<(), OutputError> {
    let data: Vec<u16> = depth_mm
        .as_slice()
        .iter()
        .map(|d| (d * 1000.0).round().clamp(0.0, 65535.0) as u16)
        .collect();
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
        depth_mm.width() as u32,
        depth_mm.height() as u32,
        data,
    )
    .expect("buffer length matches");
    img.save(path).map_err(|source| OutputError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes depth in false colour (dark blue at 0 through green and yellow to red at
/// `max_mm`), for a quick look.
pub fn write_false_colour_png(
    path: &Path,
    depth_mm: &Grid<f32>,
    max_mm: f32,
) -> Result<(), OutputError> {
    let max = if max_mm > 0.0 { max_mm } else { 1.0 };
    let mut img = image::RgbImage::new(depth_mm.width() as u32, depth_mm.height() as u32);
    for (px, d) in img.pixels_mut().zip(depth_mm.as_slice()) {
        *px = image::Rgb(colour_map((d / max).clamp(0.0, 1.0)));
    }
    img.save(path).map_err(|source| OutputError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// A perceptually ordered map: piecewise linear through five anchor colours.
pub fn colour_map(t: f32) -> [u8; 3] {
    const ANCHORS: [[f32; 3]; 5] = [
        [20.0, 20.0, 80.0],
        [30.0, 110.0, 200.0],
        [60.0, 190.0, 110.0],
        [240.0, 220.0, 50.0],
        [220.0, 40.0, 30.0],
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * 4.0;
    let i = (t as usize).min(3);
    let f = t - i as f32;
    let (a, b) = (ANCHORS[i], ANCHORS[i + 1]);
    [0, 1, 2].map(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
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
            timings: r.timings,
        }
    }
}

/// Writes every output into `dir` (created if missing): `depth.npy`, `depth16.png`,
/// `depth_colour.png`, `depth.ply`, `summary.json`. Returns the summary.
pub fn write_all(dir: &Path, r: &Reconstruction, px_per_mm: f64) -> Result<Summary, OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let summary = Summary::of(r, px_per_mm);
    write_npy(&dir.join("depth.npy"), &r.depth_mm)?;
    write_depth_png16(&dir.join("depth16.png"), &r.depth_mm)?;
    write_false_colour_png(
        &dir.join("depth_colour.png"),
        &r.depth_mm,
        summary.max_depth_mm.max(0.1),
    )?;
    write_ply(&dir.join("depth.ply"), &r.depth_mm, px_per_mm)?;
    let json_path = dir.join("summary.json");
    let json = serde_json::to_vec_pretty(&summary).map_err(|e| OutputError::Io {
        path: json_path.clone(),
        source: std::io::Error::other(e),
    })?;
    std::fs::write(&json_path, json).map_err(io(&json_path))?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_header_is_aligned_and_data_round_trips() {
        let dir = std::env::temp_dir().join(format!("stereotac-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.npy");
        let g = Grid::from_fn(3, 2, |x, y| (x + 10 * y) as f32 * 0.5);
        write_npy(&path, &g).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let header = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
        assert!(header.contains("'shape': (2, 3)"), "{header}");
        let data: Vec<f32> = bytes[10 + hlen..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(data, g.as_slice());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn colour_map_endpoints_and_nan() {
        assert_eq!(colour_map(0.0), [20, 20, 80]);
        assert_eq!(colour_map(1.0), [220, 40, 30]);
        assert_eq!(colour_map(f32::NAN), colour_map(0.0));
    }
}
