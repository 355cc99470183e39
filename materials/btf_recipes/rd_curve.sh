#!/bin/sh
# The rate-distortion curve of docs/fitting.md ("Rate against distortion"): per BTF,
# one fit with many components per cluster, then packs at each byte budget
# (`meso pack trim --max-bytes`: per-cluster N_PCA, the components that remove the
# most table error) and, for comparison at equal bytes, the even split
# (`meso pack trim --npca K`, what `meso fit --npca K` keeps), each measured with
# `meso report fit --json`. A 48-component fit takes 26-106 s on 2 cores
# (2026-12-04), a report 25-110 s.
#   MESO=target/release/meso sh materials/btf_recipes/rd_curve.sh [NAME...]
# Environment: BTF_DIR (the synthesized BTFs, as rebuild.sh), OUT (results, default
# rd), CLUSTERS (default 8), CAP (components per cluster fitted, default 48),
# BUDGETS (bytes, default 1, 2, 4, 8 and 16 x 10^6), EVEN (the even splits'
# N_PCA, default 5 10; empty: none), PRECISION (the trimmed packs' residual
# precision, `meso pack trim --precision`: f16, f32 or i8; default the fit's f16;
# when set, the points' names end in _f16, _f32 or _i8).
set -eu
MESO=${MESO:-meso}
BTF_DIR=${BTF_DIR:-btf}
OUT=${OUT:-rd}
CLUSTERS=${CLUSTERS:-8}
CAP=${CAP:-48}
BUDGETS=${BUDGETS:-1000000 2000000 4000000 8000000 16000000}
EVEN=${EVEN-5 10}
PRECISION=${PRECISION:-}
tag="" precision=""
[ -z "$PRECISION" ] || { tag="_$PRECISION"; precision="--precision $PRECISION"; }
mkdir -p "$BTF_DIR" "$OUT"
for name in ${*:-woven_cloth grain_leather knitted_wool corduroy}; do
    btf="$BTF_DIR/$name.btf"
    [ -f "$btf" ] || "$MESO" btf synth "materials/btf_recipes/$name.toml" -o "$btf"
    big="$OUT/${name}_c${CLUSTERS}_p$CAP.spmm"
    [ -f "$big" ] || "$MESO" fit "$btf" -o "$big" --clusters "$CLUSTERS" --npca "$CAP" \
        --report "$OUT/${name}_c${CLUSTERS}_p$CAP.fit.json"
    points=""
    # A trim that would break the lobe bound (its residual no longer reaches the
    # BTF's brightest values, which the bound is relative to) is reported and skipped.
    for b in $BUDGETS; do
        # shellcheck disable=SC2086
        if "$MESO" pack trim "$big" -o "$OUT/${name}_c${CLUSTERS}${tag}_b$b.spmm" --max-bytes "$b" $precision; then
            points="$points c${CLUSTERS}${tag}_b$b"
        else
            echo "$name: no point at $b bytes" >&2
        fi
    done
    for k in $EVEN; do
        # shellcheck disable=SC2086
        if "$MESO" pack trim "$big" -o "$OUT/${name}_c${CLUSTERS}${tag}_k$k.spmm" --npca "$k" $precision; then
            points="$points c${CLUSTERS}${tag}_k$k"
        else
            echo "$name: no even split at N_PCA $k" >&2
        fi
    done
    for p in $points; do
        pack="$OUT/${name}_$p.spmm"
        [ -f "$OUT/${name}_$p.json" ] ||
            "$MESO" report fit "$btf" "$pack" -o "$OUT/${name}_$p" --json >"$OUT/${name}_$p.json"
    done
done
