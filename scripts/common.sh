# Shared by the scripts: paths and the ROS-friendly environment. Source it.
# shellcheck shell=bash

DSM_REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# Build folders live outside the source tree (one per clone, keyed by path).
DSM_CACHE="${DSM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/deblur_sr_mvs/$(printf '%s' "$DSM_REPO" | md5sum | cut -c1-10)}"
DSM_PLAIN_BUILD="${DSM_PLAIN_BUILD:-$DSM_CACHE/build-plain}"   # plain CMake: core, tools, gtests
DSM_WORKSPACE="$DSM_CACHE/catkin_ws"       # catkin workspace: everything + ROS
DSM_JOBS="${DSM_JOBS:-$(nproc)}"
# ccache (installed by install_deps.sh) makes rebuilds of unchanged files free,
# also across clones (paths below the base folder are compared relative).
DSM_CMAKE_LAUNCHER=()
if command -v ccache >/dev/null 2>&1; then
  DSM_CMAKE_LAUNCHER=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
  export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$(dirname "$DSM_REPO")}"
fi

# Debian's python3 and ROS tools first: the machine's default python3 is another one.
export PATH="/usr/bin:/bin:$PATH"
export ROS_HOSTNAME="${ROS_HOSTNAME:-localhost}"
export ROS_MASTER_URI="${ROS_MASTER_URI:-http://localhost:11311}"

# Plain CMake build (Release) of the core library, tools and gtests.
dsm_build_plain() {
  cmake -S "$DSM_REPO" -B "$DSM_PLAIN_BUILD" -DCMAKE_BUILD_TYPE=Release "${DSM_CMAKE_LAUNCHER[@]}" "$@" >/dev/null
  cmake --build "$DSM_PLAIN_BUILD" -j "$DSM_JOBS"
}

# The tools of the plain build.
dsm_tool() { echo "$DSM_PLAIN_BUILD/$1"; }

# catkin workspace build (Release) of the whole package, ROS parts included;
# the repository is linked into the workspace. Log: $DSM_CACHE/catkin_make.log.
# Usage: dsm_build_catkin [tests]
dsm_build_catkin() {
  mkdir -p "$DSM_WORKSPACE/src"
  ln -sfn "$DSM_REPO" "$DSM_WORKSPACE/src/deblur_sr_mvs"
  (cd "$DSM_WORKSPACE" && catkin_make -j"$DSM_JOBS" \
    -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
    -DCMAKE_BUILD_TYPE=Release "${DSM_CMAKE_LAUNCHER[@]}" >"$DSM_CACHE/catkin_make.log" 2>&1) ||
    { tail -n 40 "$DSM_CACHE/catkin_make.log"; echo "catkin build failed (log: $DSM_CACHE/catkin_make.log)" >&2; return 1; }
  if [ "${1:-}" = "tests" ]; then
    (cd "$DSM_WORKSPACE" && catkin_make -j"$DSM_JOBS" tests >>"$DSM_CACHE/catkin_make.log" 2>&1) ||
      { tail -n 40 "$DSM_CACHE/catkin_make.log"; echo "catkin test build failed" >&2; return 1; }
  fi
}

# Sources the workspace (devel/setup.bash fails under `set -u`).
dsm_source_workspace() {
  local had_u=0
  case $- in *u*) had_u=1; set +u ;; esac
  # shellcheck disable=SC1091
  source "$DSM_WORKSPACE/devel/setup.bash"
  [ "$had_u" -eq 1 ] && set -u
  return 0
}

