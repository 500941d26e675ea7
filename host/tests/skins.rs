//! Skin families: every family follows the sensor's conventions, and the whole tactile
//! chain (calibration from the family's own presses, reconstruction) holds on a small
//! frame of a tuning family and of the independent renderer.

use stereotac::tactile::ambient::PhaseFrames;
use stereotac::tactile::calibrate::{Calibration, CalibrationSettings, calibrate};
use stereotac::tactile::camera_curve::CameraCurve;
use stereotac::tactile::crosstalk::measure;
use stereotac::tactile::render::{Scene, Shape};
use stereotac::tactile::skins::AmbientScale;
use stereotac::tactile::skins::evaluate::{EvalConfig, ball_presses, evaluate, format_report};
use stereotac::tactile::skins::families::{Role, Skin, families, family};

#[test]
fn every_family_lights_a_ball_by_the_conventions() {
    let fams = families();
    assert!(fams.iter().any(|f| f.role == Role::Tuning));
    assert!(fams.iter().filter(|f| f.role == Role::Evaluation).count() >= 2);
    for f in fams {
        for seed in 1..=2 {
            let skin = f.skin(320, 240, seed);
            let ppm = skin.px_per_mm();
            let (cx, cy) = (160.0 / ppm, 120.0 / ppm);
            // 1.5 mm from the centre, inside the 2.65 mm contact radius.
            let off = (1.5 * ppm).round() as u32;
            let scene = Scene {
                shapes: vec![Shape::Ball {
                    cx,
                    cy,
                    diameter: 8.0,
                    depth: 1.0,
                }],
            };
            let frames = skin.render(&scene, 1, AmbientScale::STEADY);
            let rb = |img: &image::RgbImage, x: u32, y: u32| {
                let p = img.get_pixel(x, y).0;
                p[0] as i32 - p[2] as i32
            };
            let flat = skin.render(&Scene::default(), 1, AmbientScale::STEADY);
            // Left of the centre faces the red strip in dx, right of it the blue one;
            // below the centre faces the blue strip in dy (relative to flat skin).
            let name = format!("{} skin {seed}", f.name);
            assert!(
                rb(&frames.dx, 160 - off, 120) - rb(&flat.dx, 160 - off, 120) > 10,
                "{name}: left not redder"
            );
            assert!(
                rb(&frames.dx, 160 + off, 120) - rb(&flat.dx, 160 + off, 120) < -10,
                "{name}: right not bluer"
            );
            assert!(
                rb(&frames.dy, 160, 120 + off) - rb(&flat.dy, 160, 120 + off) < -10,
                "{name}: below not bluer"
            );
            let lum = |img: &image::RgbImage| {
                img.pixels()
                    .map(|p| p.0.iter().map(|&c| c as u64).sum::<u64>())
                    .sum::<u64>()
            };
            // In linear light: a camera's curve lifts the dim room light it records.
            let linear = |img: &image::RgbImage| match &skin {
                Skin::Ours(o) => o.camera_gamma.map_or(img.clone(), |g| {
                    CameraCurve {
                        gamma: g as f32,
                        gain: 1.0,
                    }
                    .linearised(img)
                }),
                Skin::Physical(_) => img.clone(),
            };
            assert!(
                lum(&linear(&flat.dark)) * 2 < lum(&linear(&flat.dx)),
                "{name}: dark frame not dark"
            );
        }
    }
}

