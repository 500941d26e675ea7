//! An independent renderer of the lit skin, written apart from [`render`](crate::tactile::render)
//! and sharing none of its shading, so the pipeline can be judged on physics it was not
//! tuned on.
//!
//! Physics: each strip is a row of point LEDs with a cos^m emission lobe, per-LED
//! brightness spread and inverse-square fall-off; the skin's normals come from finite
//! differences of the depth; it reflects with Oren–Nayar diffuse plus a GGX microfacet
//! lobe (Schlick Fresnel, Smith–Schlick shadowing) towards a pinhole camera above the
//! frame centre; facets turned away from an LED get nothing from it. The camera mixes the
//! LED colours through a crosstalk matrix, adds ambient light through the skin (a
//! procedural scene and an optional ceiling spot, partly blocked where an object
//! presses), vignetting, shot and read noise, a response curve and MJPG compression.

use image::RgbImage;
use rayon::prelude::*;
use std::f64::consts::PI;

use crate::grid::Grid;
use crate::rng::Rng;

use super::{AmbientScale, SkinFrames};

/// Flat-skin LED light at the frame centre, mean of the four strips (DN at exposure 1).
const TARGET_DN: f64 = 110.0;
/// Brightest flat-skin LED light allowed anywhere in the frame at exposure 1 (DN): when
/// the strips' fall-off would push the frame edge above it, the whole LED light is scaled
/// down (a camera set up so that flat skin does not clip).
const FLAT_PEAK_DN: f64 = 205.0;
/// Frame side (mm) for which the families' LED and camera geometry ranges are quoted;
/// other frames scale them with their shorter side.
const REFERENCE_SIDE_MM: f64 = 8.0;
/// Frame size (px, shorter side) for which the spot radius range is quoted.
const REFERENCE_SIDE_PX: f64 = 480.0;
/// Depth over which a touching object goes from not blocking to fully blocking (mm).
const CONTACT_MM: f64 = 0.05;
/// Depths beyond ±this (mm) are clamped (keeps absurd inputs finite).
const MAX_DEPTH_MM: f64 = 1.0e3;
/// Slopes beyond ±this are clamped.
const MAX_SLOPE: f64 = 1.0e3;
/// Steps of the emission-lobe lookup table over cos ∈ [0, 1].
const LOBE_STEPS: usize = 1024;
/// How far each strip runs past the frame at both ends, as a fraction of the side.
const STRIP_OVERHANG: f64 = 0.1;
/// Seed tags, so the families, the ambient scene and the noise draw different streams.
const MATTE_SEED: u64 = 0x6D61_7474_6521_0001;
const GLOSSY_SEED: u64 = 0x676C_6F73_7379_0002;
const SCENE_SEED: u64 = 0x7363_656E_6521_0003;
const FRAME_MIX: u64 = 0x9E37_79B9_7F4A_7C15;
const IMAGE_MIX: u64 = 0xD1B5_4A32_D192_ED03;
const ROW_MIX: u64 = 0xA24B_AED4_963E_E407;

/// One strip of point LEDs.
#[derive(Debug, Clone, PartialEq)]
pub struct Strip {
    /// Height of the LEDs above the skin plane (mm).
    pub height_mm: f64,
    /// Distance of the LED line outside the frame edge (mm).
    pub offset_mm: f64,
    /// Radiant intensity scale (arbitrary; nominal 1.0). It is the whole strip's power:
    /// each of its LEDs gets `power / leds.len()`, so the LED count does not change it.
    pub power: f64,
    /// Emission lobe exponent m in cos^m(angle from the LED's axis). Each LED's axis is
    /// perpendicular to its strip and points across the frame, tilted down to hit the
    /// skin at the frame's far edge (aiming that far keeps the fall-off across the frame
    /// moderate).
    pub lobe: f64,
    /// Per-LED brightness multipliers along the strip (e.g. 16–30 LEDs, each ~N(1, 0.05)).
    pub leds: Vec<f64>,
}

/// Everything about one simulated skin and camera.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicalParams {
    /// Image width (px).
    pub width: usize,
    /// Image height (px).
    pub height: usize,
    /// Scale (px per mm).
    pub px_per_mm: f64,
    /// Strips in order: 1 (x−, blue in dx), 2 (y−, blue in dy), 3 (x+, red in dx), 4 (y+,
    /// red in dy).
    pub strips: [Strip; 4],
    /// Camera RGB response to the blue LED and to the red LED (columns), rows R,G,B:
    /// crosstalk (e.g. blue LED → [0.05, 0.15, 1.0], red LED → [1.0, 0.12, 0.03]).
    pub crosstalk: [[f64; 2]; 3],
    /// Oren–Nayar roughness sigma (radians).
    pub roughness: f64,
    /// Diffuse albedo.
    pub albedo: f64,
    /// Specular weight (multiplies the GGX microfacet term).
    pub specular: f64,
    /// GGX alpha (lobe width).
    pub ggx_alpha: f64,
    /// Schlick F0 (reflectance at normal incidence).
    pub fresnel_f0: f64,
    /// Pinhole camera height above the skin (mm), looking straight down the −z axis at
    /// the frame centre.
    pub camera_height_mm: f64,
    /// Exposure gain from linear radiance to DN before the response curve, relative to
    /// nominal (1.0: flat skin in the middle of the frame at about 110 DN of LED light,
    /// mean of the four strips, unless the frame edges would clip at that level).
    pub exposure: f64,
    /// Response curve exponent: output = 255 · (v/255)^(1/gamma) on linear v (gamma 1 =
    /// linear camera, 2.2 = display gamma).
    pub gamma: f64,
    /// Vignetting strength k in (1 − k·r²), r = distance from centre / half-diagonal.
    pub vignetting: f64,
    /// Ambient light through the semi-transparent skin: linear level (DN before the
    /// curve, not scaled by `exposure`).
    pub ambient: f64,
    /// Colour of the ambient light (per channel multiplier, R, G, B).
    pub ambient_colour: [f64; 3],
    /// Fraction of the ambient light a touching object blocks where it presses (0..1).
    pub contact_block: f64,
    /// Optional bright ceiling spot seen through the skin: (x px, y px, radius px, peak
    /// linear DN).
    pub spot: Option<(f64, f64, f64, f64)>,
    /// Shot noise gain (variance = gain · signal in DN).
    pub shot_gain: f64,
    /// Read noise sigma (DN).
    pub read_noise: f64,
    /// JPEG quality of MJPG compression (None = raw frames).
    pub jpeg_quality: Option<u8>,
    /// Seed for noise and the ambient scene texture.
    pub seed: u64,
}

