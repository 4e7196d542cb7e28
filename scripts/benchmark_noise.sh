#!/usr/bin/env bash
# Noise benchmark of issue 12 (not a test; results go to BENCHMARKS.md
# "Noise"): each bundled scene synthesized with Gaussian noise of sigma 0, 1,
# 2 and 4 gray levels on the LR frames (synthesize_sequence --noise, same
# seed), estimated with the default parameters and evaluated: bicubic and
# restored PSNR against the sharp HR ground truth, their difference (the
# gain), and the depth rel. error, per sigma. The image update must not
# amplify the noise: the restored PSNR must not fall faster than the
# bicubic's as sigma grows.
# Usage: scripts/benchmark_noise.sh [WORK_DIR]
#   DSM_NOISE_PATHS   camera paths (default "lateral")
#   DSM_NOISE_SIGMAS  noise levels, 8-bit units (default "0 1 2 4")
#   DSM_NOISE_SIZE    synthesize_sequence size flags (default
#                     "--hr-width 320 --hr-height 240 --frames 8")
#   DSM_TOOL_DIR      take the tools from this folder instead of building
set -eo pipefail
source "$(dirname "$0")/common.sh"

if [[ -n "$DSM_TOOL_DIR" ]]; then
  dsm_tool() { echo "$DSM_TOOL_DIR/$1"; }
else
  "$DSM_REPO/scripts/install_deps.sh" --core-only
  dsm_build_plain >/dev/null
fi
work="${1:-/tmp/dsm_benchmark_noise}"
paths="${DSM_NOISE_PATHS:-lateral}"
sigmas="${DSM_NOISE_SIGMAS:-0 1 2 4}"
size="${DSM_NOISE_SIZE:---hr-width 320 --hr-height 240 --frames 8}"
mkdir -p "$work"
synthesize="$(dsm_tool synthesize_sequence)"
estimate="$(dsm_tool estimate_sequence)"
evaluate="$(dsm_tool evaluate_sequence)"
dsm_benchmark_header
echo "# synthesize_sequence $size --seed 1 --noise SIGMA; estimate_sequence --threads 1 (defaults otherwise)"

# The mean of a key of evaluate_sequence's JSON ("mean" object).
# A - B with two decimals.
minus() { python3 -c "import sys; print('%.2f' % (float(sys.argv[1]) - float(sys.argv[2])))" "$1" "$2"; }

for path in $paths; do
  echo
  echo "## Noise, $path path"
  echo
  echo "| Scene | Sigma (gray levels) | Bicubic PSNR (dB) | Restored PSNR (dB) | Gain (dB) | Depth rel. |"
  echo "|---|---:|---:|---:|---:|---:|"
  for scene in Aloe Dolls Moebius Reindeer; do
    for sigma in $sigmas; do
      sequence="$work/${path}_${scene}_$sigma"
      # shellcheck disable=SC2086
      "$synthesize" --scene "$DSM_REPO/data/middlebury/$scene" --output "$sequence" --path "$path" \
        $size --seed 1 --noise "$sigma" >/dev/null
      "$estimate" --input "$sequence" --output "$sequence.out" --threads 1 --quiet
      "$evaluate" --result "$sequence.out" --sequence "$sequence" --json "$sequence.json" >/dev/null
      bicubic=$(dsm_evaluation_mean "$sequence.json" bicubic_psnr_db)
      restored=$(dsm_evaluation_mean "$sequence.json" image_psnr_db)
      echo "| $scene | $sigma | $bicubic | $restored | $(minus "$restored" "$bicubic") | $(dsm_evaluation_mean "$sequence.json" depth_relative_error) |"
    done
  done
done
