//! Files people open elsewhere, shared by the tactile and stereo pipelines: NumPy
//! `.npy` (f32, H×W), 16-bit grey PNG at a chosen scale, false-colour PNG, and binary
//! PLY point clouds; 8-bit grey images (the stereo pipeline's input and rectified views);
//! and reading `.npy` arrays and grey images back.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::grid::Grid;
use crate::image_file::{self, ImageFileError, Need};

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
    /// An image file that could not be read, or not as 8-bit grey or colour.
    #[error(transparent)]
    Read(#[from] ImageFileError),
    /// A file read back that is not in the form this module writes.
    #[error("{path}: {why}")]
    Format {
        /// File.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
}

pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn image_error(path: &Path) -> impl FnOnce(image::ImageError) -> OutputError + '_ {
    move |source| OutputError::Image {
        path: path.to_path_buf(),
        source,
    }
}

/// Whether two paths name one file: the same path, the same name in the same folder
/// reached another way (`./a` and `a`), or the same existing file (links): two outputs of
/// one command must not, or the second would replace the first.
pub fn same_file(a: &Path, b: &Path) -> bool {
    // The folder resolved where it exists, else the path made absolute and its `.` and
    // `..` taken out by hand (a folder about to be made); the name as given.
    let resolved = |p: &Path| -> Option<PathBuf> {
        let folder = p.parent().filter(|f| !f.as_os_str().is_empty());
        let folder = folder.unwrap_or(Path::new("."));
        let folder = folder.canonicalize().ok().or_else(|| lexical(folder))?;
        Some(folder.join(p.file_name()?))
    };
    a == b
        || matches!((resolved(a), resolved(b)), (Some(x), Some(y)) if x == y)
        || matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// What `path` holds when it is data a written file must never replace, even with
/// `--force` (a recording, a camera frame, a point cloud): the kind, read from the
/// file's first bytes. `None` for anything else, or no file.
pub fn holds_data(path: &Path) -> Option<&'static str> {
    use std::io::Read;
    let meta = std::fs::metadata(path).ok()?;
    if meta.is_dir() {
        return Some("a folder");
    }
    // A FIFO or a terminal would wait for input: only regular files are read.
    if !meta.is_file() {
        return None;
    }
    let mut head = [0u8; 8];
    let mut file = std::fs::File::open(path).ok()?;
    let n = file.read(&mut head).ok()?;
    let head = &head[..n];
    if head.starts_with(b"\x89MCAP") {
        Some("an MCAP recording")
    } else if head.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("a PNG image")
    } else if head.starts_with(b"\x93NUMPY") {
        Some("a NumPy array")
    } else if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
        Some("a PLY point cloud")
    } else {
        None
    }
}

/// `p` made absolute with `.` and `..` taken out, without asking the file system.
fn lexical(p: &Path) -> Option<PathBuf> {
    use std::path::Component;
    let mut out = std::env::current_dir().ok()?;
    for c in p.components() {
        match c {
            Component::Prefix(_) => out = PathBuf::from(c.as_os_str()),
            // Pushing the root replaces all but a prefix.
            Component::RootDir => out.push(c.as_os_str()),
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            Component::Normal(n) => out.push(n),
        }
    }
    Some(out)
}

/// A small file a command writes (a model, report or calibration), for
/// [`check_replace`]'s messages.
#[derive(Debug, Clone, Copy)]
pub struct Written<'a> {
    /// What the file is ("a calibration").
    pub what: &'a str,
    /// The flag that names it ("--out").
    pub flag: &'a str,
    /// A name to suggest instead ("stereo.yaml").
    pub example: &'a str,
}

/// Why a small file may not be written where it was asked.
#[derive(Debug, thiserror::Error)]
pub enum ReplaceRefused {
    /// The path holds data ([`holds_data`]): never replaced, even with `--force`.
    #[error(
        "{flag} {path} is {kind}: {what} is never written over it, even with --force; \
         choose another {flag} (e.g. {example})",
        flag = .written_flag, path = .path.display(), what = .written_what,
        example = .written_example
    )]
    HoldsData {
        /// The file.
        path: PathBuf,
        /// What it holds.
        kind: &'static str,
        /// What would have been written.
        written_what: String,
        /// The flag naming it.
        written_flag: String,
        /// A name to suggest instead.
        written_example: String,
    },
    /// The file exists and `--force` was not given.
    #[error(
        "{flag} {path} exists: pass --force to replace it, or choose another {flag}",
        flag = .flag, path = .path.display()
    )]
    Exists {
        /// The file.
        path: PathBuf,
        /// The flag naming it.
        flag: String,
    },
}

