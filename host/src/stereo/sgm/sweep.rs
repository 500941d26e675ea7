//! Path aggregation: sweeps over the rows that sum, for every pixel and disparity, the
//! cheapest way along each path to reach it (penalty `p1` for a one-pixel step, `p2` for
//! a jump), in `u8` lanes when the penalties allow and `u16` otherwise ([`Lane`]),
//! portable or with AVX2, chosen at run time. The sweeps and their volumes are planned by
//! the matcher ([`super::Schedule`]).

#[cfg(target_arch = "x86_64")]
use super::byte_paths;
use super::census::{CENSUS_BITS, CensusPlanes, run_costs};
use super::params::{Paths, SgmParams, Shape};
use crate::stereo::block_match::Kernel;

/// One sweep over the rows and the paths it follows. Every path of a sweep comes from the
/// row before it or from the same row, so a row's sums are complete as soon as the sweep
/// has passed it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) struct Sweep {
    /// Rows bottom to top (paths arriving from below), each right to left (following
    /// the path along the row that way), instead of top to bottom, left to right.
    upward: bool,
    /// Also the path along the row the other way (a second run over the row).
    both_ways: bool,
    /// Paths from the row before: 1 (straight) or 3 (and the two diagonals).
    from_row_before: usize,
}

impl Paths {
    /// The sweeps that follow these paths: top to bottom, left to right; then, for 4 and 8
    /// paths, bottom to top, right to left, with as many paths as the first.
    pub(super) fn sweeps(self) -> (Sweep, Option<Sweep>) {
        let down = |from_row_before, both_ways| Sweep {
            upward: false,
            both_ways,
            from_row_before,
        };
        let up = |from_row_before| Sweep {
            upward: true,
            both_ways: false,
            from_row_before,
        };
        match self {
            Paths::Three => (down(1, true), None),
            Paths::Four => (down(1, false), Some(up(1))),
            Paths::Five => (down(3, true), None),
            Paths::Eight => (down(3, false), Some(up(3))),
        }
    }
}

/// Where a sweep reads its census costs.
#[derive(Clone, Copy)]
pub(super) enum CostSource<'a> {
    /// Made a row at a time from the two views' census signatures, with this kernel.
    Census(&'a CensusPlanes, &'a CensusPlanes, Kernel),
    /// Read from a volume made beforehand (`[y][x][k]`), for two sweeps over one volume.
    Volume(&'a [u8]),
}

/// The volumes a sweep writes or helps to read, beyond its own rows.
#[derive(Default)]
pub(super) struct SweepVolumes<'a> {
    /// The sums, written into this volume (`[y][x][k]`); without it into a row of the
    /// sweep's own, handed to the sink.
    pub(super) sums: Option<&'a mut [u16]>,
    /// A volume the sink reads the same row of: fetched into the cache a row ahead.
    pub(super) read_by_sink: Option<&'a [u16]>,
}

impl<'a> SweepVolumes<'a> {
    /// The sums written into `sums`, nothing read by the sink.
    pub(super) fn writing(sums: &'a mut [u16]) -> Self {
        Self {
            sums: Some(sums),
            read_by_sink: None,
        }
    }
}

/// What a sweep hands each finished row to: its row number and the row's sums.
pub(super) type RowSink<'a> = &'a mut dyn FnMut(usize, &[u16]);

