//! Checks a model read from a file before anything uses it: every array has the length
//! its declared sizes say, sizes are bounded by what a sensor's camera can produce, and
//! every scale is finite and positive. A model file is input written by someone else;
//! without this a short array panics deep in reconstruction and a zero scale makes
//! infinite depth.

use super::TactileModel;
use super::light::LightModel;
use super::lut::Lut;
use super::mlp::Mlp;
use super::photometric::{COLOUR_POWERS, NORM_POWERS, PhotometricModel};
use crate::tactile::contact::MAX_THRESHOLD;

/// Largest frame side a model may declare (px): no sensor camera we support gives more,
/// and it bounds what a model file can make us allocate.
pub use crate::limits::MAX_FRAME_SIDE;
/// Thinnest and thickest skin a model may state (mm).
pub const MIN_SKIN_THICKNESS_MM: f64 = 0.1;
/// See [`MIN_SKIN_THICKNESS_MM`].
pub const MAX_SKIN_THICKNESS_MM: f64 = 50.0;
/// Largest LUT side (bins) and MLP layer width a model may declare.
const MAX_TABLE: usize = 1024;

/// The least image scale of a tactile sensor (px/mm, exclusive): below it a 640 px frame
/// would span more than a metre of skin.
pub const MIN_PX_PER_MM: f64 = 0.5;
/// The largest scale (px/mm) and ball diameter (mm) a model, a calibration's settings or
/// a press may state: wide of any tactile sensor, it keeps sizes computed from them bounded.
pub const MAX_SCALE: f64 = 1000.0;

/// Whether `d` is a ball diameter (mm) the calibration and a model file accept: finite,
/// above 0 and at most [`MAX_SCALE`]. The CLI, the settings and each press check with it,
/// so the bound cannot drift between them.
pub fn valid_ball_diameter(d: f64) -> bool {
    d.is_finite() && d > 0.0 && d <= MAX_SCALE
}