# Background processes of a script's ROS run (master, recorder, launch),
# stopped newest first with SIGINT by dsm_stop_processes (also on exit).
dsm_pids=()
dsm_stop_processes() {
  local i pid
  for ((i = ${#dsm_pids[@]} - 1; i >= 0; i--)); do kill -INT "${dsm_pids[i]}" 2>/dev/null || true; done
  for pid in "${dsm_pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  dsm_pids=()
}

# A private ROS master on PORT (so that a running system is not disturbed),
# log in LOG; sets ROS_MASTER_URI and waits until the master answers.
# Usage: dsm_start_master PORT LOG
dsm_start_master() {
  export ROS_MASTER_URI="http://localhost:$1"
  trap dsm_stop_processes EXIT
  roscore -p "$1" >"$2" 2>&1 &
  dsm_pids+=($!)
  local _
  for _ in $(seq 100); do rostopic list >/dev/null 2>&1 && return 0; sleep 0.2; done
  echo "the ROS master did not start (log: $2)" >&2
  return 1
}

# Everything a ROS run of the package needs: Debian packages, the plain build
# (tools), the catkin build (node, ROS tools), the sourced workspace; sets
# DSM_ROS_BIN to the ROS tools' folder.
dsm_prepare_ros_run() {
  "$DSM_REPO/scripts/install_deps.sh" >/dev/null
  dsm_build_plain >/dev/null
  dsm_build_catkin
  dsm_source_workspace
  DSM_ROS_BIN="$DSM_WORKSPACE/devel/lib/deblur_sr_mvs"
}

# The demo's input: synthesizes the bundled Dolls sequence (FRAMES blurry LR
# frames with ground truth) into OUT/dolls_sequence and writes it as the bag
# OUT/dolls.bag; sets DSM_DEMO_SEQUENCE, DSM_DEMO_BAG and DSM_DEMO_EXPOSURE (s).
# Needs dsm_prepare_ros_run first. Usage: dsm_make_demo_bag OUT FRAMES
# shellcheck disable=SC2034  # the outputs are read by the callers
dsm_make_demo_bag() {
  DSM_DEMO_SEQUENCE="$1/dolls_sequence"
  DSM_DEMO_BAG="$1/dolls.bag"
  rm -rf "$DSM_DEMO_SEQUENCE" "$DSM_DEMO_BAG"
  "$(dsm_tool synthesize_sequence)" --scene "$DSM_REPO/data/middlebury/Dolls" \
    --output "$DSM_DEMO_SEQUENCE" --frames "$2" --scale 2 --seed 0
  "$DSM_ROS_BIN/sequence_to_bag" --input "$DSM_DEMO_SEQUENCE" --output "$DSM_DEMO_BAG"
  DSM_DEMO_EXPOSURE="$(awk -F, 'NR == 2 { print $3 }' "$DSM_DEMO_SEQUENCE/frames.csv")"
}

# Waits (up to 10 minutes) until the node in namespace $1 says in its status
# that it has published $2 frames; on failure prints the tail of log $3 and
# one line naming the caller $4, and returns 1.
dsm_wait_published() {
  local ns="$1" frames="$2" log="$3" who="$4" published=0
  echo "== waiting for the node to publish all $frames frames (log: $log)"
  for _ in $(seq 300); do
    published="$(timeout 5 rostopic echo -n 1 "$ns/status/frames_published" 2>/dev/null | head -n 1 || true)"
    [ -n "$published" ] && [ "$published" -ge "$frames" ] && return 0
    sleep 2
  done
  tail -n 20 "$log"
  echo "$who: the node published ${published:-0} of $frames frames (log: $log)" >&2
  return 1
}

# Benchmarks: the first line of their output (date, cores, commit).
dsm_benchmark_header() {
  echo "# $(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores, commit $(git -C "$DSM_REPO" rev-parse --short HEAD 2>/dev/null || echo '?')"
}

# A key of the "mean" object of evaluate_sequence's JSON, 4 decimals ("n/a" for null).
# Usage: dsm_evaluation_mean FILE KEY
dsm_evaluation_mean() {
  python3 -c "import json,sys; v=json.load(open(sys.argv[1]))['mean'][sys.argv[2]]; print('n/a' if v is None else '%.4f' % v)" "$1" "$2"
}
