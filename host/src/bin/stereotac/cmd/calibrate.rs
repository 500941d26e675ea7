//! `stereotac calibrate`: the tactile model from ball presses (a directory of
//! `NAME_dx.png` / `NAME_dy.png` pairs, each with an optional LEDs-off `NAME_dark.png`,
//! or a recording's dx/dy pairs), with the fitted circle of each press, the presses set
//! aside and why, and the calibration report. When every press has its LEDs-off frame
//! the model works on LED light alone (see `stereotac::tactile::ambient`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use stereotac::out_dir::{OutDir, Replace, file_in_the_way};
use stereotac::output::{Written, check_replace, same_file, write_atomic};

use anyhow::{Context, Result};
use stereotac::live::replay;
use stereotac::tactile::ambient::PhaseFrames;
use stereotac::tactile::calibrate::{
    Calibration, CalibrationPair, CalibrationProgress, CalibrationSettings, Circle, calibrate,
    overlay, read_overrides,
};
use stereotac::tactile::camera_curve::{self, CameraCurve};
use stereotac::tactile::contact::MAX_THRESHOLD;
use stereotac::tactile::crosstalk::measure as measure_crosstalk;
use stereotac::tactile::images::{ImageError, load_more_pairs, load_references, load_rgb};
use stereotac::tactile::model::side_light::MIN_KAPPA;
use stereotac::tactile::model::validate::{MAX_SCALE, valid_ball_diameter};

use crate::console::naming_file;
use crate::progress::bar;

/// `stereotac calibrate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Directory of NAME_dx.png / NAME_dy.png pairs (with NAME_dark.png, LEDs off, if
    /// taken), or a recording (MCAP file from `record` or `run`): camera 0's dx/dy pairs
    /// and, in interleaved mode, the LEDs-off frame before each.
    pub dir: PathBuf,
    /// Diameter of the calibration ball.
    #[arg(long, allow_negative_numbers = true)]
    pub ball_diameter_mm: f64,
    /// More presses, made with another ball: DIAMETER_MM:PATH, PATH a folder of pairs or
    /// a recording like DIR (repeatable). A ball smaller than --ball-diameter-mm teaches
    /// the steep walls the larger one cannot make (on our evaluation skins a 1.31 wall
    /// read 0.79-1.05 of its depth from an 8 or 6 mm ball alone, 0.84-1.08 with half the
    /// presses of a 4 mm ball). Their names get PATH's name in front (a folder `small`:
    /// `small-press01`).
    #[arg(
        long,
        value_name = "DIAMETER_MM:PATH",
        value_parser = parse_with_ball,
        allow_hyphen_values = true
    )]
    pub with_ball: Vec<(f64, PathBuf)>,
    /// Image scale.
    #[arg(long, allow_negative_numbers = true, default_value_t = 15.0)]
    pub px_per_mm: f64,
    /// Thickness of the sensor's skin, kept in the model: no press goes deeper, so
    /// reconstructions deeper than this are refused (0.1–50).
    #[arg(long, allow_negative_numbers = true, default_value_t = stereotac::tactile::model::DEFAULT_SKIN_THICKNESS_MM)]
    pub skin_thickness_mm: f64,
    /// No-contact dx frame (otherwise the per-pixel median of the pairs).
    #[arg(long, requires = "ref_dy")]
    pub ref_dx: Option<PathBuf>,
    /// No-contact dy frame.
    #[arg(long, requires = "ref_dx")]
    pub ref_dy: Option<PathBuf>,
    /// LEDs-off frame taken with the no-contact frames (used when every press has one).
    #[arg(long, requires = "ref_dx")]
    pub ref_dark: Option<PathBuf>,
    /// No-contact dx frame taken like --ref-dx but with only the blue strip (1) lit
    /// (strip 3 set dark): with --red-only-dx, the camera's colour crosstalk is measured
    /// and undone before any colour is read (a camera whose blue LED light reaches its
    /// red channel otherwise reads slopes near the blue strips too steep).
    #[arg(long, requires_all = ["ref_dx", "red_only_dx"])]
    pub blue_only_dx: Option<PathBuf>,
    /// No-contact frame with all four strips lit in one exposure (`stereotac set --mode
    /// contact`, with `--budget-ma` raised so that the firmware does not dim the strips
    /// when all four are on: dimmed, the frames cannot add up and the curve is measured
    /// wrong), taken like the references: with --ref-dark, the camera's response curve
    /// is measured (light adds up where the camera is linear: all + dark = dx + dy) and
    /// undone on every frame before it is read. A camera that delivers sRGB (most
    /// webcams) otherwise reads steep walls short and may see no contact in genuine
    /// presses; a linear camera measures linear and nothing changes.
    #[arg(long, requires_all = ["ref_dx", "ref_dark"])]
    pub all_lit: Option<PathBuf>,
    /// No-contact dx frame with only the red strip (3) lit (strip 1 set dark).
    #[arg(long, requires_all = ["ref_dx", "blue_only_dx"])]
    pub red_only_dx: Option<PathBuf>,
    /// Measure the strips' side light (strips of finite length light a pixel near their
    /// ends from the side as well, so the other phase's brightness answers this axis'
    /// slope) and teach and read the lookup table with it taken out. Off by default: on
    /// our tuning skins with finite strips it brought steep walls from 0.79-0.86 to
    /// 0.86-0.93 mm, on the independent renderer's glossy skins it over-read the frame
    /// edges more (see the README).
    #[arg(long)]
    pub side_light: bool,
    /// JSON file of contact circles to use instead of fitted ones:
    /// {"NAME": {"cx": px, "cy": px, "r": px}, ...} (a --with-ball press by its name
    /// with the folder's in front: "small-press01").
    #[arg(long)]
    pub overrides: Option<PathBuf>,
    /// Fewest usable presses to calibrate from (presses that cannot be fitted are set
    /// aside with their reason).
    #[arg(long, default_value_t = stereotac::tactile::calibrate::DEFAULT_MIN_PRESSES)]
    pub min_presses: usize,
    /// Use this contact threshold instead of measuring it on the frames' flat skin
    /// (normalised-colour units; flat skin reads 0).
    #[arg(long, allow_negative_numbers = true)]
    pub contact_threshold: Option<f32>,
    /// Write each press's dx image with its fitted circle here (solid green: used,
    /// dashed white: set aside), to check the fits by eye.
    #[arg(long)]
    pub overlays: Option<PathBuf>,
    /// Also write the calibration report (presses, reasons, fit per region, coverage,
    /// warnings) as JSON here (an existing file is kept unless --force).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Model file to write (an existing file is kept unless --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the model file, the report and the overlays' files if they exist.
    #[arg(long)]
    pub force: bool,
}

