#!/usr/bin/env bash
# Accuracy and cost of the exposure estimated from the blur (issue 12, part
# 2; estimate_sequence --exposure auto; not a test, results go to
# BENCHMARKS.md): sequences synthesized at exposure ratios 0.25, 0.5 and 0.9
# of the frame interval, each estimated with the exposure of frames.csv
# (known) and with --exposure auto; the estimate against the truth and the
# restored PSNR of both runs (evaluate_sequence).
# Usage: scripts/benchmark_exposure.sh [WORK_DIR]
#   DSM_EXPOSURE_SCENES (default "Dolls Reindeer"), DSM_EXPOSURE_FLAGS
#   (synthesize_sequence size flags, default "--frames 6 --hr-width 320
#   --hr-height 240"), DSM_TOOL_DIR (built tools; default: the plain build).
set -eo pipefail
source "$(dirname "$0")/common.sh"

if [[ -z "${DSM_TOOL_DIR:-}" ]]; then
  "$DSM_REPO/scripts/install_deps.sh" --core-only
  dsm_build_plain >/dev/null
  DSM_TOOL_DIR="$DSM_PLAIN_BUILD"
fi
work="${1:-/tmp/dsm_benchmark_exposure}"
scenes="${DSM_EXPOSURE_SCENES:-Dolls Reindeer}"
flags="${DSM_EXPOSURE_FLAGS:---frames 6 --hr-width 320 --hr-height 240}"
mkdir -p "$work"
dsm_benchmark_header
echo "# synthesize_sequence $flags --exposure-ratio R; estimate_sequence with default parameters"
echo
echo "| Scene | Ratio | True exposure (s) | Estimate (s) | Error | PSNR known (dB) | PSNR auto (dB) | Delta (dB) | Estimation (s) | Whole run auto (s) |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
for scene in $scenes; do
  for ratio in 0.25 0.5 0.9; do
    sequence="$work/${scene}_$ratio"
    # shellcheck disable=SC2086
    "$DSM_TOOL_DIR/synthesize_sequence" --scene "$DSM_REPO/data/middlebury/$scene" --output "$sequence" \
      $flags --exposure-ratio "$ratio" >/dev/null
    for run in known auto; do
      extra=()
      [[ $run == auto ]] && extra=(--exposure auto)
      "$DSM_TOOL_DIR/estimate_sequence" --input "$sequence" --output "$sequence.$run" "${extra[@]}" --quiet
      "$DSM_TOOL_DIR/evaluate_sequence" --result "$sequence.$run" --sequence "$sequence" \
        --json "$sequence.$run.json" >/dev/null
    done
    python3 - "$sequence" "$scene" "$ratio" <<'PY'
import csv, json, sys
seq, scene, ratio = sys.argv[1:4]
truth = [float(r["exposure"]) for r in csv.DictReader(open(seq + "/frames.csv"))][1]
report = json.load(open(seq + ".auto/report.json"))
estimate = report["exposure_estimate"]
psnr = {run: json.load(open("%s.%s.json" % (seq, run)))["mean"]["image_psnr_db"] for run in ("known", "auto")}
print("| %s | %s | %.5f | %.5f | %+.1f %% | %.2f | %.2f | %+.2f | %.2f | %.1f |" % (
    scene, ratio, truth, estimate["seconds"], 100.0 * (estimate["seconds"] - truth) / truth,
    psnr["known"], psnr["auto"], psnr["auto"] - psnr["known"], estimate["elapsed_seconds"],
    report["wall_seconds"]))
PY
  done
done
