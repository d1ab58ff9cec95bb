# One summary row per filtered run of verify/examples/nonlinear_filter's N-run table, prefixed
# by `key` (awk -F'|' -v key=... [-v open=1] -f scripts/filter_rows.awk FILE): run, error mean
# [min, max], ANIS, % of steps with NIS / tip NEES above their bounds, 2σ coverage. With
# open=1 also the tier's open-loop error row. Used by scripts/heldout.sh and directions.sh.
/\| co-rotational \| open loop \|/ && open { printf "%s%-9s %s\n", key, "open", $5 }
/\| filtered, loads (given|withheld) \| .* of [0-9]+ \|/ && NF == 9 {
  run = $3; sub(/ *filtered, loads /, "", run); gsub(/ /, "", run)
  split($5, anis, ","); split($5, nis, "/"); split($6, nees, "/")
  sub(/ *%.*/, "", nis[3]); sub(/ *%.*/, "", nees[3])
  gsub(/^ +| +$/, "", $4); gsub(/^ +| +$/, "", $7); gsub(/^ +/, "", anis[1])
  printf "%s%-9s %-22s %-7s %-12s %-12s %s\n", key, run, $4, anis[1], nis[3] " %", nees[3] " %", $7
}
