"""Type stubs of the native module (the Rust layer)."""

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, "os.PathLike[str]"]
_Rgb = npt.NDArray[np.uint8]  # (height, width, 3)
_Frames = Union[Tuple[_Rgb, _Rgb], Tuple[_Rgb, _Rgb, _Rgb]]  # (dx, dy) or (dx, dy, dark)

class TactileResult:
    """The depth of one dx/dy pair and the numbers about it."""

    depth: npt.NDArray[np.float32]
    """Depth (mm, height × width), positive where pressed in, 0 off the imprint."""
    contact_mask: npt.NDArray[np.bool_]
    """Touched pixels (height × width)."""
    contact: bool
    area_mm2: float
    centroid_mm: Optional[Tuple[float, float]]
    max_depth_mm: float
    max_depth_at_px: Tuple[int, int]
    volume_mm3: float
    regions: List[Tuple[int, int, int, int]]
    """Regions integrated: (x, y, width, height) in px."""
    ambient: str
    sanitized_slopes: int
    past_reach_pixels: int
    """Touched pixels the light model read past the calibration's slopes."""
    unexplained_share: float
    """The largest share of a region's slopes its solved surface does not explain: above
    0.15 they are not one surface's (dx and dy of different moments) and
    the depth is not reliable."""
    timestamp_us: Optional[float]
    """Live results: end of the dy exposure, host µs (None offline)."""
    record: Optional[Dict[str, Any]]
    """Live results: the record `stereotac run --jsonl` prints (None offline)."""
    @property
    def timings(self) -> Dict[str, float]:
        """Milliseconds per stage: detect_ms, colour_ms, model_ms, solve_ms, total_ms."""
    def summary_json(self) -> str:
        """The summary as JSON (what `stereotac reconstruct --json` prints)."""

class Reconstructor:
    """A model with its reference frames prepared, for a stream of pairs."""

    def reconstruct(
        self, dx: _Rgb, dy: _Rgb, dark: Optional[_Rgb] = None
    ) -> TactileResult: ...

class TactileModel:
    """A tactile model: colour to slope at the size and scale it was calibrated at."""

    width: int
    height: int
    px_per_mm: float
    skin_thickness_mm: float
    @staticmethod
    def load(path: _Path) -> "TactileModel": ...
    def save(self, path: _Path) -> None: ...
    def reconstruct(
        self,
        dx: _Rgb,
        dy: _Rgb,
        ref: Optional[_Frames] = None,
        dark: Optional[_Rgb] = None,
        kind: str = "lut",
        solver: str = "dct",
        past_reach: bool = True,
    ) -> TactileResult:
        """Depth of one pair; kind "lut", "mlp", "light" or "photometric", solver "dct" (Neumann) or "dst";
        past_reach=False keeps the model's slopes (lookup table or perceptron) where they
        reach the calibration's limit."""
    def reconstructor(
        self,
        ref: Optional[_Frames] = None,
        kind: str = "lut",
        solver: str = "dct",
        past_reach: bool = True,
    ) -> Reconstructor: ...

def calibrate(
    presses: Sequence[_Frames],
    ball_diameter_mm: float,
    px_per_mm: float = 15.0,
    ref: Optional[_Frames] = None,
    skin_thickness_mm: float = 3.0,
    min_presses: int = 5,
    press_balls_mm: Optional[Sequence[float]] = None,
    single_colour_dx: Optional[
        Tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]
    ] = None,
    side_light: bool = False,
    all_lit: Optional[npt.NDArray[np.uint8]] = None,
) -> Tuple[TactileModel, Dict[str, Any]]:
    """A model from ball presses, and the calibration report; `press_balls_mm` gives
    each press's ball when they were made with more than one; `single_colour_dx`
    `(blue_only, red_only)` no-contact dx frames with one strip dark, to measure and
    undo the camera's colour crosstalk (needs `ref`); `side_light` measures the
    strips' side light and reads the lookup table with it taken out; `all_lit` a
    no-contact frame with all four strips lit, to measure and undo the camera's
    response curve (needs `ref` with its LEDs-off frame)."""

def load_rgb(path: _Path) -> npt.NDArray[np.uint8]:
    """An 8-bit image file as RGB (height, width, 3), read as the CLI reads it."""

def load_grey(path: _Path) -> npt.NDArray[np.uint8]:
    """An 8-bit image file as grey (height, width), converted as the CLI converts it."""

