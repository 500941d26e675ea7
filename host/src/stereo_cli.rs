//! CLI front-ends of the stereo pipeline: `stereo`, `stereo-eval`, `bench stereo`
//! (`stereo-calibrate` is in `calibrate_cli`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use stereotac::output::{
    read_npy, write_false_colour_png, write_npy, write_png16, write_points_ply,
};
use stereotac::stereo::block_match::{BlockMatchParams, BlockMatcher, Kernel, MatchStats};
use stereotac::stereo::eval::{self, SyntheticEval};
use stereotac::stereo::outliers::OutlierParams;
use stereotac::stereo::pipeline::{StereoConfig, StereoFrame, StereoPipeline, StereoTimings};
use stereotac::stereo::postfilter::HoleFill;
use stereotac::stereo::synthetic::{Membrane, Plane, StereoRig, fisheye_calibration, render_pair};
use stereotac::stereo::{Rectification, StereoCalibration};
use stereotac::tactile::bench::median_ms;
use stereotac::tactile::grid::Grid;

use crate::progress::bar;

/// Pipeline settings shared by `stereo` and `stereo-eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct PipelineArgs {
    /// Nearest depth searched, mm.
    #[arg(long, default_value_t = 50.0)]
    pub near_mm: f64,
    /// Farthest depth searched, mm.
    #[arg(long, default_value_t = 600.0)]
    pub far_mm: f64,
    /// Rectified focal length as a share of the cameras' (below 1 keeps more of a wide
    /// lens's field of view).
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// Matching window side (odd).
    #[arg(long, default_value_t = 9)]
    pub block_size: u32,
}

impl PipelineArgs {
    fn config(&self) -> StereoConfig {
        StereoConfig {
            near_mm: self.near_mm,
            far_mm: self.far_mm,
            rectify_scale: self.scale,
            block_size: self.block_size,
            ..StereoConfig::default()
        }
    }
}

/// `stereotac stereo`.
#[derive(Debug, clap::Args)]
pub struct StereoArgs {
    /// Calibration: one OpenCV stereo YAML, or two ROS camera_info YAML (left, then
    /// right). Not needed with --synthetic.
    #[arg(long, num_args = 1, action = clap::ArgAction::Append)]
    pub calib: Vec<PathBuf>,
    /// Left image (8-bit; colour is converted to grey).
    #[arg(long, required_unless_present = "synthetic")]
    pub left: Option<PathBuf>,
    /// Right image.
    #[arg(long, required_unless_present = "synthetic")]
    pub right: Option<PathBuf>,
    /// Use a built-in capture instead: a textured plane this many mm away, tilted, seen
    /// through the skin (its inputs are written to the output directory too).
    #[arg(long, conflicts_with_all = ["left", "right", "calib"])]
    pub synthetic: Option<f64>,
    /// Output directory.
    #[arg(long)]
    pub out_dir: PathBuf,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Turn off the edge-preserving spatial filter.
    #[arg(long)]
    pub no_spatial: bool,
    /// Fill holes up to this many pixels wide along rows (0: off).
    #[arg(long, default_value_t = 0)]
    pub fill_holes: usize,
    /// Statistical outlier removal on the point cloud (Open3D's rule, neighbour
    /// distances scaled by depth). Off by default: on a slanted surface the far side is
    /// sparser and loses points (4 % of a plane tilted 17° in the built-in capture).
    #[arg(long)]
    pub outliers: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `stereo` reports (also written as `summary.json`).
#[derive(Debug, Serialize)]
pub(crate) struct StereoSummary {
    width: usize,
    height: usize,
    focal_px: f64,
    baseline_mm: f64,
    disparity_range_px: [u32; 2],
    kernel: Kernel,
    stats: MatchStats,
    pub(crate) fill_rate: f64,
    pub(crate) points: usize,
    outliers_removed: usize,
    holes_filled: usize,
    depth_mm: Option<[f32; 3]>,
    timings: StereoTimings,
    files: Vec<&'static str>,
}

pub(crate) fn load_grey(path: &Path) -> Result<Grid<u8>> {
    let img = image::open(path)
        .with_context(|| format!("reading {}", path.display()))?
        .into_luma8();
    let (w, h) = img.dimensions();
    Ok(Grid::from_vec(w as usize, h as usize, img.into_raw()).expect("size matches"))
}

pub(crate) fn save_grey(path: &Path, g: &Grid<u8>) -> Result<()> {
    image::GrayImage::from_raw(g.width() as u32, g.height() as u32, g.as_slice().to_vec())
        .expect("size matches")
        .save(path)
        .with_context(|| format!("writing {}", path.display()))
}

fn read_text(path: &Path) -> Result<(String, String)> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    Ok((path.display().to_string(), text))
}

