"""Tactile depth from Python against the CLI, and what bad input gives."""

import json

import numpy as np
import pytest

import stereotac
from conftest import run


def contact_pair(scene_pairs):
    """A pair of the demo scene with something pressed in (the skin at rest comes first,
    then the objects, then the skin at rest again)."""
    return scene_pairs[1]


def frames(pair):
    _, dx, dy, dark = pair
    return (
        stereotac.load_rgb(dx),
        stereotac.load_rgb(dy),
        None if dark is None else stereotac.load_rgb(dark),
    )


@pytest.mark.parametrize("which", ["rest", "contact"])
def test_reconstruct_equals_cli(cli, model_path, scene_pairs, tmp_path, which):
    pair = scene_pairs[0] if which == "rest" else contact_pair(scene_pairs)
    _, dx, dy, dark = pair
    args = ["reconstruct", "--model", model_path, "--dx", dx, "--dy", dy, "--out-dir", tmp_path / "o", "--json"]
    if dark is not None:
        args += ["--dark", dark]
    summary = json.loads(run(cli, *args))
    expected = np.load(tmp_path / "o" / "depth.npy")

    model = stereotac.TactileModel.load(model_path)
    dx_img, dy_img, dark_img = frames(pair)
    r = model.reconstruct(dx_img, dy_img, dark=dark_img)

    assert r.depth.dtype == np.float32 and r.depth.shape == (model.height, model.width)
    np.testing.assert_array_equal(r.depth, expected)
    assert r.contact == (not summary["no_contact"])
    assert np.float32(r.max_depth_mm) == np.float32(summary["max_depth_mm"])  # f32 in JSON
    assert r.area_mm2 == pytest.approx(summary["contact_area_mm2"])
    assert r.volume_mm3 == pytest.approx(summary["volume_mm3"])
    assert r.past_reach_pixels == summary["past_reach_pixels"]
    assert np.float32(r.unexplained_share) == np.float32(summary["unexplained_share"])
    assert r.unexplained_share < 0.15, "one skin's slopes are one surface's"
    assert r.contact_mask.dtype == np.bool_ and r.contact_mask.shape == r.depth.shape
    assert set(r.timings) == {"detect_ms", "colour_ms", "model_ms", "solve_ms", "total_ms"}
    if which == "contact":
        assert r.contact and r.max_depth_mm > 0.2 and r.centroid_mm is not None
        assert r.regions, "a contact has regions"
    else:
        assert not r.contact and r.centroid_mm is None


def test_past_reach_off_equals_cli(cli, model_path, scene_pairs, tmp_path):
    _, dx, dy, dark = contact_pair(scene_pairs)
    args = ["reconstruct", "--model", model_path, "--dx", dx, "--dy", dy, "--out-dir", tmp_path / "o"]
    args += ["--json", "--no-past-reach"] + ([] if dark is None else ["--dark", dark])
    summary = json.loads(run(cli, *args))
    expected = np.load(tmp_path / "o" / "depth.npy")
    model = stereotac.TactileModel.load(model_path)
    dx_img, dy_img, dark_img = frames(contact_pair(scene_pairs))
    r = model.reconstruct(dx_img, dy_img, dark=dark_img, past_reach=False)
    assert r.past_reach_pixels == 0 == summary["past_reach_pixels"]
    np.testing.assert_array_equal(r.depth, expected)
    rec = model.reconstructor(past_reach=False)
    np.testing.assert_array_equal(rec.reconstruct(dx_img, dy_img, dark=dark_img).depth, expected)


def test_phases_of_two_moments_warn_that_the_slopes_are_no_surface(model_path, scene_pairs):
    # dx of the ball, dy of the disk: each phase shows its own contact, and the depth
    # solved from them looks plausible; its slopes are not one surface's, and it says so.
    model = stereotac.TactileModel.load(model_path)
    dx, _, dark = frames(scene_pairs[1])
    _, dy, _ = frames(scene_pairs[2])
    with pytest.warns(UserWarning, match="not those of one surface"):
        r = model.reconstruct(dx, dy, dark=dark)
    assert r.contact and r.unexplained_share > 0.15


