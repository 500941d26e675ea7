//! The 2-D DCT-II that diagonalises the discrete Laplacian, built on one real 2-D FFT
//! (`realfft` along rows, `rustfft` down columns) with the plans made once per size.
//!
//! Makhoul's reordering in both dimensions (`v_m = x_{2m}` for the first half,
//! `v_{N−1−m} = x_{2m+1}` for the second) turns the 2-D DCT-II of `x` into the real 2-D
//! FFT `V` of `v` plus a twiddle per frequency: the four coefficients
//! `X[k1, k2]`, `X[N1−k1, k2]`, `X[k1, N2−k2]`, `X[N1−k1, N2−k2]` are linear in the two
//! stored bins `V[k1, k2]` and `V[k1, N2−k2]` and come back from them exactly. A Poisson
//! solve is therefore forward FFT, one pass over the spectrum (to DCT coefficients,
//! divide by the Laplacian's eigenvalue, back), inverse FFT: two real 2-D FFTs and three
//! light passes, instead of four rounds of 1-D transforms with a reorder, a twiddle
//! pass and a transpose each.
//!
//! The DST-II (zero boundary) needs no transform of its own:
//! `DST-II(x)[k] = DCT-II((−1)ⁿ xₙ)[N−1−k]`, so the solver flips signs in a
//! checkerboard on the way in and out and reads the eigenvalues in reverse.
//!
//! We do not use rustdct here: its DST-I assumes zeroed scratch (reusing scratch blew a
//! 480×640 transform up to 1e139), and realfft-based transforms measured faster.

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::num_traits::{Float, FloatConst};
use realfft::{ComplexToReal, FftNum, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

use crate::grid::transpose;

/// The float types the solvers run in.
pub trait Real: FftNum + Float + FloatConst + Default {}
impl<T: FftNum + Float + FloatConst + Default> Real for T {}

fn cast<T: Real>(v: f64) -> T {
    T::from(v).expect("every f64 constant fits f32/f64")
}

/// Work buffers of one transform at a time (one set per solver, reused across frames).
#[derive(Default)]
pub struct Buffers<T: Real> {
    /// Reordered real input; the inverse's reordered output.
    real: Vec<T>,
    /// Row spectra, `h` rows of `w/2 + 1` bins.
    rows: Vec<Complex<T>>,
    /// The same transposed: `w/2 + 1` rows (one per x frequency) of `h` bins.
    columns: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
    /// One row of the input, as its producer writes it.
    source: Vec<T>,
    /// One row's bin pairs split into planes (see [`PairPlanes`]).
    pairs: PairPlanes<T>,
}

/// The bins `V[k1, k2]` and their mirrors `V[k1, N2−k2]` of one row, `k2 = 1..`, as
/// separate real and imaginary planes in the same order, with the `k2`-dependent
/// factors beside them: contiguous lanes the compiler vectorises, where the
/// interleaved, mirrored originals are not.
#[derive(Default)]
struct PairPlanes<T> {
    re: Vec<T>,
    im: Vec<T>,
    mirror_re: Vec<T>,
    mirror_im: Vec<T>,
    twiddle_re: Vec<T>,
    twiddle_im: Vec<T>,
    eigen: Vec<T>,
    mirror_eigen: Vec<T>,
}

/// Sign pattern applied on the way into and out of the transform.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signs {
    /// Values as they are (DCT, Neumann).
    Plain,
    /// `(−1)^(x+y)`: turns the DCT into the DST (Dirichlet).
    Checkerboard,
}

/// The four DCT-II coefficients that share one pair of stored bins, in the order
/// `X[k1, k2]`, `X[N1−k1, k2]`, `X[k1, N2−k2]`, `X[N1−k1, N2−k2]`. Entries whose
/// index would be `N` (no such coefficient, at `k1 = 0` or `k2 = 0`) are zero.
pub type Quad<T> = [T; 4];

