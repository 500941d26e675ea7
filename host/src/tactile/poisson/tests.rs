use proptest::prelude::*;

use super::*;

/// A sum of Gaussian bumps with its exact gradient.
#[derive(Debug, Clone)]
struct Bumps(Vec<(f64, f64, f64, f64)>); // (cx, cy, sigma, amplitude)

impl Bumps {
    fn z(&self, x: f64, y: f64) -> f64 {
        self.0
            .iter()
            .map(|&(cx, cy, s, a)| {
                a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp()
            })
            .sum()
    }
    fn grad(&self, x: f64, y: f64) -> (f64, f64) {
        self.0.iter().fold((0.0, 0.0), |(gx, gy), &(cx, cy, s, a)| {
            let e = a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp();
            (gx - e * (x - cx) / (s * s), gy - e * (y - cy) / (s * s))
        })
    }
    fn fields<T: Real>(&self, w: usize, h: usize) -> (Grid<T>, Grid<T>, Grid<f64>) {
        let p = Grid::from_fn(w, h, |x, y| {
            T::from(self.grad(x as f64, y as f64).0).unwrap()
        });
        let q = Grid::from_fn(w, h, |x, y| {
            T::from(self.grad(x as f64, y as f64).1).unwrap()
        });
        let z = Grid::from_fn(w, h, |x, y| self.z(x as f64, y as f64));
        (p, q, z)
    }
}

fn max_error<T: Real>(got: &Grid<T>, want: &Grid<f64>) -> f64 {
    got.as_slice()
        .iter()
        .zip(want.as_slice())
        .map(|(a, b)| (a.to_f64().unwrap() - b).abs())
        .fold(0.0, f64::max)
}

/// `L z` on a `w × h` grid, `at(x, y)` giving z including one pixel outside.
fn five_point_laplacian(w: usize, h: usize, at: impl Fn(isize, isize) -> f64) -> Vec<f64> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1) - 4.0 * at(x, y)
        })
        .collect()
}

/// Sizes for the exact-inversion checks: odd and even each way, single rows and
/// columns, prime lengths.
const EXACT_SIZES: [(usize, usize); 8] = [
    (37, 24),
    (29, 40),
    (1, 7),
    (6, 1),
    (2, 2),
    (13, 13),
    (64, 45),
    (1, 1),
];

#[test]
fn neumann_solver_inverts_the_discrete_laplacian_exactly() {
    // Analytic check of the linear solve itself: z → L z (mirror boundary) → solve → z.
    for (w, h) in EXACT_SIZES {
        let z = Grid::from_fn(w, h, |x, y| ((x * 31 + y * 17) % 23) as f64 / 7.0);
        let mean = z.as_slice().iter().sum::<f64>() / (w * h) as f64;
        let at = |x: isize, y: isize| {
            let x = x.clamp(0, w as isize - 1) as usize;
            let y = y.clamp(0, h as isize - 1) as usize;
            z.get(x, y)
        };
        let mut f = five_point_laplacian(w, h, at);
        let mut solver = PoissonSolver::<f64>::new();
        solver.prepare(SolverKind::Dct, w, h);
        solver.solve_in_place(SolverKind::Dct, &mut f, w, h);
        for (got, want) in f.iter().zip(z.as_slice()) {
            assert!(
                (got - (want - mean)).abs() < 1e-9,
                "{w}x{h}: {got} vs {}",
                want - mean
            );
        }
    }
}

