//! End-to-end tests of the tactile pipeline on our renderer: calibration from ball
//! presses, reconstruction accuracy, the skip paths, and hostile inputs.

use image::RgbImage;
use stereotac::tactile::ambient::{AmbientSource, PhaseFrames};
use stereotac::tactile::bench::errors;
use stereotac::tactile::calibrate::report::SATURATED_FRACTION;
use stereotac::tactile::calibrate::{
    CalibrationError, CalibrationPair, CalibrationSettings, Rejection, calibrate,
};
use stereotac::tactile::images::{ImageError, load_pairs};
use stereotac::tactile::model::{Background, ModelError, ModelKind, TactileModel};
use stereotac::tactile::phase_check::PhaseImageError;
use stereotac::tactile::poisson::SolverKind;
use stereotac::tactile::reconstruct::{ReconstructError, Reconstructor};
use stereotac::tactile::render::{Optics, Reflectance, Scene, Shape, Spot, render, render_truth};
use stereotac::tactile::synthetic::{ball_presses, reference_frames};

/// A small sensor so calibration takes well under a second.
fn optics() -> Optics {
    Optics::sized(320, 240)
}

fn settings(optics: &Optics) -> CalibrationSettings {
    let mut s = CalibrationSettings {
        px_per_mm: optics.px_per_mm,
        ..Default::default()
    };
    s.mlp.epochs = 8;
    s
}

fn calibrated(optics: &Optics) -> (TactileModel, (RgbImage, RgbImage)) {
    let pairs = ball_presses(optics, 10, 6.0, 11);
    let refs = reference_frames(optics);
    let cal = calibrate(
        &pairs,
        Some((&refs.0, &refs.1).into()),
        &settings(optics),
        |_| {},
    )
    .unwrap();
    (cal.model, refs)
}

fn ball(cx: f64, cy: f64, depth: f64) -> Scene {
    Scene {
        shapes: vec![Shape::Ball {
            cx,
            cy,
            diameter: 8.0,
            depth,
        }],
    }
}

/// A reconstructor of `model` with the reference frames `refs`.
fn reconstructor(
    model: &TactileModel,
    refs: &(RgbImage, RgbImage),
    kind: ModelKind,
    solver: SolverKind,
) -> Reconstructor {
    Reconstructor::new(model.clone(), kind, solver, Some((&refs.0, &refs.1).into())).unwrap()
}

/// The 6 mm disk, 1 mm deep with a flat bottom, whose wall has `slope`.
fn disk(slope: f64) -> Scene {
    Scene {
        shapes: vec![Shape::Disk {
            cx: 10.7,
            cy: 8.0,
            diameter: 6.0,
            depth: 1.0,
            wall: 1.0 / slope,
            linear: true,
        }],
    }
}

fn reading(
    optics: &Optics,
    model: &TactileModel,
    refs: &(RgbImage, RgbImage),
    kind: ModelKind,
    solver: SolverKind,
    scene: &Scene,
) -> f64 {
    let pair = render(optics, scene, 3);
    let truth = scene
        .truth(optics.width, optics.height, optics.px_per_mm)
        .depth;
    let mut rec = reconstructor(model, refs, kind, solver);
    let r = rec.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert!(r.depth_mm.as_slice().iter().all(|d| d.is_finite()));
    errors(&r.depth_mm, &truth).reading_mm
}

#[test]
fn calibrated_pipeline_reads_a_ball_with_both_models_and_solvers() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    assert!(model.fit.lut_train_rms < 0.08, "{:?}", model.fit);
    let scene = ball(10.0, 8.0, 1.0);
    for kind in ModelKind::ALL {
        for solver in SolverKind::ALL {
            let read = reading(&optics, &model, &refs, kind, solver, &scene);
            assert!(
                (read - 1.0).abs() < 0.12,
                "{kind} {solver}: read {read:.3} mm of 1.000"
            );
        }
    }
}

/// dx and dy of two moments (a ball in one, a disk in the other) give a plausible depth
/// whose slopes are not one surface's, and the reconstruction says so; each moment's own
/// pair is one surface, with every model.
#[test]
fn phases_of_two_moments_are_said_to_be_no_surface() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let (a, b) = (
        render(&optics, &ball(4.0, 4.0, 1.0), 3),
        render(&optics, &disk(0.79), 3),
    );
    for kind in ModelKind::ALL {
        let mut rec = reconstructor(&model, &refs, kind, SolverKind::Dct);
        for pair in [&a, &b] {
            let r = rec.reconstruct(&pair.dx, &pair.dy).unwrap();
            assert!(
                !r.not_one_surface() && r.unexplained_share < 0.05 && r.surface_warning().is_none(),
                "{kind}: one moment {}",
                r.unexplained_share
            );
        }
        let r = rec.reconstruct(&a.dx, &b.dy).unwrap();
        assert!(
            !r.no_contact() && r.not_one_surface(),
            "{kind}: {}",
            r.unexplained_share
        );
        let note = r.surface_warning().unwrap();
        assert!(
            note.contains("not those of one surface") && note.contains("same moment"),
            "{note}"
        );
    }
}

/// Warm room light added to a skin at rest after calibration reads as contact over the
/// frame; the imprint fills its region, with no skin at rest around it to measure from,
/// and the reconstruction says its depth has no zero.
#[test]
fn a_contact_with_no_skin_at_rest_around_it_is_said_to_have_no_zero() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let rest = render(&optics, &Scene::default(), 3);
    let warm = |img: &RgbImage| {
        let mut out = img.clone();
        for p in out.pixels_mut() {
            for (c, add) in p.0.iter_mut().zip([25u8, 18, 10]) {
                *c = c.saturating_add(add);
            }
        }
        out
    };
    let mut rec = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    let r = rec.reconstruct(&rest.dx, &rest.dy).unwrap();
    assert!(r.no_contact() && !r.no_skin_at_rest && r.warnings().is_empty());
    let ball = render(&optics, &ball(10.0, 8.0, 1.0), 3);
    let pressed = rec.reconstruct(&ball.dx, &ball.dy).unwrap();
    assert!(
        !pressed.no_contact() && !pressed.no_skin_at_rest,
        "a ball has skin around it"
    );
    match rec.reconstruct(&warm(&rest.dx), &warm(&rest.dy)) {
        Ok(r) => {
            assert!(!r.no_contact() && r.no_skin_at_rest, "{:?}", r.regions);
            assert!(
                r.warnings().iter().any(|w| w.contains("no skin at rest")),
                "{:?}",
                r.warnings()
            );
        }
        Err(e) => panic!("{e}"),
    }
}

/// The model without its light models: the lookup table alone, as model files written
/// before the light model read (nothing past the table's reach).
fn table_alone(model: &TactileModel) -> TactileModel {
    let mut alone = model.clone();
    alone.dx.light = None;
    alone.dy.light = None;
    alone
}

/// A disk 1 mm deep whose wall is steeper (1.6) than any slope the 6 mm calibration
/// ball made (about 0.9): the lookup table alone saturates at the ball's slopes and
/// reads it shallow (0.84 mm); the light and photometric models carry the strips'
/// response past them, and so does the table with the light model reading past its
/// reach (`tactile::past_reach`; measured 0.96 mm).
#[test]
fn the_light_model_reads_walls_steeper_than_the_calibration_ball() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let scene = disk(1.6);
    let read = |kind| reading(&optics, &model, &refs, kind, SolverKind::Dct, &scene);
    let alone = reading(
        &optics,
        &table_alone(&model),
        &refs,
        ModelKind::Lut,
        SolverKind::Dct,
        &scene,
    );
    assert!(alone < 0.9, "the table alone read {alone:.3} mm of 1.000");
    let (lut, light) = (read(ModelKind::Lut), read(ModelKind::Light));
    assert!(
        (lut - 1.0).abs() < 0.07,
        "the table with the light model past its reach read {lut:.3} mm of 1.000 (alone {alone:.3})"
    );
    assert!(
        (light - 1.0).abs() < 0.07,
        "light read {light:.3} mm of 1.000"
    );
    // So does the photometric model, from the four strips at once.
    let photometric = read(ModelKind::Photometric);
    assert!(
        (photometric - 1.0).abs() < 0.07,
        "photometric read {photometric:.3} mm of 1.000"
    );
}

/// The light model's reading past the table's reach is a switch: off, the table reads
/// alone, as from a model file without light models (bit for bit), and the count says
/// how many pixels the light model read; on again, the same depth as before. Only the
/// table and the perceptron, with light models, read past the calibration's slopes.
#[test]
fn reading_past_the_tables_reach_can_be_turned_off() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let pair = render(&optics, &disk(1.6), 3);
    let mut on = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    assert!(on.reads_past_reach());
    let with = on.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert!(with.past_reach_pixels > 0);

    let mut off = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    assert!(!off.set_past_reach(false) && !off.reads_past_reach());
    assert!(
        !off.fresh().reads_past_reach(),
        "a worker's copy keeps the switch"
    );
    let without = off.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert_eq!(without.past_reach_pixels, 0);
    let mut alone = reconstructor(&table_alone(&model), &refs, ModelKind::Lut, SolverKind::Dct);
    assert!(!alone.set_past_reach(true), "no light model to read with");
    let table = alone.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert_eq!(table.past_reach_pixels, 0);
    assert_eq!(without.depth_mm.as_slice(), table.depth_mm.as_slice());
    assert_ne!(without.depth_mm.as_slice(), with.depth_mm.as_slice());

    assert!(off.set_past_reach(true));
    let again = off.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert_eq!(again.past_reach_pixels, with.past_reach_pixels);
    assert_eq!(again.depth_mm.as_slice(), with.depth_mm.as_slice());

    // The perceptron saturates as the table does, and is read past it the same way: the
    // 1.6 wall reads deeper with it than alone.
    let truth = disk(1.6)
        .truth(optics.width, optics.height, optics.px_per_mm)
        .depth;
    let mut mlp = reconstructor(&model, &refs, ModelKind::Mlp, SolverKind::Dct);
    assert!(mlp.reads_past_reach());
    let read = mlp.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert!(read.past_reach_pixels > 0);
    assert!(!mlp.set_past_reach(false));
    let mlp_alone = mlp.reconstruct(&pair.dx, &pair.dy).unwrap();
    assert_eq!(mlp_alone.past_reach_pixels, 0);
    let (past, alone) = (
        errors(&read.depth_mm, &truth).reading_mm,
        errors(&mlp_alone.depth_mm, &truth).reading_mm,
    );
    assert!(
        (past - 1.0).abs() < 0.07 && past > alone + 0.03,
        "the perceptron read {past:.3} mm of 1.000 past its reach, {alone:.3} alone"
    );

    for kind in [ModelKind::Light, ModelKind::Photometric] {
        let mut other = reconstructor(&model, &refs, kind, SolverKind::Dct);
        assert!(
            !other.reads_past_reach() && !other.set_past_reach(true),
            "{kind}"
        );
        let r = other.reconstruct(&pair.dx, &pair.dy).unwrap();
        assert_eq!(r.past_reach_pixels, 0, "{kind}");
    }
}

