//! CLI front-ends of the tactile pipeline: `calibrate`, `reconstruct`, `bench tactile`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::progress::bar;
use anyhow::{Context, Result, bail};
use stereotac::tactile::bench::{self, BenchConfig};
use stereotac::tactile::calibrate::{CalibrationProgress, CalibrationSettings, Circle, calibrate};
use stereotac::tactile::images::{load_pairs, load_rgb};
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::output;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;

fn references(
    dx: &Option<PathBuf>,
    dy: &Option<PathBuf>,
) -> Result<Option<(image::RgbImage, image::RgbImage)>> {
    match (dx, dy) {
        (Some(dx), Some(dy)) => Ok(Some((load_rgb(dx)?, load_rgb(dy)?))),
        (None, None) => Ok(None),
        _ => bail!("give both --ref-dx and --ref-dy, or neither"),
    }
}

/// `stereotac calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// Directory of pairs.
    pub dir: PathBuf,
    /// Diameter of the calibration ball.
    #[arg(long)]
    pub ball_diameter_mm: f64,
    /// Image scale.
    #[arg(long, default_value_t = 15.0)]
    pub px_per_mm: f64,
    /// No-contact dx frame (otherwise the per-pixel median of the pairs).
    #[arg(long, requires = "ref_dy")]
    pub ref_dx: Option<PathBuf>,
    /// No-contact dy frame.
    #[arg(long, requires = "ref_dx")]
    pub ref_dy: Option<PathBuf>,
    /// JSON file of contact circles to use instead of fitted ones:
    /// {"NAME": {"cx": px, "cy": px, "r": px}, ...}.
    #[arg(long)]
    pub overrides: Option<PathBuf>,
    /// Model file to write.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn calibrate_cmd(a: CalibrateArgs) -> Result<()> {
    let pairs = load_pairs(&a.dir)?;
    let refs = references(&a.ref_dx, &a.ref_dy)?;
    let overrides: HashMap<String, Circle> = match &a.overrides {
        Some(path) => serde_json::from_slice(
            &std::fs::read(path).with_context(|| format!("reading {}", path.display()))?,
        )
        .with_context(|| {
            format!(
                "{}: expected {{\"NAME\": {{\"cx\": px, \"cy\": px, \"r\": px}}, ...}}",
                path.display()
            )
        })?,
        None => HashMap::new(),
    };
    let settings = CalibrationSettings {
        ball_diameter_mm: a.ball_diameter_mm,
        px_per_mm: a.px_per_mm,
        overrides,
        ..Default::default()
    };
    let epochs = settings.mlp.epochs;
    let progress = bar(
        (pairs.len() + 2 * epochs) as u64,
        "fitting circles, training",
    );
    let result = calibrate(
        &pairs,
        refs.as_ref().map(|(x, y)| (x, y)),
        &settings,
        |p| match p {
            CalibrationProgress::Circles { done, .. } => progress.set_position(done as u64),
            CalibrationProgress::Mlp { axis, epoch, .. } => {
                progress.set_position((pairs.len() + axis * epochs + epoch) as u64)
            }
        },
    );
    progress.finish_and_clear();
    let cal = result?;
    println!(
        "{:<16} {:>8} {:>8} {:>8} {:>9} {:>8}",
        "pair", "cx px", "cy px", "r px", "depth mm", "fit px"
    );
    for p in &cal.presses {
        println!(
            "{:<16} {:>8.1} {:>8.1} {:>8.1} {:>9.3} {:>8}",
            p.name,
            p.circle.cx,
            p.circle.cy,
            p.circle.r,
            p.depth_mm,
            if p.overridden {
                "given".to_string()
            } else {
                format!("{:.2}", p.fit_rms_px)
            }
        );
    }
    let f = cal.model.fit;
    println!(
        "slope RMS: lut {:.4} (held-out {:.4}), mlp {:.4} (held-out {:.4}); {} training / {} held-out pairs, {} samples per axis",
        f.lut_train_rms,
        f.lut_validation_rms,
        f.mlp_train_rms,
        f.mlp_validation_rms,
        f.training_pairs,
        f.validation_pairs,
        f.samples_per_axis
    );
    cal.model.save(&a.out)?;
    println!("wrote {}", a.out.display());
    Ok(())
}

/// `stereotac reconstruct`.
#[derive(Debug, clap::Args)]
pub struct ReconstructArgs {
    /// Model file from `calibrate`.
    #[arg(long)]
    pub model: PathBuf,
    /// dx image (strips 1 and 3 lit).
    #[arg(long)]
    pub dx: PathBuf,
    /// dy image (strips 2 and 4 lit).
    #[arg(long)]
    pub dy: PathBuf,
    /// No-contact dx frame (otherwise the model's background).
    #[arg(long, requires = "ref_dy")]
    pub ref_dx: Option<PathBuf>,
    /// No-contact dy frame.
    #[arg(long, requires = "ref_dx")]
    pub ref_dy: Option<PathBuf>,
    /// Output directory.
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Poisson solver: dct (Neumann, default) or dst (Dirichlet).
    #[arg(long, default_value = "dct")]
    pub solver: SolverKind,
    /// Gradient model: lut (default) or mlp.
    #[arg(long = "model-kind", default_value = "lut")]
    pub model_kind: ModelKind,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn reconstruct_cmd(a: ReconstructArgs) -> Result<()> {
    let model = TactileModel::load(&a.model)?;
    let px_per_mm = model.px_per_mm;
    let refs = references(&a.ref_dx, &a.ref_dy)?;
    let (dx, dy) = (load_rgb(&a.dx)?, load_rgb(&a.dy)?);
    let mut rec = Reconstructor::new(
        model,
        a.model_kind,
        a.solver,
        refs.as_ref().map(|(x, y)| (x, y)),
    )?;
    let r = rec.reconstruct(&dx, &dy)?;
    let summary = output::write_all(&a.out_dir, &r, px_per_mm)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if summary.no_contact {
        println!(
            "no contact ({:.2} ms); outputs in {}",
            summary.timings.total_ms,
            a.out_dir.display()
        );
    } else {
        println!(
            "max depth {:.3} mm at px {:?}, contact {:.1} mm², volume {:.2} mm³, {} region(s), {:.2} ms; outputs in {}",
            summary.max_depth_mm,
            summary.max_depth_at_px,
            summary.contact_area_mm2,
            summary.volume_mm3,
            summary.regions.len(),
            summary.timings.total_ms,
            a.out_dir.display()
        );
    }
    Ok(())
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WxH, got {s:?}"))?;
    let w: usize = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in {s:?}"))?;
    let h: usize = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in {s:?}"))?;
    if !(64..=8192).contains(&w) || !(64..=8192).contains(&h) {
        return Err(format!("size {s:?} out of range (64..8192 per side)"));
    }
    Ok((w, h))
}

pub fn bench_tactile(
    sizes: Vec<(usize, usize)>,
    repeats: usize,
    json: bool,
    json_out: Option<&Path>,
) -> Result<()> {
    let mut config = BenchConfig {
        repeats,
        ..Default::default()
    };
    if !sizes.is_empty() {
        config.sizes = sizes;
    }
    let progress = bar(1, "bench");
    let report = bench::run(&config, &mut |what, done, total| {
        progress.set_message(what.to_string());
        progress.set_length(total as u64);
        progress.set_position(done as u64);
    });
    progress.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", bench::format_table(&report));
    }
    if let Some(path) = json_out {
        std::fs::write(path, serde_json::to_vec_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
