#!/usr/bin/env bash
# Estimation on the held-out bodies of models/bodies/ (docs/results/verification.md): for each body,
# compile its co-rotational tier from scene_corotational.toml as written (force σ derived by the
# compiler) and run the filter over each scenario with 20 marker-noise draws, loads given and
# withheld (verify/examples/nonlinear_filter.rs). Prints one summary row per run; the full
# tables (per segment, advice) are in OUT_DIR/BODY-SCENARIO.txt.
#
#   scripts/heldout.sh OUT_DIR [BODY ...] [-- FLAGS ...]   # default: every body
#
# FLAGS go to every nonlinear_filter run (e.g. -- --stored-gains).
#
# Full-order references are cached in OUT_DIR/ref-*.bin (reused while scene and scenario are
# unchanged). About 5 minutes per body on two cores.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?usage: scripts/heldout.sh OUT_DIR [BODY ...] [-- FLAGS ...]}
shift
bodies=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do bodies+=("$1"); shift; done
[ $# -gt 0 ] && shift
flags=("$@")
[ ${#bodies[@]} -gt 0 ] || bodies=(kidney horn mushroom arch paddle blob)
mkdir -p "$out"
cargo build --release -q --bin crokf-compile -p crokf-compile
cargo build --release -q -p crokf-verify --example nonlinear_filter
bin=target/release
printf '%-9s %-8s %-9s %-22s %-7s %-12s %-12s %s\n' body scenario loads "error mean [min, max]" ANIS "NIS above" "NEES above" "2σ coverage mean [min, max]"
for b in "${bodies[@]}"; do
  d=models/bodies/$b
  tier=$out/$b-tier.crokf
  "$bin/crokf-compile" "$d/scene_corotational.toml" -o "$tier" > "$out/$b-compile.log" 2>&1
  for s in "$d"/scenario_*.toml; do
    name=$(basename "$s" .toml); name=${name#scenario_}
    key=$(cat "$d/scene_linear.toml" "$d/$b.msh" "$s" | sha256sum | cut -c1-16)
    "$bin/examples/nonlinear_filter" \
      "$d/scene_linear.toml" "$s" "$tier" --reference-cache "$out/ref-$key.bin" --seeds 20 ${flags[@]+"${flags[@]}"} > "$out/$b-$name.txt" 2>&1
    awk -F'|' -v key="$(printf '%-9s %-8s ' "$b" "$name")" -f scripts/filter_rows.awk \
      "$out/$b-$name.txt"
  done
done
