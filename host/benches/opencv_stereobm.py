#!/usr/bin/env python3
"""OpenCV references for `stereotac bench stereo --opencv`.

Times cv2.StereoBM (mode `bm`, the default) or cv2.StereoSGBM (mode `sgbm`: 3-way,
OpenCV's fastest semi-global mode) on one thread with the settings our matchers use and
writes its disparity (pixels, NaN where invalid) as a little-endian f32 .npy file, so
the bench can score both against the same ground truth.

usage: opencv_stereobm.py LEFT.png RIGHT.png OUT.npy NUM_DISP BLOCK MIN_DISP REPEATS [bm|sgbm]
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
    mode = sys.argv[8] if len(sys.argv) > 8 else "bm"
    cv2.setNumThreads(1)
    left = cv2.imread(left_path, cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(right_path, cv2.IMREAD_GRAYSCALE)
    if left is None or right is None:
        sys.exit(f"cannot read {left_path} or {right_path}")
    if mode == "sgbm":
        bm = cv2.StereoSGBM_create(
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
    elif mode == "bm":
        bm = cv2.StereoBM_create(numDisparities=num_disp, blockSize=block)
        bm.setMinDisparity(min_disp)
        bm.setPreFilterType(cv2.STEREO_BM_PREFILTER_XSOBEL)
        bm.setPreFilterCap(31)
        bm.setTextureThreshold(10)
        bm.setUniquenessRatio(15)
        bm.setDisp12MaxDiff(1)
        bm.setSpeckleWindowSize(100)
        bm.setSpeckleRange(16)  # disparity x16: 1 px, as ours
    else:
        sys.exit(f"mode {mode!r}: bm or sgbm")
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