/// The first problem found, as (field, what is wrong).
pub fn check(m: &TactileModel) -> Result<(), (String, String)> {
    let fail = |field: &str, why: String| Err((field.to_string(), why));
    for (field, v) in [("width", m.width), ("height", m.height)] {
        if !(1..=MAX_FRAME_SIDE).contains(&v) {
            return fail(field, format!("{v} px is outside 1..={MAX_FRAME_SIDE}"));
        }
    }
    for (field, v, min, max) in [
        ("px_per_mm", m.px_per_mm, MIN_PX_PER_MM, MAX_SCALE),
        ("ball_diameter_mm", m.ball_diameter_mm, 0.0, MAX_SCALE),
    ] {
        if !(v.is_finite() && v > min && v <= max) {
            return fail(
                field,
                format!("{v} must be finite, above {min} and at most {max}"),
            );
        }
    }
    if let Some(d) = m.other_balls_mm.iter().find(|&&d| !valid_ball_diameter(d)) {
        return fail(
            "other_balls_mm",
            format!("{d} must be finite, above 0 and at most {MAX_SCALE}"),
        );
    }
    if m.other_balls_mm.len() > MAX_TABLE {
        return fail(
            "other_balls_mm",
            format!("{} balls, more than {MAX_TABLE}", m.other_balls_mm.len()),
        );
    }
    if !(MIN_SKIN_THICKNESS_MM..=MAX_SKIN_THICKNESS_MM).contains(&m.skin_thickness_mm) {
        return fail(
            "skin_thickness_mm",
            format!(
                "{} mm is outside {MIN_SKIN_THICKNESS_MM}..={MAX_SKIN_THICKNESS_MM} mm",
                m.skin_thickness_mm
            ),
        );
    }
    let f = &m.filter;
    // Bounds wide of every sensible setting, so a filter that would reject (or accept)
    // every pixel is named here rather than blamed on the frames.
    for (field, v, lo, hi) in [
        ("filter.min_led", f.min_led, 0.0, 254.0),
        ("filter.max_white_ratio", f.max_white_ratio, 0.01, 100.0),
        ("filter.max_green_rise", f.max_green_rise, 0.0, 100.0),
    ] {
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return fail(field, format!("{v} is outside {lo}..={hi}"));
        }
    }
    if f.saturation < MIN_SATURATION {
        return fail(
            "filter.saturation",
            format!(
                "{} is below {MIN_SATURATION}: most LED light would read as saturated",
                f.saturation
            ),
        );
    }
    if let Err(why) = f.unmix.check() {
        return fail("filter.unmix", why);
    }
    let c = &m.contact;
    if !(c.threshold.is_finite() && c.threshold > 0.0 && c.threshold <= MAX_THRESHOLD) {
        return fail(
            "contact.threshold",
            format!(
                "{} must be finite, positive and at most {MAX_THRESHOLD} (a block whose LED \
                 light falls to almost nothing in both phases departs by about 4: above that \
                 nothing pressed is seen)",
                c.threshold
            ),
        );
    }
    for (field, v, range) in [
        ("contact.coarse_step", c.coarse_step, 1..=256),
        ("contact.min_cells", c.min_cells, 1..=1_000_000),
        ("contact.pad_px", c.pad_px, 0..=MAX_FRAME_SIDE),
        ("contact.dilate_px", c.dilate_px, 0..=256),
    ] {
        if !range.contains(&v) {
            return fail(field, format!("{v} is outside {range:?}"));
        }
    }
    let b = &m.background;
    if !(1..=256).contains(&b.factor) {
        return fail(
            "background.factor",
            format!("{} is outside 1..=256", b.factor),
        );
    }
    let blocks = (m.width.div_ceil(b.factor), m.height.div_ceil(b.factor));
    if (b.width, b.height) != blocks {
        return fail(
            "background.width/height",
            format!(
                "{}×{} blocks, but a {}×{} frame in blocks of {} px has {}×{}",
                b.width, b.height, m.width, m.height, b.factor, blocks.0, blocks.1
            ),
        );
    }
    for (field, planes) in [("background.dx", &b.dx), ("background.dy", &b.dy)] {
        if planes.len() != blocks.0 * blocks.1 {
            return fail(
                field,
                format!("{} blocks, {} declared", planes.len(), blocks.0 * blocks.1),
            );
        }
        // Each block is `[red − green, blue − green, green]` of 8-bit colours.
        let colour = |&[rg, bg, g]: &[f32; 3]| {
            (-255.0..=255.0).contains(&rg)
                && (-255.0..=255.0).contains(&bg)
                && (0.0..=255.0).contains(&g)
        };
        if !planes.iter().all(colour) {
            return fail(
                field,
                "holds a block that is not an 8-bit colour's [red − green, blue − green, \
                 green] (finite, ±255, green 0..=255)"
                    .into(),
            );
        }
    }
    if let Some(a) = &m.ambient {
        if !a.fits(m.width, m.height) {
            return fail(
                "ambient",
                format!(
                    "{}×{} blocks of {} px ({} values) do not cover a {}×{} frame",
                    a.width,
                    a.height,
                    a.step,
                    a.means.len(),
                    m.width,
                    m.height
                ),
            );
        }
        if a.means.iter().flatten().any(|v| !v.is_finite()) {
            return fail("ambient.means", "holds a value that is not finite".into());
        }
    }
    for (axis, model) in [("dx", &m.dx), ("dy", &m.dy)] {
        check_lut(&model.lut).map_err(|(f, why)| (format!("{axis}.lut.{f}"), why))?;
        check_mlp(&model.mlp).map_err(|(f, why)| (format!("{axis}.mlp.{f}"), why))?;
        if let Some(light) = &model.light {
            check_light(light).map_err(|(f, why)| (format!("{axis}.light.{f}"), why))?;
        }
    }
    if let Some(photometric) = &m.photometric {
        check_photometric(photometric).map_err(|(f, why)| (format!("photometric.{f}"), why))?;
    }
    for (axis, model, planes, along_x) in [
        ("dx", &m.dx, &m.background.dx, true),
        ("dy", &m.dy, &m.background.dy, false),
    ] {
        let side = red_side(planes, m.background.width, m.background.height, along_x);
        check_direction(side, |f, o| model.lut.eval_batch(f, o))
            .map_err(|why| (format!("{axis}.lut.table"), why))?;
        check_direction(side, |f, o| model.mlp.eval_batch(f, o))
            .map_err(|why| (format!("{axis}.mlp"), why))?;
    }
    if let Some((_, field, why)) = misdirected(m).into_iter().next() {
        return fail(&field, why);
    }
    if let Some(side) = &m.side_light {
        side.check()
            .map_err(|why| ("side_light.kappa".to_string(), why))?;
    }
    if let Some(curve) = &m.camera_curve {
        curve
            .check()
            .map_err(|(field, why)| (format!("camera_curve.{field}"), why))?;
    }
    Ok(())
}