/// Ranges a family draws its parameters from (uniform in each `(lo, hi)`).
struct Ranges {
    seed_tag: u64,
    /// Family LED height and offset (mm at an 8 mm frame side; scaled with the frame).
    led_height: (f64, f64),
    led_offset: (f64, f64),
    /// Per-strip multiplier on the family height and offset.
    strip_jitter: (f64, f64),
    /// Per-strip power.
    power: (f64, f64),
    /// Family lobe exponent, and the per-strip multiplier on it.
    lobe: (f64, f64),
    lobe_jitter: (f64, f64),
    /// Number of LEDs per strip (inclusive).
    leds: (usize, usize),
    /// Blue LED into the red and green channels; red LED into green and blue.
    blue_into_red: (f64, f64),
    blue_into_green: (f64, f64),
    red_into_green: (f64, f64),
    red_into_blue: (f64, f64),
    roughness: (f64, f64),
    albedo: (f64, f64),
    specular: (f64, f64),
    ggx_alpha: (f64, f64),
    fresnel_f0: (f64, f64),
    /// mm at an 8 mm frame side; scaled with the frame.
    camera_height: (f64, f64),
    exposure: (f64, f64),
    gamma: f64,
    vignetting: (f64, f64),
    ambient: (f64, f64),
    ambient_colour: (f64, f64),
    contact_block: (f64, f64),
    /// Probability of a spot, its radius (px at a 480 px frame side) and peak (DN).
    spot_chance: f64,
    spot_radius: (f64, f64),
    spot_peak: (f64, f64),
    shot_gain: (f64, f64),
    read_noise: (f64, f64),
    jpeg_quality: (u8, u8),
}

const MATTE: Ranges = Ranges {
    seed_tag: MATTE_SEED,
    led_height: (4.5, 6.0),
    led_offset: (2.5, 4.0),
    strip_jitter: (0.92, 1.08),
    power: (0.88, 1.12),
    lobe: (2.0, 3.5),
    lobe_jitter: (0.95, 1.05),
    leds: (16, 24),
    blue_into_red: (0.02, 0.08),
    blue_into_green: (0.08, 0.2),
    red_into_green: (0.06, 0.15),
    red_into_blue: (0.01, 0.05),
    roughness: (0.2, 0.5),
    albedo: (0.75, 0.95),
    specular: (0.02, 0.08),
    ggx_alpha: (0.35, 0.6),
    fresnel_f0: (0.03, 0.05),
    camera_height: (25.0, 40.0),
    exposure: (0.95, 1.1),
    gamma: 1.0,
    vignetting: (0.1, 0.3),
    ambient: (8.0, 20.0),
    ambient_colour: (0.8, 1.2),
    contact_block: (0.3, 0.7),
    spot_chance: 1.0,
    spot_radius: (20.0, 60.0),
    spot_peak: (40.0, 120.0),
    shot_gain: (0.1, 0.3),
    read_noise: (1.0, 2.0),
    jpeg_quality: (85, 95),
};

const GLOSSY: Ranges = Ranges {
    seed_tag: GLOSSY_SEED,
    led_height: (3.0, 4.5),
    led_offset: (1.5, 3.0),
    strip_jitter: (0.92, 1.08),
    power: (0.88, 1.12),
    lobe: (2.5, 4.0),
    lobe_jitter: (0.95, 1.05),
    leds: (16, 24),
    blue_into_red: (0.0, 0.04),
    blue_into_green: (0.04, 0.1),
    red_into_green: (0.03, 0.08),
    red_into_blue: (0.0, 0.03),
    roughness: (0.05, 0.2),
    albedo: (0.6, 0.85),
    specular: (0.15, 0.35),
    ggx_alpha: (0.15, 0.3),
    fresnel_f0: (0.04, 0.06),
    camera_height: (25.0, 40.0),
    exposure: (0.5, 0.7),
    gamma: 2.2,
    vignetting: (0.3, 0.5),
    ambient: (4.0, 10.0),
    ambient_colour: (0.8, 1.2),
    contact_block: (0.4, 0.8),
    spot_chance: 0.5,
    spot_radius: (20.0, 60.0),
    spot_peak: (10.0, 30.0),
    shot_gain: (0.2, 0.4),
    read_noise: (1.5, 2.5),
    jpeg_quality: (75, 90),
};

impl PhysicalParams {
    /// Family "phys-matte": like a real matte skin, lit strongly: crosstalk, a weak broad
    /// specular lobe, ambient leak partly blocked by the object, a ceiling spot somewhere
    /// in the frame, LED heights/offsets/powers differing per strip, noise, no gamma
    /// (linear camera), MJPG ~ quality 90. All random within documented ranges from `seed`.
    ///
    /// Ranges (uniform): LED height 4.5–6 mm and offset 2.5–4 mm for the family, each
    /// strip ×0.92–1.08 of those; power 0.88–1.12 per strip; lobe 2–3.5 (×0.95–1.05 per
    /// strip); 16–24 LEDs per strip, each ×N(1, 0.05) clamped to 0.8–1.2; crosstalk blue
    /// LED → [0.02–0.08, 0.08–0.2, 1], red LED → [1, 0.06–0.15, 0.01–0.05]; roughness
    /// 0.2–0.5; albedo 0.75–0.95; specular 0.02–0.08, GGX alpha 0.35–0.6, F0 0.03–0.05;
    /// camera 25–40 mm; exposure 0.95–1.1; gamma 1; vignetting 0.1–0.3; ambient 8–20 DN,
    /// colour 0.8–1.2 per channel; contact block 0.3–0.7; a spot at 10–90 % of the frame,
    /// radius 20–60 px, peak 40–120 DN; shot gain 0.1–0.3, read noise 1–2 DN; JPEG
    /// quality 85–95. The lengths in mm are for a frame whose shorter side is 8 mm
    /// (160×120 px at 15 px/mm) and scale with the shorter side (×4 at 640×480 px and
    /// 15 px/mm), so every frame size sees the same lighting; the spot radius is for a
    /// 480 px shorter side and scales likewise.
    pub fn matte(width: usize, height: usize, px_per_mm: f64, seed: u64) -> Self {
        draw(&MATTE, width, height, px_per_mm, seed)
    }