#[allow(unsafe_code)]
pub(super) fn run_sweep(
    kernel: Kernel,
    s: &Shape,
    p: &SgmParams,
    costs: CostSource<'_>,
    sweep: Sweep,
    volumes: SweepVolumes<'_>,
    sink: RowSink<'_>,
) {
    let narrow = fits_a_byte(p);
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 && crate::cpu::avx2_bmi() {
        // SAFETY: AVX2, BMI1/2, POPCNT and LZCNT were detected just above.
        return unsafe {
            if narrow {
                sweep_avx2::<u8>(s, p, costs, sweep, volumes, sink)
            } else {
                sweep_avx2::<u16>(s, p, costs, sweep, volumes, sink)
            }
        };
    }
    let _ = kernel;
    if narrow {
        sweep_rows::<u8, false>(s, p, costs, sweep, volumes, sink)
    } else {
        sweep_rows::<u16, false>(s, p, costs, sweep, volumes, sink)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
pub(super) fn sweep_avx2<T: Lane>(
    s: &Shape,
    p: &SgmParams,
    costs: CostSource<'_>,
    sweep: Sweep,
    volumes: SweepVolumes<'_>,
    sink: RowSink<'_>,
) {
    sweep_rows::<T, true>(s, p, costs, sweep, volumes, sink)
}

/// Follows `sweep`'s paths over every row: each row's census costs (from `source`), then
/// the sum over the sweep's paths of every pixel's path costs (`[x][k]`; the first path
/// writes, the others add), into that row of `volume` when one is given, else into a row
/// of its own; then `sink(y, sums)`. `AVX2`: the caller runs with AVX2 enabled, and
/// byte lanes at a multiple of 32 disparities step the pixels where no path starts
/// with [`byte_paths::step_paths`].
#[inline(always)]
#[allow(unsafe_code)]
pub(super) fn sweep_rows<T: Lane, const AVX2: bool>(
    s: &Shape,
    p: &SgmParams,
    source: CostSource<'_>,
    sweep: Sweep,
    volumes: SweepVolumes<'_>,
    sink: RowSink<'_>,
) {
    let SweepVolumes {
        sums: mut volume,
        read_by_sink,
    } = volumes;
    // Only prefetched, where that is an instruction.
    #[cfg(not(target_arch = "x86_64"))]
    let _ = read_by_sink;
    let (w, h, nd) = (s.w, s.h, s.nd);
    let stride = nd + 2;
    let used = sweep.from_row_before;
    let pen = Penalties::<T>::of(p);
    // Paths from the row before: that row's values and this row's.
    let mut prev: Vec<PathRow<T>> = (0..used).map(|_| PathRow::new(w, nd)).collect();
    let mut cur: Vec<PathRow<T>> = (0..used).map(|_| PathRow::new(w, nd)).collect();
    let mut along = AlongRow::<T>::new(nd);
    #[cfg(target_arch = "x86_64")]
    let bytes = AVX2 && T::IS_BYTE && nd.is_multiple_of(32);
    let mut made = match source {
        CostSource::Census(..) => vec![0u8; w * nd],
        CostSource::Volume(_) => Vec::new(),
    };
    let mut own = if volume.is_none() {
        vec![0u16; w * nd]
    } else {
        Vec::new()
    };
    for i in 0..h {
        let y = if sweep.upward { h - 1 - i } else { i };
        let cost: &[u8] = match source {
            CostSource::Census(left, right, kernel) => {
                run_costs(kernel, s, left.row(y), right.row(y), &mut made);
                &made
            }
            CostSource::Volume(v) => &v[y * w * nd..][..w * nd],
        };
        // The next row's parts of the volumes, fetched into the cache a pixel at a time
        // as this row is swept (a volume row, 40–80 kB, read when it is needed waits on
        // memory).
        #[cfg(target_arch = "x86_64")]
        let next_row = (i + 1 < h).then(|| if sweep.upward { y - 1 } else { y + 1 });
        #[cfg(target_arch = "x86_64")]
        let prefetch: [Option<(*const u8, usize)>; 3] = match next_row {
            Some(n) if AVX2 => [
                match source {
                    CostSource::Volume(v) => Some((v[n * w * nd..].as_ptr(), nd)),
                    CostSource::Census(..) => None,
                },
                volume
                    .as_deref()
                    .map(|v| (v[n * w * nd..].as_ptr().cast::<u8>(), 2 * nd)),
                read_by_sink.map(|v| (v[n * w * nd..].as_ptr().cast::<u8>(), 2 * nd)),
            ],
            _ => [None; 3],
        };
        let sum: &mut [u16] = match volume.as_deref_mut() {
            Some(v) => &mut v[y * w * nd..][..w * nd],
            None => &mut own,
        };
        for j in 0..w {
            let (x, behind, ahead) = if sweep.upward {
                let x = w - 1 - j;
                (x, (x + 1 < w).then_some(x + 1), x.checked_sub(1))
            } else {
                (j, j.checked_sub(1), (j + 1 < w).then_some(j + 1))
            };
            let c = &cost[x * nd..][..nd];
            let out_sum = &mut sum[x * nd..][..nd];
            #[cfg(target_arch = "x86_64")]
            for &(base, len) in prefetch.iter().flatten() {
                let mut at = x * len;
                while at < (x + 1) * len {
                    // SAFETY: `base` starts a row of `w` pixels of `len` bytes each
                    // inside its volume (taken by checked slicing), and `at` stays in
                    // pixel x's part of it; a prefetch reads and writes nothing.
                    unsafe {
                        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                            base.add(at).cast(),
                        )
                    };
                    at += 64;
                }
            }
            #[cfg(target_arch = "x86_64")]
            if bytes && i > 0 && j > 0 {
                if let (Some(b), Some(a)) = (behind, ahead) {
                    // SAFETY: `bytes` needs AVX2, which the caller enabled.
                    unsafe {
                        interior_bytes(c, &mut along, (&prev, &mut cur), [x, b, a], pen, out_sum)
                    };
                    continue;
                }
                if used == 1 {
                    // SAFETY: as above.
                    unsafe {
                        interior_bytes(c, &mut along, (&prev, &mut cur), [x, x, x], pen, out_sum)
                    };
                    continue;
                }
            }
            // From the row before: straight, then the diagonals from the column behind
            // and the one ahead.
            let sources = [Some(x), behind, ahead];
            let mut first = 0;
            if j > 0 && i > 0 {
                // Along the row and straight down in one run, the sums written once.
                let from = &prev[0].cost[x * stride..][..stride];
                let out = &mut cur[0].cost[x * stride + 1..][..nd];
                cur[0].min[x] =
                    along.pixel_with_straight(c, from, prev[0].min[x], pen, out, out_sum);
                first = 1;
            } else {
                // Along the row (writes the sums).
                along.pixel::<true>(j == 0, c, pen, out_sum);
            }
            for (path, source) in sources.iter().enumerate().take(used).skip(first) {
                let out = &mut cur[path].cost[x * stride + 1..][..nd];
                let least = match *source {
                    Some(sx) if i > 0 => {
                        let from = &prev[path].cost[sx * stride..][..stride];
                        step::<T, false>(c, from, prev[path].min[sx], pen, out, out_sum)
                    }
                    _ => start::<T, false>(c, out, out_sum),
                };
                cur[path].min[x] = least;
            }
        }
        std::mem::swap(&mut prev, &mut cur);
        if sweep.both_ways {
            for j in 0..w {
                let x = if sweep.upward { j } else { w - 1 - j };
                let c = &cost[x * nd..][..nd];
                let out_sum = &mut sum[x * nd..][..nd];
                #[cfg(target_arch = "x86_64")]
                if bytes && j > 0 {
                    // SAFETY: `bytes` needs AVX2, which the caller enabled.
                    unsafe { along_bytes(c, &mut along, pen, out_sum) };
                    continue;
                }
                along.pixel::<false>(j == 0, c, pen, out_sum);
            }
        }
        sink(y, sum);
    }
}

/// The integer type of path costs: `u8` where every value a step can reach fits a byte
/// ([`fits_a_byte`]), twice the lanes of `u16` per vector, else `u16`. Path costs are at
/// most `CENSUS_BITS + p2` and a step's candidates at most `CENSUS_BITS + 2·p2`.
pub(super) trait Lane: Copy + Ord {
    /// Padding either side of a pixel's path costs: `step` reads `d − 1` and `d + 1` for
    /// every `d` without edge cases. Large, so `+ p1` never wins.
    const PAD: Self;
    /// Larger than any path cost.
    const MAX: Self;
    const ZERO: Self;
    /// Byte lanes: [`Lane::bytes`] and [`Lane::bytes_mut`] give the values (read by
    /// the AVX2 path steps only).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    const IS_BYTE: bool;
    /// A census cost.
    fn of_cost(c: u8) -> Self;
    /// A penalty (`p1` or `p2`), which fits when the type was chosen for it.
    fn of_penalty(v: u16) -> Self;
    fn widen(self) -> u16;
    /// Sums that stay in range by the bounds above: wrapping adds, which never wrap
    /// then and keep the loops free of overflow checks in dev and test builds (which
    /// ran the sweeps scalar, ten times slower; the tests check the sums against their
    /// definition).
    fn add(self, o: Self) -> Self;
    /// Sums that may not (a padding lane plus `p1`): clamped at the type's maximum,
    /// which no step ever needs to beat.
    fn add_clamped(self, o: Self) -> Self;
    /// A difference that stays non-negative by the bounds above (wrapping, as `add`).
    fn sub(self, o: Self) -> Self;
    /// The values as bytes, for byte lanes; `None` for wider ones.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn bytes(v: &[Self]) -> Option<&[u8]>;
    /// As [`Lane::bytes`], to write.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn bytes_mut(v: &mut [Self]) -> Option<&mut [u8]>;
}

impl Lane for u8 {
    const PAD: Self = u8::MAX;
    const MAX: Self = u8::MAX;
    const ZERO: Self = 0;
    const IS_BYTE: bool = true;
    #[inline(always)]
    fn of_cost(c: u8) -> Self {
        c
    }
    #[inline(always)]
    fn of_penalty(v: u16) -> Self {
        v as u8
    }
    #[inline(always)]
    fn widen(self) -> u16 {
        u16::from(self)
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.wrapping_add(o)
    }
    #[inline(always)]
    fn add_clamped(self, o: Self) -> Self {
        self.saturating_add(o)
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self.wrapping_sub(o)
    }
    #[inline(always)]
    fn bytes(v: &[Self]) -> Option<&[u8]> {
        Some(v)
    }
    #[inline(always)]
    fn bytes_mut(v: &mut [Self]) -> Option<&mut [u8]> {
        Some(v)
    }
}

impl Lane for u16 {
    const PAD: Self = 0x3fff;
    const MAX: Self = u16::MAX;
    const ZERO: Self = 0;
    const IS_BYTE: bool = false;
    #[inline(always)]
    fn of_cost(c: u8) -> Self {
        u16::from(c)
    }
    #[inline(always)]
    fn of_penalty(v: u16) -> Self {
        v
    }
    #[inline(always)]
    fn widen(self) -> u16 {
        self
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.wrapping_add(o)
    }
    #[inline(always)]
    fn add_clamped(self, o: Self) -> Self {
        self.saturating_add(o)
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self.wrapping_sub(o)
    }
    #[inline(always)]
    fn bytes(_: &[Self]) -> Option<&[u8]> {
        None
    }
    #[inline(always)]
    fn bytes_mut(_: &mut [Self]) -> Option<&mut [u8]> {
        None
    }
}

/// Whether path costs fit `u8` lanes: a step's largest candidate, `CENSUS_BITS + 2·p2`
/// (the previous minimum, at most `CENSUS_BITS + p2`, plus `p2`), stays within a byte,
/// so the clamped padding (255) is never below a candidate that could win.
pub(super) fn fits_a_byte(p: &SgmParams) -> bool {
    u32::from(CENSUS_BITS) + 2 * u32::from(p.p2) <= u32::from(u8::MAX)
}

/// The penalties in a path cost's type.
#[derive(Clone, Copy)]
pub(super) struct Penalties<T> {
    pub(super) p1: T,
    pub(super) p2: T,
}

impl<T: Lane> Penalties<T> {
    pub(super) fn of(p: &SgmParams) -> Self {
        Self {
            p1: T::of_penalty(p.p1),
            p2: T::of_penalty(p.p2),
        }
    }
}

/// Path costs of one row for every pixel (stride `nd + 2`, padded) and their minima.
pub(super) struct PathRow<T> {
    cost: Vec<T>,
    min: Vec<T>,
}

impl<T: Lane> PathRow<T> {
    fn new(w: usize, nd: usize) -> Self {
        Self {
            cost: vec![T::PAD; w * (nd + 2)],
            min: vec![T::ZERO; w],
        }
    }
}

/// The path along a row: the previous pixel's values (padded as [`PathRow`]'s), room for
/// this pixel's, and the previous minimum.
pub(super) struct AlongRow<T> {
    prev: Vec<T>,
    next: Vec<T>,
    min: T,
}

impl<T: Lane> AlongRow<T> {
    fn new(nd: usize) -> Self {
        Self {
            prev: vec![T::PAD; nd + 2],
            next: vec![T::PAD; nd + 2],
            min: T::ZERO,
        }
    }

    /// The next pixel along the row, not its first, and the step of a path from the row
    /// before (`from`, `from_min`, into `out`) in the same run; writes the sums.
    /// Returns the other path's minimum.
    #[inline(always)]
    fn pixel_with_straight(
        &mut self,
        c: &[u8],
        from: &[T],
        from_min: T,
        pen: Penalties<T>,
        out: &mut [T],
        sum: &mut [u16],
    ) -> T {
        let n = c.len();
        let next = &mut self.next[1..=n];
        let (la, lo) = step_two(
            c,
            (&self.prev, self.min),
            (from, from_min),
            pen,
            next,
            out,
            sum,
        );
        self.min = la;
        std::mem::swap(&mut self.prev, &mut self.next);
        lo
    }

    /// The next pixel along the row (`first`: where the path starts): its path costs
    /// from its census costs `c`, added to its sums (or written, `SET`).
    #[inline(always)]
    fn pixel<const SET: bool>(
        &mut self,
        first: bool,
        c: &[u8],
        pen: Penalties<T>,
        sum: &mut [u16],
    ) {
        let out = &mut self.next[1..=c.len()];
        self.min = if first {
            start::<T, SET>(c, out, sum)
        } else {
            step::<T, SET>(c, &self.prev, self.min, pen, out, sum)
        };
        std::mem::swap(&mut self.prev, &mut self.next);
    }
}

/// Two steps of [`step`] in one run over the disparities, writing their sum: the path
/// along the row (`along`, `along_min`) and another (`other`, `other_min`). Returns
/// both minima.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn step_two<T: Lane>(
    cost: &[u8],
    along: (&[T], T),
    other: (&[T], T),
    pen: Penalties<T>,
    out_along: &mut [T],
    out_other: &mut [T],
    sum: &mut [u16],
) -> (T, T) {
    let n = out_along.len();
    let (pa, ma) = along;
    let (po, mo) = other;
    let (ja, jo) = (ma.add(pen.p2), mo.add(pen.p2));
    let (mut la, mut lo) = (T::MAX, T::MAX);
    let a3 = pa[..n].iter().zip(&pa[1..=n]).zip(&pa[2..n + 2]);
    let o3 = po[..n].iter().zip(&po[1..=n]).zip(&po[2..n + 2]);
    let outs = out_along
        .iter_mut()
        .zip(out_other.iter_mut())
        .zip(sum.iter_mut());
    for ((((oa, oo), s), &c), (((&ab, &am), &aa), ((&ob, &om), &oa2))) in
        outs.zip(&cost[..n]).zip(a3.zip(o3))
    {
        let a = path_cost(c, (ab, am, aa), ma, ja, pen.p1);
        let o = path_cost(c, (ob, om, oa2), mo, jo, pen.p1);
        *oa = a;
        *oo = o;
        *s = a.widen().wrapping_add(o.widen());
        la = la.min(a);
        lo = lo.min(o);
    }
    (la, lo)
}