/// Whether `written` may go to `path`, before the work that makes it: never over data
/// ([`holds_data`]: a slip naming the input loses it), over another existing file only
/// with `force`.
pub fn check_replace(path: &Path, force: bool, written: Written<'_>) -> Result<(), ReplaceRefused> {
    if let Some(kind) = holds_data(path) {
        return Err(ReplaceRefused::HoldsData {
            path: path.to_path_buf(),
            kind,
            written_what: written.what.to_string(),
            written_flag: written.flag.to_string(),
            written_example: written.example.to_string(),
        });
    }
    if !force && path.exists() {
        return Err(ReplaceRefused::Exists {
            path: path.to_path_buf(),
            flag: written.flag.to_string(),
        });
    }
    Ok(())
}

/// Writes `bytes` to `path` whole or not at all: into a temporary file beside it, synced,
/// then renamed over `path`. A crash or a full disk leaves the old file (or none), never
/// a truncated one. For files users keep: models, calibrations, firmware images.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::other("not a file name"))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp-{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let written = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// Reads an 8-bit image as grey (colour is converted to luma, as [`grey`] does); 16-bit,
/// float and oversized images are refused ([`crate::image_file`]).
pub fn read_grey(path: &Path) -> Result<Grid<u8>, OutputError> {
    let img = image_file::read(path, Need::Grey)?.into_luma8();
    let (w, h) = img.dimensions();
    Grid::from_vec(w as usize, h as usize, img.into_raw()).ok_or_else(|| OutputError::Format {
        path: path.to_path_buf(),
        why: format!("a {w}×{h} image whose pixels do not fill it"),
    })
}

/// An RGB frame as 8-bit grey: the `image` crate's luma (Rec. 709 weights,
/// `(2126 r + 7152 g + 722 b) / 10000` rounded down), the one conversion for files
/// (`stereo`) and live frames (`run`, `process`) alike. Computed here in a flat loop the
/// compiler vectorises: the crate's generic per-pixel conversion took 1.2 ms of a
/// 640×480 frame, a seventh of the live stereo stage.
pub fn grey(image: &image::RgbImage) -> Grid<u8> {
    let (w, h) = image.dimensions();
    let luma: Vec<u8> = image
        .as_raw()
        .chunks_exact(3)
        .map(|p| {
            let sum = 2126 * u32::from(p[0]) + 7152 * u32::from(p[1]) + 722 * u32::from(p[2]);
            // At most 255 · 10000: the quotient fits a byte.
            (sum / 10_000) as u8
        })
        .collect();
    Grid::from_vec(w as usize, h as usize, luma).expect("one value per pixel")
}

/// Writes `grid` as an 8-bit grey PNG.
pub fn write_grey_png(path: &Path, grid: &Grid<u8>) -> Result<(), OutputError> {
    image::GrayImage::from_raw(
        grid.width() as u32,
        grid.height() as u32,
        grid.as_slice().to_vec(),
    )
    .expect("a grid holds width × height pixels")
    .save(path)
    .map_err(image_error(path))
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

/// Reads a 2-D little-endian f32 `.npy` array in C order: what [`write_npy`] writes,
/// and what NumPy's `np.save` writes for a `float32` array.
/// At most [`crate::limits::MAX_IMAGE_ALLOC`] bytes of data are read.
pub fn read_npy(path: &Path) -> Result<Grid<f32>, OutputError> {
    use std::io::Read;
    // The largest array is a frame's worth of f32, plus a header (at most 64 KiB).
    let limit = crate::limits::MAX_IMAGE_ALLOC + 10 + u64::from(u16::MAX);
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(limit + 1).read_to_end(&mut bytes))
        .map_err(io(path))?;
    if bytes.len() as u64 > limit {
        return Err(OutputError::Format {
            path: path.to_path_buf(),
            why: format!("larger than {limit} bytes: more than any frame's depth"),
        });
    }
    parse_npy(path, &bytes)
}

