#!/usr/bin/env bash
# Paired comparison of two `dermis` binaries on `dermis bench --json`: runs them alternated
# (A B, B A, A B, ...) so the machine's drift hits both alike, and prints one line per run with
# the tube-10k and tube-100k figures. Compare runs within a pair only.
#
#   benches/scripts/abba_bench.sh PAIRS BIN_A BIN_B
#
# Uses `chrt -f 10` where allowed (root), else plain runs. Needs python3.
set -euo pipefail
pairs=$1
a=$2
b=$3
out=$(mktemp)
trap 'rm -f "$out"' EXIT
run() {
  RAYON_NUM_THREADS=2 chrt -f 10 "$1" bench --json 2>/dev/null >"$out" ||
    RAYON_NUM_THREADS=2 "$1" bench --json 2>/dev/null >"$out"
  python3 - "$2" "$out" <<'PY'
import json, statistics, sys
d = json.load(open(sys.argv[2]))
w = {x["name"]: x for x in d["workloads"]}
t, h = w["tube-10k"], w["tube-100k"]
print(
    f"{sys.argv[1]} tube-10k median {t['frame_ms_median']:.2f} p99 {t['frame_ms_p99']:.2f} "
    f"its {t['iterations_per_frame_mean']:.1f} conv {t['frames_converged']}/{t['frames']} "
    f"coll {t['collision_us_per_vertex']:.3f} (plan {t['collision_plan_us_per_vertex']:.3f} "
    f"passes {t['collision_passes_us_per_vertex']:.3f} "
    f"projections {t['collision_projections_us_per_vertex']:.3f}) "
    f"clearance {t['min_clearance_m']:.5f} unresolved {t['unresolved_max']} | "
    f"tube-100k median {h['frame_ms_median']:.1f} its {h['iterations_per_frame_mean']:.1f} "
    f"coll {h['collision_us_per_vertex']:.3f} (projections "
    f"{h['collision_projections_us_per_vertex']:.3f}) | "
    f"frames 13-22 median {statistics.median(t['frame_ms'][:10]):.2f}"
)
PY
}
for i in $(seq "$pairs"); do
  if [ $((i % 2)) = 1 ]; then
    run "$a" A
    run "$b" B
  else
    run "$b" B
    run "$a" A
  fi
done
