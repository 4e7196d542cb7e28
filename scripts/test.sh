#!/usr/bin/env bash
# Builds everything and runs every test once: the ROS-free core (gtests) with
# plain CMake, then the catkin package's ROS tests (gtests without a master,
# rostests); the catkin build's copies of the core gtests (ctest label "core",
# for `catkin_make run_tests`) are neither built nor run here. Installs missing
# Debian packages first. Build folders live outside the source tree (see
# scripts/common.sh). Ends with a line "N passed, M failed" from ctest's real
# counts; exits non-zero on any failure.
set -eo pipefail
source "$(dirname "$0")/common.sh"

"$DSM_REPO/scripts/install_deps.sh"

passed=0
failed=0
# Runs ctest in a build folder (further arguments go to ctest) and adds its
# counts to the totals.
run_ctest() {
  local build_dir="$1" log
  shift
  log="$(mktemp)"
  set +e
  (cd "$build_dir" && ctest --output-on-failure -j "$DSM_JOBS" "$@") 2>&1 | tee "$log"
  set -e
  local line total fails
  line="$(grep -E 'tests passed, [0-9]+ tests failed out of [0-9]+' "$log" | tail -n 1 || true)"
  if [ -n "$line" ]; then
    total="$(sed -E 's/.*out of ([0-9]+).*/\1/' <<<"$line")"
    fails="$(sed -E 's/.* ([0-9]+) tests failed.*/\1/' <<<"$line")"
    passed=$((passed + total - fails))
    failed=$((failed + fails))
  elif ! grep -q 'No tests were found' "$log"; then
    echo "test.sh: ctest in $build_dir gave no summary" >&2
    failed=$((failed + 1))
  fi
  rm -f "$log"
}

echo "== plain CMake build (core, tools, gtests) in $DSM_PLAIN_BUILD"
dsm_build_plain
run_ctest "$DSM_PLAIN_BUILD"

echo "== catkin workspace build in $DSM_WORKSPACE (node, nodelet, bag tools, ROS tests)"
dsm_build_catkin || exit 1
cmake --build "$DSM_WORKSPACE/build" --target dsm_ros_tests -j "$DSM_JOBS" >>"$DSM_CACHE/catkin_make.log" 2>&1 ||
  { tail -n 40 "$DSM_CACHE/catkin_make.log"; echo "catkin test build failed" >&2; exit 1; }
run_ctest "$DSM_WORKSPACE/build" -LE core

echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