/// Plans for the unnormalised 2-D DCT-II
/// `X[k1, k2] = Σ x[n1, n2] cos(π(2n1+1)k1 / 2N1) cos(π(2n2+1)k2 / 2N2)` of a
/// `width × height` grid (row-major, `x` along rows), and its exact inverse.
pub struct Dct2d<T: Real> {
    width: usize,
    height: usize,
    rows_forward: Arc<dyn RealToComplex<T>>,
    rows_inverse: Arc<dyn ComplexToReal<T>>,
    columns_forward: Arc<dyn Fft<T>>,
    columns_inverse: Arc<dyn Fft<T>>,
    /// `exp(−iπk / 2N1)`, `k = 0..=N1/2`.
    twiddles_x: Vec<Complex<T>>,
    /// `exp(−iπk / 2N2)`, `k = 0..=N2/2`.
    twiddles_y: Vec<Complex<T>>,
}

fn twiddles<T: Real>(n: usize) -> Vec<Complex<T>> {
    (0..=n / 2)
        .map(|k| {
            let angle = -std::f64::consts::PI * k as f64 / (2 * n) as f64;
            Complex::new(cast(angle.cos()), cast(angle.sin()))
        })
        .collect()
}

/// Position in the original sequence of entry `m` of Makhoul's reordering (length `n`).
#[inline]
fn makhoul_source(m: usize, n: usize) -> usize {
    if m < n.div_ceil(2) {
        2 * m
    } else {
        2 * (n - 1 - m) + 1
    }
}

/// Makhoul's reordering of one row: even entries forward, odd entries backward.
/// (Odd entries are copied forward and then reversed: two passes the compiler
/// vectorises, where one reversed strided copy stays scalar.)
#[inline]
fn reorder<T: Copy>(data: &[T], v: &mut [T]) {
    let n = data.len();
    let (front, back) = v.split_at_mut(n.div_ceil(2));
    let (pairs, last) = data.split_at(n / 2 * 2);
    for ((e, o), pair) in front
        .iter_mut()
        .zip(back.iter_mut())
        .zip(pairs.chunks_exact(2))
    {
        *e = pair[0];
        *o = pair[1];
    }
    if let Some(&x) = last.first() {
        front[n / 2] = x;
    }
    back.reverse();
}

/// Inverse of [`reorder`]; `v` is left with its second half reversed.
#[inline]
fn unreorder<T: Copy>(v: &mut [T], data: &mut [T]) {
    let n = data.len();
    let (front, back) = v.split_at_mut(n.div_ceil(2));
    back.reverse();
    let (pairs, last) = data.split_at_mut(n / 2 * 2);
    for ((e, o), pair) in front.iter().zip(back.iter()).zip(pairs.chunks_exact_mut(2)) {
        pair[0] = *e;
        pair[1] = *o;
    }
    if let Some(x) = last.first_mut() {
        *x = front[n / 2];
    }
}

/// Negates one half of a reordered row: with a checkerboard the entries from even
/// columns carry the row's sign and those from odd columns the opposite.
#[inline]
fn checkerboard_row<T: Real>(v: &mut [T], source_row: usize) {
    let (front, back) = v.split_at_mut(v.len().div_ceil(2));
    let flip = if source_row.is_multiple_of(2) {
        back
    } else {
        front
    };
    for value in flip {
        *value = -*value;
    }
}

impl<T: Real> Dct2d<T> {
    /// Plans the transform of a `width × height` grid (both ≥ 1).
    pub fn new(
        real_planner: &mut RealFftPlanner<T>,
        planner: &mut FftPlanner<T>,
        width: usize,
        height: usize,
    ) -> Self {
        assert!(width >= 1 && height >= 1, "DCT size must be at least 1×1");
        Self {
            width,
            height,
            rows_forward: real_planner.plan_fft_forward(width),
            rows_inverse: real_planner.plan_fft_inverse(width),
            columns_forward: planner.plan_fft_forward(height),
            columns_inverse: planner.plan_fft_inverse(height),
            twiddles_x: twiddles(width),
            twiddles_y: twiddles(height),
        }
    }

