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
#   DSM_NOISE_SCENES  bundled scenes (default "Aloe Dolls Moebius Reindeer")
#   DSM_NOISE_COMPARE 1: every sequence also with --noise-sigma 0 (the image
#                     TV weight of noise-free frames, as before the weight
#                     followed the noise; "fixed" columns)
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
scenes="${DSM_NOISE_SCENES:-Aloe Dolls Moebius Reindeer}"
compare="${DSM_NOISE_COMPARE:-0}"
size="${DSM_NOISE_SIZE:---hr-width 320 --hr-height 240 --frames 8}"
mkdir -p "$work"
synthesize="$(dsm_tool synthesize_sequence)"
estimate="$(dsm_tool estimate_sequence)"
evaluate="$(dsm_tool evaluate_sequence)"
dsm_benchmark_header
echo "# synthesize_sequence $size --seed 1 --noise SIGMA; estimate_sequence --threads 1 (defaults otherwise:"
echo "# --noise-sigma auto; 'fixed': --noise-sigma 0). Added error: sqrt(MSE(sigma) - MSE(0)) in gray"
echo "# levels, from the mean PSNRs, against the same scene's sigma-0 row (blank without one)."

# The mean of a key of evaluate_sequence's JSON ("mean" object).
# A - B with two decimals.
minus() { python3 -c "import sys; print('%.2f' % (float(sys.argv[1]) - float(sys.argv[2])))" "$1" "$2"; }
# sqrt(MSE(PSNR A) - MSE(PSNR B)) in gray levels (blank when B is empty).
added() {
  [[ -z "$2" ]] && return 0
  python3 -c "import sys,math; m=lambda p: 255.0**2*10**(-float(p)/10); print('%.2f' % math.sqrt(max(0.0, m(sys.argv[1]) - m(sys.argv[2]))))" "$1" "$2"
}
# A key of report.json's "noise" object.
noise_key() { python3 -c "import json,sys; print('%.3f' % json.load(open(sys.argv[1]))['noise'][sys.argv[2]])" "$1" "$2"; }
# Estimates and evaluates SEQUENCE into SEQUENCE.NAME with the further flags.
estimate() {
  local sequence=$1 name=$2
  shift 2
  "$estimate" --input "$sequence" --output "$sequence.$name" --threads 1 --quiet "$@"
  "$evaluate" --result "$sequence.$name" --sequence "$sequence" --json "$sequence.$name.json" >/dev/null
}

for path in $paths; do
  echo
  echo "## Noise, $path path"
  echo
  header="| Scene | Sigma | Estimated sigma | lambda_i | Bicubic PSNR (dB) | Restored PSNR (dB) | Gain (dB) | Added error, bicubic | Added error, restored | Depth rel. |"
  rule="|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
  [[ "$compare" == 1 ]] && header="$header Fixed PSNR (dB) | Fixed gain (dB) | Fixed added error | Fixed depth rel. |" &&
    rule="$rule---:|---:|---:|---:|"
  echo "$header"
  echo "$rule"
  for scene in $scenes; do
    clean_bicubic="" clean_restored="" clean_fixed=""
    for sigma in $sigmas; do
      sequence="$work/${path}_${scene}_$sigma"
      # shellcheck disable=SC2086
      "$synthesize" --scene "$DSM_REPO/data/middlebury/$scene" --output "$sequence" --path "$path" \
        $size --seed 1 --noise "$sigma" >/dev/null
      estimate "$sequence" auto
      bicubic=$(dsm_evaluation_mean "$sequence.auto.json" bicubic_psnr_db)
      restored=$(dsm_evaluation_mean "$sequence.auto.json" image_psnr_db)
      if [[ "$sigma" == 0 ]]; then clean_bicubic=$bicubic clean_restored=$restored; fi
      row="| $scene | $sigma | $(noise_key "$sequence.auto/report.json" sigma_gray_levels) | $(noise_key "$sequence.auto/report.json" lambda_i) | $bicubic | $restored | $(minus "$restored" "$bicubic") | $(added "$bicubic" "$clean_bicubic") | $(added "$restored" "$clean_restored") | $(dsm_evaluation_mean "$sequence.auto.json" depth_relative_error) |"
      if [[ "$compare" == 1 ]]; then
        estimate "$sequence" fixed --noise-sigma 0
        fixed=$(dsm_evaluation_mean "$sequence.fixed.json" image_psnr_db)
        if [[ "$sigma" == 0 ]]; then clean_fixed=$fixed; fi
        row="$row $fixed | $(minus "$fixed" "$bicubic") | $(added "$fixed" "$clean_fixed") | $(dsm_evaluation_mean "$sequence.fixed.json" depth_relative_error) |"
      fi
      echo "$row"
    done
  done
done
