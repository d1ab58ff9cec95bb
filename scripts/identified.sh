#!/usr/bin/env bash
# The noise identified from a recording on the held-out bodies of models/bodies/
# (docs/identify.md): for each body, compile its co-rotational tier from scene_corotational.toml
# (reused from OUT_DIR when there), simulate a recording of scenario_RECORDING (full-order
# co-rotational FEM, the scene's markers + noise of their σ, seed 7, the loads given), identify
# its noise (verify/examples/identify_noise.rs, --lags 10) into a copy of the scene, and filter
# every scenario with the tier refiltered for that copy, 20 noise draws, loads given and
# withheld. Prints the verdict and one summary row per run; full outputs in OUT_DIR.
#
#   scripts/identified.sh OUT_DIR RECORDING [BODY ...]    # RECORDING: press, step, …
#
# The identified copy is written in the body's folder (its mesh path is relative), saved to
# OUT_DIR/BODY-from-RECORDING.toml and removed after the runs. References cached as in heldout.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?usage: scripts/identified.sh OUT_DIR RECORDING [BODY ...]}
rec=${2:?usage: scripts/identified.sh OUT_DIR RECORDING [BODY ...]}
shift 2
bodies=("$@")
[ ${#bodies[@]} -gt 0 ] || bodies=(kidney horn mushroom arch paddle blob)
mkdir -p "$out"
cargo build --release -q --bin crokf-compile -p crokf-compile
cargo build --release -q -p crokf-verify --example nonlinear_filter --example identify_noise
bin=target/release
copy=
trap '[ -n "$copy" ] && rm -f "$copy"' EXIT
ref() { # BODY SCENARIO -> reference cache file
  local d=models/bodies/$1
  echo "$out/ref-$(cat "$d/scene_linear.toml" "$d/$1.msh" "$d/scenario_$2.toml" | sha256sum | cut -c1-16).bin"
}
for b in "${bodies[@]}"; do
  d=models/bodies/$b
  tier=$out/$b-tier.crokf
  [ -f "$tier" ] || "$bin/crokf-compile" "$d/scene_corotational.toml" -o "$tier" > "$out/$b-compile.log" 2>&1
  copy=$d/.identified-$$.toml
  "$bin/examples/identify_noise" "$d/scene_corotational.toml" \
    "$d/scenario_$rec.toml" "$tier" --reference-cache "$(ref "$b" "$rec")" --given --lags 10 -o "$copy" > "$out/$b-identify-$rec.txt" 2>&1 || true
  printf '%-9s %s\n' "$b" "$(grep '^verdict' "$out/$b-identify-$rec.txt" || tail -n 1 "$out/$b-identify-$rec.txt")"
  [ -f "$copy" ] || continue
  cp "$copy" "$out/$b-from-$rec.toml"
  for s in "$d"/scenario_*.toml; do
    name=$(basename "$s" .toml); name=${name#scenario_}
    "$bin/examples/nonlinear_filter" \
      "$d/scene_linear.toml" "$s" "$tier@$copy" --reference-cache "$(ref "$b" "$name")" --seeds 20 > "$out/$b-$name-from-$rec.txt" 2>&1
    awk -F'|' -v key="$(printf '%-9s %-8s ' "$b" "$name")" -f scripts/filter_rows.awk \
      "$out/$b-$name-from-$rec.txt"
  done
  rm -f "$copy"; copy=
done