/// Presses of a second, smaller ball (each tagged with its diameter) teach the table
/// the steep slopes the calibration ball cannot make: the 1.6 wall that the 6 mm ball's
/// table reads short reads deeper, and each press's depth comes from its own ball.
#[test]
fn presses_of_a_second_smaller_ball_teach_the_table_steep_walls() {
    let optics = optics();
    let refs = reference_frames(&optics);
    let (w, h) = (
        optics.width as f64 / optics.px_per_mm,
        optics.height as f64 / optics.px_per_mm,
    );
    // Ten presses of a ball, spread over the frame, `depths` deep.
    let presses = |diameter: f64, depths: (f64, f64), name: &str, ball: Option<f64>| {
        (0..10)
            .map(|k| {
                let t = k as f64 / 10.0;
                let depth = depths.0 + (depths.1 - depths.0) * t;
                let scene = Scene {
                    shapes: vec![Shape::Ball {
                        cx: 2.0 + (w - 4.0) * ((t * 7.3 + 0.05) % 1.0),
                        cy: 2.0 + (h - 4.0) * ((t * 3.7 + 0.05) % 1.0),
                        diameter,
                        depth,
                    }],
                };
                let pair = render(&optics, &scene, 2000 + k as u64 + 100 * diameter as u64);
                (
                    CalibrationPair {
                        name: format!("{name}{k:02}"),
                        dx: pair.dx,
                        dy: pair.dy,
                        dark: None,
                        ball_diameter_mm: ball,
                    },
                    depth,
                )
            })
            .collect::<Vec<_>>()
    };
    // The 6 mm ball pressed at most 0.9 mm deep makes slopes up to about 1.
    let (mut pairs, _): (Vec<CalibrationPair>, Vec<f64>) =
        presses(6.0, (0.6, 0.9), "large", None).into_iter().unzip();
    let one_ball = calibrate(
        &pairs,
        Some((&refs.0, &refs.1).into()),
        &settings(&optics),
        |_| {},
    )
    .unwrap();
    let (small, depths): (Vec<CalibrationPair>, Vec<f64>) =
        presses(4.0, (0.8, 1.1), "small", Some(4.0))
            .into_iter()
            .unzip();
    pairs.extend(small);
    let two_balls = calibrate(
        &pairs,
        Some((&refs.0, &refs.1).into()),
        &settings(&optics),
        |_| {},
    )
    .unwrap();
    // Each small press's depth from its own ball (a 6 mm ball would make its circle a
    // press about half as deep).
    for p in two_balls
        .presses
        .iter()
        .filter(|p| p.name.starts_with("small"))
    {
        let k: usize = p.name[5..].parse().unwrap();
        assert_eq!(p.ball_diameter_mm, 4.0);
        assert!(
            (p.depth_mm - depths[k]).abs() < 0.15,
            "{}: {:.3} mm, pressed {:.3}",
            p.name,
            p.depth_mm,
            depths[k]
        );
    }
    assert!(two_balls.presses.len() >= 18, "{:?}", two_balls.rejected);
    assert!(
        two_balls.report.max_slope[0] > 1.3,
        "{:?}",
        two_balls.report.max_slope
    );
    let scene = disk(1.6);
    let read = |model: &TactileModel| {
        reading(
            &optics,
            model,
            &refs,
            ModelKind::Lut,
            SolverKind::Dct,
            &scene,
        )
    };
    // The table alone (the light model reads past its reach otherwise: one ball then
    // 0.95 mm).
    let (one, two) = (
        read(&table_alone(&one_ball.model)),
        read(&table_alone(&two_balls.model)),
    );
    // Measured: 0.65 and 0.91 mm (0.63 and 0.88 before the slopes beside a strip in
    // shadow were read again, `tactile::shadowed`).
    assert!(one < 0.75, "one ball: {one:.3} mm of 1.000");
    assert!(
        two > 0.895 && two < 1.05,
        "two balls: {two:.3} mm of 1.000 (one ball {one:.3})"
    );
    // A ball diameter that is not a number is refused, naming the press.
    pairs[12].ball_diameter_mm = Some(f64::NAN);
    let err = calibrate(
        &pairs,
        Some((&refs.0, &refs.1).into()),
        &settings(&optics),
        |_| {},
    )
    .unwrap_err();
    assert!(matches!(err, CalibrationError::Settings(_)), "{err}");
    assert!(err.to_string().contains("small02"), "{err}");
}

/// A stretch of a flat-bottomed disk's wall overexposed in the dx phase (a wall facing a
/// strip saturates): its blocks say nothing, and left out of the contact they opened
/// the ring around the disk's flat middle, which then read 0 mm (found on a held-out
/// skin, with every model).
#[test]
fn a_saturated_stretch_of_wall_does_not_open_a_flat_bottomed_imprint() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let scene = disk(1.3);
    let ppm = optics.px_per_mm;
    let mut pair = render(&optics, &scene, 3);
    // From inside the flat middle to beyond the wall's foot, 1.6 mm high.
    let (x0, x1) = (((10.7 + 2.0) * ppm) as u32, ((10.7 + 4.8) * ppm) as u32);
    let (y0, y1) = (((8.0 - 0.8) * ppm) as u32, ((8.0 + 0.8) * ppm) as u32);
    for y in y0..y1 {
        for x in x0..x1 {
            pair.dx.get_pixel_mut(x, y).0[0] = 255;
        }
    }
    let truth = scene
        .truth(optics.width, optics.height, optics.px_per_mm)
        .depth;
    for kind in ModelKind::ALL {
        let mut rec = reconstructor(&model, &refs, kind, SolverKind::Dct);
        let r = rec.reconstruct(&pair.dx, &pair.dy).unwrap();
        let read = errors(&r.depth_mm, &truth).reading_mm;
        assert!(
            read > 0.6,
            "{kind}: the flat middle read {read:.3} mm of 1.000"
        );
        assert!(
            r.rejected_pixels > 0,
            "{kind}: the saturated stretch was refused"
        );
    }
}

#[test]
fn a_ball_on_the_frame_edge_needs_the_neumann_solver() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let scene = ball(0.0, 8.0, 1.0);
    let neumann = reading(
        &optics,
        &model,
        &refs,
        ModelKind::Lut,
        SolverKind::Dct,
        &scene,
    );
    let dirichlet = reading(
        &optics,
        &model,
        &refs,
        ModelKind::Lut,
        SolverKind::Dst,
        &scene,
    );
    assert!(neumann > 0.9, "dct read {neumann:.3}");
    assert!(
        dirichlet < 0.6,
        "dst read {dirichlet:.3} (expected to fail at the edge)"
    );
}

#[test]
fn contacts_at_every_edge_and_corner_give_finite_depth() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let (w, h) = (320.0 / 15.0, 240.0 / 15.0);
    for (cx, cy) in [
        (0.0, 0.0),
        (w / 2.0, 0.0),
        (w, 0.0),
        (w, h / 2.0),
        (w, h),
        (w / 2.0, h),
        (0.0, h),
        (0.0, h / 2.0),
    ] {
        let read = reading(
            &optics,
            &model,
            &refs,
            ModelKind::Lut,
            SolverKind::Dct,
            &ball(cx, cy, 1.0),
        );
        assert!(
            read > 0.5 && read < 1.5,
            "ball at ({cx:.1}, {cy:.1}) read {read:.3}"
        );
    }
}

#[test]
fn no_contact_stops_after_detection() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let pair = render(&optics, &Scene::default(), 9);
    for kind in ModelKind::ALL {
        let mut rec = reconstructor(&model, &refs, kind, SolverKind::Dct);
        let r = rec.reconstruct(&pair.dx, &pair.dy).unwrap();
        assert!(r.no_contact());
        assert_eq!(r.timings.model_ms, 0.0);
        assert_eq!(r.timings.solve_ms, 0.0);
        assert!(r.depth_mm.as_slice().iter().all(|&d| d == 0.0));
    }
    // The model's own background works too when no reference frames are given.
    let mut rec = Reconstructor::new(model, ModelKind::Lut, SolverKind::Dct, None).unwrap();
    assert!(rec.reconstruct(&pair.dx, &pair.dy).unwrap().no_contact());
}

/// Readings without contact hold the reconstructor's one zeroed map (no fill per pair);
/// a contact reading between them writes into a map of its own, and the shared one
/// stays zero, also after the caller changes its own copy.
#[test]
fn readings_at_rest_share_one_zeroed_map_that_contacts_leave_alone() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let rest = render(&optics, &Scene::default(), 9);
    let pressed = render(&optics, &ball(10.0, 8.0, 0.8), 10);
    let mut rec = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    let first = rec.reconstruct(&rest.dx, &rest.dy).unwrap();
    let contact = rec.reconstruct(&pressed.dx, &pressed.dy).unwrap();
    let second = rec.reconstruct(&rest.dx, &rest.dy).unwrap();
    assert!(first.no_contact() && second.no_contact() && !contact.no_contact());
    assert!(std::sync::Arc::ptr_eq(&first.depth_mm, &second.depth_mm));
    assert!(std::sync::Arc::ptr_eq(
        &first.contact_mask,
        &second.contact_mask
    ));
    assert!(!std::sync::Arc::ptr_eq(&first.depth_mm, &contact.depth_mm));
    let peak = contact
        .depth_mm
        .as_slice()
        .iter()
        .copied()
        .fold(0.0f32, f32::max);
    assert!(peak > 0.4, "{peak}");
    assert!(contact.contact_mask.as_slice().iter().any(|&t| t));
    // A caller's change to its reading is its own.
    let mut mine = first;
    std::sync::Arc::make_mut(&mut mine.depth_mm).set(3, 4, 1.0);
    let third = rec.reconstruct(&rest.dx, &rest.dy).unwrap();
    for r in [&second, &third] {
        assert!(r.depth_mm.as_slice().iter().all(|&d| d == 0.0));
        assert!(r.contact_mask.as_slice().iter().all(|&t| !t));
    }
    assert_eq!(mine.depth_mm.get(3, 4), 1.0);
}

/// A contact reading the caller has dropped lends its maps to the next contact reading,
/// which reads exactly as a fresh reconstructor's (the last reading's regions zeroed
/// again); a reading the caller keeps is never written into.
#[test]
fn contact_readings_reuse_dropped_maps_and_leave_kept_ones_alone() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let here = render(&optics, &ball(6.0, 6.0, 0.8), 10);
    let there = render(&optics, &ball(14.0, 10.0, 0.6), 11);
    let mut rec = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    let first = rec.reconstruct(&here.dx, &here.dy).unwrap();
    let first_map = std::sync::Arc::as_ptr(&first.depth_mm);
    drop(first);
    let second = rec.reconstruct(&there.dx, &there.dy).unwrap();
    assert_eq!(
        std::sync::Arc::as_ptr(&second.depth_mm),
        first_map,
        "a dropped reading's map is written again"
    );
    let want = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct)
        .reconstruct(&there.dx, &there.dy)
        .unwrap();
    assert!(!want.no_contact());
    assert_eq!(
        second.depth_mm, want.depth_mm,
        "nothing of the first press is left"
    );
    assert_eq!(second.contact_mask, want.contact_mask);
    // Kept: the next contact reading gets maps of its own.
    let kept = (*second.depth_mm).clone();
    let third = rec.reconstruct(&here.dx, &here.dy).unwrap();
    assert!(!std::sync::Arc::ptr_eq(&second.depth_mm, &third.depth_mm));
    assert_eq!(*second.depth_mm, kept);
    assert!(third.depth_mm.as_slice().iter().any(|&d| d > 0.4));
}

#[test]
fn a_ceiling_light_spot_makes_no_phantom_bump() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let lit = Optics {
        spot: Some(Spot {
            x: 160.0,
            y: 120.0,
            radius: 18.0,
            level: 120.0,
        }),
        ..optics.clone()
    };
    let pair = render(&lit, &Scene::default(), 4);
    let mut rec = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    let r = rec.reconstruct(&pair.dx, &pair.dy).unwrap();
    let max = r
        .depth_mm
        .as_slice()
        .iter()
        .fold(0.0f32, |m, d| m.max(d.abs()));
    assert!(max < 0.05, "phantom depth {max:.3} mm under a white spot");
    // And with a ball under the spot, the ball is still read.
    let pair = render(&lit, &ball(10.7, 8.0, 1.0), 4);
    let truth = ball(10.7, 8.0, 1.0).truth(320, 240, 15.0).depth;
    let r = rec.reconstruct(&pair.dx, &pair.dy).unwrap();
    let read = errors(&r.depth_mm, &truth).reading_mm;
    assert!(read > 0.7, "ball under the spot read {read:.3}");
}

#[test]
fn robust_across_reflectance_noise_and_falloff() {
    let base = optics();
    let variants = [
        Optics {
            reflectance: Reflectance::Glossy {
                strength: 0.3,
                shininess: 20.0,
            },
            ..base.clone()
        },
        Optics {
            reflectance: Reflectance::Gamma(2.2),
            ..base.clone()
        },
        Optics {
            noise: 3.0,
            ..base.clone()
        },
        Optics {
            falloff_mm: 12.0,
            ..base.clone()
        },
        Optics {
            green_leak: 0.08,
            ambient: 25.0,
            ..base.clone()
        },
    ];
    for optics in variants {
        let (model, refs) = calibrated(&optics);
        let read = reading(
            &optics,
            &model,
            &refs,
            ModelKind::Lut,
            SolverKind::Dct,
            &ball(11.0, 7.5, 1.0),
        );
        assert!((read - 1.0).abs() < 0.15, "{optics:?}: read {read:.3}");
    }
}

