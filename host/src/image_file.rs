//! Reading image files written by someone else, within bounds: the header is read first
//! (what comes before the pixels may allocate at most [`MAX_IMAGE_HEADER_ALLOC`] bytes),
//! and an image larger than [`MAX_FRAME_SIDE`] a side, or of a colour type or bit depth
//! the caller cannot use, is refused before a pixel is decoded; decoding may allocate at
//! most [`MAX_IMAGE_ALLOC`] bytes. [`header`] reads only the header. One place for every file reader (tactile pairs, stereo
//! pairs, recordings replayed, frames inside MCAP files), so each gets the same rules.
//!
//! What each use accepts:
//! - [`Need::Colour`] (tactile frames): 8-bit RGB or RGBA (alpha dropped). A grey image
//!   has lost the strip colours the pipeline reads, and a 16-bit or float image would be
//!   rescaled into a range the model was not calibrated on: both are refused with a hint.
//! - [`Need::Grey`] (stereo pairs): 8-bit grey, grey+alpha, RGB or RGBA (colour is
//!   converted to luma); 16-bit and float are refused.

use std::io::{BufRead, Cursor, Seek};
use std::path::{Path, PathBuf};

use image::{ColorType, DynamicImage, ImageDecoder, ImageFormat, ImageReader, Limits, RgbImage};

use crate::limits::{MAX_FRAME_SIDE, MAX_IMAGE_ALLOC, MAX_IMAGE_HEADER_ALLOC};

/// What the caller will do with the pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Need {
    /// 8-bit colour (the tactile pipeline reads the LED strips' colours).
    Colour,
    /// 8-bit grey; colour is converted to luma (stereo matching).
    Grey,
}

/// Why an image file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ImageFileError {
    /// The file could not be opened or read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The bytes are not an image the decoder could read, or it hit a limit.
    #[error("{}: {source}", path.display())]
    Decode {
        /// The file.
        path: PathBuf,
        /// Cause.
        source: image::ImageError,
    },
    /// Larger than any sensor frame.
    #[error(
        "{}: {width}×{height} px is larger than any sensor frame (at most {MAX_FRAME_SIDE} px a side); not decoded",
        path.display()
    )]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
    },
    /// Not a regular file (a folder, a FIFO, a device): reading it could block or mean
    /// nothing.
    #[error("{}: {kind}, not an image file: give the path of a PNG or JPEG file", path.display())]
    NotAFile {
        /// The path.
        path: PathBuf,
        /// What it is.
        kind: &'static str,
    },
    /// An empty file.
    #[error(
        "{}: an empty file (0 bytes): the image was never written; take or export it again",
        path.display()
    )]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// The bytes end before the image does.
    #[error(
        "{}: the file ends before its pixels do (cut short while written or copied); take or \
         export it again",
        path.display()
    )]
    Truncated {
        /// The file.
        path: PathBuf,
    },
    /// A colour type or bit depth this use cannot read.
    #[error("{}: {found} image, but {need}", path.display())]
    Colour {
        /// The file.
        path: PathBuf,
        /// What the file holds.
        found: String,
        /// What was needed and how to get it.
        need: &'static str,
    },
}

/// Plain words for a colour type.
fn describe(c: ColorType) -> String {
    let bits = c.bits_per_pixel() / u16::from(c.channel_count());
    let kind = match c.channel_count() {
        1 => "grey",
        2 => "grey+alpha",
        3 => "RGB",
        _ => "RGBA",
    };
    format!("a {bits}-bit {kind}")
}

/// Whether `need` can use an image of colour type `c`; the hint when not.
fn check(c: ColorType, need: Need) -> Result<(), &'static str> {
    match (need, c) {
        (Need::Colour, ColorType::Rgb8 | ColorType::Rgba8) => Ok(()),
        (Need::Colour, ColorType::L8 | ColorType::La8) => Err(
            "tactile frames must be 8-bit colour (RGB): the pipeline tells the LED strips apart by colour, which a grey image has lost",
        ),
        (Need::Colour, _) => Err(
            "tactile frames must be 8 bits per channel (RGB), as the camera delivers them; convert without rescaling, or record them with `stereotac record`",
        ),
        (Need::Grey, ColorType::L8 | ColorType::La8 | ColorType::Rgb8 | ColorType::Rgba8) => Ok(()),
        (Need::Grey, _) => {
            Err("stereo images must be 8 bits per channel (grey or RGB); convert to 8 bits first")
        }
    }
}

/// Bytes of a PNG up to its colour type (signature, the IHDR chunk's length and name,
/// width, height, bit depth, colour type).
const PNG_HEAD: usize = 26;

/// Whether `head` (a file's first bytes) starts a PNG whose pixels are palette indices.
fn png_indexed(head: &[u8]) -> bool {
    head.len() >= PNG_HEAD
        && head.starts_with(b"\x89PNG\r\n\x1a\n")
        && &head[12..16] == b"IHDR"
        && head[25] == 3
}