    fn fit(&self, buffers: &mut Buffers<T>) {
        let (w, h) = (self.width, self.height);
        let half = w / 2 + 1;
        let scratch = [
            self.rows_forward.get_scratch_len(),
            self.rows_inverse.get_scratch_len(),
            self.columns_forward.get_inplace_scratch_len(),
            self.columns_inverse.get_inplace_scratch_len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(0);
        buffers.real.resize(w * h, T::zero());
        buffers.source.resize(w, T::zero());
        buffers.rows.resize(half * h, Complex::default());
        buffers.columns.resize(half * h, Complex::default());
        buffers.scratch.resize(scratch, Complex::default());
    }

    /// Reorders `x` in both dimensions and takes its real 2-D FFT into
    /// `buffers.columns` (one row per x frequency).
    fn to_spectrum(&self, x: &[T], signs: Signs, buffers: &mut Buffers<T>) {
        let w = self.width;
        debug_assert_eq!(x.len(), w * self.height);
        self.rows_to_spectrum(
            |y, row| row.copy_from_slice(&x[y * w..(y + 1) * w]),
            signs,
            buffers,
        );
    }

    /// [`Self::to_spectrum`] of the grid whose row `y` `source_row(y, out)` writes into
    /// `out` (each row asked for once, in Makhoul's order).
    fn rows_to_spectrum(
        &self,
        mut source_row: impl FnMut(usize, &mut [T]),
        signs: Signs,
        buffers: &mut Buffers<T>,
    ) {
        let (w, h) = (self.width, self.height);
        let half = w / 2 + 1;
        self.fit(buffers);
        let Buffers {
            real,
            rows,
            columns,
            scratch,
            source,
            ..
        } = buffers;
        for (m, (v, spectrum)) in real
            .chunks_exact_mut(w)
            .zip(rows.chunks_exact_mut(half))
            .enumerate()
        {
            let y = makhoul_source(m, h);
            source_row(y, source);
            reorder(source, v);
            if signs == Signs::Checkerboard {
                checkerboard_row(v, y);
            }
            self.rows_forward
                .process_with_scratch(v, spectrum, scratch)
                .expect("buffer lengths come from the plan");
        }
        transpose(rows, columns, half, h);
        self.columns_forward.process_with_scratch(columns, scratch);
    }

    /// Inverse of [`Self::to_spectrum`], without the `1 / (N1·N2)` scale (the pass over
    /// the spectrum applies it).
    fn spectrum_into(&self, x: &mut [T], signs: Signs, buffers: &mut Buffers<T>) {
        let (w, h) = (self.width, self.height);
        let half = w / 2 + 1;
        let Buffers {
            real,
            rows,
            columns,
            scratch,
            ..
        } = buffers;
        self.columns_inverse.process_with_scratch(columns, scratch);
        transpose(columns, rows, h, half);
        for (m, (spectrum, v)) in rows
            .chunks_exact_mut(half)
            .zip(real.chunks_exact_mut(w))
            .enumerate()
        {
            // The DC bin and (even widths) the Nyquist bin of a real row are real; clear
            // rounding residue so realfft accepts the spectrum.
            spectrum[0].im = T::zero();
            if w.is_multiple_of(2) {
                spectrum[half - 1].im = T::zero();
            }
            self.rows_inverse
                .process_with_scratch(spectrum, v, scratch)
                .expect("spectrum is Hermitian-valid and lengths come from the plan");
            let source = makhoul_source(m, h);
            if signs == Signs::Checkerboard {
                checkerboard_row(v, source);
            }
            unreorder(v, &mut x[source * w..(source + 1) * w]);
        }
    }

    /// Visits every group of four DCT coefficients: `op(k1, k2, quad)` returns the new
    /// coefficients, which are written back into the spectrum.
    fn map_coefficients(
        &self,
        columns: &mut [Complex<T>],
        mut op: impl FnMut(usize, usize, Quad<T>) -> Quad<T>,
    ) {
        let h = self.height;
        for (k1, row) in columns.chunks_exact_mut(h).enumerate() {
            let tx = self.twiddles_x[k1];
            for (k2, &ty) in self.twiddles_y.iter().enumerate() {
                let j = (h - k2) % h;
                let (a, b) = to_quad(row[k2], row[j], tx, ty);
                let mut quad = [a.re, -b.re, -a.im, b.im];
                mask(&mut quad, k1, k2);
                let mut quad = op(k1, k2, quad);
                mask(&mut quad, k1, k2);
                let [a, b, c, d] = quad;
                (row[k2], row[j]) = from_quad(Complex::new(a, -c), Complex::new(-b, d), tx, ty);
            }
        }
    }

    /// Forward 2-D DCT-II in place (`x` row-major, `width × height`); coefficient
    /// `X[k1, k2]` lands at `k2 * width + k1`.
    pub fn forward(&self, x: &mut [T], buffers: &mut Buffers<T>) {
        let (w, h) = (self.width, self.height);
        self.to_spectrum(x, Signs::Plain, buffers);
        let mut columns = std::mem::take(&mut buffers.columns);
        self.map_coefficients(&mut columns, |k1, k2, quad| {
            for (i, value) in quad.into_iter().enumerate() {
                let (x1, y1) = quad_index(i, k1, k2, w, h);
                if x1 < w && y1 < h {
                    x[y1 * w + x1] = value;
                }
            }
            quad
        });
        buffers.columns = columns;
    }

    /// Exact inverse of [`Self::forward`], in place.
    pub fn inverse(&self, coefficients: &mut [T], buffers: &mut Buffers<T>) {
        let (w, h) = (self.width, self.height);
        debug_assert_eq!(coefficients.len(), w * h);
        self.fit(buffers);
        let scale = T::one() / cast::<T>((w * h) as f64);
        let mut columns = std::mem::take(&mut buffers.columns);
        self.map_coefficients(&mut columns, |k1, k2, _| {
            std::array::from_fn(|i| {
                let (x1, y1) = quad_index(i, k1, k2, w, h);
                if x1 < w && y1 < h {
                    coefficients[y1 * w + x1] * scale
                } else {
                    T::zero()
                }
            })
        });
        buffers.columns = columns;
        self.spectrum_into(coefficients, Signs::Plain, buffers);
    }

    /// Solves `L z = f` into `z`, `L` the 5-point Laplacian whose 1-D parts have the
    /// eigenvalues `eigen_x` (length `width + 1`) and `eigen_y` (length `height + 1`,
    /// the last entry of each unused) in DCT order; a zero eigenvalue sum (the constant
    /// mode of Neumann) gives a zero coefficient. Row `y` of the right-hand side `f` is
    /// what `source_row(y, out)` writes into `out` (each row asked for once): a caller
    /// that makes `f` row by row hands each row over while it is in cache, and no image
    /// of it is written and read back.
    pub fn solve_rows(
        &self,
        source_row: impl FnMut(usize, &mut [T]),
        z: &mut [T],
        signs: Signs,
        eigen_x: &[T],
        eigen_y: &[T],
        buffers: &mut Buffers<T>,
    ) {
        debug_assert_eq!(z.len(), self.width * self.height);
        self.rows_to_spectrum(source_row, signs, buffers);
        self.divide_spectrum(eigen_x, eigen_y, buffers);
        self.spectrum_into(z, signs, buffers);
    }

    /// The pass over the spectrum: to DCT coefficients, each divided by its eigenvalue
    /// sum (and the `1 / (N1·N2)` of the inverse), back to bins.
    fn divide_spectrum(&self, eigen_x: &[T], eigen_y: &[T], buffers: &mut Buffers<T>) {
        let (w, h) = (self.width, self.height);
        debug_assert_eq!(eigen_x.len(), w + 1);
        debug_assert_eq!(eigen_y.len(), h + 1);
        let scale = T::one() / cast::<T>((w * h) as f64);
        // `scale / denominator`, zero for the constant mode of Neumann.
        let ratio = |denominator: T| {
            if denominator == T::zero() {
                T::zero()
            } else {
                scale / denominator
            }
        };
        let pairs = (h - 1) / 2;
        let planes = &mut buffers.pairs;
        planes.set_factors(&self.twiddles_y[1..=pairs], eigen_y, h);
        for (k1, row) in buffers.columns.chunks_exact_mut(h).enumerate() {
            let tx = self.twiddles_x[k1];
            let (ex, ex_mirror) = (eigen_x[k1], eigen_x[w - k1]);
            // At k1 = 0 there is no mirrored x coefficient.
            let mirror = if k1 == 0 { T::zero() } else { T::one() };
            let one = Complex::new(T::one(), T::zero());
            // k2 = 0: no mirrored y coefficient; the bin pairs with itself.
            let ey = eigen_y[0];
            let s = [
                ratio(ex + ey),
                mirror * ratio(ex_mirror + ey),
                T::zero(),
                T::zero(),
            ];
            row[0] = rescale_pair(row[0], row[0], tx, one, s).0;
            // Every other k2 below N2/2 with its mirror N2 − k2: no zero eigenvalue sum
            // here (only the constant mode has one), so no branch in the loop.
            planes.gather(&row[1..], pairs);
            planes.rescale(tx, [ex, ex_mirror], scale, mirror);
            planes.scatter(&mut row[1..], pairs);
            // k2 = N2/2 (even heights) is its own mirror.
            if h.is_multiple_of(2) && h >= 2 {
                let k2 = h / 2;
                let ey = eigen_y[k2];
                let (a, b) = (ratio(ex + ey), mirror * ratio(ex_mirror + ey));
                let ty = self.twiddles_y[k2];
                row[k2] = rescale_pair(row[k2], row[k2], tx, ty, [a, b, a, b]).0;
            }
        }
    }
}

impl<T: Real> PairPlanes<T> {
    /// The factors that depend on `k2` only: twiddles `k2 = 1..=pairs` and the
    /// eigenvalues of `k2` and of its mirror `N2 − k2`.
    fn set_factors(&mut self, twiddles: &[Complex<T>], eigen_y: &[T], h: usize) {
        let pairs = twiddles.len();
        self.twiddle_re.clear();
        self.twiddle_re.extend(twiddles.iter().map(|t| t.re));
        self.twiddle_im.clear();
        self.twiddle_im.extend(twiddles.iter().map(|t| t.im));
        self.eigen.clear();
        self.eigen.extend_from_slice(&eigen_y[1..=pairs]);
        self.mirror_eigen.clear();
        self.mirror_eigen
            .extend(eigen_y[h - pairs..h].iter().rev().copied());
        for plane in [
            &mut self.re,
            &mut self.im,
            &mut self.mirror_re,
            &mut self.mirror_im,
        ] {
            plane.resize(pairs, T::zero());
        }
    }

