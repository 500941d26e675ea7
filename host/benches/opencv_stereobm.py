#!/usr/bin/env python3
"""OpenCV StereoBM reference for `stereotac bench stereo --opencv`.

Times cv2.StereoBM on one thread with the same parameters as our matcher and writes its
disparity (pixels, NaN where invalid) as a little-endian f32 .npy file, so the bench can
score both against the same ground truth.

usage: opencv_stereobm.py LEFT.png RIGHT.png OUT.npy NUM_DISP BLOCK MIN_DISP REPEATS
Needs: pip install opencv-python-headless numpy
"""
import json
import sys
import time

import cv2
import numpy as np


def main() -> None:
    left_path, right_path, out_path = sys.argv[1:4]
    num_disp, block, min_disp, repeats = (int(v) for v in sys.argv[4:8])
    cv2.setNumThreads(1)
    left = cv2.imread(left_path, cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(right_path, cv2.IMREAD_GRAYSCALE)
    if left is None or right is None:
        sys.exit(f"cannot read {left_path} or {right_path}")
    bm = cv2.StereoBM_create(numDisparities=num_disp, blockSize=block)
    bm.setMinDisparity(min_disp)
    bm.setPreFilterType(cv2.STEREO_BM_PREFILTER_XSOBEL)
    bm.setPreFilterCap(31)
    bm.setTextureThreshold(10)
    bm.setUniquenessRatio(15)
    bm.setDisp12MaxDiff(1)
    bm.setSpeckleWindowSize(100)
    bm.setSpeckleRange(16)  # disparity x16: 1 px, as ours
    disp = bm.compute(left, right)
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        disp = bm.compute(left, right)
        times.append((time.perf_counter() - start) * 1e3)
    times.sort()
    out = disp.astype(np.float32) / 16.0
    out[disp < (min_disp * 16)] = np.nan
    np.save(out_path, out.astype("<f4"))
    print(json.dumps({"median_ms": times[len(times) // 2], "opencv": cv2.__version__}))


if __name__ == "__main__":
    main()