/// Reads one OpenCV stereo file or a ROS left/right pair.
pub fn load_calibration(files: &[PathBuf]) -> Result<StereoCalibration> {
    match files {
        [one] => {
            let (name, text) = read_text(one)?;
            Ok(StereoCalibration::from_opencv_yaml(&name, &text)?)
        }
        [left, right] => {
            let (l, r) = (read_text(left)?, read_text(right)?);
            Ok(StereoCalibration::from_ros_pair(
                (&l.0, &l.1),
                (&r.0, &r.1),
            )?)
        }
        [] => bail!("give --calib FILE (OpenCV stereo YAML) or --calib LEFT --calib RIGHT (ROS)"),
        _ => bail!(
            "--calib takes one OpenCV file or two ROS files, found {}",
            files.len()
        ),
    }
}

pub fn stereo_cmd(a: StereoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out_dir)
        .with_context(|| format!("creating {}", a.out_dir.display()))?;
    let (calib, left, right) = match a.synthetic {
        Some(z) => {
            if !(z.is_finite() && z > 0.0) {
                bail!("--synthetic takes a distance in mm, found {z}");
            }
            let rig = StereoRig::sensor();
            let plane = Plane {
                z_mm: z,
                tilt_x: 0.3,
                tilt_y: 0.1,
            };
            let (l, r) = render_pair(&rig, &plane, &Membrane::sensor(), 1);
            save_grey(&a.out_dir.join("input_left.png"), &l)?;
            save_grey(&a.out_dir.join("input_right.png"), &r)?;
            (rig.calibration(), l, r)
        }
        None => {
            let calib = load_calibration(&a.calib)?;
            let left = load_grey(a.left.as_deref().context("--left is required")?)?;
            let right = load_grey(a.right.as_deref().context("--right is required")?)?;
            (calib, left, right)
        }
    };
    let config = StereoConfig {
        spatial: if a.no_spatial {
            None
        } else {
            StereoConfig::default().spatial
        },
        hole_fill: (a.fill_holes > 0).then_some(HoleFill {
            max_width: a.fill_holes,
        }),
        outliers: a.outliers.then(OutlierParams::default),
        ..a.pipeline.config()
    };
    let mut pipeline = StereoPipeline::new(&calib, config)?;
    let frame = pipeline.process(&left, &right)?;
    let summary = write_outputs(&a.out_dir, &pipeline, &frame, &config)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&a.out_dir, &summary);
    }
    Ok(())
}

