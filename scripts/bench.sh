#!/usr/bin/env bash
# Speed benchmarks (not tests): Release build, then the capture-operator
# timings (build Psi_t, apply Psi_t and Psi_t^T; 640x480 -> 320x240, M = 50,
# ~15 HR px of blur) with 1 and 2 threads. Record results in BENCHMARKS.md.
# Usage: scripts/bench.sh [--repeats N]
set -eo pipefail
source "$(dirname "$0")/common.sh"

"$DSM_REPO/scripts/install_deps.sh" --core-only
dsm_build_plain >/dev/null
echo "# $(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), commit $(git -C "$DSM_REPO" rev-parse --short HEAD 2>/dev/null || echo '?')"
"$(dsm_tool benchmark_capture_operator)" "$@"