/// One disparity's path cost from its census cost `c` and the previous pixel's path
/// costs at `d − 1`, `d`, `d + 1` (`around`), their minimum over every `d` (`prev_min`)
/// and that plus `p2` (`jump`): [`step`]'s formula, which [`step_two`] shares.
#[inline(always)]
pub(super) fn path_cost<T: Lane>(c: u8, around: (T, T, T), prev_min: T, jump: T, p1: T) -> T {
    let (below, here, above) = around;
    let best = here.min(below.min(above).add_clamped(p1)).min(jump);
    T::of_cost(c).add(best.sub(prev_min))
}

/// A path's first pixel: its costs. Adds them to `sum` (or writes them, `SET`);
/// returns their minimum.
#[inline(always)]
pub(super) fn start<T: Lane, const SET: bool>(cost: &[u8], out: &mut [T], sum: &mut [u16]) -> T {
    let mut least = T::MAX;
    for ((o, s), &c) in out.iter_mut().zip(sum.iter_mut()).zip(cost) {
        *o = T::of_cost(c);
        *s = if SET {
            o.widen()
        } else {
            s.wrapping_add(o.widen())
        };
        least = least.min(*o);
    }
    least
}

/// One step along a path: `L(d) = C(d) + min(L'(d), L'(d ± 1) + p1, min L' + p2) − min L'`
/// with `L'` the previous pixel's values (`prev`, padded: `prev[d + 1]` is `L'(d)`,
/// minimum `prev_min`). Writes `L` into `out`, adds it to `sum` (or writes it, `SET`),
/// returns its minimum. Values are at most `CENSUS_BITS + p2` (≤ 1072), so eight paths
/// sum to at most 8576. The minimum is taken before `C` is added, so no intermediate
/// exceeds `CENSUS_BITS + 2·p2`.
#[inline(always)]
pub(super) fn step<T: Lane, const SET: bool>(
    cost: &[u8],
    prev: &[T],
    prev_min: T,
    pen: Penalties<T>,
    out: &mut [T],
    sum: &mut [u16],
) -> T {
    let n = out.len();
    let jump = prev_min.add(pen.p2);
    let (below, here, above) = (&prev[..n], &prev[1..=n], &prev[2..n + 2]);
    let mut least = T::MAX;
    let lanes = out
        .iter_mut()
        .zip(sum.iter_mut())
        .zip(cost)
        .zip(below.iter().zip(here).zip(above));
    for (((o, s), &c), ((&b, &m), &a)) in lanes {
        *o = path_cost(c, (b, m, a), prev_min, jump, pen.p1);
        *s = if SET {
            o.widen()
        } else {
            s.wrapping_add(o.widen())
        };
        least = least.min(*o);
    }
    least
}

