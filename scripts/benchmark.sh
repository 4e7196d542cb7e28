#!/usr/bin/env bash
# Accuracy against peers on the motions users meet: synthesizes each bundled
# scene on each camera path with sensor noise (sigma 1 gray level), runs
# bicubic, OpenCV's BTV-L1, the package's baseline and joint, evaluates each
# against the ground truth and writes per-path tables into BENCHMARKS.md
# (between the benchmark markers) and into WORKDIR/tables.md.
#
# Paths (synthesize_sequence --path, docs/tools.md): lateral, arc, forward,
# handheld (non-constant velocity, rotation jitter), rolling (handheld with a
# rolling shutter, --readout-ratio 0.8) and gain (handheld with
# --gain-jitter 0.1). Every sequence: FRAMES frames, default size and blur,
# scale 2, --noise 1, seed SEED (0 unless DSM_BENCH_SEED says otherwise).
#
# Depth is written unmasked (estimate_sequence --depth-confidence-threshold 0)
# with its confidence maps and evaluated twice: as estimated, and as
# published by default (evaluate_sequence --confidence-threshold 0.5: NaN
# below the default threshold, exactly what the default estimate_sequence
# writes), each on the 70 % centre crop and on the full frame with coverage.
#
# Usage: scripts/benchmark.sh [WORKDIR]      (default: a fresh temporary folder)
# Env:   DSM_BENCH_SCENES="Aloe Dolls Moebius Reindeer"
#        DSM_BENCH_PATHS="lateral arc forward handheld rolling gain"
#        DSM_BENCH_FRAMES=10, DSM_BENCH_SEED=0 (synthesize_sequence --seed:
#        the noise, the hand-held path's shake and the gains),
#        DSM_BENCH_SKIP_BTV=1 (no BTV-L1: its runs take most of the time),
#        DSM_BENCH_SPEED=1 (also the 640x480 speed run),
#        DSM_BENCH_NO_UPDATE=1 (leave BENCHMARKS.md alone).
# A full run (4 scenes x 6 paths) without BTV-L1 took 10 min on 2 idle cores
# (2026-12-05, DSM_BENCH_SKIP_BTV=1: 48 method runs); BTV-L1 adds about 40 s
# per sequence.
set -eo pipefail
source "$(dirname "$0")/common.sh"

work="${1:-$(mktemp -d /tmp/dsm_benchmark.XXXXXX)}"
scenes="${DSM_BENCH_SCENES:-Aloe Dolls Moebius Reindeer}"
paths="${DSM_BENCH_PATHS:-lateral arc forward handheld rolling gain}"
frames="${DSM_BENCH_FRAMES:-10}"
seed="${DSM_BENCH_SEED:-0}"
threshold=0.5  # DepthConfidenceOptions::threshold, estimate_sequence's default
"$DSM_REPO/scripts/install_deps.sh" --core-only
dsm_build_plain >/dev/null
tool() { "$(dsm_tool "$1")" "${@:2}"; }

path_flags() {
  case "$1" in
    lateral | arc | forward | handheld) echo "--path $1" ;;
    rolling) echo "--path handheld --readout-ratio 0.8" ;;
    gain) echo "--path handheld --gain-jitter 0.1" ;;
    *) echo "benchmark: unknown path '$1'" >&2; return 1 ;;
  esac
}

evaluate() {  # name, dir: eval.json (as estimated) and eval_published.json
  local name="$1" dir="$2"
  tool evaluate_sequence --result "$dir/$name" --sequence "$dir/sequence" \
    --json "$dir/$name/eval.json" --method "$name" >/dev/null
  if [ -d "$dir/$name/depth_confidence" ]; then
    tool evaluate_sequence --result "$dir/$name" --sequence "$dir/sequence" --confidence-threshold "$threshold" \
      --json "$dir/$name/eval_published.json" --method "$name" >/dev/null
  fi
}

for path in $paths; do
  flags="$(path_flags "$path")"
  for scene in $scenes; do
    dir="$work/$path/$scene"
    mkdir -p "$dir"
    echo "== $path / $scene"
    # shellcheck disable=SC2086  # flags is a list of words
    tool synthesize_sequence --scene "$DSM_REPO/data/middlebury/$scene" --output "$dir/sequence" \
      --frames "$frames" --scale 2 --noise 1 --seed "$seed" $flags >/dev/null
    if [ -z "$DSM_BENCH_SKIP_BTV" ]; then
      echo "   btvl1"
      tool superres_btvl1 --input "$dir/sequence" --output "$dir/btvl1" --scale 2 >/dev/null
      evaluate btvl1 "$dir"
    fi
    for mode in baseline joint; do
      echo "   $mode"
      if ! tool estimate_sequence --input "$dir/sequence" --output "$dir/$mode" --mode "$mode" \
        --depth-confidence-threshold 0 --quiet >"$dir/$mode.log" 2>&1; then
        echo "   $mode failed: $(tail -n 1 "$dir/$mode.log")"
        continue
      fi
      evaluate "$mode" "$dir"
    done
  done
done

if [ -n "$DSM_BENCH_SPEED" ]; then
  # Speed at the size of issue 9's target: 10 frames 320x240 -> 640x480, the
  # paper's parameters (M 50, max_iter 3). The Dolls scene is seen with 1.8x
  # the focal length to fill 640x480 (softer texture; speed, not accuracy).
  speed="$work/speed_640x480"
  mkdir -p "$speed"
  echo "== speed: 10 frames 320x240 -> 640x480"
  tool synthesize_sequence --scene "$DSM_REPO/data/middlebury/Dolls" --output "$speed/sequence" \
    --scene-zoom 1.8 --hr-width 640 --hr-height 480 --frames 10 --scale 2 >/dev/null
  tool estimate_sequence --input "$speed/sequence" --output "$speed/joint" --quiet
  tool evaluate_sequence --result "$speed/joint" --sequence "$speed/sequence" \
    --json "$speed/joint/eval.json" --method joint >/dev/null
fi

python3 "$DSM_REPO/scripts/benchmark_tables.py" "$work" > "$work/tables.md"
stamp="$(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores, commit $(git -C "$DSM_REPO" rev-parse --short HEAD 2>/dev/null || echo '?')"
{
  echo "<!-- benchmark:begin -->"
  echo "Command: \`DSM_BENCH_SCENES=\"$scenes\" DSM_BENCH_PATHS=\"$paths\" DSM_BENCH_FRAMES=$frames${DSM_BENCH_SEED:+ DSM_BENCH_SEED=$seed}${DSM_BENCH_SKIP_BTV:+ DSM_BENCH_SKIP_BTV=1} scripts/benchmark.sh\` ($stamp)."
  echo
  cat "$work/tables.md"
  echo "<!-- benchmark:end -->"
} > "$work/section.md"
if [ -z "$DSM_BENCH_NO_UPDATE" ]; then
  python3 - "$DSM_REPO/BENCHMARKS.md" "$work/section.md" <<'PY'
import re, sys
path, section = sys.argv[1], open(sys.argv[2]).read().rstrip("\n")
text = open(path).read()
pattern = re.compile(r"<!-- benchmark:begin -->.*?<!-- benchmark:end -->", re.S)
text = pattern.sub(lambda _: section, text) if pattern.search(text) else text.rstrip("\n") + "\n\n## Against peers\n\n" + section + "\n"
open(path, "w").write(text)
PY
fi
cat "$work/tables.md"
echo "benchmark: results in $work${DSM_BENCH_NO_UPDATE:+ (BENCHMARKS.md left alone)}"
