//! Our own synthetic visuotactile sensor: shapes pressed into a flat skin, shaded the way
//! the dx and dy LED phases light it, with a choice of reflectance models, LED fall-off,
//! ambient light, a ceiling-light spot and camera noise. It feeds the demo, the benchmark
//! and the tests; the pipeline never sees its ground truth except through images.
//!
//! Conventions: depth `d` in mm is positive where the skin is pressed in; slopes are
//! `p = ∂d/∂x`, `q = ∂d/∂y` (dimensionless); the surface normal is `(p, q, 1)/|…|`. In the
//! dx image strip 1 (x−) is blue and strip 3 (x+) red; in the dy image strip 2 (y−) is
//! blue and strip 4 (y+) red.

use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::grid::Grid;
use crate::rng::Rng;

/// One indenter, positioned in mm from the image's top-left corner.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Shape {
    /// A ball of `diameter` pressed `depth` into the skin (a spherical cap).
    Ball {
        /// Centre x (mm).
        cx: f64,
        /// Centre y (mm).
        cy: f64,
        /// Ball diameter (mm).
        diameter: f64,
        /// Press depth (mm).
        depth: f64,
    },
    /// A flat-bottomed disk of `diameter` pressed `depth`, its rim falling to zero over
    /// `wall` mm: a raised-cosine rim when `linear` is false, a straight one (slope
    /// `depth / wall`) when true.
    Disk {
        /// Centre x (mm).
        cx: f64,
        /// Centre y (mm).
        cy: f64,
        /// Diameter of the flat bottom (mm).
        diameter: f64,
        /// Press depth (mm).
        depth: f64,
        /// Rim width (mm).
        wall: f64,
        /// Straight rim instead of raised cosine.
        linear: bool,
    },
    /// A screw lying on its side: a cylinder with a thread, pressed `depth`.
    Screw {
        /// Centre x (mm).
        cx: f64,
        /// Centre y (mm).
        cy: f64,
        /// Length (mm).
        length: f64,
        /// Major diameter (mm).
        diameter: f64,
        /// Press depth (mm).
        depth: f64,
        /// Thread pitch (mm).
        pitch: f64,
        /// Axis angle (radians from +x).
        angle: f64,
    },
}

impl Shape {
    /// Indentation depth (mm, ≥ 0) at `(x, y)` mm.
    pub fn depth(&self, x: f64, y: f64) -> f64 {
        match *self {
            Shape::Ball {
                cx,
                cy,
                diameter,
                depth,
            } => {
                let r = diameter / 2.0;
                let rho2 = (x - cx).powi(2) + (y - cy).powi(2);
                if rho2 >= r * r {
                    0.0
                } else {
                    ((r * r - rho2).sqrt() - (r - depth)).max(0.0)
                }
            }
            Shape::Disk {
                cx,
                cy,
                diameter,
                depth,
                wall,
                linear,
            } => {
                let rho = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt();
                let t = (rho - diameter / 2.0) / wall;
                if t <= 0.0 {
                    depth
                } else if t >= 1.0 {
                    0.0
                } else if linear {
                    depth * (1.0 - t)
                } else {
                    depth * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
                }
            }
            Shape::Screw {
                cx,
                cy,
                length,
                diameter,
                depth,
                pitch,
                angle,
            } => {
                let (s, c) = angle.sin_cos();
                let along = (x - cx) * c + (y - cy) * s;
                let across = -(x - cx) * s + (y - cy) * c;
                if along.abs() > length / 2.0 {
                    return 0.0;
                }
                let thread =
                    0.08 * diameter * (0.5 + 0.5 * (std::f64::consts::TAU * along / pitch).cos());
                let r = diameter / 2.0 - thread;
                if across.abs() >= r {
                    return 0.0;
                }
                let major = diameter / 2.0;
                // The ends are chamfered over 1 mm rather than cut square (a cliff has no
                // gradient to measure).
                let end = ((length / 2.0 - along.abs()) / 1.0).min(1.0);
                (((r * r - across * across).sqrt() - (major - depth)) * end).max(0.0)
            }
        }
    }
}

/// A set of indenters; where they overlap the deepest one shapes the skin.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// The indenters.
    pub shapes: Vec<Shape>,
}

impl Scene {
    /// Depth (mm) at `(x, y)` mm.
    pub fn depth(&self, x: f64, y: f64) -> f64 {
        self.shapes
            .iter()
            .map(|s| s.depth(x, y))
            .fold(0.0, f64::max)
    }