/// The crosstalk measured from a skin's single-colour frames (only the blue strip lit,
/// only the red) is the one its renderer mixes in, on our renderer and on the independent
/// one (both with linear cameras); the chain holds with it undone, and without the
/// measurement the filter is the identity.
#[test]
fn crosstalk_is_measured_from_single_colour_frames_and_undone() {
    for name in ["ours-random", "phys-matte"] {
        let skin = family(name).unwrap().skin(320, 240, 1);
        // The shares of each LED's light in the other's channel difference, from the
        // renderer's own parameters.
        let want = match &skin {
            Skin::Ours(o) => {
                let s = ((o.cross_leak - o.green_leak) / (1.0 - o.green_leak)) as f32;
                (s, s)
            }
            Skin::Physical(p) => {
                let c = p.params().crosstalk;
                (
                    ((c[0][0] - c[1][0]) / (c[2][0] - c[1][0])) as f32,
                    ((c[2][1] - c[1][1]) / (c[0][1] - c[1][1])) as f32,
                )
            }
        };
        let refs = skin.references(8);
        let (blue_only, red_only) = skin.single_colour_references(8);
        let got = measure(&refs.dx, &blue_only, &red_only).unwrap().shares();
        assert!(
            (got.0 - want.0).abs() < 0.01 && (got.1 - want.1).abs() < 0.01,
            "{name}: measured {got:?}, the renderer's {want:?}"
        );
        assert!(
            want.0.abs() > 0.01 || want.1.abs() > 0.01,
            "{name}: no crosstalk to find"
        );
    }
    let config = EvalConfig {
        crosstalk: true,
        ..small()
    };
    let r = evaluate(&family("phys-matte").unwrap(), &config, &mut |_| {});
    let table = format_report(&r);
    assert!(r.calibration.error.is_none(), "{table}");
    assert!(r.unmix.is_some_and(|u| !u.is_identity()), "{table}");
    assert!(table.contains("crosstalk measured and undone"), "{table}");
    assert_eq!(r.rest_contacts, Some(0), "{table}");
    assert!(r.beside_max_mm.unwrap() <= 0.02, "{table}");
    let disk = r.disk.expect("disks fit the frame");
    assert!((disk.mean - 1.0).abs() < 0.25, "{table}");
    let plain = evaluate(&family("phys-matte").unwrap(), &small(), &mut |_| {});
    assert!(plain.unmix.is_none());
}

/// Strips of finite length (`ours-finite-strips`): calibration asked for the side light
/// finds it, turning the light towards each strip's middle (the dy strips towards +x on
/// the left of the frame and −x on the right, the dx strips likewise along y), and the
/// chain holds with it; the nominal skin, matte with strips along the whole axis, keeps
/// none.
#[test]
fn the_side_light_of_finite_strips_is_measured_and_of_long_ones_not() {
    let config = EvalConfig {
        side_light: true,
        ..small()
    };
    let finite = family("ours-finite-strips").unwrap();
    let skin = finite.skin(320, 240, 1);
    let cal = calibrate_12_presses(&skin, finite.ball_diameter_mm, |s| s.side_light = true);
    let side = cal
        .model
        .side_light
        .expect("finite strips light from the side");
    let [left, right, top, bottom] =
        [(0.1, 0.5), (0.9, 0.5), (0.5, 0.1), (0.5, 0.9)].map(|(x, y)| side.at(x, y));
    // (12 presses of a 320×240 frame cover its corners thinly: the signs and the
    // change across the frame, not the values.)
    assert!(
        left[0] > 0.0 && right[0] < 0.0 && left[0] - right[0] > 0.15,
        "{left:?} {right:?}"
    );
    assert!(
        top[1] > 0.0 && bottom[1] < 0.0 && top[1] - bottom[1] > 0.15,
        "{top:?} {bottom:?}"
    );
    let r = evaluate(&finite, &config, &mut |_| {});
    let table = format_report(&r);
    assert!(r.side_light.is_some_and(|k| k > 0.1), "{table}");
    assert!(table.contains("side light up to"), "{table}");
    assert_eq!(r.rest_contacts, Some(0), "{table}");
    assert!(r.beside_max_mm.unwrap() <= 0.02, "{table}");
    let disk = r.disk.expect("disks fit the frame");
    assert!((disk.mean - 1.0).abs() < 0.25, "{table}");
    let long = evaluate(&family("ours-nominal").unwrap(), &config, &mut |_| {});
    assert_eq!(long.side_light, None, "{}", format_report(&long));
}

