"""The simulated sensor from Python: identity and settings, LED phase events on the host
clock, and the live pipeline's results (the same loop as `stereotac run`)."""

import pytest

import stereotac


@pytest.fixture
def sensor():
    with stereotac.Sensor(sim=True) as s:
        yield s


def test_info_and_settings(sensor):
    info = sensor.info()
    assert info["serial"] and info["protocol"] >= 1 and "config" in info
    sensor.set(pulse_us=150, settle_us=400)
    t = sensor.info()["config"]
    assert (t["trigger_pulse_us"], t["led_settle_us"]) == (150, 400)
    with pytest.raises(stereotac.BadInputError, match="nothing to set"):
        sensor.set()
    with pytest.raises(stereotac.BadInputError, match="period_ms"):
        sensor.set(period_ms=0)
    with pytest.raises(stereotac.DeviceError):
        sensor.set(pulse_us=10**9)  # the sensor refuses it; nothing changes
    assert sensor.info()["config"]["trigger_pulse_us"] == 150


def test_events_on_the_host_clock(sensor):
    phases = [e for e in sensor.events(mode="gradient", period_ms=50, duration_s=1.0) if e["event"] == "phase"]
    assert 10 <= len(phases) <= 30, len(phases)
    assert [p["phase"] for p in phases[:2]] in (["dx", "dy"], ["dy", "dx"])
    times = [p["trigger_host_us"] for p in phases]
    assert times == sorted(times)
    steps = [b - a for a, b in zip(times, times[1:])]
    assert all(abs(s - 50_000) < 1_000 for s in steps), steps
    with pytest.raises(stereotac.BadInputError, match="mode"):
        sensor.events(mode="strobe")


def test_live_results_with_increasing_timestamps(sensor, model_path):
    got = {"tactile": [], "stereo": [], "frame": []}
    for item in sensor.run(
        cameras=["sim", "sim"], mode="interleaved", model=model_path, duration_s=4, frames=True
    ):
        if isinstance(item, stereotac.TactileResult):
            got["tactile"].append(item)
        elif isinstance(item, stereotac.StereoResult):
            got["stereo"].append(item)
        else:
            got["frame"].append(item)
    assert got["tactile"] and got["stereo"] and got["frame"]
    for kind in ("tactile", "stereo"):
        times = [r.timestamp_us for r in got[kind]]
        assert all(t is not None for t in times)
        assert times == sorted(times) and len(set(times)) == len(times), times
    t = got["tactile"][0]
    assert t.depth.shape == (480, 640) and t.record["sequence"] == 0
    assert t.record["latency_ms"] is not None and t.record["latency_ms"] > 0
    assert any(r.contact for r in got["tactile"])
    s = got["stereo"][0]
    assert s.points.shape[1] == 3 and s.record["fill"] > 0.5
    frames = got["frame"]
    assert {f.camera for f in frames} == {0, 1}
    assert {f.phase for f in frames} >= {"dark", "dx", "dy"}
    # The sensor is back once the run ends.
    assert sensor.info()["serial"]


def test_a_run_stopped_early_gives_the_sensor_back(sensor, model_path):
    with sensor.run(model=model_path, duration_s=30) as run:
        first = next(iter(run))
        assert isinstance(first, stereotac.TactileResult)
    assert sensor.info()["serial"]
    # Dropped without closing: stopped all the same.
    for _ in sensor.run(model=model_path, duration_s=30):
        break
    assert sensor.info()["serial"]


def test_bad_runs_are_refused_before_they_start(sensor, model_path, tmp_path):
    with pytest.raises(stereotac.BadInputError, match="model"):
        sensor.run(cameras=["/dev/video99"], mode="gradient")
    with pytest.raises(stereotac.DeviceError, match="video99"):
        sensor.run(cameras=["/dev/video99"], mode="gradient", model=model_path)
    with pytest.raises(stereotac.BadInputError, match="duration_s"):
        sensor.run(model=model_path, duration_s=0)
    with pytest.raises(stereotac.BadInputError, match="nothing to do"):
        sensor.run(cameras=["sim"], mode="vision")
    with pytest.raises(stereotac.IoError):
        sensor.run(model=tmp_path / "none.json")
    assert sensor.info()["serial"]


def test_a_dark_frame_model_needs_dark_phases_or_static_ambient(sensor, model_path, tmp_path):
    import json

    model = json.loads(open(model_path).read())
    bw, bh = -(-model["width"] // 16), -(-model["height"] // 16)
    model["ambient"] = {"step": 16, "width": bw, "height": bh, "means": [[0.0] * 3] * (bw * bh)}
    dark = tmp_path / "dark.json"
    dark.write_text(json.dumps(model))
    with pytest.raises(stereotac.BadInputError, match="static_ambient"):
        sensor.run(mode="gradient", model=dark)
    results = [r for r in sensor.run(mode="gradient", model=dark, static_ambient=True, duration_s=1.5)]
    assert results and all(r.record["ambient"] == "calibration" for r in results)


def test_past_reach_off_reads_the_table_alone(sensor, model_path):
    results = list(sensor.run(mode="gradient", model=model_path, past_reach=False, duration_s=2))
    assert results
    assert all(r.past_reach_pixels == 0 == r.record["past_reach_pixels"] for r in results)


def test_a_closed_sensor_says_so(model_path):
    s = stereotac.Sensor(sim=True)
    s.close()
    with pytest.raises(stereotac.DeviceError, match="closed"):
        s.info()
    with pytest.raises(stereotac.DeviceError, match="closed"):
        s.run(model=model_path)
    with pytest.raises(stereotac.BadInputError, match="serial"):
        stereotac.Sensor(sim=True, serial="X")


def test_runs_and_events_left_mid_way_stop(sensor, model_path):
    # Broken out of: the next run starts at once, and the LEDs are off after events.
    for _ in sensor.run(model=model_path, duration_s=30):
        break
    with sensor.run(model=model_path, duration_s=30) as run:
        assert isinstance(next(iter(run)), stereotac.TactileResult)
    for _ in sensor.events(period_ms=50):
        break
    assert sensor.info()["status"]["running"] is False


def test_close_stops_a_run_nobody_reads(model_path):
    import time

    s = stereotac.Sensor(sim=True)
    run = s.run(model=model_path, frames=True, duration_s=60)
    time.sleep(3)  # frames and results pile up unread
    start = time.monotonic()
    s.close()
    assert time.monotonic() - start < 5
    with pytest.raises(stereotac.DeviceError, match="closed"):
        s.info()
    run.close()