def test_reconstructor_and_model_agree(model_path, scene_pairs):
    model = stereotac.TactileModel.load(model_path)
    dx, dy, dark = frames(contact_pair(scene_pairs))
    rec = model.reconstructor()
    a = rec.reconstruct(dx, dy, dark=dark)
    b = rec.reconstruct(dx, dy, dark=dark)  # buffers reused: the same result
    c = model.reconstruct(dx, dy, dark=dark)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.depth, c.depth)
    # The references given as frames of the skin at rest: still a contact, same place.
    rx, ry, rd = frames(scene_pairs[0])
    ref = (rx, ry) if rd is None else (rx, ry, rd)
    d = model.reconstruct(dx, dy, ref=ref, dark=dark)
    assert d.contact
    assert abs(d.max_depth_at_px[0] - a.max_depth_at_px[0]) < 20
    assert abs(d.max_depth_at_px[1] - a.max_depth_at_px[1]) < 20


def test_any_memory_layout_is_read_in_order(model_path, scene_pairs):
    model = stereotac.TactileModel.load(model_path)
    dx, dy, dark = frames(contact_pair(scene_pairs))
    want = model.reconstruct(dx, dy, dark=dark).depth
    # Fortran order, and every other pixel of a frame twice the size: other strides.
    fortran = [None if a is None else np.asfortranarray(a) for a in (dx, dy, dark)]
    big = [None if a is None else np.repeat(np.repeat(a, 2, axis=0), 2, axis=1) for a in (dx, dy, dark)]
    strided = [None if a is None else a[::2, ::2] for a in big]
    assert not strided[0].flags["C_CONTIGUOUS"]
    for dx2, dy2, dark2 in (fortran, strided):
        np.testing.assert_array_equal(model.reconstruct(dx2, dy2, dark=dark2).depth, want)


def test_bad_inputs_raise_clearly(model_path, scene_pairs):
    model = stereotac.TactileModel.load(model_path)
    dx, dy, _ = frames(scene_pairs[0])
    cases = [
        (dx.astype(np.float32), dy, "uint8"),
        (dx[:, :, 0], dy, "(height, width, 3)"),
        (np.dstack([dx, dx[:, :, :1]]), dy, "(height, width, 3)"),
        (dx[:240, :320], dy[:240, :320], "calibrated at"),
        (dx, dy[:240], "same size"),
        (np.zeros_like(dx), np.zeros_like(dy), "no usable LED light"),
        ("dx.png", dy, "uint8"),
        (np.zeros((0, 0, 3), np.uint8), dy, "1 to"),
    ]
    for a, b, words in cases:
        with pytest.raises(stereotac.BadInputError, match=None) as e:
            model.reconstruct(a, b)
        assert words in str(e.value), f"{words!r} not in {e.value}"
        assert isinstance(e.value, ValueError) and isinstance(e.value, stereotac.StereotacError)
    with pytest.raises(stereotac.BadInputError, match="kind"):
        model.reconstruct(dx, dy, kind="cnn")
    with pytest.raises(stereotac.BadInputError, match="solver"):
        model.reconstruct(dx, dy, solver="fft")
    with pytest.raises(stereotac.BadInputError, match="ref"):
        model.reconstruct(dx, dy, ref=(dx,))


