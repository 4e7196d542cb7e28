#!/usr/bin/env bash
# What a user sees in rviz, headless: builds the package, makes the demo bag
# (the bundled Dolls sequence, as scripts/demo.sh does), starts a virtual X
# server (Xvfb) and a private ROS master, plays the bag through
# launch/play_bag.launch with rviz:=true (rviz/estimator.rviz), waits until the
# node has published every frame (3 windows), takes a screenshot of the screen
# (the rviz window fills it) and stops everything it started.
# Usage: scripts/rviz_screenshot.sh [OUTPUT.png]   (default: rviz_view.png)
# Environment: DSM_RVIZ_FRAMES (14), DSM_RVIZ_PORT (ROS master port, 11398),
#   DSM_RVIZ_SIZE (screenshot size, 1024x640), DSM_RVIZ_WORK (bag and logs,
#   default $DSM_CACHE/rviz_screenshot).
set -eo pipefail
source "$(dirname "$0")/common.sh"

output="$(realpath -m "${1:-rviz_view.png}")"
frames="${DSM_RVIZ_FRAMES:-14}"
screen=1280x800  # rviz/estimator.rviz's window size
start_s=$SECONDS

echo "== installing missing packages (rviz, Xvfb, ImageMagick too), building (Release)"
"$DSM_REPO/scripts/install_deps.sh" --viewer >/dev/null
dsm_prepare_ros_run

work="${DSM_RVIZ_WORK:-$DSM_CACHE/rviz_screenshot}"
mkdir -p "$work" "$(dirname "$output")"
echo "== synthesizing the Dolls sequence ($frames frames) and its bag in $work"
dsm_make_demo_bag "$work" "$frames" >"$work/synthesize.log" 2>&1 ||
  { tail -n 20 "$work/synthesize.log"; exit 1; }

# Everything started below is stopped on exit (newest first), also on errors.
trap dsm_stop_processes EXIT
# A virtual screen on a free display number (Xvfb writes the number it took).
rm -f "$work/display"
Xvfb -displayfd 3 -screen 0 "${screen}x24" -nolisten tcp 3>"$work/display" >"$work/xvfb.log" 2>&1 &
dsm_pids+=($!)
for _ in $(seq 100); do [ -s "$work/display" ] && break; sleep 0.1; done
[ -s "$work/display" ] || { cat "$work/xvfb.log"; echo "Xvfb did not start" >&2; exit 1; }
DISPLAY=":$(head -n 1 "$work/display")"
export DISPLAY
echo "== Xvfb on display $DISPLAY"

dsm_start_master "${DSM_RVIZ_PORT:-11398}" "$work/roscore.log"
echo "== ROS master at $ROS_MASTER_URI"
echo "== roslaunch deblur_sr_mvs play_bag.launch bag:=$DSM_DEMO_BAG exposure_time:=$DSM_DEMO_EXPOSURE rviz:=true"
# The delay gives rviz time to start and subscribe (the node publishes the
# cloud only to subscribers).
roslaunch deblur_sr_mvs play_bag.launch bag:="$DSM_DEMO_BAG" exposure_time:="$DSM_DEMO_EXPOSURE" \
  rviz:=true delay:=5 >"$work/node.log" 2>&1 &
dsm_pids+=($!)

ns=/deblur_sr_mvs
dsm_wait_published "$ns" "$frames" "$work/node.log" rviz_screenshot
rosnode list 2>/dev/null | grep -qx /rviz ||
  { tail -n 20 "$work/node.log"; echo "rviz_screenshot: rviz is not running (log: $work/node.log)" >&2; exit 1; }
sleep 3  # rviz draws the last messages

import -display "$DISPLAY" -window root "$work/screen.png"
convert "$work/screen.png" -resize "${DSM_RVIZ_SIZE:-1024x640}" -strip "$output"
dsm_stop_processes
trap - EXIT
echo "rviz_screenshot: $output ($(identify -format '%wx%h' "$output"), $(du -k "$output" | cut -f1) KB)" \
     "in $((SECONDS - start_s)) s; logs in $work"