    /// Family "phys-glossy": camera with display gamma (2.2), glossier skin (stronger,
    /// narrower specular), lower LED light (exposure lower, more relative noise), weaker
    /// crosstalk, stronger vignetting; random within ranges from `seed`.
    ///
    /// Ranges (uniform), as for [`PhysicalParams::matte`] except: LED height 3–4.5 mm,
    /// offset 1.5–3 mm; lobe 2.5–4; crosstalk blue LED → [0–0.04, 0.04–0.1, 1], red LED →
    /// [1, 0.03–0.08, 0–0.03]; roughness 0.05–0.2; albedo 0.6–0.85; specular 0.15–0.35,
    /// GGX alpha 0.15–0.3, F0 0.04–0.06; exposure 0.5–0.7; gamma 2.2; vignetting
    /// 0.3–0.5; ambient 4–10 DN; contact block 0.4–0.8; a weak spot (peak 10–30 DN) half
    /// of the time; shot gain 0.2–0.4, read noise 1.5–2.5 DN; JPEG quality 75–90.
    pub fn glossy(width: usize, height: usize, px_per_mm: f64, seed: u64) -> Self {
        draw(&GLOSSY, width, height, px_per_mm, seed)
    }
}

/// Frame's shorter side relative to the reference side (1 for bad inputs).
fn frame_scale(width: usize, height: usize, px_per_mm: f64) -> f64 {
    let side_mm = width.min(height) as f64 / px_per_mm;
    let scale = side_mm / REFERENCE_SIDE_MM;
    if scale.is_finite() && scale > 0.0 {
        scale
    } else {
        1.0
    }
}

fn pick(rng: &mut Rng, range: (f64, f64)) -> f64 {
    rng.range(range.0, range.1)
}

/// Uniform integer in `lo..=hi`.
fn pick_count(rng: &mut Rng, lo: usize, hi: usize) -> usize {
    let span = hi.saturating_sub(lo);
    lo + ((rng.uniform() * (span as f64 + 1.0)) as usize).min(span)
}

fn draw(r: &Ranges, width: usize, height: usize, px_per_mm: f64, seed: u64) -> PhysicalParams {
    let mut rng = Rng::new(seed ^ r.seed_tag);
    let scale = frame_scale(width, height, px_per_mm);
    let led_height = pick(&mut rng, r.led_height) * scale;
    let led_offset = pick(&mut rng, r.led_offset) * scale;
    let lobe = pick(&mut rng, r.lobe);
    let strips = std::array::from_fn(|_| {
        let height_mm = led_height * pick(&mut rng, r.strip_jitter);
        let offset_mm = led_offset * pick(&mut rng, r.strip_jitter);
        let power = pick(&mut rng, r.power);
        let strip_lobe = lobe * pick(&mut rng, r.lobe_jitter);
        let count = pick_count(&mut rng, r.leds.0, r.leds.1);
        let leds = (0..count)
            .map(|_| (1.0 + 0.05 * rng.gaussian()).clamp(0.8, 1.2))
            .collect();
        Strip {
            height_mm,
            offset_mm,
            power,
            lobe: strip_lobe,
            leds,
        }
    });
    let blue_into_red = pick(&mut rng, r.blue_into_red);
    let blue_into_green = pick(&mut rng, r.blue_into_green);
    let red_into_green = pick(&mut rng, r.red_into_green);
    let red_into_blue = pick(&mut rng, r.red_into_blue);
    let roughness = pick(&mut rng, r.roughness);
    let albedo = pick(&mut rng, r.albedo);
    let specular = pick(&mut rng, r.specular);
    let ggx_alpha = pick(&mut rng, r.ggx_alpha);
    let fresnel_f0 = pick(&mut rng, r.fresnel_f0);
    let camera_height_mm = pick(&mut rng, r.camera_height) * scale;
    let exposure = pick(&mut rng, r.exposure);
    let vignetting = pick(&mut rng, r.vignetting);
    let ambient = pick(&mut rng, r.ambient);
    let ambient_colour = [
        pick(&mut rng, r.ambient_colour),
        pick(&mut rng, r.ambient_colour),
        pick(&mut rng, r.ambient_colour),
    ];
    let contact_block = pick(&mut rng, r.contact_block);
    let spot_roll = rng.uniform();
    let spot_x = rng.range(0.1, 0.9) * width as f64;
    let spot_y = rng.range(0.1, 0.9) * height as f64;
    let spot_radius =
        pick(&mut rng, r.spot_radius) * (width.min(height) as f64 / REFERENCE_SIDE_PX);
    let spot_peak = pick(&mut rng, r.spot_peak);
    let spot = (spot_roll < r.spot_chance).then_some((spot_x, spot_y, spot_radius, spot_peak));
    let shot_gain = pick(&mut rng, r.shot_gain);
    let read_noise = pick(&mut rng, r.read_noise);
    let (q_lo, q_hi) = r.jpeg_quality;
    let quality = pick_count(&mut rng, usize::from(q_lo), usize::from(q_hi));
    PhysicalParams {
        width,
        height,
        px_per_mm,
        strips,
        crosstalk: [
            [blue_into_red, 1.0],
            [blue_into_green, red_into_green],
            [1.0, red_into_blue],
        ],
        roughness,
        albedo,
        specular,
        ggx_alpha,
        fresnel_f0,
        camera_height_mm,
        exposure,
        gamma: r.gamma,
        vignetting,
        ambient,
        ambient_colour,
        contact_block,
        spot,
        shot_gain,
        read_noise,
        jpeg_quality: Some(u8::try_from(quality).unwrap_or(q_hi)),
        seed,
    }
}

/// The independent renderer.
#[derive(Debug, Clone)]
pub struct PhysicalSkin {
    params: PhysicalParams,
    prepared: Prepared,
    /// Ambient light through the skin at nominal level with nothing pressed, linear DN
    /// per pixel and channel: the procedural scene (mean ≈ 1) times `ambient` and
    /// `ambient_colour`, plus the spot.
    ambient_dn: Vec<[f32; 3]>,
    /// The dx image has all four strips lit ([`Self::with_all_strips_in_dx`]).
    all_in_dx: bool,
}

/// One strip ready to shade: LEDs as `[x, y, z, weight]` (mm), the emission axis and
/// the lobe as a lookup table of cos^m.
#[derive(Debug, Clone)]
struct Lights {
    leds: Vec<[f64; 4]>,
    axis: [f64; 3],
    lobe: Vec<f64>,
}