/// Byte lanes' values ([`Lane::bytes`]); called where the lanes are known to be bytes.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn bytes<T: Lane>(v: &[T]) -> &[u8] {
    T::bytes(v).expect("byte lanes")
}

/// As [`bytes`], to write.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn bytes_mut<T: Lane>(v: &mut [T]) -> &mut [u8] {
    T::bytes_mut(v).expect("byte lanes")
}

/// Steps every path of a pixel where none starts (not in the sweep's first row or
/// column, and with the diagonals not in its last column) in one run of
/// [`byte_paths::step_paths`]: the path along the row from `along`, and path `r` from
/// the row before from `rows.0[r]` at column `from[r]` into `rows.1[r]` at column
/// `from[0]`. Writes the sums.
///
/// # Safety
/// The CPU has AVX2; `T` is a byte lane and the disparities a multiple of 32.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
pub(super) unsafe fn interior_bytes<T: Lane>(
    c: &[u8],
    along: &mut AlongRow<T>,
    rows: (&[PathRow<T>], &mut [PathRow<T>]),
    from: [usize; 3],
    pen: Penalties<T>,
    sum: &mut [u16],
) {
    let (prev, cur) = rows;
    let nd = c.len();
    let stride = nd + 2;
    let x = from[0];
    let (p1, p2) = (pen.p1.widen() as u8, pen.p2.widen() as u8);
    let source = |r: usize| {
        let row = &prev[r];
        (
            bytes(&row.cost[from[r] * stride..][..stride]),
            row.min[from[r]].widen() as u8,
        )
    };
    let along_from = (bytes(&along.prev), along.min.widen() as u8);
    let next = bytes_mut(&mut along.next[1..=nd]);
    let at = x * stride + 1;
    match cur {
        [c0] => {
            let out = [next, bytes_mut(&mut c0.cost[at..][..nd])];
            // SAFETY: AVX2, by this function's contract.
            let m = unsafe {
                byte_paths::step_paths::<2, false>(c, [along_from, source(0)], p1, p2, out, sum)
            };
            along.min = T::of_cost(m[0]);
            c0.min[x] = T::of_cost(m[1]);
        }
        [c0, c1, c2] => {
            let out = [
                next,
                bytes_mut(&mut c0.cost[at..][..nd]),
                bytes_mut(&mut c1.cost[at..][..nd]),
                bytes_mut(&mut c2.cost[at..][..nd]),
            ];
            let from = [along_from, source(0), source(1), source(2)];
            // SAFETY: AVX2, by this function's contract.
            let m = unsafe { byte_paths::step_paths::<4, false>(c, from, p1, p2, out, sum) };
            along.min = T::of_cost(m[0]);
            c0.min[x] = T::of_cost(m[1]);
            c1.min[x] = T::of_cost(m[2]);
            c2.min[x] = T::of_cost(m[3]);
        }
        _ => unreachable!("1 or 3 paths from the row before"),
    }
    std::mem::swap(&mut along.prev, &mut along.next);
}

