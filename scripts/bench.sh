#!/usr/bin/env bash
# Speed against accuracy, one command (docs/RESULTS.md): builds bench/speed_accuracy, renders Blender
# Cycles sweeps of the built-in scenes (plain and with Cycles' adaptive sampling) and independent
# Cycles references, runs every scene x mode progressively with the error after every round, scores
# everything against both references (eprfarm's and Cycles'), and draws the charts and image strips.
#
#   scripts/bench.sh [--quick] [--out DIR] [--charts DIR] [--size N] [--spp P] [--ref-spp N]
#                    [--scenes "cornell conference hall wall glossy"] [--modes "pt rp skip exact"]
#                    [--cycles-scenes "cornell conference hall wall"] [--cycles-spp 1,2,4,...]
#                    [--cycles-adaptive-spp 8,16,...] [--big-cycles-spp 2,8,...]
#                    [--big-cycles-adaptive-spp 8,32,...] [--cycles-ref-spp N] [--big-cycles-ref-spp N]
#                    [--big-size 512] [--big-spp 64] [--big-ref-spp 512] [--big-modes "pt skip"]
#                    [--threads N] [--no-cycles | --cycles-only] [--no-big] [--no-build]
#
# Main sweep: every scene at --size, P = --spp, modes --modes, reference --ref-spp (cached in
# bench/cache by a hash of scene and settings). "Big": the Cornell box at --big-size (the Cycles
# comparison at 512 x 512), modes --big-modes, P = --big-spp. Cycles renders with --threads threads
# too (0 = all cores, for both). Glossy is never given to Cycles: its Phong lobe has no Cycles
# equivalent (the export drops it). Cycles' adaptive sweep: --cycles-adaptive-spp are maximum sample
# counts. Cycles references: --cycles-ref-spp (big: --big-cycles-ref-spp; default: as eprfarm's) as two halves of seeds 1000001 and
# 1000002, like eprfarm's, cached in bench/cache/ under a hash of the exported scene, size, spp, seed
# and Blender's version. --cycles-only renders the Cycles side into OUT and stops; a later run with
# --no-cycles and the same --out scores what is there. --quick: 64 x 64, P = 64, reference 256, big 128 x 128 P = 16.
# Outputs: OUT/{main,big}/csv/*.csv, tables.md, summary.json, strip/; charts (PNG + SVG) in --charts.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

OUT=bench/out CHARTS=docs/results SIZE=128 SPP=256 REF_SPP=1024
SCENES="cornell conference hall glossy wall" MODES="pt rp skip exact"
CYCLES_SCENES="cornell conference hall wall" CYCLES_SPP=1,2,4,8,16,32,64,128,256
CYCLES_ADAPTIVE_SPP=8,16,32,64,128,256
BIG_SIZE=512 BIG_SPP=64 BIG_REF_SPP=512 BIG_MODES="pt skip" BIG_CYCLES_SPP=2,8,32,128
BIG_CYCLES_ADAPTIVE_SPP=8,32,128
CY_REF_SPP='' BIG_CY_REF_SPP=''
THREADS=0 CYCLES=1 CYCLES_ONLY=0 BIG=1 BUILD=1
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) SIZE=64 SPP=64 REF_SPP=256 CYCLES_SPP=1,4,16,64 CYCLES_ADAPTIVE_SPP=16,64 BIG_SIZE=128
             BIG_SPP=16 BIG_REF_SPP=128 BIG_CYCLES_SPP=1,4,16 BIG_CYCLES_ADAPTIVE_SPP=16 ;;
    --out) OUT=$2; shift ;;
    --charts) CHARTS=$2; shift ;;
    --size) SIZE=$2; shift ;;
    --spp) SPP=$2; shift ;;
    --ref-spp) REF_SPP=$2; shift ;;
    --scenes) SCENES=$2; shift ;;
    --modes) MODES=$2; shift ;;
    --cycles-scenes) CYCLES_SCENES=$2; shift ;;
    --cycles-spp) CYCLES_SPP=$2; shift ;;
    --cycles-adaptive-spp) CYCLES_ADAPTIVE_SPP=$2; shift ;;
    --big-cycles-adaptive-spp) BIG_CYCLES_ADAPTIVE_SPP=$2; shift ;;
    --cycles-ref-spp) CY_REF_SPP=$2; shift ;;
    --big-cycles-ref-spp) BIG_CY_REF_SPP=$2; shift ;;
    --big-size) BIG_SIZE=$2; shift ;;
    --big-spp) BIG_SPP=$2; shift ;;
    --big-ref-spp) BIG_REF_SPP=$2; shift ;;
    --big-modes) BIG_MODES=$2; shift ;;
    --big-cycles-spp) BIG_CYCLES_SPP=$2; shift ;;
    --threads) THREADS=$2; shift ;;
    --no-cycles) CYCLES=0 ;;
    --cycles-only) CYCLES_ONLY=1 ;;
    --no-big) BIG=0 ;;
    --no-build) BUILD=0 ;;
    -h|--help) sed -n '2,26p' "$0"; exit 0 ;;
    *) echo "bench.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done