/// Reflectance constants.
#[derive(Debug, Clone)]
struct Brdf {
    /// albedo / π.
    diffuse: f64,
    /// Oren–Nayar A and B.
    on_a: f64,
    on_b: f64,
    specular: f64,
    /// GGX alpha².
    alpha2: f64,
    /// Schlick–GGX k = alpha / 2.
    k: f64,
    f0: f64,
}

/// Everything derived from the parameters once.
#[derive(Debug, Clone)]
struct Prepared {
    px_per_mm: f64,
    camera: [f64; 3],
    strips: [Lights; 4],
    brdf: Brdf,
    /// Radiance → DN at exposure 1.
    gain: f64,
    /// `1 / gamma` when the camera is not linear.
    curve: Option<f64>,
    /// Vignetting: strength and frame centre and squared half-diagonal (px).
    vignetting: f64,
    centre_px: [f64; 2],
    half_diagonal2: f64,
}

/// A surface point seen by the camera.
struct Surface {
    point: [f64; 3],
    normal: [f64; 3],
    view: [f64; 3],
    /// n·v, kept away from 0.
    nv: f64,
    /// Smith–Schlick shadowing of the view direction divided by n·v.
    gv: f64,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalise(v: [f64; 3]) -> Option<[f64; 3]> {
    let len = dot(v, v).sqrt();
    (len.is_finite() && len > 1e-12).then_some([v[0] / len, v[1] / len, v[2] / len])
}

fn finite_or(v: f64, fallback: f64) -> f64 {
    if v.is_finite() { v } else { fallback }
}

fn lobe_table(m: f64) -> Vec<f64> {
    let m = finite_or(m, 0.0).clamp(0.0, 200.0);
    (0..=LOBE_STEPS)
        .map(|i| (i as f64 / LOBE_STEPS as f64).powf(m))
        .collect()
}

/// cos^m from the table, linearly interpolated.
fn lobe(table: &[f64], cos: f64) -> f64 {
    let t = cos.clamp(0.0, 1.0) * LOBE_STEPS as f64;
    let i = t as usize;
    match (table.get(i), table.get(i + 1)) {
        (Some(&a), Some(&b)) => a + (b - a) * (t - i as f64),
        (Some(&a), None) => a,
        _ => 0.0,
    }
}

/// 0 where untouched, 1 where the object presses at least `CONTACT_MM`.
fn contact(depth: f64) -> f64 {
    let t = (depth / CONTACT_MM).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Prepared {
    fn new(p: &PhysicalParams) -> Self {
        let px_per_mm = if p.px_per_mm.is_finite() && p.px_per_mm > 0.0 {
            p.px_per_mm
        } else {
            1.0
        };
        let (w_mm, h_mm) = (p.width as f64 / px_per_mm, p.height as f64 / px_per_mm);
        let strips = std::array::from_fn(|i| lights(i, &p.strips[i], w_mm, h_mm));
        let sigma2 = finite_or(p.roughness, 0.0).powi(2);
        let alpha = finite_or(p.ggx_alpha, 0.5).clamp(1e-3, 4.0);
        let gamma = finite_or(p.gamma, 1.0);
        let (wf, hf) = (p.width as f64, p.height as f64);
        Self {
            px_per_mm,
            camera: [w_mm / 2.0, h_mm / 2.0, finite_or(p.camera_height_mm, 30.0)],
            strips,
            brdf: Brdf {
                diffuse: finite_or(p.albedo, 0.0) / PI,
                on_a: 1.0 - 0.5 * sigma2 / (sigma2 + 0.33),
                on_b: 0.45 * sigma2 / (sigma2 + 0.09),
                specular: finite_or(p.specular, 0.0),
                alpha2: alpha * alpha,
                k: alpha / 2.0,
                f0: finite_or(p.fresnel_f0, 0.04),
            },
            gain: 1.0,
            curve: (gamma > 0.0 && (gamma - 1.0).abs() > 1e-9).then_some(1.0 / gamma),
            vignetting: finite_or(p.vignetting, 0.0),
            centre_px: [wf / 2.0, hf / 2.0],
            half_diagonal2: (wf * wf + hf * hf) / 4.0,
        }
    }

    /// The camera's view of the surface point `point` with unit normal `normal`.
    fn surface(&self, point: [f64; 3], normal: [f64; 3]) -> Surface {
        let to_camera = [
            self.camera[0] - point[0],
            self.camera[1] - point[1],
            self.camera[2] - point[2],
        ];
        let view = normalise(to_camera).unwrap_or([0.0, 0.0, 1.0]);
        let nv = dot(normal, view).clamp(1e-3, 1.0);
        let k = self.brdf.k;
        Surface {
            point,
            normal,
            view,
            nv,
            gv: 1.0 / (nv * (1.0 - k) + k),
        }
    }

    /// Radiance towards the camera from one strip's LEDs.
    fn strip_light(&self, lights: &Lights, s: &Surface) -> f64 {
        let b = &self.brdf;
        let mut total = 0.0;
        for led in &lights.leds {
            let d = [
                led[0] - s.point[0],
                led[1] - s.point[1],
                led[2] - s.point[2],
            ];
            let r2 = dot(d, d);
            if r2 <= 1e-12 {
                continue;
            }
            let inv_r = 1.0 / r2.sqrt();
            let l = [d[0] * inv_r, d[1] * inv_r, d[2] * inv_r];
            let nl = dot(s.normal, l);
            // Self-shadowing: a facet turned away from the LED gets nothing from it.
            if nl <= 0.0 {
                continue;
            }
            let emit = -dot(l, lights.axis);
            if emit <= 0.0 {
                continue;
            }
            let irradiance = led[3] * lobe(&lights.lobe, emit) * nl / r2;
            // Oren–Nayar: cos(φi − φr)·sin θi·sin θr = l·v − (n·l)(n·v), and
            // sin α · tan β = sin θi · sin θr / max(cos θi, cos θr).
            let azimuth = (dot(l, s.view) - nl * s.nv).max(0.0);
            let diffuse = b.diffuse * (b.on_a + b.on_b * azimuth / nl.max(s.nv));
            let half = [l[0] + s.view[0], l[1] + s.view[1], l[2] + s.view[2]];
            let half2 = dot(half, half);
            let specular = if b.specular > 0.0 && half2 > 1e-12 {
                let inv_h = 1.0 / half2.sqrt();
                let nh = (dot(s.normal, half) * inv_h).max(0.0);
                let vh = (dot(s.view, half) * inv_h).clamp(0.0, 1.0);
                let dd = nh * nh * (b.alpha2 - 1.0) + 1.0;
                let ndf = b.alpha2 / (PI * dd * dd);
                let fresnel = b.f0 + (1.0 - b.f0) * (1.0 - vh).powi(5);
                // G / (4 (n·l)(n·v)) with Schlick–GGX G1(x) = x / (x (1 − k) + k).
                let gl = 1.0 / (nl * (1.0 - b.k) + b.k);
                b.specular * ndf * fresnel * gl * s.gv * 0.25
            } else {
                0.0
            };
            total += (diffuse + specular) * irradiance;
        }
        total
    }

    /// Vignetting factor at pixel centre `(xp, yp)` (px).
    fn vignette(&self, xp: f64, yp: f64) -> f64 {
        let dx = xp - self.centre_px[0];
        let dy = yp - self.centre_px[1];
        (1.0 - self.vignetting * (dx * dx + dy * dy) / self.half_diagonal2).max(0.0)
    }
}

/// The LEDs of strip `index` (0: x−, 1: y−, 2: x+, 3: y+) on a `w_mm × h_mm` frame.
fn lights(index: usize, strip: &Strip, w_mm: f64, h_mm: f64) -> Lights {
    let height = finite_or(strip.height_mm, 0.0);
    let offset = finite_or(strip.offset_mm, 0.0);
    let count = strip.leds.len();
    let per_led = finite_or(strip.power, 0.0) / count.max(1) as f64;
    // Along the strip, from before its start to past its end.
    let along = |k: usize, side: f64| {
        let t = (k as f64 + 0.5) / count.max(1) as f64;
        side * (-STRIP_OVERHANG + (1.0 + 2.0 * STRIP_OVERHANG) * t)
    };
    // Each LED aims perpendicular to its strip at the far edge of the frame on the skin.
    let axis = match index {
        0 => [w_mm + offset, 0.0, -height],
        1 => [0.0, h_mm + offset, -height],
        2 => [-(w_mm + offset), 0.0, -height],
        _ => [0.0, -(h_mm + offset), -height],
    };
    let place = |k: usize| match index {
        0 => [-offset, along(k, h_mm)],
        1 => [along(k, w_mm), -offset],
        2 => [w_mm + offset, along(k, h_mm)],
        _ => [along(k, w_mm), h_mm + offset],
    };
    let leds = strip
        .leds
        .iter()
        .enumerate()
        .map(|(k, &m)| {
            let [x, y] = place(k);
            [x, y, height, per_led * finite_or(m, 0.0)]
        })
        .collect();
    Lights {
        leds,
        axis: normalise(axis).unwrap_or([0.0, 0.0, -1.0]),
        lobe: lobe_table(strip.lobe),
    }
}

/// The procedural scene behind the skin (per channel, mean 1) as ambient DN plus the spot.
fn ambient_light(p: &PhysicalParams) -> Vec<[f32; 3]> {
    struct Blob {
        x: f64,
        y: f64,
        inv_two_r2: f64,
        colour: [f64; 3],
    }
    let (w, h) = (p.width, p.height);
    let (wf, hf) = (w as f64, h as f64);
    let size = w.max(h).max(1) as f64;
    let mut rng = Rng::new(p.seed ^ SCENE_SEED);
    // A coloured tilt across the frame, then a few soft coloured blobs.
    let tilt: [[f64; 2]; 3] =
        std::array::from_fn(|_| [rng.range(-0.25, 0.25), rng.range(-0.25, 0.25)]);
    let count = pick_count(&mut rng, 3, 6);
    let blobs: Vec<Blob> = (0..count)
        .map(|_| {
            let x = rng.range(-0.1, 1.1) * wf;
            let y = rng.range(-0.1, 1.1) * hf;
            let radius = rng.range(0.08, 0.3) * size;
            let strength = rng.range(0.2, 0.6);
            let colour = [
                rng.range(0.2, 1.0) * strength,
                rng.range(0.2, 1.0) * strength,
                rng.range(0.2, 1.0) * strength,
            ];
            Blob {
                x,
                y,
                inv_two_r2: 1.0 / (2.0 * radius * radius),
                colour,
            }
        })
        .collect();
    let mut scene: Vec<[f64; 3]> = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let (xp, yp) = (x as f64 + 0.5, y as f64 + 0.5);
            let (u, v) = (xp / wf - 0.5, yp / hf - 0.5);
            let mut t: [f64; 3] = std::array::from_fn(|c| 1.0 + tilt[c][0] * u + tilt[c][1] * v);
            for blob in &blobs {
                let r2 = (xp - blob.x).powi(2) + (yp - blob.y).powi(2);
                let g = (-r2 * blob.inv_two_r2).exp();
                for (tc, bc) in t.iter_mut().zip(blob.colour) {
                    *tc += bc * g;
                }
            }
            scene.push(t);
        }
    }
    let mut sum = [0.0f64; 3];
    for t in &scene {
        for (s, v) in sum.iter_mut().zip(t) {
            *s += *v;
        }
    }
    let n = scene.len().max(1) as f64;
    let inv_mean = sum.map(|s| if s > 1e-9 { n / s } else { 1.0 });
    let level = finite_or(p.ambient, 0.0);
    let colour = p.ambient_colour.map(|c| finite_or(c, 1.0));
    let spot = p.spot.filter(|s| s.2.is_finite() && s.2 > 0.0);
    scene
        .iter()
        .enumerate()
        .map(|(i, t)| -> [f32; 3] {
            let (x, y) = ((i % w.max(1)) as f64, (i / w.max(1)) as f64);
            let spot_dn = spot.map_or(0.0, |(sx, sy, radius, peak)| {
                let r2 = (x - sx).powi(2) + (y - sy).powi(2);
                finite_or(peak * (-r2 / (2.0 * radius * radius)).exp(), 0.0)
            });
            std::array::from_fn(|c| {
                let texture = (t[c] * inv_mean[c]).clamp(0.05, 3.0);
                (level * colour[c] * texture + spot_dn) as f32
            })
        })
        .collect()
}

