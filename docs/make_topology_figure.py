"""Draw docs/img/topology_repair.png: a repaired handle.

    python docs/make_topology_figure.py HARMAP_BINARY -o docs/img/topology_repair.png

Writes a genus-0 "C" ring (a torus cut open by a gap of 0.02 radians and capped: the
ends are a third of a voxel apart at resolution 40), voxelizes it with --allow-genus (the
raw solid) and by default (repaired), and draws the slice z = 0 of both, the voxels the
repair removed in red and those it added in blue.
"""
import argparse
import pathlib
import subprocess
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import zarr

BIG, SMALL, GAP, GAP_AT, N, M = 1.0, 0.3, 0.02, 0.4, 96, 24


def c_ring_obj(path):
    u_at = lambda i: GAP_AT + GAP / 2 + (2 * np.pi - GAP) * i / N
    v, t = [], []
    for i in range(N + 1):
        u = u_at(i)
        for j in range(M):
            w = 2 * np.pi * j / M
            r = BIG + SMALL * np.cos(w)
            v.append((r * np.cos(u), r * np.sin(u), SMALL * np.sin(w)))
    idx = lambda i, j: i * M + j % M
    for i in range(N):
        for j in range(M):
            t.append((idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)))
            t.append((idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)))
    c0, c1 = len(v), len(v) + 1
    v.append((BIG * np.cos(u_at(0)), BIG * np.sin(u_at(0)), 0.0))
    v.append((BIG * np.cos(u_at(N)), BIG * np.sin(u_at(N)), 0.0))
    for j in range(M):
        t.append((c0, idx(0, j), idx(0, j + 1)))
        t.append((c1, idx(N, j + 1), idx(N, j)))
    with open(path, "w") as f:
        for p in v:
            f.write("v %.9f %.9f %.9f\n" % p)
        for a, b, c in t:
            f.write(f"f {a + 1} {b + 1} {c + 1}\n")


def repair_of(run):
    """The run's repair record (stages.voxelize.result.repair)."""
    root = zarr.open_group(str(run), mode="r")
    return root.attrs["harmap"]["stages"]["voxelize"]["result"]["repair"]


def solid_slice(run):
    root = zarr.open_group(str(run), mode="r")
    g = root.attrs["harmap"]["grid"]
    lab = np.asarray(root["labels/0"][...])
    # The slice through z = 0 (world), the ring's middle plane.
    z = int(round((0.0 - g["origin"][2]) / g["spacing"]))
    s = lab[z]
    return (s >= 1) & (s <= 3), g


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("harmap")
    ap.add_argument("-o", "--output", default="docs/img/topology_repair.png")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        d = pathlib.Path(d)
        c_ring_obj(d / "ring.obj")
        base = [a.harmap, "-q", "--progress", "never", "voxelize", str(d / "ring.obj"), "--resolution", "40"]
        subprocess.run(base + ["-o", str(d / "raw.harmap"), "--allow-genus"], check=True)
        subprocess.run(base + ["-o", str(d / "rep.harmap")], check=True)
        raw, g = solid_slice(d / "raw.harmap")
        rep, _ = solid_slice(d / "rep.harmap")
        r = repair_of(d / "rep.harmap")
    print(
        f"{r['method']}: {r['voxels_removed']} removed, {r['voxels_added']} added; "
        f"{r['handles_cut']} cut, {r['handles_filled']} filled; the other way {r['alternative_voxels']}"
    )
    h = g["spacing"]
    ox, oy = g["origin"][0], g["origin"][1]
    ny, nx = raw.shape
    ext = (ox - h / 2, ox + (nx - 0.5) * h, oy - h / 2, oy + (ny - 0.5) * h)
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.6))
    for ax, title, img in ((axes[0], "raw solid (--allow-genus)", raw), (axes[1], f"repaired (default): {r['voxels_removed']} removed, {r['voxels_added']} added", rep)):
        rgb = np.ones(raw.shape + (3,))
        rgb[img] = (0.62, 0.79, 0.88)
        if img is rep:
            rgb[raw & ~rep] = (0.85, 0.1, 0.1)
            rgb[~raw & rep] = (0.1, 0.2, 0.85)
        ax.imshow(rgb, origin="lower", extent=ext, interpolation="nearest")
        u = np.linspace(0, 2 * np.pi, 200)
        for r in (BIG - SMALL, BIG + SMALL):
            ax.plot(r * np.cos(u), r * np.sin(u), color="0.4", lw=0.5)
        for r in (BIG - SMALL, BIG + SMALL):
            ax.plot([0, r * np.cos(GAP_AT)], [0, r * np.sin(GAP_AT)], color="k", lw=0.4, ls=":")
        ax.set_title(title)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_aspect("equal")
    fig.suptitle("A genus-0 C ring at resolution 40: the ends fuse at the dotted line; slice z = 0")
    fig.tight_layout()
    fig.savefig(a.output, dpi=110)


if __name__ == "__main__":
    main()