pub(crate) fn write_outputs(
    dir: &Path,
    pipeline: &StereoPipeline,
    frame: &StereoFrame,
    config: &StereoConfig,
) -> Result<StereoSummary> {
    let rect = pipeline.rectification();
    let params = pipeline.matcher().params();
    save_grey(&dir.join("left_rect.png"), &frame.left)?;
    save_grey(&dir.join("right_rect.png"), &frame.right)?;
    write_npy(&dir.join("disparity.npy"), &frame.disparity)?;
    write_npy(&dir.join("depth.npy"), &frame.depth_mm)?;
    // 100 counts per mm: 0.01 mm steps up to 655 mm.
    write_png16(&dir.join("depth16.png"), &frame.depth_mm, 100.0)?;
    write_false_colour_png(
        &dir.join("depth_colour.png"),
        &frame.depth_mm,
        config.near_mm as f32,
        config.far_mm as f32,
    )?;
    write_false_colour_png(
        &dir.join("disparity_colour.png"),
        &frame.disparity,
        params.min_disparity as f32,
        params.max_disparity() as f32,
    )?;
    let grey: Vec<u8> = frame
        .cloud
        .pixels
        .iter()
        .map(|&i| frame.left.as_slice()[i as usize])
        .collect();
    write_points_ply(
        &dir.join("cloud.ply"),
        &frame.cloud.points,
        Some(&grey),
        "stereotac stereo point cloud, mm, rectified left camera frame",
    )?;
    let mut depths: Vec<f32> = frame
        .depth_mm
        .as_slice()
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    depths.sort_by(f32::total_cmp);
    let (w, h) = (frame.disparity.width(), frame.disparity.height());
    let summary = StereoSummary {
        width: w,
        height: h,
        focal_px: rect.focal(),
        baseline_mm: rect.baseline(),
        disparity_range_px: [params.min_disparity, params.max_disparity()],
        kernel: pipeline.matcher().kernel(),
        stats: frame.stats,
        fill_rate: depths.len() as f64 / (w * h).max(1) as f64,
        points: frame.cloud.len(),
        outliers_removed: frame.outliers_removed,
        holes_filled: frame.holes_filled,
        depth_mm: (!depths.is_empty()).then(|| {
            [
                depths[0],
                depths[depths.len() / 2],
                depths[depths.len() - 1],
            ]
        }),
        timings: frame.timings,
        files: vec![
            "left_rect.png",
            "right_rect.png",
            "disparity.npy",
            "depth.npy",
            "depth16.png",
            "depth_colour.png",
            "disparity_colour.png",
            "cloud.ply",
            "summary.json",
        ],
    };
    let path = dir.join("summary.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&summary)?)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(summary)
}

fn print_summary(dir: &Path, s: &StereoSummary) {
    println!(
        "rectified {}×{}, f = {:.1} px, baseline {:.2} mm, disparities {}..={} px ({:?} kernel)",
        s.width,
        s.height,
        s.focal_px,
        s.baseline_mm,
        s.disparity_range_px[0],
        s.disparity_range_px[1],
        s.kernel
    );
    let st = &s.stats;
    println!(
        "valid {:.1} % of pixels; rejected: border {}, low texture {}, not unique {}, \
         range edge {}, left-right {}, speckle {}, outliers {}",
        100.0 * s.fill_rate,
        st.border,
        st.low_texture,
        st.not_unique,
        st.range_edge,
        st.left_right,
        st.speckle,
        s.outliers_removed
    );
    if let Some([lo, mid, hi]) = s.depth_mm {
        println!(
            "depth: min {lo:.1} mm, median {mid:.1} mm, max {hi:.1} mm; {} points",
            s.points
        );
    }
    let t = &s.timings;
    println!(
        "time: rectify {:.2} ms, match {:.2} ms, filters {:.2} ms, reproject {:.2} ms, \
         outliers {:.1} ms, total {:.1} ms",
        t.rectify_ms, t.match_ms, t.filter_ms, t.reproject_ms, t.outliers_ms, t.total_ms
    );
    println!("wrote {} into {}", s.files.join(", "), dir.display());
}

/// `stereotac stereo-eval`.
#[derive(Debug, clap::Args)]
pub struct StereoEvalArgs {
    /// Target distances, mm.
    #[arg(long, value_delimiter = ',', default_values_t = [100.0, 150.0, 200.0, 250.0, 300.0])]
    pub distances: Vec<f64>,
    /// Frames per distance.
    #[arg(long, default_value_t = 10)]
    pub frames: usize,
    /// Region of interest: this share of each side, centred.
    #[arg(long, default_value_t = 0.4)]
    pub roi: f64,
    /// Share of light from the skin (0..1).
    #[arg(long, default_value_t = Membrane::sensor().haze)]
    pub haze: f64,
    /// Sensor noise, grey levels.
    #[arg(long, default_value_t = Membrane::sensor().noise)]
    pub noise: f64,
    /// Cameras: an ideal rectified rig, or the sensor's 160° fisheye pair (raw frames
    /// through the lens model, rectified by the pipeline).
    #[arg(long, value_enum, default_value_t = LensArg::Ideal)]
    pub lens: LensArg,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
}

/// `--lens` of `stereo-eval`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LensArg {
    /// An ideal rectified pinhole pair.
    Ideal,
    /// The sensor's wide fisheye pair, raw.
    Wide,
}

