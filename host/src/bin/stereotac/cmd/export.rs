//! `stereotac export`: a recording's pairs as image files, for people who want files:
//! camera 0's dx/dy pairs as `NAME_dx.png` / `NAME_dy.png` (what `calibrate` and
//! `reconstruct` read) and dark stereo pairs as `NAME_left.png` / `NAME_right.png`
//! (what `stereo` reads), NAME being the phase index of the pair's first frame; with
//! them, what the recording holds to read them: its stereo calibration
//! (`stereo_calibration.yaml`, for `stereo --calib`) and its tactile model
//! (`tactile_model.json`, for `reconstruct --model`).

use std::path::{Path, PathBuf};
use stereotac::out_dir::{OutDir, Replace};

use anyhow::{Context, Result, bail};
use image::RgbImage;
use stereotac::live::replay::{RecordedPair, pairs};
use stereotac::recording::{reader, topics};
use stereotac::stereo::calibration::StereoCalibration;
use stereotac::tactile::model::TactileModel;

use crate::progress::spinner;

/// `stereotac export`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recording (MCAP).
    pub recording: PathBuf,
    /// Directory to write the pairs into (created; one with files in it only with
    /// --force; existing files are never overwritten).
    #[arg(long, value_name = "DIR")]
    pub pairs: PathBuf,
    /// Write into a directory that already has files (existing files are still never
    /// overwritten: pairs of two recordings in one folder are read as one set by
    /// `calibrate` and `reconstruct`).
    #[arg(long)]
    pub force: bool,
}

pub fn run(a: Args) -> Result<()> {
    // A folder with files in it only with --force: another recording's pairs beside
    // these would be read as one set of presses or frames (and the export would stop at
    // the first name both share, half written). Existing files are never replaced (each
    // is created new); a folder this run made goes again if the export fails.
    let out = OutDir::prepare(&a.pairs, Replace::force_if(a.force))?;
    let progress = spinner("exporting");
    let (mut gradient, mut stereo) = (0u64, 0u64);
    // What this run wrote, taken back if it fails: in a folder forced into, half an
    // export beside the files there would be read as one set with them.
    let mut written: Vec<PathBuf> = Vec::new();
    let mut write = |name: String, img: &RgbImage| -> Result<()> {
        let path = a.pairs.join(name);
        write_new(&path, img)?;
        written.push(path);
        Ok(())
    };
    let exported = pairs(&a.recording, |pair| -> Result<()> {
        match pair {
            RecordedPair::Gradient { name, dx, dy, dark } => {
                write(format!("{name}_dx.png"), &dx)?;
                write(format!("{name}_dy.png"), &dy)?;
                if let Some(dark) = dark {
                    write(format!("{name}_dark.png"), &dark)?;
                }
                gradient += 1;
            }
            RecordedPair::Stereo { name, left, right } => {
                write(format!("{name}_left.png"), &left)?;
                write(format!("{name}_right.png"), &right)?;
                stereo += 1;
            }
        }
        progress.set_message(format!("{gradient} dx/dy pairs, {stereo} stereo pairs"));
        Ok(())
    })
    .with_context(|| format!("exporting {}", a.recording.display()));
    progress.finish_and_clear();
    if exported.is_err() || gradient + stereo == 0 {
        for path in &written {
            let _ = std::fs::remove_file(path);
        }
    }
    let truncated = exported?;
    if let Some(why) = truncated {
        eprintln!("warning: {}: {why}", a.recording.display());
    }
    if gradient + stereo == 0 {
        bail!(
            "{}: no dx/dy pairs (camera 0, --mode gradient or interleaved) and no stereo pairs \
             (two cameras, --mode vision or interleaved) in this recording",
            a.recording.display()
        );
    }
    // The pairs are written: from here on nothing takes them back.
    out.keep();
    // The attachments come with the header: read once, for both. A header that does not
    // read, or an attachment that cannot be written, costs that attachment, not the
    // export.
    let header = reader::header(&a.recording)
        .map_err(|e| {
            eprintln!(
                "warning: {}: its attachments (stereo calibration, tactile model) could not \
                 be read, the pairs are written without them: {e}",
                a.recording.display()
            )
        })
        .ok();
    let mut with = Vec::new();
    for (attachment, wanted, what) in [
        (
            topics::CALIBRATION_ATTACHMENT,
            stereo > 0,
            "stereo calibration",
        ),
        (topics::MODEL_ATTACHMENT, gradient > 0, "tactile model"),
    ] {
        let Some(header) = header.as_ref().filter(|_| wanted) else {
            continue;
        };
        if write_attachment(&a.recording, header, &a.pairs, attachment, what) {
            with.push(attachment);
        }
    }
    println!(
        "wrote {gradient} dx/dy pairs and {stereo} stereo pairs to {}{}",
        a.pairs.display(),
        if with.is_empty() {
            String::new()
        } else {
            format!(", with {}", with.join(" and "))
        }
    );
    Ok(())
}

/// Writes `recording`'s `attachment` (its `what`, from its `header`) into `dir` when the
/// recording holds one that reads: the exported pairs are of no use without it. Says why
/// when it is not written (a file that cannot be written is a warning too: the pairs
/// are written already); `true` when it is (or the same file is already there).
fn write_attachment(
    recording: &Path,
    header: &reader::RecordingHeader,
    dir: &Path,
    attachment: &str,
    what: &str,
) -> bool {
    let rec = recording.display();
    let Some(bytes) = header.attachments.get(attachment) else {
        let needs = match attachment {
            topics::CALIBRATION_ATTACHMENT => "`stereo` on these pairs needs --calib of this rig",
            _ => "`reconstruct` on these pairs needs --model of this sensor",
        };
        eprintln!("note: {rec} holds no {what}: {needs}");
        return false;
    };
    let name = format!("{rec} attachment {attachment}");
    let reads = match attachment {
        topics::CALIBRATION_ATTACHMENT => {
            StereoCalibration::from_opencv_yaml(&name, &String::from_utf8_lossy(bytes))
                .map(|_| ())
                .map_err(anyhow::Error::from)
        }
        _ => TactileModel::from_json(&name, bytes)
            .map(|_| ())
            .map_err(anyhow::Error::from),
    };
    if let Err(e) = reads {
        eprintln!("warning: {what} not written: {e:#}");
        return false;
    }
    let path = dir.join(attachment);
    if path.exists() {
        // Two recordings of one rig exported into one folder hold the same file.
        if std::fs::read(&path).is_ok_and(|there| &there == bytes) {
            return true;
        }
        eprintln!(
            "warning: {what} not written: {} already holds another (files are never \
             overwritten: export into a new directory)",
            path.display()
        );
        return false;
    }
    // Created new, as the pairs are: a file that appeared since is not replaced.
    let created = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&path);
    let written = created.and_then(|mut file| {
        std::io::Write::write_all(&mut file, bytes).inspect_err(|_| {
            // A short file would pass for the attachment in a later export.
            let _ = std::fs::remove_file(&path);
        })
    });
    if let Err(e) = written {
        eprintln!("warning: {what} not written: {}: {e}", path.display());
        return false;
    }
    true
}

/// Writes `img` as PNG to a file that must not exist yet.
fn write_new(path: &Path, img: &RgbImage) -> Result<()> {
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .with_context(|| {
            format!(
                "{}: cannot create it (files are never overwritten: export into a new \
                 directory)",
                path.display()
            )
        })?;
    let mut w = std::io::BufWriter::new(file);
    img.write_to(&mut w, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", path.display()))?;
    // A write error in the last buffered bytes (a full disk) is an error, not a short file.
    w.into_inner()
        .map_err(|e| e.into_error())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
