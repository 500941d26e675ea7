//! False-colour pictures people can read: a depth or disparity map in
//! [`crate::output::colour_map`]'s colours with a colour bar beside it that states the
//! range and its unit, so two pictures are compared by their legends, not guessed at.
//!
//! The range is chosen by the caller ([`RangeChoice`]): fixed (a command's `--range`,
//! or the depths searched), or from the data's own percentiles; [`ColourRange`] says
//! which, and goes into `summary.json`. Values outside the range take the end colours;
//! pixels without a value are black. Tactile and stereo outputs both draw through here.

use std::path::Path;

use image::{Rgb, RgbImage};
use serde::Serialize;

use crate::grid::Grid;
use crate::output::{OutputError, colour_map, image_error};

/// How to choose a picture's range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RangeChoice {
    /// From `lo` to `hi` as given.
    Fixed {
        /// Value shown in the first colour.
        lo: f32,
        /// Value shown in the last colour.
        hi: f32,
    },
    /// From the data's `lo`-th to its `hi`-th percentile (of the pixels with a value).
    Percentiles {
        /// Lower percentile, 0–100.
        lo: f32,
        /// Upper percentile, 0–100.
        hi: f32,
    },
}

impl RangeChoice {
    /// The usual automatic choice: the 2nd to the 98th percentile.
    pub const AUTO: Self = Self::Percentiles { lo: 2.0, hi: 98.0 };

    /// Reads a command-line range: `auto`, or `LO,HI` (numbers, LO below HI).
    pub fn parse(text: &str) -> Result<Self, String> {
        if text.trim().eq_ignore_ascii_case("auto") {
            return Ok(Self::AUTO);
        }
        let bad =
            || format!("expected `auto` or `LO,HI` (two numbers, LO below HI), found {text:?}");
        let (lo, hi) = text.split_once(',').ok_or_else(bad)?;
        let (lo, hi): (f32, f32) = (
            lo.trim().parse().map_err(|_| bad())?,
            hi.trim().parse().map_err(|_| bad())?,
        );
        if lo.is_finite() && hi.is_finite() && lo < hi {
            Ok(Self::Fixed { lo, hi })
        } else {
            Err(bad())
        }
    }

    /// The range for `grid`, at least `min_span` wide (a flat or empty map would
    /// otherwise have no range at all); `unit` names the values' unit.
    pub fn resolve(&self, grid: &Grid<f32>, min_span: f32, unit: &'static str) -> ColourRange {
        let (lo, hi, from) = match *self {
            Self::Fixed { lo, hi } => (lo, hi, "given".to_string()),
            Self::Percentiles { lo, hi } => {
                let mut v: Vec<f32> = grid
                    .as_slice()
                    .iter()
                    .copied()
                    .filter(|v| v.is_finite())
                    .collect();
                let from = format!("percentiles {lo}–{hi} of the data");
                if v.is_empty() {
                    (0.0, min_span, format!("{from} (no values: none shown)"))
                } else {
                    v.sort_unstable_by(f32::total_cmp);
                    let at = |p: f32| {
                        let i = (p.clamp(0.0, 100.0) / 100.0 * (v.len() - 1) as f32).round();
                        v[i as usize]
                    };
                    (at(lo), at(hi), from)
                }
            }
        };
        let hi = hi.max(lo + min_span);
        ColourRange { lo, hi, unit, from }
    }
}

/// The range a picture shows (written into `summary.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ColourRange {
    /// Value of the first colour (dark blue).
    pub lo: f32,
    /// Value of the last colour (red).
    pub hi: f32,
    /// Unit of the values.
    pub unit: &'static str,
    /// How it was chosen.
    pub from: String,
}

/// Least width of the legend beside the picture (px); wider when its labels need it.
const LEGEND_WIDTH: u32 = 96;
/// Glyph scale of the legend's text (font pixels per image pixel).
const TEXT_SCALE: u32 = 2;
/// Advance of one character of the legend's text (px).
const CHAR_WIDTH: u32 = 6 * TEXT_SCALE;
/// The labels start this far right of the legend's left edge (past the bar).
const LABEL_X: u32 = 22;

