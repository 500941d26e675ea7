"""Stereo depth from Python against the CLI, and what bad input gives."""

import numpy as np
import pytest

import stereotac


def load(capture):
    rig = stereotac.StereoRig.load(capture / "input_calibration.yaml")
    left = stereotac.load_grey(capture / "input_left.png")
    right = stereotac.load_grey(capture / "input_right.png")
    return rig, left, right


def test_compute_equals_cli(stereo_capture):
    rig, left, right = load(stereo_capture)
    s = rig.compute(left, right)
    np.testing.assert_array_equal(s.depth, np.load(stereo_capture / "depth.npy"))
    np.testing.assert_array_equal(s.disparity, np.load(stereo_capture / "disparity.npy"))
    valid = np.isfinite(s.depth)
    assert s.points.dtype == np.float32 and s.points.shape == (int(valid.sum()), 3)
    assert s.colors.dtype == np.uint8 and s.colors.shape == s.points.shape
    # Each point sits at its pixel's depth (through Q: to float rounding), with that
    # pixel's grey value.
    np.testing.assert_allclose(s.points[:, 2], s.depth.ravel()[s.pixels], rtol=1e-6)
    np.testing.assert_array_equal(s.colors[:, 0], s.left_rect.ravel()[s.pixels])
    assert s.fill_rate == pytest.approx(valid.mean())
    # The built-in capture is a plane 150 mm away, tilted: a median near 150 mm.
    assert 120 < float(np.median(s.depth[valid])) < 180
    assert s.warnings == []
    assert rig.baseline_mm == pytest.approx(14.0, rel=0.05)


def test_rgb_and_strided_inputs(stereo_capture):
    rig, left, right = load(stereo_capture)
    want = rig.compute(left, right).depth
    rgb = [np.dstack([a, a, a]) for a in (left, right)]  # equal channels: the same grey
    np.testing.assert_array_equal(rig.compute(*rgb).depth, want)
    fortran = [np.asfortranarray(a) for a in (left, right)]
    np.testing.assert_array_equal(rig.compute(*fortran).depth, want)


def test_bad_inputs_raise_clearly(stereo_capture, tmp_path):
    rig, left, right = load(stereo_capture)
    for a, b, words in [
        (left[:100], right[:100], "frame"),
        (left.astype(np.int16), right, "uint8"),
        (left[:, :, None].repeat(2, axis=2), right, "(height, width)"),
        (left, np.ascontiguousarray(right[:480, :480]), "calibration"),
    ]:
        with pytest.raises(stereotac.BadInputError) as e:
            rig.compute(a, b)
        assert words in str(e.value), f"{words!r} not in {e.value}"
    with pytest.raises(stereotac.IoError):
        stereotac.StereoRig.load(tmp_path / "none.yaml")
    with pytest.raises(stereotac.BadInputError, match="matcher"):
        stereotac.StereoRig.load(stereo_capture / "input_calibration.yaml", matcher="census")
    with pytest.raises(stereotac.BadInputError, match="units"):
        stereotac.StereoRig.load(stereo_capture / "input_calibration.yaml", units="inch")
    with pytest.raises(stereotac.BadInputError, match="sgm_paths=6: 3, 4, 5 or 8"):
        stereotac.StereoRig.load(
            stereo_capture / "input_calibration.yaml", matcher="sgm", sgm_paths=6
        )
    with pytest.raises(stereotac.BadInputError, match='add matcher="sgm"'):
        stereotac.StereoRig.load(stereo_capture / "input_calibration.yaml", sgm_paths=3)


def test_semi_global_paths(stereo_capture):
    # Three paths (OpenCV StereoSGBM 3-way's) and eight put the tilted plane's median
    # at the same depth.
    calib = stereo_capture / "input_calibration.yaml"
    left = stereotac.load_grey(stereo_capture / "input_left.png")
    right = stereotac.load_grey(stereo_capture / "input_right.png")
    assert stereotac.StereoRig.load(calib).sgm_paths is None
    assert stereotac.StereoRig.load(calib, matcher="sgm").sgm_paths == 8
    # Each matcher's own window unless one is given.
    assert stereotac.StereoRig.load(calib).window_px == 9
    assert stereotac.StereoRig.load(calib, matcher="sgm").window_px == 11
    assert stereotac.StereoRig.load(calib, matcher="sgm", block_size=7).window_px == 7
    medians = []
    for paths in (3, 8):
        rig = stereotac.StereoRig.load(calib, matcher="sgm", sgm_paths=paths)
        assert rig.sgm_paths == paths
        s = rig.compute(left, right)
        assert s.fill_rate > 0.7
        medians.append(float(np.median(s.depth[np.isfinite(s.depth)])))
    assert abs(medians[0] - medians[1]) < 0.5, medians
    assert 120 < medians[0] < 180


def test_metres_need_units(stereo_capture, tmp_path):
    # The same rig written in metres: refused in mm with a hint, right with units="m".
    text = (stereo_capture / "input_calibration.yaml").read_text()
    rig_mm, left, right = load(stereo_capture)
    assert "T:" in text
    import re

    def to_m(block):
        nums = re.findall(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", block.group(2))
        return block.group(1) + ", ".join(str(float(n) / 1000.0) for n in nums) + block.group(3)

    metres = re.sub(r"(T:[^\[]*\[)([^\]]*)(\])", to_m, text, flags=re.S)
    path = tmp_path / "metres.yaml"
    path.write_text(metres)
    with pytest.raises(stereotac.BadInputError, match="--units m|units"):
        stereotac.StereoRig.load(path)
    rig_m = stereotac.StereoRig.load(path, units="m")
    assert rig_m.baseline_mm == pytest.approx(rig_mm.baseline_mm, rel=1e-6)


def test_transposed_frames_are_refused(stereo_capture):
    rig, left, right = load(stereo_capture)
    # As many pixels, other sides: refused, not matched into nonsense.
    with pytest.raises(stereotac.BadInputError, match="calibration"):
        rig.compute(left.T, right.T)


def test_a_ros_pair_gives_the_same_depth(cli, stereo_capture, tmp_path):
    from conftest import run

    yaml = stereo_capture / "input_calibration.yaml"
    ros = (tmp_path / "left.yaml", tmp_path / "right.yaml")
    run(cli, "stereo-convert", "--calib", yaml, "--ros-left", ros[0], "--ros-right", ros[1])
    rig_ros = stereotac.StereoRig.load(ros)
    rig, left, right = load(stereo_capture)
    assert rig_ros.baseline_mm == pytest.approx(rig.baseline_mm, rel=1e-6)
    a, b = rig.compute(left, right).depth, rig_ros.compute(left, right).depth
    both = np.isfinite(a) & np.isfinite(b)
    assert both.mean() > 0.5
    np.testing.assert_allclose(a[both], b[both], rtol=1e-3)
