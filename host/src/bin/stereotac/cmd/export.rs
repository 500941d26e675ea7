//! `stereotac export`: a recording's pairs as image files, for people who want files:
//! camera 0's dx/dy pairs as `NAME_dx.png` / `NAME_dy.png` (what `calibrate` and
//! `reconstruct` read) and dark stereo pairs as `NAME_left.png` / `NAME_right.png`
//! (what `stereo` reads), NAME being the phase index of the pair's first frame.

use std::path::{Path, PathBuf};
use stereotac::out_dir::{OutDir, Replace};

use anyhow::{Context, Result, bail};
use image::RgbImage;
use stereotac::live::replay::{RecordedPair, pairs};

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
    let truncated = pairs(&a.recording, |pair| -> Result<()> {
        match pair {
            RecordedPair::Gradient { name, dx, dy, dark } => {
                write_new(&a.pairs.join(format!("{name}_dx.png")), &dx)?;
                write_new(&a.pairs.join(format!("{name}_dy.png")), &dy)?;
                if let Some(dark) = dark {
                    write_new(&a.pairs.join(format!("{name}_dark.png")), &dark)?;
                }
                gradient += 1;
            }
            RecordedPair::Stereo { name, left, right } => {
                write_new(&a.pairs.join(format!("{name}_left.png")), &left)?;
                write_new(&a.pairs.join(format!("{name}_right.png")), &right)?;
                stereo += 1;
            }
        }
        progress.set_message(format!("{gradient} dx/dy pairs, {stereo} stereo pairs"));
        Ok(())
    })
    .with_context(|| format!("exporting {}", a.recording.display()))?;
    progress.finish_and_clear();
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
    out.keep();
    println!(
        "wrote {gradient} dx/dy pairs and {stereo} stereo pairs to {}",
        a.pairs.display()
    );
    Ok(())
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
