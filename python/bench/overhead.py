"""What the Python layer costs per call, against the Rust library in the same run.

For a 640x480 tactile pair (a contact) and a 640x480 stereo pair, it times, one call
of each in turn: the Python call (`Reconstructor.reconstruct`, `StereoRig.compute`:
numpy in, arrays and numbers out) and the library's own calls on the same frames
converted once (`_library_ms`: what a Rust program does, timed inside). The difference
of the medians is the overhead: conversion in, result out, the call. Goal (issue 22):
at most 5 % or 0.2 ms, whichever is larger.

    python bench/overhead.py --model DEMO/model.json --pair DX.png DY.png [DARK.png] \
        --stereo STEREO_DIR [--rounds 15] [--dev-build]   (calls: 20x rounds tactile, 4x stereo)

(inputs as the pytest fixtures make them: `stereotac demo`, `stereotac export`,
`stereotac stereo --synthetic 150`). Build the package in release for real figures; `--dev-build` (CI's smoke run of a
package built with the dev profile) prints the figures without judging them.
"""

import argparse
import statistics
import time
from pathlib import Path

import stereotac


def compare(name, python_call, library_ms, calls, judge=True):
    """Median of `calls` Python calls against the median of as many library calls,
    alternating one of each (the machine's drift and noise fall on both alike)."""
    python_call()  # warm: plans, buffers
    py, lib = [], []
    for _ in range(calls):
        start = time.perf_counter()
        python_call()
        py.append((time.perf_counter() - start) * 1e3)
        lib.append(library_ms(1))
    p, l = statistics.median(py), statistics.median(lib)
    over = p - l
    goal = max(0.05 * l, 0.2)
    if not judge:
        verdict = "not judged: dev build"
    else:
        verdict = "meets" if over <= goal else "MISSES"
    print(
        f"{name:<8} python {p:8.3f} ms  library {l:8.3f} ms  overhead {over:+.3f} ms "
        f"({100 * over / l:+.1f} %)  goal <= {goal:.3f} ms: {verdict}  ({calls} calls each)"
    )
    return over <= goal


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--pair", type=Path, nargs="+", required=True, metavar="PNG")
    ap.add_argument("--stereo", type=Path, required=True, help="a `stereo --synthetic` output folder")
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument(
        "--dev-build",
        action="store_true",
        help="the package was built with the dev profile: print the figures, judge nothing",
    )
    a = ap.parse_args()
    if len(a.pair) not in (2, 3):
        ap.error(f"--pair takes DX.png DY.png [DARK.png], got {len(a.pair)} file(s)")

    model = stereotac.TactileModel.load(a.model)
    frames = [stereotac.load_rgb(p) for p in a.pair]
    dx, dy = frames[0], frames[1]
    dark = frames[2] if len(frames) > 2 else None
    rec = model.reconstructor()
    r = rec.reconstruct(dx, dy, dark=dark)
    print(f"tactile: {model.width}x{model.height}, {r}")
    ok = compare(
        "tactile",
        lambda: rec.reconstruct(dx, dy, dark=dark),
        lambda n: rec._library_ms(dx, dy, dark=dark, repeats=n),
        20 * a.rounds,
        judge=not a.dev_build,
    )
    rig = stereotac.StereoRig.load(a.stereo / "input_calibration.yaml")
    left = stereotac.load_grey(a.stereo / "input_left.png")
    right = stereotac.load_grey(a.stereo / "input_right.png")
    print(f"stereo: {left.shape[1]}x{left.shape[0]}, {rig}")
    ok &= compare(
        "stereo",
        lambda: rig.compute(left, right),
        lambda n: rig._library_ms(left, right, repeats=n),
        4 * a.rounds,
        judge=not a.dev_build,
    )
    if a.dev_build:
        print("dev build: goals not judged (a release build gives the figures: pip install ./python)")
    else:
        print("all goals met" if ok else "some goals missed")


if __name__ == "__main__":
    main()
