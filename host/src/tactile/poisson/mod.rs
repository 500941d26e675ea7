//! Fast Poisson integration of a slope field into a height map.
//!
//! Given slopes `p = ∂z/∂x` and `q = ∂z/∂y` sampled at pixel centres, find `z` whose
//! discrete gradient best matches them in the least-squares sense: `∇²z = ∂p/∂x + ∂q/∂y`
//! with the 5-point Laplacian. The divergence is taken from slopes averaged onto
//! half-pixel positions (`(p[i] + p[i+1]) / 2 ≈ z[i+1] − z[i]`), which removes the
//! half-pixel shift of a plain forward difference.
//!
//! Two solvers, both exact (no iteration) and `O(N log N)`: each is one 2-D DCT-II
//! (two real 2-D FFTs and a pass over the spectrum, see [`Dct2d`]) whose plans are built
//! once per domain size and cached in [`PoissonSolver`]:
//!
//! * [`SolverKind::Dct`], Neumann boundary: no flux across the border of the domain
//!   (the surface is mirrored there). The result is defined up to a constant, which is
//!   fixed so that the median of the border ring is zero. Right when a contact reaches
//!   the frame edge.
//! * [`SolverKind::Dst`], Dirichlet boundary: `z = 0` half a pixel outside the domain
//!   (the surface is mirrored with opposite sign there). Right when
//!   the domain's border is known to be flat and undeformed; wrong (too shallow) when a
//!   contact crosses it.
//!
//! Degenerate inputs: an empty domain or mismatched sizes are typed errors; non-finite
//! slopes are refused (sanitise first, see [`super::sanitize`]); `1 × N` domains work.

mod transforms;

use std::collections::HashMap;
use std::fmt;
use std::str::FromStr;

use realfft::RealFftPlanner;
use serde::{Deserialize, Serialize};

pub use transforms::{Buffers, Dct2d, Real, Signs, next_smooth};

use rustfft::FftPlanner;

use crate::grid::Grid;

/// Which boundary condition / transform to integrate with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SolverKind {
    /// Neumann boundary, DCT-II.
    Dct,
    /// Dirichlet boundary, DST-II.
    Dst,
}

impl SolverKind {
    /// Every solver, for benchmarks and help texts.
    pub const ALL: [SolverKind; 2] = [SolverKind::Dct, SolverKind::Dst];

    /// Lower-case name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            SolverKind::Dct => "dct",
            SolverKind::Dst => "dst",
        }
    }

    /// The smallest efficient domain length ≥ `n` for this solver.
    pub fn good_length(self, n: usize) -> usize {
        match self {
            SolverKind::Dct => next_smooth(n),
            SolverKind::Dst => next_smooth(n),
        }
    }
}

impl fmt::Display for SolverKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SolverKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown solver {s:?} (expected one of: dct, dst)"))
    }
}

/// Why a slope field could not be integrated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoissonError {
    /// The domain has no pixel.
    #[error("cannot integrate an empty {width}×{height} domain")]
    Empty {
        /// Domain width.
        width: usize,
        /// Domain height.
        height: usize,
    },
    /// `p` and `q` differ in size.
    #[error("slope fields differ in size: p is {p:?}, q is {q:?}")]
    SizeMismatch {
        /// `(width, height)` of p.
        p: (usize, usize),
        /// `(width, height)` of q.
        q: (usize, usize),
    },
    /// A slope is NaN or infinite.
    #[error("non-finite slope at ({x}, {y}); sanitise the gradients first")]
    NonFinite {
        /// Column.
        x: usize,
        /// Row.
        y: usize,
    },
}

/// Divergence of the slope field on the pixel grid, with slopes averaged onto half-pixel
/// positions. At the border the flux through the boundary is `0` for Neumann and the
/// border pixel's own slope (one-sided) for Dirichlet. Non-finite slopes are refused
/// ([`PoissonError::NonFinite`] names the first one, `p` before `q`; `out` is then not a
/// divergence). Sizes are the caller's to check (`p` and `q` alike).
pub fn divergence<T: Real>(
    kind: SolverKind,
    p: &Grid<T>,
    q: &Grid<T>,
    out: &mut Vec<T>,
) -> Result<(), PoissonError> {
    let (w, h) = (p.width(), p.height());
    out.clear();
    out.resize(w * h, T::zero());
    let mut finite = true;
    for (y, row) in out.chunks_exact_mut(w.max(1)).enumerate().take(h) {
        finite &= divergence_row(kind, p, q, y, row);
    }
    if finite {
        Ok(())
    } else {
        Err(first_non_finite(p, q))
    }
}

