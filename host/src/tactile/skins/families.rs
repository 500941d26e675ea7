//! Named skin families, split into the ones we tune the pipeline on and the ones we only
//! judge it on.
//!
//! A family is a generator of skins: the seed draws one skin's physics. Tuning families
//! come from our renderer; evaluation families include held-out draws of our renderer and
//! two families of the independent renderer ([`super::physical`]), which nothing in the
//! pipeline was tuned on.

use std::fmt;

use image::RgbImage;

use super::physical::{PhysicalParams, PhysicalSkin};
use super::{AmbientScale, SkinFrames};
use crate::rng::Rng;
use crate::tactile::render::{Optics, Reflectance, Scene, render_truth};

/// What a family may be used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Thresholds and defaults may be chosen looking at it.
    Tuning,
    /// Only ever measured.
    Evaluation,
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Role::Tuning => "tuning",
            Role::Evaluation => "evaluation",
        })
    }
}

/// One simulated skin, whichever renderer draws it.
#[derive(Debug, Clone)]
pub enum Skin {
    /// Our renderer.
    Ours(Box<Optics>),
    /// The independent renderer.
    Physical(Box<PhysicalSkin>),
}

impl Skin {
    /// Frame size `(width, height)`.
    pub fn size(&self) -> (usize, usize) {
        match self {
            Skin::Ours(o) => (o.width, o.height),
            Skin::Physical(p) => (p.params().width, p.params().height),
        }
    }

    /// Scale (px per mm).
    pub fn px_per_mm(&self) -> f64 {
        match self {
            Skin::Ours(o) => o.px_per_mm,
            Skin::Physical(p) => p.params().px_per_mm,
        }
    }

    /// The dx, dy and dark frames of `scene`; `frame` varies the noise.
    pub fn render(&self, scene: &Scene, frame: u64, ambient: AmbientScale) -> SkinFrames {
        let (w, h) = self.size();
        let truth = scene.truth(w, h, self.px_per_mm());
        match self {
            Skin::Ours(o) => {
                let (dx, dy, dark) =
                    render_truth(o, &truth, frame, [ambient.dx, ambient.dy, ambient.dark]);
                SkinFrames { dx, dy, dark }
            }
            Skin::Physical(p) => p.render(&truth.depth, frame, ambient),
        }
    }

    /// No-contact frames averaged over `count` exposures, as a careful user would capture
    /// the references.
    pub fn references(&self, count: usize) -> SkinFrames {
        self.averaged(count, 500_000)
    }

    /// Flat-skin dx frames with only the blue strip (1) lit and with only the red strip
    /// (3) lit, each averaged over `count` exposures of their own noise, as the
    /// references are: what [`crate::tactile::crosstalk::measure`] reads beside the dx
    /// reference.
    pub fn single_colour_references(&self, count: usize) -> (RgbImage, RgbImage) {
        (
            self.with_strip_off(2).averaged(count, 600_000).dx,
            self.with_strip_off(0).averaged(count, 700_000).dx,
        )
    }

    /// A flat-skin frame with all four strips lit, averaged over `count` exposures as the
    /// references are: what [`crate::tactile::camera_curve::CameraCurve::measure`] reads
    /// beside them and their LEDs-off frame.
    pub fn all_lit_reference(&self, count: usize) -> RgbImage {
        let count = count.max(1);
        let (w, h) = self.size();
        let mut sum = vec![0u32; w * h * 3];
        for k in 0..count {
            let frame = 800_000 + k as u64;
            let img = match self {
                Skin::Ours(o) => crate::tactile::render::render_all_lit(o, frame),
                Skin::Physical(p) => {
                    let flat = crate::grid::Grid::filled(w, h, 0.0f32);
                    p.with_all_strips_in_dx()
                        .render(&flat, frame, AmbientScale::STEADY)
                        .dx
                }
            };
            for (s, v) in sum.iter_mut().zip(img.as_raw()) {
                *s += u32::from(*v);
            }
        }
        let raw = sum
            .iter()
            .map(|s| ((*s as f64 / count as f64).round()) as u8)
            .collect();
        RgbImage::from_raw(w as u32, h as u32, raw).expect("w*h*3 values")
    }