pub fn run(a: Args) -> Result<()> {
    // Before the work, not after: a model or a report is never replaced by accident.
    for (path, flag) in
        std::iter::once((&a.out, "--out")).chain(a.report.iter().map(|r| (r, "--report")))
    {
        // Not even with --force: a JSON file written over a recording or a frame (the
        // input itself, given as --out by a slip) loses the data.
        let example = if flag == "--out" {
            "model.json"
        } else {
            "report.json"
        };
        let written = Written {
            what: "a model or report",
            flag,
            example,
        };
        check_replace(path, a.force, written)?;
    }
    // A folder the files go into that cannot be made (a file in its place) is said
    // now; missing folders are made once the calibration has succeeded.
    for path in std::iter::once(&a.out).chain(a.report.iter()) {
        if let Some(blocker) = path.parent().and_then(file_in_the_way) {
            anyhow::bail!(
                "{}: {} is a file, not a folder: give a path in a folder",
                path.display(),
                blocker.display()
            );
        }
    }
    if let Some(report) = &a.report {
        anyhow::ensure!(
            !same_file(report, &a.out),
            "--report {} is the model file --out names: give the report a file of its own",
            report.display()
        );
    }
    let overrides: HashMap<String, Circle> = match &a.overrides {
        Some(path) => read_overrides(
            &std::fs::read(path).with_context(|| format!("reading {}", path.display()))?,
        )
        .with_context(|| format!("--overrides {}", path.display()))?,
        None => HashMap::new(),
    };
    let mut settings = CalibrationSettings {
        ball_diameter_mm: a.ball_diameter_mm,
        px_per_mm: a.px_per_mm,
        skin_thickness_mm: a.skin_thickness_mm,
        min_presses: a.min_presses,
        overrides,
        side_light: a.side_light,
        ..Default::default()
    };
    if let Some(t) = a.contact_threshold {
        anyhow::ensure!(
            t.is_finite() && t > 0.0 && t <= MAX_THRESHOLD,
            "--contact-threshold must be a finite positive number of at most {MAX_THRESHOLD} \
             (a block whose LED light falls to almost nothing in both phases departs by about \
             4), got {t}"
        );
        settings.contact.threshold = t;
        settings.fixed_threshold = true;
    }
    settings.check()?;
    let overlays = a
        .overlays
        .as_deref()
        .map(|dir| OutDir::prepare(dir, Replace::force_if(a.force)))
        .transpose()?;
    // The references first: a folder's press of another size is set aside undecoded.
    let refs = load_references(a.ref_dx.as_deref(), a.ref_dy.as_deref())?;
    let ref_dark = a.ref_dark.as_deref().map(load_rgb).transpose()?;
    if let (Some((ref_dx, ref_dy)), Some(all), Some(dark)) = (&refs, &a.all_lit, &ref_dark) {
        let context = || {
            format!(
                "measuring the camera's response curve from --all-lit {} beside --ref-dx, --ref-dy and --ref-dark",
                all.display()
            )
        };
        settings.camera_curve =
            CameraCurve::measure(&load_rgb(all)?, ref_dx, ref_dy, dark).with_context(context)?;
        match &settings.camera_curve {
            Some(c) => eprintln!(
                "camera curve: response exponent {:.2}; undone on every frame before it is read",
                c.gamma
            ),
            None => eprintln!("camera curve: linear (nothing to undo)"),
        }
    }
    // The crosstalk is measured on linear light, as the model reads it.
    let linear = |img| camera_curve::undone(settings.camera_curve.as_ref(), img);
    if let (Some((ref_dx, _)), Some(blue), Some(red)) = (&refs, &a.blue_only_dx, &a.red_only_dx) {
        let context = || {
            format!(
                "measuring the crosstalk from --blue-only-dx {} and --red-only-dx {} beside --ref-dx",
                blue.display(),
                red.display()
            )
        };
        let unmix = measure_crosstalk(
            &linear(ref_dx.clone()),
            &linear(load_rgb(blue)?),
            &linear(load_rgb(red)?),
        )
        .with_context(context)?;
        let (blue_in_red, red_in_blue) = unmix.shares();
        eprintln!(
            "crosstalk: {:.1}% of the blue LED's light in R - G, {:.1}% of the red LED's in B - G; undone before the colours are read",
            100.0 * blue_in_red,
            100.0 * red_in_blue
        );
        settings.filter.unmix = unmix;
    }
    let want = refs.as_ref().map(|(dx, _)| dx.dimensions());
    let (mut pairs, mut unreadable) = load_presses(&a.dir, want, 0)?;
    // Every source's names, for a slip in the overrides file: (source, first names).
    let mut sources = vec![(a.dir.clone(), first_names(&pairs))];
    // The second ball's frames at the first folder's size (an odd one is set aside), and
    // within the bound on a calibration's frames together.
    let want = want.or_else(|| pairs.first().map(|p| p.dx.dimensions()));
    // The same folder or recording given twice would teach each press twice, with two
    // balls: refused.
    let mut read = vec![a.dir.canonicalize().unwrap_or_else(|_| a.dir.clone())];
    for (diameter, path) in &a.with_ball {
        let option = format!("--with-ball {diameter}:{}", path.display());
        let same = path.canonicalize().unwrap_or_else(|_| path.clone());
        if read.contains(&same) {
            anyhow::bail!(
                "{option}: {} is read already (as DIR or in another --with-ball): give each \
                 ball's presses in a folder or recording of their own",
                path.display()
            );
        }
        read.push(same);
        let prefix = source_name(path);
        let decoded = decoded_bytes(&pairs);
        let (more, more_unreadable) =
            load_presses(path, want, decoded).with_context(|| option.clone())?;
        unreadable.extend(
            more_unreadable
                .into_iter()
                .map(|(name, why)| (format!("{prefix}-{name}"), why)),
        );
        let before = pairs.len();
        for mut pair in more {
            pair.name = format!("{prefix}-{}", pair.name);
            pair.ball_diameter_mm = Some(*diameter);
            if let Some(clash) = pairs[..before].iter().find(|p| p.name == pair.name) {
                anyhow::bail!(
                    "--with-ball {diameter}:{}: its press {:?} has the name of a press read \
                     before it ({:?}): give the folders of the balls different names",
                    path.display(),
                    pair.name,
                    clash.name
                );
            }
            pairs.push(pair);
        }
        sources.push((path.clone(), first_names(&pairs[before..])));
    }
    // An override naming no press would change nothing: a slip in the name, said now.
    let mut unknown: Vec<&String> = settings
        .overrides
        .keys()
        .filter(|name| !pairs.iter().any(|p| &&p.name == name))
        .collect();
    unknown.sort();
    if let (Some(first), Some(file)) = (unknown.first(), &a.overrides) {
        let names: Vec<String> = sources
            .iter()
            .map(|(path, names)| format!("{} in {}", names, path.display()))
            .collect();
        anyhow::bail!(
            "{}: no press is named {first:?}{} (the presses are named {})",
            file.display(),
            if unknown.len() > 1 {
                format!(" (nor {} other name(s) there)", unknown.len() - 1)
            } else {
                String::new()
            },
            names.join("; ")
        );
    }
    // A press whose files cannot be read costs that press only: said now (before the
    // work) and again with the presses the calibration sets aside.
    for (name, why) in &unreadable {
        eprintln!("warning: press {name} set aside: {why}");
    }
    let epochs = settings.mlp.epochs;
    let progress = bar(
        (pairs.len() + 2 * epochs) as u64,
        "fitting circles, training",
    );
    let result = calibrate(
        &pairs,
        refs.as_ref().map(|(dx, dy)| PhaseFrames {
            dx,
            dy,
            dark: ref_dark.as_ref(),
        }),
        &settings,
        |p| match p {
            CalibrationProgress::Circles { done, .. } => progress.set_position(done as u64),
            CalibrationProgress::Mlp { axis, epoch, .. } => {
                progress.set_position((pairs.len() + axis * epochs + epoch) as u64)
            }
        },
    );
    progress.finish_and_clear();
    // Too few presses: the error lists those it set aside; the unreadable ones too.
    let unread_list = || {
        unreadable
            .iter()
            .map(|(name, why)| format!("\n  {name}: cannot be read: {why}"))
            .collect::<String>()
    };
    let cal = result.map_err(|e| {
        let few = matches!(
            e,
            stereotac::tactile::calibrate::CalibrationError::TooFewPresses { .. }
        );
        let e = anyhow::Error::from(e);
        let e = if few && !unreadable.is_empty() {
            e.context(format!(
                "{} more press(es) set aside before calibrating:{}",
                unreadable.len(),
                unread_list()
            ))
        } else {
            e
        };
        // Every error names what was calibrated from: a script calibrating many folders
        // otherwise reads "1 pair(s)" without knowing whose.
        let inputs: Vec<String> = sources
            .iter()
            .map(|(path, _)| path.display().to_string())
            .collect();
        e.context(format!("calibrating from {}", inputs.join(" and ")))
    })?;
    // The names' column as wide as the longest (a second ball's names carry its folder's).
    let width = pairs
        .iter()
        .map(|p| p.name.chars().count())
        .max()
        .unwrap_or(0)
        .max(16);
    println!(
        "{:<width$} {:>8} {:>8} {:>8} {:>9} {:>8} {:>7}",
        "pair", "cx px", "cy px", "r px", "depth mm", "fit px", "sat %"
    );
    for p in &cal.presses {
        println!(
            "{:<width$} {:>8.1} {:>8.1} {:>8.1} {:>9.3} {:>8} {:>7.1}",
            p.name,
            p.circle.cx,
            p.circle.cy,
            p.circle.r,
            p.depth_mm,
            if p.overridden {
                "given".to_string()
            } else {
                format!("{:.2}", p.fit_rms_px)
            },
            100.0 * p.saturated[0].max(p.saturated[1])
        );
    }
    for (name, why) in &unreadable {
        println!("{name:<width$} set aside: cannot be read: {why}");
    }
    for r in &cal.rejected {
        println!("{:<width$} set aside: {}", r.name, r.reason);
    }
    let f = cal.model.fit;
    // Without held-out pairs there is no held-out figure (the model stores 0 there).
    let held_out = |v: f32| {
        if f.validation_pairs > 0 {
            format!("{v:.4}")
        } else {
            "n/a".to_string()
        }
    };
    println!(
        "slope RMS: lut {:.4} (held-out {}), mlp {:.4} (held-out {}), light {:.4} (held-out {}), photometric {:.4} (held-out {}{}); {} training / {} held-out pairs, {} samples per axis",
        f.lut_train_rms,
        held_out(f.lut_validation_rms),
        f.mlp_train_rms,
        held_out(f.mlp_validation_rms),
        f.light_train_rms,
        held_out(f.light_validation_rms),
        f.photometric_train_rms,
        held_out(f.photometric_validation_rms),
        if f.validation_pairs > 0 {
            format!(
                " over the {:.0}% it reads",
                100.0 * f.photometric_validation_read
            )
        } else {
            String::new()
        },
        f.training_pairs,
        f.validation_pairs,
        f.samples_per_axis
    );
    let rep = &cal.report;
    println!(
        "contact threshold {:.3}{}; slope RMS per region (LUT, rows top to bottom): {}",
        rep.contact_threshold,
        match (&rep.flat_skin_noise, settings.fixed_threshold) {
            (_, true) => " (given)".to_string(),
            (Some(n), false) => format!(
                " (1.5 × the 99.99th percentile of flat skin's deviation, {} px sampled)",
                n.pixels
            ),
            (None, false) => " (provisional: no flat skin to measure)".to_string(),
        },
        rep.regions
            .chunks(3)
            .map(|row| row
                .iter()
                .map(|r| if r.samples > 0 {
                    format!("{:.3}", r.lut_rms)
                } else {
                    "–".to_string()
                })
                .collect::<Vec<_>>()
                .join(" "))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    if a.side_light {
        match &cal.model.side_light {
            Some(side) => println!(
                "side light of the strips: the other phase's brightness changes by up to {:.2} per unit slope (taken out of the lookup table's colours)",
                side.largest()
            ),
            None => println!(
                "side light of the strips: none measured (under {MIN_KAPPA} per unit slope everywhere, or too few pixels with every strip lit): the model reads as without --side-light"
            ),
        }
    }
    if let Some(photometric) = &cal.model.photometric {
        let r = photometric.response();
        println!(
            "photometric model's response: colour^{:.2} · |n|^{:.2} = the strips' shading (1 and 1: a matte skin seen by a linear camera)",
            r.colour, r.norm
        );
    }
    for w in &rep.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(dir) = overlays {
        write_overlays(dir.path(), &pairs, &cal)?;
        dir.keep();
    }
    for path in std::iter::once(&a.out).chain(a.report.iter()) {
        if let Some(folder) = path.parent().filter(|f| !f.as_os_str().is_empty()) {
            std::fs::create_dir_all(folder)
                .with_context(|| format!("making the folder {}", folder.display()))?;
        }
    }
    if let Some(path) = &a.report {
        let mut report = cal.report_json();
        report["unreadable"] = unreadable
            .iter()
            .map(|(name, why)| serde_json::json!({"name": name, "reason": why.to_string()}))
            .collect();
        write_atomic(path, &serde_json::to_vec_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    cal.model.save(&a.out)?;
    println!("wrote {}", a.out.display());
    Ok(())
}

/// Presses, and the names of those whose files cannot be read with the reason.
type Presses = (Vec<CalibrationPair>, Vec<(String, ImageError)>);

/// The presses at `path`: a recording's pairs, or a folder's pairs and the names of
/// those whose files cannot be read.
fn load_presses(path: &Path, want: Option<(u32, u32)>, decoded: u64) -> Result<Presses> {
    if path.is_file() {
        let pairs = recorded_pairs(path).context(
            "presses are a folder of NAME_dx.png / NAME_dy.png pairs or an MCAP recording",
        )?;
        return Ok((pairs, Vec::new()));
    }
    let folder = load_more_pairs(path, want, decoded).map_err(|e| {
        let e = anyhow::Error::from(e);
        // A `record --png` folder: frames with an index, not named pairs.
        if path.join("index.jsonl").is_file() {
            e.context(format!(
                "{} is a `record --png` folder: calibrate takes NAME_dx.png / NAME_dy.png \
                 pairs or an MCAP recording; record the presses to MCAP (`record --out \
                 presses.mcap`) and give that file, or `export` it to pairs",
                path.display()
            ))
        } else {
            e
        }
    })?;
    Ok((folder.pairs, folder.set_aside))
}

/// The name a `--with-ball` source's presses get in front: a folder's name (all of it:
/// `balls.4mm`), a recording's without its extension.
fn source_name(path: &Path) -> String {
    let path = if path.file_name().is_none() {
        // `.`, `..` or a path ending in them.
        path.canonicalize().unwrap_or_else(|_| path.to_path_buf())
    } else {
        path.to_path_buf()
    };
    let name = if path.is_file() {
        path.file_stem()
    } else {
        path.file_name()
    };
    name.map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "more".to_string())
}

/// The first few names of `pairs`, for a message.
fn first_names(pairs: &[CalibrationPair]) -> String {
    let names: Vec<&str> = pairs.iter().take(3).map(|p| p.name.as_str()).collect();
    format!(
        "{}{}",
        names.join(", "),
        if pairs.len() > 3 { ", …" } else { "" }
    )
}

/// What `pairs`' frames take decoded (bytes).
fn decoded_bytes(pairs: &[CalibrationPair]) -> u64 {
    pairs
        .iter()
        .flat_map(|p| [Some(&p.dx), Some(&p.dy), p.dark.as_ref()])
        .flatten()
        .map(|f| f.as_raw().len() as u64)
        .sum()
}

/// `DIAMETER_MM:PATH` of `--with-ball`.
fn parse_with_ball(s: &str) -> Result<(f64, PathBuf), String> {
    let (d, path) = s
        .split_once(':')
        .ok_or_else(|| format!("expected DIAMETER_MM:PATH (e.g. 4:presses-4mm), got {s:?}"))?;
    let d: f64 = d
        .trim()
        .parse()
        .map_err(|_| format!("{d:?} is not a ball diameter in mm (e.g. 4:presses-4mm)"))?;
    if !valid_ball_diameter(d) {
        return Err(format!(
            "ball diameter {d} mm: give a number above 0 and up to {MAX_SCALE}"
        ));
    }
    if path.is_empty() {
        return Err("no PATH after the diameter (e.g. 4:presses-4mm)".to_string());
    }
    Ok((d, PathBuf::from(path)))
}

/// One overlay image per press: `DIR/NAME.png`.
fn write_overlays(dir: &Path, pairs: &[CalibrationPair], cal: &Calibration) -> Result<()> {
    for pair in pairs {
        let used = cal.presses.iter().find(|p| p.name == pair.name);
        let rejected = cal.rejected.iter().find(|r| r.name == pair.name);
        let circle = used
            .map(|p| p.circle)
            .or_else(|| rejected.and_then(|r| r.circle));
        let image = overlay(&pair.dx, circle.as_ref(), used.is_some());
        let path = dir.join(format!("{}.png", pair.name));
        image
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    println!("wrote {} overlays to {}", pairs.len(), dir.display());
    let older = older_images(dir, pairs);
    if let Some(first) = older.first() {
        eprintln!(
            "warning: {} also holds {} PNG image(s) this run did not write (e.g. {first}): \
             overlays of presses not given now, or other files; remove them or give an \
             empty folder",
            dir.display(),
            older.len()
        );
    }
    Ok(())
}

/// The `.png` files in `dir` that are not the overlay of one of `pairs` (a folder given
/// with `--force` keeps an earlier run's overlays), sorted by name.
fn older_images(dir: &Path, pairs: &[CalibrationPair]) -> Vec<String> {
    let ours: std::collections::HashSet<String> =
        pairs.iter().map(|p| format!("{}.png", p.name)).collect();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut older: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.to_ascii_lowercase().ends_with(".png") && !ours.contains(n))
        .collect();
    older.sort();
    older
}

/// Camera 0's dx/dy pairs of a recording.
fn recorded_pairs(path: &std::path::Path) -> Result<Vec<CalibrationPair>> {
    let mut pairs = Vec::new();
    let truncated = replay::pairs(path, |pair| -> Result<()> {
        if let replay::RecordedPair::Gradient { name, dx, dy, dark } = pair {
            pairs.push(CalibrationPair {
                name,
                dx,
                dy,
                dark,
                ball_diameter_mm: None,
            });
        }
        Ok(())
    })
    .map_err(|e| naming_file(e, "reading", path))?;
    if let Some(why) = truncated {
        eprintln!("warning: {}: {why}", path.display());
    }
    if pairs.is_empty() {
        anyhow::bail!(
            "{}: no dx/dy pairs from camera 0 (record with --mode gradient or interleaved)",
            path.display()
        );
    }
    Ok(pairs)
}
