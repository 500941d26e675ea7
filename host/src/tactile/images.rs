//! Reading the phase images: single RGB8 files and directories of `NAME_dx.png` /
//! `NAME_dy.png` pairs, with errors that name the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::RgbImage;

use super::calibrate::CalibrationPair;
use crate::image_file::{self, ImageFileError, Need};

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
    /// Two files for one frame of a press (their suffixes differ only in case): which
    /// one is the frame is not guessed.
    #[error(
        "{} and {} are both its {phase} frame (the suffixes differ only in case): keep one",
        first.display(),
        second.display()
    )]
    Twice {
        /// One file.
        first: PathBuf,
        /// The other.
        second: PathBuf,
        /// "dx", "dy" or "LEDs-off".
        phase: &'static str,
    },
    /// A file of another size than the frames it goes with: set aside undecoded.
    #[error(
        "{}: {}×{} px, but {against} are {}×{} px; not decoded: give every frame from this \
         sensor's camera at one resolution",
        path.display(), got.0, got.1, want.0, want.1
    )]
    Size {
        /// The file.
        path: PathBuf,
        /// Its size, from its header.
        got: (u32, u32),
        /// The size wanted.
        want: (u32, u32),
        /// Whose size that is.
        against: &'static str,
    },
    /// Without reference frames the pairs' size is the one most pairs have; no size is.
    #[error(
        "{}: the pairs' dx frames come in {}, none more often than the others: give \
         frames of one camera at one resolution (or reference frames, whose size then \
         decides)",
        path.display(),
        sizes
            .iter()
            .map(|((w, h), n, first)| {
                let name = first.file_name().unwrap_or_default().to_string_lossy();
                format!("{w}×{h} px ({n}, e.g. {name})")
            })
            .collect::<Vec<_>>()
            .join(", ")
    )]
    MixedSizes {
        /// Directory.
        path: PathBuf,
        /// Each size met, with how many dx frames have it and the first of them (by
        /// name).
        sizes: Vec<((u32, u32), usize, PathBuf)>,
    },
    /// The folder's frames of the size taken would need more memory decoded than
    /// [`crate::limits::MAX_CALIBRATION_FRAMES`]: refused before any is decoded.
    #[error(
        "{}: its {frames} frames of {}×{} px would bring the calibration's frames to {:.1} GB \
         decoded (at most {:.1} GB): calibrate from fewer presses (30 are plenty) or smaller \
         frames",
        path.display(),
        size.0,
        size.1,
        *bytes as f64 / 1e9,
        crate::limits::MAX_CALIBRATION_FRAMES as f64 / 1e9
    )]
    TooMuch {
        /// Directory.
        path: PathBuf,
        /// Frames of the complete pairs (dx, dy and their LEDs-off frames).
        frames: usize,
        /// Their size.
        size: (u32, u32),
        /// What they would take decoded, with the folders read before it.
        bytes: u64,
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
    /// Pairs were found, but none could be read.
    #[error(
        "{}: none of its {count} pair(s) could be read; the first: {first}",
        path.display()
    )]
    NoneReadable {
        /// Directory.
        path: PathBuf,
        /// Pairs found.
        count: usize,
        /// Why the first could not be read.
        first: Box<ImageError>,
    },
}