#[test]
fn dirichlet_solver_inverts_the_discrete_laplacian_exactly() {
    for (w, h) in EXACT_SIZES {
        let z = Grid::from_fn(w, h, |x, y| ((x * 13 + y * 7) % 19) as f64 / 5.0 - 1.0);
        // Zero half a pixel outside: the first outside pixel mirrors the border with
        // opposite sign.
        let at = |x: isize, y: isize| {
            let sign = if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
                -1.0
            } else {
                1.0
            };
            sign * z.get(
                x.clamp(0, w as isize - 1) as usize,
                y.clamp(0, h as isize - 1) as usize,
            )
        };
        let mut f = five_point_laplacian(w, h, at);
        let mut solver = PoissonSolver::<f64>::new();
        solver.prepare(SolverKind::Dst, w, h);
        solver.solve_in_place(SolverKind::Dst, &mut f, w, h);
        for (got, want) in f.iter().zip(z.as_slice()) {
            assert!((got - want).abs() < 1e-9, "{w}x{h}: {got} vs {want}");
        }
    }
}

#[test]
fn gaussian_bump_integrates_back_with_both_solvers() {
    let bump = Bumps(vec![(60.0, 45.0, 12.0, 10.0)]);
    let (w, h) = (120, 90);
    let (p, q, z) = bump.fields::<f64>(w, h);
    let mut solver = PoissonSolver::<f64>::new();
    for kind in SolverKind::ALL {
        let got = solver.integrate(kind, &p, &q).unwrap();
        let err = max_error(&got, &z);
        // Half-pixel averaging is second-order: ~h²/8 · z''' relative error.
        assert!(err < 0.02, "{kind}: max error {err} on a 10-unit bump");
    }
}

#[test]
fn bump_on_the_frame_edge_needs_neumann() {
    // Centred on the left edge: Dirichlet forces z = 0 where the bump is tallest.
    let bump = Bumps(vec![(0.0, 40.0, 10.0, 5.0)]);
    let (p, q, z) = bump.fields::<f64>(96, 80);
    let mut solver = PoissonSolver::<f64>::new();
    let neumann = solver.integrate(SolverKind::Dct, &p, &q).unwrap();
    let dirichlet = solver.integrate(SolverKind::Dst, &p, &q).unwrap();
    let peak = |g: &Grid<f64>| g.as_slice().iter().copied().fold(f64::MIN, f64::max);
    assert!(
        (peak(&neumann) - 5.0).abs() < 0.1,
        "neumann peak {}",
        peak(&neumann)
    );
    assert!(
        peak(&dirichlet) < 3.0,
        "dirichlet peak {}",
        peak(&dirichlet)
    );
    assert!(max_error(&neumann, &z) < 0.1);
}

#[test]
fn degenerate_sizes_and_bad_input_are_typed() {
    let mut solver = PoissonSolver::<f32>::new();
    for kind in SolverKind::ALL {
        for (w, h) in [(1, 1), (1, 9), (9, 1), (2, 3)] {
            let p = Grid::from_fn(w, h, |x, _| x as f32 * 0.1);
            let q = Grid::from_fn(w, h, |_, y| y as f32 * 0.1);
            let z = solver.integrate(kind, &p, &q).unwrap();
            assert!(z.as_slice().iter().all(|v| v.is_finite()), "{kind} {w}x{h}");
        }
        let empty = Grid::<f32>::filled(0, 4, 0.0);
        assert!(matches!(
            solver.integrate(kind, &empty, &empty),
            Err(PoissonError::Empty { .. })
        ));
        let a = Grid::filled(3, 4, 0.0f32);
        let b = Grid::filled(4, 3, 0.0f32);
        assert!(matches!(
            solver.integrate(kind, &a, &b),
            Err(PoissonError::SizeMismatch { .. })
        ));
        let mut nan = a.clone();
        nan.set(2, 1, f32::NAN);
        assert_eq!(
            solver.integrate(kind, &nan, &a),
            Err(PoissonError::NonFinite { x: 2, y: 1 })
        );
        let mut inf = a.clone();
        inf.set(0, 3, f32::INFINITY);
        assert_eq!(
            solver.integrate(kind, &a, &inf),
            Err(PoissonError::NonFinite { x: 0, y: 3 })
        );
    }
}

