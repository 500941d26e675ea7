//! The stereo part of `stereotac demo`: one vision frame of a built-in textured target,
//! raw through the sensor's 160° lenses, rectified, matched and reprojected like a real
//! frame, written as the `stereo` command writes it.

use std::path::Path;

use anyhow::{Context, Result};
use stereotac::stereo::StereoPipeline;
use stereotac::stereo::pipeline::StereoConfig;
use stereotac::stereo::synthetic::{Membrane, RawRig, TexturedPlane, wide_fisheye_calibration};

use crate::stereo_cli::write_outputs;

/// Target distance of the demo frame, mm.
const DISTANCE_MM: f64 = 150.0;

pub fn run(out: &Path) -> Result<()> {
    let dir = out.join("stereo");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    println!(
        "\nstereo: a vision frame (LEDs dark) of a textured target {DISTANCE_MM} mm away, \
         tilted 15°, raw through the 160° lenses"
    );
    let rig = RawRig::new(&wide_fisheye_calibration());
    let tilt = 15f64.to_radians();
    let target = TexturedPlane {
        point: nalgebra::Point3::new(0.0, 0.0, DISTANCE_MM),
        normal: nalgebra::Vector3::new(tilt.sin(), 0.0, tilt.cos()),
    };
    let (left, right) = rig.render(&target, &Membrane::sensor(), 1);
    let config = StereoConfig::default();
    let mut pipeline = StereoPipeline::new(rig.calibration(), config)?;
    let frame = pipeline.process(&left, &right)?;
    let summary = write_outputs(&dir, &pipeline, &frame, &config)?;
    let t = &frame.timings;
    println!(
        "depth at the centre {:.1} mm (true {DISTANCE_MM}), {:.1} % of pixels valid, {} points; \
         rectify {:.1} ms, match {:.1} ms, whole frame {:.1} ms",
        frame
            .depth_mm
            .get(frame.depth_mm.width() / 2, frame.depth_mm.height() / 2),
        100.0 * summary.fill_rate,
        summary.points,
        t.rectify_ms,
        t.match_ms,
        t.total_ms
    );
    println!(
        "wrote {} (depth .npy and PNGs, cloud.ply, summary.json)",
        dir.display()
    );
    Ok(())
}
