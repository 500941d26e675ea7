//! Reading the phase images: single RGB8 files and directories of `NAME_dx.png` /
//! `NAME_dy.png` pairs, with errors that name the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::RgbImage;

use super::calibrate::CalibrationPair;
use crate::image_file::{self, ImageFileError};

/// Why images could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be read, decoded, or is not an 8-bit colour image.
    #[error(transparent)]
    Read(#[from] ImageFileError),
    /// The directory could not be listed.
    #[error("{}: {source}", path.display())]
    Dir {
        /// Directory.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A `_dx` file without its `_dy` partner, or the other way round.
    #[error("{}: no matching {partner} file", path.display())]
    Unpaired {
        /// The file found.
        path: PathBuf,
        /// The partner looked for.
        partner: String,
    },
    /// One reference frame given without the other.
    #[error("give both no-contact reference frames (dx and dy), or neither")]
    HalfReference,
    /// No pairs in the directory.
    #[error("{}: no NAME_dx.png / NAME_dy.png pairs found", path.display())]
    Empty {
        /// Directory.
        path: PathBuf,
    },
}

/// Reads an 8-bit RGB(A) image; grey, 16-bit and oversized images are refused
/// ([`crate::image_file`]).
pub fn load_rgb(path: &Path) -> Result<RgbImage, ImageError> {
    Ok(image_file::read_rgb(path)?)
}

/// Reads the no-contact reference frames (dx, dy) when both are given; `None` when
/// neither is.
pub fn load_references(
    dx: Option<&Path>,
    dy: Option<&Path>,
) -> Result<Option<(RgbImage, RgbImage)>, ImageError> {
    match (dx, dy) {
        (Some(dx), Some(dy)) => Ok(Some((load_rgb(dx)?, load_rgb(dy)?))),
        (None, None) => Ok(None),
        _ => Err(ImageError::HalfReference),
    }
}

/// Reads every `NAME_dx.png` / `NAME_dy.png` pair in `dir` (suffix case ignored), with
/// its LEDs-off frame `NAME_dark.png` when there is one, sorted by name.
pub fn load_pairs(dir: &Path) -> Result<Vec<CalibrationPair>, ImageError> {
    let dir_error = |source| ImageError::Dir {
        path: dir.to_path_buf(),
        source,
    };
    let mut found: BTreeMap<String, [Option<PathBuf>; 3]> = BTreeMap::new();
    for e in std::fs::read_dir(dir).map_err(dir_error)? {
        let path = e.map_err(dir_error)?.path();
        let file = path
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_default();
        let lower = file.to_ascii_lowercase();
        for (slot, suffix) in ["_dx.png", "_dy.png", "_dark.png"].into_iter().enumerate() {
            if lower.ends_with(suffix) {
                let name = file[..file.len() - suffix.len()].to_string();
                found.entry(name).or_default()[slot] = Some(path.clone());
            }
        }
    }
    if found.is_empty() {
        return Err(ImageError::Empty {
            path: dir.to_path_buf(),
        });
    }
    found
        .into_iter()
        .map(|(name, [dx, dy, dark])| match (dx, dy) {
            (Some(dx), Some(dy)) => Ok(CalibrationPair {
                dx: load_rgb(&dx)?,
                dy: load_rgb(&dy)?,
                dark: dark.as_deref().map(load_rgb).transpose()?,
                name,
            }),
            (Some(path), None) => Err(ImageError::Unpaired {
                path,
                partner: format!("{name}_dy.png"),
            }),
            (None, Some(path)) => Err(ImageError::Unpaired {
                path,
                partner: format!("{name}_dx.png"),
            }),
            (None, None) => Err(ImageError::Unpaired {
                path: dark.unwrap_or_default(),
                partner: format!("{name}_dx.png and {name}_dy.png"),
            }),
        })
        .collect()
}
