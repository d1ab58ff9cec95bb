#!/usr/bin/env bash
# The co-rotational tier on loads in random directions (docs/results/tier.md §11): N unit
# directions drawn uniformly on the sphere (seeded), each a scenario ramping the load group
# LOAD to FRACTION × RANGE over RAMP s and holding it to DURATION s; the tier compiled once from
# SCENE_TIER, then verify/examples/nonlinear_filter (open loop, filtered with the loads given
# and withheld, 5 marker-noise draws) against the full-order co-rotational FEM of SCENE_REF.
# Prints one row per direction and run; full tables in OUT_DIR/dir-K.txt.
#
#   scripts/directions.sh OUT_DIR SCENE_REF SCENE_TIER LOAD RANGE "X Y Z" [N] [FRACTION] [RAMP] [DURATION]
#
# e.g. scripts/directions.sh /tmp/dirs models/cantilever/scene.toml \
#        models/cantilever/scene_corotational.toml tip 20 "1.0 0.05 0.05" 20 0.8 0.5 1.5
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?usage: see the header}; ref=$2; tier_scene=$3; load=$4; range=$5; point=($6)
n=${7:-20}; fraction=${8:-0.8}; ramp=${9:-0.5}; duration=${10:-1.5}
mkdir -p "$out"
cargo build --release -q --bin crokf-compile -p crokf-compile
cargo build --release -q -p crokf-verify --example nonlinear_filter
bin=target/release
tier=$out/tier.crokf
"$bin/crokf-compile" "$tier_scene" -o "$tier" > "$out/compile.log" 2>&1
python3 - "$out" "$n" "$load" "$range" "$fraction" "$ramp" "$duration" "${point[@]}" <<'PY'
import math, random, sys
out, n, load, rng, frac, ramp, dur, px, py, pz = sys.argv[1:]
random.seed(20261127)
for k in range(int(n)):
    v = [random.gauss(0, 1) for _ in range(3)]
    s = math.sqrt(sum(c * c for c in v))
    f = [float(frac) * float(rng) * c / s for c in v]
    with open(f"{out}/dir-{k:02d}.toml", "w") as fh:
        fh.write(f"# direction {k}: ({v[0]/s:+.3f}, {v[1]/s:+.3f}, {v[2]/s:+.3f}), "
                 f"{frac} of the range over {ramp} s, held\n")
        fh.write(f"# Schema: verify/src/scenario.rs.\nduration = {dur}\n\n[[load]]\n")
        fh.write(f'name = "{load}"\ntimes = [0.0, {ramp}]\n')
        fh.write(f"forces = [[0.0, 0.0, 0.0], [{f[0]:.6f}, {f[1]:.6f}, {f[2]:.6f}]]\n\n")
        fh.write(f'[[points]]\nname = "tip"\nposition = [{px}, {py}, {pz}]\n')
PY
printf '%-4s %-9s %-22s %-7s %-12s %-12s %s\n' dir loads "error mean [min, max]" ANIS "NIS above" "NEES above" "2σ coverage"
for s in "$out"/dir-*.toml; do
  k=$(basename "$s" .toml); k=${k#dir-}
  "$bin/examples/nonlinear_filter" "$ref" "$s" "$tier" \
    --reference-cache "$out/ref-$k.bin" --seeds 5 > "$out/dir-$k.txt" 2>&1
  awk -F'|' -v key="$(printf '%-4s ' "$k")" -v open=1 -f scripts/filter_rows.awk "$out/dir-$k.txt"
done