/// [`read_npy`] on bytes already read; `path` names them in errors.
pub fn parse_npy(path: &Path, bytes: &[u8]) -> Result<Grid<f32>, OutputError> {
    let bad = |why: &str| OutputError::Format {
        path: path.to_path_buf(),
        why: why.to_string(),
    };
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" || bytes[6] != 1 {
        return Err(bad("not a version 1 .npy file"));
    }
    let len = usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
    let header = bytes
        .get(10..10 + len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad("truncated header"))?;
    if !header.contains("'descr': '<f4'") || !header.contains("'fortran_order': False") {
        return Err(bad("not a little-endian f32 array in C order"));
    }
    let shape: Vec<usize> = header
        .split("'shape': (")
        .nth(1)
        .and_then(|rest| rest.split_once(')'))
        .map(|(shape, _)| shape)
        .ok_or_else(|| bad("no shape"))?
        .split(',')
        .map(str::trim)
        .filter(|v| !v.is_empty())
        .map(|v| v.parse().map_err(|_| bad("a shape entry is not a number")))
        .collect::<Result<_, _>>()?;
    let [height, width] = shape[..] else {
        return Err(bad("not a 2-D array"));
    };
    let data: Vec<f32> = bytes[10 + len..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Grid::from_vec(width, height, data).ok_or_else(|| bad("data length does not match the shape"))
}

/// Writes `grid` as a 16-bit grey PNG with `counts_per_unit` counts per unit of the
/// grid (e.g. 1000 per mm: micrometres). Values are rounded and clamped to 0..=65535;
/// NaN is written as 0 (the usual "no depth" value of depth images). Returns how many
/// values were above the largest count (written as 65535: the caller says so).
pub fn write_png16(
    path: &Path,
    grid: &Grid<f32>,
    counts_per_unit: f32,
) -> Result<usize, OutputError> {
    let mut above = 0;
    let data: Vec<u16> = grid
        .as_slice()
        .iter()
        .map(|v| {
            let c = (v * counts_per_unit).round();
            above += usize::from(c > 65535.0);
            if c.is_nan() {
                0
            } else {
                c.clamp(0.0, 65535.0) as u16
            }
        })
        .collect();
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
        grid.width() as u32,
        grid.height() as u32,
        data,
    )
    .expect("buffer length matches");
    img.save(path).map_err(image_error(path))?;
    Ok(above)
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

/// Writes a depth map's surface as a binary little-endian PLY mesh: `vertices` holds one
/// entry per pixel of a `width`×`height` grid (`None`: no point there), and each square of
/// four neighbouring pixels becomes two triangles where their points exist and `joined`
/// says each edge lies on one surface (not across a depth step). Returns the number of
/// triangles written.
pub fn write_mesh_ply(
    path: &Path,
    width: usize,
    vertices: &[Option<[f32; 3]>],
    joined: impl Fn(&[f32; 3], &[f32; 3]) -> bool,
    comment: &str,
) -> Result<usize, OutputError> {
    let height = vertices.len().checked_div(width).unwrap_or(0);
    let mut index = vec![u32::MAX; vertices.len()];
    let mut count = 0u32;
    for (slot, v) in index.iter_mut().zip(vertices) {
        if v.is_some() {
            *slot = count;
            count += 1;
        }
    }
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let point = |i: usize| vertices[i].as_ref();
    for y in 0..height.saturating_sub(1) {
        for x in 0..width - 1 {
            let (a, b) = (y * width + x, y * width + x + 1);
            let (c, d) = (a + width, b + width);
            for [p, q, r] in [[a, c, b], [b, c, d]] {
                if let (Some(pp), Some(pq), Some(pr)) = (point(p), point(q), point(r))
                    && joined(pp, pq)
                    && joined(pq, pr)
                    && joined(pr, pp)
                {
                    faces.push([index[p], index[q], index[r]]);
                }
            }
        }
    }
    let mut f = BufWriter::new(File::create(path).map_err(io(path))?);
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {count}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        faces.len()
    );
    f.write_all(header.as_bytes()).map_err(io(path))?;
    for v in vertices.iter().flatten() {
        for c in v {
            f.write_all(&c.to_le_bytes()).map_err(io(path))?;
        }
    }
    for face in &faces {
        f.write_all(&[3]).map_err(io(path))?;
        for i in face {
            f.write_all(&(*i as i32).to_le_bytes()).map_err(io(path))?;
        }
    }
    f.flush().map_err(io(path))?;
    Ok(faces.len())
}