    /// Splits bins `1..=pairs` and their mirrors (counted from the end of `row`, which
    /// starts at `k2 = 1`) into the planes. Copied forward, then the mirror planes
    /// reversed: each pass runs in vector lanes.
    fn gather(&mut self, row: &[Complex<T>], pairs: usize) {
        let (low, high) = row.split_at(pairs);
        let high = &high[high.len() - pairs..];
        for (v, (re, im)) in low.iter().zip(self.re.iter_mut().zip(self.im.iter_mut())) {
            (*re, *im) = (v.re, v.im);
        }
        for (v, (re, im)) in high
            .iter()
            .zip(self.mirror_re.iter_mut().zip(self.mirror_im.iter_mut()))
        {
            (*re, *im) = (v.re, v.im);
        }
        self.mirror_re.reverse();
        self.mirror_im.reverse();
    }

    /// Inverse of [`Self::gather`]; the mirror planes are turned back first.
    fn scatter(&mut self, row: &mut [Complex<T>], pairs: usize) {
        let (low, high) = row.split_at_mut(pairs);
        let skip = high.len() - pairs;
        let high = &mut high[skip..];
        for (v, (re, im)) in low.iter_mut().zip(self.re.iter().zip(self.im.iter())) {
            *v = Complex::new(*re, *im);
        }
        self.mirror_re.reverse();
        self.mirror_im.reverse();
        for (v, (re, im)) in high
            .iter_mut()
            .zip(self.mirror_re.iter().zip(self.mirror_im.iter()))
        {
            *v = Complex::new(*re, *im);
        }
    }

