#!/usr/bin/env bash
# The main job on bundled data: synthesizes the bundled Dolls sequence (10
# blurry LR frames with ground truth), runs the joint estimator on it, evaluates
# it against the ground truth and writes what a person wants to look at:
#   demo_output/dolls_sequence/   the input sequence (images/, frames.csv, gt/)
#   demo_output/dolls_result/     restored HR images (latent/), depth (depth/,
#                                 depth_color/), poses.txt, report.json
#   demo_output/dolls_comparison.png  input | bicubic | restored | truth, depth, trajectory
#   demo_output/metrics.md        the paper's two tables for this run
# The ROS node on a bag replaces the offline estimator here with issue 4.
# Usage: scripts/demo.sh [OUTPUT_DIR]   (default: demo_output/)
set -eo pipefail
source "$(dirname "$0")/common.sh"

out="${1:-$DSM_REPO/demo_output}"
"$DSM_REPO/scripts/install_deps.sh" --core-only
echo "== building (Release) in $DSM_PLAIN_BUILD"
dsm_build_plain >/dev/null

mkdir -p "$out"
echo "== synthesizing the Dolls sequence into $out/dolls_sequence"
rm -rf "$out/dolls_sequence" "$out/dolls_result"
"$(dsm_tool synthesize_sequence)" --scene "$DSM_REPO/data/middlebury/Dolls" \
  --output "$out/dolls_sequence" --frames 10 --scale 2 --seed 0
echo "== joint estimation (paper's parameters: M 50, max_iter 3, x2)"
"$(dsm_tool estimate_sequence)" --input "$out/dolls_sequence" --output "$out/dolls_result"
echo "== evaluation against the ground truth"
"$(dsm_tool evaluate_sequence)" --result "$out/dolls_result" --sequence "$out/dolls_sequence" \
  --method joint --json "$out/metrics.json" > "$out/metrics.md"
sed -n '1,12p' "$out/metrics.md"
"$(dsm_tool make_comparison_figure)" --sequence "$out/dolls_sequence" --result "$out/dolls_result" \
  --output "$out/dolls_comparison.png"
echo "demo: done; open $out/dolls_comparison.png and $out/metrics.md"
