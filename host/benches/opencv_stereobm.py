#!/usr/bin/env python3
"""OpenCV references for `stereotac bench stereo --opencv` and `stereo-eval --compare`.

Runs cv2.StereoBM (mode `bm`) or cv2.StereoSGBM (mode `sgbm`: 3-way, OpenCV's fastest
semi-global mode) on one thread with the settings our matchers use, on every pair listed
in PAIRS (a text file, one pair a line: LEFT, RIGHT and OUT separated by tabs). Each pair
is computed once untimed, then REPEATS times timed; the median of all timed runs is
printed as JSON. Each pair's disparity (pixels, NaN where invalid) is written to its OUT
as a little-endian f32 .npy file, so the caller can score it against the same ground
truth as its own.

usage: opencv_stereobm.py PAIRS NUM_DISP BLOCK MIN_DISP REPEATS bm|sgbm
Needs: pip install opencv-python-headless numpy
"""
import json
import sys
import time

import cv2
import numpy as np


def matcher(mode: str, num_disp: int, block: int, min_disp: int):
    if mode == "sgbm":
        return cv2.StereoSGBM_create(
            minDisparity=min_disp,
            numDisparities=num_disp,
            blockSize=block,
            P1=8 * block * block,  # OpenCV's documented choice for grey images
            P2=32 * block * block,
            disp12MaxDiff=1,
            uniquenessRatio=10,
            speckleWindowSize=100,
            speckleRange=1,  # multiplied by 16 inside: 1 px, as ours
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )
    if mode == "bm":
        bm = cv2.StereoBM_create(numDisparities=num_disp, blockSize=block)
        bm.setMinDisparity(min_disp)
        bm.setPreFilterType(cv2.STEREO_BM_PREFILTER_XSOBEL)
        bm.setPreFilterCap(31)
        bm.setTextureThreshold(10)
        bm.setUniquenessRatio(15)
        bm.setDisp12MaxDiff(1)
        bm.setSpeckleWindowSize(100)
        bm.setSpeckleRange(16)  # disparity x16: 1 px, as ours
        return bm
    sys.exit(f"mode {mode!r}: bm or sgbm")


def main() -> None:
    if len(sys.argv) != 7:
        sys.exit(__doc__)
    pairs_path = sys.argv[1]
    num_disp, block, min_disp, repeats = (int(v) for v in sys.argv[2:6])
    mode = sys.argv[6]
    cv2.setNumThreads(1)
    stereo = matcher(mode, num_disp, block, min_disp)
    with open(pairs_path, encoding="utf-8") as f:
        pairs = [line.rstrip("\n").split("\t") for line in f if line.strip()]
    if not pairs or any(len(p) != 3 for p in pairs):
        sys.exit(f"{pairs_path}: expected lines of LEFT<tab>RIGHT<tab>OUT")
    times = []
    for left_path, right_path, out_path in pairs:
        left = cv2.imread(left_path, cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(right_path, cv2.IMREAD_GRAYSCALE)
        if left is None or right is None:
            sys.exit(f"cannot read {left_path} or {right_path}")
        disp = stereo.compute(left, right)
        for _ in range(max(1, repeats)):
            start = time.perf_counter()
            disp = stereo.compute(left, right)
            times.append((time.perf_counter() - start) * 1e3)
        out = disp.astype(np.float32) / 16.0
        out[disp < (min_disp * 16)] = np.nan
        np.save(out_path, out.astype("<f4"))
    times.sort()
    print(json.dumps({"median_ms": times[len(times) // 2], "opencv": cv2.__version__}))


if __name__ == "__main__":
    main()