    /// Ground-truth depth (mm) and slopes `(p, q)` at pixel centres. Slopes are central
    /// differences of the exact depth over ±1/100 px.
    pub fn truth(&self, width: usize, height: usize, px_per_mm: f64) -> SceneTruth {
        let h = 0.01 / px_per_mm;
        let at = |x: usize, y: usize| ((x as f64 + 0.5) / px_per_mm, (y as f64 + 0.5) / px_per_mm);
        let depth = Grid::from_fn(width, height, |x, y| {
            let (mx, my) = at(x, y);
            self.depth(mx, my) as f32
        });
        let p = Grid::from_fn(width, height, |x, y| {
            let (mx, my) = at(x, y);
            ((self.depth(mx + h, my) - self.depth(mx - h, my)) / (2.0 * h)) as f32
        });
        let q = Grid::from_fn(width, height, |x, y| {
            let (mx, my) = at(x, y);
            ((self.depth(mx, my + h) - self.depth(mx, my - h)) / (2.0 * h)) as f32
        });
        SceneTruth { depth, p, q }
    }
}

/// Exact depth and slopes of a scene on the pixel grid.
#[derive(Debug, Clone)]
pub struct SceneTruth {
    /// Depth in mm.
    pub depth: Grid<f32>,
    /// `∂d/∂x`.
    pub p: Grid<f32>,
    /// `∂d/∂y`.
    pub q: Grid<f32>,
}

/// How the skin's coating reflects the LED light.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Reflectance {
    /// Matte (cosine law).
    Lambert,
    /// Matte plus a Blinn–Phong highlight towards the camera.
    Glossy {
        /// Highlight strength relative to the matte term.
        strength: f64,
        /// Blinn–Phong exponent.
        shininess: f64,
    },
    /// Matte seen through a non-linear camera response `v^(1/gamma)`.
    Gamma(f64),
    /// A rough diffuse coating (Minnaert's law, our stand-in for a rough surface's
    /// back-scatter): `cos(i)^k · cos(r)^(k − 1)`, the camera overhead. `k` = 1 is
    /// Lambert; below 1 the colour answers the slope less than the cosine law and
    /// tilted skin looks brighter from above.
    Rough {
        /// Minnaert exponent `k` (0 < k ≤ 1).
        exponent: f64,
    },
}

/// A bright white blob, e.g. a ceiling light seen through the skin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spot {
    /// Centre x (px).
    pub x: f64,
    /// Centre y (px).
    pub y: f64,
    /// Gaussian radius (px).
    pub radius: f64,
    /// Peak added to every channel (DN).
    pub level: f64,
}

/// Everything about the simulated sensor except what is pressed into it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Optics {
    /// Image width (px).
    pub width: usize,
    /// Image height (px).
    pub height: usize,
    /// Scale (px per mm).
    pub px_per_mm: f64,
    /// Light elevation far from a strip (degrees above the skin).
    pub elevation_far_deg: f64,
    /// Light elevation right next to a strip.
    pub elevation_near_deg: f64,
    /// Distance over which the elevation goes from near to far, and the fall-off scale of
    /// the intensity `1 / (1 + (d / falloff)²)` (mm).
    pub falloff_mm: f64,
    /// Brightness of flat skin in the middle of the frame (DN).
    pub flat_level: f64,
    /// Reflectance model.
    pub reflectance: Reflectance,
    /// Uniform white ambient light (DN, every channel).
    pub ambient: f64,
    /// Optional ceiling-light spot.
    pub spot: Option<Spot>,
    /// Fraction of each LED's light that the camera also records in green.
    pub green_leak: f64,
    /// Fraction of the red LED's light recorded in blue, and of the blue LED's in red.
    pub cross_leak: f64,
    /// Per-strip variation, strips in order 1 (x−), 2 (y−), 3 (x+), 4 (y+).
    pub strips: [StripVariation; 4],
    /// How far each strip runs past both ends of its frame side (mm; negative: it stops
    /// short of them), or `None` for strips so long that every pixel is lit along the
    /// phase's axis alone. A strip of finite length lights a pixel near one of its ends
    /// from the side as well ([`side_light`]), so there a phase's colours also answer the
    /// other axis' slope, as on a real sensor.
    #[serde(default)]
    pub strip_overhang_mm: Option<f64>,
    /// The camera's response curve: each channel's value `v` (DN, everything added,
    /// noise included) is recorded as `255 · (v/255 · g)^(1/γ)`, `g` the exposure that
    /// keeps flat skin's level where a linear camera records it, or `None` for a linear
    /// camera. Unlike [`Reflectance::Gamma`], which bends each strip's shading alone,
    /// this bends the sum a camera sees: both LEDs' light in a channel, their crosstalk,
    /// the ambient light and the spot, so `R − G` no longer takes the green leak out.
    #[serde(default)]
    pub camera_gamma: Option<f64>,
    /// Colour of the ambient light (multiplier per channel R, G, B).
    pub ambient_colour: [f64; 3],
    /// Fraction of the ambient light (and spot) a touching object blocks where it
    /// presses in.
    pub ambient_block: f64,
    /// Camera gain on everything before the response curve.
    pub exposure: f64,
    /// Vignetting `1 − k·r²` (r: distance from the centre over the half-diagonal).
    pub vignetting: f64,
    /// Camera noise, standard deviation (DN).
    pub noise: f64,
    /// MJPG compression quality, `None` for raw frames.
    pub jpeg_quality: Option<u8>,
    /// Noise seed.
    pub seed: u64,
}