    /// The same skin with strip `index` (wiring order) dark.
    fn with_strip_off(&self, index: usize) -> Skin {
        match self {
            Skin::Ours(o) => {
                let mut o = o.clone();
                o.strips[index].gain = 0.0;
                Skin::Ours(o)
            }
            Skin::Physical(p) => {
                let mut off = [false; 4];
                off[index] = true;
                Skin::Physical(Box::new(p.with_strips_off(off)))
            }
        }
    }

    /// No-contact frames averaged over `count` exposures numbered from `first_frame`.
    fn averaged(&self, count: usize, first_frame: u64) -> SkinFrames {
        let count = count.max(1);
        let (w, h) = self.size();
        let mut sums = [
            vec![0u32; w * h * 3],
            vec![0u32; w * h * 3],
            vec![0u32; w * h * 3],
        ];
        for k in 0..count {
            let f = self.render(
                &Scene::default(),
                first_frame + k as u64,
                AmbientScale::STEADY,
            );
            for (sum, img) in sums.iter_mut().zip([&f.dx, &f.dy, &f.dark]) {
                for (s, v) in sum.iter_mut().zip(img.as_raw()) {
                    *s += u32::from(*v);
                }
            }
        }
        let [dx, dy, dark] = sums.map(|sum| {
            let raw = sum
                .iter()
                .map(|s| ((*s as f64 / count as f64).round()) as u8)
                .collect();
            image::RgbImage::from_raw(w as u32, h as u32, raw).expect("w*h*3 values")
        });
        SkinFrames { dx, dy, dark }
    }
}

/// A named generator of skins.
#[derive(Debug, Clone, Copy)]
pub struct Family {
    /// Name used on the command line and in reports.
    pub name: &'static str,
    /// Tuning or evaluation.
    pub role: Role,
    /// Diameter of the calibration ball pressed into it (mm).
    pub ball_diameter_mm: f64,
    /// One line on what it models.
    pub about: &'static str,
    build: fn(usize, usize, u64) -> Skin,
}

impl Family {
    /// The skin of this family drawn by `seed`, at `width × height` (15 px/mm at 640
    /// wide, scaling with the width).
    pub fn skin(&self, width: usize, height: usize, seed: u64) -> Skin {
        (self.build)(width, height, seed)
    }
}

/// Seeds of our renderer's evaluation draws start here; tuning draws stay below.
const HELD_OUT_SEEDS: u64 = 1 << 32;