/// A camera's response curve (`ours-camera-gamma`, and the independent renderer's
/// display gamma on `phys-glossy`) is measured from a flat frame with all four strips lit,
/// beside the references and their LEDs-off frame; linear cameras (our renderer's other
/// skins, `phys-matte`) measure linear. Calibrated with the curve undone, the model keeps
/// it, its file round-trips it, and the chain holds.
#[test]
fn a_camera_curve_is_measured_from_light_that_adds_up_and_undone() {
    let measured = |name: &str| {
        let skin = family(name).unwrap().skin(320, 240, 1);
        let refs = skin.references(4);
        let all = skin.all_lit_reference(4);
        let got = CameraCurve::measure(&all, &refs.dx, &refs.dy, &refs.dark).unwrap();
        (skin, got)
    };
    let (skin, got) = measured("ours-camera-gamma");
    let Skin::Ours(optics) = &skin else {
        panic!("our renderer")
    };
    let truth = optics.camera_gamma.expect("a camera with a curve") as f32;
    let got = got.expect("not linear");
    assert!((got.gamma - truth).abs() < 0.05, "{got:?} against {truth}");
    let glossy = measured("phys-glossy").1.expect("display gamma");
    assert!((glossy.gamma - 2.2).abs() < 0.1, "{glossy:?}");
    for name in ["ours-random", "ours-nominal", "phys-matte"] {
        assert_eq!(measured(name).1, None, "{name}");
    }

    let config = EvalConfig {
        camera_curve: true,
        ..small()
    };
    let r = evaluate(&family("ours-camera-gamma").unwrap(), &config, &mut |_| {});
    let table = format_report(&r);
    assert!(r.calibration.error.is_none(), "{table}");
    assert!(
        r.camera_gamma.is_some_and(|g| (g - truth).abs() < 0.1),
        "{table}"
    );
    assert!(table.contains("camera curve (gamma"), "{table}");
    assert_eq!(r.rest_contacts, Some(0), "{table}");
    assert!(r.beside_max_mm.unwrap() <= 0.02, "{table}");
    let disk = r.disk.expect("disks fit the frame");
    assert!((disk.mean - 1.0).abs() < 0.1, "{table}");

    let cal = calibrate_12_presses(&skin, 6.0, |s| s.camera_curve = Some(got));
    assert_eq!(cal.model.camera_curve, Some(got));
    let json = serde_json::to_string(&cal.model).unwrap();
    assert!(json.contains("\"camera_curve\""));
    let back: stereotac::tactile::model::TactileModel = serde_json::from_str(&json).unwrap();
    assert_eq!(back, cal.model);
}

/// `skin` calibrated from 12 presses of a `ball_mm` ball against its references (no
/// LEDs-off frames), with the default settings as `change` leaves them.
fn calibrate_12_presses(
    skin: &Skin,
    ball_mm: f64,
    change: impl FnOnce(&mut CalibrationSettings),
) -> Calibration {
    let refs = skin.references(4);
    let presses = ball_presses(skin, ball_mm, 12, 1, 0);
    let mut settings = CalibrationSettings {
        ball_diameter_mm: ball_mm,
        px_per_mm: skin.px_per_mm(),
        ..Default::default()
    };
    change(&mut settings);
    let references = PhaseFrames {
        dx: &refs.dx,
        dy: &refs.dy,
        dark: None,
    };
    calibrate(&presses, Some(references), &settings, |_| {}).unwrap()
}

fn small() -> EvalConfig {
    EvalConfig {
        width: 320,
        height: 240,
        presses: 12,
        placements: 4,
        rest_frames: 3,
        disk_diameter_mm: 5.0,
        ..Default::default()
    }
}