def test_model_files(model_path, tmp_path, scene_pairs):
    with pytest.raises(stereotac.IoError) as e:
        stereotac.TactileModel.load(tmp_path / "missing.json")
    assert isinstance(e.value, OSError) and "missing.json" in str(e.value)
    junk = tmp_path / "junk.json"
    junk.write_text("{\"not\": \"a model\"}")
    with pytest.raises(stereotac.BadInputError, match="junk.json"):
        stereotac.TactileModel.load(junk)
    model = stereotac.TactileModel.load(model_path)
    copy = tmp_path / "copy.json"
    model.save(copy)
    again = stereotac.TactileModel.load(copy)
    assert (again.width, again.height, again.px_per_mm) == (model.width, model.height, model.px_per_mm)
    dx, dy, dark = frames(contact_pair(scene_pairs))
    np.testing.assert_array_equal(
        again.reconstruct(dx, dy, dark=dark).depth, model.reconstruct(dx, dy, dark=dark).depth
    )


def test_calibrate_equals_cli(cli, press_pairs, scene_pairs, tmp_path):
    folder, pairs = press_pairs
    run(cli, "calibrate", folder, "--ball-diameter-mm", "6", "--out", tmp_path / "cli.json")
    cli_model = stereotac.TactileModel.load(tmp_path / "cli.json")
    presses = [tuple(a for a in frames(p) if a is not None) for p in pairs]
    model, report = stereotac.calibrate(presses, 6.0)
    assert isinstance(report, dict) and {"presses", "rejected", "report", "fit"} <= set(report)
    assert len(report["presses"]) + len(report["rejected"]) == len(pairs)
    dx, dy, dark = frames(contact_pair(scene_pairs))
    np.testing.assert_array_equal(
        model.reconstruct(dx, dy, dark=dark).depth, cli_model.reconstruct(dx, dy, dark=dark).depth
    )
    with pytest.raises(stereotac.BadInputError, match="ball diameter"):
        stereotac.calibrate(presses, -1.0)
    with pytest.raises(stereotac.BadInputError, match="no calibration pairs"):
        stereotac.calibrate([], 6.0)
    # Each press's ball: the same ball given per press is the same model; one diameter
    # short, or one that is not a number, is refused.
    same, _ = stereotac.calibrate(presses, 6.0, press_balls_mm=[6.0] * len(presses))
    np.testing.assert_array_equal(
        same.reconstruct(dx, dy, dark=dark).depth, model.reconstruct(dx, dy, dark=dark).depth
    )
    # A smaller ball makes the same circle a deeper press.
    _, small = stereotac.calibrate(presses, 6.0, press_balls_mm=[5.5] * len(presses))
    _, large = stereotac.calibrate(presses, 6.0)
    large_depth = {p["name"]: p["depth_mm"] for p in large["presses"]}
    assert small["presses"] and all(p["ball_diameter_mm"] == 5.5 for p in small["presses"])
    for p in small["presses"]:
        assert p["depth_mm"] > large_depth[p["name"]], p["name"]
    with pytest.raises(stereotac.BadInputError, match="one per press"):
        stereotac.calibrate(presses, 6.0, press_balls_mm=[6.0] * (len(presses) - 1))
    with pytest.raises(stereotac.BadInputError, match="press002"):
        stereotac.calibrate(presses, 6.0, press_balls_mm=[6.0, 6.0, float("nan")] + [6.0] * (len(presses) - 3))


def test_calibrate_measures_the_crosstalk_from_single_colour_frames(press_pairs, scene_pairs):
    _, pairs = press_pairs
    presses = [tuple(a for a in frames(p) if a is not None) for p in pairs]
    ref = tuple(a for a in frames(scene_pairs[0]) if a is not None)
    rdx = ref[0]
    # A camera without crosstalk: with a strip dark its colour's channel falls to green.
    blue_only, red_only = rdx.copy(), rdx.copy()
    blue_only[..., 0] = np.minimum(rdx[..., 0], rdx[..., 1])
    red_only[..., 2] = np.minimum(rdx[..., 2], rdx[..., 1])
    plain, _ = stereotac.calibrate(presses, 6.0, ref=ref)
    measured, _ = stereotac.calibrate(presses, 6.0, ref=ref, single_colour_dx=(blue_only, red_only))
    dx, dy, dark = frames(contact_pair(scene_pairs))
    np.testing.assert_array_equal(
        measured.reconstruct(dx, dy, dark=dark).depth, plain.reconstruct(dx, dy, dark=dark).depth
    )
    with pytest.raises(stereotac.BadInputError, match="give ref too"):
        stereotac.calibrate(presses, 6.0, single_colour_dx=(blue_only, red_only))
    # Swapped: neither LED's light is left alone.
    with pytest.raises(stereotac.BadInputError, match="single_colour_dx: only"):
        stereotac.calibrate(presses, 6.0, ref=ref, single_colour_dx=(red_only, blue_only))