#[test]
fn a_constant_ramp_stays_finite_and_monotone() {
    // Constant slope: z = 0.5 x up to a constant; Neumann sees zero divergence inside but
    // nonzero flux at the border, which it cannot honour. The least-squares answer is a
    // bounded, finite surface; we only require finiteness and monotone rows.
    let p = Grid::filled(16, 8, 0.5f64);
    let q = Grid::filled(16, 8, 0.0f64);
    let z = PoissonSolver::new()
        .integrate(SolverKind::Dct, &p, &q)
        .unwrap();
    for y in 0..8 {
        for x in 1..16 {
            assert!(z.get(x, y) > z.get(x - 1, y));
        }
    }
}

fn bumps_strategy() -> impl Strategy<Value = Bumps> {
    prop::collection::vec(
        (20.0..80.0f64, 20.0..60.0f64, 6.0..14.0f64, -3.0..3.0f64),
        1..4,
    )
    .prop_map(Bumps)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Exact gradients of random smooth surfaces integrate back, in f64 and in f32, and
    /// f32 stays within 1e-4 of f64 relative to the peak.
    #[test]
    fn random_smooth_surfaces_integrate_back(bumps in bumps_strategy(), kind in prop::sample::select(SolverKind::ALL.to_vec())) {
        let (w, h) = (100, 80);
        let (p64, q64, z) = bumps.fields::<f64>(w, h);
        let (p32, q32, _) = bumps.fields::<f32>(w, h);
        let z64 = PoissonSolver::<f64>::new().integrate(kind, &p64, &q64).unwrap();
        let z32 = PoissonSolver::<f32>::new().integrate(kind, &p32, &q32).unwrap();
        let peak = z.as_slice().iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-3);
        // Bumps may reach the border; Dirichlet is then only approximately right.
        let border = z.row(0).iter().chain(z.row(h - 1)).chain((0..h).flat_map(|y| [z.get(0, y), z.get(w - 1, y)]).collect::<Vec<_>>().iter()).fold(0.0f64, |m, v| m.max(v.abs()));
        let tolerance = 0.01 * peak + match kind { SolverKind::Dct => 2.0, SolverKind::Dst => 1.0 } * border;
        // Neumann fixes the constant by the border median; compare shapes after removing it.
        let offset = |g: &Grid<f64>| g.as_slice().iter().zip(z.as_slice()).map(|(a, b)| a - b).sum::<f64>() / (w * h) as f64;
        let o64 = if kind == SolverKind::Dct { offset(&z64) } else { 0.0 };
        let err64 = z64.as_slice().iter().zip(z.as_slice()).map(|(a, b)| (a - o64 - b).abs()).fold(0.0, f64::max);
        prop_assert!(err64 <= tolerance, "f64 error {} > {}", err64, tolerance);
        let diff = z32.as_slice().iter().zip(z64.as_slice()).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max);
        prop_assert!(diff <= 1e-4 * peak.max(1.0), "f32 vs f64 {} (peak {})", diff, peak);
    }
}

/// Σ over interior pixel pairs of (z difference − half-pixel slope)²: the functional the
/// Neumann solver minimises.
fn gradient_residual(z: &Grid<f64>, p: &Grid<f64>, q: &Grid<f64>) -> f64 {
    let (w, h) = (z.width(), z.height());
    let mut r = 0.0;
    for y in 0..h {
        for x in 0..w {
            if x + 1 < w {
                r +=
                    (z.get(x + 1, y) - z.get(x, y) - 0.5 * (p.get(x, y) + p.get(x + 1, y))).powi(2);
            }
            if y + 1 < h {
                r +=
                    (z.get(x, y + 1) - z.get(x, y) - 0.5 * (q.get(x, y) + q.get(x, y + 1))).powi(2);
            }
        }
    }
    r
}