/// A part of a model that reconstruction can do without: a phase's light model (it reads
/// slopes past the table's reach, and is a model kind of its own) or the photometric model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OptionalPart {
    /// The dx phase's (`true`) or the dy phase's light model.
    Light {
        /// The dx phase's.
        dx: bool,
    },
    /// The photometric model.
    Photometric,
}

/// The optional parts of `m` that read a slope's direction wrongly, or not at all, at the
/// frame's centre ([`check_direction`]), each with its field and what it read. A file
/// with one is refused ([`check`]); calibration leaves such a part out and says so (a
/// skin whose presses fit these simpler models badly should not cost the whole
/// calibration). The parts' shapes must have been checked before.
pub fn misdirected(m: &TactileModel) -> Vec<(OptionalPart, String, String)> {
    let mut out = Vec::new();
    for (axis, model, planes, along_x) in [
        ("dx", &m.dx, &m.background.dx, true),
        ("dy", &m.dy, &m.background.dy, false),
    ] {
        let side = red_side(planes, m.background.width, m.background.height, along_x);
        if let Some(light) = &model.light
            && let Err(why) = check_direction(side, |f, o| light.eval_batch(f, o))
        {
            let part = OptionalPart::Light { dx: along_x };
            out.push((part, format!("{axis}.light.response"), why));
        }
        if let Some(photometric) = &m.photometric {
            // The other phase's colours are flat skin's: the slope along this axis alone.
            let read = |f: &[[f32; 4]], o: &mut [f32]| {
                for (f, o) in f.iter().zip(o.iter_mut()) {
                    let colours = if along_x {
                        [f[0], f[1], 1.0, 1.0]
                    } else {
                        [1.0, 1.0, f[0], f[1]]
                    };
                    let slopes = photometric.read(colours, f[2], f[3]);
                    *o = slopes.map_or(0.0, |s| s[usize::from(!along_x)]);
                }
            };
            if let Err(why) = check_direction(side, read) {
                let field = format!("photometric.lights ({axis} strips)");
                out.push((OptionalPart::Photometric, field, why));
            }
        }
    }
    out
}

/// How far from flat skin's colour [`check_direction`] reads (normalised colour: a gentle
/// slope's).
const DIRECTION_PROBE: f32 = 0.15;
/// Least change of the background's red-minus-blue light from one end of an axis to the
/// other (8-bit levels) that says on which side the red strip is.
const MIN_SIDE_CHANGE: f32 = 8.0;

/// On which side of an axis the background (flat skin) has the red strip's light: `1.0`
/// on the + side (right for dx, `along_x`; bottom for dy), as the sensor is built; `-1.0`
/// on the − side (strips mounted the other way round, or a camera that gives blue for
/// red); `0.0` when the two ends differ too little to say. The mean red-minus-blue
/// light of the last third of the blocks along the axis against the first third's.
fn red_side(planes: &[[f32; 3]], width: usize, height: usize, along_x: bool) -> f32 {
    let (mut first, mut last, mut n_first, mut n_last) = (0.0f32, 0.0f32, 0usize, 0usize);
    let length = if along_x { width } else { height };
    for (i, [rg, bg, _]) in planes.iter().enumerate() {
        let at = if along_x {
            i % width.max(1)
        } else {
            i / width.max(1)
        };
        if 3 * at < length {
            (first, n_first) = (first + rg - bg, n_first + 1);
        } else if 3 * at >= 2 * length {
            (last, n_last) = (last + rg - bg, n_last + 1);
        }
    }
    if n_first == 0 || n_last == 0 {
        return 0.0;
    }
    let change = last / n_last as f32 - first / n_first as f32;
    if change.abs() < MIN_SIDE_CHANGE {
        0.0
    } else {
        change.signum()
    }
}