/// Refuses an indexed PNG for tactile frames: a palette keeps at most 256 colours, which
/// the decoder expands to RGB without a word, and the skin's shading read from so few
/// colours is wrong. Grey stereo images are often stored losslessly as palettes, so they
/// pass.
fn refuse_indexed(head: &[u8], path: &Path, need: Need) -> Result<(), ImageFileError> {
    if need == Need::Colour && png_indexed(head) {
        return Err(ImageFileError::Colour {
            path: path.to_path_buf(),
            found: "an indexed (palette) PNG".to_string(),
            need: "tactile frames must keep every pixel's own 8-bit colour (RGB): a palette holds at most 256 colours, too few for the skin's shading; save it as RGB without reducing its colours",
        });
    }
    Ok(())
}

/// A decoding error, said as a file cut short where the bytes ran out.
fn decode_error(path: &Path) -> impl Fn(image::ImageError) -> ImageFileError + '_ {
    move |source| match &source {
        image::ImageError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            ImageFileError::Truncated {
                path: path.to_path_buf(),
            }
        }
        _ => ImageFileError::Decode {
            path: path.to_path_buf(),
            source,
        },
    }
}

fn limits() -> Limits {
    let mut l = Limits::default();
    l.max_image_width = Some(MAX_FRAME_SIDE as u32);
    l.max_image_height = Some(MAX_FRAME_SIDE as u32);
    l.max_alloc = Some(MAX_IMAGE_ALLOC);
    l
}

/// Bounds while the header is read: no size limit (our own check names the size), and
/// [`MAX_IMAGE_HEADER_ALLOC`] for what comes before the pixels.
fn header_limits() -> Limits {
    let mut l = Limits::no_limits();
    l.max_alloc = Some(MAX_IMAGE_HEADER_ALLOC);
    l
}

/// The decoder of `reader` once its header passed the checks; `path` names the source in
/// errors.
fn checked_decoder<'a, R: BufRead + Seek + 'a>(
    mut reader: ImageReader<R>,
    path: &Path,
    need: Need,
) -> Result<impl ImageDecoder + 'a, ImageFileError> {
    reader.limits(header_limits());
    let decoder = reader.into_decoder().map_err(decode_error(path))?;
    let (width, height) = decoder.dimensions();
    let side = 1..=MAX_FRAME_SIDE as u32;
    if !side.contains(&width) || !side.contains(&height) {
        return Err(ImageFileError::TooLarge {
            path: path.to_path_buf(),
            width,
            height,
        });
    }
    let colour = decoder.color_type();
    check(colour, need).map_err(|need| ImageFileError::Colour {
        path: path.to_path_buf(),
        found: describe(colour),
        need,
    })?;
    Ok(decoder)
}

/// Decodes from `reader` after checking the header; `path` names the source in errors.
fn decode<R: BufRead + Seek>(
    reader: ImageReader<R>,
    path: &Path,
    need: Need,
) -> Result<DynamicImage, ImageFileError> {
    let mut decoder = checked_decoder(reader, path, need)?;
    decoder.set_limits(limits()).map_err(decode_error(path))?;
    DynamicImage::from_decoder(decoder).map_err(decode_error(path))
}