#[test]
fn the_chain_holds_on_a_tuning_and_an_independent_family() {
    for (name, disk_tolerance) in [("ours-nominal", 0.05), ("phys-matte", 0.25)] {
        let f = family(name).unwrap();
        let r = evaluate(&f, &small(), &mut |_| {});
        let table = format_report(&r);
        assert!(r.calibration.error.is_none(), "{table}");
        assert!(r.calibration.used >= 6, "{table}");
        assert_eq!(r.rest_contacts, Some(0), "{table}");
        assert!(r.rest_max_mm.unwrap() <= 0.02, "{table}");
        assert!(r.beside_max_mm.unwrap() <= 0.02, "{table}");
        assert!(r.roi_ratio.unwrap() < 4.0, "{table}");
        assert!(r.edge_peak_ratio.unwrap() > 0.9, "{table}");
        let disk = r.disk.expect("disks fit the frame");
        assert!((disk.mean - 1.0).abs() < disk_tolerance, "{table}");
        // Times are reported, the pairs at rest timed in turn with the contact pairs:
        // a contact pair (detection, model and solve) costs more than one at rest.
        let [contact_ms, rest_ms] = r.pair_ms.expect("contact and rest pairs timed");
        let ratio = r.contact_over_rest.expect("timed in turn");
        assert!(contact_ms > rest_ms && ratio > 1.0, "{table}");
        assert_eq!(r.refused_frames, 0, "{table}");
    }
}

/// A ball larger than the family's teaches gentler slopes: the disk's wall (0.79) sits at
/// the top of what an 8 mm ball makes, where a plain mean of slopes per colour reads
/// short (0.949 mm on this skin at 640×480). The debiased table holds the depth (0.986
/// over 10 placements). At full size: a smaller frame has too few samples per slope
/// to show it.
#[test]
fn a_large_calibration_ball_still_reads_the_disk_deep_enough() {
    let f = family("ours-random").unwrap();
    let config = EvalConfig {
        ball_diameter_mm: Some(8.0),
        placements: 4,
        rest_frames: 1,
        ..Default::default()
    };
    let r = evaluate(&f, &config, &mut |_| {});
    let table = format_report(&r);
    let disk = r.disk.expect("disks fit the frame");
    assert!((disk.mean - 1.0).abs() < 0.03, "{table}");
}

/// On this tuning skin the blue strip overexposes the wall of a ball centred on the
/// frame's left edge where it faces the strip: the colour filter refuses those pixels.
/// Read as flat, that band took the ball to 0.89 of its depth; filled from their
/// neighbours the slopes give 0.96.
#[test]
fn a_saturated_wall_does_not_flatten_a_ball_at_the_frame_edge() {
    let f = family("ours-random").unwrap();
    let config = EvalConfig {
        skin_seed: 1,
        placements: 1,
        rest_frames: 1,
        ..Default::default()
    };
    let r = evaluate(&f, &config, &mut |_| {});
    let table = format_report(&r);
    assert!(r.edge_peak_ratio.unwrap() >= 0.95, "{table}");
}

/// The depth goal on the independent renderer, not met yet: a 1 mm disk reads
/// 0.92 mm there with the table (steep walls 0.71). Run with `--ignored` to see it.
#[test]
#[ignore = "issue 19 open: the independent renderer reads a 1 mm disk 0.92 mm"]
fn independent_renderer_reads_a_disk_within_the_goal() {
    let f = family("phys-matte").unwrap();
    let config = EvalConfig {
        placements: 10,
        rest_frames: 2,
        ..Default::default()
    };
    let r = evaluate(&f, &config, &mut |_| {});
    let table = format_report(&r);
    let disk = r.disk.expect("disks fit the frame");
    assert!(
        (disk.mean - 1.0).abs() <= 0.02 && disk.std <= 0.02,
        "{table}"
    );
    assert!(r.steep_disk.unwrap().mean >= 0.9, "{table}");
}