/// Row `y` of [`divergence`] into `o` (length `p.width()`); `false` when row `y` of `p`
/// or of `q` holds a NaN or an infinity (only row `y` is checked, though the rows of `q`
/// above and below are read: every row is checked on its own turn, and a solve asks for
/// each once). Rows are made one at a time so that the solver can take each as it
/// reorders it, while its slope rows are in cache, and the check costs no pass of its own.
fn divergence_row<T: Real>(
    kind: SolverKind,
    p: &Grid<T>,
    q: &Grid<T>,
    y: usize,
    o: &mut [T],
) -> bool {
    let (w, h) = (p.width(), p.height());
    let half = T::from(0.5).expect("0.5 fits");
    let edge = |v: T| match kind {
        SolverKind::Dct => T::zero(),
        SolverKind::Dst => v,
    };
    let finite = |row: &[T]| !row.iter().fold(false, |bad, v| bad | !v.is_finite());
    let (pr, here) = (p.row(y), q.row(y));
    if w == 1 {
        o[0] = edge(pr[0]) - edge(pr[0]);
    } else {
        // Flux (p[x] + p[x+1]) / 2 out of the right side minus the same into the left
        // side: (p[x+1] − p[x−1]) / 2 inside, written without a carried value so that
        // the loop runs in vector lanes.
        o[0] = (pr[0] + pr[1]) * half - edge(pr[0]);
        for ((o, right), left) in o[1..w - 1].iter_mut().zip(&pr[2..]).zip(pr) {
            *o = (*right - *left) * half;
        }
        o[w - 1] = edge(pr[w - 1]) - (pr[w - 2] + pr[w - 1]) * half;
    }
    // y fluxes: (q[y] + q[y+1]) / 2 out of the bottom, the same from the row above into
    // the top; inside, (q[y+1] − q[y−1]) / 2.
    match (
        y.checked_sub(1).map(|a| q.row(a)),
        (y + 1 < h).then(|| q.row(y + 1)),
    ) {
        (Some(above), Some(below)) => {
            for ((o, a), b) in o.iter_mut().zip(above).zip(below) {
                *o = *o + (*b - *a) * half;
            }
        }
        (None, Some(below)) => {
            for ((o, c), b) in o.iter_mut().zip(here).zip(below) {
                *o = *o + (*c + *b) * half - edge(*c);
            }
        }
        (Some(above), None) => {
            for ((o, a), c) in o.iter_mut().zip(above).zip(here) {
                *o = *o + edge(*c) - (*a + *c) * half;
            }
        }
        (None, None) => {
            for (o, c) in o.iter_mut().zip(here) {
                *o = *o + (edge(*c) - edge(*c));
            }
        }
    }
    finite(pr) & finite(here)
}

/// The error for the first non-finite slope, `p` before `q` (one is known to hold one).
fn first_non_finite<T: Real>(p: &Grid<T>, q: &Grid<T>) -> PoissonError {
    let w = p.width().max(1);
    let i = [p, q]
        .into_iter()
        .find_map(|g| g.as_slice().iter().position(|v| !v.is_finite()))
        .unwrap_or(0);
    PoissonError::NonFinite { x: i % w, y: i / w }
}

/// Integrates slope fields; owns the cached plans and work buffers, so reuse one per
/// thread across frames.
pub struct PoissonSolver<T: Real> {
    real_planner: RealFftPlanner<T>,
    planner: FftPlanner<T>,
    plans: HashMap<(usize, usize), Dct2d<T>>,
    eigen: HashMap<(SolverKind, usize), Vec<T>>,
    buffers: Buffers<T>,
}

impl<T: Real> Default for PoissonSolver<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// Plans (sizes) kept before the cache is cleared (ROIs change size).
const PLAN_CACHE_LIMIT: usize = 64;

impl<T: Real> PoissonSolver<T> {
    /// A solver with empty plan caches.
    pub fn new() -> Self {
        Self {
            real_planner: RealFftPlanner::new(),
            planner: FftPlanner::new(),
            plans: HashMap::new(),
            eigen: HashMap::new(),
            buffers: Buffers::default(),
        }
    }

    /// Builds (or finds) the plans for a `width × height` domain ahead of time.
    pub fn prepare(&mut self, kind: SolverKind, width: usize, height: usize) {
        if width == 0 || height == 0 {
            return;
        }
        if self.plans.len() >= PLAN_CACHE_LIMIT && !self.plans.contains_key(&(width, height)) {
            self.plans.clear();
        }
        let (real_planner, planner) = (&mut self.real_planner, &mut self.planner);
        self.plans
            .entry((width, height))
            .or_insert_with(|| Dct2d::new(real_planner, planner, width, height));
        // Cleared before either length goes in: clearing between the two would drop the
        // width's table that the solve is about to use.
        let missing = [width, height]
            .iter()
            .filter(|&&n| !self.eigen.contains_key(&(kind, n)))
            .count();
        if self.eigen.len() + missing > 2 * PLAN_CACHE_LIMIT {
            self.eigen.clear();
        }
        for n in [width, height] {
            self.eigen
                .entry((kind, n))
                .or_insert_with(|| laplacian_eigenvalues(kind, n));
        }
    }

