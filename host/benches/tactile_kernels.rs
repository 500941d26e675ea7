//! Criterion benches of the tactile kernels: Poisson solves (with a real 2-D FFT of the
//! same size as reference, measured in the same run), gradient models, colour filter,
//! contact detection (on a cached pair and on pairs read from memory) and whole
//! reconstructions of built-in scenes (a skin at rest, a ball, the 13 mm disk) with the
//! built-in calibration.
//! Run with `cargo bench -p stereotac --bench tactile_kernels`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use image::RgbImage;
use stereotac::rng::Rng;
use stereotac::tactile::bench::{Fft2d, smooth_slopes};
use stereotac::tactile::colour::{ColourFilter, Reference};
use stereotac::tactile::contact::{
    ContactParams, Detection, References, block_references, find_regions, look_at_every_row,
};
use stereotac::tactile::crosstalk::Unmix;
use stereotac::tactile::model::ModelKind;
use stereotac::tactile::model::{Lut, Mlp, MlpTraining, Sample};
use stereotac::tactile::poisson::{PoissonSolver, SolverKind};
use stereotac::tactile::reconstruct::Reconstructor;
use stereotac::tactile::render::{Optics, RenderedPair, builtin_scenes, render};
use stereotac::tactile::synthetic::builtin_calibration;

/// Detection's signature: [`find_regions`] and [`look_at_every_row`].
type Detect =
    fn(&RgbImage, &RgbImage, &References, &ColourFilter, &ContactParams, SolverKind) -> Detection;

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
    let reference = Reference::from_image(
        &image::RgbImage::from_pixel(640, 480, image::Rgb([116, 6, 116])),
        Unmix::IDENTITY,
    );
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

/// Whole reconstructions (LUT, DCT) of built-in scenes at 640×480, and detection alone on
/// the skin at rest: a frame with no contact should cost a small part of one with contact.
fn scenes(c: &mut Criterion) {
    let optics = Optics::resolution(640, 480);
    let (cal, refs) = builtin_calibration(&optics, 20, |_| {}).expect("built-in calibration");
    let model = cal.model;
    let mut g = c.benchmark_group("reconstruct_640x480");
    let all = builtin_scenes(&optics);
    for name in ["none", "sphere", "disk"] {
        let (_, scene) = all
            .iter()
            .find(|(n, _)| *n == name)
            .expect("built-in scene");
        let pair = render(&optics, scene, 7);
        let mut rec = Reconstructor::new(
            model.clone(),
            ModelKind::Lut,
            SolverKind::Dct,
            Some((&refs.0, &refs.1).into()),
        )
        .expect("sizes match");
        g.bench_function(name, |b| {
            b.iter(|| rec.reconstruct(&pair.dx, &pair.dy).expect("valid pair"))
        });
        if name == "none" {
            let block_refs = block_references(
                &refs.0,
                &refs.1,
                model.contact.coarse_step,
                model.filter.unmix,
            );
            // The same on frames not in any cache: a camera's frame is written by the
            // decoder, and the pair's older frame waited a phase, so neither is cached
            // when it is read. 24 pairs (44 MB) in turn, more than the caches hold.
            let fresh: Vec<_> = (0..24).map(|k| render(&optics, scene, 100 + k)).collect();
            let mut next = 0;
            // The glance, and the reference: detection that reads every row; one pair
            // again and again, and the fresh pairs in turn.
            for (name, detect) in [
                ("detect_none", find_regions as Detect),
                ("detect_none_every_row", look_at_every_row),
            ] {
                let read = |p: &RenderedPair| {
                    let (filter, contact) = (&model.filter, &model.contact);
                    detect(&p.dx, &p.dy, &block_refs, filter, contact, SolverKind::Dct)
                };
                g.bench_function(name, |b| b.iter(|| read(&pair)));
                g.bench_function(format!("{name}_fresh"), |b| {
                    b.iter(|| {
                        next = (next + 1) % fresh.len();
                        read(&fresh[next])
                    })
                });
            }
        }
    }
    g.finish();
}

criterion_group!(benches, poisson, models, colour, scenes);
criterion_main!(benches);