/// Scene light twice as bright as at calibration: the LEDs-off frame of each cycle takes
/// it out (interleaved mode), where raw frames show contact that is not there.
#[test]
fn leds_off_frames_remove_ambient_light_that_changed_since_calibration() {
    let f = family("ours-random").unwrap();
    let brighter = AmbientScale {
        dx: 2.0,
        dy: 2.0,
        dark: 2.0,
    };
    let flicker = AmbientScale {
        dx: 1.3,
        dy: 0.8,
        dark: 1.0,
    };
    for ambient in [brighter, flicker] {
        let config = EvalConfig {
            dark: true,
            ambient,
            ..small()
        };
        let r = evaluate(&f, &config, &mut |_| {});
        let table = format_report(&r);
        assert!(r.calibration.error.is_none(), "{table}");
        assert_eq!(r.rest_contacts, Some(0), "{table}");
        assert!(r.rest_max_mm.unwrap() <= 0.02, "{table}");
        assert!(r.beside_max_mm.unwrap() <= 0.02, "{table}");
        let disk = r.disk.expect("disks fit the frame");
        assert!((disk.mean - 1.0).abs() < 0.05, "{table}");
    }
    // The same brighter room without them: the scene is hard enough to matter.
    let raw = evaluate(
        &f,
        &EvalConfig {
            ambient: brighter,
            ..small()
        },
        &mut |_| {},
    );
    assert!(
        raw.rest_contacts.unwrap() > 0 || raw.beside_max_mm.unwrap() > 0.02,
        "raw frames coped with twice the ambient light: the test no longer shows what LEDs-off frames add\n{}",
        format_report(&raw)
    );
}