#[test]
fn a_non_integrable_field_gives_the_least_squares_surface() {
    // A pure rotation (p, q) = (−y, x)·s: no surface has this gradient. The Neumann
    // solution must be finite and fit no worse than any other surface; we check it against
    // the flat one and against small perturbations of itself.
    let (w, h) = (64, 48);
    let s = 0.01;
    let p = Grid::from_fn(w, h, |_, y| -(y as f64 - 24.0) * s);
    let q = Grid::from_fn(w, h, |x, _| (x as f64 - 32.0) * s);
    let z = PoissonSolver::new()
        .integrate(SolverKind::Dct, &p, &q)
        .unwrap();
    assert!(z.as_slice().iter().all(|v| v.is_finite()));
    let best = gradient_residual(&z, &p, &q);
    assert!(best < gradient_residual(&Grid::filled(w, h, 0.0), &p, &q));
    for (i, bump) in [(100usize, 0.05f64), (1500, -0.05), (3000, 0.02)] {
        let mut other = z.clone();
        other.as_mut_slice()[i] += bump;
        assert!(
            gradient_residual(&other, &p, &q) > best,
            "perturbing pixel {i} fits better"
        );
    }
    let z = PoissonSolver::new()
        .integrate(SolverKind::Dst, &p, &q)
        .unwrap();
    let worst = z.as_slice().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        worst.is_finite() && worst < s * (w + h) as f64 * 10.0,
        "dst |z| up to {worst}"
    );
}

#[test]
fn one_sanitised_spike_stays_local() {
    // Fact from the reference implementation: an unbounded 1e3 spike bends depth 300+ px
    // away. Clamped to the steepest real slope it must not.
    let (w, h) = (320, 240);
    let mut p = Grid::filled(w, h, 0.0f32);
    let q = Grid::filled(w, h, 0.0f32);
    p.set(160, 120, 1e3);
    let mut clamped = p.clone();
    crate::tactile::sanitize::sanitize(clamped.as_mut_slice(), 3.0);
    let mut solver = PoissonSolver::<f32>::new();
    let raw = solver.integrate(SolverKind::Dct, &p, &q).unwrap();
    let fixed = solver.integrate(SolverKind::Dct, &clamped, &q).unwrap();
    let far = |z: &Grid<f32>| (0..w).map(|x| z.get(x, 0).abs()).fold(0.0f32, f32::max);
    assert!(
        far(&raw) > 1.0,
        "the unclamped spike reaches the border ({})",
        far(&raw)
    );
    assert!(
        far(&fixed) < 0.01,
        "the clamped spike stays local ({})",
        far(&fixed)
    );
}

#[test]
fn divergence_is_the_difference_of_half_pixel_fluxes() {
    // By definition: the flux through the right side of pixel x is (p[x] + p[x+1]) / 2,
    // through the outer border 0 (Neumann) or the border pixel's own slope (Dirichlet);
    // the same along y. Odd and even sizes, single rows and columns.
    let mut rng = crate::rng::Rng::new(3);
    for (w, h) in [(7, 5), (1, 4), (6, 1), (1, 1), (2, 2), (16, 9)] {
        let p = Grid::from_fn(w, h, |_, _| rng.range(-1.0, 1.0));
        let q = Grid::from_fn(w, h, |_, _| rng.range(-1.0, 1.0));
        for kind in SolverKind::ALL {
            let border = |v: f64| if kind == SolverKind::Dct { 0.0 } else { v };
            // Flux out of the high side of cell i along a line of n values.
            let flux = |line: &dyn Fn(usize) -> f64, n: usize, i: isize| {
                if i < 0 {
                    border(line(0))
                } else if i as usize + 1 >= n {
                    border(line(n - 1))
                } else {
                    (line(i as usize) + line(i as usize + 1)) / 2.0
                }
            };
            let mut got = Vec::new();
            divergence(kind, &p, &q, &mut got).unwrap();
            for y in 0..h {
                for x in 0..w {
                    let row = |i: usize| p.get(i, y);
                    let column = |i: usize| q.get(x, i);
                    let want = flux(&row, w, x as isize) - flux(&row, w, x as isize - 1)
                        + flux(&column, h, y as isize)
                        - flux(&column, h, y as isize - 1);
                    let got = got[y * w + x];
                    assert!(
                        (got - want).abs() < 1e-12,
                        "{kind} {w}x{h} ({x}, {y}): {got} vs {want}"
                    );
                }
            }
        }
    }
}

