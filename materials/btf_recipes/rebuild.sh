#!/bin/sh
# Rebuilds the fitted packs in materials/ from their BTF recipes (docs/fitting.md):
# synthesizes each BTF (kept in $BTF_DIR, 161 MB each, not committed) and fits the
# pack with the settings below. Deterministic: the same Meso writes the same bytes.
#   MESO=target/release/meso sh materials/btf_recipes/rebuild.sh [NAME...]
set -eu
MESO=${MESO:-meso}
BTF_DIR=${BTF_DIR:-btf}
mkdir -p "$BTF_DIR"
for name in ${*:-knitted_wool woven_cloth grain_leather corduroy}; do
    # Per pack: clusters and N_PCA, and optionally a byte budget the fit is trimmed
    # to (`meso pack trim`: per-cluster N_PCA; the best point under 4 MB of the curve
    # in docs/fitting.md); everything else is `meso fit`'s default (seed 0).
    trim=""
    case "$name" in
        woven_cloth | knitted_wool | corduroy) settings="--clusters 8 --npca 48" trim="--max-bytes 4000000 --precision i8" ;;
        # Fewer, larger clusters pay for the leather (docs/fitting.md, "Fewer clusters").
        grain_leather) settings="--clusters 3 --npca 80" trim="--max-bytes 4000000 --precision i8" ;;
        *) echo "unknown pack $name" >&2; exit 2 ;;
    esac
    btf="$BTF_DIR/$name.btf"
    [ -f "$btf" ] || "$MESO" btf synth "materials/btf_recipes/$name.toml" -o "$btf"
    out="materials/$name.spmm"
    [ -z "$trim" ] || out="$BTF_DIR/$name.fit.spmm"
    # shellcheck disable=SC2086
    "$MESO" fit "$btf" -o "$out" $settings --report "$BTF_DIR/$name.fit.json"
    # shellcheck disable=SC2086
    [ -z "$trim" ] || "$MESO" pack trim "$out" -o "materials/$name.spmm" $trim
done
