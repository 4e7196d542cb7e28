#!/usr/bin/env bash
# Rolling-shutter benchmark (not a test; results go to BENCHMARKS.md): each
# bundled scene on the hand-held path read out over DSM_READOUT (0.8) of the
# frame interval (docs/file_formats.md#rolling-shutter), estimated
#   - with the rolling-shutter model (sensor.yaml read, the default),
#   - as if the shutter were global (the same frames without sensor.yaml),
# and the same path rendered with a global shutter, estimated as usual.
# Prints restored / bicubic PSNR, depth rel. error, ATE and rotation error.
# Usage: scripts/benchmark_rolling_shutter.sh [WORK_DIR]
#   (DSM_BENCH_SIZE "W H" of the HR frames: "320 240"; DSM_BENCH_FRAMES: 8)
set -eo pipefail
source "$(dirname "$0")/common.sh"

"$DSM_REPO/scripts/install_deps.sh" --core-only
dsm_build_plain >/dev/null
work="${1:-/tmp/dsm_benchmark_rolling_shutter}"
readout="${DSM_READOUT:-0.8}"
read -r width height <<<"${DSM_BENCH_SIZE:-320 240}"
frames="${DSM_BENCH_FRAMES:-8}"
mkdir -p "$work"
synthesize="$(dsm_tool synthesize_sequence)"
estimate="$(dsm_tool estimate_sequence)"
evaluate="$(dsm_tool evaluate_sequence)"
dsm_benchmark_header

row() {  # scene, label, sequence, result
  local json="$4.json"
  "$evaluate" --result "$4" --sequence "$3" --json "$json" >/dev/null
  echo "| $1 | $2 | $(dsm_evaluation_mean "$json" bicubic_psnr_db) | $(dsm_evaluation_mean "$json" image_psnr_db) | $(dsm_evaluation_mean "$json" depth_relative_error) | $(dsm_evaluation_mean "$json" ate_rmse) | $(dsm_evaluation_mean "$json" rotation_error_deg) |"
}

echo
echo "## Hand-held path, ${frames} frames, ${width}x${height} HR, readout ${readout} x frame interval (seed 3, joint, defaults)"
echo
echo "| Scene | Run | Bicubic PSNR (dB) | Restored PSNR (dB) | Depth rel. | ATE | Rotation error (deg) |"
echo "|---|---|---:|---:|---:|---:|---:|"
for scene in Aloe Dolls Moebius Reindeer; do
  common=(--scene "$DSM_REPO/data/middlebury/$scene" --path handheld --frames "$frames" --hr-width "$width" --hr-height "$height" --seed 3)
  rolling="$work/${scene}_rolling"
  global="$work/${scene}_global"
  "$synthesize" "${common[@]}" --output "$rolling" --readout-ratio "$readout" >/dev/null
  "$synthesize" "${common[@]}" --output "$global" >/dev/null
  rm -rf "$rolling.as_global" && cp -r "$rolling" "$rolling.as_global" && rm "$rolling.as_global/sensor.yaml"
  "$estimate" --input "$rolling" --output "$rolling.out" --quiet
  "$estimate" --input "$rolling.as_global" --output "$rolling.as_global.out" --quiet
  "$estimate" --input "$global" --output "$global.out" --quiet
  row "$scene" "rolling shutter, modelled" "$rolling" "$rolling.out"
  row "$scene" "rolling shutter, modelled as global (readout 0)" "$rolling" "$rolling.as_global.out"
  row "$scene" "global-shutter rendering of the path" "$global" "$global.out"
done