    /// Integrates `p = ∂z/∂x`, `q = ∂z/∂y` into `z` (same size) with the given boundary
    /// condition. See the module documentation for conventions. A NaN or infinite slope
    /// is found on the way through the solve (no pass of its own), so a refused input
    /// costs a solve (and plans for its size) before the error.
    pub fn integrate(
        &mut self,
        kind: SolverKind,
        p: &Grid<T>,
        q: &Grid<T>,
    ) -> Result<Grid<T>, PoissonError> {
        let (w, h) = (p.width(), p.height());
        if (q.width(), q.height()) != (w, h) {
            return Err(PoissonError::SizeMismatch {
                p: (w, h),
                q: (q.width(), q.height()),
            });
        }
        if w == 0 || h == 0 {
            return Err(PoissonError::Empty {
                width: w,
                height: h,
            });
        }
        self.prepare(kind, w, h);
        // The divergence goes into the transform row by row, as the solver reorders it:
        // no divergence image is written and read back.
        let mut z = vec![T::zero(); w * h];
        let mut finite = true;
        let plan = &self.plans[&(w, h)];
        let (ex, ey) = (&self.eigen[&(kind, w)], &self.eigen[&(kind, h)]);
        plan.solve_rows(
            |y, row| finite &= divergence_row(kind, p, q, y, row),
            &mut z,
            signs(kind),
            ex,
            ey,
            &mut self.buffers,
        );
        if !finite {
            return Err(first_non_finite(p, q));
        }
        let mut z = Grid::from_vec(w, h, z).expect("length is w*h");
        if kind == SolverKind::Dct {
            anchor_border_median(&mut z);
        }
        Ok(z)
    }

    /// Solves `L z = f` in place (row-major `w × h`), `L` the 5-point Laplacian with the
    /// boundary of `kind`. For Neumann the zero-frequency term is dropped (mean 0).
    /// [`Self::prepare`] must have been called for this size. (Tests: `integrate` hands
    /// its rows to the transform as it makes them.)
    #[cfg(test)]
    fn solve_in_place(&mut self, kind: SolverKind, f: &mut [T], w: usize, h: usize) {
        let plan = &self.plans[&(w, h)];
        let (ex, ey) = (&self.eigen[&(kind, w)], &self.eigen[&(kind, h)]);
        let input = f.to_vec();
        let rows = |y: usize, row: &mut [T]| row.copy_from_slice(&input[y * w..][..w]);
        plan.solve_rows(rows, f, signs(kind), ex, ey, &mut self.buffers);
    }
}

/// The sign pattern that makes the DCT solve `kind`'s boundary.
fn signs(kind: SolverKind) -> Signs {
    match kind {
        SolverKind::Dct => Signs::Plain,
        SolverKind::Dst => Signs::Checkerboard,
    }
}

/// Eigenvalues of the 1-D second-difference operator with the boundary of `kind`, in the
/// order of the DCT coefficients the solve divides: index `k` of the DCT for Neumann,
/// and for Dirichlet the DST index `N − 1 − k` (the DST runs as a DCT of the
/// checkerboard-signed input, coefficients reversed). One unused entry at the end
/// (`N`, a coefficient that does not exist) keeps the solve's indexing branch-free.
fn laplacian_eigenvalues<T: Real>(kind: SolverKind, n: usize) -> Vec<T> {
    (0..=n)
        .map(|k| {
            let theta = match kind {
                SolverKind::Dct => std::f64::consts::PI * k as f64 / n as f64,
                SolverKind::Dst => std::f64::consts::PI * (n - k) as f64 / n as f64,
            };
            T::from(2.0 * theta.cos() - 2.0).expect("fits")
        })
        .collect()
}

/// Shifts `z` so the median of its border ring is zero.
fn anchor_border_median<T: Real>(z: &mut Grid<T>) {
    let (w, h) = (z.width(), z.height());
    let mut ring: Vec<T> = Vec::with_capacity(2 * (w + h));
    ring.extend_from_slice(z.row(0));
    if h > 1 {
        ring.extend_from_slice(z.row(h - 1));
    }
    for y in 1..h.saturating_sub(1) {
        ring.push(z.get(0, y));
        if w > 1 {
            ring.push(z.get(w - 1, y));
        }
    }
    let mid = ring.len() / 2;
    let (_, median, _) = ring.select_nth_unstable_by(mid, |a, b| a.total_cmp_(b));
    let median = *median;
    for v in z.as_mut_slice() {
        *v = *v - median;
    }
}

/// `total_cmp` for the generic float (finite inputs are guaranteed here).
trait TotalCmp {
    fn total_cmp_(&self, other: &Self) -> std::cmp::Ordering;
}
impl<T: Real> TotalCmp for T {
    fn total_cmp_(&self, other: &Self) -> std::cmp::Ordering {
        self.partial_cmp(other).unwrap_or(std::cmp::Ordering::Equal)
    }
}

#[cfg(test)]
mod tests;