/// Every family, tuning ones first.
pub fn families() -> Vec<Family> {
    vec![
        Family {
            name: "ours-nominal",
            role: Role::Tuning,
            ball_diameter_mm: 6.0,
            about: "our renderer, nominal optics (the demo's skin)",
            build: |w, h, _| Skin::Ours(Box::new(Optics::resolution(w, h))),
        },
        Family {
            name: "ours-random",
            role: Role::Tuning,
            ball_diameter_mm: 6.0,
            about: "our renderer, physics drawn at random (tuning draws)",
            build: |w, h, seed| Skin::Ours(Box::new(Optics::random(w, h, seed % HELD_OUT_SEEDS))),
        },
        Family {
            name: "ours-finite-strips",
            role: Role::Tuning,
            ball_diameter_mm: 6.0,
            about: "ours-random's skins with strips of finite length (side light near their ends)",
            build: |w, h, seed| {
                ours_random_with(w, h, seed, 0x51DE_116E_7000_0001, |optics, rng| {
                    optics.strip_overhang_mm = Some(rng.range(-1.5, 4.0));
                })
            },
        },
        Family {
            name: "ours-rough",
            role: Role::Tuning,
            ball_diameter_mm: 6.0,
            about: "ours-random's skins with a rough diffuse coating (Minnaert, k 0.6-0.9) instead of their reflectance",
            build: |w, h, seed| {
                ours_random_with(w, h, seed, 0x2006_4C0A_7100_0001, |optics, rng| {
                    optics.reflectance = Reflectance::Rough {
                        exponent: rng.range(0.6, 0.9),
                    };
                })
            },
        },
        Family {
            name: "ours-camera-gamma",
            role: Role::Tuning,
            ball_diameter_mm: 6.0,
            about: "ours-random's skins seen by a camera with a response curve (gamma 1.8-2.6 on the pixel values)",
            build: |w, h, seed| {
                ours_random_with(w, h, seed, 0xCA3E_7A6A_3300_0001, |optics, rng| {
                    // The curve moves to the camera: a skin drawn with a curve on each
                    // strip's shading alone is matte here.
                    if let Reflectance::Gamma(_) = optics.reflectance {
                        optics.reflectance = Reflectance::Lambert;
                    }
                    optics.camera_gamma = Some(rng.range(1.8, 2.6));
                })
            },
        },
        Family {
            name: "ours-low-light",
            role: Role::Tuning,
            ball_diameter_mm: 6.0,
            about: "ours-random's skins lit from low strips (elevation 14-22 deg far from a strip, 32-45 next to it)",
            build: |w, h, seed| {
                ours_random_with(w, h, seed, 0x10E1_1647_0000_0001, |optics, rng| {
                    optics.elevation_far_deg = rng.range(14.0, 22.0);
                    optics.elevation_near_deg = rng.range(32.0, 45.0);
                })
            },
        },
        Family {
            name: "ours-held-out",
            role: Role::Evaluation,
            ball_diameter_mm: 8.0,
            about: "our renderer, physics drawn at random (held-out draws, 8 mm ball)",
            build: |w, h, seed| Skin::Ours(Box::new(Optics::random(w, h, HELD_OUT_SEEDS + seed))),
        },
        Family {
            name: "phys-matte",
            role: Role::Evaluation,
            ball_diameter_mm: 8.0,
            about: "independent renderer: point LEDs, Oren-Nayar + weak GGX, crosstalk, ceiling spot, MJPG",
            build: |w, h, seed| {
                Skin::Physical(Box::new(PhysicalSkin::new(PhysicalParams::matte(
                    w,
                    h,
                    15.0 * w as f64 / 640.0,
                    seed,
                ))))
            },
        },
        Family {
            name: "phys-glossy",
            role: Role::Evaluation,
            ball_diameter_mm: 6.0,
            about: "independent renderer: display gamma, glossy skin, low LED light, vignetting, MJPG",
            build: |w, h, seed| {
                Skin::Physical(Box::new(PhysicalSkin::new(PhysicalParams::glossy(
                    w,
                    h,
                    15.0 * w as f64 / 640.0,
                    seed,
                ))))
            },
        },
    ]
}

/// `ours-random`'s skin of `seed` with one thing changed by `change`, which draws from its
/// own generator (seeded by `seed ^ tag`): a family made this way differs from
/// `ours-random`, seed for seed, only in that.
fn ours_random_with(
    width: usize,
    height: usize,
    seed: u64,
    tag: u64,
    change: impl FnOnce(&mut Optics, &mut Rng),
) -> Skin {
    let mut optics = Optics::random(width, height, seed % HELD_OUT_SEEDS);
    change(&mut optics, &mut Rng::new(seed ^ tag));
    Skin::Ours(Box::new(optics))
}

/// The family called `name`.
pub fn family(name: &str) -> Option<Family> {
    families().into_iter().find(|f| f.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn optics(name: &str, seed: u64) -> Optics {
        match family(name).expect("a family").skin(320, 240, seed) {
            Skin::Ours(o) => *o,
            Skin::Physical(_) => panic!("{name} is not our renderer's"),
        }
    }

    /// `ours-low-light` is `ours-random`, seed for seed, with its strips lower: the light
    /// elevations differ, within their ranges, and nothing else does.
    #[test]
    fn low_light_skins_differ_from_random_ones_only_in_the_elevations() {
        for seed in 1..=4 {
            let (random, low) = (optics("ours-random", seed), optics("ours-low-light", seed));
            assert!((14.0..22.0).contains(&low.elevation_far_deg), "seed {seed}");
            assert!(
                (32.0..45.0).contains(&low.elevation_near_deg),
                "seed {seed}"
            );
            assert!(
                low.elevation_far_deg < random.elevation_far_deg,
                "seed {seed}"
            );
            let same = Optics {
                elevation_far_deg: random.elevation_far_deg,
                elevation_near_deg: random.elevation_near_deg,
                ..low
            };
            assert_eq!(same, random, "seed {seed}");
        }
    }
}
