#!/usr/bin/env python3
"""Builds the per-path tables of scripts/benchmark.sh from its JSON files.

Usage: benchmark_tables.py WORKDIR > tables.md
WORKDIR/<path>/<scene>/<method>/eval.json (evaluate_sequence --json, depth as
estimated), .../eval_published.json (the same with the default confidence
threshold: NaN where the depth is not known) and .../report.json (the
method's own report: wall time, memory); WORKDIR/speed_640x480 optionally.
"""
import json
import math
import os
import sys

METHODS = [
    ("bicubic", "Bicubic"),
    ("btvl1", "BTV-L1"),
    ("baseline", "Baseline"),
    ("joint", "Joint"),
]
PATH_ORDER = ["lateral", "arc", "forward", "handheld", "rolling", "gain"]
PATH_NOTES = {
    "lateral": "lateral, constant velocity",
    "arc": "arc around the scene",
    "forward": "forward motion",
    "handheld": "hand-held: non-constant velocity, rotation jitter",
    "rolling": "hand-held with a rolling shutter (--readout-ratio 0.8)",
    "gain": "hand-held with gain jitter (--gain-jitter 0.1)",
}


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def fmt(value, digits):
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def percent(value):
    return "-" if value is None else f"{100.0 * value:.1f} %"


def subdirs(folder):
    return sorted(d for d in os.listdir(folder) if os.path.isdir(os.path.join(folder, d)))


class Results:
    def __init__(self, work):
        self.work = work
        found = [d for d in subdirs(work) if not d.startswith("speed_")]
        self.paths = [p for p in PATH_ORDER if p in found] + [p for p in found if p not in PATH_ORDER]
        self.scenes = {p: subdirs(os.path.join(work, p)) for p in self.paths}

    def json(self, path, scene, method, name):
        source = "joint" if method == "bicubic" else method
        return load(os.path.join(self.work, path, scene, source, name))

    def metric(self, path, scene, method, key, published=False):
        e = self.json(path, scene, method, "eval_published.json" if published else "eval.json")
        if not e:
            return None
        mean = e["mean"]
        if method == "bicubic":
            return mean.get("bicubic_psnr_db") if key == "image_psnr_db" else None
        return mean.get(key)

    def average(self, path, method, key, published=False):
        values = [self.metric(path, s, method, key, published) for s in self.scenes[path]]
        if not values or any(v is None for v in values):
            return None
        return sum(values) / len(values)


HEADER = ("Image PSNR (dB) | Depth PSNR (dB) | rel. crop | rel. full | published rel. crop | "
          "published rel. full | coverage | ATE")


def cells(get, method):
    """The HEADER columns of one method; get(key, published) reads a metric."""
    if method in ("bicubic", "btvl1"):  # images only
        return [fmt(get("image_psnr_db", False), 2)] + [""] * 7
    return [fmt(get("image_psnr_db", False), 2), fmt(get("depth_psnr_db", False), 2),
            fmt(get("depth_relative_error", False), 4), fmt(get("depth_relative_error_full_frame", False), 4),
            fmt(get("depth_relative_error", True), 4), fmt(get("depth_relative_error_full_frame", True), 4),
            percent(get("depth_coverage_full_frame", True)), fmt(get("ate_rmse", False), 5)]


def summary(results, out):
    out.append("Mean over the scenes run on each path (depth as estimated; \"published\": NaN where the "
               "confidence is below 0.5, the default output). Depth rel. error after per-frame median "
               "scaling on the 70 % centre crop and on the full frame; coverage = share of the ground "
               "truth's pixels with a published depth; ATE RMSE Sim(3)-aligned, ground-truth metres.\n")
    out.append(f"| Path | Method | {HEADER} |")
    out.append("|---|---|" + "---:|" * 8)
    for path in results.paths:
        for method, label in METHODS:
            get = lambda key, published: results.average(path, method, key, published)
            out.append(f"| {path} | {label} | " + " | ".join(cells(get, method)) + " |")
    out.append("")
    out.append("Joint against baseline per sequence (ratios < 1: joint better; depth as estimated, "
               "centre crop):\n")
    all_scenes = sorted({s for p in results.paths for s in results.scenes[p]})
    out.append("| Path | " + " | ".join(f"{s} depth / ATE" for s in all_scenes) + " | mean depth / ATE |")
    out.append("|---|" + "---:|" * (len(all_scenes) + 1))
    for path in results.paths:
        row, depth_ratios, ate_ratios = [], [], []
        for scene in all_scenes:
            if scene not in results.scenes[path]:
                row.append("not run")
                continue
            ratio = []
            for key, bucket in (("depth_relative_error", depth_ratios), ("ate_rmse", ate_ratios)):
                j = results.metric(path, scene, "joint", key)
                b = results.metric(path, scene, "baseline", key)
                value = j / b if j is not None and b else None
                if value is not None:
                    bucket.append(value)
                ratio.append(fmt(value, 2))
            row.append(" / ".join(ratio))
        mean = lambda v: sum(v) / len(v) if v else None
        out.append(f"| {path} | " + " | ".join(row) +
                   f" | {fmt(mean(depth_ratios), 2)} / {fmt(mean(ate_ratios), 2)} |")
    out.append("")


def per_path(results, out, path):
    scenes = results.scenes[path]
    out.append(f"#### {path}: {PATH_NOTES.get(path, path)}\n")
    out.append(f"| Scene | Method | {HEADER} | wall |")
    out.append("|---|---|" + "---:|" * 9)
    for scene in scenes:
        for method, label in METHODS:
            get = lambda key, published: results.metric(path, scene, method, key, published)
            report = results.json(path, scene, method, "report.json") if method != "bicubic" else None
            wall = (report or {}).get("wall_seconds", (report or {}).get("wall_time_s"))
            wall_text = f"{fmt(wall, 1)} s" if wall is not None else ""
            out.append(f"| {scene} | {label} | " + " | ".join(cells(get, method)) + f" | {wall_text} |")
    out.append("")


def speed(work, out):
    report = load(os.path.join(work, "speed_640x480", "joint", "report.json"))
    evaluation = load(os.path.join(work, "speed_640x480", "joint", "eval.json"))
    if not report:
        return
    out.append("Speed at issue 9's size: 10 frames 320x240 -> 640x480, M 50, max_iter 3, "
               "both cores (Dolls seen with 1.8x focal length):\n")
    out.append("| wall | peak memory | stages (s) | image PSNR (bicubic) |")
    out.append("|---:|---:|---|---:|")
    stages = ", ".join(f"{k} {v:.1f}" for k, v in report.get("stage_seconds", {}).items())
    psnr = ""
    if evaluation:
        m = evaluation["mean"]
        psnr = f"{fmt(m.get('image_psnr_db'), 2)} ({fmt(m.get('bicubic_psnr_db'), 2)})"
    out.append(f"| {fmt(report.get('wall_seconds'), 1)} s | {fmt(report.get('peak_memory_mib'), 0)} MiB | "
               f"{stages} | {psnr} |")
    out.append("")


def main():
    results = Results(sys.argv[1])
    out = []
    if results.paths:
        summary(results, out)
        for path in results.paths:
            per_path(results, out, path)
    speed(results.work, out)
    print("\n".join(out).rstrip("\n"))


if __name__ == "__main__":
    main()
