#!/usr/bin/env bash
# Runs the unit tests (plain CMake) and the ROS tests (catkin: the node's
# gtests and rostest) built with AddressSanitizer + UndefinedBehaviorSanitizer
# (option DSM_SANITIZE). Separate build folders; slower than scripts/test.sh.
# LeakSanitizer is on for the core tests and off for the ROS tests, whose ROS
# libraries keep static allocations until exit.
# Usage: scripts/sanitize.sh
set -eo pipefail
source "$(dirname "$0")/common.sh"
"$DSM_REPO/scripts/install_deps.sh" >/dev/null

export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
plain="$DSM_CACHE/build-asan"
echo "== plain build with ASan + UBSan in $plain"
cmake -S "$DSM_REPO" -B "$plain" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDSM_SANITIZE=ON >/dev/null
cmake --build "$plain" -j "$DSM_JOBS" >"$DSM_CACHE/build-asan.log" 2>&1 || { tail -n 30 "$DSM_CACHE/build-asan.log"; exit 1; }
(cd "$plain" && ASAN_OPTIONS=detect_leaks=1 ctest -j "$DSM_JOBS" --output-on-failure 2>&1 | tail -n 5)

ws="$DSM_CACHE/catkin_ws_asan"
echo "== catkin build with ASan + UBSan in $ws"
mkdir -p "$ws/src"
ln -sfn "$DSM_REPO" "$ws/src/deblur_sr_mvs"
(cd "$ws" && catkin_make -j"$DSM_JOBS" -DPYTHON_EXECUTABLE=/usr/bin/python3 \
   -DPython3_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDSM_SANITIZE=ON \
   >"$DSM_CACHE/catkin_make_asan.log" 2>&1 &&
 catkin_make -j"$DSM_JOBS" tests >>"$DSM_CACHE/catkin_make_asan.log" 2>&1) ||
  { tail -n 30 "$DSM_CACHE/catkin_make_asan.log"; exit 1; }
(cd "$ws/build" && ASAN_OPTIONS=detect_leaks=0 ctest --output-on-failure 2>&1 | tail -n 5)
