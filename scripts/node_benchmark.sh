#!/usr/bin/env bash
# End-to-end latency and throughput of the ROS node on a bag: synthesizes a
# Dolls sequence of N frames, writes it as a bag, plays it through
# launch/play_bag.launch at a given rate on a private master, records the
# node's status messages and samples the node's RSS and CPU time every few
# seconds, then prints a summary (per-window latency and processing time,
# drops, throughput, RSS, the node's CPU seconds per published frame) and
# writes it to OUT/summary.md.
# Usage: scripts/node_benchmark.sh [--frames N] [--rate R] [--size WxH] [--out DIR] [--param NAME=VALUE]...
#   --frames N   frames in the bag (default 30)
#   --rate R     bag playback rate (default 1.0)
#   --size WxH   LR frame size (default: Dolls' own, 168x185); the scene is
#                seen with --scene-zoom times its focal length (default 1.8)
#                to fill it, as scripts/benchmark.sh does for 320x240
#   --out DIR    output folder (default /tmp/dsm_node_benchmark)
#   --param      node parameter override, e.g. --param samples=16 (repeatable)
#   --no-build   run the catkin workspace as it is (e.g. another commit's
#                libraries copied into its devel/lib, for a before/after run)
# Steady state: windows continued from the previous one (status.continued)
# each publish window_size - window_overlap new frames; their mean processing
# time gives the streaming throughput. Play the bag slower than the node
# processes (no queueing, no drops) to measure it.
set -eo pipefail
source "$(dirname "$0")/common.sh"

frames=30
rate=1.0
out=/tmp/dsm_node_benchmark
overrides=()
size=""
zoom=1.8
no_build=0
while [ $# -gt 0 ]; do
  case "$1" in
    --frames) frames="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --scene-zoom) zoom="$2"; shift 2 ;;
    --no-build) no_build=1; shift ;;
    --rate) rate="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --param) overrides+=("$2"); shift 2 ;;
    *) echo "node_benchmark: unknown argument $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done

# The catkin build has the node and every tool this script runs.
"$DSM_REPO/scripts/install_deps.sh" >/dev/null
[ "$no_build" = 1 ] || dsm_build_catkin
dsm_source_workspace
ros_bin="$DSM_WORKSPACE/devel/lib/deblur_sr_mvs"
mkdir -p "$out"
out="$(cd "$out" && pwd)"

size_args=()
if [ -n "$size" ]; then
  lr_width="${size%x*}"
  lr_height="${size#*x}"
  size_args=(--hr-width $((2 * lr_width)) --hr-height $((2 * lr_height)) --scene-zoom "$zoom")
fi
seq_dir="$out/sequence"
key="$frames ${size_args[*]}"
if [ ! -f "$out/input.bag" ] || [ "$(cat "$out/input.frames" 2>/dev/null)" != "$key" ]; then
  rm -rf "$seq_dir" "$out/input.bag"
  "$ros_bin/synthesize_sequence" --scene "$DSM_REPO/data/middlebury/Dolls" \
    --output "$seq_dir" --frames "$frames" --scale 2 --seed 0 "${size_args[@]}" >/dev/null
  "$ros_bin/sequence_to_bag" --input "$seq_dir" --output "$out/input.bag" >/dev/null
  echo "$key" >"$out/input.frames"
fi
exposure="$(awk -F, 'NR == 2 { print $3 }' "$seq_dir/frames.csv")"

# Parameters: the defaults plus the overrides.
params="$out/params.yaml"
cp "$DSM_REPO/config/default.yaml" "$params"
for kv in "${overrides[@]}"; do echo "${kv%%=*}: ${kv#*=}" >>"$params"; done
window_size="$(awk -F': *' '$1 == "window_size" { v = $2 } END { sub(/ .*/, "", v); print v }' "$params")"
overlap="$(awk -F': *' '$1 == "window_overlap" { v = $2 } END { sub(/ .*/, "", v); print v }' "$params")"
windows=$(( (frames - overlap) / (window_size - overlap) ))

dsm_start_master "${DSM_BENCH_PORT:-11398}" "$out/roscore.log"
ns=/deblur_sr_mvs
rm -f "$out/status.bag" "$out/outputs.bag"
# Everything the node publishes, for the accuracy of its outputs (below).
/usr/lib/rosbag/record -O "$out/outputs.bag" __name:=benchmark_recorder $ns/status \
  $ns/restored/image $ns/restored/camera_info $ns/depth/image $ns/depth/camera_info \
  $ns/pose $ns/path /tf >/dev/null 2>&1 &
dsm_pids+=($!)
start=$(date +%s.%N)
roslaunch deblur_sr_mvs play_bag.launch bag:="$out/input.bag" exposure_time:="$exposure" \
  rate:="$rate" delay:=3 params:="$params" >"$out/node.log" 2>&1 &
