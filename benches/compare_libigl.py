#!/usr/bin/env python3
"""harmap voxelize vs libigl's fast winding number on the same voxel centers.

The claim under test: harmap must be at least 5x faster than libigl's fast winding
number (Barill et al. 2018, `igl.fast_winding_number(V, F, Q)`) deciding inside/outside
for the same N^3-class grid of voxel centers.

    pip install libigl numpy zarr           # zarr>=3
    python benches/compare_libigl.py --mesh ../shared/data/meshes/armadillo.obj.gz --n 256

What is timed:
  * harmap: the whole `harmap voxelize MESH -o RUN --resolution N --force --progress
    never --threads T` command, wall clock (parse, inside test, cavity fill, topology,
    center, zstd labels written to disk) - everything, so it is the conservative side;
    median of --repeat runs (the machine may be shared).
  * libigl: the `igl.fast_winding_number(V, F, Q)` call alone on every voxel center of
    the run's grid (shape, origin and spacing read from RUN/zarr.json; voxel (k, j, i)
    at origin + spacing * (i, j, k)), with IGL_NUM_THREADS = T. Mesh loading and building
    Q are not timed. The tree build inside the call is, and is also shown on its own
    (a call with a single query point).
Agreement: the fraction of voxels where |w| > 0.5 equals "harmap label in {1, 2, 3}".
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    here = Path(__file__).resolve().parent.parent
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--harmap", default=str(here / "target/release/harmap"), help="harmap binary (default: target/release/harmap)")
    ap.add_argument("--mesh", default=str(here.parent / "shared/data/meshes/armadillo.obj.gz"), help="mesh (OBJ/PLY/STL/OFF, optionally .gz)")
    ap.add_argument("--n", type=int, default=256, help="--resolution: voxels along the longest side (default 256)")
    ap.add_argument("--threads", type=int, default=2, help="threads for both tools (default 2)")
    ap.add_argument("--repeat", type=int, default=3, help="harmap runs; the median is reported (default 3)")
    ap.add_argument("--keep", metavar="DIR", help="keep the run directory here instead of a temporary one")
    ap.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = ap.parse_args()

    # libigl reads IGL_NUM_THREADS once, on first use: set it before importing.
    os.environ["IGL_NUM_THREADS"] = str(args.threads)
    import igl
    import numpy as np
    import zarr

    fwn = getattr(igl, "fast_winding_number", None) or getattr(igl, "fast_winding_number_for_meshes")
    mesh = Path(args.mesh)
    harmap = Path(args.harmap)
    if not harmap.exists():
        sys.exit(f"error: {harmap} does not exist; build it with `cargo build --release`")
    if not mesh.exists():
        sys.exit(f"error: {mesh} does not exist")

    tmp = Path(tempfile.mkdtemp(prefix="harmap-vs-igl-"))
    try:
        run = Path(args.keep) if args.keep else tmp / "run.harmap"
        cmd = [str(harmap), "voxelize", str(mesh), "-o", str(run), "--resolution", str(args.n),
               "--force", "--progress", "never", "--threads", str(args.threads)]
        print("$", " ".join(cmd), f"  (x{args.repeat}, median)", flush=True)
        runs = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            p = subprocess.run(cmd, capture_output=True, text=True)
            runs.append(time.perf_counter() - t0)
            if p.returncode != 0:
                sys.exit(f"error: harmap voxelize failed ({p.returncode}):\n{p.stderr}")
        t_harmap = statistics.median(runs)

        h = json.loads((run / "zarr.json").read_text())["attributes"]["harmap"]
        g = h["grid"]
        nz, ny, nx = g["shape"]
        ox, oy, oz = g["origin"]
        s = float(g["spacing"])
        nvox = nz * ny * nx
        stage = h["stages"]["voxelize"]
        inner = (stage.get("result") or {}).get("timings")
        labels = np.asarray(zarr.open_array(str(run / "labels" / "0"), mode="r")[...])
        assert labels.shape == (nz, ny, nx)
        solid_h = (labels >= 1) & (labels <= 3)
        boundary = labels == 1
        del labels

        # The mesh, decompressed for libigl's reader when gzipped.
        src = mesh
        if mesh.suffix == ".gz":
            src = tmp / mesh.stem
            with gzip.open(mesh, "rb") as fi, open(src, "wb") as fo:
                shutil.copyfileobj(fi, fo)
        V, F = igl.read_triangle_mesh(str(src))
        V = np.ascontiguousarray(V, dtype=np.float64)
        F = np.ascontiguousarray(F, dtype=np.int64)

        # Every voxel center, C order (z slowest, x fastest), as (x, y, z) rows.
        zz, yy, xx = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
        Q = np.empty((nvox, 3), dtype=np.float64)
        Q[:, 0] = ox + s * xx.ravel()
        Q[:, 1] = oy + s * yy.ravel()
        Q[:, 2] = oz + s * zz.ravel()
        del xx, yy, zz

        t0 = time.perf_counter()
        fwn(V, F, Q[:1])
        t_build = time.perf_counter() - t0
        print(f"libigl fast_winding_number on {nvox} points ({len(F)} triangles, {args.threads} threads) ...", flush=True)
        t0 = time.perf_counter()
        w = fwn(V, F, Q)
        t_igl = time.perf_counter() - t0
        del Q

        solid_w = (np.abs(w) > 0.5).reshape(nz, ny, nx)
        agree = solid_w == solid_h
        n_agree = int(agree.sum())
        dis = ~agree
        n_dis = nvox - n_agree
        dis_boundary = int((dis & boundary).sum())
        only_h = int((dis & solid_h).sum())
        only_w = int((dis & solid_w).sum())
        # Near-surface voxels: |w| far from 0 and 1 means the center is within the
        # approximation's fuzz or on the surface itself.
        ambiguous = int(((np.abs(w) > 0.25) & (np.abs(w) < 0.75)).sum())
        # How far the differing voxel centers are from the surface (in voxels): centers
        # lying on the surface itself are ties that either answer may take.
        far = None
        if 0 < n_dis <= 100_000:
            k, j, i = np.nonzero(dis)
            P = np.stack([ox + s * i, oy + s * j, oz + s * k], axis=1).astype(np.float64)
            d2 = igl.point_mesh_squared_distance(P, V, F)[0]
            d = np.sqrt(np.asarray(d2).ravel()) / s
            far = (float(d.max()), int((d > 1e-3).sum()))

        speedup = t_igl / t_harmap
        rows = [
            ("harmap voxelize (whole command)", t_harmap, nvox / t_harmap, 1.0),
            ("libigl fast_winding_number", t_igl, nvox / t_igl, speedup),
        ]
        print()
        print(f"mesh {mesh.name}: {len(V)} vertices, {len(F)} triangles; grid {nz}x{ny}x{nx} = {nvox} voxels "
              f"(--resolution {args.n}, spacing {s:.6g}); {args.threads} threads")
        print(f"{'tool':34s} {'seconds':>9s} {'voxels/s':>12s} {'harmap speedup':>15s}")
        for name, t, rate, sp in rows:
            print(f"{name:34s} {t:9.3f} {rate:12.4g} {sp:14.2f}x")
        if len(runs) > 1:
            print("  harmap runs: " + ", ".join(f"{t:.3f}" for t in runs) + " s")
        print(f"  (libigl tree build alone, one query point: {t_build:.3f} s)")
        if inner:
            print("  harmap voxelize passes: " + ", ".join(f"{k} {v:.2f}s" for k, v in inner))
        print(f"agreement (|w| > 0.5 vs labels 1,2,3): {n_agree / nvox:.6%} "
              f"({n_dis} voxels differ: {only_h} solid only in harmap, {only_w} only in libigl; "
              f"{dis_boundary} of them harmap boundary voxels; {ambiguous} voxels with 0.25 < |w| < 0.75)")
        if far is not None:
            print(f"  differing voxel centers: farthest {far[0]:.3g} voxels from the surface; "
                  f"{far[1]} farther than 0.001 voxels (the rest lie on the surface: ties)")
        verdict = "PASS" if speedup >= 5.0 else "FAIL"
        print(f"{verdict}: harmap is {speedup:.2f}x faster than libigl's fast winding number (target >= 5x)")
        if args.json:
            Path(args.json).write_text(json.dumps({
                "mesh": str(mesh), "n": args.n, "threads": args.threads, "grid": [nz, ny, nx], "voxels": nvox,
                "harmap_seconds": t_harmap, "harmap_runs": runs, "igl_seconds": t_igl, "igl_build_seconds": t_build,
                "speedup": speedup, "agreement": n_agree / nvox, "disagree": n_dis,
                "disagree_only_harmap": only_h, "disagree_only_igl": only_w, "disagree_boundary": dis_boundary,
                "disagree_max_distance_voxels": far[0] if far else None,
                "disagree_off_surface": far[1] if far else None,
                "harmap_passes": inner,
            }, indent=2))
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