#[test]
fn hostile_images_give_finite_output_or_typed_errors() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    let mut rec = reconstructor(&model, &refs, ModelKind::Mlp, SolverKind::Dct);
    let black = RgbImage::new(320, 240);
    let white = RgbImage::from_pixel(320, 240, image::Rgb([255, 255, 255]));
    let mut noise = RgbImage::new(320, 240);
    let mut state = 1u32;
    for p in noise.pixels_mut() {
        state = state.wrapping_mul(1664525).wrapping_add(1013904223);
        *p = image::Rgb([(state >> 24) as u8, (state >> 16) as u8, (state >> 8) as u8]);
    }
    for (dx, dy) in [
        (&black, &black),
        (&white, &white),
        (&noise, &noise),
        (&black, &white),
    ] {
        let r = rec.reconstruct(dx, dy).unwrap();
        assert!(r.depth_mm.as_slice().iter().all(|d| d.is_finite()));
    }
    let small = RgbImage::new(100, 240);
    assert!(matches!(
        rec.reconstruct(&small, &black),
        Err(ReconstructError::PairSize { .. })
    ));
    assert!(matches!(
        rec.reconstruct(&small, &small),
        Err(ReconstructError::ModelSize { .. })
    ));
    assert!(matches!(
        Reconstructor::new(
            model.clone(),
            ModelKind::Lut,
            SolverKind::Dct,
            Some((&small, &small).into())
        ),
        Err(ReconstructError::ModelSize { .. })
    ));
    // A model whose arrays do not match its sizes is refused, not indexed out of bounds.
    let mut short = model.clone();
    short.dx.lut.table.truncate(7);
    assert!(matches!(
        Reconstructor::new(short, ModelKind::Lut, SolverKind::Dct, None),
        Err(ReconstructError::InvalidModel { field, .. }) if field == "dx.lut.table"
    ));
    // Degenerate frame sizes run through the same code (model resized with a background
    // of that size): 1×N and N×1 frames of flat skin with noise over their middle third
    // (contact there, integrated; noise over the whole frame is refused as light that
    // changed since the references).
    for (w, h) in [(1usize, 57usize), (57, 1), (3, 3)] {
        let flat = RgbImage::from_pixel(w as u32, h as u32, image::Rgb([150, 20, 130]));
        let img = RgbImage::from_fn(w as u32, h as u32, |x, y| {
            let along = (x as usize).max(y as usize);
            if (w.max(h) / 3..2 * w.max(h) / 3).contains(&along) {
                image::Rgb([(x * 37 % 256) as u8, 9, (y * 53 % 256) as u8])
            } else {
                image::Rgb([150, 20, 130])
            }
        });
        let mut m = model.clone();
        m.width = w;
        m.height = h;
        m.background = Background::from_images(&flat, &flat, m.background.factor);
        let mut rec = Reconstructor::new(m, ModelKind::Lut, SolverKind::Dct, None).unwrap();
        let r = rec.reconstruct(&img, &img).unwrap();
        assert!(
            r.depth_mm.as_slice().iter().all(|d| d.is_finite()),
            "{w}x{h}"
        );
        if w.max(h) > 3 {
            assert!(
                !r.no_contact(),
                "{w}x{h}: the middle third reads as contact"
            );
        }
        // (One image as dx and dy: refused as two frames of one phase where the frame
        // is wide or tall enough to tell.)
        let everywhere = rec.reconstruct(&noise_like(&img), &noise_like(&img));
        assert!(
            match &everywhere {
                Ok(r) => r.depth_mm.as_slice().iter().all(|d| d.is_finite()),
                Err(e) => matches!(
                    e,
                    ReconstructError::LightChanged { .. }
                        | ReconstructError::FramePair(PhaseImageError::SamePhase { .. })
                ),
            },
            "{w}x{h}: {:?}",
            everywhere.err()
        );
    }
}

/// Reference frames that show a press (taken with something on the skin) are refused,
/// naming the place: every press departs from them there, and a model calibrated on
/// them read a phantom contact there in every frame. The same presses on references of
/// the skin at rest calibrate.
#[test]
fn references_that_show_a_press_are_refused_with_the_place() {
    let optics = optics();
    let s = settings(&optics);
    let presses = ball_presses(&optics, 12, 6.0, 11);
    let rest = reference_frames(&optics);
    calibrate(&presses, Some((&rest.0, &rest.1).into()), &s, |_| {}).unwrap();
    let (w_mm, h_mm) = (
        optics.width as f64 / optics.px_per_mm,
        optics.height as f64 / optics.px_per_mm,
    );
    for (fx, fy) in [(0.3, 0.6), (0.75, 0.25)] {
        let (cx, cy) = (fx * w_mm, fy * h_mm);
        let scene = Scene {
            shapes: vec![Shape::Ball {
                cx,
                cy,
                diameter: 6.0,
                depth: 1.0,
            }],
        };
        let pressed = render(&optics, &scene, 999);
        let e = calibrate(
            &presses,
            Some((&pressed.dx, &pressed.dy).into()),
            &s,
            |_| {},
        )
        .map(|_| ())
        .unwrap_err();
        let CalibrationError::SharedDeparture {
            x,
            y,
            given,
            departs_in,
            ..
        } = &e
        else {
            panic!("ball at {cx:.1}, {cy:.1} mm: {e}");
        };
        assert!(*given && departs_in.0 * 10 >= departs_in.1 * 6, "{e}");
        assert!(
            e.to_string()
                .contains("the reference frames show something"),
            "{e}"
        );
        let off_mm = (x / optics.px_per_mm - cx).hypot(y / optics.px_per_mm - cy);
        assert!(
            off_mm < 1.0,
            "named {x}, {y} px for a ball at {cx:.1}, {cy:.1} mm: {e}"
        );
    }
}

/// Reference frames given at reconstruction are compared with the model's background:
/// one taken during a press is refused with the place (it made a phantom imprint in every
/// frame), while fresh frames of flat skin and light that changed since calibration (what
/// references are for) are taken.
#[test]
fn references_given_at_reconstruction_that_show_a_press_are_refused() {
    let optics = optics();
    let (model, _) = calibrated(&optics);
    let new = |dx: &RgbImage, dy: &RgbImage| {
        Reconstructor::new(
            model.clone(),
            ModelKind::Lut,
            SolverKind::Dct,
            Some((dx, dy).into()),
        )
    };
    let scaled = |img: &RgbImage, gain: f32| {
        let mut out = img.clone();
        for v in out.iter_mut() {
            *v = (f32::from(*v) * gain).round().min(255.0) as u8;
        }
        out
    };
    // A warm light through the skin over a corner (a lamp): it adds to the red strip's
    // colour and takes from the blue's as a slope does, but one way only.
    let warm = |img: &RgbImage| {
        let mut out = img.clone();
        let (w, h) = (img.width() as f32, img.height() as f32);
        for (x, y, px) in out.enumerate_pixels_mut() {
            let d2 = (x as f32 - 0.7 * w).powi(2) + (y as f32 - 0.3 * h).powi(2);
            let glow = (-d2 / (2.0 * (w / 6.0).powi(2))).exp();
            for (c, add) in [(0, 40.0), (1, 20.0)] {
                px.0[c] = (f32::from(px.0[c]) + add * glow).round().min(255.0) as u8;
            }
        }
        out
    };
    for frame in [501, 502, 503] {
        let rest = render(&optics, &Scene::default(), frame);
        new(&rest.dx, &rest.dy).expect("fresh flat skin is taken");
        new(&warm(&rest.dx), &warm(&rest.dy)).expect("a warm light is taken");
        for gain in [0.8, 1.2] {
            let (dx, dy) = (scaled(&rest.dx, gain), scaled(&rest.dy, gain));
            let mut rec = new(&dx, &dy).expect("light that changed is taken");
            let r = rec.reconstruct(&dx, &dy).unwrap();
            assert!(r.no_contact(), "{gain}");
        }
    }
    let (w_mm, h_mm) = (
        optics.width as f64 / optics.px_per_mm,
        optics.height as f64 / optics.px_per_mm,
    );
    // Two presses inside the frame, one centred on its left edge.
    for (fx, fy, depth) in [(0.3, 0.6, 1.0), (0.75, 0.25, 0.4), (0.0, 0.5, 0.8)] {
        let (cx, cy) = (fx * w_mm, fy * h_mm);
        let pressed = render(&optics, &ball(cx, cy, depth), 600);
        let err = new(&pressed.dx, &pressed.dy).err().expect("refused");
        let ReconstructError::ReferencesShowPress { x, y, .. } = err else {
            panic!("ball at {cx:.1}, {cy:.1} mm: {err}");
        };
        let off_mm = (x as f64 / optics.px_per_mm - cx).hypot(y as f64 / optics.px_per_mm - cy);
        assert!(
            off_mm < 1.5,
            "named {x}, {y} px for a ball at {cx:.1}, {cy:.1} mm: {err}"
        );
        assert!(err.to_string().contains("take them again"), "{err}");
    }
}

#[test]
fn presses_without_led_light_leave_the_threshold_alone_and_a_noisy_threshold_is_warned() {
    let optics = optics();
    let s = settings(&optics);
    let refs = reference_frames(&optics);
    let refs = || Some((&refs.0, &refs.1).into());
    let good = ball_presses(&optics, 6, 6.0, 11);
    let cal = calibrate(&good, refs(), &s, |_| {}).unwrap();
    // A press with a black dy, and one with its phases swapped, among them: set aside
    // before the flat skin's noise is measured, so the threshold is the good presses'.
    let mut mixed = good.clone();
    let black = RgbImage::new(optics.width as u32, optics.height as u32);
    mixed.insert(
        1,
        CalibrationPair {
            name: "black".into(),
            dx: good[0].dx.clone(),
            dy: black,
            dark: None,
            ball_diameter_mm: None,
        },
    );
    mixed.push(CalibrationPair {
        name: "swapped".into(),
        dx: good[1].dy.clone(),
        dy: good[1].dx.clone(),
        dark: None,
        ball_diameter_mm: None,
    });
    mixed.push(CalibrationPair {
        name: "dx twice".into(),
        dx: good[2].dx.clone(),
        dy: good[2].dx.clone(),
        dark: None,
        ball_diameter_mm: None,
    });
    let with_bad = calibrate(&mixed, refs(), &s, |_| {}).unwrap();
    assert_eq!(
        with_bad.model.contact.threshold,
        cal.model.contact.threshold
    );
    assert_eq!(with_bad.presses.len(), good.len());
    let names: Vec<&str> = with_bad.rejected.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(
        names,
        ["black", "swapped", "dx twice"],
        "in the presses' order"
    );
    assert!(
        with_bad.rejected[2]
            .reason
            .to_string()
            .contains("look like two images of the dx phase"),
        "{}",
        with_bad.rejected[2].reason
    );
    // A pair whose dx and dy frames show two different presses is set aside saying so,
    // and the calibration is made again without it: its second press no longer counts
    // as flat skin, so the threshold and the model are the good presses' own.
    let mut two = good.clone();
    two.insert(
        2,
        CalibrationPair {
            name: "two presses".into(),
            dx: good[3].dx.clone(),
            dy: good[5].dy.clone(),
            dark: None,
            ball_diameter_mm: None,
        },
    );
    let without = calibrate(&two, refs(), &s, |_| {}).unwrap();
    assert_eq!(without.rejected.len(), 1, "{:?}", without.rejected);
    let why = without.rejected[0].reason.to_string();
    assert!(
        without.rejected[0].name == "two presses" && why.contains("show different presses"),
        "{why}"
    );
    assert_eq!(without.model.contact.threshold, cal.model.contact.threshold);
    assert_eq!(without.presses, cal.presses);
    assert_eq!(without.report.presses_given, good.len() + 1);
    assert!(
        without
            .report
            .warnings
            .iter()
            .any(|w| w.starts_with(&format!("1 of {} presses set aside", good.len() + 1))),
        "{:?}",
        without.report.warnings
    );
    // A threshold given below the flat skin's noise is used, with a warning that names
    // the measured one; the measured threshold itself gets none.
    let says = "contact threshold given";
    assert!(!cal.report.warnings.iter().any(|w| w.contains(says)));
    let mut fixed = s.clone();
    fixed.fixed_threshold = true;
    fixed.contact.threshold = 0.001;
    let low = calibrate(&good, refs(), &fixed, |_| {}).unwrap();
    assert_eq!(low.model.contact.threshold, 0.001);
    let warning = low.report.warnings.iter().find(|w| w.contains(says));
    let measured = format!("{:.3}", cal.model.contact.threshold);
    assert!(
        warning.is_some_and(|w| w.contains("at rest") && w.contains(&measured)),
        "{:?}",
        low.report.warnings
    );
    fixed.contact.threshold = 3.0 * cal.model.contact.threshold;
    let high = calibrate(&good, refs(), &fixed, |_| {}).unwrap();
    assert!(!high.report.warnings.iter().any(|w| w.contains(says)));
}