/// Opens an image file for `need`: a regular file with bytes in it (a FIFO would block
/// the read), not an indexed PNG where colour is needed.
fn open(
    path: &Path,
    need: Need,
) -> Result<ImageReader<std::io::BufReader<std::fs::File>>, ImageFileError> {
    use std::io::Read;
    let io = |source| ImageFileError::Io {
        path: path.to_path_buf(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(ImageFileError::NotAFile {
            path: path.to_path_buf(),
            kind: if meta.is_dir() {
                "a folder"
            } else {
                "a special file (a FIFO, a socket or a device)"
            },
        });
    }
    if meta.len() == 0 {
        return Err(ImageFileError::Empty {
            path: path.to_path_buf(),
        });
    }
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut head = Vec::with_capacity(PNG_HEAD);
    (&mut file)
        .take(PNG_HEAD as u64)
        .read_to_end(&mut head)
        .map_err(io)?;
    refuse_indexed(&head, path, need)?;
    file.rewind().map_err(io)?;
    ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(io)
}

/// Reads an image file for `need`, within the bounds above.
pub fn read(path: &Path, need: Need) -> Result<DynamicImage, ImageFileError> {
    decode(open(path, need)?, path, need)
}

/// The size `(width, height)` an image file declares, after the same checks as [`read`]
/// and without decoding a pixel: to compare files before paying for them.
pub fn header(path: &Path, need: Need) -> Result<(u32, u32), ImageFileError> {
    Ok(checked_decoder(open(path, need)?, path, need)?.dimensions())
}

/// Reads an 8-bit colour image (tactile frames).
pub fn read_rgb(path: &Path) -> Result<RgbImage, ImageFileError> {
    Ok(read(path, Need::Colour)?.into_rgb8())
}

/// Decodes image bytes of a known format for `need`; `name` says where they came from.
pub fn decode_bytes(
    name: &str,
    bytes: &[u8],
    format: ImageFormat,
    need: Need,
) -> Result<DynamicImage, ImageFileError> {
    let path = Path::new(name);
    if format == ImageFormat::Png {
        refuse_indexed(bytes, path, need)?;
    }
    let mut reader = ImageReader::new(Cursor::new(bytes));
    reader.set_format(format);
    decode(reader, path, need)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(img: &DynamicImage) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, ImageFormat::Png).unwrap();
        out.into_inner()
    }

    #[test]
    fn colour_and_grey_uses_accept_and_refuse_what_they_should() {
        let rgb = DynamicImage::ImageRgb8(RgbImage::new(8, 6));
        let grey = DynamicImage::ImageLuma8(image::GrayImage::new(8, 6));
        let deep = DynamicImage::ImageRgb16(image::ImageBuffer::new(8, 6));
        let d = |img: &DynamicImage, need| decode_bytes("x.png", &png(img), ImageFormat::Png, need);
        assert_eq!(d(&rgb, Need::Colour).unwrap().width(), 8);
        assert_eq!(d(&grey, Need::Grey).unwrap().width(), 8);
        assert_eq!(d(&rgb, Need::Grey).unwrap().width(), 8);
        let e = d(&grey, Need::Colour).unwrap_err().to_string();
        assert!(
            e.contains("x.png: a 8-bit grey image") && e.contains("colour"),
            "{e}"
        );
        let e = d(&deep, Need::Colour).unwrap_err().to_string();
        assert!(e.contains("16-bit RGB") && e.contains("8 bits"), "{e}");
        assert!(matches!(
            d(&deep, Need::Grey),
            Err(ImageFileError::Colour { .. })
        ));
    }

    #[test]
    fn an_image_larger_than_any_frame_is_refused_from_its_header() {
        // A valid PNG header declaring 100000×100000 px, with no pixel data: refused
        // before decoding allocates anything.
        let mut bytes = png(&DynamicImage::ImageRgb8(RgbImage::new(1, 1)));
        bytes[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        bytes[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        // The header's CRC covers the size: recompute it so only the size is wrong.
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&bytes[12..29]);
        bytes[29..33].copy_from_slice(&crc.to_be_bytes());
        let e = decode_bytes("big.png", &bytes, ImageFormat::Png, Need::Colour).unwrap_err();
        assert!(
            matches!(e, ImageFileError::TooLarge { width: 100_000, .. }),
            "{e}"
        );
        let e = decode_bytes("junk.png", b"not a png", ImageFormat::Png, Need::Grey);
        assert!(matches!(e, Err(ImageFileError::Decode { .. })));
    }

    /// A PNG of `img` carrying a colour profile of `profile_bytes` zeros.
    fn png_with_profile(img: &RgbImage, profile_bytes: usize) -> Vec<u8> {
        use image::ImageEncoder;
        let mut out = Vec::new();
        let mut encoder = image::codecs::png::PngEncoder::new(&mut out);
        encoder.set_icc_profile(vec![0; profile_bytes]).unwrap();
        encoder
            .write_image(
                img.as_raw(),
                img.width(),
                img.height(),
                image::ExtendedColorType::Rgb8,
            )
            .unwrap();
        out
    }

    #[test]
    fn what_comes_before_the_pixels_is_bounded_and_the_pixels_are_not() {
        let small = RgbImage::from_pixel(16, 12, image::Rgb([10, 20, 30]));
        // A camera's profile is read with the header; one that expands past the header's
        // bound is dropped instead of allocated (a 2 MB file held a 2 GiB profile).
        for (profile, kept) in [(4096, true), (MAX_IMAGE_HEADER_ALLOC as usize + 1, false)] {
            let bytes = png_with_profile(&small, profile);
            let reader = || {
                let mut r = ImageReader::new(Cursor::new(&bytes[..]));
                r.set_format(ImageFormat::Png);
                r
            };
            let mut decoder = checked_decoder(reader(), Path::new("p.png"), Need::Colour).unwrap();
            let read = decoder.icc_profile().unwrap().map(|p| p.len());
            assert_eq!(read.is_some(), kept, "{profile}: {read:?}");
            let img = decode(reader(), Path::new("p.png"), Need::Colour).unwrap();
            assert_eq!(img.into_rgb8(), small);
        }
        // The pixels themselves may take far more than the header's bound.
        let (w, h) = (4096u32, MAX_IMAGE_HEADER_ALLOC as u32 / 4096 / 3 + 64);
        let big = DynamicImage::ImageRgb8(RgbImage::new(w, h));
        let img = decode_bytes("big.png", &png(&big), ImageFormat::Png, Need::Colour).unwrap();
        assert_eq!((img.width(), img.height()), (w, h));
    }

    /// A PNG whose pixels are indices into a palette of `colours`, written by hand
    /// (zlib's stored blocks: no compressor needed).
    fn indexed_png(colours: &[[u8; 3]], w: u32, h: u32) -> Vec<u8> {
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut chunk = |name: &[u8], data: &[u8]| {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let start = out.len();
            out.extend_from_slice(name);
            out.extend_from_slice(data);
            let sum = crc.checksum(&out[start..]);
            out.extend_from_slice(&sum.to_be_bytes());
        };
        let mut ihdr = [w.to_be_bytes(), h.to_be_bytes()].concat();
        ihdr.extend_from_slice(&[8, 3, 0, 0, 0]);
        chunk(b"IHDR", &ihdr);
        chunk(b"PLTE", &colours.concat());
        // Each row: filter type 0, then one index per pixel.
        let raw: Vec<u8> = (0..h)
            .flat_map(|_| {
                std::iter::once(0).chain((0..w).map(|x| (x as usize % colours.len()) as u8))
            })
            .collect();
        let (mut a, mut b) = (1u32, 0u32);
        for &byte in &raw {
            a = (a + u32::from(byte)) % 65521;
            b = (b + a) % 65521;
        }
        let len = raw.len() as u16;
        let mut zlib = vec![0x78, 0x01, 0x01];
        zlib.extend_from_slice(&len.to_le_bytes());
        zlib.extend_from_slice(&(!len).to_le_bytes());
        zlib.extend_from_slice(&raw);
        zlib.extend_from_slice(&((b << 16) | a).to_be_bytes());
        chunk(b"IDAT", &zlib);
        chunk(b"IEND", &[]);
        out
    }

    /// An indexed PNG is refused for tactile frames (the decoder would expand it to RGB
    /// without a word) and read for stereo; a file cut short is said to be one.
    #[test]
    fn palettes_are_refused_for_colour_and_cut_files_are_named() {
        let bytes = indexed_png(&[[200, 30, 120], [90, 40, 180]], 8, 6);
        let e = decode_bytes("p.png", &bytes, ImageFormat::Png, Need::Colour).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("p.png: an indexed (palette) PNG") && text.contains("save it as RGB"),
            "{text}"
        );
        let grey = decode_bytes("p.png", &bytes, ImageFormat::Png, Need::Grey).unwrap();
        assert_eq!(grey.width(), 8);
        let whole = png(&DynamicImage::ImageRgb8(RgbImage::from_pixel(
            64,
            48,
            image::Rgb([1, 2, 3]),
        )));
        let cut = &whole[..whole.len() - 20];
        let e = decode_bytes("cut.png", cut, ImageFormat::Png, Need::Colour).unwrap_err();
        assert!(matches!(e, ImageFileError::Truncated { .. }), "{e}");
        assert!(e.to_string().contains("ends before its pixels"), "{e}");
    }

    /// Files that are not images are refused before a byte is read: an empty one, a
    /// folder, and a FIFO (whose read would block until someone writes to it).
    #[test]
    fn empty_files_folders_and_fifos_are_refused_by_what_they_are() {
        let dir = std::env::temp_dir().join(format!("stereotac-notfile-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let empty = dir.join("empty.png");
        std::fs::write(&empty, b"").unwrap();
        let e = read(&empty, Need::Colour).unwrap_err();
        assert!(matches!(e, ImageFileError::Empty { .. }), "{e}");
        let e = read(&dir, Need::Grey).unwrap_err().to_string();
        assert!(e.contains("a folder, not an image file"), "{e}");
        #[cfg(unix)]
        {
            let fifo = dir.join("fifo.png");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.is_ok_and(|s| s.success()) {
                let e = header(&fifo, Need::Colour).unwrap_err().to_string();
                assert!(e.contains("a special file"), "{e}");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_header_alone_gives_the_size_after_the_same_checks() {
        let dir = std::env::temp_dir().join(format!("stereotac-header-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (rgb, grey) = (dir.join("rgb.png"), dir.join("grey.png"));
        RgbImage::new(40, 30).save(&rgb).unwrap();
        image::GrayImage::new(40, 30).save(&grey).unwrap();
        assert_eq!(header(&rgb, Need::Colour).unwrap(), (40, 30));
        assert_eq!(header(&grey, Need::Grey).unwrap(), (40, 30));
        assert!(matches!(
            header(&grey, Need::Colour),
            Err(ImageFileError::Colour { .. })
        ));
        assert!(matches!(
            header(&dir.join("none.png"), Need::Colour),
            Err(ImageFileError::Io { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