/// Depth (mm) of `depth` at `(x, y)`: 0 outside the grid or where not finite.
fn depth_at(depth: &Grid<f32>, x: usize, y: usize) -> f64 {
    if x < depth.width() && y < depth.height() {
        let d = f64::from(depth.get(x, y));
        if d.is_finite() {
            return d.clamp(-MAX_DEPTH_MM, MAX_DEPTH_MM);
        }
    }
    0.0
}

/// MJPG round trip; the raw image when encoding or decoding fails.
fn mjpeg(raw: RgbImage, quality: Option<u8>) -> RgbImage {
    let Some(quality) = quality else {
        return raw;
    };
    let mut bytes: Vec<u8> = Vec::new();
    let encoded = {
        let mut encoder =
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality.max(1));
        encoder.encode_image(&raw).is_ok()
    };
    if !encoded {
        return raw;
    }
    match image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg) {
        Ok(decoded) => {
            let rgb = decoded.to_rgb8();
            if rgb.dimensions() == raw.dimensions() {
                rgb
            } else {
                raw
            }
        }
        Err(_) => raw,
    }
}

impl PhysicalSkin {
    /// Prepares a skin (precomputes the ambient scene texture: a procedural scene seen
    /// through the skin, a coloured tilt and a few soft coloured blobs, mean ≈ 1 per
    /// channel, and the LED light normalisation).
    pub fn new(params: PhysicalParams) -> Self {
        let mut prepared = Prepared::new(&params);
        let ppm = prepared.px_per_mm;
        let flat = [0.0, 0.0, 1.0];
        // Flat skin at the frame centre: mean of the four strips → TARGET_DN.
        let centre = prepared.surface([prepared.camera[0], prepared.camera[1], 0.0], flat);
        let mean = prepared
            .strips
            .iter()
            .map(|s| prepared.strip_light(s, &centre))
            .sum::<f64>()
            / 4.0;
        // Brightest flat-skin channel anywhere in the frame (per unit gain).
        const SAMPLES: usize = 16;
        let mut peak = 0.0f64;
        for j in 0..=SAMPLES {
            for i in 0..=SAMPLES {
                let xp = params.width.saturating_sub(1) as f64 * i as f64 / SAMPLES as f64 + 0.5;
                let yp = params.height.saturating_sub(1) as f64 * j as f64 / SAMPLES as f64 + 0.5;
                let surface = prepared.surface([xp / ppm, yp / ppm, 0.0], flat);
                let light = prepared
                    .strips
                    .each_ref()
                    .map(|s| prepared.strip_light(s, &surface));
                let vignette = prepared.vignette(xp, yp);
                for (blue, red) in [(light[0], light[2]), (light[1], light[3])] {
                    for row in &params.crosstalk {
                        peak = peak.max((row[0] * blue + row[1] * red) * vignette);
                    }
                }
            }
        }
        let mut gain = if mean.is_finite() && mean > 0.0 {
            TARGET_DN / mean
        } else {
            f64::INFINITY
        };
        if peak.is_finite() && peak > 0.0 {
            gain = gain.min(FLAT_PEAK_DN / peak);
        }
        prepared.gain = if gain.is_finite() { gain } else { 0.0 };
        let ambient_dn = ambient_light(&params);
        Self {
            params,
            prepared,
            ambient_dn,
            all_in_dx: false,
        }
    }

