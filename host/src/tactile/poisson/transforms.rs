//! 1-D real-to-real transforms that diagonalise the discrete Laplacian, built on
//! `realfft` with the FFT plan made once per length and reused for every row.
//!
//! * DCT-II (Makhoul's reordering: one real FFT of the same length) for reflective
//!   (Neumann) boundaries, with its exact inverse.
//! * DST-II, computed through the DCT-II of the sign-alternated input, for zero
//!   (Dirichlet) boundaries half a pixel outside the domain. The same cost as the DCT.
//!   (A DST-I through an odd extension needs a real FFT of length 2(N+1) and measured
//!   2.5× slower at 640×480.)
//!
//! We do not use rustdct here: its DST-I assumes zeroed scratch (reusing scratch blew a
//! 480×640 transform up to 1e139), and the realfft versions measured faster.

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::num_traits::{Float, FloatConst};
use realfft::{ComplexToReal, FftNum, RealFftPlanner, RealToComplex};

/// The float types the solvers run in.
pub trait Real: FftNum + Float + FloatConst + Default {}
impl<T: FftNum + Float + FloatConst + Default> Real for T {}

fn cast<T: Real>(v: f64) -> T {
    T::from(v).expect("every f64 constant fits f32/f64")
}

/// Unnormalised DCT-II `X_k = Σ x_n cos(π(2n+1)k / 2N)` and its exact inverse.
///
/// (A hand-fused route, one complex FFT of length N/2 with the real-FFT unpacking and the
/// DCT twiddles in one pass, was tried and measured 1.4–1.8× slower than this one.)
pub struct DctII<T: Real> {
    len: usize,
    forward: Arc<dyn RealToComplex<T>>,
    inverse: Arc<dyn ComplexToReal<T>>,
    /// `exp(-iπk / 2N)` for `k = 0..=N/2`.
    twiddles: Vec<Complex<T>>,
}

/// Work buffers for one transform at a time (one set per thread).
pub struct Scratch<T: Real> {
    real: Vec<T>,
    spectrum: Vec<Complex<T>>,
    fft: Vec<Complex<T>>,
}

impl<T: Real> Scratch<T> {
    fn fit(&mut self, real: usize, spectrum: usize, fft: usize) {
        self.real.resize(real, T::zero());
        self.spectrum.resize(spectrum, Complex::default());
        self.fft.resize(fft, Complex::default());
    }
}

impl<T: Real> Default for Scratch<T> {
    fn default() -> Self {
        Self {
            real: Vec::new(),
            spectrum: Vec::new(),
            fft: Vec::new(),
        }
    }
}

impl<T: Real> DctII<T> {
    /// Plans the transform of length `len` (≥ 1).
    pub fn new(planner: &mut RealFftPlanner<T>, len: usize) -> Self {
        assert!(len >= 1, "DCT length must be at least 1");
        let n = cast::<T>(len as f64);
        let twiddles = (0..=len / 2)
            .map(|k| {
                let angle = -T::PI() * cast::<T>(k as f64) / (n + n);
                Complex::new(angle.cos(), angle.sin())
            })
            .collect();
        Self {
            len,
            forward: planner.plan_fft_forward(len),
            inverse: planner.plan_fft_inverse(len),
            twiddles,
        }
    }

    /// Makhoul's reordering `v_n = x_{2n}` (n < N/2), `v_{N−1−n} = x_{2n+1}` into `v`.
    #[inline]
    fn reorder(data: &[T], v: &mut [T]) {
        let n = data.len();
        for (dst, src) in v[..n.div_ceil(2)].iter_mut().zip(data.iter().step_by(2)) {
            *dst = *src;
        }
        for (dst, src) in v[n.div_ceil(2)..]
            .iter_mut()
            .rev()
            .zip(data.iter().skip(1).step_by(2))
        {
            *dst = *src;
        }
    }

    /// Inverse of [`Self::reorder`].
    #[inline]
    fn unreorder(v: &[T], data: &mut [T]) {
        let n = data.len();
        for (src, dst) in v[..n.div_ceil(2)].iter().zip(data.iter_mut().step_by(2)) {
            *dst = *src;
        }
        for (src, dst) in v[n.div_ceil(2)..]
            .iter()
            .rev()
            .zip(data.iter_mut().skip(1).step_by(2))
        {
            *dst = *src;
        }
    }

    /// Transform length.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always `false`: a plan has at least one point.
    pub fn is_empty(&self) -> bool {
        false
    }

    fn fit(&self, scratch: &mut Scratch<T>) {
        let fft = self
            .forward
            .get_scratch_len()
            .max(self.inverse.get_scratch_len());
        scratch.fit(self.len, self.len / 2 + 1, fft);
    }

    /// In-place forward DCT-II of `data` (length `len`).
    pub fn forward(&self, data: &mut [T], scratch: &mut Scratch<T>) {
        let n = self.len;
        debug_assert_eq!(data.len(), n);
        self.fit(scratch);
        Self::reorder(data, &mut scratch.real);
        self.forward
            .process_with_scratch(&mut scratch.real, &mut scratch.spectrum, &mut scratch.fft)
            .expect("buffer lengths come from the plan");
        let spec = &scratch.spectrum;
        data[0] = spec[0].re;
        // Entries k and n−k come from bin k; split so the loop has no branch.
        let (low, high) = data.split_at_mut(n.div_ceil(2));
        for (k, ((tw, v), lo)) in self.twiddles[1..]
            .iter()
            .zip(&spec[1..])
            .zip(low[1..].iter_mut())
            .enumerate()
        {
            let z = *tw * *v;
            *lo = z.re;
            // k + 1 < n − (k + 1) holds for every bin in `low`.
            high[high.len() - 1 - k] = -z.im;
        }
        if n.is_multiple_of(2) && n > 1 {
            high[0] = (self.twiddles[n / 2] * spec[n / 2]).re;
        }
    }

