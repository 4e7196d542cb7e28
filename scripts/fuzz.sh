#!/usr/bin/env bash
# Fuzzes the sequence-folder readers and the node's image-message conversion
# with libFuzzer (clang, ASan + UBSan), SECONDS per target (default 120).
# Seeds: the files of a small synthesized sequence. Findings (crash inputs) go
# to $DSM_CACHE/fuzz/<target>/; the script exits 1 if there is any.
# Usage: scripts/fuzz.sh [SECONDS]
set -eo pipefail
source "$(dirname "$0")/common.sh"

seconds="${1:-120}"
"$DSM_REPO/scripts/install_deps.sh" >/dev/null
build="$DSM_CACHE/build-fuzz"
# fuzzer-no-link: the libraries the fuzzers link get libFuzzer's coverage
# instrumentation too, so that it is guided by the readers' code, not only
# by the harness.
CC=clang CXX=clang++ cmake -S "$DSM_REPO" -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DDSM_FUZZ=ON -DDSM_SANITIZE=ON -DDSM_BUILD_CORE_TESTS=OFF -DDSM_NATIVE_ARCH=OFF \
  -DCMAKE_CXX_FLAGS=-fsanitize=fuzzer-no-link "${DSM_CMAKE_LAUNCHER[@]}" >/dev/null
cmake --build "$build" -j "$DSM_JOBS" --target fuzz_sequence_readers fuzz_image_message >/dev/null

work="$DSM_CACHE/fuzz"
mkdir -p "$work"
if [ ! -d "$work/seed_sequence" ]; then
  cmake --build "$build" -j "$DSM_JOBS" --target synthesize_sequence >/dev/null
  ASAN_OPTIONS=detect_leaks=0 "$build/synthesize_sequence" --scene "$DSM_REPO/data/middlebury/Dolls" \
    --output "$work/seed_sequence" --frames 2 --subframes 60 --hr-width 64 --hr-height 48 >/dev/null
fi
corpus="$work/corpus_readers"
mkdir -p "$corpus"
seq_dir="$work/seed_sequence"
seed() { { printf "\\x$(printf %02x "$1")"; cat "$2"; } > "$corpus/seed_$1_$(basename "$2")"; }
seed 0 "$seq_dir/camera.yaml"; seed 1 "$seq_dir/frames.csv"; seed 2 "$seq_dir/gt/poses.txt"
seed 3 "$seq_dir/gt/depth/000000.tiff"; seed 4 "$seq_dir/images/000000.png"
mkdir -p "$work/corpus_image"

status=0
for target in fuzz_sequence_readers fuzz_image_message; do
  corpus_dir="$corpus"
  [ "$target" = fuzz_image_message ] && corpus_dir="$work/corpus_image"
  mkdir -p "$work/$target"
  echo "== $target for $seconds s"
  set +e
  (cd "$work/$target" && ASAN_OPTIONS=detect_leaks=1 "$build/$target" -max_total_time="$seconds" \
     -max_len=65536 -rss_limit_mb=4096 -print_final_stats=1 "$corpus_dir" >"$work/$target.log" 2>&1)
  rc=$?
  set -e
  grep -E "^stat::number_of_executed_units|^stat::peak_rss_mb|^#[0-9]+ +DONE" "$work/$target.log" || true
  if [ $rc -ne 0 ]; then
    status=1
    echo "$target: FINDING (exit $rc); see $work/$target.log and $work/$target/crash-*"
    grep -m 5 -E "ERROR|SUMMARY|runtime error" "$work/$target.log" || true
  else
    echo "$target: no finding"
  fi
done
exit $status