/// Noise of `img`'s size over the whole frame.
fn noise_like(img: &RgbImage) -> RgbImage {
    RgbImage::from_fn(img.width(), img.height(), |x, y| {
        image::Rgb([(x * 37 % 256) as u8, 9, (y * 53 % 256) as u8])
    })
}

#[test]
fn calibration_rejects_bad_input_with_clear_errors() {
    let optics = optics();
    let s = settings(&optics);
    assert!(matches!(
        calibrate(&[], None, &s, |_| {}),
        Err(CalibrationError::NoPairs)
    ));
    let flat = render(&optics, &Scene::default(), 1);
    let refs = reference_frames(&optics);
    let pair = CalibrationPair {
        name: "flat".into(),
        dx: flat.dx.clone(),
        dy: flat.dy.clone(),
        dark: None,
        ball_diameter_mm: None,
    };
    for (ppm, ball) in [(1e9, 6.0), (15.0, f64::INFINITY), (0.0, 6.0)] {
        let bad = CalibrationSettings {
            px_per_mm: ppm,
            ball_diameter_mm: ball,
            ..s.clone()
        };
        assert!(
            matches!(
                calibrate(std::slice::from_ref(&pair), None, &bad, |_| {}),
                Err(CalibrationError::Settings(_))
            ),
            "px/mm {ppm}, ball {ball} mm"
        );
    }
    let err = calibrate(
        std::slice::from_ref(&pair),
        Some((&refs.0, &refs.1).into()),
        &s,
        |_| {},
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            CalibrationError::TooFewPresses { good: 0, ref rejected, .. }
                if rejected[0].name == "flat"
                    && matches!(rejected[0].reason, Rejection::NoContact { .. })
        ),
        "{err}"
    );
    assert!(err.to_string().contains("flat: no contact found"), "{err}");
    // A press whose dy is black, or whose phases are swapped, is set aside saying so
    // (not "no contact found").
    let press = ball_presses(&optics, 1, 6.0, 5).remove(0);
    for (dx, dy, says) in [
        (
            press.dx.clone(),
            RgbImage::new(optics.width as u32, optics.height as u32),
            "dy",
        ),
        (press.dy.clone(), press.dx.clone(), "swapped"),
    ] {
        let bad = CalibrationPair {
            name: "bad".into(),
            dx,
            dy,
            dark: None,
            ball_diameter_mm: None,
        };
        let err = calibrate(
            std::slice::from_ref(&bad),
            Some((&refs.0, &refs.1).into()),
            &s,
            |_| {},
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("bad: ") && err.contains(says) && !err.contains("no contact found"),
            "{says}: {err}"
        );
    }
    assert!(matches!(
        calibrate(std::slice::from_ref(&pair), None, &s, |_| {}),
        Err(CalibrationError::TooFewForMedian(1))
    ));
    let mut odd = ball_presses(&optics, 3, 6.0, 5);
    odd[1].dy = RgbImage::new(10, 10);
    let err = calibrate(&odd, None, &s, |_| {}).unwrap_err();
    assert!(err.to_string().contains("press01_dy"), "{err}");
    // A ball much smaller than claimed: every press is set aside with the reason.
    let presses = ball_presses(&optics, 6, 6.0, 5);
    let tiny = CalibrationSettings {
        ball_diameter_mm: 2.0,
        ..s.clone()
    };
    let err = calibrate(&presses, Some((&refs.0, &refs.1).into()), &tiny, |_| {}).unwrap_err();
    match &err {
        CalibrationError::TooFewPresses {
            good: 0,
            total: 6,
            rejected,
            ..
        } => assert!(
            rejected
                .iter()
                .all(|r| matches!(r.reason, Rejection::TooLarge { .. })),
            "{err}"
        ),
        _ => panic!("{err}"),
    }
    // The fix named for the CLI and for Python.
    let text = err.to_string();
    assert!(
        text.contains("--ball-diameter-mm") && text.contains("ball_diameter_mm"),
        "{err}"
    );
    // References that are not this sensor's phases are refused before anything else.
    let black = RgbImage::new(320, 240);
    let err = calibrate(&presses, Some((&refs.0, &black).into()), &s, |_| {}).unwrap_err();
    assert!(err.to_string().contains("reference frames dy"), "{err}");
    let err = calibrate(&presses, Some((&refs.1, &refs.0).into()), &s, |_| {}).unwrap_err();
    assert!(err.to_string().contains("swapped"), "{err}");
    let (model, _) = calibrated(&optics);
    for (dx, dy, want) in [
        (&refs.1, &refs.0, "swapped"),
        (&refs.0, &black, "LED light"),
    ] {
        let err = Reconstructor::new(
            model.clone(),
            ModelKind::Lut,
            SolverKind::Dct,
            Some((dx, dy).into()),
        )
        .err()
        .expect("refused");
        assert!(
            matches!(err, ReconstructError::References(_)) && err.to_string().contains(want),
            "{err}"
        );
    }
    // Frames without LED light are flagged, not read as "no contact".
    let mut rec = reconstructor(&model, &refs, ModelKind::Lut, SolverKind::Dct);
    let r = rec.reconstruct(&black, &black).unwrap();
    assert!(r.unlit() && r.no_contact(), "{:?}", r.unlit_fraction);
    let lit = render(&optics, &Scene::default(), 2);
    assert!(!rec.reconstruct(&lit.dx, &lit.dy).unwrap().unlit());
    // One phase unlit is enough: the other's colours alone would read as slopes (a
    // pressed disk's dx beside a black dy read 0.57 mm for 1 mm, with exit 0).
    let pressed = render(&optics, &disk(0.79), 3);
    for (dx, dy, phase) in [(&pressed.dx, &black, "dy"), (&black, &pressed.dy, "dx")] {
        let r = rec.reconstruct(dx, dy).unwrap();
        assert_eq!(r.unlit_phase(), Some(phase), "{:?}", r.unlit_fraction);
        let err = r.require_lit().expect_err("refused");
        assert!(
            err.to_string().contains(&format!("of the {phase} frame")),
            "{err}"
        );
    }
    assert!(
        rec.reconstruct(&pressed.dx, &pressed.dy)
            .unwrap()
            .require_lit()
            .is_ok()
    );
    // The exposure changed since the references (0.6× and 1.4×): the whole skin departs
    // from them. Refused with the fix, not read as a frame-wide contact.
    for gain in [0.6f32, 1.4] {
        let scale = |img: &RgbImage| {
            let mut out = img.clone();
            for v in out.iter_mut() {
                *v = (f32::from(*v) * gain).round().min(255.0) as u8;
            }
            out
        };
        let err = rec
            .reconstruct(&scale(&lit.dx), &scale(&lit.dy))
            .expect_err("refused");
        assert!(
            matches!(err, ReconstructError::LightChanged { .. })
                && err.to_string().contains("--ref-dx/--ref-dy"),
            "{gain}: {err}"
        );
        assert!(err.refuses_this_pair_only());
    }
    // Bumps pressed over the whole skin (a texture, a mesh) depart from the references
    // over most of the frame too, but as slopes do: read, not refused.
    let mut shapes = Vec::new();
    for i in 0..5 {
        for j in 0..4 {
            shapes.extend(ball(2.5 + 4.0 * i as f64, 2.0 + 4.0 * j as f64, 0.6).shapes);
        }
    }
    let bumps = render(&optics, &Scene { shapes }, 4);
    let r = rec
        .reconstruct(&bumps.dx, &bumps.dy)
        .expect("a press, read");
    let touched = r.contact_mask.as_slice().iter().filter(|t| **t).count();
    assert!(
        touched * 2 > r.contact_mask.as_slice().len(),
        "the bumps cover most of the frame: {touched}"
    );
    assert!(
        r.depth_mm.as_slice().iter().any(|&d| d > 0.3),
        "read as depth"
    );
}

