//! Fast Poisson integration of a slope field into a height map.
//!
//! Given slopes `p = ∂z/∂x` and `q = ∂z/∂y` sampled at pixel centres, find `z` whose
//! discrete gradient best matches them in the least-squares sense: `∇²z = ∂p/∂x + ∂q/∂y`
//! with the 5-point Laplacian. The divergence is taken from slopes averaged onto
//! half-pixel positions (`(p[i] + p[i+1]) / 2 ≈ z[i+1] − z[i]`), which removes the
//! half-pixel shift of a plain forward difference.
//!
//! Two solvers, both exact (no iteration) and `O(N log N)` through real FFTs whose plans
//! are built once per length and cached in [`PoissonSolver`]:
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

pub use transforms::{DctII, DstII, Real, Scratch, next_smooth};

use crate::grid::{Grid, transpose};

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
/// border pixel's own slope (one-sided) for Dirichlet.
pub fn divergence<T: Real>(kind: SolverKind, p: &Grid<T>, q: &Grid<T>, out: &mut Vec<T>) {
    let (w, h) = (p.width(), p.height());
    out.clear();
    out.resize(w * h, T::zero());
    let half = T::from(0.5).expect("0.5 fits");
    let edge = |v: T| match kind {
        SolverKind::Dct => T::zero(),
        SolverKind::Dst => v,
    };
    for y in 0..h {
        let pr = p.row(y);
        let o = &mut out[y * w..(y + 1) * w];
        let mut left = edge(pr[0]);
        for x in 0..w {
            let right = if x + 1 < w {
                (pr[x] + pr[x + 1]) * half
            } else {
                edge(pr[x])
            };
            o[x] = right - left;
            left = right;
        }
    }
    // y fluxes row by row (contiguous): flux below row y is (q[y] + q[y+1]) / 2.
    for y in 0..h {
        let o = &mut out[y * w..(y + 1) * w];
        let here = q.row(y);
        if y + 1 < h {
            for ((o, a), b) in o.iter_mut().zip(here).zip(q.row(y + 1)) {
                *o = *o + (*a + *b) * half;
            }
        } else {
            for (o, a) in o.iter_mut().zip(here) {
                *o = *o + edge(*a);
            }
        }
        if y > 0 {
            for ((o, a), b) in o.iter_mut().zip(q.row(y - 1)).zip(here) {
                *o = *o - (*a + *b) * half;
            }
        } else {
            for (o, a) in o.iter_mut().zip(here) {
                *o = *o - edge(*a);
            }
        }
    }
}

/// Integrates slope fields; owns the cached plans and work buffers, so reuse one per
/// thread across frames.
pub struct PoissonSolver<T: Real> {
    planner: RealFftPlanner<T>,
    dct: HashMap<usize, DctII<T>>,
    dst: HashMap<usize, DstII<T>>,
    eigen: HashMap<(SolverKind, usize), Vec<T>>,
    scratch: Scratch<T>,
    work: Vec<T>,
    work_t: Vec<T>,
}

impl<T: Real> Default for PoissonSolver<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// Plans kept per transform kind before the cache is cleared (ROIs change size).
const PLAN_CACHE_LIMIT: usize = 64;

impl<T: Real> PoissonSolver<T> {
    /// A solver with empty plan caches.
    pub fn new() -> Self {
        Self {
            planner: RealFftPlanner::new(),
            dct: HashMap::new(),
            dst: HashMap::new(),
            eigen: HashMap::new(),
            scratch: Scratch::default(),
            work: Vec::new(),
            work_t: Vec::new(),
        }
    }

