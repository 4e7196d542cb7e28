#!/usr/bin/env bash
# The main job on bundled data. Today: synthesizes the bundled Dolls sequence
# (10 blurry LR frames with ground truth) and writes a picture of one frame:
# blurry input | bicubic | ground-truth sharp | ground-truth depth.
# It grows into the full pipeline (estimator, node) with the next issues.
# Usage: scripts/demo.sh [OUTPUT_DIR]   (default: demo_output/)
set -eo pipefail
source "$(dirname "$0")/common.sh"

out="${1:-$DSM_REPO/demo_output}"
"$DSM_REPO/scripts/install_deps.sh" --core-only
echo "== building (Release) in $DSM_PLAIN_BUILD"
dsm_build_plain >/dev/null

mkdir -p "$out"
echo "== synthesizing the Dolls sequence into $out/dolls_sequence"
rm -rf "$out/dolls_sequence"
"$(dsm_tool synthesize_sequence)" --scene "$DSM_REPO/data/middlebury/Dolls" \
  --output "$out/dolls_sequence" --frames 10 --scale 2 --seed 0
echo "== writing the picture"
"$(dsm_tool make_comparison_figure)" --sequence "$out/dolls_sequence" \
  --output "$out/dolls_comparison.png"
echo "demo: done; open $out/dolls_comparison.png"
