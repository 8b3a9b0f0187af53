#!/usr/bin/env bash
# `dermis bench --quick` runs and prints the documented JSON shape, so the harness cannot rot.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo run --release --quiet -- bench --quick --json > target/bench-quick.json
python3 - <<'PY'
import json
d = json.load(open("target/bench-quick.json"))
assert d["machine"]["threads"] >= 1 and d["machine"]["bandwidth_gb_s"] > 0
names = [w["name"] for w in d["workloads"]]
assert names == ["tube-10k", "tube-100k", "relax-1m"], names
for w in d["workloads"]:
    for key in ("skin_vertices", "frame_ms_median", "frame_ms_p99", "iterations_per_frame_mean",
                "relax_vertex_iterations_per_s", "relax_fraction_of_floor", "bytes_per_vertex",
                "thread_scaling_2_over_1", "energy_after_30"):
        assert key in w, key
print("bench --quick:", {w["name"]: round(w["relax_vertex_iterations_per_s"] / 1e6, 1) for w in d["workloads"]}, "M vertex-iterations/s")
PY