/// A gradient model must read a slope's direction as the strips give it. Where the red
/// strip's light is brighter than on flat skin and the blue's darker, the skin faces the
/// red strip; on the side `red_side` names (`1.0`: the + side), that is a slope of that
/// sign (depth grows towards the strip), and the other way round one of the other sign.
/// A table or perceptron edited by hand (negated, zeroed), or made for another sensor,
/// reads them the other way or not at all: imprints come out raised or flat with no other
/// sign of it. Read at the frame's centre; with `red_side` 0 only opposite signs are
/// asked.
fn check_direction(red_side: f32, eval: impl Fn(&[[f32; 4]], &mut [f32])) -> Result<(), String> {
    let d = DIRECTION_PROBE;
    let mut slopes = [0.0f32; 2];
    eval(
        &[[1.0 + d, 1.0 - d, 0.5, 0.5], [1.0 - d, 1.0 + d, 0.5, 0.5]],
        &mut slopes,
    );
    let [towards_red, towards_blue] = slopes;
    let opposite = towards_red * towards_blue < 0.0;
    if opposite && towards_red * red_side >= 0.0 {
        return Ok(());
    }
    let side = match red_side {
        s if s > 0.0 => "positive (the background has the red strip on the + side)",
        s if s < 0.0 => "negative (the background has the red strip on the − side)",
        _ => "of one sign",
    };
    Err(format!(
        "reads slope {towards_red:.3} where the red strip's light is {d} above flat skin's and \
         the blue's {d} below, and {towards_blue:.3} the other way round: a calibrated \
         model reads the first {side} and the second of the other sign"
    ))
}

fn check_photometric(p: &PhotometricModel) -> Result<(), (String, String)> {
    for (field, v, range) in [
        ("colour_power", p.colour_power, COLOUR_POWERS),
        ("norm_power", p.norm_power, NORM_POWERS),
    ] {
        if !range.contains(&v) {
            return Err((
                field.to_string(),
                format!(
                    "{v} is outside {}..={} (the response calibration chooses from; 1 is a \
                     matte skin seen by a linear camera)",
                    range.start(),
                    range.end()
                ),
            ));
        }
    }
    check_cells(
        (p.cells_x, p.cells_y),
        ("lights", "cells", p.lights.len()),
        p.lights.iter().flatten().flatten().copied(),
    )
}

fn check_light(l: &LightModel) -> Result<(), (String, String)> {
    check_cells(
        (l.cells_x, l.cells_y),
        ("response", "values", l.response.len()),
        l.response.iter().flatten().copied(),
    )
}

/// A grid of per-cell entries: `cells_x`, `cells_y` in 1..=64, `entries` (field name,
/// what one entry is called, how many there are) one per cell, every value finite.
fn check_cells(
    (cells_x, cells_y): (usize, usize),
    (field, entry, len): (&str, &str, usize),
    mut values: impl Iterator<Item = f32>,
) -> Result<(), (String, String)> {
    let fail = |field: &str, why: String| Err((field.to_string(), why));
    for (name, v) in [("cells_x", cells_x), ("cells_y", cells_y)] {
        if !(1..=64).contains(&v) {
            return fail(name, format!("{v} is outside 1..=64"));
        }
    }
    let want = cells_x * cells_y;
    if len != want {
        return fail(field, format!("{len} {entry}, {want} declared"));
    }
    if values.any(|v| !v.is_finite()) {
        return fail(field, "holds a value that is not finite".into());
    }
    Ok(())
}

