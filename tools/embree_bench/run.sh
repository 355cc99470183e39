#!/usr/bin/env bash
# Embree 4 beside the tracer on the rays of `meso bench rays`: installs PyPI's `embreex`
# wheel (Embree 4.4.0 with its TBB) in a virtual environment and runs
# `meso bench rays MESH --embree LIB`, which loads that library and times both in one
# process, alternating (README.md).
# usage: tools/embree_bench/run.sh MESO_BINARY MESH.obj [THREADS] [meso bench rays options...]
set -euo pipefail
meso=$1 mesh=$2 threads=${3:-1}
shift $(($# < 3 ? $# : 3))
work=${EMBREE_BENCH_DIR:-/tmp/meso_embree_bench}
mkdir -p "$work"
if [ ! -d "$work/venv" ]; then
  python3 -m venv "$work/venv"
  "$work/venv/bin/pip" install -q 'embreex==4.4.0.post1'
fi
lib=$(ls "$work"/venv/lib/python3*/site-packages/embreex.libs/libembree4*.so* | head -n 1)
"$meso" bench rays "$mesh" --threads "$threads" --embree "$lib" "$@"