/// How one strip differs from the nominal one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StripVariation {
    /// Brightness multiplier.
    pub gain: f64,
    /// Added to both light elevations (degrees).
    pub elevation_deg: f64,
    /// Multiplier on the fall-off distance.
    pub falloff: f64,
}

impl StripVariation {
    /// A nominal strip.
    pub const NOMINAL: StripVariation = StripVariation {
        gain: 1.0,
        elevation_deg: 0.0,
        falloff: 1.0,
    };
}

impl Optics {
    /// A 640×480 sensor at 15 px/mm with moderate fall-off and noise.
    pub fn standard() -> Self {
        Self::sized(640, 480)
    }

    /// The standard skin seen by a camera of another resolution: px/mm scales with the
    /// width (1280×960 → 30 px/mm), so scenes keep their size in mm.
    pub fn resolution(width: usize, height: usize) -> Self {
        Self {
            px_per_mm: 15.0 * width as f64 / 640.0,
            ..Self::sized(width, height)
        }
    }

    /// The standard optics at another size (same px/mm, so a larger or smaller skin).
    pub fn sized(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            px_per_mm: 15.0,
            elevation_far_deg: 30.0,
            elevation_near_deg: 45.0,
            falloff_mm: 30.0,
            flat_level: 110.0,
            reflectance: Reflectance::Lambert,
            ambient: 6.0,
            spot: None,
            green_leak: 0.0,
            cross_leak: 0.0,
            strips: [StripVariation::NOMINAL; 4],
            strip_overhang_mm: None,
            camera_gamma: None,
            ambient_colour: [1.0; 3],
            ambient_block: 0.0,
            exposure: 1.0,
            vignetting: 0.0,
            noise: 1.0,
            jpeg_quality: None,
            seed: 1,
        }
    }

    /// The standard optics with every physical parameter drawn at random from `seed`
    /// within the ranges of a plausible real skin: LED elevation and fall-off per strip,
    /// strip brightness imbalance, crosstalk, gloss or a camera gamma, exposure,
    /// vignetting, tinted ambient light partly blocked by a touching object, a ceiling
    /// spot anywhere, noise and MJPG compression.
    pub fn random(width: usize, height: usize, seed: u64) -> Self {
        let mut rng = Rng::new(seed ^ 0x5EED_0F0F_7C5A_11AA);
        let base = Self::resolution(width, height);
        let mut strip = || StripVariation {
            gain: rng.range(0.85, 1.15),
            elevation_deg: rng.range(-6.0, 6.0),
            falloff: rng.range(0.7, 1.4),
        };
        let strips = [strip(), strip(), strip(), strip()];
        let reflectance = match rng.next_u64() % 3 {
            0 => Reflectance::Lambert,
            1 => Reflectance::Glossy {
                strength: rng.range(0.05, 0.3),
                shininess: rng.range(8.0, 40.0),
            },
            _ => Reflectance::Gamma(rng.range(1.4, 2.4)),
        };
        let spot = (rng.uniform() < 0.6).then(|| Spot {
            x: rng.range(0.0, width as f64),
            y: rng.range(0.0, height as f64),
            radius: rng.range(15.0, 60.0) * base.px_per_mm / 15.0,
            level: rng.range(30.0, 110.0),
        });
        Self {
            elevation_far_deg: rng.range(24.0, 36.0),
            elevation_near_deg: rng.range(40.0, 55.0),
            falloff_mm: rng.range(18.0, 45.0),
            flat_level: rng.range(80.0, 130.0),
            reflectance,
            ambient: rng.range(3.0, 25.0),
            spot,
            green_leak: rng.range(0.0, 0.12),
            cross_leak: rng.range(0.0, 0.06),
            strips,
            ambient_colour: [
                rng.range(0.8, 1.2),
                rng.range(0.8, 1.2),
                rng.range(0.8, 1.2),
            ],
            ambient_block: rng.range(0.0, 0.7),
            exposure: rng.range(0.85, 1.1),
            vignetting: rng.range(0.0, 0.4),
            noise: rng.range(0.7, 2.5),
            jpeg_quality: (rng.uniform() < 0.5).then(|| 80 + (rng.next_u64() % 16) as u8),
            seed: rng.next_u64(),
            ..base
        }
    }
}

/// The two images of one gradient pair.
#[derive(Debug, Clone)]
pub struct RenderedPair {
    /// Strips 1 (blue, x−) and 3 (red, x+) lit.
    pub dx: RgbImage,
    /// Strips 2 (blue, y−) and 4 (red, y+) lit.
    pub dy: RgbImage,
}

