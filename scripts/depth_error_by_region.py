#!/usr/bin/env python3
"""Depth rel. error of two results, split by image region.

Usage: depth_error_by_region.py SEQUENCE RESULT_A RESULT_B
(needs Debian's python3-opencv and python3-numpy: run with /usr/bin/python3)

For every frame of SEQUENCE (synthesize_sequence's layout: gt/depth/*.tiff,
gt/latent/*.png) and each result (estimate_sequence's depth/*.tiff), the
depth is scaled by the median of gt / estimate on the 70 % centre crop (as
evaluate_sequence does) and |scaled - gt| / gt is averaged on that crop over:
  all     every pixel;
  edge    pixels within 3 px of a ground-truth depth edge (|Sobel of log
          depth| summed over x and y above 0.05);
  smooth  the others;
  flat    smooth pixels whose sharp ground-truth image has the weakest
          texture (the lowest quarter of a smoothed |Laplacian|).
Prints one line per region: each result's mean error and the region's share
of the crop. An analysis aid (BENCHMARKS.md "The re-sweep kept off flat image
regions"), not the benchmark's metric code.
"""
import os
import sys

import cv2
import numpy as np


def load(path):
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        sys.exit("depth_error_by_region: cannot read " + path)
    return image.astype(np.float64)


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    sequence, results = sys.argv[1], sys.argv[2:4]
    totals = {}
    for name in sorted(os.listdir(os.path.join(sequence, "gt", "depth"))):
        gt = load(os.path.join(sequence, "gt", "depth", name))
        height, width = gt.shape
        crop = (slice(int(height * 0.15), int(height * 0.85)), slice(int(width * 0.15), int(width * 0.85)))
        log_depth = np.log(np.maximum(gt, 1e-9))
        gradient = np.abs(cv2.Sobel(log_depth, cv2.CV_64F, 1, 0, ksize=3)) + np.abs(
            cv2.Sobel(log_depth, cv2.CV_64F, 0, 1, ksize=3))
        edge = cv2.dilate((gradient > 0.05).astype(np.uint8), np.ones((7, 7), np.uint8))[crop] > 0
        latent = load(os.path.join(sequence, "gt", "latent", name.replace(".tiff", ".png")))
        if latent.ndim == 3:
            latent = latent.mean(axis=2)
        if latent.shape != gt.shape:
            latent = cv2.resize(latent, (width, height), interpolation=cv2.INTER_AREA)
        texture = cv2.GaussianBlur(np.abs(cv2.Laplacian(latent, cv2.CV_64F)), (9, 9), 3)[crop]
        flat = (texture < np.percentile(texture, 25)) & ~edge
        regions = {"all": np.ones_like(edge), "edge": edge, "smooth": ~edge, "flat": flat}
        for result in results:
            depth = load(os.path.join(result, "depth", name))
            if depth.shape != gt.shape:
                depth = cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST)
            valid = np.isfinite(depth[crop]) & (depth[crop] > 0) & (gt[crop] > 0)
            scale = np.median(gt[crop][valid] / depth[crop][valid])
            error = np.abs(depth[crop] * scale - gt[crop]) / gt[crop]
            for region, mask in regions.items():
                use = mask & valid
                total = totals.setdefault((result, region), [0.0, 0, 0])
                total[0] += error[use].sum()
                total[1] += use.sum()
                total[2] += mask.size
    for region in ("all", "edge", "smooth", "flat"):
        cells = ["%s %.4f" % (os.path.basename(os.path.normpath(r)), totals[(r, region)][0] / max(totals[(r, region)][1], 1))
                 for r in results]
        share = totals[(results[0], region)][1] / max(totals[(results[0], "all")][1], 1)
        print(region, " ".join(cells), "share %.2f" % share)


if __name__ == "__main__":
    main()
