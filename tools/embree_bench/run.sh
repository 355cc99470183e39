#!/usr/bin/env bash
# Embree 4 on the rays of `meso bench rays`: builds embree_bench against the Embree
# library of PyPI's `embreex` wheel (installed into a throwaway virtual environment),
# writes the rays with `meso bench rays --save-rays`, and times Embree on them.
# usage: tools/embree_bench/run.sh MESO_BINARY MESH.obj [THREADS] [low|medium|high]
set -euo pipefail
meso=$1 mesh=$2 threads=${3:-1} quality=${4:-medium}
here=$(cd "$(dirname "$0")" && pwd)
work=${EMBREE_BENCH_DIR:-/tmp/meso_embree_bench}
mkdir -p "$work"
if [ ! -d "$work/venv" ]; then
  python3 -m venv "$work/venv"
  "$work/venv/bin/pip" install -q 'embreex==4.4.0.post1'
fi
libs=$(echo "$work"/venv/lib/python3*/site-packages/embreex.libs)
lib=$(ls "$libs"/libembree4*.so*)
cc -O2 -o "$work/embree_bench" "$here/embree_bench.c" "$lib" -Wl,-rpath,"$libs" -lm -lpthread
rays="$work/rays_$(basename "$mesh" .obj)"
"$meso" bench rays "$mesh" --threads "$threads" --save-rays "$rays"
"$work/embree_bench" "$rays" "$threads" "$quality"