/// Which phase to shade.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// The dx phase.
    X,
    /// The dy phase.
    Y,
}

/// Renders the dx and dy images of `scene`. `frame` varies the noise between frames.
pub fn render(optics: &Optics, scene: &Scene, frame: u64) -> RenderedPair {
    let truth = scene.truth(optics.width, optics.height, optics.px_per_mm);
    let (dx, dy, _) = render_truth(optics, &truth, frame, [1.0; 3]);
    RenderedPair { dx, dy }
}

/// Renders the dx, dy and LEDs-off images of a scene's truth, the ambient light scaled
/// by `ambient[k]` in image `k` (scene light that changes between exposures).
pub fn render_truth(
    optics: &Optics,
    truth: &SceneTruth,
    frame: u64,
    ambient: [f64; 3],
) -> (RgbImage, RgbImage, RgbImage) {
    let mut rng = Rng::new(optics.seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let depth = Some(&truth.depth);
    (
        shade(
            optics,
            &[Axis::X],
            &truth.p,
            &truth.q,
            depth,
            ambient[0],
            &mut rng,
        ),
        shade(
            optics,
            &[Axis::Y],
            &truth.p,
            &truth.q,
            depth,
            ambient[1],
            &mut rng,
        ),
        shade(optics, &[], &truth.p, &truth.q, depth, ambient[2], &mut rng),
    )
}

/// Renders a pair from slope fields (shared by [`render`] and tests of odd inputs).
pub fn render_slopes(optics: &Optics, p: &Grid<f32>, q: &Grid<f32>, frame: u64) -> RenderedPair {
    let mut rng = Rng::new(optics.seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    RenderedPair {
        dx: shade(optics, &[Axis::X], p, q, None, 1.0, &mut rng),
        dy: shade(optics, &[Axis::Y], p, q, None, 1.0, &mut rng),
    }
}

/// A flat-skin frame with all four strips lit (both phases at once, one exposure), from
/// which [`crate::tactile::camera_curve`] measures the camera's response curve.
pub fn render_all_lit(optics: &Optics, frame: u64) -> RgbImage {
    let mut rng = Rng::new(optics.seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let flat = Grid::filled(optics.width, optics.height, 0.0f32);
    shade(
        optics,
        &[Axis::X, Axis::Y],
        &flat,
        &flat,
        None,
        1.0,
        &mut rng,
    )
}

/// One image lit by the phases in `lit` (one for a phase image, none with the LEDs off,
/// both for a frame with every strip on).
fn shade(
    optics: &Optics,
    lit: &[Axis],
    p: &Grid<f32>,
    q: &Grid<f32>,
    depth: Option<&Grid<f32>>,
    ambient_scale: f64,
    rng: &mut Rng,
) -> RgbImage {
    let (w, h) = (optics.width, optics.height);
    let mm = |px: usize| (px as f64 + 0.5) / optics.px_per_mm;
    let (span_w, span_h) = (w as f64 / optics.px_per_mm, h as f64 / optics.px_per_mm);
    let half_diagonal2 = (w as f64 * w as f64 + h as f64 * h as f64) / 4.0;
    let response = optics
        .camera_gamma
        .map(|g| CameraResponse::new(g, optics.flat_level));
    // The blue and red light of `axis`' phase at pixel (x, y) with normal `n`.
    let phase_light = |axis: Axis, x: usize, y: usize, n: &[f64; 3]| {
        // Strips (index into `optics.strips`) lit blue and red in this phase.
        let (blue_strip, red_strip) = match axis {
            Axis::X => (0, 2),
            Axis::Y => (1, 3),
        };
        let centre_gain = {
            let d = match axis {
                Axis::X => span_w / 2.0,
                Axis::Y => span_h / 2.0,
            };
            1.0 / falloff(d, optics.falloff_mm)
        };
        // Distance to the blue strip (at the low side) and to the red one, and the
        // pixel's place along them.
        let (d_blue, d_red, along, length) = match axis {
            Axis::X => (mm(x), span_w - mm(x), mm(y), span_h),
            Axis::Y => (mm(y), span_h - mm(y), mm(x), span_w),
        };
        let strip = |k: usize, d: f64, towards: f64| {
            let v = &optics.strips[k];
            // The light's horizontal direction: along the axis, turned towards the
            // middle of a strip of finite length.
            let side = optics.strip_overhang_mm.map_or(0.0, |o| {
                side_light(d, strip_elevation(optics, v, d), along, length, o)
            });
            let norm = (1.0 + side * side).sqrt();
            let dir = match axis {
                Axis::X => [towards / norm, side / norm],
                Axis::Y => [side / norm, towards / norm],
            };
            v.gain * light(optics, v, n, d, dir) * centre_gain
        };
        (
            strip(blue_strip, d_blue, -1.0),
            strip(red_strip, d_red, 1.0),
        )
    };
    let mut img = RgbImage::new(w as u32, h as u32);
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (p.get(x, y) as f64, q.get(x, y) as f64);
            let norm = (1.0 + px * px + py * py).sqrt();
            let n = [px / norm, py / norm, 1.0 / norm];
            let (mut blue, mut red) = (0.0, 0.0);
            for &axis in lit {
                let (b, r) = phase_light(axis, x, y, &n);
                blue += b;
                red += r;
            }
            let mut spot = 0.0;
            if let Some(s) = optics.spot {
                let r2 = (x as f64 - s.x).powi(2) + (y as f64 - s.y).powi(2);
                spot = s.level * (-r2 / (2.0 * s.radius * s.radius)).exp();
            }
            let pressed = depth.map_or(0.0, |d| (d.get(x, y) as f64 / 0.05).clamp(0.0, 1.0));
            let white =
                (optics.ambient + spot) * ambient_scale * (1.0 - optics.ambient_block * pressed);
            let level = optics.flat_level;
            let (red, blue) = (level * red, level * blue);
            let led = [
                red + optics.cross_leak * blue,
                optics.green_leak * (red + blue),
                blue + optics.cross_leak * red,
            ];
            let r2 = ((x as f64 + 0.5 - w as f64 / 2.0).powi(2)
                + (y as f64 + 0.5 - h as f64 / 2.0).powi(2))
                / half_diagonal2;
            let gain = optics.exposure * (1.0 - optics.vignetting * r2);
            let mut out = [0.0; 3];
            for (c, v) in out.iter_mut().enumerate() {
                *v = (led[c] + white * optics.ambient_colour[c]) * gain
                    + optics.noise * rng.gaussian();
                if let Some(response) = &response {
                    *v = response.record(*v);
                }
            }
            img.put_pixel(
                x as u32,
                y as u32,
                image::Rgb(out.map(|v| v.round().clamp(0.0, 255.0) as u8)),
            );
        }
    }
    match optics.jpeg_quality {
        Some(quality) => jpeg_round_trip(img, quality),
        None => img,
    }
}

/// A camera's response curve ([`Optics::camera_gamma`]).
#[derive(Debug, Clone, Copy)]
struct CameraResponse {
    inverse_gamma: f64,
    /// `255 · g^(1/γ)`: the output of a full-scale input, exposure included.
    scale: f64,
}

impl CameraResponse {
    /// The curve of `gamma` with the exposure that records `flat_level` (DN) as itself.
    fn new(gamma: f64, flat_level: f64) -> Self {
        let gamma = if gamma.is_finite() && gamma > 0.0 {
            gamma
        } else {
            1.0
        };
        let flat = (flat_level / 255.0).clamp(1e-3, 1.0);
        // 255 · (flat · g)^(1/γ) = 255 · flat  ⇔  g = flat^(γ − 1).
        let g = flat.powf(gamma - 1.0);
        Self {
            inverse_gamma: 1.0 / gamma,
            scale: 255.0 * g.powf(1.0 / gamma),
        }
    }

    /// The value recorded for `v` DN of linear light.
    fn record(&self, v: f64) -> f64 {
        self.scale * (v.max(0.0) / 255.0).powf(self.inverse_gamma)
    }
}

/// The image as an MJPG camera delivers it: JPEG-compressed at `quality` and decoded.
pub fn jpeg_round_trip(img: RgbImage, quality: u8) -> RgbImage {
    let mut bytes = Vec::new();
    let encoded =
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality).encode_image(&img);
    if encoded.is_err() {
        return img;
    }
    match image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg) {
        Ok(decoded) => decoded.to_rgb8(),
        Err(_) => img,
    }
}

