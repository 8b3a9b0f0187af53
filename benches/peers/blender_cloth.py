#!/usr/bin/env python3
"""Blender's cloth simulation on the same skin tubes as `dermis bench`.

Issue 8 sets dermis's tube-10k frame against Blender's cloth, what many artists use for this
job. The tube of `dermis bench` (exported by `dermis bench --write-mesh DIR`) becomes a cloth
object with Blender's defaults (5 quality steps per frame, collision quality 2, no self
collision, no bending override), its two end rings pinned (a `pin` vertex group), over the
bench's muscle at full flexion (50k triangles) as a static collision object. The cloth's
minimum collision distance and the collider's outer thickness are the skin thickness (2 mm).
Each timed frame is one `scene.frame_set` of a 30 fps scene (the cloth step of that frame, its
point cache not baked). Prints Blender's ms/frame and its ratio to dermis's whole-frame median
(over its deforming muscle and two bones, converged to the default tolerance), read from
`dermis bench --json` output.

Usage (from the repository root; not run in CI; Debian/Ubuntu: `apt-get install blender`):

    cargo build --release
    target/release/dermis bench --json > target/bench.json
    python3 benches/peers/blender_cloth.py --bench-json target/bench.json

Blender runs headless (`blender -b --factory-startup -t 2`, two threads like the bench). The
same file is the script Blender runs (`--one`): it needs only Blender's bundled Python.
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



def run_one(mesh_dir, name, frames):
    """Inside Blender: times `frames` cloth frames of the tube `name`; prints one JSON line."""
    import bpy

    # An empty scene (factory start-up holds a cube, a camera and a light).
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj, do_unlink=True)
    scene = bpy.context.scene

    def add_mesh(mesh_name, path):
        points, faces = read_obj(path)
        mesh = bpy.data.meshes.new(mesh_name)
        mesh.from_pydata(points, [], faces)
        mesh.validate()
        obj = bpy.data.objects.new(mesh_name, mesh)
        scene.collection.objects.link(obj)
        return obj, points

    tube, points = add_mesh(name, os.path.join(mesh_dir, name + ".obj"))
    muscle, _ = add_mesh("muscle", os.path.join(mesh_dir, "muscle.obj"))

    # The end rings pinned, as in the bench (its anchors hold the ends) and the PBD peer.
    zs = [p[2] for p in points]
    z_min, z_max = min(zs), max(zs)
    pin = tube.vertex_groups.new(name="pin")
    pin.add([i for i, z in enumerate(zs) if z <= z_min + 1e-6 or z >= z_max - 1e-6], 1.0,
            "REPLACE")

    cloth = tube.modifiers.new("Cloth", "CLOTH")
    cloth.settings.vertex_group_mass = "pin"
    cloth.collision_settings.use_collision = True
    cloth.collision_settings.use_self_collision = False
    cloth.collision_settings.distance_min = THICKNESS_M
    cloth.point_cache.frame_start = 1
    cloth.point_cache.frame_end = frames + 2

    muscle.modifiers.new("Collision", "COLLISION")
    muscle.collision.thickness_outer = THICKNESS_M

    scene.render.fps = 30
    scene.frame_start = 1
    scene.frame_end = frames + 2
    scene.frame_set(1)
    scene.frame_set(2)  # warm-up: the first cloth step (allocations, first contacts)
    times = []
    for f in range(3, frames + 3):
        t = time.perf_counter()
        scene.frame_set(f)
        times.append((time.perf_counter() - t) * 1e3)
    # The cloth moved: the timed frames were simulated, not read back from a cache.
    evaluated = tube.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    moved = max(
        max(abs(a - b) for a, b in zip(v.co, p)) for v, p in zip(evaluated.vertices, points)
    )
    # The collision was engaged: cloth vertices near the muscle's surface (BVH distance).
    from mathutils.bvhtree import BVHTree

    muscle_points, muscle_faces = read_obj(os.path.join(mesh_dir, "muscle.obj"))
    tree = BVHTree.FromPolygons(muscle_points, muscle_faces)
    near = 0
    for v in evaluated.vertices:
        hit = tree.find_nearest(tube.matrix_world @ v.co, 2.0 * THICKNESS_M)
        near += hit[0] is not None
    times.sort()
    print("BLENDER_RESULT " + json.dumps({
        "name": name,
        "vertices": len(points),
        "frames": frames,
        "blender_version": bpy.app.version_string,
        "threads": bpy.app.render_threads if hasattr(bpy.app, "render_threads") else None,
        "blender_ms_median": statistics.median(times),
        "blender_ms_p99": times[min(len(times) - 1, int(0.99 * len(times)))],
        "max_vertex_motion_m": moved,
        "vertices_within_2_thickness_of_muscle": near,
    }), flush=True)


def blender_args():
    """The arguments after Blender's `--`, when run inside Blender; else `None`."""
    if "--" in sys.argv:
        try:
            import bpy  # noqa: F401
        except ImportError:
            return None
        return sys.argv[sys.argv.index("--") + 1:]
    return None


def main():
    inside = blender_args()
    if inside is not None:
        ap = argparse.ArgumentParser()
        ap.add_argument("--one", nargs=2, metavar=("MESH_DIR", "NAME"), required=True)
        ap.add_argument("--frames", type=int, default=5)
        args = ap.parse_args(inside)
        run_one(args.one[0], args.one[1], args.frames)
        return

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bench-json", help="output of `dermis bench --json` (else it is run)")
    ap.add_argument("--dermis", default="target/release/dermis", help="the dermis binary")
    ap.add_argument("--blender", default="blender", help="the Blender executable")
    ap.add_argument("--frames", type=int, default=5, help="timed Blender frames per tube")
    ap.add_argument("--sizes", default="tube-10k", help="workloads to compare")
    args = ap.parse_args()

    by_name = bench_workloads(args.bench_json, args.dermis)
    with bench_meshes(args.dermis) as mesh_dir:
        print(f"{'workload':<10} {'vertices':>9} {'Blender ms':>11} {'Blender p99':>12} "
              f"{'dermis ms':>10} {'dermis p99':>11} {'Blender/dermis':>15}")
        for name in args.sizes.split(","):
            run = subprocess.run(
                [args.blender, "-b", "--factory-startup", "-noaudio", "-t", "2",
                 "--python-exit-code", "1", "--python", os.path.abspath(__file__), "--",
                 "--one", mesh_dir, name, "--frames", str(args.frames)],
                check=True, capture_output=True, text=True,
            )
            lines = [line for line in run.stdout.splitlines()
                     if line.startswith("BLENDER_RESULT ")]
            if not lines:
                sys.exit(f"Blender printed no result for {name}:\n{run.stdout}\n{run.stderr}")
            theirs = json.loads(lines[-1].split(" ", 1)[1])
            w = by_name[name]
            print(f"{name:<10} {theirs['vertices']:>9} {theirs['blender_ms_median']:>11.1f} "
                  f"{theirs['blender_ms_p99']:>12.1f} {w['frame_ms_median']:>10.2f} "
                  f"{w['frame_ms_p99']:>11.2f} "
                  f"{theirs['blender_ms_median'] / w['frame_ms_median']:>15.1f}")
            print(f"  Blender {theirs['blender_version']}, cloth max vertex motion "
                  f"{theirs['max_vertex_motion_m']:.4f} m, "
                  f"{theirs['vertices_within_2_thickness_of_muscle']} vertices within two "
                  "thicknesses of the muscle (in contact)")
    print("Blender/dermis > 1: dermis's frame is faster (issue 8 target: >= 400 at tube-10k).")


if __name__ == "__main__":
    main()