class StereoResult:
    """The depth of one stereo pair (rectified views)."""

    disparity: npt.NDArray[np.float32]
    depth: npt.NDArray[np.float32]
    points: npt.NDArray[np.float32]
    """N × 3, mm, rectified left camera frame (X right, Y down, Z forward)."""
    colors: npt.NDArray[np.uint8]
    """N × 3: each point's grey value in the rectified left view."""
    pixels: npt.NDArray[np.uint32]
    left_rect: npt.NDArray[np.uint8]
    right_rect: npt.NDArray[np.uint8]
    fill_rate: float
    warnings: List[str]
    timestamp_us: Optional[float]
    """Live results: end of the left exposure, host µs (None offline)."""
    record: Optional[Dict[str, Any]]
    """Live results: the frame's summary record (None offline)."""
    @property
    def timings(self) -> Dict[str, float]: ...

class StereoRig:
    """A calibrated camera pair with its rectification maps and matcher."""

    focal_px: float
    baseline_mm: float
    disparity_range_px: Tuple[int, int]
    sgm_paths: Optional[int]
    """Paths semi-global matching aggregates along (None with block matching)."""
    window_px: int
    """Matching window side: block matching's blocks, semi-global matching's refinement
    window (block_size, or 9 for bm and 11 for sgm)."""
    @staticmethod
    def load(
        source: Union[_Path, Tuple[_Path, _Path]],
        units: str = "mm",
        matcher: str = "bm",
        near_mm: Optional[float] = None,
        far_mm: Optional[float] = None,
        scale: Optional[float] = None,
        block_size: Optional[int] = None,
        spatial: bool = True,
        fill_holes: int = 0,
        outliers: bool = False,
        sgm_paths: Optional[int] = None,
    ) -> "StereoRig": ...
    def compute(self, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]) -> StereoResult: ...

class Frame:
    """A recorded camera frame with its LED phase label."""

    camera: int
    sequence: int
    timestamp_us: float
    stamp_ref: str
    exposure_us: float
    label: str
    """The matcher's verdict: phase, straddles, event_missing, no_trigger, unresolved."""
    phase: Optional[str]
    """dark, all, dx or dy (label "phase")."""
    index: Optional[int]
    trigger: Optional[int]
    image: npt.NDArray[np.uint8]
    """(height, width, 3), RGB."""

class Message:
    """A recorded message, decoded: depth (float32 H×W, mm) and points (float32 N×3,
    mm) as arrays, JSON messages as dicts, log lines as {"level", "message"}, else bytes."""

    topic: str
    log_time_ns: int
    value: Any

class RecordingItems:
    def __iter__(self) -> "RecordingItems": ...
    def __next__(self) -> Union[Frame, Message]: ...

class Recording:
    """An MCAP recording (`stereotac run`, `record`, `process`, the demo)."""

    def __init__(self, path: _Path) -> None: ...
    @property
    def metadata(self) -> Dict[str, Dict[str, str]]: ...
    @property
    def attachments(self) -> Dict[str, bytes]: ...
    def model(self) -> Optional[TactileModel]:
        """The tactile model the recording holds, or None."""
    def __iter__(self) -> RecordingItems:
        """Every frame and message in file order."""
    def frames(self) -> RecordingItems:
        """The camera frames only."""

class Events:
    """LED phase events of a running sequence, as dicts on the host clock."""

    def __iter__(self) -> "Events": ...
    def __next__(self) -> Dict[str, Any]: ...
    def close(self) -> None: ...

class LiveRun:
    """A live session's results as they come (`Sensor.run`)."""

    def __iter__(self) -> "LiveRun": ...
    def __next__(self) -> Union[TactileResult, StereoResult, Frame]: ...
    def close(self) -> None: ...
    def __enter__(self) -> "LiveRun": ...
    def __exit__(self, *args: Any) -> bool: ...

class Sensor:
    """A sensor: USB hardware (by serial) or the built-in simulated one (sim=True)."""

    def __init__(self, sim: bool = False, serial: Optional[str] = None) -> None: ...
    def __enter__(self) -> "Sensor": ...
    def __exit__(self, *args: Any) -> bool: ...
    def close(self) -> None: ...
    def info(self) -> Dict[str, Any]:
        """Identity, configuration, counters, clock sync (`stereotac info --json`)."""
    def set(
        self,
        period_ms: Optional[int] = None,
        pulse_us: Optional[int] = None,
        settle_us: Optional[int] = None,
    ) -> None: ...
    def events(
        self, mode: str = "gradient", period_ms: int = 250, duration_s: Optional[float] = None
    ) -> Events: ...
    def run(
        self,
        cameras: Sequence[str] = ("sim",),
        mode: str = "gradient",
        model: Optional[Union[_Path, TactileModel]] = None,
        calib: Optional[Union[_Path, Tuple[_Path, _Path]]] = None,
        units: str = "mm",
        duration_s: Optional[float] = None,
        period_ms: int = 250,
        frames: bool = False,
        kind: str = "lut",
        static_ambient: bool = False,
        past_reach: bool = True,
    ) -> LiveRun:
        """The live pipeline of `stereotac run`: results with host timestamps."""