pub fn stereo_eval_cmd(a: StereoEvalArgs) -> Result<()> {
    if a.frames == 0 || a.distances.is_empty() {
        bail!("need at least one distance and one frame");
    }
    if let Some(bad) = a.distances.iter().find(|d| !(d.is_finite() && **d > 0.0)) {
        bail!("distances must be positive, found {bad}");
    }
    let usable = (0.0..=1.0).contains(&a.haze) && a.roi > 0.0 && a.roi <= 1.0 && a.noise >= 0.0;
    if !usable {
        bail!("--haze must be in 0..1, --roi in (0, 1], --noise not negative");
    }
    let setup = SyntheticEval {
        distances_mm: a.distances.clone(),
        frames: a.frames,
        roi: a.roi,
        membrane: Membrane {
            haze: a.haze,
            noise: a.noise,
            ..Membrane::sensor()
        },
        lens: match a.lens {
            LensArg::Ideal => eval::Lens::Ideal,
            LensArg::Wide => eval::Lens::Wide,
        },
        ..SyntheticEval::default()
    };
    let progress = bar(2 * a.distances.len() as u64, "rendering, matching");
    let rows = eval::run_synthetic(&setup, a.pipeline.config(), |_| progress.inc(1))?;
    progress.finish_and_clear();
    let json = report_json(&rows, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
    } else {
        println!(
            "synthetic flat targets, {} lens, {} frames each, ROI {:.0} % of each side, haze {}, noise {} grey levels",
            match a.lens {
                LensArg::Ideal => "ideal",
                LensArg::Wide => "wide fisheye",
            },
            a.frames,
            100.0 * a.roi,
            a.haze,
            a.noise
        );
        print!("{}", eval::table(&rows));
    }
    Ok(())
}

