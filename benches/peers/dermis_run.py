"""What the peer scripts share: the skin thickness, dermis's bench figures, the bench's meshes and their OBJ reader."""

import contextlib
import json
import subprocess
import tempfile

# The bench's skin thickness, m (its contact distance).
THICKNESS_M = 0.002


def bench_workloads(bench_json, dermis):
    """dermis's workloads by name, from `bench_json` (`dermis bench --json` output) if given,
    else from a fresh `dermis bench --json` run of the binary `dermis`."""
    if bench_json:
        with open(bench_json) as f:
            ours = json.load(f)
    else:
        out = subprocess.run([dermis, "bench", "--json"], check=True, capture_output=True,
                             text=True).stdout
        ours = json.loads(out)
    return {w["name"]: w for w in ours["workloads"]}


@contextlib.contextmanager
def bench_meshes(dermis):
    """A temporary folder holding the bench's skin tubes and muscle (`tube-10k.obj`,
    `tube-100k.obj`, `muscle.obj`, written by `dermis bench --write-mesh`)."""
    with tempfile.TemporaryDirectory() as mesh_dir:
        subprocess.run([dermis, "bench", "--write-mesh", mesh_dir], check=True,
                       capture_output=True)
        yield mesh_dir


def read_obj(path):
    """Vertices (list of (x, y, z)) and triangles (0-based index triples) of a triangle OBJ."""
    points, faces = [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                points.append(tuple(float(t) for t in line.split()[1:4]))
            elif line.startswith("f "):
                faces.append(tuple(int(t.split("/")[0]) - 1 for t in line.split()[1:4]))
    return points, faces
