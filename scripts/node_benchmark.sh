#!/usr/bin/env bash
# End-to-end latency and throughput of the ROS node on a bag: synthesizes a
# Dolls sequence of N frames, writes it as a bag, plays it through
# launch/play_bag.launch at a given rate on a private master, records the
# node's status messages and samples the node's RSS every few seconds, then
# prints a summary (per-window latency and processing time, drops, throughput,
# RSS) and writes it to OUT/summary.md.
# Usage: scripts/node_benchmark.sh [--frames N] [--rate R] [--out DIR] [--param NAME=VALUE]...
#   --frames N   frames in the bag (default 30)
#   --rate R     bag playback rate (default 1.0)
#   --out DIR    output folder (default /tmp/dsm_node_benchmark)
#   --param      node parameter override, e.g. --param samples=16 (repeatable)
set -eo pipefail
source "$(dirname "$0")/common.sh"

frames=30
rate=1.0
out=/tmp/dsm_node_benchmark
overrides=()
while [ $# -gt 0 ]; do
  case "$1" in
    --frames) frames="$2"; shift 2 ;;
    --rate) rate="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --param) overrides+=("$2"); shift 2 ;;
    *) echo "node_benchmark: unknown argument $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done

dsm_prepare_ros_run
ros_bin="$DSM_ROS_BIN"
mkdir -p "$out"
out="$(cd "$out" && pwd)"

seq_dir="$out/sequence"
if [ ! -f "$out/input.bag" ] || [ "$(cat "$out/input.frames" 2>/dev/null)" != "$frames" ]; then
  rm -rf "$seq_dir" "$out/input.bag"
  "$(dsm_tool synthesize_sequence)" --scene "$DSM_REPO/data/middlebury/Dolls" \
    --output "$seq_dir" --frames "$frames" --scale 2 --seed 0 >/dev/null
  "$ros_bin/sequence_to_bag" --input "$seq_dir" --output "$out/input.bag" >/dev/null
  echo "$frames" >"$out/input.frames"
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
rm -f "$out/status.bag"
/usr/lib/rosbag/record -O "$out/status.bag" __name:=benchmark_recorder $ns/status >/dev/null 2>&1 &
dsm_pids+=($!)
start=$(date +%s.%N)
roslaunch deblur_sr_mvs play_bag.launch bag:="$out/input.bag" exposure_time:="$exposure" \
  rate:="$rate" delay:=3 params:="$params" >"$out/node.log" 2>&1 &
dsm_pids+=($!)

echo "node_benchmark: $frames frames at rate $rate, windows of $window_size (overlap $overlap): expecting $windows windows"
echo "seconds,rss_kib" >"$out/rss.csv"
node_pid=""
done_windows=0
for _ in $(seq 3600); do
  [ -n "$node_pid" ] || node_pid="$(pgrep -f "deblur_sr_mvs/estimator_node" | head -n 1 || true)"
  if [ -n "$node_pid" ]; then
    rss="$(ps -o rss= -p "$node_pid" 2>/dev/null | tr -d ' ' || true)"
    [ -n "$rss" ] && echo "$(echo "$(date +%s.%N) - $start" | bc),$rss" >>"$out/rss.csv"
  fi
  index="$(timeout 5 rostopic echo -n 1 $ns/status/window_index 2>/dev/null | head -n 1 || true)"
  dropped="$(timeout 5 rostopic echo -n 1 $ns/status/windows_dropped 2>/dev/null | head -n 1 || true)"
  done_windows=$(( ${index:-0} + ${dropped:-0} ))
  [ "$done_windows" -ge "$windows" ] && break
  sleep 2
done
sleep 1
dsm_stop_processes
trap - EXIT

/usr/bin/python3 - "$out" "$frames" "$rate" "$windows" <<'EOF' | tee "$out/summary.md"
import csv, sys
import rosbag
out, frames, rate, expected = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
statuses = [m for _, m, _ in rosbag.Bag(f"{out}/status.bag").read_messages()]
ok = [s for s in statuses if s.success]
lat = [s.latency_seconds for s in ok]
proc = [s.processing_seconds for s in ok]
last = statuses[-1]
rss = [int(r["rss_kib"]) for r in csv.DictReader(open(f"{out}/rss.csv"))]
print("| frames in bag | rate | windows processed + dropped / expected | failed | published frames | "
      "latency mean / max (s) | processing per window mean (s) | estimation throughput (frames/s) | RSS first / peak (MiB) |")
print("|---|---|---|---|---|---|---|---|---|")
print(f"| {frames} | {rate:g} | {len(ok)} + {last.windows_dropped} / {expected} | {last.windows_failed} | "
      f"{last.frames_published} | {sum(lat)/max(len(lat),1):.2f} / {max(lat, default=0):.2f} | "
      f"{sum(proc)/max(len(proc),1):.2f} | {last.frames_published / max(sum(proc), 1e-9):.2f} | "
      f"{rss[0]/1024 if rss else 0:.0f} / {max(rss, default=0)/1024:.0f} |")
EOF
