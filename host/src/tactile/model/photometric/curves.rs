//! The photometric model's response: how the skin and the camera turn light into colour,
//! `c^P·|n|^e = 1 − a·p − b·q` ([`Response`]), and its curves as a read evaluates them,
//! exactly or from tables made once ([`Curves`]).
//!
//! Numbers: f64; outside a table's span, and for NaN, the exact curve; a matte response's
//! curves are exact whichever way they are made.

use super::MAX_SLOPE;

/// How the skin and camera turn light into colour: `c^P·|n|^e = 1 − a·p − b·q`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Response {
    /// `P`, the colour's power.
    pub colour: f64,
    /// `e`, the power of `|n| = √(1 + p² + q²)`.
    pub norm: f64,
}

impl Response {
    /// A matte skin seen by a linear camera.
    pub const MATTE: Self = Self {
        colour: 1.0,
        norm: 1.0,
    };

    /// `c^P`, the colour made linear in the slopes' shading.
    #[inline]
    pub(super) fn linear(self, c: f64) -> f64 {
        if self.colour == 1.0 {
            c
        } else {
            c.powf(self.colour)
        }
    }

    /// `|n|^e` from `|n|²`.
    #[inline]
    pub(super) fn norm_factor(self, norm_sq: f64) -> f64 {
        if self.norm == 1.0 {
            norm_sq.sqrt()
        } else {
            norm_sq.powf(0.5 * self.norm)
        }
    }

    /// The colour of a strip whose shading `1 − a·p − b·q` is `shade` at slopes with
    /// `|n|² = norm_sq` (0 where the strip faces away).
    #[inline]
    pub(super) fn predict(self, shade: f64, norm_sq: f64) -> f64 {
        self.colour_of_linear((shade / self.norm_factor(norm_sq)).max(0.0))
    }

    /// `v^(1/P)`: the colour whose linear value is `v`.
    #[inline]
    fn colour_of_linear(self, v: f64) -> f64 {
        if self.colour == 1.0 {
            v
        } else {
            v.powf(1.0 / self.colour)
        }
    }
}

/// The response's curves as a read evaluates them: exactly, or from tables made once for
/// a model ([`Curves::tabled`]: each `powf` of the exact curves costs as much as the rest
/// of a pixel's read). Outside a table, or where a curve has none, [`Response`]'s exact
/// curve answers; a matte response has no tables, so its curves are exact either way (bit
/// for bit the matte model's reading).
#[derive(Debug, Clone)]
pub struct Curves {
    pub(super) response: Response,
    /// `c^P` for colours in [[`TABLE_LOW`], [`TABLE_HIGH`]].
    linear: Table,
    /// `v^(1/P)` for `v` in [[`TABLE_LOW`], [`TABLE_HIGH`]].
    predict: Table,
    /// `x^(e/2)` for `|n|²` from 1 to `1 + 2·MAX_SLOPE²`.
    norm: Table,
}

/// Entries of each of [`Curves`]' tables.
const TABLE_ENTRIES: usize = 2048;

/// The tables of [`Curves`] span colours from here (below, the exact curve: a strip this
/// dark is shadowed, and `v^(1/P)` bends most near 0)...
const TABLE_LOW: f64 = 0.05;

/// ...to here (four times flat skin's colour; above, the exact curve).
const TABLE_HIGH: f64 = 4.0;

impl Curves {
    /// The exact curves (no tables).
    pub fn exact(response: Response) -> Self {
        Self {
            response,
            linear: Table::default(),
            predict: Table::default(),
            norm: Table::default(),
        }
    }

    /// The curves tabled, linear between [`TABLE_ENTRIES`] entries (within 2e-5 of the
    /// exact curves over the tables' spans, a test holds), exact outside them.
    pub fn tabled(response: Response) -> Self {
        let Response { colour, norm } = response;
        let colour_table = |power: f64| {
            if colour == 1.0 {
                Table::default()
            } else {
                Table::new(TABLE_LOW, TABLE_HIGH, |c| c.powf(power))
            }
        };
        Self {
            response,
            linear: colour_table(colour),
            predict: colour_table(1.0 / colour),
            norm: if norm == 1.0 {
                Table::default()
            } else {
                Table::new(1.0, 1.0 + 2.0 * MAX_SLOPE * MAX_SLOPE, |x| {
                    x.powf(0.5 * norm)
                })
            },
        }
    }

    /// `c^P`.
    #[inline]
    pub(super) fn linear(&self, c: f64) -> f64 {
        self.linear.at(c, |c| self.response.linear(c))
    }

    /// `|n|^e` from `|n|²`.
    #[inline]
    pub(super) fn norm_factor(&self, norm_sq: f64) -> f64 {
        self.norm.at(norm_sq, |x| self.response.norm_factor(x))
    }

    /// [`Response::predict`].
    #[cfg(test)]
    pub(super) fn predict(&self, shade: f64, norm_sq: f64) -> f64 {
        self.colour_of(shade, self.norm_factor(norm_sq))
    }

    /// The colour of a strip whose shading `1 − a·p − b·q` is `shade` where `|n|^e` is
    /// `norm_factor`: `(shade / norm_factor)^(1/P)`, 0 where the strip faces away.
    #[inline]
    pub(super) fn colour_of(&self, shade: f64, norm_factor: f64) -> f64 {
        let v = (shade / norm_factor).max(0.0);
        self.predict.at(v, |v| self.response.colour_of_linear(v))
    }
}

/// A curve's values at evenly spaced points, read linearly between them; empty: the
/// exact curve everywhere.
#[derive(Debug, Clone, Default)]
struct Table {
    low: f64,
    /// Entries per unit.
    scale: f64,
    values: Vec<f64>,
}

impl Table {
    fn new(low: f64, high: f64, f: impl Fn(f64) -> f64) -> Self {
        let step = (high - low) / (TABLE_ENTRIES - 1) as f64;
        Self {
            low,
            scale: 1.0 / step,
            values: (0..TABLE_ENTRIES)
                .map(|i| f(low + i as f64 * step))
                .collect(),
        }
    }

    /// The curve at `x`: from the table inside its span, else `exact(x)` (NaN too, and
    /// everywhere for an empty table).
    #[inline]
    fn at(&self, x: f64, exact: impl Fn(f64) -> f64) -> f64 {
        let u = (x - self.low) * self.scale;
        let last = self.values.len().saturating_sub(1);
        if u >= 0.0 && u < last as f64 {
            let i = u as usize;
            let (a, b) = (self.values[i], self.values[i + 1]);
            a + (u - i as f64) * (b - a)
        } else {
            exact(x)
        }
    }
}