fn falloff(d: f64, scale: f64) -> f64 {
    1.0 / (1.0 + (d / scale).powi(2))
}

/// The elevation (radians) of a strip's light at distance `d` mm from it.
fn strip_elevation(optics: &Optics, strip: &StripVariation, d: f64) -> f64 {
    let falloff_mm = optics.falloff_mm * strip.falloff;
    let blend = (-d / falloff_mm * 3.0).exp();
    (optics.elevation_far_deg
        + (optics.elevation_near_deg - optics.elevation_far_deg) * blend
        + strip.elevation_deg)
        .clamp(5.0, 85.0)
        .to_radians()
}

/// The side component of a finite strip's light, relative to its component along the
/// axis (the tangent of the angle by which the light turns towards the strip's middle),
/// at a pixel `d` mm from the strip and `along` mm from the start of its frame side of
/// `length` mm; the strip runs `overhang` mm past both ends.
///
/// The strip is a line of point sources at the height that makes the light's elevation
/// `elevation`, each seen with inverse-square fall-off. With `c` the distance to the
/// line and `s` the offset along it, the side and axial components of the summed unit
/// directions are `∫ s/(c² + s²)^{3/2} ds` and `∫ d/(c² + s²)^{3/2} ds` over the strip,
/// in closed form below. An infinite strip, or the pixel at its middle, has none.
pub fn side_light(d: f64, elevation: f64, along: f64, length: f64, overhang: f64) -> f64 {
    let d = d.max(1e-3);
    let c2 = (d / elevation.cos().max(1e-3)).powi(2);
    let (a, b) = (-overhang - along, length + overhang - along);
    if b <= a {
        return 0.0;
    }
    let r = |s: f64| (c2 + s * s).sqrt();
    let side = 1.0 / r(a) - 1.0 / r(b);
    let axial = d / c2 * (b / r(b) - a / r(a));
    if axial > 0.0 { side / axial } else { 0.0 }
}

