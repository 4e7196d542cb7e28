#!/usr/bin/env bash
# Speed side by side (not a test; results go to BENCHMARKS.md, "Speed"):
# builds a reference commit and the current checkout, synthesizes (with the
# current synthesize_sequence) 10-frame 320x240 -> 640x480 sequences and runs
# the reference estimate_sequence, then the current one, on each, one right
# after the other, with default parameters. Prints a Markdown table: wall
# time, CPU seconds (user + sys; CPU / wall = cores busy) and peak RSS of both, the ratio old/new, PSNR / depth rel. error / ATE
# of both (current evaluate_sequence: accuracy must not move) and the top
# stages of report.json's stage_seconds.
#
# Sequences (DSM_SPEED_SEQUENCES, default all four):
#   dolls            scripts/benchmark.sh's speed sequence (Dolls, 1.8x zoom)
#   handheld_gray    hand-held path (rotates and translates) over the near
#                    Reindeer scene, converted to gray
#   handheld_colour  the same in colour
#   handheld_rolling the same path with a rolling shutter (readout 0.8 x the
#                    frame interval, sensor.yaml)
# A reference commit that does not read sensor.yaml estimates the rolling
# sequence as if its shutter were global; the table says so.
#
# Usage: scripts/benchmark_speed.sh [REFERENCE_COMMIT [WORK_DIR]]
# Env: DSM_SPEED_REFERENCE (default 175f35b), DSM_SPEED_SEQUENCES,
#   DSM_SPEED_FRAMES (10), DSM_SPEED_SIZE ("640 480", HR), DSM_SPEED_ARGS
#   (extra estimate_sequence flags for both, e.g. "--iterations 1"),
#   DSM_SPEED_NEW_ARGS (flags for the current build's runs only, e.g. the
#   faster settings "--iterations 2 --no-depth-sweep" that the reference
#   does not know),
#   DSM_SPEED_CURRENT_BUILD (a build folder to take the "new" tools from
#   instead of building this checkout) and DSM_SPEED_CURRENT_LABEL (its
#   commit, for the header), DSM_SPEED_PERF=1 (each run under `perf record
#   -F 99`; the top functions by self time go to WORK_DIR/NAME/{old,new}.perf.txt).
# The tools of both builds are copied into WORK_DIR/bin first, so a rebuild
# during the run does not change what is measured.
set -eo pipefail
source "$(dirname "$0")/common.sh"

reference="${1:-${DSM_SPEED_REFERENCE:-175f35b}}"
work="${2:-$(mktemp -d /tmp/dsm_benchmark_speed.XXXXXX)}"
sequences="${DSM_SPEED_SEQUENCES:-dolls handheld_gray handheld_colour handheld_rolling}"
# handheld_gray converts its inputs with Debian's ImageMagick (scripts/install_deps.sh --viewer).
if [[ " $sequences " == *" handheld_gray "* ]] && ! dpkg-query -W -f='${Status}' imagemagick 2>/dev/null | grep -q "install ok installed"; then
  echo "benchmark_speed: handheld_gray needs ImageMagick: run scripts/install_deps.sh --viewer (or leave it out of DSM_SPEED_SEQUENCES)" >&2
  exit 1
fi
frames="${DSM_SPEED_FRAMES:-10}"
read -r width height <<<"${DSM_SPEED_SIZE:-640 480}"
read -r -a extra_args <<<"${DSM_SPEED_ARGS:-}"
read -r -a new_args <<<"${DSM_SPEED_NEW_ARGS:-}"
tools=(synthesize_sequence estimate_sequence evaluate_sequence)
mkdir -p "$work/bin/old" "$work/bin/new"

# The reference: its source by `git archive` into a folder of the cache
# (kept, so the next run builds nothing), a plain Release build of the tool.
reference_hash="$(git -C "$DSM_REPO" rev-parse --short=10 "$reference^{commit}")"
reference_dir="$DSM_CACHE/speed_reference/$reference_hash"
if [ ! -x "$reference_dir/build/estimate_sequence" ]; then
  echo "== building the reference $reference_hash in $reference_dir" >&2
  rm -rf "$reference_dir/src" && mkdir -p "$reference_dir/src"
  git -C "$DSM_REPO" archive "$reference_hash" | tar -x -C "$reference_dir/src"
  CCACHE_BASEDIR="$reference_dir" cmake -S "$reference_dir/src" -B "$reference_dir/build" \
    -DCMAKE_BUILD_TYPE=Release "${DSM_CMAKE_LAUNCHER[@]}" >/dev/null
  CCACHE_BASEDIR="$reference_dir" cmake --build "$reference_dir/build" --target estimate_sequence \
    -j "$DSM_JOBS" >"$reference_dir/build.log" 2>&1 || { tail -n 30 "$reference_dir/build.log"; exit 1; }
fi
cp "$reference_dir/build/estimate_sequence" "$work/bin/old/"

# The current checkout.
current_build="${DSM_SPEED_CURRENT_BUILD:-$DSM_PLAIN_BUILD}"
if [ -z "$DSM_SPEED_CURRENT_BUILD" ]; then
  echo "== building the current checkout in $current_build" >&2
  cmake -S "$DSM_REPO" -B "$current_build" -DCMAKE_BUILD_TYPE=Release "${DSM_CMAKE_LAUNCHER[@]}" >/dev/null
  cmake --build "$current_build" --target "${tools[@]}" -j "$DSM_JOBS" >/dev/null
