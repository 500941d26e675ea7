"""stereotac: the stereotac visuotactile sensor from Python.

A thin layer over the Rust host library (the same code as the ``stereotac`` command):
numpy arrays in and out, errors as exceptions, the GIL released while it works.

Tactile depth (photometric stereo on the lit skin)::

    import numpy as np, stereotac
    model = stereotac.TactileModel.load("model.json")       # from `stereotac calibrate`
    result = model.reconstruct(dx, dy)                        # uint8 (H, W, 3) RGB arrays
    result.depth            # float32 (H, W), mm, positive where pressed in
    result.contact, result.max_depth_mm, result.area_mm2, result.centroid_mm

Stereo depth (LEDs dark, through the skin)::

    rig = stereotac.StereoRig.load("stereo.yaml")             # or (left.yaml, right.yaml) from ROS
    s = rig.compute(left, right)                              # uint8 grey or RGB arrays
    s.depth, s.disparity, s.points, s.colors

Recordings (MCAP, from ``stereotac run``/``record``/``process``)::

    rec = stereotac.Recording("run.mcap")
    for item in rec:            # file order: Frame (image + LED phase) or Message
        if isinstance(item, stereotac.Message) and item.topic == "/stereotac/tactile/depth":
            depth_mm = item.value   # float32 (H, W)

The sensor (``sim=True``: the built-in simulated one), live results on the host clock::

    with stereotac.Sensor(sim=True) as sensor:
        for r in sensor.run(cameras=["sim", "sim"], mode="interleaved", duration_s=5):
            print(r.timestamp_us, r)          # TactileResult or StereoResult

Errors: every exception is a ``StereotacError``; ``BadInputError`` is also a
``ValueError``, ``IoError`` an ``OSError``; ``DeviceError`` is about the sensor.
"""

from ._errors import BadInputError, DeviceError, IoError, StereotacError
from ._stereotac import (
    Frame,
    Message,
    Reconstructor,
    Recording,
    Sensor,
    StereoResult,
    StereoRig,
    TactileModel,
    TactileResult,
    __version__,
    calibrate,
    load_grey,
    load_rgb,
)

__all__ = [
    "BadInputError",
    "DeviceError",
    "Frame",
    "IoError",
    "Message",
    "Reconstructor",
    "Recording",
    "Sensor",
    "StereoResult",
    "StereoRig",
    "StereotacError",
    "TactileModel",
    "TactileResult",
    "__version__",
    "calibrate",
    "load_grey",
    "load_rgb",
]
