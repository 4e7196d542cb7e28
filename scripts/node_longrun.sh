#!/usr/bin/env bash
# Long-run test of the ROS node (not part of the fast suite): loops the bundled
# Dolls bag (10 frames, the demo's) through launch/play_bag.launch at RATE x
# its 30 fps for MINUTES, samples the node's RSS, latency and counters every 10 s,
# then stops the node with SIGINT and checks that it exits within 2 s with no
# error output. Each loop makes the clock jump back: the node restarts its
# trajectory every loop, so resets are exercised too.
# Usage: scripts/node_longrun.sh [--minutes M] [--rate R] [--out DIR]
#   --minutes M  duration (default 20)
#   --rate R     bag rate (default 1: 30 frames/s, far faster than the node)
#   --out DIR    output folder (default /tmp/dsm_node_longrun)
# Writes DIR/samples.csv and DIR/summary.md; exit code 1 if a check fails.
set -eo pipefail
source "$(dirname "$0")/common.sh"

minutes=20
rate=1
out=/tmp/dsm_node_longrun
while [ $# -gt 0 ]; do
  case "$1" in
    --minutes) minutes="$2"; shift 2 ;;
    --rate) rate="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    *) echo "node_longrun: unknown argument $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done

[[ "$minutes" =~ ^[0-9]+$ ]] || { echo "node_longrun: --minutes must be a whole number" >&2; exit 2; }
dsm_prepare_ros_run
ros_bin="$DSM_ROS_BIN"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
if [ ! -f "$out/dolls.bag" ]; then
  "$(dsm_tool synthesize_sequence)" --scene "$DSM_REPO/data/middlebury/Dolls" \
    --output "$out/sequence" --frames 10 --scale 2 --seed 0 >/dev/null
  "$ros_bin/sequence_to_bag" --input "$out/sequence" --output "$out/dolls.bag" >/dev/null
fi
exposure="$(awk -F, 'NR == 2 { print $3 }' "$out/sequence/frames.csv")"

dsm_start_master "${DSM_LONGRUN_PORT:-11397}" "$out/roscore.log"
roslaunch deblur_sr_mvs play_bag.launch bag:="$out/dolls.bag" exposure_time:="$exposure" \
  rate:="$rate" loop:=true delay:=2 >"$out/node.log" 2>&1 &
dsm_pids+=($!)

ns=/deblur_sr_mvs
# The latest (latched) status, one field per line as "name: value".
status_fields() { timeout 5 rostopic echo -n 1 --noarr "$ns/status" 2>/dev/null || true; }
field() { awk -v k="$1" -F': ' '$1 == k { print $2; exit }' <<<"$status"; }
echo "seconds,rss_kib,windows,dropped,failed,resets,published,latency_s" >"$out/samples.csv"
start=$(date +%s)
end=$((start + minutes * 60))
node_pid=""
echo "node_longrun: $minutes min, bag rate $rate, samples every 10 s -> $out/samples.csv"
next=$((start + 10))
while [ "$(date +%s)" -lt "$end" ]; do
  sleep "$(( next > $(date +%s) ? next - $(date +%s) : 0 ))"
  next=$((next + 10))
  [ -n "$node_pid" ] || node_pid="$(pgrep -f "$ros_bin/estimator_node" | head -n 1 || true)"
  if [ -z "$node_pid" ] || ! kill -0 "$node_pid" 2>/dev/null; then
    echo "node_longrun: the node is not running (crash?)" >&2
    break
  fi
  rss="$(ps -o rss= -p "$node_pid" | tr -d ' ')"
  status="$(status_fields)"
  echo "$(( $(date +%s) - start )),$rss,$(field window_index),$(field windows_dropped),$(field windows_failed),$(field resets),$(field frames_published),$(field latency_seconds)" >>"$out/samples.csv"
done

# Clean shutdown: SIGINT to the node while it works; it must exit within 2 s.
shutdown_s=""
if [ -n "$node_pid" ] && kill -0 "$node_pid" 2>/dev/null; then
  t0=$(date +%s.%N)
  kill -INT "$node_pid"
  while kill -0 "$node_pid" 2>/dev/null; do sleep 0.02; done
  shutdown_s="$(echo "$(date +%s.%N) - $t0" | bc)"
fi
dsm_stop_processes
trap - EXIT

/usr/bin/python3 - "$out" "$minutes" "$rate" "${shutdown_s:-none}" <<'PY' | tee "$out/summary.md"
import csv, sys, re
out, minutes, rate, shutdown = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
rows = [r for r in csv.DictReader(open(f"{out}/samples.csv"))]
def num(r, k):
    try: return float(r[k])
    except (ValueError, TypeError): return None
t = [num(r, "seconds") for r in rows]
rss = [num(r, "rss_kib") for r in rows]
lat = [num(r, "latency_s") for r in rows if num(r, "latency_s") is not None]
warm = [v for s, v in zip(t, rss) if s is not None and s >= 120 and v]
growth = (warm[-1] - warm[0]) / warm[0] * 100 if len(warm) >= 2 else float("nan")
# RSS moves by +-5 % from window to window (allocations per window): compare
# the means of the first and the last 5 minutes after warm-up as well.
span = 30  # samples of 10 s
mean_growth = ((sum(warm[-span:]) / len(warm[-span:])) / (sum(warm[:span]) / len(warm[:span])) - 1) * 100 \
    if len(warm) >= 2 * span else float("nan")
half = len(lat) // 2
lat_first = sum(lat[:half]) / max(half, 1)
lat_second = sum(lat[half:]) / max(len(lat) - half, 1)
log = open(f"{out}/node.log", errors="replace").read()
errors = [l for l in log.splitlines() if re.search(r"ERROR|FATAL|terminate called|Segmentation|Aborted|what\(\)|has died", l)]
last = rows[-1] if rows else {}
checks = {
    "ran the whole time (no crash)": bool(rows) and t[-1] >= int(minutes) * 60 - 20,
    "RSS growth after 2 min warm-up < 5 %": growth == growth and growth < 5.0,
    "latency not rising (2nd half mean <= 1.5 x 1st half mean)": bool(lat) and lat_second <= 1.5 * lat_first,
    "SIGINT: exit within 2 s": shutdown != "none" and float(shutdown) < 2.0,
    "no error output in the node log": not errors,
}
print(f"Long run: {minutes} min, bag rate {rate}, {len(rows)} samples")
print()
print(f"RSS after warm-up: {min(warm, default=0)/1024:.0f}-{max(warm, default=0)/1024:.0f} MiB; "
      f"mean of the last 5 min vs the first 5 min: {mean_growth:+.1f} %")
print()
print("| RSS after warm-up first / last (MiB) | growth | latency mean 1st / 2nd half (s) | windows processed | dropped | failed | resets | frames published | SIGINT to exit (s) |")
print("|---|---|---|---|---|---|---|---|---|")
print(f"| {warm[0]/1024 if warm else 0:.0f} / {warm[-1]/1024 if warm else 0:.0f} | {growth:+.1f} % | {lat_first:.2f} / {lat_second:.2f} | "
      f"{last.get('windows')} | {last.get('dropped')} | {last.get('failed')} | {last.get('resets')} | {last.get('published')} | {shutdown} |")
print()
for name, ok in checks.items():
    print(f"- {'PASS' if ok else 'FAIL'}: {name}")
for line in errors[:5]:
    print(f"  error output: {line}")
sys.exit(0 if all(checks.values()) else 1)
PY