    /// [`rescale_pair`] on every pair of the row, in lanes: `tx` is the row's twiddle,
    /// `ex` its eigenvalue and its mirror's, `mirror` 0 when the row has no mirror.
    fn rescale(&mut self, tx: Complex<T>, ex: [T; 2], scale: T, mirror: T) {
        let n = self.re.len();
        let (re, im) = (&mut self.re[..n], &mut self.im[..n]);
        let (mre, mim) = (&mut self.mirror_re[..n], &mut self.mirror_im[..n]);
        let (tre, tim) = (&self.twiddle_re[..n], &self.twiddle_im[..n]);
        let (ey, mey) = (&self.eigen[..n], &self.mirror_eigen[..n]);
        for i in 0..n {
            let s = [
                scale / (ex[0] + ey[i]),
                mirror * scale / (ex[1] + ey[i]),
                scale / (ex[0] + mey[i]),
                mirror * scale / (ex[1] + mey[i]),
            ];
            let (a, b) = rescale_pair(
                Complex::new(re[i], im[i]),
                Complex::new(mre[i], mim[i]),
                tx,
                Complex::new(tre[i], tim[i]),
                s,
            );
            (re[i], im[i], mre[i], mim[i]) = (a.re, a.im, b.re, b.im);
        }
    }
}

/// The two stored bins `r1 = V[k1, k2]`, `r2 = V[k1, N2−k2]` turned into their quad
/// (see [`Quad`]) as two complex numbers `a`, `b`: `[a.re, −b.re, −a.im, b.im]`.
#[inline(always)]
fn to_quad<T: Real>(
    r1: Complex<T>,
    r2: Complex<T>,
    tx: Complex<T>,
    ty: Complex<T>,
) -> (Complex<T>, Complex<T>) {
    let half = cast::<T>(0.5);
    let p = tx * r1;
    let q = (tx * r2).conj();
    // Spectra of the real and imaginary parts of the x-transformed column; rotated,
    // their real and imaginary parts are the quad (up to sign).
    let re = (p + q) * half;
    let d = (p - q) * half;
    let im = Complex::new(d.im, -d.re);
    (ty * re, ty * im)
}

/// Inverse of [`to_quad`]: the two stored bins from `a`, `b`.
#[inline(always)]
fn from_quad<T: Real>(
    a: Complex<T>,
    b: Complex<T>,
    tx: Complex<T>,
    ty: Complex<T>,
) -> (Complex<T>, Complex<T>) {
    let re = ty.conj() * a;
    let im = ty.conj() * b;
    let i_im = Complex::new(-im.im, im.re);
    (tx.conj() * (re + i_im), tx.conj() * (re - i_im).conj())
}

/// The solve's pass over one pair of stored bins: to the quad, each coefficient
/// multiplied by its factor in `s` (in the quad's order), and back.
#[inline(always)]
fn rescale_pair<T: Real>(
    r1: Complex<T>,
    r2: Complex<T>,
    tx: Complex<T>,
    ty: Complex<T>,
    s: [T; 4],
) -> (Complex<T>, Complex<T>) {
    let (a, b) = to_quad(r1, r2, tx, ty);
    let a = Complex::new(a.re * s[0], a.im * s[2]);
    let b = Complex::new(b.re * s[1], b.im * s[3]);
    from_quad(a, b, tx, ty)
}

/// Zeroes the entries of a quad that name no coefficient (index `N` at `k = 0`).
#[inline]
fn mask<T: Real>(quad: &mut Quad<T>, k1: usize, k2: usize) {
    if k1 == 0 {
        quad[1] = T::zero();
        quad[3] = T::zero();
    }
    if k2 == 0 {
        quad[2] = T::zero();
        quad[3] = T::zero();
    }
}

/// `(x, y)` frequency of entry `i` of the quad at `(k1, k2)`.
fn quad_index(i: usize, k1: usize, k2: usize, w: usize, h: usize) -> (usize, usize) {
    let x = if i.is_multiple_of(2) { k1 } else { w - k1 };
    let y = if i < 2 { k2 } else { h - k2 };
    (x, y)
}

/// The smallest length ≥ `n` whose prime factors are 2, 3 and 5 only (FFT-friendly).
pub fn next_smooth(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::f64::consts::PI;

    /// The 2-D DCT-II by its definition.
    fn naive(x: &[f64], w: usize, h: usize) -> Vec<f64> {
        let basis = |n: usize, k: usize, len: usize| {
            (PI * (2 * n + 1) as f64 * k as f64 / (2 * len) as f64).cos()
        };
        (0..w * h)
            .map(|i| {
                let (k1, k2) = (i % w, i / w);
                (0..w * h)
                    .map(|j| x[j] * basis(j % w, k1, w) * basis(j / w, k2, h))
                    .sum()
            })
            .collect()
    }

    fn signal(n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| ((i * 7919) % 113) as f64 / 17.0 - 3.0)
            .collect()
    }