    /// In-place inverse of [`Self::forward`].
    pub fn inverse(&self, data: &mut [T], scratch: &mut Scratch<T>) {
        let n = self.len;
        debug_assert_eq!(data.len(), n);
        self.fit(scratch);
        for k in 0..=n / 2 {
            let mirrored = if k == 0 { T::zero() } else { data[n - k] };
            let z = Complex::new(data[k], -mirrored);
            scratch.spectrum[k] = self.twiddles[k].conj() * z;
        }
        // The DC bin and (even lengths) the Nyquist bin are real by construction;
        // clear rounding residue so realfft accepts the spectrum.
        scratch.spectrum[0].im = T::zero();
        if n.is_multiple_of(2) {
            scratch.spectrum[n / 2].im = T::zero();
        }
        self.inverse
            .process_with_scratch(&mut scratch.spectrum, &mut scratch.real, &mut scratch.fft)
            .expect("spectrum is Hermitian-valid and lengths come from the plan");
        let scale = T::one() / cast::<T>(n as f64);
        for v in scratch.real.iter_mut() {
            *v = *v * scale;
        }
        Self::unreorder(&scratch.real, data);
    }
}

/// Unnormalised DST-II `X_k = Σ x_n sin(π(2n+1)(k+1) / 2N)` and its exact inverse,
/// through [`DctII`]: `DST-II(x)_k = DCT-II((−1)ⁿ xₙ)_{N−1−k}`.
pub struct DstII<T: Real> {
    dct: DctII<T>,
}

impl<T: Real> DstII<T> {
    /// Plans the transform of length `len` (≥ 1).
    pub fn new(planner: &mut RealFftPlanner<T>, len: usize) -> Self {
        Self {
            dct: DctII::new(planner, len),
        }
    }

    /// Transform length.
    pub fn len(&self) -> usize {
        self.dct.len
    }

    /// Always `false`: a plan has at least one point.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// In-place forward DST-II.
    pub fn forward(&self, data: &mut [T], scratch: &mut Scratch<T>) {
        alternate_signs(data);
        self.dct.forward(data, scratch);
        data.reverse();
    }

    /// In-place inverse of [`Self::forward`].
    pub fn inverse(&self, data: &mut [T], scratch: &mut Scratch<T>) {
        data.reverse();
        self.dct.inverse(data, scratch);
        alternate_signs(data);
    }
}

fn alternate_signs<T: Real>(data: &mut [T]) {
    for v in data.iter_mut().skip(1).step_by(2) {
        *v = -*v;
    }
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

    /// `X_k = Σ x_n basis(n, k, N)` by definition.
    fn naive(x: &[f64], basis: impl Fn(f64, f64, f64) -> f64) -> Vec<f64> {
        let n = x.len() as f64;
        (0..x.len())
            .map(|k| {
                x.iter()
                    .enumerate()
                    .map(|(i, v)| v * basis(i as f64, k as f64, n))
                    .sum()
            })
            .collect()
    }

    fn signal(n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| ((i * 7919) % 113) as f64 / 17.0 - 3.0)
            .collect()
    }

    /// The fast transform matches the definition and its inverse gives the input back.
    fn check(
        lengths: &[usize],
        basis: impl Fn(f64, f64, f64) -> f64,
        mut run: impl FnMut(usize, &mut Vec<f64>, bool),
    ) {
        for &n in lengths {
            let x = signal(n);
            let mut y = x.clone();
            run(n, &mut y, true);
            for (a, b) in y.iter().zip(naive(&x, &basis)) {
                assert!((a - b).abs() < 1e-9 * (1.0 + b.abs()), "n={n}: {a} vs {b}");
            }
            run(n, &mut y, false);
            for (a, b) in y.iter().zip(&x) {
                assert!((a - b).abs() < 1e-10, "n={n} inverse: {a} vs {b}");
            }
        }
    }

    #[test]
    fn dct_matches_definition_and_inverts() {
        let mut planner = RealFftPlanner::new();
        let mut scratch = Scratch::default();
        check(
            &[1, 2, 3, 4, 5, 7, 8, 16, 31, 64, 97],
            |i, k, n| (PI * (2.0 * i + 1.0) * k / (2.0 * n)).cos(),
            |n, y, forward| {
                let plan = DctII::<f64>::new(&mut planner, n);
                if forward {
                    plan.forward(y, &mut scratch)
                } else {
                    plan.inverse(y, &mut scratch)
                }
            },
        );
    }

    #[test]
    fn dst_matches_definition_and_inverts() {
        let mut planner = RealFftPlanner::new();
        let mut scratch = Scratch::default();
        check(
            &[1, 2, 3, 4, 6, 9, 15, 63, 100],
            |i, k, n| (PI * (2.0 * i + 1.0) * (k + 1.0) / (2.0 * n)).sin(),
            |n, y, forward| {
                let plan = DstII::<f64>::new(&mut planner, n);
                if forward {
                    plan.forward(y, &mut scratch)
                } else {
                    plan.inverse(y, &mut scratch)
                }
            },
        );
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
