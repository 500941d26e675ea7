//! Criterion benches of the stereo kernels: the fixed-point undistort-rectify remap of a
//! 640×480 frame, with a copy of the same frame as the reference measured in the same run;
//! block matching; and statistical outlier removal on a full 640×480 cloud, the image-grid
//! search against the k-d tree it replaces.
//! Run with `cargo bench -p stereotac --bench stereo_kernels`.

use criterion::{Criterion, criterion_group, criterion_main};
use stereotac::stereo::outliers::{OutlierParams, grid_inliers, statistical_inliers};
use stereotac::stereo::synthetic::{
    Membrane, Plane, StereoRig, camera_cloud, fisheye_calibration, render_pair,
};
use stereotac::stereo::{BlockMatchParams, BlockMatcher, Kernel, Rectification};

fn remap(c: &mut Criterion) {
    let calib = fisheye_calibration();
    let rect = Rectification::bouguet(&calib, 0.8).expect("a horizontal pair");
    let (table, _) = rect.maps(&calib);
    let src: Vec<u8> = (0..640 * 480).map(|i| (i * 7 % 251) as u8).collect();
    let mut out = vec![0u8; 640 * 480];
    let mut g = c.benchmark_group("remap");
    g.bench_function("fixed_point_640x480", |b| {
        b.iter(|| table.remap(&src, &mut out).expect("sizes match"))
    });
    g.bench_function("copy_640x480_reference", |b| {
        b.iter(|| out.copy_from_slice(std::hint::black_box(&src)))
    });
    g.finish();
}

fn block_match(c: &mut Criterion) {
    let rig = StereoRig::sensor();
    let (left, right) = render_pair(&rig, &Plane::facing(120.0), &Membrane::sensor(), 1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool");
    let mut g = c.benchmark_group("block_match_640x480_64d_9x9_1thread");
    g.sample_size(20);
    for kernel in [Kernel::Portable, Kernel::Avx2] {
        let Ok(m) =
            BlockMatcher::new(BlockMatchParams::default()).and_then(|m| m.with_kernel(kernel))
        else {
            continue;
        };
        g.bench_function(format!("{kernel:?}"), |b| {
            pool.install(|| b.iter(|| m.compute(&left, &right).expect("same size")))
        });
    }
    let no_speckle = BlockMatchParams {
        speckle_window: 0,
        ..BlockMatchParams::default()
    };
    let m = BlockMatcher::new(no_speckle).expect("valid");
    g.bench_function("best_without_speckle_filter", |b| {
        pool.install(|| b.iter(|| m.compute(&left, &right).expect("same size")))
    });
    g.finish();
}

fn outliers(c: &mut Criterion) {
    let (cloud, _) = camera_cloud(640, 480, 0.6, 0.3);
    let params = OutlierParams::default();
    let mut g = c.benchmark_group("outliers_640x480_k20");
    g.sample_size(10);
    g.bench_function("image_grid", |b| {
        b.iter(|| grid_inliers(&cloud, 640, 480, &params))
    });
    g.bench_function("kd_tree_reference", |b| {
        b.iter(|| statistical_inliers(&cloud.points, &params))
    });
    g.finish();
}

criterion_group!(benches, remap, block_match, outliers);
criterion_main!(benches);
