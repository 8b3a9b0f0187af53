#!/usr/bin/env bash
# CI guard: the instruction count of a fixed relaxation (examples/relax_probe.rs: a ~10k-vertex
# anchored skin tube, 100 NCG iterations, one rayon thread) under callgrind, against the committed
# baseline in .ci/callgrind-baseline.txt. Fails if the count grows by more than 10%. Instruction
# counts do not depend on how loaded the machine is, unlike wall time.
#
#   bash .ci/checks/callgrind.sh           # check
#   bash .ci/checks/callgrind.sh --update  # rewrite the baseline (commit it, say why)
set -euo pipefail
cd "$(dirname "$0")/../.."
baseline_file=.ci/callgrind-baseline.txt
vertices=10000
iterations=100
tolerance=0.10

if ! command -v valgrind >/dev/null 2>&1; then
  echo "callgrind: installing valgrind"
  sudo_cmd=""
  if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1; then sudo_cmd="sudo"; fi
  $sudo_cmd apt-get update -qq >/dev/null
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq valgrind >/dev/null
fi

cargo build --release --quiet --example relax_probe
out_dir=$(mktemp -d)
trap 'rm -rf "$out_dir"' EXIT
RAYON_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file="$out_dir/callgrind.out" \
  target/release/examples/relax_probe "$vertices" "$iterations" >"$out_dir/stdout" 2>"$out_dir/stderr" || {
  cat "$out_dir/stderr" >&2
  exit 1
}
count=$(awk '/^summary:/ { print $2 }' "$out_dir/callgrind.out")
if [ -z "$count" ]; then
  echo "callgrind: no instruction count in the callgrind output" >&2
  exit 1
fi
cat "$out_dir/stdout"

if [ "${1:-}" = "--update" ]; then
  {
    echo "# Instructions (callgrind Ir) of: RAYON_NUM_THREADS=1 target/release/examples/relax_probe $vertices $iterations"
    echo "# Checked by .ci/checks/callgrind.sh (fails above +$(awk -v t="$tolerance" 'BEGIN { print t * 100 }')%). Update with --update, say why in the commit."
    echo "$count"
  } >"$baseline_file"
  echo "callgrind: baseline updated to $count instructions"
  exit 0
fi

baseline=$(grep -v '^#' "$baseline_file" | head -n 1 | tr -d '[:space:]')
awk -v c="$count" -v b="$baseline" -v t="$tolerance" 'BEGIN {
  ratio = c / b
  printf "callgrind: %d instructions, baseline %d, ratio %.4f (limit %.2f)\n", c, b, ratio, 1 + t
  if (ratio > 1 + t) {
    print "callgrind: the relaxation got more expensive; if that is intended, run with --update and say why in the commit" > "/dev/stderr"
    exit 1
  }
}'