def test_calibrate_measures_and_undoes_the_camera_curve_from_an_all_lit_frame(press_pairs, scene_pairs, tmp_path):
    _, pairs = press_pairs
    presses = [tuple(a for a in frames(p) if a is not None) for p in pairs]
    rdx, rdy, _ = frames(scene_pairs[0])
    # The demo's presses come without LEDs-off frames; its skin's room light is about 6 DN
    # (the scene recording's LEDs-off frame is the stereo view, far brighter).
    ref = (rdx, rdy, np.full_like(rdx, 6))
    # A linear camera: all four strips lit hold both phases' light over the room's once.
    all_lit = np.clip(rdx.astype(np.int32) + rdy - 6, 0, 255).astype(np.uint8)
    plain, _ = stereotac.calibrate(presses, 6.0, ref=ref)
    linear, _ = stereotac.calibrate(presses, 6.0, ref=ref, all_lit=all_lit)
    dx, dy, dark = frames(contact_pair(scene_pairs))
    np.testing.assert_array_equal(
        linear.reconstruct(dx, dy, dark=dark).depth, plain.reconstruct(dx, dy, dark=dark).depth
    )
    linear.save(tmp_path / "linear.json")
    assert "camera_curve" not in (tmp_path / "linear.json").read_text()
    # The same frames through a display gamma: measured and kept in the model.
    def bent(a):
        return np.round(255.0 * (a / 255.0) ** (1 / 2.2)).astype(np.uint8)
    bent_presses = [tuple(bent(a) for a in p) for p in presses]
    bent_ref = tuple(bent(a) for a in ref)
    curved, _ = stereotac.calibrate(bent_presses, 6.0, ref=bent_ref, all_lit=bent(all_lit))
    curved.save(tmp_path / "curved.json")
    gamma = json.loads((tmp_path / "curved.json").read_text())["camera_curve"]["gamma"]
    assert abs(gamma - 2.2) < 0.1, gamma
    with pytest.raises(stereotac.BadInputError, match="give ref as"):
        stereotac.calibrate(presses, 6.0, ref=ref[:2], all_lit=all_lit)
    # The dx frame is no all-lit frame: it holds only one phase's light.
    with pytest.raises(stereotac.BadInputError, match="all_lit: the frames do not add up"):
        stereotac.calibrate(presses, 6.0, ref=ref, all_lit=ref[0])


def test_calibrate_measures_the_side_light_only_when_asked(press_pairs, scene_pairs, tmp_path):
    _, pairs = press_pairs
    presses = [tuple(a for a in frames(p) if a is not None) for p in pairs]
    ref = tuple(a for a in frames(scene_pairs[0]) if a is not None)
    plain, _ = stereotac.calibrate(presses, 6.0, ref=ref)
    asked, _ = stereotac.calibrate(presses, 6.0, ref=ref, side_light=True)
    # The demo's strips run along the whole axis: nothing to take out, the same depth,
    # and the model file has no side light.
    dx, dy, dark = frames(contact_pair(scene_pairs))
    np.testing.assert_array_equal(
        asked.reconstruct(dx, dy, dark=dark).depth, plain.reconstruct(dx, dy, dark=dark).depth
    )
    asked.save(tmp_path / "m.json")
    assert "side_light" not in (tmp_path / "m.json").read_text()