log() { echo "[bench $(date -u +%H:%M:%S) load $(cut -d' ' -f1 /proc/loadavg)] $*"; }
CPUS=$(nproc)
CY_THREADS=$THREADS
[ "$CY_THREADS" = 0 ] && CY_THREADS=$CPUS   # Cycles gets exactly the tracer's thread count

if [ "$BUILD" = 1 ]; then
  [ -f build/build.ninja ] || cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache >/dev/null
  log "building speed_accuracy"
  ninja -C build -j2 speed_accuracy >/dev/null
fi
SA=$ROOT/build/bench/speed_accuracy
[ -x "$SA" ] || { echo "bench.sh: $SA missing (drop --no-build)" >&2; exit 1; }
mkdir -p "$OUT" "$CHARTS"
OUT=$(cd "$OUT" && pwd)
log "start: $CPUS hardware threads, tracer threads ${THREADS/#0/all}, Cycles threads $CY_THREADS" | tee "$OUT/run.log"

specs() { for s in $1; do printf -- '--scene builtin:%s ' "$s"; done; }
modes() { for m in $1; do printf -- '--mode %s ' "$m"; done; }

export_obj() {  # scene; OUT/obj is emptied when a run starts, so a changed built-in is exported anew
  [ -f "$OUT/obj/$1.obj" ] || "$SA" --export-obj "$OUT/obj" --scene "builtin:$1" >/dev/null
}

cycles_sweep() {  # scene size spp-list [adaptive]
  local obj=$OUT/obj dir=$OUT/cycles/$1_$2x$2${4:+_adaptive} name=$1_$2${4:+_adaptive}
  export_obj "$1"
  log "cycles${4:+ adaptive}: $1 at $2x$2, spp $3, $CY_THREADS threads" | tee -a "$OUT/run.log"
  blender -b --factory-startup -noaudio -P scripts/cycles_sweep.py -- --obj "$obj/$1.obj" \
      --camera "$obj/$1.camera" --width "$2" --height "$2" --spp "$3" --threads "$CY_THREADS" \
      ${4:+--adaptive} --outdir "$dir" > "$OUT/cycles_$name.log" 2>&1 ||
    { tail -20 "$OUT/cycles_$name.log"; touch "$dir/done"; return 1; }
  grep '^cycles_sweep: spp' "$OUT/cycles_$name.log" | tee -a "$OUT/run.log"
}

# An independent Cycles reference of one scene: two halves of spp/2 (seeds 1000001, 1000002), cached
# in bench/cache/ and linked as OUT/cycles/SCENE_WxH_reference/{a,b}.exr for speed_accuracy.
cycles_reference() {  # scene size spp
  local obj=$OUT/obj dir=$OUT/cycles/$1_$2x$2_reference half=$(($3 / 2)) ab=a key seed file
  export_obj "$1"
  mkdir -p "$dir" bench/cache
  for seed in 1000001 1000002; do
    key=$( { cat "$obj/$1.obj" "$obj/$1.mtl" "$obj/$1.camera"; blender --version 2>/dev/null | head -1
             echo "$2x$2 spp=$half seed=$seed subdiv=16"; } | sha1sum | cut -c1-16)
    file=$ROOT/bench/cache/cycles_ref_$1_$2x$2_spp${half}_seed${seed}_$key.exr
    if [ ! -f "$file" ]; then
      log "cycles reference: $1 at $2x$2, $half spp, seed $seed" | tee -a "$OUT/run.log"
      # shellcheck disable=SC2046
      if ! blender -b --factory-startup -noaudio -P scripts/cycles_reference.py -- --obj "$obj/$1.obj" \
          --width "$2" --height "$2" --spp "$half" --seed "$seed" --threads "$CY_THREADS" \
          --out "$file.tmp.exr" $(cat "$obj/$1.camera") > "$OUT/cycles_ref_$1_$2_$seed.log" 2>&1; then
        tail -20 "$OUT/cycles_ref_$1_$2_$seed.log"; touch "$dir/done"; return 1
      fi
      mv "$file.tmp.exr" "$file"
    fi
    ln -sf "$file" "$dir/$ab.exr"
    ab=b
  done
  touch "$dir/done"
}

