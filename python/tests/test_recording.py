"""Recordings from Python: frames, messages and header of the demo's and `process`'s
recordings, and what a damaged or missing file gives."""

import numpy as np
import pytest

import stereotac
from conftest import run


def test_frames_and_header(demo_out):
    rec = stereotac.Recording(demo_out / "demo.mcap")
    assert {"stereotac", "sensor"} <= set(rec.metadata)
    assert "stereo_calibration.yaml" in rec.attachments
    assert rec.model() is None  # the demo's recordings leave the model to `calibrate`
    frames = list(rec.frames())
    assert frames and all(isinstance(f, stereotac.Frame) for f in frames)
    f = frames[0]
    assert f.image.dtype == np.uint8 and f.image.shape == (480, 640, 3)
    phases = {f.phase for f in frames if f.label == "phase"}
    assert {"dx", "dy"} <= phases
    for camera in {f.camera for f in frames}:
        times = [f.timestamp_us for f in frames if f.camera == camera]
        assert times == sorted(times), "frames in time order per camera"


def test_processed_depth_matches_its_summary(cli, demo_out, model_path, tmp_path):
    out = tmp_path / "processed.mcap"
    run(cli, "process", demo_out / "demo.mcap", "--model", model_path, "--mcap", out)
    rec = stereotac.Recording(out)
    model = rec.model()
    assert model is not None and (model.width, model.height) == (640, 480)
    depth, contact, points = [], [], []
    for item in rec:
        if isinstance(item, stereotac.Message):
            if item.topic == "/stereotac/tactile/depth":
                depth.append(item.value)
            elif item.topic == "/stereotac/tactile/contact":
                contact.append(item.value)
            elif item.topic == "/stereotac/stereo/points":
                points.append(item.value)
    assert depth and len(depth) == len(contact)
    for d, c in zip(depth, contact):
        assert d.dtype == np.float32 and d.shape == (480, 640)
        # Stored in metres as float32, read back in mm: the summary's deepest point.
        assert float(d.max()) == pytest.approx(c["max_depth_mm"], rel=1e-5, abs=1e-6)
        assert isinstance(c["contact"], bool)
    assert any(c["contact"] for c in contact)
    # Stereo points of the built-in scene (a plane about 150 mm away), in mm.
    assert points and all(p.dtype == np.float32 and p.shape[1] == 3 for p in points)
    assert 100 < float(np.median(points[0][:, 2])) < 200


def test_damaged_and_missing_files(demo_out, tmp_path):
    with pytest.raises(stereotac.IoError):
        stereotac.Recording(tmp_path / "none.mcap")
    whole = (demo_out / "demo.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    with pytest.warns(UserWarning, match="not read whole: the file ends inside"):
        items = list(stereotac.Recording(cut))
    full = sum(1 for _ in stereotac.Recording(demo_out / "demo.mcap"))
    assert 0 < len(items) < full
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a recording at all" * 10)
    with pytest.raises(stereotac.BadInputError, match="junk.mcap"):
        list(stereotac.Recording(junk))