fn check_lut(l: &Lut) -> Result<(), (String, String)> {
    let fail = |field: &str, why: String| Err((field.to_string(), why));
    if !(2..=MAX_TABLE).contains(&l.bins) {
        return fail("bins", format!("{} is outside 2..={MAX_TABLE}", l.bins));
    }
    if !(l.max_value.is_finite() && l.max_value > 0.0 && l.max_value <= MAX_LUT_COLOUR) {
        return fail(
            "max_value",
            format!(
                "{} must be finite, positive and at most {MAX_LUT_COLOUR} (a colour relative \
                 to flat skin's)",
                l.max_value
            ),
        );
    }
    for (field, v) in [("cells_x", l.cells_x), ("cells_y", l.cells_y)] {
        if !(1..=64).contains(&v) {
            return fail(field, format!("{v} is outside 1..=64"));
        }
    }
    let gain_negative = if l.gain_negative.is_empty() {
        None
    } else {
        Some(("gain_negative", &l.gain_negative, l.cells_x * l.cells_y))
    };
    for (field, values, want) in [
        ("table", &l.table, l.bins * l.bins),
        ("gain", &l.gain, l.cells_x * l.cells_y),
    ]
    .into_iter()
    .chain(gain_negative)
    {
        if values.len() != want {
            return fail(field, format!("{} values, {want} declared", values.len()));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return fail(field, "holds a value that is not finite".into());
        }
        // A gain scales a reading: one that is not positive turns slopes around or off.
        if field != "table" && values.iter().any(|&v| !(v > 0.0 && v <= MAX_LUT_GAIN)) {
            return fail(
                field,
                format!(
                    "holds a gain outside (0, {MAX_LUT_GAIN}]: it would turn slopes around, off or up"
                ),
            );
        }
    }
    Ok(())
}

/// Largest colour (relative to flat skin's) a table's axis may reach.
const MAX_LUT_COLOUR: f32 = 100.0;
/// Largest gain of a table's cell (calibration's are near 1, stretched at most 2×).
const MAX_LUT_GAIN: f32 = 100.0;
/// Smallest saturation level a filter may declare (DN).
const MIN_SATURATION: u8 = 64;

fn check_mlp(m: &Mlp) -> Result<(), (String, String)> {
    let fail = |field: String, why: String| Err((field, why));
    if m.input_offset
        .iter()
        .chain(&m.input_scale)
        .any(|v| !v.is_finite())
    {
        return fail(
            "input_offset/input_scale".into(),
            "holds a value that is not finite".into(),
        );
    }
    let Some(last) = m.layers.last() else {
        return fail("layers".into(), "no layers".into());
    };
    let mut inputs = 4;
    for (i, l) in m.layers.iter().enumerate() {
        let field = |f: &str| format!("layers[{i}].{f}");
        if l.inputs != inputs {
            return fail(
                field("inputs"),
                format!("{}, but the layer before gives {inputs}", l.inputs),
            );
        }
        if !(1..=MAX_TABLE).contains(&l.outputs) {
            return fail(
                field("outputs"),
                format!("{} is outside 1..={MAX_TABLE}", l.outputs),
            );
        }
        if l.weights.len() != l.inputs * l.outputs {
            return fail(
                field("weights"),
                format!(
                    "{} values, {}×{} declared",
                    l.weights.len(),
                    l.outputs,
                    l.inputs
                ),
            );
        }
        if l.bias.len() != l.outputs {
            return fail(
                field("bias"),
                format!("{} values, {} declared", l.bias.len(), l.outputs),
            );
        }
        if l.weights.iter().chain(&l.bias).any(|v| !v.is_finite()) {
            return fail(field("weights"), "holds a value that is not finite".into());
        }
        inputs = l.outputs;
    }
    if last.outputs != 1 {
        return fail(
            "layers".into(),
            format!("the last layer gives {} outputs, not 1", last.outputs),
        );
    }
    if let Some(why) = m.response.as_ref().and_then(|c| c.check().err()) {
        return fail("response.points".into(), why);
    }
    Ok(())
}
