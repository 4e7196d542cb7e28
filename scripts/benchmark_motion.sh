#!/usr/bin/env bash
# Accuracy benchmark of real camera motion (not a test; results go to
# BENCHMARKS.md):
#   1. pure rotation (no parallax: docs/file_formats.md#no-parallax) on the
#      four bundled scenes: restored vs bicubic PSNR, rotation error per frame;
#   2. metric scale from a pose prior (estimate_sequence --pose-prior): the
#      ground-truth poses plus Gaussian position noise as the prior, on the
#      lateral, arc and hand-held paths of Dolls; depth rel. error in metres
#      without any alignment against the scale-aligned figure, ATE without
#      alignment.
# Usage: scripts/benchmark_motion.sh [WORK_DIR]   (DSM_PRIOR_NOISE, metres: 0.01)
set -eo pipefail
source "$(dirname "$0")/common.sh"

"$DSM_REPO/scripts/install_deps.sh" --core-only
dsm_build_plain >/dev/null
work="${1:-/tmp/dsm_benchmark_motion}"
noise="${DSM_PRIOR_NOISE:-0.01}"
mkdir -p "$work"
synthesize="$(dsm_tool synthesize_sequence)"
estimate="$(dsm_tool estimate_sequence)"
evaluate="$(dsm_tool evaluate_sequence)"
dsm_benchmark_header


echo
echo "## Pure rotation (8 frames, default size and blur, joint, default parameters)"
echo
echo "| Scene | Bicubic PSNR (dB) | Restored PSNR (dB) | Gain (dB) | Rotation error mean / max (deg) |"
echo "|---|---:|---:|---:|---:|"
for scene in Aloe Dolls Moebius Reindeer; do
  sequence="$work/rotate_$scene"
  "$synthesize" --scene "$DSM_REPO/data/middlebury/$scene" --output "$sequence" --path rotate --frames 8 >/dev/null
  "$estimate" --input "$sequence" --output "$sequence.out" --quiet
  "$evaluate" --result "$sequence.out" --sequence "$sequence" --json "$sequence.json" >/dev/null
  bicubic=$(dsm_evaluation_mean "$sequence.json" bicubic_psnr_db)
  restored=$(dsm_evaluation_mean "$sequence.json" image_psnr_db)
  gain=$(python3 -c "import sys; print('%.2f' % (float(sys.argv[2]) - float(sys.argv[1])))" "$bicubic" "$restored")
  echo "| $scene | $bicubic | $restored | $gain | $(dsm_evaluation_mean "$sequence.json" rotation_error_deg) / $(dsm_evaluation_mean "$sequence.json" max_rotation_error_deg) |"
done

echo
echo "## Metric scale from a pose prior (Dolls, 10 frames; prior = ground truth + ${noise} m Gaussian noise per axis, seed 1)"
echo
echo "| Path | Depth rel. in metres, no alignment | Depth rel., scale-aligned | Ratio | ATE without alignment (m) | Prior note |"
echo "|---|---:|---:|---:|---:|---|"
for path in lateral arc handheld; do
  sequence="$work/prior_$path"
  "$synthesize" --scene "$DSM_REPO/data/middlebury/Dolls" --output "$sequence" --path "$path" --frames 10 >/dev/null
  python3 - "$sequence/gt/poses.txt" "$sequence.prior.txt" "$noise" <<'EOF'
import random, sys
random.seed(1)
with open(sys.argv[1]) as source, open(sys.argv[2], "w") as target:
    for line in source:
        if line.startswith("#") or not line.strip():
            continue
        v = line.split()
        for i in (1, 2, 3):
            v[i] = "%.9f" % (float(v[i]) + random.gauss(0.0, float(sys.argv[3])))
        target.write(" ".join(v) + "\n")
EOF
  "$estimate" --input "$sequence" --output "$sequence.out" --pose-prior "$sequence.prior.txt" --quiet
  "$evaluate" --result "$sequence.out" --sequence "$sequence" --json "$sequence.aligned.json" >/dev/null
  "$evaluate" --result "$sequence.out" --sequence "$sequence" --metric --json "$sequence.metric.json" >/dev/null
  metric=$(dsm_evaluation_mean "$sequence.metric.json" depth_relative_error)
  aligned=$(dsm_evaluation_mean "$sequence.aligned.json" depth_relative_error)
  ratio=$(python3 -c "import sys; print('%.2f' % (float(sys.argv[1]) / float(sys.argv[2])))" "$metric" "$aligned")
  note=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['pose_prior']['note'])" "$sequence.out/report.json")
  echo "| $path | $metric | $aligned | $ratio | $(dsm_evaluation_mean "$sequence.metric.json" ate_rmse) | $note |"
done