/// The pairs of a folder ([`load_pairs`]), and those set aside: a file that cannot be
/// read (damaged, truncated, grey, 16-bit) or a `_dx` without its `_dy` costs that press,
/// not the calibration.
#[derive(Debug)]
pub struct FolderPairs {
    /// The pairs read, sorted by name.
    pub pairs: Vec<CalibrationPair>,
    /// Each pair set aside: its name and why.
    pub set_aside: Vec<(String, ImageError)>,
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
/// its LEDs-off frame `NAME_dark.png` when there is one, sorted by name. A pair that
/// cannot be read is set aside with the reason; an error when the folder cannot be
/// listed, holds no pairs, or none can be read. The files' headers are read first: a pair
/// with a file of another size than `want` (the reference frames' size), or without it
/// than most pairs' dx frames, is set aside undecoded (a folder of huge images costs
/// their headers only, and one odd press costs that press).
pub fn load_pairs(dir: &Path, want: Option<(u32, u32)>) -> Result<FolderPairs, ImageError> {
    load_more_pairs(dir, want, 0)
}

/// [`load_pairs`] for a folder read after others whose frames took `decoded` bytes: the
/// bound on a calibration's frames holds for all of them together.
pub fn load_more_pairs(
    dir: &Path,
    want: Option<(u32, u32)>,
    decoded: u64,
) -> Result<FolderPairs, ImageError> {
    let dir_error = |source| ImageError::Dir {
        path: dir.to_path_buf(),
        source,
    };
    let mut found: BTreeMap<String, [Option<PathBuf>; 3]> = BTreeMap::new();
    // A press with two files for one of its frames, and the first such pair of files.
    let mut twice: BTreeMap<String, ImageError> = BTreeMap::new();
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
                let place = &mut found.entry(name.clone()).or_default()[slot];
                if let Some(first) = place.replace(path.clone()) {
                    twice.entry(name).or_insert(ImageError::Twice {
                        first,
                        second: path.clone(),
                        phase: ["dx", "dy", "LEDs-off"][slot],
                    });
                }
            }
        }
    }
    if found.is_empty() {
        return Err(ImageError::Empty {
            path: dir.to_path_buf(),
        });
    }
    let count = found.len();
    let (want, against) = match want {
        Some(size) => (Some(size), "the reference frames"),
        None => {
            let dx_sizes = found.values().filter_map(|[dx, _, _]| {
                let dx = dx.as_deref()?;
                Some((image_file::header(dx, Need::Colour).ok()?, dx.to_path_buf()))
            });
            let size = most_common(dx_sizes).map_err(|sizes| ImageError::MixedSizes {
                path: dir.to_path_buf(),
                sizes,
            })?;
            (size, "most pairs' frames")
        }
    };
    if let Some(size) = want {
        // Every complete pair's frames counted at the size taken: at least what decoding
        // costs (frames of another size are set aside undecoded).
        let frames: usize = found
            .values()
            .filter(|[dx, dy, _]| dx.is_some() && dy.is_some())
            .map(|[_, _, dark]| 2 + usize::from(dark.is_some()))
            .sum();
        let bytes = decoded + frames as u64 * u64::from(size.0) * u64::from(size.1) * 3;
        if bytes > crate::limits::MAX_CALIBRATION_FRAMES {
            return Err(ImageError::TooMuch {
                path: dir.to_path_buf(),
                frames,
                size,
                bytes,
            });
        }
    }
    let mut out = FolderPairs {
        pairs: Vec::with_capacity(count),
        set_aside: Vec::new(),
    };
    for (name, [dx, dy, dark]) in found {
        if let Some(e) = twice.remove(&name) {
            out.set_aside.push((name, e));
            continue;
        }
        let pair = match (dx, dy) {
            (Some(dx), Some(dy)) => (|| {
                for path in [Some(&dx), Some(&dy), dark.as_ref()].into_iter().flatten() {
                    let got = image_file::header(path, Need::Colour)?;
                    if let Some(want) = want.filter(|&w| w != got) {
                        return Err(ImageError::Size {
                            path: path.clone(),
                            got,
                            want,
                            against,
                        });
                    }
                }
                Ok(CalibrationPair {
                    dx: load_rgb(&dx)?,
                    dy: load_rgb(&dy)?,
                    dark: dark.as_deref().map(load_rgb).transpose()?,
                    name: name.clone(),
                    ball_diameter_mm: None,
                })
            })(),
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
        };
        match pair {
            Ok(p) => out.pairs.push(p),
            Err(e) => out.set_aside.push((name, e)),
        }
    }
    if out.pairs.is_empty() {
        let (_, first) = out.set_aside.swap_remove(0);
        return Err(ImageError::NoneReadable {
            path: dir.to_path_buf(),
            count,
            first: Box::new(first),
        });
    }
    Ok(out)
}

/// The value met more often than any other (`None` when there is none); when two or
/// more are met most often, every value with its count.
#[allow(clippy::type_complexity)]
fn most_common<T>(
    values: impl Iterator<Item = ((u32, u32), T)>,
) -> Result<Option<(u32, u32)>, Vec<((u32, u32), usize, T)>> {
    let mut counts: Vec<((u32, u32), usize, T)> = Vec::new();
    for (v, first) in values {
        match counts.iter_mut().find(|(c, _, _)| *c == v) {
            Some((_, n, _)) => *n += 1,
            None => counts.push((v, 1, first)),
        }
    }
    let Some(most) = counts.iter().map(|(_, n, _)| *n).max() else {
        return Ok(None);
    };
    match counts.iter().filter(|(_, n, _)| *n == most).count() {
        1 => Ok(counts
            .into_iter()
            .find(|(_, n, _)| *n == most)
            .map(|(v, _, _)| v)),
        _ => Err(counts),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A press with two files for one frame, their suffixes differing only in case, is
    /// set aside naming both (one would have replaced the other without a word); the
    /// others are read.
    #[test]
    fn two_files_for_one_frame_set_their_press_aside() {
        let dir = std::env::temp_dir().join(format!("stereotac-twice-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let frame = RgbImage::from_pixel(8, 6, image::Rgb([180, 20, 150]));
        for name in ["a_dx.png", "a_dy.png", "b_dx.png", "b_dy.png", "b_dx.PNG"] {
            frame
                .save_with_format(dir.join(name), image::ImageFormat::Png)
                .unwrap();
        }
        let read = load_pairs(&dir, None).unwrap();
        assert_eq!(read.pairs.len(), 1);
        assert_eq!(read.pairs[0].name, "a");
        let (name, why) = &read.set_aside[0];
        let why = why.to_string();
        assert_eq!(name, "b");
        assert!(
            why.contains("b_dx.png") && why.contains("b_dx.PNG") && why.contains("dx frame"),
            "{why}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
