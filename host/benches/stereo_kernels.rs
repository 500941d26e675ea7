//! Criterion benches of the stereo kernels: the fixed-point undistort-rectify remap of a
//! 640×480 frame, with a copy of the same frame as the reference measured in the same run;
//! block matching; and statistical outlier removal on a full 640×480 cloud, the image-grid
//! search against the k-d tree it replaces; and the steps after matching (spatial filter,
//! reprojection to a cloud) against the previous kernels, kept here as references.
//! Run with `cargo bench -p stereotac --bench stereo_kernels`.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Matrix4;
use stereotac::grid::Grid;
use stereotac::stereo::outliers::{OutlierParams, grid_inliers, statistical_inliers};
use stereotac::stereo::postfilter::SpatialFilter;
use stereotac::stereo::reproject::{PointCloud, reproject};
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

/// The steps after matching on a real disparity map (the block matcher's, 87 % valid),
/// on one thread and on two.
fn after_matching(c: &mut Criterion) {
    let rig = StereoRig::sensor();
    let (left, right) = render_pair(&rig, &Plane::facing(120.0), &Membrane::sensor(), 1);
    let matcher = BlockMatcher::new(BlockMatchParams::default()).expect("valid");
    let disparity = matcher.compute(&left, &right).expect("same size").disparity;
    let q = Rectification::bouguet(&rig.calibration(), 1.0)
        .expect("a horizontal pair")
        .q;
    let filter = SpatialFilter::default();
    {
        let (mut a, mut b) = (disparity.clone(), disparity.clone());
        filter.apply(&mut a);
        spatial_reference(&filter, &mut b);
        assert!(
            a.as_slice()
                .iter()
                .zip(b.as_slice())
                .all(|(x, y)| x.to_bits() == y.to_bits())
        );
        let (new, old) = (
            reproject(&disparity, &q),
            reproject_reference(&disparity, &q),
        );
        assert_eq!(new.pixels, old.pixels);
        let close =
            |a: &[f32; 3], b: &[f32; 3]| (0..3).all(|k| (a[k] - b[k]).abs() <= 1e-5 * b[2].abs());
        assert!(new.points.iter().zip(&old.points).all(|(a, b)| close(a, b)));
    }
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a pool");
        let mut g = c.benchmark_group(format!("after_matching_640x480_{threads}thread"));
        g.sample_size(30);
        g.bench_function("spatial_filter", |b| {
            pool.install(|| {
                b.iter_batched_ref(
                    || disparity.clone(),
                    |d| filter.apply(d),
                    criterion::BatchSize::LargeInput,
                )
            })
        });
        g.bench_function("spatial_filter_reference", |b| {
            pool.install(|| {
                b.iter_batched_ref(
                    || disparity.clone(),
                    |d| spatial_reference(&filter, d),
                    criterion::BatchSize::LargeInput,
                )
            })
        });
        g.bench_function("reproject", |b| {
            pool.install(|| b.iter(|| reproject(&disparity, &q)))
        });
        g.bench_function("reproject_reference", |b| {
            b.iter(|| reproject_reference(&disparity, &q))
        });
        g.finish();
    }
}

/// The spatial filter as it was: the horizontal passes one row at a time.
fn spatial_reference(f: &SpatialFilter, disparity: &mut Grid<f32>) {
    use rayon::prelude::*;
    let (alpha, delta) = (f.alpha.clamp(f32::MIN_POSITIVE, 1.0), f.delta);
    let w = disparity.width();
    if w == 0 || disparity.height() == 0 || !delta.is_finite() {
        return;
    }
    let line = |v: &mut f32, previous: &mut f32| {
        if v.is_finite() && previous.is_finite() && (*v - *previous).abs() < delta {
            *v = alpha * *v + (1.0 - alpha) * *previous;
        }
        *previous = *v;
    };
    let towards = |row: &mut [f32], previous: &[f32]| {
        for (v, &p) in row.iter_mut().zip(previous) {
            if (*v - p).abs() < delta {
                *v = alpha * *v + (1.0 - alpha) * p;
            }
        }
    };
    let data = disparity.as_mut_slice();
    let bands = rayon::current_num_threads().min(w / 64).max(1);
    let band_w = w.div_ceil(bands);
    for _ in 0..f.iterations {
        data.par_chunks_mut(w).for_each(|row| {
            let mut p = f32::NAN;
            row.iter_mut().for_each(|v| line(v, &mut p));
            let mut p = f32::NAN;
            row.iter_mut().rev().for_each(|v| line(v, &mut p));
        });
        let mut columns: Vec<Vec<&mut [f32]>> = (0..bands).map(|_| Vec::new()).collect();
        for row in data.chunks_mut(w) {
            for (band, part) in columns.iter_mut().zip(row.chunks_mut(band_w)) {
                band.push(part);
            }
        }
        columns.par_iter_mut().for_each(|rows| {
            for y in 1..rows.len() {
                let (done, rest) = rows.split_at_mut(y);
                towards(rest[0], done[y - 1]);
            }
            for y in (0..rows.len().saturating_sub(1)).rev() {
                let (head, done) = rows.split_at_mut(y + 1);
                towards(head[y], done[0]);
            }
        });
    }
}

/// Reprojection as it was: one thread, the whole matrix product per pixel.
fn reproject_reference(disparity: &Grid<f32>, q: &Matrix4<f64>) -> PointCloud {
    let q = q.cast::<f32>();
    let w = disparity.width();
    let mut cloud = PointCloud::default();
    for (i, &d) in disparity.as_slice().iter().enumerate() {
        if !(d > 0.0 && d.is_finite()) {
            continue;
        }
        let (u, v) = ((i % w) as f32, (i / w) as f32);
        let h = q * nalgebra::Vector4::new(u, v, d, 1.0);
        if h.w.abs() <= f32::EPSILON {
            continue;
        }
        let p = [h.x / h.w, h.y / h.w, h.z / h.w];
        if p.iter().all(|c| c.is_finite()) {
            cloud.points.push(p);
            cloud.pixels.push(i as u32);
        }
    }
    cloud
}

criterion_group!(benches, remap, block_match, outliers, after_matching);
criterion_main!(benches);
