//! Criterion benches of the tactile kernels: Poisson solves (with a real 2-D FFT of the
//! same size as reference, measured in the same run), gradient models, colour filter.
//! Run with `cargo bench -p stereotac --bench tactile_kernels`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use stereotac::rng::Rng;
use stereotac::tactile::bench::{Fft2d, smooth_slopes};
use stereotac::tactile::colour::{ColourFilter, Reference};
use stereotac::tactile::model::{Lut, Mlp, MlpTraining, Sample};
use stereotac::tactile::poisson::{PoissonSolver, SolverKind};

fn poisson(c: &mut Criterion) {
    let mut g = c.benchmark_group("poisson");
    for (w, h) in [(640usize, 480usize), (300, 300), (1280, 960)] {
        let (p, q) = smooth_slopes(w, h);
        let mut solver = PoissonSolver::<f32>::new();
        for kind in SolverKind::ALL {
            g.bench_with_input(
                BenchmarkId::new(kind.name(), format!("{w}x{h}")),
                &(),
                |b, _| b.iter(|| solver.integrate(kind, &p, &q).unwrap()),
            );
        }
        // Reference: one forward real 2-D FFT of the same size.
        let mut fft = Fft2d::new(w, h);
        g.bench_with_input(
            BenchmarkId::new("fft2d", format!("{w}x{h}")),
            &(),
            |b, _| b.iter(|| fft.run(p.as_slice()).len()),
        );
    }
    g.finish();
}

fn models(c: &mut Criterion) {
    let mut rng = Rng::new(5);
    let samples: Vec<Sample> = (0..20_000)
        .map(|_| {
            let features = [
                rng.range(0.3, 1.7) as f32,
                rng.range(0.3, 1.7) as f32,
                rng.uniform() as f32,
                rng.uniform() as f32,
            ];
            Sample {
                target: (features[0] - features[1]) / (features[0] + features[1]),
                features,
            }
        })
        .collect();
    let lut = Lut::fit(&samples, 48, 3.0, 4, 3);
    let mlp = Mlp::fit(
        &samples,
        &MlpTraining {
            epochs: 2,
            ..Default::default()
        },
        |_, _| {},
    );
    let features: Vec<[f32; 4]> = samples
        .iter()
        .map(|s| s.features)
        .cycle()
        .take(100_000)
        .collect();
    let mut out = vec![0.0f32; features.len()];
    let mut g = c.benchmark_group("model_100k_pixels");
    g.bench_function("lut", |b| {
        b.iter(|| {
            for (f, o) in features.iter().zip(out.iter_mut()) {
                *o = lut.eval(f[0], f[1], f[2], f[3]);
            }
        })
    });
    g.bench_function("mlp", |b| b.iter(|| mlp.eval_batch(&features, &mut out)));
    g.finish();
}

fn colour(c: &mut Criterion) {
    let img = image::RgbImage::from_fn(640, 480, |x, y| {
        image::Rgb([(100 + x % 50) as u8, 8, (90 + y % 60) as u8])
    });
    let reference = Reference::from_image(&image::RgbImage::from_pixel(
        640,
        480,
        image::Rgb([116, 6, 116]),
    ));
    let filter = ColourFilter::default();
    c.bench_function("colour_normalise_640x480", |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for (i, p) in img.pixels().enumerate() {
                if let Some((r, bl)) = reference.normalise(&filter, i, p.0) {
                    acc += r - bl;
                }
            }
            acc
        })
    });
}

criterion_group!(benches, poisson, models, colour);
criterion_main!(benches);
