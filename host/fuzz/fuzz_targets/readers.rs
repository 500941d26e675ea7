//! The host's file readers on arbitrary bytes: the first byte picks the reader, the rest
//! is the file. None may panic, hang or allocate beyond the documented bounds
//! (`stereotac::limits`); whatever one accepts must be usable (a model that loads builds
//! a reconstructor, a calibration that loads is a plausible rig, an accepted UF2 has
//! whole blocks).
#![no_main]

use image::ImageFormat;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

use stereotac::image_file::{Need, decode_bytes};
use stereotac::output::parse_npy;
use stereotac::stereo::{LengthUnit, StereoCalibration};
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;
use stereotac::uf2::{FirmwareImage, check_uf2};

fuzz_target!(|data: &[u8]| {
    let Some((&which, file)) = data.split_first() else {
        return;
    };
    let text = String::from_utf8_lossy(file);
    match which % 8 {
        0 => {
            if let Ok(c) = StereoCalibration::from_opencv_yaml_in("c.yaml", &text, LengthUnit::Mm) {
                assert!(c.baseline().is_finite() && c.baseline() > 0.0);
            }
        }
        1 => {
            // A ROS pair: the bytes split at the first NUL (or in half).
            let cut = file.iter().position(|&b| b == 0).unwrap_or(file.len() / 2);
            let left = String::from_utf8_lossy(&file[..cut]);
            let right = String::from_utf8_lossy(file.get(cut + 1..).unwrap_or_default());
            if let Ok(c) = StereoCalibration::from_ros_pair(("l.yaml", &left), ("r.yaml", &right)) {
                assert!(c.baseline().is_finite() && c.baseline() > 0.0);
            }
        }
        2 => {
            // A model that loads is checked: it must build a reconstructor (up to a
            // megapixel, to keep the fuzzer's memory small; the size bound itself is
            // `MAX_FRAME_SIDE`, checked on load).
            if let Ok(model) = TactileModel::from_json("m.json", file)
                && model.width * model.height <= 1 << 20
            {
                let built = Reconstructor::new(model, ModelKind::Lut, SolverKind::Dct, None);
                assert!(built.is_ok(), "{:?}", built.err());
            }
        }
        3 | 4 => {
            let need = if which % 8 == 3 {
                Need::Colour
            } else {
                Need::Grey
            };
            if let Ok(img) = decode_bytes("f.png", file, ImageFormat::Png, need) {
                assert!(img.width() >= 1 && img.height() >= 1);
            }
        }
        5 => {
            if let Ok(image) = FirmwareImage::parse(file) {
                let uf2 = image.to_uf2();
                assert_eq!(uf2.len() % 512, 0);
                assert!(check_uf2(&uf2).is_ok());
            }
        }
        6 => {
            if let Ok(blocks) = check_uf2(file) {
                assert_eq!(blocks * 512, file.len());
            }
        }
        _ => {
            if let Ok(grid) = parse_npy(Path::new("a.npy"), file) {
                assert_eq!(grid.as_slice().len(), grid.width() * grid.height());
            }
        }
    }
});
