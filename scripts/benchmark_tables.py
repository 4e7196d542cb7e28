#!/usr/bin/env python3
"""Builds the paper-style tables of scripts/benchmark.sh from its JSON files.

Usage: benchmark_tables.py WORKDIR > tables.md
WORKDIR/<scene>/<method>/eval.json (evaluate_sequence --json) and
WORKDIR/<scene>/<method>/report.json (the method's own report: wall time, memory).
"""
import json
import math
import os
import sys

METHODS = [
    ("bicubic", "Bicubic interpolation"),
    ("btvl1", "BTV-L1 (OpenCV superres, Farsiu et al.)"),
    ("baseline", "Bic. + Baseline"),
    ("joint_nosr", "Proposed (w/o SR) + Bic."),
    ("joint", "Proposed (joint)"),
]


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


def main():
    work = sys.argv[1]
    scenes = sorted(d for d in os.listdir(work)
                    if os.path.isdir(os.path.join(work, d)) and not d.startswith("speed_"))
    evals, reports = {}, {}
    for scene in scenes:
        for method, _ in METHODS:
            source = "joint" if method == "bicubic" else method
            evals[(scene, method)] = load(os.path.join(work, scene, source, "eval.json"))
            reports[(scene, method)] = load(os.path.join(work, scene, method, "report.json"))

    def metric(scene, method, key):
        e = evals.get((scene, method))
        if not e:
            return None
        mean = e["mean"]
        if method == "bicubic":
            return mean.get("bicubic_psnr_db") if key == "image_psnr_db" else None
        return mean.get(key)

    def average(method, key):
        values = [metric(s, method, key) for s in scenes]
        values = [v for v in values if v is not None]
        return sum(values) / len(values) if len(values) == len(scenes) and values else None

    out = []
    out.append("Image PSNR (dB), mean over the frames of each sequence (cf. the paper's tab:quantBlur):\n")
    out.append("| Method | " + " | ".join(scenes) + " | avg. |")
    out.append("|---|" + "---:|" * (len(scenes) + 1))
    for method, label in METHODS:
        row = [fmt(metric(s, method, "image_psnr_db"), 2) for s in scenes]
        out.append(f"| {label} | " + " | ".join(row) + f" | {fmt(average(method, 'image_psnr_db'), 2)} |")
    out.append("")
    out.append("Depth (PSNR dB / rel. error, median scale per frame, 70 % centre crop) and ATE RMSE "
               "(Sim(3)-aligned, ground-truth metres) (cf. tab:quant):\n")
    out.append("| Scene | Method | Depth PSNR | rel. | ATE |")
    out.append("|---|---|---:|---:|---:|")
    for scene in scenes:
        for method, label in METHODS:
            if method in ("bicubic", "btvl1"):
                continue
            out.append(f"| {scene} | {label} | {fmt(metric(scene, method, 'depth_psnr_db'), 2)} | "
                       f"{fmt(metric(scene, method, 'depth_relative_error'), 4)} | "
                       f"{fmt(metric(scene, method, 'ate_rmse'), 5)} |")
    out.append("")
    out.append("Wall time and peak memory per sequence (this machine):\n")
    out.append("| Method | " + " | ".join(scenes) + " |")
    out.append("|---|" + "---:|" * len(scenes))
    for method, label in METHODS:
        if method == "bicubic":
            continue
        cells = []
        for scene in scenes:
            r = reports.get((scene, method)) or {}
            wall = r.get("wall_seconds", r.get("wall_time_s"))
            memory = r.get("peak_memory_mib")
            cells.append(f"{fmt(wall, 1)} s" + (f", {fmt(memory, 0)} MiB" if memory else ""))
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    speed = load(os.path.join(work, "speed_640x480", "joint", "report.json"))
    speed_eval = load(os.path.join(work, "speed_640x480", "joint", "eval.json"))
    if speed:
        out.append("")
        out.append("Speed at the issue's size: 10 frames 320x240 -> 640x480, M 50, max_iter 3, "
                   "both cores (Dolls seen with 1.8x focal length):\n")
        out.append("| wall | peak memory | stages (s) | image PSNR (bicubic) |")
        out.append("|---:|---:|---|---:|")
        stages = ", ".join(f"{k} {v:.1f}" for k, v in speed.get("stage_seconds", {}).items())
        psnr = ""
        if speed_eval:
            m = speed_eval["mean"]
            psnr = f"{fmt(m.get('image_psnr_db'), 2)} ({fmt(m.get('bicubic_psnr_db'), 2)})"
        out.append(f"| {fmt(speed.get('wall_seconds'), 1)} s | {fmt(speed.get('peak_memory_mib'), 0)} MiB | "
                   f"{stages} | {psnr} |")
    print("\n".join(out))


if __name__ == "__main__":
    main()
