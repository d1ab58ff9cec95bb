#!/usr/bin/env bash
# A marker lost for 100 steps on the held-out bodies (docs/results/verification.md, "A marker lost for
# 100 steps"): each body's tip marker (nonlinear_filter's, the one that moves most: the one
# nearest the load) gives no value for records FROM … FROM + STEPS − 1 of the press and the
# reversal, loads given and withheld, 20 noise draws (verify/examples/nonlinear_filter with
# --marker-lost :FROM:STEPS and any further FLAGS, e.g. --stored-gains). Uses the tiers and the cached
# full-order references that scripts/heldout.sh wrote to OUT_DIR (run it first). Prints the
# summary rows and the before / lost / after rows; full tables in OUT_DIR/lost-BODY-SCENARIO.txt.
#
#   scripts/lost_marker.sh OUT_DIR [FROM] [STEPS] [FLAGS ...]   # default: 75 100
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?usage: scripts/lost_marker.sh OUT_DIR [FROM] [STEPS] [FLAGS ...]}
from=${2:-75}
steps=${3:-100}
shift $(($# < 3 ? $# : 3))
flags=("$@")
cargo build --release -q -p crokf-verify --example nonlinear_filter
for b in kidney horn mushroom arch paddle blob; do
  d=models/bodies/$b
  tier=$out/$b-tier.crokf
  [ -f "$tier" ] || { echo "no $tier: run scripts/heldout.sh $out first" >&2; exit 1; }
  for name in press reverse; do
    s=$d/scenario_$name.toml
    key=$(cat "$d/scene_linear.toml" "$d/$b.msh" "$s" | sha256sum | cut -c1-16)
    f=$out/lost-$b-$name.txt
    target/release/examples/nonlinear_filter \
      "$d/scene_linear.toml" "$s" "$tier" --reference-cache "$out/ref-$key.bin" --seeds 20 --marker-lost ":$from:$steps" ${flags[@]+"${flags[@]}"} > "$f" 2>&1
    awk -F'|' -v key="$(printf '%-9s %-8s ' "$b" "$name")" -f scripts/filter_rows.awk "$f"
    grep -h "refused:" "$f" | cut -d'|' -f4,5 | sed "s/^/$(printf '%-9s %-8s ' "$b" "$name")/" || true
    grep -h "| lost |\|| after |" "$f" \
      | awk -F'|' -v key="$(printf '%-9s %-8s ' "$b" "$name")" '{printf "%s%s %s: NIS %s  tip NEES %s  coverage %s\n", key, $3, $4, $6, $7, $8}' || true
  done
done