/// Light from a strip at distance `d` mm in horizontal direction `dir` (a unit vector),
/// reflected by a surface with normal `n`, relative to flat skin lit from the same place.
fn light(optics: &Optics, strip: &StripVariation, n: &[f64; 3], d: f64, dir: [f64; 2]) -> f64 {
    let falloff_mm = optics.falloff_mm * strip.falloff;
    let elevation = strip_elevation(optics, strip, d);
    let (se, ce) = elevation.sin_cos();
    let l = [dir[0] * ce, dir[1] * ce, se];
    let cos_i = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0);
    let matte = cos_i / se;
    let value = match optics.reflectance {
        Reflectance::Lambert => matte,
        Reflectance::Glossy {
            strength,
            shininess,
        } => {
            let half = [l[0], l[1], l[2] + 1.0];
            let hn = (half[0] * half[0] + half[1] * half[1] + half[2] * half[2]).sqrt();
            let spec = |n: &[f64; 3]| {
                ((n[0] * half[0] + n[1] * half[1] + n[2] * half[2]) / hn)
                    .max(0.0)
                    .powf(shininess)
            };
            matte + strength * (spec(n) - spec(&[0.0, 0.0, 1.0]))
        }
        Reflectance::Gamma(gamma) => matte.max(0.0).powf(1.0 / gamma),
        Reflectance::Rough { exponent } => {
            let k = exponent.clamp(0.05, 1.0);
            matte.max(0.0).powf(k) * n[2].clamp(1e-3, 1.0).powf(k - 1.0)
        }
    };
    value.max(0.0) * falloff(d, falloff_mm)
}

/// The benchmark's and demo's built-in scenes, laid out for `optics`' frame size.
pub fn builtin_scenes(optics: &Optics) -> Vec<(&'static str, Scene)> {
    let (w, h) = (
        optics.width as f64 / optics.px_per_mm,
        optics.height as f64 / optics.px_per_mm,
    );
    let ball = |cx, cy, diameter, depth| Shape::Ball {
        cx,
        cy,
        diameter,
        depth,
    };
    vec![
        (
            "sphere",
            Scene {
                shapes: vec![ball(w * 0.45, h * 0.55, 8.0, 1.0)],
            },
        ),
        (
            "disk",
            Scene {
                shapes: vec![disk(w * 0.5, h * 0.5, false)],
            },
        ),
        (
            "steep-disk",
            Scene {
                shapes: vec![disk(w * 0.5, h * 0.5, true)],
            },
        ),
        (
            "screw",
            Scene {
                shapes: vec![Shape::Screw {
                    cx: w * 0.5,
                    cy: h * 0.45,
                    length: 16.0,
                    diameter: 4.0,
                    depth: 0.8,
                    pitch: 1.25,
                    angle: 0.4,
                }],
            },
        ),
        (
            "multi",
            Scene {
                shapes: vec![
                    ball(w * 0.25, h * 0.3, 5.0, 0.7),
                    ball(w * 0.7, h * 0.35, 6.0, 0.9),
                    ball(w * 0.5, h * 0.75, 4.0, 0.5),
                ],
            },
        ),
        (
            "edge",
            Scene {
                shapes: vec![ball(0.0, h * 0.5, 8.0, 1.0)],
            },
        ),
        ("none", Scene::default()),
    ]
}