/// `grid` in false colour over `range`, with the legend on the right: a colour bar from
/// `lo` (bottom) to `hi` (top) and five labelled ticks, the unit on top; a grid without
/// a value (nothing matched) says "none" under the unit instead (a bar would state a
/// range of nothing).
pub fn with_legend(grid: &Grid<f32>, range: &ColourRange) -> RgbImage {
    let (w, h) = (grid.width() as u32, grid.height() as u32);
    let span = range.hi - range.lo;
    let labels = tick_labels(range);
    // As wide as the longest label (a range like -1234.5 to 20000 has seven characters
    // and more), so none is cut.
    let longest = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32;
    let legend = LEGEND_WIDTH
        .max(LABEL_X + longest * CHAR_WIDTH + 4)
        .max(6 + range.unit.chars().count() as u32 * CHAR_WIDTH + 4);
    let mut img = RgbImage::from_pixel(w + legend, h.max(1), Rgb([24, 24, 28]));
    for (i, v) in grid.as_slice().iter().enumerate() {
        let (x, y) = ((i % grid.width()) as u32, (i / grid.width()) as u32);
        let c = if v.is_finite() {
            colour_map((v - range.lo) / span)
        } else {
            [0, 0, 0]
        };
        img.put_pixel(x, y, Rgb(c));
    }
    let glyph_h = 7 * TEXT_SCALE;
    let top = glyph_h + 16;
    let bottom = h.saturating_sub(glyph_h / 2 + 4);
    if bottom <= top + 10 {
        return img; // too small for a legend: the colours alone
    }
    let bar_x = w + 6;
    if !grid.as_slice().iter().any(|v| v.is_finite()) {
        draw_text(&mut img, bar_x, 3, range.unit);
        draw_text(&mut img, bar_x, top, "none");
        return img;
    }
    for y in top..=bottom {
        let t = (bottom - y) as f32 / (bottom - top) as f32;
        for x in bar_x..bar_x + 12 {
            img.put_pixel(x, y, Rgb(colour_map(t)));
        }
    }
    draw_text(&mut img, bar_x, 3, range.unit);
    for (k, label) in labels.iter().enumerate() {
        let t = k as f32 / 4.0;
        let y = bottom - ((bottom - top) as f32 * t).round() as u32;
        // The tick left of the bar, so it never reads as a minus sign.
        for x in bar_x - 5..bar_x - 1 {
            img.put_pixel(x, y, Rgb([230, 230, 230]));
        }
        draw_text(&mut img, w + LABEL_X, y.saturating_sub(glyph_h / 2), label);
    }
    img
}

/// When a range given by the user shows none of `grid`'s values (the picture `name` is
/// one end colour, or black), the warning that says so, with the values' own span.
pub fn none_within(range: &ColourRange, grid: &Grid<f32>, name: &str) -> Option<String> {
    let (mut lo, mut hi, mut count) = (f32::INFINITY, f32::NEG_INFINITY, 0usize);
    for &v in grid.as_slice().iter().filter(|v| v.is_finite()) {
        if (range.lo..=range.hi).contains(&v) {
            return None;
        }
        (lo, hi, count) = (lo.min(v), hi.max(v), count + 1);
    }
    let decimals = decimals_for(hi - lo).max(decimals_for(range.hi - range.lo));
    let unit = range.unit;
    Some(if count == 0 {
        format!("{name}: there are no values to show in the range given")
    } else {
        format!(
            "{name}: none of its {count} values ({lo:.decimals$}–{hi:.decimals$} {unit}) lies \
             within the range given, {:.decimals$}–{:.decimals$} {unit}: the picture shows \
             one end colour; give a range around the values, or `auto`",
            range.lo, range.hi
        )
    })
}

/// The five tick labels of `range`, bottom to top.
fn tick_labels(range: &ColourRange) -> Vec<String> {
    let span = range.hi - range.lo;
    let decimals = decimals_for(span);
    (0..5)
        .map(|k| {
            let value = range.lo + span * k as f32 / 4.0;
            // No "-0.00": a value that rounds to zero is written as zero.
            let value = if value.abs() < 0.5 * 10f32.powi(-(decimals as i32)) {
                0.0
            } else {
                value
            };
            format!("{value:.decimals$}")
        })
        .collect()
}

/// Writes [`with_legend`] as a PNG.
pub fn write_png(path: &Path, grid: &Grid<f32>, range: &ColourRange) -> Result<(), OutputError> {
    with_legend(grid, range)
        .save(path)
        .map_err(image_error(path))
}

/// Decimals enough to tell five ticks over `span` apart.
fn decimals_for(span: f32) -> usize {
    match span / 4.0 {
        s if s >= 10.0 => 0,
        s if s >= 1.0 => 1,
        s if s >= 0.1 => 2,
        _ => 3,
    }
}