#[test]
fn many_region_sizes_outgrow_the_plan_caches_safely() {
    // Regions of ever new sizes fill the caches past their limits; every solve must still
    // find its plans (the caches are cleared, never half-cleared under a solve).
    let mut solver = PoissonSolver::<f32>::new();
    for i in 1..=3 * PLAN_CACHE_LIMIT {
        // Widths seen before, heights always new: the cache reaches its limit between a
        // region's (cached) width and its (new) height.
        let (w, h) = (8 + i % 3, 16 + i);
        let p = Grid::from_fn(w, h, |x, _| x as f32 * 0.01);
        let q = Grid::filled(w, h, 0.0f32);
        for kind in SolverKind::ALL {
            let z = solver.integrate(kind, &p, &q).unwrap();
            assert!(z.as_slice().iter().all(|v| v.is_finite()), "{kind} {w}x{h}");
        }
    }
    assert!(solver.plans.len() <= PLAN_CACHE_LIMIT);
    assert!(solver.eigen.len() <= 2 * PLAN_CACHE_LIMIT);
}

#[test]
fn integrating_row_by_row_equals_divergence_then_solve() {
    // `integrate` hands the divergence to the transform one row at a time; the result is
    // the same, bit for bit, as the divergence image solved in place.
    let mut rng = crate::rng::Rng::new(11);
    for (w, h) in EXACT_SIZES {
        let p = Grid::from_fn(w, h, |_, _| rng.range(-1.0, 1.0) as f32);
        let q = Grid::from_fn(w, h, |_, _| rng.range(-1.0, 1.0) as f32);
        for kind in SolverKind::ALL {
            let mut solver = PoissonSolver::<f32>::new();
            let got = solver.integrate(kind, &p, &q).unwrap();
            let mut f = Vec::new();
            divergence(kind, &p, &q, &mut f).unwrap();
            solver.solve_in_place(kind, &mut f, w, h);
            let mut want = Grid::from_vec(w, h, f).unwrap();
            if kind == SolverKind::Dct {
                anchor_border_median(&mut want);
            }
            assert_eq!(got, want, "{kind} {w}x{h}");
        }
    }
}

#[test]
fn a_non_finite_slope_anywhere_is_named() {
    // The check rides along the divergence's rows: every row of both fields, both
    // borders, is looked at; the first bad value of p is named before any of q.
    // Sizes where a Neumann divergence ignores some slopes (one column: p; one row: q)
    // are checked the same.
    let mut solver = PoissonSolver::<f32>::new();
    let places = |w: usize, h: usize| {
        let mut v = vec![
            (0, 0),
            (w - 1, 0),
            (0, h - 1),
            (w - 1, h - 1),
            (w / 2, h / 2),
        ];
        v.dedup();
        v.into_iter().map(move |p| (w, h, p))
    };
    let cases = [(5, 4), (1, 4), (6, 1), (1, 1)]
        .into_iter()
        .flat_map(|(w, h)| places(w, h));
    for (w, h, (x, y)) in cases {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            for kind in SolverKind::ALL {
                let fine = Grid::filled(w, h, 0.1f32);
                let mut broken = fine.clone();
                broken.set(x, y, bad);
                let want = Err(PoissonError::NonFinite { x, y });
                assert_eq!(
                    solver.integrate(kind, &broken, &fine),
                    want,
                    "p {kind} {w}x{h}"
                );
                assert_eq!(
                    solver.integrate(kind, &fine, &broken),
                    want,
                    "q {kind} {w}x{h}"
                );
                let mut also = fine.clone();
                also.set(0, 0, bad);
                assert_eq!(
                    solver.integrate(kind, &broken, &also),
                    want,
                    "p first {kind}"
                );
            }
        }
    }
}