/// The 13 mm disk pressed 1 mm, centred at `(cx, cy)` mm: a raised-cosine rim
/// of 2.5 mm (max slope 0.63), or a straight rim of slope 1.3 when `steep`.
pub fn disk(cx: f64, cy: f64, steep: bool) -> Shape {
    Shape::Disk {
        cx,
        cy,
        diameter: 13.0,
        depth: 1.0,
        wall: if steep { 1.0 / 1.3 } else { 2.5 },
        linear: steep,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`side_light`] by direct summation over 20 000 point sources along the strip.
    fn side_light_summed(d: f64, elevation: f64, along: f64, length: f64, overhang: f64) -> f64 {
        let height = d * elevation.tan();
        let n = 20_000;
        let (start, end) = (-overhang, length + overhang);
        let (mut side, mut axial) = (0.0, 0.0);
        for k in 0..n {
            let s = start + (end - start) * (k as f64 + 0.5) / n as f64 - along;
            let r2 = d * d + height * height + s * s;
            // Unit direction times inverse-square intensity.
            let w = 1.0 / (r2 * r2.sqrt());
            side += s * w;
            axial += d * w;
        }
        side / axial
    }

    #[test]
    fn a_finite_strip_lights_from_the_side_as_its_point_sources_sum() {
        let e = 30f64.to_radians();
        for (d, along, overhang) in [
            (20.0, 0.0, 3.0),
            (3.0, 0.5, 3.0),
            (10.0, 5.0, -1.0),
            (25.0, 30.0, 0.0),
        ] {
            let exact = side_light(d, e, along, 32.0, overhang);
            let summed = side_light_summed(d, e, along, 32.0, overhang);
            assert!(
                (exact - summed).abs() < 1e-3,
                "{d} {along} {overhang}: {exact} vs {summed}"
            );
        }
        // Near the start the light turns towards the strip's middle (+), near the end
        // the other way, as much; none at the middle; a longer strip turns it less, and
        // a very long one not at all.
        let at = |along: f64, overhang: f64| side_light(20.0, e, along, 32.0, overhang);
        assert!(at(0.0, 3.0) > 0.4, "{}", at(0.0, 3.0));
        assert!((at(0.0, 3.0) + at(32.0, 3.0)).abs() < 1e-12);
        assert!(at(16.0, 3.0).abs() < 1e-12);
        assert!(at(0.0, 10.0) < at(0.0, 3.0) && at(0.0, 1e7).abs() < 1e-5);
        // Degenerate strips and pixels on them give numbers, never NaN.
        for v in [
            side_light(0.0, e, 0.0, 32.0, 3.0),
            side_light(5.0, e, 0.0, 32.0, -20.0),
        ] {
            assert!(v.is_finite(), "{v}");
        }
    }

    #[test]
    fn a_camera_response_bends_the_sum_it_records_and_keeps_flat_skin_level() {
        let curve = CameraResponse::new(2.2, 110.0);
        // Flat skin's level is recorded as itself, full scale as full scale times the
        // exposure's share, and the curve is the power law between.
        assert!((curve.record(110.0) - 110.0).abs() < 1e-9);
        let g = (110.0f64 / 255.0).powf(1.2);
        for v in [0.0, 5.0, 55.0, 110.0, 200.0, 255.0] {
            let want = 255.0 * (v / 255.0 * g).powf(1.0 / 2.2);
            assert!((curve.record(v) - want).abs() < 1e-9, "{v}");
        }
        assert_eq!(curve.record(-3.0), 0.0);
        // Half the light reads 2^(-1/γ) of flat skin's level, not half of it.
        assert!((curve.record(55.0) / 110.0 - 0.5f64.powf(1.0 / 2.2)).abs() < 1e-9);
        // γ = 1 is a linear camera; a nonsense γ is one too.
        for gamma in [1.0, 0.0, f64::NAN] {
            assert!((CameraResponse::new(gamma, 110.0).record(37.0) - 37.0).abs() < 1e-9);
        }
        // In the rendered frames: with the curve, flat skin keeps its level and a dim
        // facet (skin sloping away from the red strip) reads brighter than linear.
        let optics = |gamma| Optics {
            noise: 0.0,
            ambient: 0.0,
            camera_gamma: gamma,
            ..Optics::standard()
        };
        let (w, h) = (640, 480);
        let flat = Grid::filled(w, h, 0.0f32);
        let away = Grid::filled(w, h, -0.5f32);
        let red = |gamma: Option<f64>, p: &Grid<f32>| {
            render_slopes(&optics(gamma), p, &flat, 0)
                .dx
                .get_pixel(320, 240)
                .0[0] as f64
        };
        assert!((red(Some(2.2), &flat) - red(None, &flat)).abs() <= 1.0);
        let (linear, bent) = (
            red(None, &away) / red(None, &flat),
            red(Some(2.2), &away) / red(Some(2.2), &flat),
        );
        assert!(linear < 0.9, "{linear}");
        assert!(
            (bent - linear.powf(1.0 / 2.2)).abs() < 0.02,
            "{bent} {linear}"
        );
    }

    #[test]
    fn with_finite_strips_a_phase_answers_the_other_axis_slope_near_their_ends() {
        let optics = |overhang| Optics {
            noise: 0.0,
            strip_overhang_mm: overhang,
            ..Optics::standard()
        };
        // Skin sloping along y only (q = 0.4), seen in the dx phase.
        let (w, h) = (640, 480);
        let p = Grid::filled(w, h, 0.0f32);
        let q = Grid::filled(w, h, 0.4f32);
        let flat = Grid::filled(w, h, 0.0f32);
        let red = |o: Option<f64>, slope: &Grid<f32>, x: u32, y: u32| {
            render_slopes(&optics(o), &p, slope, 0).dx.get_pixel(x, y).0[0] as i32
        };
        let change = |o: Option<f64>, y: u32| red(o, &q, 320, y) - red(o, &flat, 320, y);
        // Strips along the whole axis: the y slope only dims every pixel alike (|n|).
        assert_eq!(change(None, 5), change(None, 240));
        // Finite strips: near their top end their light comes from below as well, so a
        // skin sloping down (+y) faces it and reads brighter than at the middle.
        assert!(change(Some(2.0), 5) >= change(Some(2.0), 240) + 4);
        // A strip running far past the frame lights as one along the whole axis.
        let long = render_slopes(&optics(Some(1e6)), &p, &q, 0).dx;
        let none = render_slopes(&optics(None), &p, &q, 0).dx;
        let most = long
            .as_raw()
            .iter()
            .zip(none.as_raw())
            .map(|(a, b)| (*a as i32 - *b as i32).abs())
            .max();
        assert!(most <= Some(1), "{most:?}");
    }

    #[test]
    fn flat_skin_is_balanced_in_the_middle_and_colours_follow_the_slope() {
        let optics = Optics {
            noise: 0.0,
            ..Optics::standard()
        };
        let pair = render(&optics, &Scene::default(), 0);
        let mid = pair.dx.get_pixel(320, 240).0;
        assert!((mid[0] as i32 - mid[2] as i32).abs() <= 1, "{mid:?}");
        assert_eq!(mid[1] as f64, optics.ambient);
        // A ball's right half faces x− (blue) in the dx image, its left half x+ (red).
        let scene = Scene {
            shapes: vec![Shape::Ball {
                cx: 320.0 / 15.0,
                cy: 240.0 / 15.0,
                diameter: 8.0,
                depth: 1.0,
            }],
        };
        let pair = render(&optics, &scene, 0);
        let right = pair.dx.get_pixel(340, 240).0;
        let left = pair.dx.get_pixel(300, 240).0;
        assert!(right[2] > right[0] + 20, "{right:?}");
        assert!(left[0] > left[2] + 20, "{left:?}");
        let below = pair.dy.get_pixel(320, 260).0;
        assert!(below[2] > below[0] + 20, "{below:?}");
    }

    #[test]
    fn a_rough_coating_follows_minnaerts_law_and_is_lambert_at_one() {
        let with = |reflectance| Optics {
            reflectance,
            ..Optics::standard()
        };
        let strip = &StripVariation::NOMINAL;
        let flat = [0.0, 0.0, 1.0];
        // A facet tilted 30° towards the strip (the light comes from −x, dir = −1).
        let t = 30f64.to_radians();
        let tilted = [-t.sin(), 0.0, t.cos()];
        let (d, dir) = (10.0, [-1.0, 0.0]);
        let lambert = with(Reflectance::Lambert);
        let one = with(Reflectance::Rough { exponent: 1.0 });
        for n in [&flat, &tilted] {
            assert_eq!(
                light(&one, strip, n, d, dir),
                light(&lambert, strip, n, d, dir)
            );
        }
        let k = 0.7;
        let rough = with(Reflectance::Rough { exponent: k });
        // Flat skin reads as flat skin whatever the coating.
        let flat_light = light(&rough, strip, &flat, d, dir);
        assert!((flat_light - light(&lambert, strip, &flat, d, dir)).abs() < 1e-12);
        // cos(i)^k cos(r)^(k − 1), relative to flat skin's cos(e)^k: the cosine law's
        // ratio to the power k, times cos(30°)^(k − 1).
        let ratio = light(&lambert, strip, &tilted, d, dir) / flat_light;
        let want = ratio.powf(k) * t.cos().powf(k - 1.0);
        let got = light(&rough, strip, &tilted, d, dir) / flat_light;
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        assert!(
            ratio > 1.0 && got < ratio,
            "answers the slope less: {got} vs {ratio}"
        );
    }

    #[test]
    fn shapes_have_the_stated_depths() {
        let s = disk(10.0, 10.0, true);
        assert_eq!(s.depth(10.0, 10.0), 1.0);
        assert!((s.depth(10.0 + 6.5 + 0.5 / 1.3, 10.0) - 0.5).abs() < 1e-9);
        let b = Shape::Ball {
            cx: 0.0,
            cy: 0.0,
            diameter: 6.0,
            depth: 1.0,
        };
        assert!((b.depth(0.0, 0.0) - 1.0).abs() < 1e-12);
        assert_eq!(b.depth(3.0, 0.0), 0.0);
    }
}
