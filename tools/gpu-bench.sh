#!/usr/bin/env bash
# The GPU figures of issue 17, on a machine with a hardware GPU: the LB solver, the renderer and
# relighting, one JSON file per run under docs/bench/ (as the command printed it), named after
# the run and the UTC date. Put the figures in docs/PERFORMANCE.md afterwards.
#
#   tools/gpu-bench.sh            # all runs
#   RUNS=3 tools/gpu-bench.sh     # fewer frames per trace setting (default 5)
#   SYLVA=path/to/sylva tools/gpu-bench.sh   # a binary built elsewhere
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
bin=${SYLVA:-}
if [ -z "$bin" ]; then
  cargo build --release -p sylva-cli
  bin=target/release/sylva
fi
out=docs/bench
stamp=$(date -u +%Y%m%d)
mkdir -p "$out"

# Refuse to publish software-adapter figures as GPU figures: `auto` opens hardware GPUs only.
probe=$("$bin" bench lb --device auto --grid 8 --steps 2 --repeats 1 --json)
if ! grep -q '"device":"gpu"' <<<"$probe"; then
  echo "no hardware GPU found (bench lb --device auto ran on the CPU); nothing written" >&2
  exit 1
fi

run() {
  local name=$1
  shift
  echo "== $name: sylva $*"
  "$bin" "$@" --json >"$out/$name-$stamp.json"
}

run lb-gpu-128x256 bench lb --device gpu --grid 128 --steps 256
run lb-gpu-f16-128x256 bench lb --device gpu --precision f16 --grid 128 --steps 256
run lb-gpu-256x512 bench lb --device gpu --grid 256 --steps 512
run lb-gpu-cloud bench lb --device gpu --medium cloud
for scene in catalpa beech canopy; do
  # The first run solves the scene's LB lighting on the GPU and caches it (lb_seconds).
  run "trace-gpu-$scene" bench trace "$scene" --device gpu --runs "${RUNS:-5}"
  run "trace-gpu-paper-$scene" bench trace "$scene" --device gpu --light paper --runs "${RUNS:-5}"
done
for scene in catalpa beech; do
  run "trace-cpu$(nproc)-$scene" bench trace "$scene" --device cpu --runs "${RUNS:-5}"
done
# Solves each model's 54 base solutions on the GPU first (cached afterwards).
run relight-gpu-catalpa bench relight catalpa --device gpu --runs 3
run relight-gpu-canopy bench relight canopy --device gpu --runs 3
ls -l "$out"/*-"$stamp".json