    /// Builds (or finds) the plans for a `width × height` domain ahead of time.
    pub fn prepare(&mut self, kind: SolverKind, width: usize, height: usize) {
        for n in [width, height] {
            if n == 0 {
                continue;
            }
            match kind {
                SolverKind::Dct => {
                    if self.dct.len() >= PLAN_CACHE_LIMIT && !self.dct.contains_key(&n) {
                        self.dct.clear();
                    }
                    let planner = &mut self.planner;
                    self.dct.entry(n).or_insert_with(|| DctII::new(planner, n));
                }
                SolverKind::Dst => {
                    if self.dst.len() >= PLAN_CACHE_LIMIT && !self.dst.contains_key(&n) {
                        self.dst.clear();
                    }
                    let planner = &mut self.planner;
                    self.dst.entry(n).or_insert_with(|| DstII::new(planner, n));
                }
            }
            if self.eigen.len() >= 2 * PLAN_CACHE_LIMIT && !self.eigen.contains_key(&(kind, n)) {
                self.eigen.clear();
            }
            self.eigen
                .entry((kind, n))
                .or_insert_with(|| laplacian_eigenvalues(kind, n));
        }
    }

    /// Integrates `p = ∂z/∂x`, `q = ∂z/∂y` into `z` (same size) with the given boundary
    /// condition. See the module documentation for conventions.
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
        for grid in [p, q] {
            // One pass without an early exit runs in vector lanes; the position is looked
            // for only when there is something to report.
            let values = grid.as_slice();
            if values.iter().fold(false, |bad, v| bad | !v.is_finite()) {
                let i = values.iter().position(|v| !v.is_finite()).unwrap_or(0);
                return Err(PoissonError::NonFinite { x: i % w, y: i / w });
            }
        }
        self.prepare(kind, w, h);
        let mut f = std::mem::take(&mut self.work);
        divergence(kind, p, q, &mut f);
        self.solve_in_place(kind, &mut f, w, h);
        let mut z = Grid::from_vec(w, h, f).expect("length is w*h");
        if kind == SolverKind::Dct {
            anchor_border_median(&mut z);
        }
        Ok(z)
    }

    /// Solves `L z = f` in place (row-major `w × h`), `L` the 5-point Laplacian with the
    /// boundary of `kind`. For Neumann the zero-frequency term is dropped (mean 0).
    fn solve_in_place(&mut self, kind: SolverKind, f: &mut [T], w: usize, h: usize) {
        let mut t = std::mem::take(&mut self.work_t);
        t.clear();
        t.resize(w * h, T::zero());
        self.rows(kind, f, w, true);
        transpose(f, &mut t, w, h);
        self.rows(kind, &mut t, h, true);
        let ex = &self.eigen[&(kind, w)];
        let ey = &self.eigen[&(kind, h)];
        // `t` is w rows (one per x frequency) of h values (y frequencies).
        // Without branches (the zero frequency of Neumann gives 0), so it runs in lanes.
        for (row, &ex) in t.chunks_exact_mut(h).zip(ex) {
            for (v, &ey) in row.iter_mut().zip(&ey[..h]) {
                let denom = ex + ey;
                let quotient = *v / denom;
                *v = if denom == T::zero() {
                    T::zero()
                } else {
                    quotient
                };
            }
        }
        self.rows(kind, &mut t, h, false);
        transpose(&t, f, h, w);
        self.rows(kind, f, w, false);
        self.work_t = t;
    }

    fn rows(&mut self, kind: SolverKind, data: &mut [T], len: usize, forward: bool) {
        match kind {
            SolverKind::Dct => {
                let plan = &self.dct[&len];
                for row in data.chunks_exact_mut(len) {
                    if forward {
                        plan.forward(row, &mut self.scratch);
                    } else {
                        plan.inverse(row, &mut self.scratch);
                    }
                }
            }
            SolverKind::Dst => {
                let plan = &self.dst[&len];
                for row in data.chunks_exact_mut(len) {
                    if forward {
                        plan.forward(row, &mut self.scratch);
                    } else {
                        plan.inverse(row, &mut self.scratch);
                    }
                }
            }
        }
    }
}

/// Eigenvalues of the 1-D second-difference operator with the boundary of `kind`.
fn laplacian_eigenvalues<T: Real>(kind: SolverKind, n: usize) -> Vec<T> {
    (0..n)
        .map(|k| {
            let theta = match kind {
                SolverKind::Dct => std::f64::consts::PI * k as f64 / n as f64,
                SolverKind::Dst => std::f64::consts::PI * (k + 1) as f64 / n as f64,
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
