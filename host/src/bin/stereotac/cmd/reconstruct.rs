//! `stereotac reconstruct`: the depth of one dx/dy pair into `depth.npy`, PNGs, PLY and
//! `summary.json`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use stereotac::out_dir::{OutDir, Replace};
use stereotac::picture::RangeChoice;
use stereotac::tactile::ambient::{AmbientSource, PhaseFrames};
use stereotac::tactile::images::{load_references, load_rgb};
use stereotac::tactile::model::{ModelKind, TactileModel};
use stereotac::tactile::output;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::Reconstructor;

/// `stereotac reconstruct`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Model file from `calibrate`.
    #[arg(long)]
    pub model: PathBuf,
    /// dx image (strips 1 and 3 lit).
    #[arg(long)]
    pub dx: PathBuf,
    /// dy image (strips 2 and 4 lit).
    #[arg(long)]
    pub dy: PathBuf,
    /// LEDs-off image taken with them: its ambient light is removed when the model was
    /// calibrated with LEDs-off frames (otherwise the model's own estimate is).
    #[arg(long)]
    pub dark: Option<PathBuf>,
    /// No-contact dx frame (otherwise the model's background).
    #[arg(long, requires = "ref_dy")]
    pub ref_dx: Option<PathBuf>,
    /// No-contact dy frame.
    #[arg(long, requires = "ref_dx")]
    pub ref_dy: Option<PathBuf>,
    /// LEDs-off frame taken with the no-contact frames.
    #[arg(long, requires = "ref_dx")]
    pub ref_dark: Option<PathBuf>,
    /// Output directory (created; one with files in it is refused unless --force).
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Write into an output directory that already has files in it.
    #[arg(long)]
    pub force: bool,
    /// Poisson solver: dct (Neumann, default) or dst (Dirichlet).
    #[arg(long, default_value = "dct")]
    pub solver: SolverKind,
    /// Gradient model: lut (default), mlp, light or photometric (each only with a model
    /// file that holds it; a missing one is named).
    #[arg(long = "model-kind", default_value = "lut")]
    pub model_kind: ModelKind,
    /// Keep the model's slopes (lookup table or perceptron) where they reach the
    /// calibration's limit. By default the model file's light model reads steeper walls
    /// there (summary.json's past_reach_pixels counts them); turn it off for a skin where
    /// that over-reads.
    #[arg(long)]
    pub no_past_reach: bool,
    /// Range of depth_colour.png, mm: `LO,HI` (to compare pictures), or `auto` (default:
    /// flat skin to the deepest point, at least 0.5 mm). The range is in the picture's
    /// legend and summary.json.
    #[arg(long, allow_hyphen_values = true, value_name = "auto|LO,HI", value_parser = parse_colour_range)]
    pub colour_range: Option<RangeChoice>,
    /// Also write the depth map as a mesh (depth_mesh.ply: triangles between
    /// neighbouring pixels).
    #[arg(long)]
    pub mesh: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> Result<()> {
    let out = OutDir::prepare(&a.out_dir, Replace::force_if(a.force))?;
    let model = TactileModel::load(&a.model)?;
    let px_per_mm = model.px_per_mm;
    let refs = load_references(a.ref_dx.as_deref(), a.ref_dy.as_deref())?;
    let ref_dark = a.ref_dark.as_deref().map(load_rgb).transpose()?;
    let (dx, dy) = (load_rgb(&a.dx)?, load_rgb(&a.dy)?);
    let dark = a.dark.as_deref().map(load_rgb).transpose()?;
    // Said at the end (and in summary.json), with the outputs' own.
    let mut warnings = Vec::new();
    for path in [&a.dark, &a.ref_dark].into_iter().flatten() {
        if model.ambient.is_none() {
            warnings.push(format!(
                "{} not used: the model was calibrated without LEDs-off frames (calibrate \
                 with NAME_dark.png files to use them)",
                path.display()
            ));
        }
    }
    let mut rec = Reconstructor::new(
        model,
        a.model_kind,
        a.solver,
        refs.as_ref().map(|(dx, dy)| PhaseFrames {
            dx,
            dy,
            dark: ref_dark.as_ref(),
        }),
    )
    .with_context(|| match (&a.ref_dx, &a.ref_dy) {
        (Some(dx), Some(dy)) => format!(
            "--model {} with the reference frames --ref-dx {} / --ref-dy {}",
            a.model.display(),
            dx.display(),
            dy.display()
        ),
        _ => format!("--model {}", a.model.display()),
    })?;
    rec.set_past_reach(!a.no_past_reach);
    let r = rec
        .reconstruct_frames(PhaseFrames {
            dx: &dx,
            dy: &dy,
            dark: dark.as_ref(),
        })
        .and_then(|r| r.require_lit())
        .with_context(|| format!("{} / {}: nothing written", a.dx.display(), a.dy.display()))?;
    if let (Some(path), AmbientSource::CalibrationDarkRefused) = (&a.dark, r.ambient) {
        warnings.push(format!(
            "{} not used: it is brighter than the lit frames in more than 5 % of its values, \
             so it is not their LEDs-off frame (another exposure, gain or camera); the \
             calibration's ambient light was removed instead",
            path.display()
        ));
    }
    // `auto` is the tactile default (percentiles of a mostly flat map would show nothing).
    let range = a.colour_range.filter(|c| *c != RangeChoice::AUTO);
    let written = output::write_all(out.path(), &r, px_per_mm, range, warnings)?;
    for w in &written.warnings {
        eprintln!("warning: {w}");
    }
    let mesh = out.path().join("depth_mesh.ply");
    if a.mesh {
        output::write_mesh(&mesh, &r.depth_mm, px_per_mm)?;
    } else if mesh.exists() {
        // Replaced outputs (--force) form one set: an earlier run's mesh of another pair
        // would sit beside this pair's depth as if it were its own.
        std::fs::remove_file(&mesh)
            .with_context(|| format!("removing the earlier run's {}", mesh.display()))?;
    }
    out.keep();
    let summary = &written.summary;
    if a.json {
        // What summary.json holds.
        println!("{}", serde_json::to_string_pretty(&written)?);
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

/// `--colour-range`: `auto` or `LO,HI` ([`RangeChoice::parse`]), never another flag.
fn parse_colour_range(text: &str) -> Result<RangeChoice, String> {
    crate::args::not_a_flag(text, "auto or LO,HI")?;
    RangeChoice::parse(text)
}