/// A model that undoes a camera curve and removes the LEDs-off frame's light first tells
/// a skin at rest from the frames as they came (`raw_glance`): every pair reads as it does
/// with every value undone and subtracted first, faint presses included, and the ambient
/// light taken out is the same.
#[test]
fn the_glance_at_frames_as_they_came_reads_every_pair_as_the_full_read_does() {
    use stereotac::tactile::ambient::{AmbientSource, subtracted};
    use stereotac::tactile::contact::block_references;
    use stereotac::tactile::model::ModelKind;
    use stereotac::tactile::poisson::SolverKind;
    use stereotac::tactile::raw_glance::RawGlance;
    use stereotac::tactile::reconstruct::Reconstructor;

    let skin = family("ours-camera-gamma").unwrap().skin(320, 240, 1);
    let refs = skin.references(4);
    let curve = CameraCurve::measure(&skin.all_lit_reference(4), &refs.dx, &refs.dy, &refs.dark)
        .unwrap()
        .expect("a camera with a curve");
    let presses = ball_presses(&skin, 6.0, 12, 1, 0);
    assert!(presses.iter().all(|p| p.dark.is_some()));
    let settings = CalibrationSettings {
        ball_diameter_mm: 6.0,
        px_per_mm: skin.px_per_mm(),
        camera_curve: Some(curve),
        ..Default::default()
    };
    let references = PhaseFrames {
        dx: &refs.dx,
        dy: &refs.dy,
        dark: Some(&refs.dark),
    };
    let cal = calibrate(&presses, Some(references), &settings, |_| {}).unwrap();
    let new = || {
        Reconstructor::new(
            cal.model.clone(),
            ModelKind::Lut,
            SolverKind::Dct,
            Some(references),
        )
        .unwrap()
    };
    let (mut glance, mut full) = (new(), new());
    assert!(glance.set_raw_glance(true));
    assert!(!full.set_raw_glance(false));

    // At rest, faint balls (0.03-0.15 mm: some under the threshold) and a clear one, in a room whose light
    // changed between the exposures.
    let mut scenes = vec![Scene::default(); 4];
    for (k, depth) in [0.03, 0.06, 0.1, 0.15, 0.5].into_iter().enumerate() {
        scenes.push(Scene {
            shapes: vec![Shape::Ball {
                cx: 4.0 + 3.0 * k as f64,
                cy: 5.0 + 2.0 * k as f64,
                diameter: 6.0,
                depth,
            }],
        });
    }
    let flicker = AmbientScale {
        dx: 1.3,
        dy: 0.8,
        dark: 1.0,
    };
    let (mut at_rest, mut contacts) = (0, 0);
    for (i, scene) in scenes.iter().enumerate() {
        let f = skin.render(scene, 7000 + i as u64, flicker);
        // With its own LEDs-off frame, without one, and with one of another scene
        // (brighter than the lit frames: refused, the calibration's light instead).
        let white = image::RgbImage::from_pixel(320, 240, image::Rgb([230, 230, 230]));
        for (dark, source) in [
            (Some(&f.dark), AmbientSource::DarkFrame),
            (None, AmbientSource::Calibration),
            (Some(&white), AmbientSource::CalibrationDarkRefused),
        ] {
            let frames = PhaseFrames {
                dx: &f.dx,
                dy: &f.dy,
                dark,
            };
            let (a, b) = (
                glance.reconstruct_frames(frames).unwrap(),
                full.reconstruct_frames(frames).unwrap(),
            );
            let what = format!("scene {i}, {source:?}");
            assert_eq!(a.no_contact(), b.no_contact(), "{what}");
            assert_eq!(a.depth_mm, b.depth_mm, "{what}");
            assert_eq!(a.regions, b.regions, "{what}");
            assert_eq!((a.ambient, b.ambient), (source, source), "{what}");
            for (u, v) in a.unlit_fraction.iter().zip(&b.unlit_fraction) {
                assert!((u - v).abs() < 0.01, "{what}: {u} against {v}");
            }
            if source == AmbientSource::DarkFrame {
                if a.no_contact() {
                    at_rest += 1;
                } else {
                    contacts += 1;
                }
            }
        }
    }
    // The scenes test both verdicts: every pair at rest, some presses seen.
    assert!(
        at_rest >= 4 && contacts >= 2,
        "{at_rest} at rest, {contacts} seen"
    );

    // And the glance itself answers for the pairs at rest (the reconstructor's
    // references: linear, the LEDs-off frame's light taken out), not for the clear press.
    let m = &cal.model;
    let linear = |i: &image::RgbImage| curve.linearised(i);
    let dark = linear(&refs.dark);
    let (led_dx, led_dy) = (
        subtracted(&linear(&refs.dx), &dark),
        subtracted(&linear(&refs.dy), &dark),
    );
    let block_refs = block_references(&led_dx, &led_dy, m.contact.coarse_step, m.filter.unmix);
    let estimate = m.ambient.as_ref().unwrap().image(320, 240);
    let raw = RawGlance::new(
        m.camera_curve.as_ref(),
        Some(&estimate),
        m.contact.coarse_step,
    )
    .expect("a curve and ambient light to take out");
    for (i, scene) in scenes
        .iter()
        .enumerate()
        .filter(|(i, _)| [0, 3, 8].contains(i))
    {
        let f = skin.render(scene, 7000 + i as u64, flicker);
        let frames = PhaseFrames {
            dx: &f.dx,
            dy: &f.dy,
            dark: Some(&f.dark),
        };
        let verdict = raw.at_rest(frames, &block_refs, &m.filter, &m.contact);
        assert_eq!(verdict.is_some(), i < 4, "scene {i}");
        if let Some((detection, source)) = verdict {
            assert!(detection.regions.is_empty());
            assert_eq!(source, AmbientSource::DarkFrame);
        }
    }

    // A model that neither undoes a curve nor removes ambient light has no such glance.
    let mut raw_presses = presses.clone();
    for p in &mut raw_presses {
        p.dark = None;
    }
    let plain = CalibrationSettings {
        camera_curve: None,
        ..settings
    };
    let plain = calibrate(
        &raw_presses,
        Some((&refs.dx, &refs.dy).into()),
        &plain,
        |_| {},
    );
    let mut rec = Reconstructor::new(
        plain.unwrap().model,
        ModelKind::Lut,
        SolverKind::Dct,
        Some(PhaseFrames {
            dx: &refs.dx,
            dy: &refs.dy,
            dark: None,
        }),
    )
    .unwrap();
    assert!(!rec.set_raw_glance(true));
}