/// The rows as pretty JSON, also written to `out` when given.
fn report_json<T: Serialize>(rows: &T, out: Option<&Path>) -> Result<String> {
    let json = serde_json::to_string_pretty(rows)?;
    if let Some(path) = out {
        std::fs::write(path, &json).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(json)
}

/// `stereotac bench stereo` options.
#[derive(Debug, clap::Args)]
pub struct BenchStereoArgs {
    /// Repeats per measurement; the median is reported.
    #[arg(long, default_value_t = 15)]
    pub repeats: usize,
    /// Also time OpenCV's StereoBM on the same input (needs python3 with opencv-python).
    #[arg(long)]
    pub opencv: bool,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    pub json_out: Option<PathBuf>,
}

/// One measurement of the stereo bench.
#[derive(Debug, Serialize)]
struct BenchRow {
    what: String,
    threads: usize,
    median_ms: f64,
    /// Against the row named in `reference` (time / reference time).
    ratio: Option<f64>,
    reference: Option<String>,
    /// Share of pixels with a disparity more than 1 px off the ground truth, among the
    /// pixels both this matcher and the ground truth cover.
    bad_1px_pct: Option<f64>,
    valid_pct: Option<f64>,
}

/// Matching quality against the true disparity of the bench scene.
fn quality(disparity: &Grid<f32>, truth: &Grid<f32>) -> (f64, f64) {
    let (mut valid, mut bad) = (0usize, 0usize);
    for (d, t) in disparity.as_slice().iter().zip(truth.as_slice()) {
        if d.is_finite() {
            valid += 1;
            if (d - t).abs() > 1.0 {
                bad += 1;
            }
        }
    }
    let n = disparity.as_slice().len().max(1);
    (
        100.0 * bad as f64 / valid.max(1) as f64,
        100.0 * valid as f64 / n as f64,
    )
}

const OPENCV_SCRIPT: &str = include_str!("../benches/opencv_stereobm.py");

pub fn bench_stereo(a: &BenchStereoArgs) -> Result<()> {
    let rig = StereoRig::sensor();
    let plane = Plane {
        z_mm: 120.0,
        tilt_x: 0.3,
        tilt_y: 0.1,
    };
    let (left, right) = render_pair(&rig, &plane, &Membrane::sensor(), 1);
    let truth = rig.true_disparity(&plane);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let two = rayon::ThreadPoolBuilder::new().num_threads(2).build()?;
    let mut rows: Vec<BenchRow> = Vec::new();
    let row = |what: &str, threads, ms, reference: Option<(&str, f64)>| BenchRow {
        what: what.to_string(),
        threads,
        median_ms: ms,
        ratio: reference.map(|(_, r)| ms / r),
        reference: reference.map(|(n, _)| n.to_string()),
        bad_1px_pct: None,
        valid_pct: None,
    };
    let progress = bar(6, "benchmarking");

    // Remap: a fisheye camera's map, against a plain copy of the frame.
    let fisheye_pair = fisheye_calibration();
    let (table, _) = Rectification::bouguet(&fisheye_pair, 0.8)?.maps(&fisheye_pair);
    let mut out = vec![0u8; 640 * 480];
    let copy = one.install(|| {
        median_ms(a.repeats, || {
            out.copy_from_slice(std::hint::black_box(left.as_slice()))
        })
    });
    rows.push(row("frame copy 640×480 (reference)", 1, copy, None));
    let remap = one.install(|| {
        median_ms(a.repeats, || {
            table.remap(left.as_slice(), &mut out).expect("sizes match")
        })
    });
    rows.push(row(
        "remap 640×480 (fisheye, 5-bit bilinear)",
        1,
        remap,
        None,
    ));
    progress.inc(1);

    // Matching: 64 disparities, 9×9, one thread, each kernel.
    let params = BlockMatchParams::default();
    let mut portable_ms = None;
    for kernel in [Kernel::Portable, Kernel::Avx2] {
        let Ok(m) = BlockMatcher::new(params)?.with_kernel(kernel) else {
            continue;
        };
        let mut last = None;
        let ms = one.install(|| {
            median_ms(a.repeats, || {
                last = Some(m.compute(&left, &right).expect("same size"))
            })
        });
        let reference = portable_ms.map(|p| ("match, Portable", p));
        let mut r = row(&format!("match, {kernel:?} (64 d, 9×9)"), 1, ms, reference);
        if let Some(d) = last {
            let (bad, valid) = quality(&d.disparity, &truth);
            r.bad_1px_pct = Some(bad);
            r.valid_pct = Some(valid);
        }
        rows.push(r);
        portable_ms.get_or_insert(ms);
        progress.inc(1);
    }
    let best = BlockMatcher::new(params)?;
    let best_ms = one.install(|| median_ms(a.repeats, || drop(best.compute(&left, &right))));

    // OpenCV's StereoBM on the same images, same parameters, one thread.
    if a.opencv {
        match run_opencv(&left, &right, &truth, &params, a.repeats) {
            Ok(cv) => {
                let mut r = row("OpenCV StereoBM (64 d, 9×9)", 1, cv.median_ms, None);
                r.bad_1px_pct = Some(cv.bad_1px_pct);
                r.valid_pct = Some(cv.valid_pct);
                rows.push(r);
                rows.push(row(
                    &format!("match, {:?} vs OpenCV", best.kernel()),
                    1,
                    best_ms,
                    Some(("OpenCV StereoBM", cv.median_ms)),
                ));
            }
            Err(e) => eprintln!("OpenCV reference skipped: {e:#}"),
        }
    }
    progress.inc(1);

    // The whole vision frame at the sensor's range (5–60 cm), on 1 and 2 threads.
    for (threads, pool) in [(1, &one), (2, &two)] {
        let config = StereoConfig {
            spatial: None,
            ..StereoConfig::default()
        };
        let mut p = StereoPipeline::new(&fisheye_pair, config)?;
        let ms = pool.install(|| {
            median_ms(a.repeats, || {
                drop(p.process(&left, &right).expect("sizes match"))
            })
        });
        let n = p.matcher().params().num_disparities;
        rows.push(row(
            &format!("whole frame: rectify both, match ({n} d), reproject"),
            threads,
            ms,
            None,
        ));
        progress.inc(1);
    }
    progress.finish_and_clear();

    let json = report_json(&rows, a.json_out.as_deref())?;
    if a.json {
        println!("{json}");
        return Ok(());
    }
    println!("stereo bench, 640×480, median of {} runs", a.repeats);
    println!(
        "{:<52} {:>7} {:>10} {:>8} {:>9} {:>9}",
        "what", "threads", "ms", "ratio", "bad>1px%", "valid%"
    );
    for r in &rows {
        let opt = |v: Option<f64>, p: usize| v.map_or("-".into(), |v| format!("{v:.p$}"));
        println!(
            "{:<52} {:>7} {:>10.3} {:>8} {:>9} {:>9}",
            r.what,
            r.threads,
            r.median_ms,
            opt(r.ratio, 2),
            opt(r.bad_1px_pct, 2),
            opt(r.valid_pct, 1)
        );
    }
    Ok(())
}

struct OpenCvResult {
    median_ms: f64,
    bad_1px_pct: f64,
    valid_pct: f64,
}

/// Times OpenCV's StereoBM through python3 (`host/benches/opencv_stereobm.py`) on the
/// same images and scores its disparity against the same ground truth.
fn run_opencv(
    left: &Grid<u8>,
    right: &Grid<u8>,
    truth: &Grid<f32>,
    params: &BlockMatchParams,
    repeats: usize,
) -> Result<OpenCvResult> {
    let dir = std::env::temp_dir().join(format!("stereotac-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (l, r, d, script) = (
        dir.join("left.png"),
        dir.join("right.png"),
        dir.join("opencv_disparity.npy"),
        dir.join("opencv_stereobm.py"),
    );
    save_grey(&l, left)?;
    save_grey(&r, right)?;
    std::fs::write(&script, OPENCV_SCRIPT)?;
    let out = std::process::Command::new("python3")
        .arg(&script)
        .args([&l, &r, &d])
        .args([
            params.num_disparities.to_string(),
            params.block_size.to_string(),
            params.min_disparity.to_string(),
            repeats.to_string(),
        ])
        .output()
        .context("running python3")?;
    if !out.status.success() {
        bail!("{}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let reply: serde_json::Value = serde_json::from_slice(&out.stdout).with_context(|| {
        format!(
            "reading the script's reply {:?}",
            String::from_utf8_lossy(&out.stdout)
        )
    })?;
    let median_ms = reply["median_ms"]
        .as_f64()
        .context("no median_ms in the reply")?;
    let disparity = read_npy(&d)?;
    if (disparity.width(), disparity.height()) != (left.width(), left.height()) {
        bail!(
            "{}: not a {}×{} array",
            d.display(),
            left.width(),
            left.height()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    let (bad, valid) = quality(&disparity, truth);
    Ok(OpenCvResult {
        median_ms,
        bad_1px_pct: bad,
        valid_pct: valid,
    })
}