/// The next pixel along the row, not its first, with [`byte_paths::step_paths`]: adds
/// its path costs to `sum`.
///
/// # Safety
/// As [`interior_bytes`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
pub(super) unsafe fn along_bytes<T: Lane>(
    c: &[u8],
    along: &mut AlongRow<T>,
    pen: Penalties<T>,
    sum: &mut [u16],
) {
    let nd = c.len();
    let (p1, p2) = (pen.p1.widen() as u8, pen.p2.widen() as u8);
    let from = [(bytes(&along.prev), along.min.widen() as u8)];
    let out = [bytes_mut(&mut along.next[1..=nd])];
    // SAFETY: AVX2, by this function's contract.
    let [m] = unsafe { byte_paths::step_paths::<1, true>(c, from, p1, p2, out, sum) };
    along.min = T::of_cost(m);
    std::mem::swap(&mut along.prev, &mut along.next);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::sgm::census::{View, census};
    use crate::stereo::sgm::tests::shifted_pair;

    /// The definition of aggregation: for each path direction `(dx, dy)` (the previous
    /// pixel is `(x − dx, y − dy)`), `L(p, d) = C(p, d) + min(L(p′, d), L(p′, d ± 1) + p1,
    /// min L(p′) + p2) − min L(p′)`, starting with `C` where `p′` is off the image; the
    /// sum over the directions, in i64 with no reuse of anything the sweeps share.
    fn aggregated_by_definition(
        left: &CensusPlanes,
        right: &CensusPlanes,
        p: &SgmParams,
        directions: &[(isize, isize)],
    ) -> Vec<i64> {
        let (w, h) = (left.width, left.height);
        let nd = p.num_disparities as usize;
        let cost = |x: usize, y: usize, k: usize| -> i64 {
            let xr = x as isize - (p.min_disparity as usize + k) as isize;
            if xr < 0 {
                i64::from(CENSUS_BITS)
            } else {
                let (a, b) = (left.signature(x, y), right.signature(xr as usize, y));
                i64::from((a ^ b).count_ones())
            }
        };
        let mut total = vec![0i64; w * h * nd];
        for &(dx, dy) in directions {
            let mut l = vec![0i64; w * h * nd];
            // Rows and columns in the order the path runs, so p′ comes before p.
            let ys: Vec<usize> = if dy < 0 {
                (0..h).rev().collect()
            } else {
                (0..h).collect()
            };
            let xs: Vec<usize> = if dx < 0 {
                (0..w).rev().collect()
            } else {
                (0..w).collect()
            };
            for &y in &ys {
                for &x in &xs {
                    let (px, py) = (x as isize - dx, y as isize - dy);
                    let inside = px >= 0 && py >= 0 && px < w as isize && py < h as isize;
                    for k in 0..nd {
                        let c = cost(x, y, k);
                        let v = if inside {
                            let at = |k: usize| l[(py as usize * w + px as usize) * nd + k];
                            let least = (0..nd).map(at).min().unwrap();
                            let mut best = at(k).min(least + i64::from(p.p2));
                            if k > 0 {
                                best = best.min(at(k - 1) + i64::from(p.p1));
                            }
                            if k + 1 < nd {
                                best = best.min(at(k + 1) + i64::from(p.p1));
                            }
                            c + best - least
                        } else {
                            c
                        };
                        l[(y * w + x) * nd + k] = v;
                    }
                }
            }
            for (t, v) in total.iter_mut().zip(&l) {
                *t += v;
            }
        }
        total
    }

    /// The sweeps' sums over every path, as `compute` combines them: the second sweep
    /// adding its rows as it goes (one thread), or into a volume of its own
    /// (`side_by_side`).
    fn aggregated_by_sweeps(
        kernel: Kernel,
        left: &CensusPlanes,
        right: &CensusPlanes,
        p: &SgmParams,
        side_by_side: bool,
    ) -> Vec<i64> {
        let s = Shape {
            w: left.width,
            h: left.height,
            nd: p.num_disparities as usize,
            d_min: p.min_disparity as usize,
        };
        let row_cells = s.w * s.nd;
        let mut total = vec![0i64; row_cells * s.h];
        let (first, second) = p.paths.sweeps();
        let mut add = |y: usize, sum: &[u16]| {
            for (t, &v) in total[y * row_cells..][..row_cells].iter_mut().zip(sum) {
                *t += i64::from(v);
            }
        };
        match second {
            None => run_sweep(
                kernel,
                &s,
                p,
                CostSource::Census(left, right, kernel),
                first,
                SweepVolumes::default(),
                &mut add,
            ),
            Some(second) => {
                let mut volume = vec![0u8; row_cells * s.h];
                for (y, row) in volume.chunks_exact_mut(row_cells).enumerate() {
                    run_costs(kernel, &s, left.row(y), right.row(y), row);
                }
                let costs = CostSource::Volume(&volume);
                let mut sums = vec![0u16; row_cells * s.h];
                run_sweep(
                    kernel,
                    &s,
                    p,
                    costs,
                    first,
                    SweepVolumes::writing(&mut sums),
                    &mut |_, _| {},
                );
                for (y, row) in sums.chunks_exact(row_cells).enumerate() {
                    add(y, row);
                }
                if side_by_side {
                    let mut own = vec![0u16; row_cells * s.h];
                    run_sweep(
                        kernel,
                        &s,
                        p,
                        costs,
                        second,
                        SweepVolumes::writing(&mut own),
                        &mut |_, _| {},
                    );
                    for (y, row) in own.chunks_exact(row_cells).enumerate() {
                        add(y, row);
                    }
                } else {
                    let volumes = SweepVolumes {
                        sums: None,
                        read_by_sink: Some(&sums),
                    };
                    run_sweep(kernel, &s, p, costs, second, volumes, &mut add);
                }
            }
        }
        total
    }

    #[test]
    fn the_sweeps_sum_each_path_as_defined() {
        let (l, r) = shifted_pair(75, 23, |x, y| 9.0 + 0.1 * x as f32 - 0.2 * y as f32);
        let cl = census(Kernel::Portable, &l, View::Left, Vec::new());
        let along_and_down = [(1, 0), (-1, 0), (0, 1)];
        let straight = [(1, 0), (-1, 0), (0, 1), (0, -1)];
        let from_above = [(1, 0), (-1, 0), (0, 1), (1, 1), (-1, 1)];
        let every = [
            (1, 0),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (-1, 1),
            (1, -1),
            (-1, -1),
        ];
        for (paths, directions) in [
            (Paths::Three, &along_and_down[..]),
            (Paths::Four, &straight[..]),
            (Paths::Five, &from_above[..]),
            (Paths::Eight, &every[..]),
        ] {
            // p2 = 103: the largest with byte lanes; 104 and 300: 16-bit lanes. 32
            // disparities: byte lanes with the AVX2 kernel take the pixels where no path
            // starts (byte_paths).
            let cases = [(8, 96, 16), (30, 103, 16), (8, 104, 16), (40, 300, 16)]
                .into_iter()
                .chain([(8, 96, 32), (30, 103, 32), (8, 104, 32)]);
            for (p1, p2, nd) in cases {
                let p = SgmParams {
                    min_disparity: 3,
                    num_disparities: nd,
                    paths,
                    p1,
                    p2,
                    ..SgmParams::default()
                };
                // Padding nd + d_min: every run of candidates inside.
                let pad = nd as usize + 3;
                let cr = census(Kernel::Portable, &r, View::Right { pad }, Vec::new());
                assert_eq!(fits_a_byte(&p), p2 <= 103);
                let expected = aggregated_by_definition(&cl, &cr, &p, directions);
                for kernel in Kernel::tested() {
                    for side_by_side in [false, true] {
                        let got = aggregated_by_sweeps(kernel, &cl, &cr, &p, side_by_side);
                        let first_miss = got.iter().zip(&expected).position(|(a, b)| a != b);
                        assert_eq!(
                            first_miss, None,
                            "{paths:?} {kernel:?} p1 {p1} p2 {p2} {nd} d, side by side \
                             {side_by_side}"
                        );
                    }
                }
            }
        }
    }

    /// Byte lanes at their bound (p2 = 103): previous path costs at the largest a path
    /// can hold (`CENSUS_BITS + p2`) or 0, census costs 0 or the largest, next to the
    /// padding; every step equals the 16-bit one.
    #[test]
    fn byte_lanes_at_their_bound_equal_16_bit_lanes() {
        let p = SgmParams {
            p1: 30,
            p2: 103,
            ..SgmParams::default()
        };
        assert!(fits_a_byte(&p));
        let high = u16::from(CENSUS_BITS) + p.p2;
        let nd = 16;
        let mut rng = crate::rng::Rng::new(5);
        for round in 0..200 {
            let mut prev16 = vec![<u16 as Lane>::PAD; nd + 2];
            let mut prev8 = vec![<u8 as Lane>::PAD; nd + 2];
            for k in 0..nd {
                let v = if rng.uniform() < 0.5 { high } else { 0 };
                prev16[k + 1] = v;
                prev8[k + 1] = v as u8;
            }
            // A previous minimum as a step leaves it: the least of the values.
            let min16 = prev16[1..=nd].iter().copied().min().unwrap();
            let cost: Vec<u8> = (0..nd)
                .map(|_| if rng.uniform() < 0.5 { CENSUS_BITS } else { 0 })
                .collect();
            let (mut out16, mut out8) = (vec![0u16; nd], vec![0u8; nd]);
            let (mut sum16, mut sum8) = (vec![round; nd], vec![round; nd]);
            let least16 = step::<u16, false>(
                &cost,
                &prev16,
                min16,
                Penalties::of(&p),
                &mut out16,
                &mut sum16,
            );
            let least8 = step::<u8, false>(
                &cost,
                &prev8,
                min16 as u8,
                Penalties::of(&p),
                &mut out8,
                &mut sum8,
            );
            assert_eq!(u16::from(least8), least16);
            assert!(out16.iter().zip(&out8).all(|(&a, &b)| a == u16::from(b)));
            assert_eq!(sum16, sum8);
            assert!(out16.iter().all(|&v| v <= high));
        }
    }
}