# Cycles renders alongside eprfarm's runs (in the background, one render at a time): both are timed
# in CPU seconds too, which the other process barely moves; speed_accuracy waits for each sweep's
# "done" file before scoring it.
CYCLES_PID=
if [ "$CYCLES" = 1 ]; then
  rm -rf "$OUT/cycles" "$OUT/obj"
  CY_SCENES=$(for s in $CYCLES_SCENES; do [ "$s" = glossy ] || echo "$s"; done)  # the Phong lobe has no Cycles equivalent
  for s in $CY_SCENES; do
    for d in "" _adaptive _reference; do mkdir -p "$OUT/cycles/${s}_${SIZE}x$SIZE$d"; done
  done
  [ "$BIG" = 1 ] && for d in "" _adaptive _reference; do mkdir -p "$OUT/cycles/cornell_${BIG_SIZE}x$BIG_SIZE$d"; done
  (
    # References first (cached after the first run): speed_accuracy waits for a scene's reference
    # before its runs, to score every round against it too.
    for s in $CY_SCENES; do cycles_reference "$s" "$SIZE" "${CY_REF_SPP:-$REF_SPP}" || true; done
    [ "$BIG" = 1 ] && { cycles_reference cornell "$BIG_SIZE" "${BIG_CY_REF_SPP:-$BIG_REF_SPP}" || true; }
    for s in $CY_SCENES; do
      cycles_sweep "$s" "$SIZE" "$CYCLES_SPP" || true
      cycles_sweep "$s" "$SIZE" "$CYCLES_ADAPTIVE_SPP" adaptive || true
    done
    if [ "$BIG" = 1 ]; then
      cycles_sweep cornell "$BIG_SIZE" "$BIG_CYCLES_SPP" || true
      cycles_sweep cornell "$BIG_SIZE" "$BIG_CYCLES_ADAPTIVE_SPP" adaptive || true
    fi
  ) &
  CYCLES_PID=$!
fi
if [ "$CYCLES_ONLY" = 1 ]; then
  [ -n "$CYCLES_PID" ] && wait "$CYCLES_PID"
  log "cycles only: done -> $OUT/cycles" | tee -a "$OUT/run.log"
  exit 0
fi

log "main sweep: $SCENES at ${SIZE}x$SIZE, P = $SPP, modes $MODES" | tee -a "$OUT/run.log"
# shellcheck disable=SC2046
"$SA" $(specs "$SCENES") $(modes "$MODES") --size "$SIZE" --spp "$SPP" --ref-spp "$REF_SPP" \
    --threads "$THREADS" --out "$OUT/main" --cycles "$OUT/cycles" | tee -a "$OUT/run.log"
if [ "$BIG" = 1 ]; then
  log "big: cornell at ${BIG_SIZE}x$BIG_SIZE, P = $BIG_SPP, modes $BIG_MODES" | tee -a "$OUT/run.log"
  # shellcheck disable=SC2046
  "$SA" --scene builtin:cornell $(modes "$BIG_MODES") --size "$BIG_SIZE" --spp "$BIG_SPP" \
      --ref-spp "$BIG_REF_SPP" --target "$BIG_SPP" --threads "$THREADS" --out "$OUT/big" --no-strip \
      --cycles "$OUT/cycles" | tee -a "$OUT/run.log"
fi

[ -n "$CYCLES_PID" ] && wait "$CYCLES_PID"
log "charts -> $CHARTS" | tee -a "$OUT/run.log"
bash bench/charts/make_charts.sh "$OUT" "$CHARTS"
log "done" | tee -a "$OUT/run.log"