#[test]
fn model_files_round_trip_and_refuse_other_versions() {
    let optics = optics();
    let (model, _) = calibrated(&optics);
    let dir = std::env::temp_dir().join(format!("stereotac-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("m.json");
    model.save(&path).unwrap();
    assert_eq!(TactileModel::load(&path).unwrap(), model);
    let text =
        std::fs::read_to_string(&path)
            .unwrap()
            .replacen("\"version\":1", "\"version\":99", 1);
    std::fs::write(&path, text).unwrap();
    assert!(matches!(
        TactileModel::load(&path),
        Err(ModelError::Version { version: 99, .. })
    ));
    std::fs::write(&path, "{}").unwrap();
    assert!(matches!(
        TactileModel::load(&path),
        Err(ModelError::Parse { .. })
    ));
    assert!(matches!(
        TactileModel::load(&dir.join("missing.json")),
        Err(ModelError::Io { .. })
    ));
    // Damaged or hostile fields are refused by name, never a panic later.
    let good: serde_json::Value = serde_json::from_slice(&model.to_json()).unwrap();
    // A key this version does not have (a typo, or a hand edit) is refused by name, at
    // the top level and inside.
    for (place, key) in [("", "px_per_mmm"), ("contact", "treshold")] {
        let mut m = good.clone();
        let target = if place.is_empty() {
            &mut m
        } else {
            &mut m[place]
        };
        target[key] = 15.into();
        let e = TactileModel::from_json("m.json", &serde_json::to_vec(&m).unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains(key) && e.contains("unknown field"), "{e}");
    }
    type Damage = fn(&mut serde_json::Value);
    let cases: [(&str, Damage); 44] = [
        // A side light of the wrong shape, or one no strip makes.
        (
            "side_light.kappa",
            |m| m["side_light"] = serde_json::json!({"kappa": [[0.1, 0.2, 0.3], vec![0.0; 12]]}),
        ),
        ("side_light.kappa", |m| {
            let mut wild = vec![0.0; 12];
            wild[3] = 1e6;
            m["side_light"] = serde_json::json!({"kappa": [vec![0.0; 12], wild]})
        }),
        // A crosstalk no camera has, or one that cannot be undone.
        (
            "filter.unmix",
            |m| m["filter"]["unmix"] = serde_json::json!({"red": [1.0, -0.9], "blue": [0.0, 1.0]}),
        ),
        (
            "filter.unmix",
            |m| m["filter"]["unmix"] = serde_json::json!({"red": [1.0, 1.0], "blue": [1.0, 1.0]}),
        ),
        ("dx.lut.gain_negative", |m| {
            m["dx"]["lut"]["gain_negative"]
                .as_array_mut()
                .unwrap()
                .pop();
        }),
        ("dy.lut.gain_negative", |m| {
            m["dy"]["lut"]["gain_negative"]
                .as_array_mut()
                .unwrap()
                .push(1.0.into())
        }),
        ("dx.light.response", |m| {
            m["dx"]["light"]["response"].as_array_mut().unwrap().pop();
        }),
        ("dx.mlp.response.points", |m| {
            m["dx"]["mlp"]["response"]["points"]
                .as_array_mut()
                .unwrap()
                .truncate(1)
        }),
        ("dy.mlp.response.points", |m| {
            m["dy"]["mlp"]["response"]["points"][1] = serde_json::json!([-1e30, 0.0])
        }),
        ("dy.mlp.response.points", |m| {
            m["dy"]["mlp"]["response"]["points"]
                .as_array_mut()
                .unwrap()
                .reverse()
        }),
        ("dy.light.cells_x", |m| {
            m["dy"]["light"]["cells_x"] = 0.into()
        }),
        ("photometric.lights", |m| {
            m["photometric"]["lights"].as_array_mut().unwrap().pop();
        }),
        ("photometric.cells_y", |m| {
            m["photometric"]["cells_y"] = 100.into()
        }),
        ("photometric.colour_power", |m| {
            m["photometric"]["colour_power"] = 0.into()
        }),
        ("photometric.norm_power", |m| {
            m["photometric"]["norm_power"] = (-1.0).into()
        }),
        // A camera curve no camera has.
        ("camera_curve.gamma", |m| {
            m["camera_curve"] = serde_json::json!({"gamma": 40.0, "gain": 2.0})
        }),
        ("camera_curve.gain", |m| {
            m["camera_curve"] = serde_json::json!({"gamma": 2.2, "gain": 0.0})
        }),
        ("skin_thickness_mm", |m| m["skin_thickness_mm"] = 0.into()),
        ("skin_thickness_mm", |m| m["skin_thickness_mm"] = 1e6.into()),
        ("background.dx", |m| {
            m["background"]["dx"].as_array_mut().unwrap().truncate(3)
        }),
        ("dx.lut.table", |m| {
            m["dx"]["lut"]["table"].as_array_mut().unwrap().pop();
        }),
        ("dy.lut.gain", |m| {
            m["dy"]["lut"]["gain"].as_array_mut().unwrap().clear()
        }),
        ("dx.mlp.layers[1].weights", |m| {
            m["dx"]["mlp"]["layers"][1]["weights"]
                .as_array_mut()
                .unwrap()
                .truncate(5)
        }),
        ("width", |m| m["width"] = 100_000.into()),
        ("px_per_mm", |m| m["px_per_mm"] = 0.into()),
        ("other_balls_mm", |m| {
            m["other_balls_mm"] = serde_json::json!([4.0, -2.0])
        }),
        ("background.factor", |m| {
            m["background"]["factor"] = 0.into()
        }),
        ("contact.threshold", |m| {
            m["contact"]["threshold"] = (-1.0).into()
        }),
        // Values a hand edit makes that used to load and read nonsense (or "no LED
        // light", blamed on the frames).
        ("contact.threshold", |m| {
            m["contact"]["threshold"] = 1e30.into()
        }),
        ("dx.lut.max_value", |m| {
            m["dx"]["lut"]["max_value"] = 1e30.into()
        }),
        ("dx.lut.gain", |m| m["dx"]["lut"]["gain"][0] = (-5.0).into()),
        ("background.dy", |m| {
            m["background"]["dy"][0][2] = (-50.0).into()
        }),
        ("filter.min_led", |m| m["filter"]["min_led"] = 1e30.into()),
        ("filter.max_white_ratio", |m| {
            m["filter"]["max_white_ratio"] = 0.into()
        }),
        ("filter.saturation", |m| {
            m["filter"]["saturation"] = 0.into()
        }),
        ("dy.mlp.layers", |m| {
            m["dy"]["mlp"]["layers"] = serde_json::json!([])
        }),
        ("background.width/height", |m| m["height"] = 100.into()),
        // Tables and networks that read slopes the wrong way round, or not at all
        // (raised or flat imprints with exit 0).
        ("dx.lut.table", |m| {
            for v in m["dx"]["lut"]["table"].as_array_mut().unwrap() {
                *v = (-v.as_f64().unwrap()).into();
            }
        }),
        ("dy.lut.table", |m| {
            for v in m["dy"]["lut"]["table"].as_array_mut().unwrap() {
                *v = 0.into();
            }
        }),
        // Light and photometric models zeroed or turned round: they read no slope, or
        // the wrong way (a contact read 0 mm, or 0.52 instead of 1.05, with exit 0).
        ("dx.light.response", |m| {
            for cell in m["dx"]["light"]["response"].as_array_mut().unwrap() {
                *cell = serde_json::json!([0.0, 0.0]);
            }
        }),
        ("dy.light.response", |m| {
            for cell in m["dy"]["light"]["response"].as_array_mut().unwrap() {
                for v in cell.as_array_mut().unwrap() {
                    *v = (-v.as_f64().unwrap()).into();
                }
            }
        }),
        ("photometric.lights (dx strips)", |m| {
            let cells = m["photometric"]["lights"].as_array().unwrap().len();
            m["photometric"]["lights"] = serde_json::json!(vec![[[0.0, 0.0]; 4]; cells])
        }),
        ("photometric.lights (dy strips)", |m| {
            for cell in m["photometric"]["lights"].as_array_mut().unwrap() {
                for strip in &mut cell.as_array_mut().unwrap()[2..] {
                    for v in strip.as_array_mut().unwrap() {
                        *v = (-v.as_f64().unwrap()).into();
                    }
                }
            }
        }),
        ("dx.mlp", |m| {
            let last = m["dx"]["mlp"]["layers"]
                .as_array_mut()
                .unwrap()
                .last_mut()
                .unwrap();
            for key in ["weights", "bias"] {
                for v in last[key].as_array_mut().unwrap() {
                    *v = 0.into();
                }
            }
        }),
    ];
    // Damage that is not JSON for a model (a key gone, a NaN typed into a table, text
    // where a number goes) names where it is.
    let text = serde_json::to_string(&good).unwrap();
    let mut missing = good.clone();
    missing["contact"]
        .as_object_mut()
        .unwrap()
        .remove("threshold");
    let mut text_in_table = good.clone();
    text_in_table["dx"]["lut"]["table"][7] = "x".into();
    // Lists of a fixed size with another length.
    let mut short_offset = good.clone();
    short_offset["dx"]["mlp"]["input_offset"]
        .as_array_mut()
        .unwrap()
        .pop();
    let mut short_cell = good.clone();
    short_cell["photometric"]["lights"][0]
        .as_array_mut()
        .unwrap()
        .pop();
    for (bytes, at) in [
        (
            serde_json::to_vec(&short_offset).unwrap(),
            "at `dx.mlp.input_offset`",
        ),
        (
            serde_json::to_vec(&short_cell).unwrap(),
            "at `photometric.lights[0]`",
        ),
        (serde_json::to_vec(&missing).unwrap(), "at `contact`"),
        (
            serde_json::to_vec(&text_in_table).unwrap(),
            "at `dx.lut.table[7]`",
        ),
        (
            text.replacen("\"threshold\":", "\"threshold\":NaN,\"x\":", 1)
                .into_bytes(),
            "at `contact.threshold`",
        ),
    ] {
        let err = TactileModel::from_json("m.json", &bytes)
            .unwrap_err()
            .to_string();
        assert!(err.contains(at) && err.contains("m.json"), "{at}: {err}");
        // A model file, damaged: said so, with the fix (not "not a model file").
        assert!(
            err.contains("edited or damaged")
                && err.contains("recalibrate")
                && !err.contains("not a stereotac model file"),
            "{at}: {err}"
        );
    }
    for (field, damage) in cases {
        let mut m = good.clone();
        damage(&mut m);
        let err = TactileModel::from_json("m.json", &serde_json::to_vec(&m).unwrap()).unwrap_err();
        assert!(
            matches!(&err, ModelError::Invalid { field: f, .. } if f == field),
            "{field}: {err}"
        );
        assert!(err.to_string().contains("recalibrate"), "{err}");
    }
    // Calibration's step for such parts: it leaves them out and says why, one line each,
    // and what is left loads.
    let mut turned = good.clone();
    for cell in turned["dy"]["light"]["response"].as_array_mut().unwrap() {
        *cell = serde_json::json!([0.0, 0.0]);
    }
    turned["photometric"]["lights"] = serde_json::json!(vec![
        [[0.0, 0.0]; 4];
        turned["photometric"]["lights"]
            .as_array()
            .unwrap()
            .len()
    ]);
    let mut turned: TactileModel = serde_json::from_value(turned).unwrap();
    let said = turned.leave_out_misdirected();
    assert_eq!(said.len(), 3, "{said:#?}");
    for (line, field) in said.iter().zip([
        "photometric.lights (dx strips)",
        "dy.light.response",
        "photometric.lights (dy strips)",
    ]) {
        assert!(
            line.starts_with(field) && line.contains("left out"),
            "{line}"
        );
    }
    assert!(turned.dx.light.is_some() && turned.dy.light.is_none());
    assert!(turned.photometric.is_none());
    TactileModel::from_json("m.json", &serde_json::to_vec(&turned).unwrap()).unwrap();
    let mut whole: TactileModel = serde_json::from_value(good.clone()).unwrap();
    assert!(whole.leave_out_misdirected().is_empty());
    // A model written before the light model existed still loads; asking it for the
    // light model is refused with the fix, the other models work.
    let mut old = good.clone();
    for axis in ["dx", "dy"] {
        old[axis].as_object_mut().unwrap().remove("light");
        // Nor had the MLP its response curve: its outputs stand as they are.
        old[axis]["mlp"].as_object_mut().unwrap().remove("response");
        // Nor the table its gains of negative readings: `gain` serves both signs.
        old[axis]["lut"]
            .as_object_mut()
            .unwrap()
            .remove("gain_negative");
    }
    // Nor the photometric model.
    assert!(good.get("photometric").is_some());
    old.as_object_mut().unwrap().remove("photometric");
    let old = TactileModel::from_json("m.json", &serde_json::to_vec(&old).unwrap()).unwrap();
    let err = Reconstructor::new(old.clone(), ModelKind::Light, SolverKind::Dct, None)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("dx.light") && err.contains("calibrate again"),
        "{err}"
    );
    let err = Reconstructor::new(old.clone(), ModelKind::Photometric, SolverKind::Dct, None)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("photometric") && err.contains("calibrate again"),
        "{err}"
    );
    assert!(Reconstructor::new(old.clone(), ModelKind::Lut, SolverKind::Dct, None).is_ok());
    assert!(old.dx.mlp.response.is_none());
    assert!(old.dx.lut.gain_negative.is_empty());
    // ...and reads both signs with `gain`: the depth of a file whose negative gains are a
    // copy of `gain`, bit for bit, and not that of the signed model.
    let pair = render(&optics, &ball(10.0, 8.0, 1.0), 3);
    let depth = |m: TactileModel| {
        let mut rec = Reconstructor::new(m, ModelKind::Lut, SolverKind::Dct, None).unwrap();
        let d = rec.reconstruct(&pair.dx, &pair.dy).unwrap().depth_mm;
        d.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    let mut copied = old.clone();
    for axis in [&mut copied.dx, &mut copied.dy] {
        axis.lut.gain_negative = axis.lut.gain.clone();
    }
    let unsigned = depth(old.clone());
    assert_eq!(unsigned, depth(copied));
    assert_ne!(unsigned, depth(model.clone()));
    assert!(Reconstructor::new(old, ModelKind::Mlp, SolverKind::Dct, None).is_ok());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn depth_beyond_the_skin_is_refused_with_the_reason() {
    let optics = optics();
    let (model, refs) = calibrated(&optics);
    assert_eq!(model.skin_thickness_mm, 3.0, "the default skin");
    let pair = render(&optics, &ball(10.0, 8.0, 1.0), 3);
    let reconstructor = |model: &TactileModel| {
        Reconstructor::new(
            model.clone(),
            ModelKind::Lut,
            SolverKind::Dct,
            Some((&refs.0, &refs.1).into()),
        )
    };
    let deepest = reconstructor(&model)
        .unwrap()
        .reconstruct(&pair.dx, &pair.dy)
        .unwrap()
        .depth_mm
        .as_slice()
        .iter()
        .fold(0.0f32, |a, d| a.max(d.abs()));
    assert!((0.8..1.2).contains(&deepest), "{deepest}");
    // A 1 mm press on a skin said to be 0.5 mm thick cannot be right: refused, with the
    // depth, where, and the fix.
    let thin = TactileModel {
        skin_thickness_mm: 0.5,
        ..model.clone()
    };
    let err = reconstructor(&thin)
        .unwrap()
        .reconstruct(&pair.dx, &pair.dy)
        .unwrap_err();
    match &err {
        ReconstructError::DepthBeyondSkin {
            depth_mm,
            x,
            y,
            skin_mm,
        } => {
            assert_eq!(*depth_mm, deepest);
            assert_eq!(*skin_mm, 0.5);
            // Where the ball is: 10 × 8 mm at 15 px/mm, give or take its radius.
            let r = 4.0 * optics.px_per_mm;
            let (bx, by) = (10.0 * optics.px_per_mm, 8.0 * optics.px_per_mm);
            assert!(
                (*x as f64 - bx).hypot(*y as f64 - by) < r,
                "({x}, {y}) is not on the ball"
            );
        }
        e => panic!("{e}"),
    }
    assert!(err.refuses_this_pair_only());
    let text = err.to_string();
    assert!(text.contains("--skin-thickness-mm"), "{text}");
    // dx and dy given the wrong way round make depth no skin allows: refused too.
    match reconstructor(&model)
        .unwrap()
        .reconstruct(&pair.dy, &pair.dx)
    {
        Err(e) => {
            assert!(e.refuses_this_pair_only(), "{e}");
            assert!(e.to_string().contains("swapped"), "{e}");
        }
        Ok(r) => panic!("swapped frames read {} region(s)", r.regions.len()),
    }
    // Files written before the field existed read as the default skin.
    let mut json: serde_json::Value = serde_json::from_slice(&model.to_json()).unwrap();
    json.as_object_mut().unwrap().remove("skin_thickness_mm");
    let old = TactileModel::from_json("old.json", &serde_json::to_vec(&json).unwrap()).unwrap();
    assert_eq!(old.skin_thickness_mm, 3.0);

    // Calibration sets aside presses deeper than the skin, with that reason, and refuses
    // a skin thickness that is not a number.
    let pairs = ball_presses(&optics, 6, 6.0, 11);
    let mut s = settings(&optics);
    s.skin_thickness_mm = 0.3;
    match calibrate(&pairs, Some((&refs.0, &refs.1).into()), &s, |_| {}) {
        Err(CalibrationError::TooFewPresses { rejected, .. }) => {
            assert!(!rejected.is_empty());
            for r in &rejected {
                assert!(
                    matches!(r.reason, Rejection::DeeperThanSkin { depth_mm, skin_mm: 0.3, .. } if depth_mm > 0.3),
                    "{}: {}",
                    r.name,
                    r.reason
                );
            }
        }
        other => panic!("{:?}", other.map(|c| c.presses.len())),
    }
    for bad in [f64::NAN, 0.0, 51.0] {
        s.skin_thickness_mm = bad;
        let e = calibrate(&pairs, None, &s, |_| {}).unwrap_err();
        assert!(matches!(e, CalibrationError::Settings(_)), "{bad}: {e}");
    }
}

#[test]
fn reconstruct_pictures_state_their_range_and_meshes_cover_the_frame() {
    let optics = optics();
    let (model, _) = calibrated(&optics);
    let dir = std::env::temp_dir().join(format!("stereotac-pictures-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let model_path = dir.join("model.json");
    model.save(&model_path).unwrap();
    let run = |scene: &Scene, out: &str, extra: &[&str]| {
        let pair = render(&optics, scene, 3);
        pair.dx.save(dir.join("dx.png")).unwrap();
        pair.dy.save(dir.join("dy.png")).unwrap();
        let out = dir.join(out);
        let mut args: Vec<String> = [
            "reconstruct",
            "--model",
            model_path.to_str().unwrap(),
            "--dx",
            dir.join("dx.png").to_str().unwrap(),
            "--dy",
            dir.join("dy.png").to_str().unwrap(),
            "--out-dir",
            out.to_str().unwrap(),
        ]
        .map(String::from)
        .to_vec();
        args.extend(extra.iter().map(|s| s.to_string()));
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
            .args(&args)
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{}",
            String::from_utf8_lossy(&status.stderr)
        );
        let summary: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
        let picture = image::open(out.join("depth_colour.png")).unwrap();
        (out, summary, picture.width())
    };
    // Automatic: flat skin to the deepest point, stated; the legend beside the frame.
    let (_, s, width) = run(&ball(10.0, 8.0, 1.0), "auto", &[]);
    let range = &s["colour_range"];
    assert_eq!(range["lo"], 0.0);
    let hi = range["hi"].as_f64().unwrap();
    assert!(
        (hi - s["max_depth_mm"].as_f64().unwrap()).abs() < 1e-6,
        "{s}"
    );
    assert_eq!(range["unit"], "mm");
    assert!(width > optics.width as u32, "no legend: {width}");
    // A skin at rest still has a range (not noise stretched to fill the colours).
    let (_, s, _) = run(&Scene::default(), "rest", &[]);
    assert_eq!(s["colour_range"]["hi"], 0.5, "{s}");
    // Fixed, to compare pictures; and the mesh.
    let (out, s, _) = run(
        &ball(10.0, 8.0, 1.0),
        "fixed",
        &["--colour-range", "0,2", "--mesh"],
    );
    assert_eq!(
        (
            s["colour_range"]["lo"].as_f64(),
            s["colour_range"]["hi"].as_f64()
        ),
        (Some(0.0), Some(2.0))
    );
    assert_eq!(s["colour_range"]["from"], "given");
    assert_eq!(s["warnings"], serde_json::json!([]), "{s}");
    // A given range that shows none of the depths is said in summary.json.
    let (_, off, _) = run(&ball(10.0, 8.0, 1.0), "off", &["--colour-range", "5,9"]);
    let warnings = off["warnings"].as_array().unwrap();
    assert!(
        warnings.len() == 1 && warnings[0].as_str().unwrap().contains("depth_colour.png"),
        "{off}"
    );
    // So is an LEDs-off frame the model cannot use (calibrated without them).
    let dark = dir.join("dark.png");
    RgbImage::new(optics.width as u32, optics.height as u32)
        .save(&dark)
        .unwrap();
    let (_, unused, _) = run(
        &ball(10.0, 8.0, 1.0),
        "unused",
        &["--dark", dark.to_str().unwrap()],
    );
    let warnings = unused["warnings"].as_array().unwrap();
    assert!(
        warnings.len() == 1
            && warnings[0]
                .as_str()
                .unwrap()
                .contains("dark.png not used: the model"),
        "{unused}"
    );
    // A range from below zero is a value, not a flag (it said "unexpected argument").
    let (_, below, _) = run(
        &ball(10.0, 8.0, 1.0),
        "below",
        &["--colour-range", "-0.1,1"],
    );
    let lo = below["colour_range"]["lo"].as_f64().unwrap();
    assert!((lo + 0.1).abs() < 1e-6, "{below}");
    // A wall steeper than the calibration ball's is read past the table's reach by
    // default (counted in summary.json), by the table alone with --no-past-reach.
    let (_, past, _) = run(&disk(1.6), "past", &[]);
    let (_, alone, _) = run(&disk(1.6), "alone", &["--no-past-reach"]);
    assert!(past["past_reach_pixels"].as_u64().unwrap() > 0, "{past}");
    assert_eq!(alone["past_reach_pixels"], 0, "{alone}");
    let deepest = |s: &serde_json::Value| s["max_depth_mm"].as_f64().unwrap();
    assert!(deepest(&alone) < deepest(&past) - 0.05, "{alone}\n{past}");
    let mesh = std::fs::read(out.join("depth_mesh.ply")).unwrap();
    let header = String::from_utf8_lossy(&mesh[..400]);
    let (w, h) = (optics.width, optics.height);
    assert!(
        header.contains(&format!("element vertex {}\n", w * h)),
        "{header}"
    );
    assert!(
        header.contains(&format!("element face {}\n", 2 * (w - 1) * (h - 1))),
        "{header}"
    );
    // Replaced with --force and no --mesh: the earlier pair's mesh goes with the rest.
    let (out, _, _) = run(&Scene::default(), "fixed", &["--force"]);
    assert!(!out.join("depth_mesh.ply").exists(), "a stale mesh is left");
    assert!(out.join("summary.json").exists());
    // Reference frames of another size are refused naming the files given.
    let small = dir.join("small.png");
    RgbImage::new(32, 24).save(&small).unwrap();
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(["reconstruct", "--model", model_path.to_str().unwrap()])
        .args(["--dx", dir.join("dx.png").to_str().unwrap()])
        .args(["--dy", dir.join("dy.png").to_str().unwrap()])
        .args([
            "--ref-dx",
            small.to_str().unwrap(),
            "--ref-dy",
            small.to_str().unwrap(),
        ])
        .args(["--out-dir", dir.join("refs").to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success()
            && err.contains("--ref-dx")
            && err.contains("small.png")
            && err.contains("(32, 24)"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A folder's pairs: a file that cannot be read, or a frame without its partner, costs
/// that press (set aside with the reason), not the calibration; a folder with nothing
/// readable is an error naming the first reason.
#[test]
fn pair_directories_set_aside_unpaired_and_unreadable_files() {
    let dir = std::env::temp_dir().join(format!("stereotac-pairs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    assert!(matches!(
        load_pairs(&dir, None),
        Err(ImageError::Empty { .. })
    ));
    let img = RgbImage::new(4, 4);
    img.save(dir.join("a_dx.png")).unwrap();
    let err = load_pairs(&dir, None).unwrap_err();
    assert!(
        matches!(&err, ImageError::NoneReadable { first, .. } if matches!(**first, ImageError::Unpaired { .. })),
        "{err}"
    );
    std::fs::write(dir.join("a_dy.png"), b"not a png").unwrap();
    let err = load_pairs(&dir, None).unwrap_err().to_string();
    assert!(
        err.contains("none of its 1 pair(s) could be read") && err.contains("a_dy.png"),
        "{err}"
    );
    img.save(dir.join("a_dy.png")).unwrap();
    let got = load_pairs(&dir, None).unwrap();
    assert!(got.pairs.len() == 1 && got.set_aside.is_empty());
    assert!(got.pairs[0].dark.is_none());
    img.save(dir.join("a_dark.png")).unwrap();
    assert!(
        load_pairs(&dir, None).unwrap().pairs[0].dark.is_some(),
        "NAME_dark.png goes with its pair"
    );
    // Beside the good pair: a dark frame alone, a damaged PNG, a grey frame.
    img.save(dir.join("b_dark.png")).unwrap();
    std::fs::write(dir.join("c_dx.png"), b"\x89PNG\r\n\x1a\n cut short").unwrap();
    img.save(dir.join("c_dy.png")).unwrap();
    img.save(dir.join("d_dx.png")).unwrap();
    image::DynamicImage::ImageRgb8(img.clone())
        .into_luma8()
        .save(dir.join("d_dy.png"))
        .unwrap();
    let got = load_pairs(&dir, None).unwrap();
    let names: Vec<&str> = got.pairs.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["a"]);
    let aside: Vec<(&str, String)> = got
        .set_aside
        .iter()
        .map(|(n, e)| (n.as_str(), e.to_string()))
        .collect();
    assert_eq!(aside.len(), 3, "{aside:?}");
    assert!(
        aside[0].0 == "b" && aside[0].1.contains("b_dark.png"),
        "{aside:?}"
    );
    assert!(
        aside[1].0 == "c" && aside[1].1.contains("c_dx.png"),
        "{aside:?}"
    );
    assert!(
        aside[2].0 == "d" && aside[2].1.contains("d_dy.png"),
        "{aside:?}"
    );
    // A press of another size than most (a huge one, or a frame of another camera) is
    // set aside from its header; against references of another size, every press is.
    RgbImage::new(4, 4).save(dir.join("e_dx.png")).unwrap();
    RgbImage::new(4, 4).save(dir.join("e_dy.png")).unwrap();
    RgbImage::new(6000, 5).save(dir.join("f_dx.png")).unwrap();
    RgbImage::new(6000, 5).save(dir.join("f_dy.png")).unwrap();
    let got = load_pairs(&dir, None).unwrap();
    let names: Vec<&str> = got.pairs.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["a", "e"]);
    let (name, why) = got.set_aside.last().unwrap();
    assert!(
        name == "f"
            && matches!(
                why,
                ImageError::Size {
                    got: (6000, 5),
                    want: (4, 4),
                    ..
                }
            )
            && why
                .to_string()
                .contains("f_dx.png: 6000×5 px, but most pairs' frames are 4×4"),
        "{name}: {why}"
    );
    // As many of another size as of the most common one: no size is most pairs', and
    // which are the presses is not guessed.
    for name in ["g", "h"] {
        for phase in ["dx", "dy"] {
            RgbImage::new(6000, 5)
                .save(dir.join(format!("{name}_{phase}.png")))
                .unwrap();
        }
    }
    let err = load_pairs(&dir, None).unwrap_err();
    assert!(
        matches!(&err, ImageError::MixedSizes { sizes, .. } if sizes.len() == 2)
            && err
                .to_string()
                .contains("4×4 px (3, e.g. a_dx.png), 6000×5 px (3, e.g. f_dx.png)"),
        "{err}"
    );
    let err = load_pairs(&dir, Some((8, 8))).unwrap_err().to_string();
    assert!(
        err.contains("but the reference frames are 8×8 px; not decoded"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Presses with LEDs-off frames give a model on LED light: it keeps the calibration's
/// ambient light (saved with it), removes each pair's own LEDs-off frame, and falls back
/// to its estimate without one; a model on raw frames leaves the LEDs-off frame unused.
/// Press `k` with its dx, dy and LEDs-off frames, named `p{k}`.
fn press_with_dark(k: u64, (dx, dy, dark): (RgbImage, RgbImage, RgbImage)) -> CalibrationPair {
    CalibrationPair {
        name: format!("p{k}"),
        dx,
        dy,
        dark: Some(dark),
        ball_diameter_mm: None,
    }
}

#[test]
fn leds_off_frames_make_a_model_on_led_light() {
    let optics = Optics {
        ambient: 20.0,
        ..optics()
    };
    let scene = |shapes| Scene { shapes };
    let frames = |scene: &Scene, frame, ambient: [f64; 3]| {
        let truth = scene.truth(optics.width, optics.height, optics.px_per_mm);
        render_truth(&optics, &truth, frame, ambient)
    };
    let presses: Vec<CalibrationPair> = (0..10)
        .map(|k| {
            let s = scene(vec![Shape::Ball {
                cx: 4.0 + 1.3 * k as f64,
                cy: 5.0 + (k % 3) as f64 * 2.5,
                diameter: 6.0,
                depth: 0.8 + 0.04 * k as f64,
            }]);
            press_with_dark(k, frames(&s, 100 + k, [1.0; 3]))
        })
        .collect();
    let (rdx, rdy, rdark) = frames(&Scene::default(), 1, [1.0; 3]);
    let references = PhaseFrames {
        dx: &rdx,
        dy: &rdy,
        dark: Some(&rdark),
    };
    let cal = calibrate(&presses, Some(references), &settings(&optics), |_| {}).unwrap();
    let ambient = cal.model.ambient.clone().expect("calibrated on LED light");
    let mean_green = ambient.means.iter().map(|m| m[1]).sum::<f32>() / ambient.means.len() as f32;
    assert!(
        (mean_green - 20.0).abs() < 4.0,
        "the estimate holds the ambient light: {mean_green}"
    );
    let back = TactileModel::from_json("m", &cal.model.to_json()).unwrap();
    assert_eq!(back, cal.model, "the estimate is saved with the model");
    // A press's own ball is kept through the LED light's pairs.
    let mut given = presses.clone();
    given[3].ball_diameter_mm = Some(6.2);
    let own = calibrate(&given, Some(references), &settings(&optics), |_| {}).unwrap();
    let ball_of = |name: &str| {
        own.presses
            .iter()
            .find(|p| p.name == name)
            .map(|p| p.ball_diameter_mm)
    };
    assert_eq!((ball_of("p3"), ball_of("p4")), (Some(6.2), Some(6.0)));

    let mut rec = Reconstructor::new(
        cal.model.clone(),
        ModelKind::Lut,
        SolverKind::Dct,
        Some(references),
    )
    .unwrap();
    let ball = ball(10.0, 8.0, 1.0);
    let truth = ball
        .truth(optics.width, optics.height, optics.px_per_mm)
        .depth;
    // The room twice as bright as at calibration.
    let (dx, dy, dark) = frames(&ball, 7, [2.0; 3]);
    let with_dark = rec
        .reconstruct_frames(PhaseFrames {
            dx: &dx,
            dy: &dy,
            dark: Some(&dark),
        })
        .unwrap();
    assert_eq!(with_dark.ambient, AmbientSource::DarkFrame);
    let e = errors(&with_dark.depth_mm, &truth);
    assert!((e.reading_mm - 1.0).abs() < 0.05, "{e:?}");
    let (rest_dx, rest_dy, rest_dark) = frames(&Scene::default(), 8, [2.0; 3]);
    let rest = rec
        .reconstruct_frames(PhaseFrames {
            dx: &rest_dx,
            dy: &rest_dy,
            dark: Some(&rest_dark),
        })
        .unwrap();
    assert!(rest.no_contact(), "twice the ambient light is not contact");
    // Without the LEDs-off frame: the calibration's ambient light is removed instead.
    let (dx1, dy1, _) = frames(&ball, 9, [1.0; 3]);
    let estimate = rec.reconstruct(&dx1, &dy1).unwrap();
    assert_eq!(estimate.ambient, AmbientSource::Calibration);
    let e = errors(&estimate.depth_mm, &truth);
    assert!((e.reading_mm - 1.0).abs() < 0.05, "{e:?}");
    // A LEDs-off frame brighter than the lit frames (another camera's view) is not used.
    let elsewhere = RgbImage::from_fn(dx.width(), dx.height(), |x, y| {
        image::Rgb([((x * 7 + y * 3) % 200) as u8 + 50; 3])
    });
    let refused = rec
        .reconstruct_frames(PhaseFrames {
            dx: &dx1,
            dy: &dy1,
            dark: Some(&elsewhere),
        })
        .unwrap();
    assert_eq!(refused.ambient, AmbientSource::CalibrationDarkRefused);
    assert_eq!(refused.depth_mm, estimate.depth_mm);
    // A dark frame of another size is refused.
    let small = RgbImage::new(8, 8);
    assert!(matches!(
        rec.reconstruct_frames(PhaseFrames {
            dx: &dx,
            dy: &dy,
            dark: Some(&small),
        }),
        Err(ReconstructError::ModelSize {
            what: "dark frame",
            ..
        })
    ));
    // A model on raw frames: the LEDs-off frame is not used.
    let presses_copy = presses.clone();
    let raw: Vec<CalibrationPair> = presses
        .into_iter()
        .map(|p| CalibrationPair { dark: None, ..p })
        .collect();
    let raw_model = calibrate(&raw, Some((&rdx, &rdy).into()), &settings(&optics), |_| {})
        .unwrap()
        .model;
    assert!(raw_model.ambient.is_none());
    // Presses whose LEDs-off frames show other light: calibrated on raw frames, with why.
    let mut odd = presses_copy;
    odd[3].dark = Some(elsewhere.clone());
    let cal = calibrate(&odd, Some((&rdx, &rdy).into()), &settings(&optics), |_| {}).unwrap();
    assert!(cal.model.ambient.is_none());
    assert!(
        cal.report
            .warnings
            .iter()
            .any(|w| w.contains("p3") && w.contains("brighter")),
        "{:?}",
        cal.report.warnings
    );
    let mut rec = Reconstructor::new(
        raw_model,
        ModelKind::Lut,
        SolverKind::Dct,
        Some((&rdx, &rdy).into()),
    )
    .unwrap();
    let r = rec
        .reconstruct_frames(PhaseFrames {
            dx: &dx1,
            dy: &dy1,
            dark: Some(&dark),
        })
        .unwrap();
    assert_eq!(r.ambient, AmbientSource::ColourFilter);
}

#[test]
fn calibration_warns_when_presses_saturate_the_camera() {
    // The nominal skin's steepest walls facing a strip saturate a few % of a contact:
    // no warning. With the exposure raised, walls facing a strip clip: the warning names
    // the worst press, and the per-press shares are in the presses' fits.
    let nominal = Optics::resolution(320, 240);
    let bright = Optics {
        exposure: 1.3,
        ..nominal.clone()
    };
    for (optics, warned) in [(nominal, false), (bright, true)] {
        let pairs = ball_presses(&optics, 10, 6.0, 11);
        let refs = reference_frames(&optics);
        let cal = calibrate(
            &pairs,
            Some((&refs.0, &refs.1).into()),
            &settings(&optics),
            |_| {},
        )
        .unwrap();
        let worst = cal
            .presses
            .iter()
            .map(|p| p.saturated[0].max(p.saturated[1]))
            .fold(0.0, f64::max);
        let warning = cal
            .report
            .warnings
            .iter()
            .find(|w| w.contains("saturate the camera"));
        assert_eq!(
            warning.is_some(),
            warned,
            "exposure {}: worst press {:.1}% saturated, warnings {:?}",
            optics.exposure,
            100.0 * worst,
            cal.report.warnings
        );
        assert_eq!(worst >= SATURATED_FRACTION, warned, "worst press {worst}");
    }
}

#[test]
fn saturation_is_judged_press_by_press_on_the_raw_frames() {
    // Presses with LEDs-off frames (the model works on LED light) and one press with
    // nothing in it, set aside: each used press's share is the one of its own raw frames,
    // not of the frames minus their LEDs-off light, nor of a neighbouring press.
    let optics = Optics {
        ambient: 20.0,
        exposure: 1.3,
        ..optics()
    };
    let frames = |shapes: Vec<Shape>, frame| {
        let truth = Scene { shapes }.truth(optics.width, optics.height, optics.px_per_mm);
        render_truth(&optics, &truth, frame, [1.0; 3])
    };
    let presses: Vec<CalibrationPair> = (0..9)
        .map(|k| {
            let shapes = if k == 2 {
                Vec::new()
            } else {
                vec![Shape::Ball {
                    cx: 3.5 + 1.7 * k as f64,
                    cy: 4.0 + (k % 3) as f64 * 3.0,
                    diameter: 6.0,
                    depth: 0.8 + 0.05 * k as f64,
                }]
            };
            press_with_dark(k, frames(shapes, 200 + k))
        })
        .collect();
    let (rdx, rdy, rdark) = frames(Vec::new(), 1);
    let references = PhaseFrames {
        dx: &rdx,
        dy: &rdy,
        dark: Some(&rdark),
    };
    let cal = calibrate(&presses, Some(references), &settings(&optics), |_| {}).unwrap();
    assert!(cal.model.ambient.is_some(), "calibrated on LED light");
    assert!(
        cal.rejected.iter().any(|r| r.name == "p2"),
        "{:?}",
        cal.rejected
    );
    // The share by its definition, on any pair of frames.
    let share = |img: &RgbImage, c: &stereotac::tactile::calibrate::Circle| {
        let (mut inside, mut hot) = (0usize, 0usize);
        for (x, y, px) in img.enumerate_pixels() {
            let (dx, dy) = (x as f64 + 0.5 - c.cx, y as f64 + 0.5 - c.cy);
            if dx * dx + dy * dy < c.r * c.r {
                inside += 1;
                hot += usize::from(px.0.iter().any(|&v| v >= 250));
            }
        }
        hot as f64 / inside.max(1) as f64
    };
    let minus = |a: &RgbImage, b: &RgbImage| {
        RgbImage::from_fn(a.width(), a.height(), |x, y| {
            let (p, q) = (a.get_pixel(x, y).0, b.get_pixel(x, y).0);
            image::Rgb([0, 1, 2].map(|i| p[i].saturating_sub(q[i])))
        })
    };
    let mut differs = false;
    for p in &cal.presses {
        let pair = presses.iter().find(|q| q.name == p.name).unwrap();
        let dark = pair.dark.as_ref().unwrap();
        let want = [share(&pair.dx, &p.circle), share(&pair.dy, &p.circle)];
        assert_eq!(p.saturated, want, "{}", p.name);
        let led = [
            share(&minus(&pair.dx, dark), &p.circle),
            share(&minus(&pair.dy, dark), &p.circle),
        ];
        differs |= led != want;
    }
    assert!(
        cal.presses
            .iter()
            .any(|p| p.saturated[0].max(p.saturated[1]) > 0.05),
        "some press saturates: {:?}",
        cal.presses.iter().map(|p| p.saturated).collect::<Vec<_>>()
    );
    assert!(
        differs,
        "the frames minus their LEDs-off light would give other shares"
    );
}

/// A sensor built the other way round (every frame mirrored left to right: the red strip
/// on the other side) calibrates, its model file loads, and a ball reads as a dip of
/// its depth. Presses mirrored against references that are not are refused (their
/// light departs from the references' all over: caught before the model's own check,
/// `CalibrationError::ModelFailsCheck`, which no crafted input here reaches).
#[test]
fn a_mirrored_sensor_calibrates_and_mirrored_presses_alone_are_refused() {
    let optics = optics();
    let s = settings(&optics);
    let flip = image::imageops::flip_horizontal::<RgbImage>;
    let pairs = ball_presses(&optics, 10, 6.0, 11);
    let mirrored: Vec<CalibrationPair> = pairs
        .iter()
        .map(|p| CalibrationPair {
            dx: flip(&p.dx),
            dy: flip(&p.dy),
            ..p.clone()
        })
        .collect();
    let refs = reference_frames(&optics);
    let flipped = (flip(&refs.0), flip(&refs.1));
    let cal = calibrate(&mirrored, Some((&flipped.0, &flipped.1).into()), &s, |_| {}).unwrap();
    let model = TactileModel::from_json("mirrored.json", &cal.model.to_json()).unwrap();
    let scene = ball(10.0, 8.0, 1.0);
    let pair = render(&optics, &scene, 3);
    let mut rec = reconstructor(&model, &flipped, ModelKind::Lut, SolverKind::Dct);
    let r = rec.reconstruct(&flip(&pair.dx), &flip(&pair.dy)).unwrap();
    let peak = r.depth_mm.as_slice().iter().fold(0.0f32, |a, &d| a.max(d));
    assert!(
        (0.8..1.2).contains(&peak),
        "mirrored sensor: peak {peak} mm"
    );
    let err = calibrate(&mirrored, Some((&refs.0, &refs.1).into()), &s, |_| {}).unwrap_err();
    assert!(
        matches!(err, CalibrationError::SharedDeparture { .. }),
        "{err}"
    );
}

/// A PNG of `w`×`h` RGB pixels that holds its header and no pixels: what a folder's
/// sizing reads, cheap to write whatever the size.
fn png_header_only(w: u32, h: u32) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xedb8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        let body: Vec<u8> = kind.iter().chain(data).copied().collect();
        c.extend(&body);
        c.extend(crc32(&body).to_be_bytes());
        c
    };
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, 2, 0, 0, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    // The pixels' chunk begins (an empty zlib stream): readers want to reach it.
    png.extend(chunk(
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    ));
    png.extend(chunk(b"IEND", &[]));
    png
}

/// A folder whose frames would take more memory decoded than a calibration may (12
/// presses of 8000×8000 frames: 4.6 GB) is refused from the headers, before any frame
/// is decoded, saying what it would take; presses of that size against small reference
/// frames are set aside undecoded as before.
#[test]
fn a_folder_of_huge_frames_is_refused_before_decoding() {
    let dir = std::env::temp_dir().join(format!("stereotac-huge-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let huge = png_header_only(8000, 8000);
    for k in 0..12 {
        for phase in ["dx", "dy"] {
            std::fs::write(dir.join(format!("p{k}_{phase}.png")), &huge).unwrap();
        }
    }
    let err = load_pairs(&dir, None).unwrap_err();
    assert!(
        matches!(
            &err,
            ImageError::TooMuch {
                frames: 24,
                size: (8000, 8000),
                ..
            }
        ) && err.to_string().contains("frames to 4.6 GB"),
        "{err}"
    );
    let err = load_pairs(&dir, Some((64, 48))).unwrap_err();
    assert!(
        matches!(&err, ImageError::NoneReadable { first, .. } if matches!(**first, ImageError::Size { .. })),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `calibrate --with-ball 4:DIR`: the second folder's presses are named after it, fitted
/// with their own ball (the report says which), and one too large for its ball says so.
#[test]
fn the_cli_calibrates_from_folders_of_two_balls() {
    let optics = optics();
    let dir = std::env::temp_dir().join(format!("stereotac-two-balls-{}", std::process::id()));
    let (large, small) = (dir.join("large"), dir.join("small"));
    for (folder, diameter, seed) in [(&large, 6.0, 11), (&small, 4.0, 12)] {
        std::fs::create_dir_all(folder).unwrap();
        for p in ball_presses(&optics, 8, diameter, seed) {
            p.dx.save(folder.join(format!("{}_dx.png", p.name)))
                .unwrap();
            p.dy.save(folder.join(format!("{}_dy.png", p.name)))
                .unwrap();
        }
    }
    // A press of the 6 mm ball among the 4 mm ones: too large for a 4 mm ball.
    let stray = render(&optics, &ball(10.0, 8.0, 1.4), 77);
    stray.dx.save(small.join("stray_dx.png")).unwrap();
    stray.dy.save(small.join("stray_dy.png")).unwrap();
    let (ref_dx, ref_dy) = (dir.join("ref_dx.png"), dir.join("ref_dy.png"));
    let refs = reference_frames(&optics);
    refs.0.save(&ref_dx).unwrap();
    refs.1.save(&ref_dy).unwrap();
    let (model, report) = (dir.join("model.json"), dir.join("report.json"));
    // An overlays folder an earlier run wrote into, with a press not given now.
    let overlays = dir.join("overlays");
    std::fs::create_dir_all(&overlays).unwrap();
    std::fs::write(overlays.join("gone-press.png"), b"older").unwrap();
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args([
            "calibrate",
            &s(&large),
            "--ball-diameter-mm",
            "6",
            "--px-per-mm",
        ])
        .arg(optics.px_per_mm.to_string())
        .args(["--ref-dx", &s(&ref_dx), "--ref-dy", &s(&ref_dy)])
        .args(["--with-ball", &format!("4:{}", s(&small))])
        .args(["--out", &s(&model), "--report", &s(&report)])
        .args(["--overlays", &s(&overlays), "--force"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let presses = report["presses"].as_array().unwrap();
    let balls: Vec<(String, f64)> = presses
        .iter()
        .map(|p| {
            (
                p["name"].as_str().unwrap().to_string(),
                p["ball_diameter_mm"].as_f64().unwrap(),
            )
        })
        .collect();
    assert!(
        balls
            .iter()
            .any(|(n, b)| n.starts_with("small-press") && *b == 4.0),
        "{balls:?}"
    );
    assert!(
        balls
            .iter()
            .any(|(n, b)| n.starts_with("press") && *b == 6.0),
        "{balls:?}"
    );
    assert!(
        balls
            .iter()
            .all(|(n, b)| n.starts_with("small-") == (*b == 4.0)),
        "{balls:?}"
    );
    // The stray press is set aside as too large for the ball it was given.
    let stray = report["rejected"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["name"] == "small-stray")
        .unwrap_or_else(|| panic!("{}", report["rejected"]));
    assert_eq!(stray["reason"]["kind"], "too_large", "{stray}");
    assert_eq!(stray["reason"]["ball_mm"].as_f64(), Some(4.0), "{stray}");
    assert!(
        stdout.contains("small-stray") && stdout.contains("larger than a 4 mm ball"),
        "{stdout}"
    );
    // The model names the second ball as well as the first.
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    assert_eq!(written["ball_diameter_mm"].as_f64(), Some(6.0));
    assert_eq!(
        written["other_balls_mm"],
        serde_json::json!([4.0]),
        "{}",
        written["other_balls_mm"]
    );
    // Each press's overlay is written; the older image is named, not removed.
    assert!(overlays.join("small-stray.png").is_file());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("gone-press.png") && stderr.contains("did not write"),
        "{stderr}"
    );
    assert!(overlays.join("gone-press.png").is_file());
    // A JSON file where the presses go: said to be neither a folder nor a recording.
    let json = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(["calibrate", &s(&model), "--ball-diameter-mm", "6"])
        .args(["--out", &s(&dir.join("from-json.json"))])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&json.stderr);
    assert_eq!(json.status.code(), Some(1), "{err}");
    assert!(
        err.contains("looks like a JSON file") && err.contains("NAME_dx.png"),
        "{err}"
    );
    // The first folder again as the second ball's: refused, naming the option.
    let again = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
        .args(["calibrate", &s(&large), "--ball-diameter-mm", "6"])
        .args(["--with-ball", &format!("4:{}/", s(&large))])
        .args(["--out", &s(&dir.join("again.json"))])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--with-ball 4:") && err.contains("is read already"),
        "{err}"
    );
    assert!(!dir.join("again.json").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `calibrate --blue-only-dx F --red-only-dx F`: the camera's crosstalk is measured
/// beside --ref-dx, said, kept in the model and undone; the two frames swapped, or one
/// without the other, are refused.
#[test]
fn the_cli_measures_and_keeps_the_crosstalk() {
    use stereotac::tactile::skins::evaluate::ball_presses;
    use stereotac::tactile::skins::families::family;
    let skin = family("phys-matte").unwrap().skin(320, 240, 1);
    let dir = std::env::temp_dir().join(format!("stereotac-crosstalk-{}", std::process::id()));
    let presses = dir.join("presses");
    std::fs::create_dir_all(&presses).unwrap();
    for p in ball_presses(&skin, 6.0, 10, 3, 0) {
        p.dx.save(presses.join(format!("{}_dx.png", p.name)))
            .unwrap();
        p.dy.save(presses.join(format!("{}_dy.png", p.name)))
            .unwrap();
    }
    let refs = skin.references(4);
    let (blue, red) = skin.single_colour_references(4);
    let path = |n: &str| dir.join(n).to_str().unwrap().to_string();
    refs.dx.save(path("ref_dx.png")).unwrap();
    refs.dy.save(path("ref_dy.png")).unwrap();
    blue.save(path("blue.png")).unwrap();
    red.save(path("red.png")).unwrap();
    let calibrate = |extra: &[String]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
            .args(["calibrate", &path("presses"), "--ball-diameter-mm", "6"])
            .args([
                "--ref-dx",
                &path("ref_dx.png"),
                "--ref-dy",
                &path("ref_dy.png"),
            ])
            .args(["--out", &path("model.json"), "--force"])
            .args(extra)
            .output()
            .unwrap()
    };
    let flags = |b: &str, r: &str| {
        vec![
            "--blue-only-dx".to_string(),
            path(b),
            "--red-only-dx".to_string(),
            path(r),
        ]
    };
    let out = calibrate(&flags("blue.png", "red.png"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("crosstalk: -1"), "{stderr}");
    let model: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path("model.json")).unwrap()).unwrap();
    let red_row = model["filter"]["unmix"]["red"].as_array().unwrap();
    // The blue LED's light is about 17 % of R − G on this skin: undone with +0.17.
    let undo = red_row[1].as_f64().unwrap();
    assert!((0.12..0.22).contains(&undo), "{model}");
    TactileModel::load(&dir.join("model.json")).unwrap();
    // Without the frames the model has no unmix (older binaries read it).
    let out = calibrate(&[]);
    assert!(out.status.success());
    let model: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path("model.json")).unwrap()).unwrap();
    assert!(model["filter"].get("unmix").is_none(), "{model}");
    // Swapped: the error names both files and says what to give.
    let out = calibrate(&flags("red.png", "blue.png"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("red.png") && stderr.contains("only its blue strip lit"),
        "{stderr}"
    );
    // One without the other.
    let out = calibrate(&["--blue-only-dx".to_string(), path("blue.png")]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--red-only-dx"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `calibrate --side-light` on frames of strips of finite length keeps the side light in
/// the model file and says how large it is; on the nominal skin (strips along the whole
/// axis) it says none was measured and the file has none.
#[test]
fn the_cli_measures_the_side_light_when_asked() {
    use stereotac::tactile::skins::evaluate::ball_presses;
    use stereotac::tactile::skins::families::family;
    let dir = std::env::temp_dir().join(format!("stereotac-side-light-{}", std::process::id()));
    for (name, kept) in [("ours-finite-strips", true), ("ours-nominal", false)] {
        let f = family(name).unwrap();
        let skin = f.skin(320, 240, 1);
        let presses = dir.join(name);
        std::fs::create_dir_all(&presses).unwrap();
        for p in ball_presses(&skin, f.ball_diameter_mm, 12, 1, 0) {
            p.dx.save(presses.join(format!("{}_dx.png", p.name)))
                .unwrap();
            p.dy.save(presses.join(format!("{}_dy.png", p.name)))
                .unwrap();
        }
        let refs = skin.references(4);
        let path = |n: &str| {
            dir.join(format!("{name}-{n}"))
                .to_str()
                .unwrap()
                .to_string()
        };
        refs.dx.save(path("ref_dx.png")).unwrap();
        refs.dy.save(path("ref_dy.png")).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_stereotac"))
            .arg("calibrate")
            .arg(&presses)
            .args([
                "--ball-diameter-mm",
                "6",
                "--px-per-mm",
                "7.5",
                "--side-light",
            ])
            .args([
                "--ref-dx",
                &path("ref_dx.png"),
                "--ref-dy",
                &path("ref_dy.png"),
            ])
            .args(["--out", &path("model.json")])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{name}: {stdout}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let model: serde_json::Value =
            serde_json::from_slice(&std::fs::read(path("model.json")).unwrap()).unwrap();
        if kept {
            assert!(stdout.contains("changes by up to"), "{name}: {stdout}");
            let kappa = model["side_light"]["kappa"].as_array().expect("kept");
            assert!(kappa.iter().all(|k| k.as_array().unwrap().len() == 12));
        } else {
            assert!(
                stdout.contains("side light of the strips: none measured"),
                "{name}: {stdout}"
            );
            assert!(model.get("side_light").is_none(), "{name}: {model}");
        }
        TactileModel::load(std::path::Path::new(&path("model.json"))).unwrap();
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