    #[test]
    fn dct2d_matches_the_definition_and_inverts() {
        let mut real_planner = RealFftPlanner::new();
        let mut planner = FftPlanner::new();
        let mut buffers = Buffers::default();
        // Odd and even in each direction, single rows and columns, smooth and prime.
        for (w, h) in [
            (1, 1),
            (1, 5),
            (6, 1),
            (2, 2),
            (3, 4),
            (4, 3),
            (7, 6),
            (8, 9),
            (16, 5),
            (13, 11),
        ] {
            let plan = Dct2d::<f64>::new(&mut real_planner, &mut planner, w, h);
            let x = signal(w * h);
            let mut y = x.clone();
            plan.forward(&mut y, &mut buffers);
            for (i, (a, b)) in y.iter().zip(naive(&x, w, h)).enumerate() {
                assert!(
                    (a - b).abs() < 1e-9 * (1.0 + b.abs()),
                    "{w}x{h} coefficient ({}, {}): {a} vs {b}",
                    i % w,
                    i / w
                );
            }
            plan.inverse(&mut y, &mut buffers);
            for (a, b) in y.iter().zip(&x) {
                assert!((a - b).abs() < 1e-10, "{w}x{h} inverse: {a} vs {b}");
            }
        }
    }

    #[test]
    fn makhoul_order_round_trips() {
        for n in 1..9 {
            let x: Vec<usize> = (0..n).collect();
            let mut v = vec![0; n];
            reorder(&x, &mut v);
            for (m, &source) in v.iter().enumerate() {
                assert_eq!(source, makhoul_source(m, n), "n={n}");
            }
            let mut back = vec![0; n];
            unreorder(&mut v, &mut back);
            assert_eq!(back, x);
        }
    }

    #[test]
    fn smooth_lengths() {
        assert_eq!(next_smooth(479), 480);
        assert_eq!(next_smooth(1279), 1280);
        assert_eq!(next_smooth(7), 8);
        assert_eq!(next_smooth(0), 1);
        assert_eq!(next_smooth(121), 125);
    }
}