    /// The same skin whose dx image has all four strips lit in one exposure (the dy and
    /// dark images as before): the frame the camera's curve is measured from.
    pub fn with_all_strips_in_dx(&self) -> PhysicalSkin {
        PhysicalSkin {
            all_in_dx: true,
            ..self.clone()
        }
    }

    /// The same skin with the strips `off` (wiring order) dark and nothing else changed,
    /// the exposure included: single-colour frames.
    pub fn with_strips_off(&self, off: [bool; 4]) -> PhysicalSkin {
        let mut skin = self.clone();
        for (lights, off) in skin.prepared.strips.iter_mut().zip(off) {
            if off {
                for led in &mut lights.leds {
                    led[3] = 0.0;
                }
            }
        }
        skin
    }

    /// The parameters.
    pub fn params(&self) -> &PhysicalParams {
        &self.params
    }

    /// dx, dy and dark frames of the skin pressed to `depth_mm` (a `width × height` grid;
    /// a grid of another size is a caller bug: return frames of the params' size using
    /// depth 0 where out of range, never panic; non-finite depth counts as 0). `frame`
    /// varies the noise (deterministic from seed and frame). `ambient` scales the ambient
    /// light of each exposure.
    pub fn render(&self, depth_mm: &Grid<f32>, frame: u64, ambient: AmbientScale) -> SkinFrames {
        let (w, h) = (self.params.width, self.params.height);
        let (Ok(w32), Ok(h32)) = (u32::try_from(w), u32::try_from(h)) else {
            return SkinFrames {
                dx: RgbImage::new(0, 0),
                dy: RgbImage::new(0, 0),
                dark: RgbImage::new(0, 0),
            };
        };
        if w == 0 || h == 0 {
            return SkinFrames {
                dx: RgbImage::new(w32, h32),
                dy: RgbImage::new(w32, h32),
                dark: RgbImage::new(w32, h32),
            };
        }
        let depth: Vec<f64> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| depth_at(depth_mm, x, y))
            .collect();
        let base = self.params.seed ^ frame.wrapping_mul(FRAME_MIX);
        let seeds: [u64; 3] =
            std::array::from_fn(|i| base ^ (i as u64 + 1).wrapping_mul(IMAGE_MIX));
        let scale = [ambient.dx, ambient.dy, ambient.dark];
        let row = w * 3;
        let mut dx = vec![0u8; row * h];
        let mut dy = vec![0u8; row * h];
        let mut dark = vec![0u8; row * h];
        dx.par_chunks_mut(row)
            .zip(dy.par_chunks_mut(row))
            .zip(dark.par_chunks_mut(row))
            .enumerate()
            .for_each(|(y, ((row_dx, row_dy), row_dark))| {
                self.shade_row(&depth, y, seeds, scale, [row_dx, row_dy, row_dark]);
            });
        let to_image = |buf: Vec<u8>| {
            RgbImage::from_raw(w32, h32, buf).unwrap_or_else(|| RgbImage::new(w32, h32))
        };
        let quality = self.params.jpeg_quality;
        SkinFrames {
            dx: mjpeg(to_image(dx), quality),
            dy: mjpeg(to_image(dy), quality),
            dark: mjpeg(to_image(dark), quality),
        }
    }

    /// Row `y` of the three images.
    fn shade_row(
        &self,
        depth: &[f64],
        y: usize,
        seeds: [u64; 3],
        scale: [f64; 3],
        out: [&mut [u8]; 3],
    ) {
        let row_seed = (y as u64).wrapping_add(1).wrapping_mul(ROW_MIX);
        let mut rngs = seeds.map(|s| Rng::new(s ^ row_seed));
        let [out_dx, out_dy, out_dark] = out;
        let pixels = out_dx
            .chunks_exact_mut(3)
            .zip(out_dy.chunks_exact_mut(3))
            .zip(out_dark.chunks_exact_mut(3));
        for (x, ((px_dx, px_dy), px_dark)) in pixels.enumerate() {
            let light = self.pixel_light(depth, x, y, scale);
            for ((px, values), rng) in [px_dx, px_dy, px_dark]
                .into_iter()
                .zip(light)
                .zip(rngs.iter_mut())
            {
                for (o, v) in px.iter_mut().zip(values) {
                    *o = self.sensor(v, rng);
                }
            }
        }
    }

    /// Linear DN of pixel `(x, y)` in the dx, dy and dark images, before noise.
    fn pixel_light(&self, depth: &[f64], x: usize, y: usize, scale: [f64; 3]) -> [[f64; 3]; 3] {
        let p = &self.params;
        let pr = &self.prepared;
        let (w, h) = (p.width, p.height);
        let at = |xx: usize, yy: usize| depth.get(yy * w + xx).copied().unwrap_or(0.0);
        let d = at(x, y);
        // Finite differences: central inside, one-sided at the borders.
        let dx = if w < 2 {
            0.0
        } else if x == 0 {
            at(1, y) - at(0, y)
        } else if x + 1 >= w {
            at(x, y) - at(x - 1, y)
        } else {
            0.5 * (at(x + 1, y) - at(x - 1, y))
        };
        let dy = if h < 2 {
            0.0
        } else if y == 0 {
            at(x, 1) - at(x, 0)
        } else if y + 1 >= h {
            at(x, y) - at(x, y - 1)
        } else {
            0.5 * (at(x, y + 1) - at(x, y - 1))
        };
        let slope_p = (dx * pr.px_per_mm).clamp(-MAX_SLOPE, MAX_SLOPE);
        let slope_q = (dy * pr.px_per_mm).clamp(-MAX_SLOPE, MAX_SLOPE);
        let inv = 1.0 / (1.0 + slope_p * slope_p + slope_q * slope_q).sqrt();
        let normal = [slope_p * inv, slope_q * inv, inv];
        let (xp, yp) = (x as f64 + 0.5, y as f64 + 0.5);
        let surface = pr.surface([xp / pr.px_per_mm, yp / pr.px_per_mm, -d], normal);
        let light = pr.strips.each_ref().map(|s| pr.strip_light(s, &surface));
        let led = finite_or(p.exposure, 0.0) * pr.gain;
        let mix = |blue: f64, red: f64| p.crosstalk.map(|row| led * (row[0] * blue + row[1] * red));
        let dx_light = if self.all_in_dx {
            mix(light[0] + light[1], light[2] + light[3])
        } else {
            mix(light[0], light[2])
        };
        let lit = [dx_light, mix(light[1], light[3]), [0.0; 3]];
        let block = 1.0 - p.contact_block * contact(d);
        let ambient = self.ambient_dn.get(y * w + x).copied().unwrap_or([0.0; 3]);
        let vignette = pr.vignette(xp, yp);
        std::array::from_fn(|k| {
            std::array::from_fn(|c| {
                (lit[k][c] + f64::from(ambient[c]) * scale[k] * block) * vignette
            })
        })
    }

    /// Noise, response curve and quantisation of one linear value (DN).
    fn sensor(&self, v: f64, rng: &mut Rng) -> u8 {
        let p = &self.params;
        let variance = (p.shot_gain * v.max(0.0) + p.read_noise * p.read_noise).max(0.0);
        let noisy = v + variance.sqrt() * rng.gaussian();
        let out = match self.prepared.curve {
            Some(inv_gamma) => 255.0 * (noisy.max(0.0) / 255.0).powf(inv_gamma),
            None => noisy,
        };
        out.round().clamp(0.0, 255.0) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tactile::render::{Scene, Shape};

    const W: usize = 160;
    const H: usize = 120;
    const PPM: f64 = 15.0;

    /// Mean colour of the `(2r+1)²` window around `(x, y)`.
    fn mean(img: &RgbImage, x: u32, y: u32, r: u32) -> [f64; 3] {
        let mut sum = [0.0; 3];
        let mut n = 0.0;
        for yy in y - r..=y + r {
            for xx in x - r..=x + r {
                for (s, v) in sum.iter_mut().zip(img.get_pixel(xx, yy).0) {
                    *s += f64::from(v);
                }
                n += 1.0;
            }
        }
        sum.map(|s| s / n)
    }

    fn flat() -> Grid<f32> {
        Grid::filled(W, H, 0.0)
    }

    fn families(seed: u64) -> [PhysicalParams; 2] {
        [
            PhysicalParams::matte(W, H, PPM, seed),
            PhysicalParams::glossy(W, H, PPM, seed),
        ]
    }

    #[test]
    fn flat_skin_is_balanced_dark_in_green_and_unsaturated() {
        for seed in 1..=3 {
            for params in families(seed) {
                let params = PhysicalParams {
                    spot: None,
                    ..params
                };
                let skin = PhysicalSkin::new(params);
                let frames = skin.render(&flat(), 0, AmbientScale::STEADY);
                let mid = mean(&frames.dx, 80, 60, 2);
                let [r, g, b] = mid;
                assert!((r - b).abs() <= 0.25 * r.max(b), "seed {seed}: {mid:?}");
                assert!(g < 0.75 * r.min(b), "seed {seed}: {mid:?}");
                assert!(
                    (40.0..250.0).contains(&r) && (40.0..250.0).contains(&b),
                    "seed {seed}: {mid:?}"
                );
                let dark = mean(&frames.dark, 80, 60, 2);
                assert!(
                    dark.iter().all(|&c| c < 0.6 * r.min(b)),
                    "seed {seed}: dark {dark:?} vs dx {mid:?}"
                );
                let saturated = frames
                    .dx
                    .pixels()
                    .chain(frames.dy.pixels())
                    .filter(|px| px.0.contains(&255))
                    .count();
                assert!(
                    saturated * 100 < 2 * W * H,
                    "seed {seed}: {saturated} saturated"
                );
            }
        }
    }

    #[test]
    fn ball_colours_follow_the_slope_convention() {
        let scene = Scene {
            shapes: vec![Shape::Ball {
                cx: 80.0 / PPM,
                cy: 60.0 / PPM,
                diameter: 4.0,
                depth: 0.6,
            }],
        };
        let depth = scene.truth(W, H, PPM).depth;
        for seed in 1..=3 {
            for params in families(seed) {
                let params = PhysicalParams {
                    spot: None,
                    ..params
                };
                let frames = PhysicalSkin::new(params).render(&depth, 0, AmbientScale::STEADY);
                // Left half: p > 0, faces the x+ strip (red in dx).
                let left = mean(&frames.dx, 64, 60, 1);
                assert!(left[0] > left[2] + 10.0, "seed {seed}: left {left:?}");
                let right = mean(&frames.dx, 96, 60, 1);
                assert!(right[2] > right[0] + 10.0, "seed {seed}: right {right:?}");
                // Lower half: q < 0, faces the y− strip (blue in dy).
                let below = mean(&frames.dy, 80, 76, 1);
                assert!(below[2] > below[0] + 10.0, "seed {seed}: below {below:?}");
                let above = mean(&frames.dy, 80, 44, 1);
                assert!(above[0] > above[2] + 10.0, "seed {seed}: above {above:?}");
            }
        }
    }

    #[test]
    fn frames_are_deterministic_and_noise_varies_with_the_frame() {
        let skin = PhysicalSkin::new(PhysicalParams::matte(W, H, PPM, 7));
        let a = skin.render(&flat(), 3, AmbientScale::STEADY);
        let b = skin.render(&flat(), 3, AmbientScale::STEADY);
        let c = skin.render(&flat(), 4, AmbientScale::STEADY);
        assert_eq!(a.dx.as_raw(), b.dx.as_raw());
        assert_eq!(a.dy.as_raw(), b.dy.as_raw());
        assert_eq!(a.dark.as_raw(), b.dark.as_raw());
        assert_ne!(a.dx.as_raw(), c.dx.as_raw());
        assert_ne!(a.dark.as_raw(), c.dark.as_raw());
        // The two phases and the dark frame draw different noise.
        let raw = PhysicalParams {
            jpeg_quality: None,
            ..PhysicalParams::matte(W, H, PPM, 7)
        };
        let frames = PhysicalSkin::new(raw.clone()).render(&flat(), 0, AmbientScale::STEADY);
        assert_eq!(PhysicalSkin::new(raw).params().seed, 7);
        assert_ne!(frames.dx.as_raw(), frames.dy.as_raw());
    }

    #[test]
    fn odd_depth_grids_and_parameters_do_not_panic() {
        let skin = PhysicalSkin::new(PhysicalParams::glossy(W, H, PPM, 2));
        let reference = skin.render(&flat(), 0, AmbientScale::STEADY);
        for depth in [
            Grid::filled(10, 7, 0.5f32),
            Grid::filled(300, 200, 0.3f32),
            Grid::filled(0, 0, 0.0f32),
        ] {
            let frames = skin.render(&depth, 0, AmbientScale::STEADY);
            for img in [&frames.dx, &frames.dy, &frames.dark] {
                assert_eq!(img.dimensions(), (160, 120));
            }
        }
        // Non-finite depth counts as 0: exactly the flat frames.
        let bad = Grid::from_fn(W, H, |x, y| match (x + y) % 3 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            _ => f32::NEG_INFINITY,
        });
        let frames = skin.render(&bad, 0, AmbientScale::STEADY);
        assert_eq!(frames.dx.as_raw(), reference.dx.as_raw());
        assert_eq!(frames.dy.as_raw(), reference.dy.as_raw());
        assert_eq!(frames.dark.as_raw(), reference.dark.as_raw());
        // Huge finite depth and odd parameters.
        let huge = Grid::from_fn(W, H, |x, _| match x % 2 {
            0 => 1.0e30f32,
            _ => -1.0e30,
        });
        let mut odd = PhysicalParams::matte(W, H, PPM, 3);
        odd.px_per_mm = 0.0;
        odd.gamma = 0.0;
        odd.ggx_alpha = f64::NAN;
        odd.roughness = -1.0;
        odd.camera_height_mm = -5.0;
        odd.strips[0].leds.clear();
        odd.strips[1].lobe = f64::NAN;
        odd.strips[2].height_mm = 0.0;
        odd.spot = Some((10.0, 10.0, 0.0, 50.0));
        odd.jpeg_quality = Some(0);
        let frames = PhysicalSkin::new(odd).render(&huge, 1, AmbientScale::STEADY);
        assert_eq!(frames.dx.dimensions(), (160, 120));
        let scaled = AmbientScale {
            dx: f64::NAN,
            dy: -1.0,
            dark: f64::INFINITY,
        };
        let frames = skin.render(&huge, 2, scaled);
        assert_eq!(frames.dark.dimensions(), (160, 120));
        // Empty frames.
        let empty = PhysicalParams::matte(0, 0, PPM, 1);
        let frames = PhysicalSkin::new(empty).render(&flat(), 0, AmbientScale::STEADY);
        assert_eq!(frames.dx.dimensions(), (0, 0));
        let one = PhysicalParams::matte(1, 1, PPM, 1);
        let frames = PhysicalSkin::new(one).render(&flat(), 0, AmbientScale::STEADY);
        assert_eq!(frames.dy.dimensions(), (1, 1));
    }

    #[test]
    fn a_pressing_object_blocks_ambient_light() {
        let params = PhysicalParams {
            spot: None,
            jpeg_quality: None,
            contact_block: 0.6,
            ..PhysicalParams::matte(W, H, PPM, 4)
        };
        let skin = PhysicalSkin::new(params);
        let scene = Scene {
            shapes: vec![Shape::Disk {
                cx: 80.0 / PPM,
                cy: 60.0 / PPM,
                diameter: 4.0,
                depth: 0.5,
                wall: 0.5,
                linear: false,
            }],
        };
        let depth = scene.truth(W, H, PPM).depth;
        let pressed = skin.render(&depth, 0, AmbientScale::STEADY).dark;
        let free = skin.render(&flat(), 0, AmbientScale::STEADY).dark;
        let level = |img: &RgbImage, x: u32, y: u32| mean(img, x, y, 12).iter().sum::<f64>();
        // Inside the flat bottom (radius 30 px) and far outside the disk.
        let inside = level(&pressed, 80, 60) / level(&free, 80, 60);
        let outside = level(&pressed, 20, 20) / level(&free, 20, 20);
        assert!(inside < 0.6, "inside {inside}");
        assert!((0.9..1.1).contains(&outside), "outside {outside}");
        assert!(inside < 0.7 * outside, "inside {inside}, outside {outside}");
    }
}