dsm_pids+=($!)

echo "node_benchmark: $frames frames at rate $rate, windows of $window_size (overlap $overlap): expecting $windows windows"
echo "seconds,rss_kib,cpu_seconds" >"$out/rss.csv"
node_pid=""
done_windows=0
for _ in $(seq 3600); do
  [ -n "$node_pid" ] || node_pid="$(pgrep -f "deblur_sr_mvs/estimator_node" | head -n 1 || true)"
  if [ -n "$node_pid" ]; then
    read -r rss cpu < <(ps -o rss=,times= -p "$node_pid" 2>/dev/null || true)
    [ -n "$rss" ] && echo "$(echo "$(date +%s.%N) - $start" | bc),$rss,$cpu" >>"$out/rss.csv"
  fi
  index="$(timeout 5 rostopic echo -n 1 $ns/status/window_index 2>/dev/null | head -n 1 || true)"
  dropped="$(timeout 5 rostopic echo -n 1 $ns/status/windows_dropped 2>/dev/null | head -n 1 || true)"
  done_windows=$(( ${index:-0} + ${dropped:-0} ))
  [ "$done_windows" -ge "$windows" ] && break
  sleep 2
done
sleep 1
# The node's CPU time at the end (user + sys, all threads): work that does not
# depend on how loaded the machine is.
if [ -n "$node_pid" ]; then
  read -r rss cpu < <(ps -o rss=,times= -p "$node_pid" 2>/dev/null || true)
  [ -n "$rss" ] && echo "$(echo "$(date +%s.%N) - $start" | bc),$rss,$cpu" >>"$out/rss.csv"
fi
dsm_stop_processes
trap - EXIT

/usr/bin/python3 - "$out" "$frames" "$rate" "$windows" "$((window_size - overlap))" <<'EOF' | tee "$out/summary.md"
import csv, sys
import rosbag
out, frames, rate, expected = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
new_per_window = int(sys.argv[5])
statuses = [m for _, m, _ in rosbag.Bag(f"{out}/outputs.bag").read_messages(topics=["/deblur_sr_mvs/status"])]
ok = [s for s in statuses if s.success]
lat = [s.latency_seconds for s in ok]
proc = [s.processing_seconds for s in ok]
last = statuses[-1]
samples = list(csv.DictReader(open(f"{out}/rss.csv")))
rss = [int(r["rss_kib"]) for r in samples]
cpu = max((int(r["cpu_seconds"]) for r in samples), default=0)
print("| frames in bag | rate | windows processed + dropped / expected | failed | published frames | "
      "latency mean / max (s) | processing per window mean (s) | estimation throughput (frames/s) | RSS first / peak (MiB) | "
      "node CPU (s) | CPU per published frame (s) |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
print(f"| {frames} | {rate:g} | {len(ok)} + {last.windows_dropped} / {expected} | {last.windows_failed} | "
      f"{last.frames_published} | {sum(lat)/max(len(lat),1):.2f} / {max(lat, default=0):.2f} | "
      f"{sum(proc)/max(len(proc),1):.2f} | {last.frames_published / max(sum(proc), 1e-9):.2f} | "
      f"{rss[0]/1024 if rss else 0:.0f} / {max(rss, default=0)/1024:.0f} | "
      f"{cpu} | {cpu / max(last.frames_published, 1):.2f} |")
steady = [s for s in ok if s.continued]
def stage(s, name):
    return sum(v for n, v in zip(s.stage_names, s.stage_seconds) if n == name)
if steady:
    sp = [s.processing_seconds for s in steady]
    sl = [s.latency_seconds for s in steady]
    mean_p = sum(sp) / len(sp)
    print()
    print("| continued windows | processing mean (s) | of which initialization (s) | steady throughput (frames/s) | "
          "latency mean (s) | latency / processing |")
    print("|---|---|---|---|---|---|")
    print(f"| {len(steady)} | {mean_p:.2f} | {sum(stage(s, 'initialization') for s in steady) / len(steady):.2f} | "
          f"{new_per_window / mean_p:.3f} | {sum(sl) / len(sl):.2f} | {sum(sl) / len(sl) / mean_p:.2f} |")
EOF

# Accuracy of what the node published against the sequence's ground truth.
rm -rf "$out/result"
"$ros_bin/bag_to_result" --input "$out/outputs.bag" --sequence "$seq_dir" --output "$out/result" >/dev/null
"$ros_bin/evaluate_sequence" --result "$out/result" --sequence "$seq_dir" --method "ROS node" \
  --json "$out/metrics.json" | tee -a "$out/summary.md"
