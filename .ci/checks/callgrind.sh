#!/usr/bin/env bash
# CI guard: instruction counts (callgrind Ir, one rayon thread) of two fixed workloads, against
# the committed baselines in .ci/callgrind-baseline.txt. Fails if a count grows by more than 10%.
# Instruction counts do not depend on how loaded the machine is, unlike wall time.
#
#   relax:   examples/relax_probe.rs, a ~10k-vertex anchored skin tube, 100 NCG iterations
#            (whole program);
#   contact: examples/contact_probe.rs, the bench's tube-10k skin over the 50k-triangle deforming
#            muscle and two capsules, 3 frames of plans and 100 projection passes each (only
#            the muscle's `ColliderMesh::set_vertices`, `SkinCollision::advance_frame` and
#            `project` are counted, not the set-up: the muscle's BVH parts are refitted by the
#            first queries that reach them, so its refresh and the contact work share the refits).
#
#   bash .ci/checks/callgrind.sh           # check
#   bash .ci/checks/callgrind.sh --update  # rewrite the baselines (commit them, say why)
set -euo pipefail
cd "$(dirname "$0")/../.."
baseline_file=.ci/callgrind-baseline.txt
tolerance=0.10

if ! command -v valgrind >/dev/null 2>&1; then
  echo "callgrind: installing valgrind"
  sudo_cmd=""
  if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1; then sudo_cmd="sudo"; fi
  $sudo_cmd apt-get update -qq >/dev/null
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq valgrind >/dev/null
fi

cargo build --release --quiet --example relax_probe --example contact_probe
out_dir=$(mktemp -d)
trap 'rm -rf "$out_dir"' EXIT

# measure NAME [valgrind options...] -- COMMAND...: prints the instruction count.
measure() {
  local name=$1
  shift
  local opts=()
  while [ "$1" != "--" ]; do
    opts+=("$1")
    shift
  done
  shift
  RAYON_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file="$out_dir/$name.out" \
    "${opts[@]}" "$@" >"$out_dir/$name.stdout" 2>"$out_dir/$name.stderr" || {
    cat "$out_dir/$name.stderr" >&2
    exit 1
  }
  cat "$out_dir/$name.stdout" >&2
  local count
  count=$(awk '/^summary:/ { print $2 }' "$out_dir/$name.out")
  if [ -z "$count" ]; then
    echo "callgrind: no instruction count in the $name output" >&2
    exit 1
  fi
  echo "$count"
}

relax=$(measure relax -- target/release/examples/relax_probe 10000 100)
contact=$(measure contact \
  "--toggle-collect=dermis::collision::collider::ColliderMesh::set_vertices" \
  "--toggle-collect=dermis::collision::SkinCollision::advance_frame" \
  "--toggle-collect=<dermis::collision::SkinCollision as dermis::solver::Projection>::project" \
  -- target/release/examples/contact_probe 10000 3 100)

if [ "${1:-}" = "--update" ]; then
  {
    echo "# Instructions (callgrind Ir, RAYON_NUM_THREADS=1) per workload; see .ci/checks/callgrind.sh."
    echo "# Checked there (fails above +$(awk -v t="$tolerance" 'BEGIN { print t * 100 }')%). Update with --update, say why in the commit."
    echo "relax $relax"
    echo "contact $contact"
  } >"$baseline_file"
  echo "callgrind: baselines updated: relax $relax, contact $contact instructions"
  exit 0
fi

status=0
for name in relax contact; do
  count=${!name}
  baseline=$(awk -v n="$name" '$1 == n { print $2 }' "$baseline_file")
  if [ -z "$baseline" ]; then
    echo "callgrind: no $name baseline in $baseline_file" >&2
    exit 1
  fi
  awk -v n="$name" -v c="$count" -v b="$baseline" -v t="$tolerance" 'BEGIN {
    ratio = c / b
    printf "callgrind %s: %d instructions, baseline %d, ratio %.4f (limit %.2f)\n", n, c, b, ratio, 1 + t
    if (ratio > 1 + t) {
      printf "callgrind: %s got more expensive; if that is intended, run with --update and say why in the commit\n", n > "/dev/stderr"
      exit 1
    }
  }' || status=1
done
exit $status