/// Draws `text` with its top-left corner at `(x, y)`, clipped to the image; characters
/// the font lacks are drawn as blanks.
fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str) {
    let mut cx = x;
    for ch in text.chars() {
        if let Some(rows) = glyph(ch) {
            for (gy, row) in rows.iter().enumerate() {
                for gx in 0..5u32 {
                    if row & (0b10000 >> gx) == 0 {
                        continue;
                    }
                    for sy in 0..TEXT_SCALE {
                        for sx in 0..TEXT_SCALE {
                            let (px, py) =
                                (cx + gx * TEXT_SCALE + sx, y + gy as u32 * TEXT_SCALE + sy);
                            if px < img.width() && py < img.height() {
                                img.put_pixel(px, py, Rgb([235, 235, 235]));
                            }
                        }
                    }
                }
            }
        }
        cx += CHAR_WIDTH;
    }
}

/// A 5×7 pixel font for the characters legends use (rows top to bottom, bit 4 left).
fn glyph(c: char) -> Option<[u8; 7]> {
    Some(match c {
        '0' => [0x0e, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0e],
        '1' => [0x04, 0x0c, 0x04, 0x04, 0x04, 0x04, 0x0e],
        '2' => [0x0e, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1f],
        '3' => [0x1f, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0e],
        '4' => [0x02, 0x06, 0x0a, 0x12, 0x1f, 0x02, 0x02],
        '5' => [0x1f, 0x10, 0x1e, 0x01, 0x01, 0x11, 0x0e],
        '6' => [0x06, 0x08, 0x10, 0x1e, 0x11, 0x11, 0x0e],
        '7' => [0x1f, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0e, 0x11, 0x11, 0x0e, 0x11, 0x11, 0x0e],
        '9' => [0x0e, 0x11, 0x11, 0x0f, 0x01, 0x02, 0x0c],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0c, 0x0c],
        '-' => [0x00, 0x00, 0x00, 0x1f, 0x00, 0x00, 0x00],
        'm' => [0x00, 0x00, 0x1a, 0x15, 0x15, 0x11, 0x11],
        'p' => [0x00, 0x00, 0x1e, 0x11, 0x1e, 0x10, 0x10],
        'x' => [0x00, 0x00, 0x11, 0x0a, 0x04, 0x0a, 0x11],
        'n' => [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11],
        'o' => [0x00, 0x00, 0x0e, 0x11, 0x11, 0x11, 0x0e],
        'e' => [0x00, 0x00, 0x0e, 0x11, 0x1f, 0x10, 0x0e],
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_parse_resolve_and_never_collapse() {
        assert_eq!(RangeChoice::parse("auto"), Ok(RangeChoice::AUTO));
        assert_eq!(
            RangeChoice::parse(" 100, 300 "),
            Ok(RangeChoice::Fixed {
                lo: 100.0,
                hi: 300.0
            })
        );
        for bad in ["", "1", "3,1", "1,1", "a,b", "nan,1", "1,inf"] {
            assert!(RangeChoice::parse(bad).is_err(), "{bad:?}");
        }
        // 0..=99 with a NaN: the 2nd to 98th percentiles.
        let mut g = Grid::from_fn(10, 10, |x, y| (y * 10 + x) as f32);
        g.as_mut_slice()[0] = f32::NAN;
        let r = RangeChoice::AUTO.resolve(&g, 0.1, "mm");
        assert_eq!((r.lo, r.hi), (3.0, 97.0));
        assert!(r.from.contains("percentiles"));
        // A flat map still has a range; an empty one gets the default.
        let flat = Grid::filled(4, 4, 0.0f32);
        let r = RangeChoice::AUTO.resolve(&flat, 0.5, "mm");
        assert_eq!((r.lo, r.hi), (0.0, 0.5));
        let none = Grid::filled(4, 4, f32::NAN);
        let r = RangeChoice::AUTO.resolve(&none, 0.5, "mm");
        assert_eq!((r.lo, r.hi), (0.0, 0.5));
        assert!(r.from.contains("no values"));
        let fixed = RangeChoice::Fixed { lo: 1.0, hi: 2.0 }.resolve(&flat, 0.1, "px");
        assert_eq!(
            (fixed.lo, fixed.hi, fixed.from.as_str()),
            (1.0, 2.0, "given")
        );
    }

    #[test]
    fn the_legend_shows_the_range_beside_the_picture() {
        let g = Grid::from_fn(64, 96, |x, _| x as f32);
        let r = RangeChoice::Fixed { lo: 0.0, hi: 63.0 }.resolve(&g, 0.1, "mm");
        let img = with_legend(&g, &r);
        assert_eq!(img.dimensions(), (64 + LEGEND_WIDTH, 96));
        // The picture: first colour at lo, last at hi.
        assert_eq!(img.get_pixel(0, 10).0, colour_map(0.0));
        assert_eq!(img.get_pixel(63, 10).0, colour_map(1.0));
        // The bar runs from the last colour at the top to the first at the bottom, and
        // the legend has text (light pixels) beside it.
        let bar_x = 64 + 6 + 6;
        let column: Vec<[u8; 3]> = (0..96).map(|y| img.get_pixel(bar_x, y).0).collect();
        assert!(column.contains(&colour_map(1.0)) && column.contains(&colour_map(0.0)));
        let text = img.pixels().filter(|p| p.0 == [235, 235, 235]).count();
        assert!(text > 50, "{text} text pixels");
        // NaN is black; a picture too small for a legend still shows its colours.
        let mut holes = g.clone();
        holes.as_mut_slice()[5] = f32::NAN;
        assert_eq!(with_legend(&holes, &r).get_pixel(5, 0).0, [0, 0, 0]);
        let tiny = Grid::filled(3, 3, 1.0f32);
        assert_eq!(with_legend(&tiny, &r).dimensions(), (3 + LEGEND_WIDTH, 3));
        let empty = Grid::filled(0, 0, 1.0f32);
        assert_eq!(with_legend(&empty, &r).width(), LEGEND_WIDTH);
        // Nothing to show: no colour bar (it would state a range of nothing), the unit
        // and "none" instead.
        let nothing = Grid::filled(64, 96, f32::NAN);
        let img = with_legend(&nothing, &RangeChoice::AUTO.resolve(&nothing, 1.0, "mm"));
        let bar: Vec<[u8; 3]> = (0..96).map(|y| img.get_pixel(bar_x, y).0).collect();
        assert!(!bar.contains(&colour_map(0.0)), "no bar");
        let text = img.pixels().filter(|p| p.0 == [235, 235, 235]).count();
        assert!(text > 50, "{text} text pixels");
    }

    #[test]
    fn a_given_range_that_shows_no_value_is_said() {
        let g = Grid::from_fn(8, 8, |x, _| 150.0 + x as f32 * 20.0);
        let range = |lo, hi| RangeChoice::Fixed { lo, hi }.resolve(&g, 1.0, "mm");
        assert_eq!(none_within(&range(100.0, 160.0), &g, "d.png"), None);
        let w = none_within(&range(1000.0, 2000.0), &g, "d.png").unwrap();
        assert!(
            w.contains("none of its 64 values (150–290 mm)") && w.contains("1000–2000 mm"),
            "{w}"
        );
        let nothing = Grid::filled(4, 4, f32::NAN);
        assert!(none_within(&range(0.0, 1.0), &nothing, "d.png").is_some());
    }

    #[test]
    fn long_labels_widen_the_legend_instead_of_being_cut() {
        // Ticks -1000.00 to -999.00: eight characters, past the least width's six.
        let g = Grid::filled(64, 96, -999.5f32);
        let r = RangeChoice::Fixed {
            lo: -1000.0,
            hi: -999.0,
        }
        .resolve(&g, 0.1, "mm");
        assert_eq!(tick_labels(&r)[0], "-1000.00");
        let img = with_legend(&g, &r);
        let right = 64 + LABEL_X + 8 * CHAR_WIDTH;
        assert!(img.width() >= right, "{} < {right}", img.width());
        // The last label's last character ('0') is drawn in its column.
        let last_char = (right - CHAR_WIDTH..right)
            .any(|x| (0..img.height()).any(|y| img.get_pixel(x, y).0 == [235, 235, 235]));
        assert!(last_char, "the labels' last characters are missing");
        // Short labels keep the least width.
        let r = RangeChoice::Fixed { lo: 0.0, hi: 1.0 }.resolve(&g, 0.1, "mm");
        assert_eq!(with_legend(&g, &r).width(), 64 + LEGEND_WIDTH);
    }

    #[test]
    fn every_legend_character_has_a_glyph() {
        for c in "0123456789.-mpxnoe".chars() {
            assert!(glyph(c).is_some(), "{c}");
        }
        assert!(glyph('?').is_none());
    }
}
