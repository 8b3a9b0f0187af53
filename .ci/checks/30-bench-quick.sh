#!/usr/bin/env bash
# `dermis bench --quick` runs and prints the documented JSON shape, so the harness cannot rot.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo run --release --quiet -- bench --quick --json > target/bench-quick.json
python3 - <<'PY'
import json, math
d = json.load(open("target/bench-quick.json"))
m = d["machine"]
assert m["threads"] >= 1 and m["bandwidth_gb_s"] > 0 and m["spring_ns"] > 0, m
assert m["kernels"] in ("scalar", "avx2", "avx512"), m
names = [w["name"] for w in d["workloads"]]
assert names == ["tube-10k", "tube-100k", "relax-1m"], names
always = ("skin_vertices", "collider_triangles", "frames", "frames_converged", "frame_ms_median",
          "frame_ms_p99", "iterations_per_frame_mean", "relax_vertex_iterations_per_s",
          "relax_fraction_of_floor", "bytes_per_vertex", "thread_scaling_2_over_1",
          "relax_speedup_vs_previous", "previous_energy_after_30",
          "relax_speedup_vs_naive_scatter", "energy_after_30")
contact = ("substeps_per_frame_mean", "collision_passes_per_frame_mean", "collision_us_per_vertex",
           "collision_naive_us_per_vertex_pass", "collision_speedup_vs_naive",
           "collider_refresh_ms", "min_clearance_m", "unresolved_max", "shuffled_over_ordered",
           "shuffled_energy_after_30")
for w in d["workloads"]:
    arm = w["name"] != "relax-1m"
    for key in always + (contact if arm else ()):
        v = w[key]
        assert isinstance(v, (int, float)) and math.isfinite(v) and v >= 0, (w["name"], key, v)
    if arm:
        assert w["collider_triangles"] == 50000, w["collider_triangles"]
        # The skin stayed outside the muscle and the bones (thickness 2 mm).
        assert w["min_clearance_m"] > 0.001, (w["name"], w["min_clearance_m"])
        assert abs(w["shuffled_energy_after_30"] - w["energy_after_30"]) <= 1e-6 * w["energy_after_30"]
    else:
        assert all(w[k] is None for k in contact), w
print("bench --quick:", {w["name"]: {"frame_ms": round(w["frame_ms_median"], 1),
                                     "Mvert_it_s": round(w["relax_vertex_iterations_per_s"] / 1e6, 1),
                                     "coll_us_per_vertex": w["collision_us_per_vertex"]}
                         for w in d["workloads"]}, f"({d['wall_s']:.0f} s)")
PY
