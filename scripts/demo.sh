#!/usr/bin/env bash
# The main job on bundled data, the way a user runs it: a bag through the ROS
# node. Synthesizes the bundled Dolls sequence (10 blurry LR frames with ground
# truth), writes it as a bag, starts a private ROS master, plays the bag
# through launch/play_bag.launch (headless), records the node's outputs,
# converts them back into a result folder, evaluates it against the ground
# truth and writes what a person wants to look at:
#   demo_output/dolls.bag                 the input bag (camera + ground truth)
#   demo_output/node_outputs.bag          what the node published
#   demo_output/dolls_result/             restored HR images (latent/), depth (depth/,
#                                         depth_color/), poses.txt, report.json (windows)
#   demo_output/dolls_comparison.png      input | bicubic | restored | truth, depth, trajectory
#   demo_output/metrics.md                the paper's two tables, plus the node's timing
# Usage: scripts/demo.sh [OUTPUT_DIR]   (default: demo_output/)
set -eo pipefail
source "$(dirname "$0")/common.sh"

out="${1:-$DSM_REPO/demo_output}"
frames=10
echo "== installing missing packages, building (Release): tools in $DSM_PLAIN_BUILD, node in $DSM_WORKSPACE"
dsm_prepare_ros_run
ros_bin="$DSM_ROS_BIN"

mkdir -p "$out"
out="$(cd "$out" && pwd)"
seq_dir="$out/dolls_sequence"
echo "== synthesizing the Dolls sequence ($frames frames) and its bag"
rm -rf "$out/dolls_result" "$out/node_outputs.bag"
dsm_make_demo_bag "$out" "$frames"
exposure="$DSM_DEMO_EXPOSURE"

# A private master, so that a running robot system is not disturbed.
dsm_start_master "${DSM_DEMO_PORT:-11399}" "$out/roscore.log"
echo "== ROS master at $ROS_MASTER_URI"

ns=/deblur_sr_mvs
/usr/lib/rosbag/record -O "$out/node_outputs.bag" __name:=demo_recorder \
  $ns/restored/image $ns/restored/camera_info $ns/depth/image $ns/depth/camera_info \
  $ns/pose $ns/path $ns/status /tf >"$out/record.log" 2>&1 &
dsm_pids+=($!)
echo "== roslaunch deblur_sr_mvs play_bag.launch bag:=$out/dolls.bag exposure_time:=$exposure"
roslaunch deblur_sr_mvs play_bag.launch bag:="$out/dolls.bag" exposure_time:="$exposure" \
  delay:=3 >"$out/node.log" 2>&1 &
dsm_pids+=($!)

dsm_wait_published "$ns" "$frames" "$out/node.log" demo
sleep 1  # the recorder writes the last messages
dsm_stop_processes
trap - EXIT

echo "== converting the recorded outputs into $out/dolls_result"
"$ros_bin/bag_to_result" --input "$out/node_outputs.bag" --sequence "$seq_dir" --output "$out/dolls_result"
echo "== evaluation against the ground truth"
"$(dsm_tool evaluate_sequence)" --result "$out/dolls_result" --sequence "$seq_dir" \
  --method "joint (ROS node)" --json "$out/metrics.json" > "$out/metrics.md"
/usr/bin/python3 - "$out/dolls_result/report.json" >> "$out/metrics.md" <<'EOF'
import json, sys
report = json.load(open(sys.argv[1]))
windows = report["windows"]
print("\n## The node on the bag\n")
print("| window | frames | new | processing (s) | latency (s) | result |")
print("|---|---|---|---|---|---|")
for w in windows:
    print(f"| {w['window_index']} | {w['frames']} | {w['frames'] - w['first_new']} | "
          f"{w['processing_seconds']:.2f} | {w['latency_seconds']:.2f} | {w['message']} |")
total = sum(w["processing_seconds"] for w in windows)
print(f"\nFrames published: {report.get('frames_published')}, rejected: {report.get('frames_rejected')}, "
      f"windows dropped: {report.get('windows_dropped')}, failed: {report.get('windows_failed')}.")
print(f"Throughput: {report.get('frames_published', 0) / max(total, 1e-9):.2f} frames/s of estimation "
      f"({total:.1f} s for {len(windows)} windows). {report.get('scale_note', '')}.")
EOF
cat "$out/metrics.md"
"$(dsm_tool make_comparison_figure)" --sequence "$seq_dir" --result "$out/dolls_result" \
  --output "$out/dolls_comparison.png"
echo "demo: done; open $out/dolls_comparison.png and $out/metrics.md"