/// Writes points (mm) as a binary little-endian PLY, with a grey value per point when
/// `grey` is given (same length as `points`).
pub fn write_points_ply(
    path: &Path,
    points: &[[f32; 3]],
    grey: Option<&[u8]>,
    comment: &str,
) -> Result<(), OutputError> {
    let mut f = BufWriter::new(File::create(path).map_err(io(path))?);
    let colour = grey.filter(|g| g.len() == points.len());
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        points.len()
    );
    if colour.is_some() {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    header.push_str("end_header\n");
    f.write_all(header.as_bytes()).map_err(io(path))?;
    for (i, p) in points.iter().enumerate() {
        for v in p {
            f.write_all(&v.to_le_bytes()).map_err(io(path))?;
        }
        if let Some(g) = colour {
            f.write_all(&[g[i]; 3]).map_err(io(path))?;
        }
    }
    f.flush().map_err(io(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_files_are_told_by_their_first_bytes() {
        let dir = std::env::temp_dir().join(format!("stereotac-holds-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = |name: &str, bytes: &[u8]| {
            let p = dir.join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        // Named by what they hold, whatever their names say.
        let mcap = file("model.json", b"\x89MCAP0\r\n...");
        assert_eq!(holds_data(&mcap), Some("an MCAP recording"));
        let png = file("a.json", b"\x89PNG\r\n\x1a\n....");
        assert_eq!(holds_data(&png), Some("a PNG image"));
        assert_eq!(
            holds_data(&file("d.npy", b"\x93NUMPY\x01\x00")),
            Some("a NumPy array")
        );
        assert_eq!(
            holds_data(&file("c.ply", b"ply\nformat")),
            Some("a PLY point cloud")
        );
        assert_eq!(holds_data(&dir), Some("a folder"));
        // A model, a short file, an empty one and no file are not data.
        assert_eq!(holds_data(&file("m.json", b"{\"format\": 1}")), None);
        assert_eq!(holds_data(&file("short", b"\x89")), None);
        assert_eq!(holds_data(&file("empty", b"")), None);
        assert_eq!(holds_data(&dir.join("absent")), None);
        // Data is refused even with force, naming the flag and a name to use; another
        // file needs force; no file is fine.
        let written = Written {
            what: "a model",
            flag: "--out",
            example: "model.json",
        };
        let e = check_replace(&png, true, written).unwrap_err().to_string();
        assert!(
            e.contains("--out") && e.contains("a PNG image") && e.contains("(e.g. model.json)"),
            "{e}"
        );
        let model = file("old.json", b"{}");
        let e = check_replace(&model, false, written)
            .unwrap_err()
            .to_string();
        assert!(e.contains("exists: pass --force"), "{e}");
        check_replace(&model, true, written).unwrap();
        check_replace(&dir.join("absent"), false, written).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn same_file_sees_one_file_named_two_ways() {
        let dir = std::env::temp_dir().join(format!("stereotac-same-file-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let a = dir.join("a.json");
        // Not there yet: the same name in the same folder, however the folder is reached.
        assert!(same_file(&a, &dir.join("sub").join("..").join("a.json")));
        assert!(same_file(&a, &a));
        assert!(!same_file(&a, &dir.join("b.json")));
        assert!(!same_file(&a, &dir.join("sub").join("a.json")));
        // In a folder not made yet.
        let later = dir.join("later");
        assert!(same_file(
            &later.join("x.yaml"),
            &later.join(".").join("x.yaml")
        ));
        assert!(!same_file(&later.join("x.yaml"), &later.join("y.yaml")));
        // There: a link to it too (where the platform makes them).
        std::fs::write(&a, b"x").unwrap();
        #[cfg(unix)]
        {
            let link = dir.join("sub").join("link.json");
            std::os::unix::fs::symlink(&a, &link).unwrap();
            assert!(same_file(&a, &link));
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn grey_is_the_image_crates_rec709_luma() {
        let img = image::RgbImage::from_fn(3, 1, |x, _| match x {
            0 => image::Rgb([255, 0, 0]),
            1 => image::Rgb([0, 255, 0]),
            _ => image::Rgb([255, 255, 255]),
        });
        assert_eq!(grey(&img).as_slice(), &[54, 182, 255]);
    }

    /// The flat loop gives the `image` crate's own luma for every level of every channel
    /// and for mixed pixels.
    #[test]
    fn grey_is_the_image_crates_luma() {
        let mut rng = crate::rng::Rng::new(11);
        let mut raw = Vec::new();
        for v in 0..=255u8 {
            raw.extend([v, 0, 0, 0, v, 0, 0, 0, v, v, v, v]);
        }
        for _ in 0..4096 {
            raw.extend([0; 3].map(|_| (rng.uniform() * 256.0) as u8));
        }
        let img = image::RgbImage::from_raw((raw.len() / 3) as u32, 1, raw).unwrap();
        assert_eq!(
            grey(&img).as_slice(),
            image::imageops::grayscale(&img).as_raw().as_slice()
        );
    }

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
        assert_eq!(read_npy(&path).unwrap(), g);
        std::fs::write(&path, &bytes[..bytes.len() - 4]).unwrap();
        assert!(matches!(read_npy(&path), Err(OutputError::Format { .. })));
        // Hostile headers: refused, never a panic or an overflow.
        let with_header = |h: &str| {
            let mut b = b"\x93NUMPY\x01\x00".to_vec();
            b.extend_from_slice(&(h.len() as u16).to_le_bytes());
            b.extend_from_slice(h.as_bytes());
            b.extend_from_slice(&[0; 16]);
            b
        };
        for header in [
            "{'descr': '<f4', 'fortran_order': False, 'shape': (18446744073709551615, 2), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2, 1), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (-1, 2), }",
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2",
        ] {
            let e = parse_npy(&path, &with_header(header)).unwrap_err();
            assert!(matches!(e, OutputError::Format { .. }), "{header}: {e}");
        }
        let mut short = with_header("{");
        short[8] = 0xff;
        assert!(parse_npy(&path, &short).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn meshes_join_neighbours_on_one_surface_only() {
        let dir = std::env::temp_dir().join(format!("stereotac-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.ply");
        // 3×3 pixels: the middle one missing, the right column behind a depth step.
        let vertices: Vec<Option<[f32; 3]>> = (0..9)
            .map(|i| {
                let (x, y) = (i % 3, i / 3);
                let z = if x == 2 { 50.0 } else { 10.0 };
                ((x, y) != (1, 1)).then_some([x as f32, y as f32, z])
            })
            .collect();
        let near = |a: &[f32; 3], b: &[f32; 3]| (a[2] - b[2]).abs() < 1.0;
        // Of the eight triangles, two avoid the hole: (0,0)-(0,1)-(1,0) on the near
        // surface and (2,1)-(1,2)-(2,2) across the step.
        let all = write_mesh_ply(&path, 3, &vertices, |_, _| true, "test").unwrap();
        assert_eq!(all, 2);
        let faces = write_mesh_ply(&path, 3, &vertices, near, "test").unwrap();
        assert_eq!(faces, 1);
        let bytes = std::fs::read(&path).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.contains("element vertex 8\n"), "{text}");
        assert!(text.contains("element face 1\n"));
        let body = bytes.len() - (text.find("end_header\n").unwrap() + 11);
        assert_eq!(body, 8 * 12 + 13);
        // The triangle's indices skip the missing pixel: (0,0) → 0, (0,1) → 3, (1,0) → 1.
        let face = &bytes[bytes.len() - 13..];
        assert_eq!(face[0], 3);
        let idx: Vec<i32> = face[1..]
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(idx, vec![0, 3, 1]);
        assert_eq!(write_mesh_ply(&path, 0, &[], near, "empty").unwrap(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn atomic_writes_replace_whole_files_and_leave_no_temporaries() {
        let dir = std::env::temp_dir().join(format!("stereotac-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("model.json");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second, longer").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second, longer");
        assert_eq!(
            std::fs::read_dir(&dir).unwrap().count(),
            1,
            "no temporary left"
        );
        // Into a folder that does not exist: an error, nothing written.
        assert!(write_atomic(&dir.join("no/such/dir/x"), b"x").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn colour_map_endpoints_and_nan() {
        assert_eq!(colour_map(0.0), [20, 20, 80]);
        assert_eq!(colour_map(1.0), [220, 40, 30]);
        assert_eq!(colour_map(f32::NAN), colour_map(0.0));
    }

    #[test]
    fn png16_scales_and_ply_has_one_record_per_point() {
        let dir = std::env::temp_dir().join(format!("stereotac-out-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let g = Grid::from_vec(3, 1, vec![1.5, f32::NAN, 700.0]).unwrap();
        let png = dir.join("a.png");
        assert_eq!(
            write_png16(&png, &g, 100.0).unwrap(),
            1,
            "700 mm is past 655.35"
        );
        let img = image::open(&png).unwrap().into_luma16();
        assert_eq!(img.as_raw(), &vec![150, 0, 65535]);
        let ply = dir.join("a.ply");
        write_points_ply(
            &ply,
            &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
            Some(&[7, 8]),
            "t",
        )
        .unwrap();
        let bytes = std::fs::read(&ply).unwrap();
        let end = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        assert!(
            std::str::from_utf8(&bytes[..end])
                .unwrap()
                .contains("element vertex 2")
        );
        assert_eq!(bytes.len() - end, 2 * 15);
        assert_eq!(&bytes[end + 12..end + 15], &[7, 7, 7]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