fi
for t in "${tools[@]}"; do cp "$current_build/$t" "$work/bin/new/"; done
current_commit="$(git -C "$DSM_REPO" rev-parse --short HEAD)"
[ -n "$(git -C "$DSM_REPO" status --porcelain --untracked-files=no)" ] && current_commit="$current_commit+changes"
current_commit="${DSM_SPEED_CURRENT_LABEL:-$current_commit}"

# Whether the reference reads a rolling shutter's sensor.yaml.
reference_reads_sensor=no
git -C "$DSM_REPO" grep -q "sensor.yaml" "$reference_hash" -- src && reference_reads_sensor=yes

synthesize() {  # name, output folder
  local scene=Reindeer path=(--path handheld --seed 3) extra=()
  case "$1" in
    dolls) scene=Dolls path=() ;;
    handheld_gray | handheld_colour) ;;
    handheld_rolling) extra=(--readout-ratio 0.8) ;;
    *) echo "benchmark_speed: unknown sequence $1" >&2; return 1 ;;
  esac
  rm -rf "$2"
  "$work/bin/new/synthesize_sequence" --scene "$DSM_REPO/data/middlebury/$scene" --output "$2" \
    --scene-zoom 1.8 --hr-width "$width" --hr-height "$height" --frames "$frames" --scale 2 \
    "${path[@]}" "${extra[@]}" >/dev/null
  if [ "$1" = handheld_gray ]; then  # the inputs only; evaluation compares in gray
    for image in "$2"/images/*.png; do convert "$image" -colorspace Gray -type Grayscale "$image"; done
  fi
}

# Runs one estimate_sequence under /usr/bin/time: WHICH (old|new), sequence, output.
estimate() {
  rm -rf "$3"
  local profiler=() which_args=()
  [ "$1" = new ] && which_args=("${new_args[@]}")
  [ -n "$DSM_SPEED_PERF" ] && profiler=(perf record -F 99 -o "$3.perf.data" --)
  /usr/bin/time -f "%e %U %S %M" -o "$3.time" "${profiler[@]}" "$work/bin/$1/estimate_sequence" --input "$2" \
    --output "$3" --quiet "${extra_args[@]}" "${which_args[@]}" >"$3.log" 2>&1 ||
    { echo "failed: $(tail -n 1 "$3.log")" >"$3.failed"; return 0; }
  "$work/bin/new/evaluate_sequence" --result "$3" --sequence "$2" --json "$3.eval.json" >/dev/null
  if [ -n "$DSM_SPEED_PERF" ]; then
    perf report -i "$3.perf.data" --no-children --sort symbol --stdio 2>/dev/null |
      awk '!/^#/ && NF && n++ < 15' >"$3.perf.txt"
  fi
}

# One table row from the two runs of a sequence.
row() {  # name, sequence dir
  /usr/bin/python3 - "$1" "$2" "$reference_reads_sensor" <<'PY'
import json, os, sys
name, folder, reads_sensor = sys.argv[1:4]
def run(which):
    out = os.path.join(folder, which)
    if os.path.exists(out + ".failed"):
        return None
    wall, user, system, rss_kib = open(out + ".time").read().split()[-4:]
    mean = json.load(open(out + ".eval.json"))["mean"]
    stages = json.load(open(os.path.join(out, "report.json")))["stage_seconds"]
    top = sorted(stages.items(), key=lambda kv: -kv[1])[:4]
    return dict(wall=float(wall), cpu=float(user) + float(system), rss=int(rss_kib) / 2**20, mean=mean,
                stages=", ".join("%s %.1f" % (k, v) for k, v in top))
def num(v, fmt):
    return "n/a" if v is None else fmt % v
old, new = run("old"), run("new")
label = name
if name == "handheld_rolling" and reads_sensor == "no":
    label += " (reference: global-shutter model)"
if old is None or new is None:
    print("| %s | %s |" % (label, "a run failed: see %s/{old,new}.log" % folder))
    sys.exit(0)
def pair(key, fmt):
    return "%s / %s" % (num(old["mean"].get(key), fmt), num(new["mean"].get(key), fmt))
print("| %s | %.1f | %.1f | **%.2fx** | %.1f / %.1f | %.2f / %.2f | %.2f / %.2f | %s | %s | %s | %s | %s |" % (
    label, old["wall"], new["wall"], old["wall"] / new["wall"], old["cpu"], new["cpu"],
    old["cpu"] / old["wall"], new["cpu"] / new["wall"], old["rss"], new["rss"],
    pair("image_psnr_db", "%.2f"), pair("depth_relative_error", "%.4f"), pair("ate_rmse", "%.5f"),
    old["stages"], new["stages"]))
PY
}

dsm_benchmark_header
echo "Reference $reference_hash (reads sensor.yaml: $reference_reads_sensor) against $current_commit;" \
  "$frames frames, HR ${width}x${height} (LR = HR / 2), defaults${DSM_SPEED_ARGS:+ + $DSM_SPEED_ARGS}${DSM_SPEED_NEW_ARGS:+ (current only: $DSM_SPEED_NEW_ARGS)}; work: $work"
echo
echo "| Sequence | Wall old (s) | Wall new (s) | Old / new | CPU old / new (s) | Cores busy old / new | Peak RSS old / new (GiB) | PSNR old / new (dB) | Depth rel. old / new | ATE old / new | Top stages old (s) | Top stages new (s) |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|"
for name in $sequences; do
  dir="$work/$name"
  mkdir -p "$dir"
  synthesize "$name" "$dir/sequence"
  estimate old "$dir/sequence" "$dir/old"
  estimate new "$dir/sequence" "$dir/new"
  row "$name" "$dir"
done
