#!/usr/bin/env python3
"""PositionBasedDynamics (PyPI `pypbd`) on the same skin tubes as `dermis bench`.

The tube of `dermis bench` (exported by `dermis bench --write-mesh DIR`) becomes a PBD cloth
with one distance constraint per edge (dermis's skin is springs on the mesh edges, no bending),
its two end rings pinned, over the bench's muscle at full flexion (50k triangles) as a static
rigid collider (PBD's cubic signed-distance-field collision, tolerance = the skin thickness).
Each frame is one PBD time step of 1/30 s with one substep and 30 constraint iterations (the
iteration count of issue 8's peer figures). Prints PBD's ms/frame and the ratio to dermis's
whole-frame median (over its deforming muscle and two bones, converged to the default
tolerance), read from `dermis bench --json` output.

Usage (from the repository root; not run in CI):

    python3 -m venv target/pbd-venv && target/pbd-venv/bin/pip install pypbd numpy
    cargo build --release
    target/release/dermis bench --json > target/bench.json
    target/pbd-venv/bin/python benches/peers/pbd_tube.py --bench-json target/bench.json

PBD runs with OMP_NUM_THREADS=2 and OMP_WAIT_POLICY=passive unless they are set.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from dermis_run import THICKNESS_M, bench_meshes, bench_workloads, read_obj  # noqa: E402

ITERATIONS = 30


def run_one(mesh_dir, name, frames, collider=True, resolution=30, rigid_test=False):
    """Times `frames` PBD steps of the tube `name`; prints one JSON line."""
    import numpy as np
    import pypbd as pbd

    sim = pbd.Simulation.getCurrent()
    sim.initDefault()
    model = sim.getModel()
    points, triangles = read_obj(os.path.join(mesh_dir, name + ".obj"))
    faces = [i for tri in triangles for i in tri]
    tri_model = model.addTriangleModel(
        [np.array(p) for p in points], faces, testMesh=True
    )
    # simModel 1: PBD distance constraints (one per edge); no bending.
    model.addClothConstraints(tri_model, 1, 1.0, 1.0, 1.0, 1.0, 0.3, 0.3, False, False)
    particles = model.getParticles()
    zs = [p[2] for p in points]
    z_min, z_max = min(zs), max(zs)
    offset = tri_model.getIndexOffset() if hasattr(tri_model, "getIndexOffset") else 0
    for i, z in enumerate(zs):
        if z <= z_min + 1e-6 or z >= z_max - 1e-6:
            particles.setMass(offset + i, 0.0)

    if collider:
        vd, mesh = pbd.OBJLoader.loadObjToMesh(os.path.join(mesh_dir, "muscle.obj"), [1.0] * 3)
        rb = model.addRigidBody(1.0, vd, mesh, testMesh=rigid_test, generateCollisionObject=True,
                                resolution=[resolution] * 3)
        rb.setMass(0.0)
    ts = sim.getTimeStep()
    ts.getCollisionDetection().setTolerance(THICKNESS_M)
    ts.setValueUInt(pbd.TimeStepController.NUM_SUB_STEPS, 1)
    ts.setValueUInt(pbd.TimeStepController.MAX_ITERATIONS, ITERATIONS)
    pbd.TimeManager.getCurrent().setTimeStepSize(1.0 / 30.0)

    ts.step(model)  # warm-up (first contacts, allocations)
    times = []
    for _ in range(frames):
        t = time.perf_counter()
        ts.step(model)
        times.append((time.perf_counter() - t) * 1e3)
    times.sort()
    print(json.dumps({
        "name": name,
        "vertices": len(points),
        "frames": frames,
        "pbd_ms_median": statistics.median(times),
        "pbd_ms_p99": times[min(len(times) - 1, int(0.99 * len(times)))],
    }))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bench-json", help="output of `dermis bench --json` (else it is run)")
    ap.add_argument("--dermis", default="target/release/dermis", help="the dermis binary")
    ap.add_argument("--frames", type=int, default=10, help="timed PBD frames per tube")
    ap.add_argument("--sizes", default="tube-10k,tube-100k", help="workloads to compare")
    ap.add_argument("--one", nargs=2, metavar=("MESH_DIR", "NAME"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        run_one(args.one[0], args.one[1], args.frames)
        return

    by_name = bench_workloads(args.bench_json, args.dermis)
    with bench_meshes(args.dermis) as mesh_dir:
        print(f"{'workload':<10} {'vertices':>9} {'PBD ms':>9} {'PBD p99':>9} "
              f"{'dermis ms':>10} {'dermis p99':>11} {'PBD/dermis':>11}")
        for name in args.sizes.split(","):
            # One process per tube: pypbd keeps one global simulation.
            # OpenMP threads must sleep, not spin, when they wait: on a shared machine spinning
            # threads steal the cores and PBD's times become 5-20x worse.
            env = dict(os.environ)
            env.setdefault("OMP_NUM_THREADS", "2")
            env.setdefault("OMP_WAIT_POLICY", "passive")
            line = subprocess.run(
                [sys.executable, __file__, "--one", mesh_dir, name, "--frames", str(args.frames)],
                check=True, capture_output=True, text=True, env=env,
            ).stdout.strip().splitlines()[-1]
            pbd_figures = json.loads(line)
            w = by_name[name]
            print(f"{name:<10} {pbd_figures['vertices']:>9} {pbd_figures['pbd_ms_median']:>9.2f} "
                  f"{pbd_figures['pbd_ms_p99']:>9.2f} {w['frame_ms_median']:>10.2f} "
                  f"{w['frame_ms_p99']:>11.2f} {pbd_figures['pbd_ms_median'] / w['frame_ms_median']:>11.4f}")
    print("PBD/dermis > 1: dermis's frame is faster (issue 8 target: >= 4 at tube-10k).")


if __name__ == "__main__":
    main()
