#!/usr/bin/env python3
"""Check a harmap run directory with the Python Zarr / OME-Zarr ecosystem.

    python check_run.py RUN

Opens RUN with zarr-python 3 and checks the `harmap` group attributes against the
labels array RUN/labels/0 (shape, dtype, dimension names, label counts, center voxel,
boundary/interior consistency), then reads RUN/labels as an OME-Zarr 0.5 image with
ome-zarr's Reader and validates it with ome-zarr-models (`v05.Image`), checking that the
coordinate transformations are scale = spacing and translation = origin (z, y, x).

If ome-zarr's Reader cannot read the image, the script falls back to ome-zarr-models
alone (and says so). Exit status 0 and a line "ok: ..." on success; exit status 1 and
a line "FAIL: ..." on the first failed check; 2 on bad usage.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

SOLID = (1, 2, 3)
NAMES = ["exterior", "boundary", "interior", "center", "layer1", "layer2", "layer3", "layer4"]


class CheckError(Exception):
    """A failed check."""


def require(cond: bool, msg: str) -> None:
    if not cond:
        raise CheckError(msg)


def close(a, b, tol: float = 1e-9) -> bool:
    a, b = list(a), list(b)
    return len(a) == len(b) and all(
        math.isclose(float(x), float(y), rel_tol=tol, abs_tol=tol) for x, y in zip(a, b)
    )


def check_zarr(run: Path) -> tuple[dict, str]:
    """zarr-python checks; returns the harmap attributes and a summary."""
    import numpy as np
    import zarr

    try:
        root = zarr.open_group(str(run), mode="r")
    except Exception as e:  # noqa: BLE001
        raise CheckError(f"zarr-python cannot open {run} as a group: {type(e).__name__}: {e}") from e
    require(root.metadata.zarr_format == 3, f"{run}: zarr_format is {root.metadata.zarr_format}, expected 3")
    attrs = root.attrs.asdict()
    require("harmap" in attrs, f"{run}/zarr.json: no 'harmap' attribute (keys: {sorted(attrs)})")
    h = attrs["harmap"]
    require(h.get("format_version") == 1, f"harmap.format_version is {h.get('format_version')!r}, expected 1")
    grid = h.get("grid")
    require(isinstance(grid, dict), "harmap.grid is missing")
    shape = tuple(grid.get("shape") or ())
    origin = grid.get("origin")
    spacing = grid.get("spacing")
    require(len(shape) == 3 and all(isinstance(n, int) and n > 0 for n in shape), f"harmap.grid.shape {shape!r} is not 3 positive integers")
    require(isinstance(origin, list) and len(origin) == 3, f"harmap.grid.origin {origin!r} is not [x, y, z]")
    require(isinstance(spacing, (int, float)) and spacing > 0, f"harmap.grid.spacing {spacing!r} is not a positive number")
    require("unit" in grid and (grid["unit"] is None or isinstance(grid["unit"], str)), f"harmap.grid.unit {grid.get('unit')!r} is not null or a string")
    stage = (h.get("stages") or {}).get("voxelize") or {}
    require(stage.get("status") == "done", f"harmap.stages.voxelize.status is {stage.get('status')!r}, expected 'done'")
    counts = (stage.get("result") or {}).get("counts")
    require(isinstance(counts, list) and len(counts) == 8, f"harmap.stages.voxelize.result.counts {counts!r} is not 8 numbers")
    cv = h.get("center_voxel")
    require(isinstance(cv, list) and len(cv) == 3, f"harmap.center_voxel {cv!r} is not [z, y, x]")
    require(all(0 <= c < n for c, n in zip(cv, shape)), f"harmap.center_voxel {cv} lies outside the grid {list(shape)}")
    center = h.get("center")
    require(isinstance(center, list) and len(center) == 3, f"harmap.center {center!r} is not [x, y, z]")
    # Coordinates contract: voxel (k, j, i) sits at origin + spacing * (i, j, k).
    expect_center = [origin[a] + spacing * cv[2 - a] for a in range(3)]
    require(close(center, expect_center, 1e-6), f"harmap.center {center} is not the center of voxel {cv} (origin + spacing * (i, j, k) = {expect_center})")

    try:
        arr = root["labels/0"]
    except Exception as e:  # noqa: BLE001
        raise CheckError(f"zarr-python cannot open {run}/labels/0: {type(e).__name__}: {e}") from e
    require(isinstance(arr, zarr.Array), f"{run}/labels/0 is not an array")
    require(tuple(arr.shape) == shape, f"labels/0 shape {tuple(arr.shape)} != harmap.grid.shape {shape}")
    require(arr.dtype == np.uint8, f"labels/0 dtype is {arr.dtype}, expected uint8")
    dims = arr.metadata.dimension_names
    require(dims is not None and tuple(dims) == ("z", "y", "x"), f"labels/0 dimension_names is {dims!r}, expected ('z', 'y', 'x')")
    fill = arr.metadata.fill_value
    require(int(fill) == 0, f"labels/0 fill_value is {fill!r}, expected 0")
    codecs = [type(c).__name__ for c in arr.metadata.codecs]

    # Label values, counts and the 6-neighbour structure, slab by slab along z with a
    # one-slice halo (voxels outside the grid count as exterior).
    nz, ny, nx = shape
    slab = max(1, min(nz, (64 << 20) // max(1, ny * nx)))
    seen = np.zeros(256, dtype=np.int64)
    bad_boundary = bad_interior = 0
    first_bad: list[str] = []
    for z0 in range(0, nz, slab):
        z1 = min(nz, z0 + slab)
        lo, hi = max(0, z0 - 1), min(nz, z1 + 1)
        block = np.asarray(arr[lo:hi])
        core = block[z0 - lo : z0 - lo + (z1 - z0)]
        seen += np.bincount(core.ravel(), minlength=256)
        solid = np.isin(block, SOLID)
        pad = np.zeros((z1 - z0 + 2, ny + 2, nx + 2), dtype=bool)
        pad[(1 if z0 == lo else 0) : (1 if z0 == lo else 0) + (hi - lo), 1:-1, 1:-1] = solid
        c = pad[1:-1, 1:-1, 1:-1]
        all_solid_nbrs = (
            pad[:-2, 1:-1, 1:-1] & pad[2:, 1:-1, 1:-1]
            & pad[1:-1, :-2, 1:-1] & pad[1:-1, 2:, 1:-1]
            & pad[1:-1, 1:-1, :-2] & pad[1:-1, 1:-1, 2:]
        )
        assert c.shape == core.shape
        bb = (core == 1) & all_solid_nbrs
        bi = np.isin(core, (2, 3)) & ~all_solid_nbrs
        bad_boundary += int(bb.sum())
        bad_interior += int(bi.sum())
        for what, m in (("boundary voxel (1) with no non-solid 6-neighbour", bb), ("interior/center voxel (2/3) with a non-solid 6-neighbour", bi)):
            if m.any() and len(first_bad) < 3:
                k, j, i = np.argwhere(m)[0]
                first_bad.append(f"{what} at [z, y, x] = [{z0 + k}, {j}, {i}]")
    extra = {v: int(seen[v]) for v in range(8, 256) if seen[v]}
    require(not extra, f"labels/0 holds values outside 0..7: {extra}")
    found = [int(x) for x in seen[:8]]
    require(found == [int(x) for x in counts], "label counts differ from harmap.stages.voxelize.result.counts:\n"
            + "\n".join(f"  {v} {NAMES[v]:9s} array {found[v]:>12d}  metadata {counts[v]:>12d}" for v in range(8)))
    require(sum(found) == nz * ny * nx, "label counts do not add up to the grid size")
    label_c = int(arr[cv[0], cv[1], cv[2]])
    require(label_c == 3, f"the center voxel {cv} has label {label_c}, expected 3 (center)")
    require(bad_boundary == 0 and bad_interior == 0,
            f"{bad_boundary} boundary and {bad_interior} interior/center voxels contradict the 6-neighbour rule; first: " + "; ".join(first_bad))
    require(found[1] > 0 and found[3] > 0, f"no boundary or no center voxels (counts {found})")
    summary = (f"labels {list(shape)} uint8 dims {tuple(dims)} codecs {codecs}; counts {found}; "
               f"center voxel {cv} = 3; boundary/interior rule holds")
    return h, summary


def expected_transforms(h: dict) -> tuple[list[float], list[float]]:
    g = h["grid"]
    o = g["origin"]
    return [g["spacing"]] * 3, [o[2], o[1], o[0]]


def check_transforms(ct, h: dict, who: str) -> None:
    """`ct`: the coordinateTransformations of dataset "0" as a list of dicts."""
    scale, trans = expected_transforms(h)
    types = [t.get("type") for t in ct]
    require(types == ["scale", "translation"], f"{who}: coordinateTransformations types {types}, expected ['scale', 'translation']")
    require(close(ct[0]["scale"], scale), f"{who}: scale {ct[0]['scale']} != spacing {scale}")
    require(close(ct[1]["translation"], trans), f"{who}: translation {ct[1]['translation']} != origin (z, y, x) {trans}")


def check_ome_zarr_reader(run: Path, h: dict) -> str:
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Multiscales, Reader

    loc = parse_url(str(run / "labels"), mode="r")
    require(loc is not None, f"ome-zarr parse_url({run / 'labels'}) returned None (not readable as zarr)")
    nodes = list(Reader(loc)())
    require(len(nodes) > 0, "ome-zarr Reader found no nodes in RUN/labels")
    node = nodes[0]
    require(any(isinstance(s, Multiscales) for s in node.specs), f"ome-zarr Reader did not see a multiscales image in RUN/labels (specs {node.specs})")
    axes = node.metadata.get("axes")
    names = [a["name"] if isinstance(a, dict) else a for a in (axes or [])]
    require(names == ["z", "y", "x"], f"ome-zarr Reader: axes {axes}, expected z, y, x")
    require(len(node.data) == 1, f"ome-zarr Reader: {len(node.data)} resolution levels, expected 1")
    shape = tuple(h["grid"]["shape"])
    d = node.data[0]
    require(tuple(d.shape) == shape and str(d.dtype) == "uint8", f"ome-zarr Reader: level 0 is {d.shape} {d.dtype}, expected {shape} uint8")
    cts = node.metadata.get("coordinateTransformations")
    require(cts is not None and len(cts) == 1, f"ome-zarr Reader: coordinateTransformations {cts!r}")
    check_transforms(cts[0], h, "ome-zarr Reader")
    cv = h["center_voxel"]
    require(int(d[cv[0], cv[1], cv[2]].compute()) == 3, "ome-zarr Reader: center voxel is not 3 in the dask array")
    return "ome-zarr Reader ok"


def check_ome_zarr_models(run: Path, h: dict) -> str:
    import zarr
    from ome_zarr_models.v05 import Image

    img = Image.from_zarr(zarr.open_group(str(run / "labels"), mode="r"))
    ms = img.attributes.ome.multiscales
    require(len(ms) == 1 and len(ms[0].datasets) == 1, f"ome-zarr-models: {len(ms)} multiscales / datasets, expected 1 / 1")
    names = [a.name for a in ms[0].axes]
    require(names == ["z", "y", "x"], f"ome-zarr-models: axes {names}, expected z, y, x")
    ds = ms[0].datasets[0]
    require(ds.path == "0", f"ome-zarr-models: dataset path {ds.path!r}, expected '0'")
    ct = [t.model_dump() for t in ds.coordinateTransformations]
    check_transforms(ct, h, "ome-zarr-models")
    return "ome-zarr-models v05.Image ok"


def check_solve_and_trace(run: Path, h: dict) -> str:
    """If solved: phi and u agree with the labels and each other. If traced: the seed
    table's columns have one row per seed, and theta/psi are the direction of the end
    point from the center."""
    import numpy as np
    import zarr

    root = zarr.open_group(str(run), mode="r")
    out = []
    if (run / "phi" / "0").exists():
        lab = root["labels/0"][:]
        phi = root["phi/0"][:]
        u = root["u/0"][:]
        require(phi.dtype == np.float64 and u.dtype == np.float64, f"phi/u dtypes {phi.dtype}, {u.dtype}, expected float64")
        require(tuple(root["phi/0"].metadata.dimension_names) == ("z", "y", "x"), "phi/0 dimension names are not z, y, x")
        require(np.array_equal(np.isnan(phi), lab == 0), "phi is NaN exactly where the label is exterior (0): not so")
        # A mesh run carries the cut arms of the sub-voxel boundary (docs/format.md):
        # its boundary voxels are unknowns, with phi in (0, 1], like the interior.
        cut = (run / "cuts" / "0").exists()
        if cut:
            cuts = root["cuts/0"][:]
            require(cuts.dtype == np.uint64 and cuts.shape == lab.shape, f"cuts/0 is {cuts.dtype} {cuts.shape}")
            require(tuple(root["cuts/0"].metadata.dimension_names) == ("z", "y", "x"), "cuts/0 dimension names are not z, y, x")
            require(bool(np.all(cuts[(lab != 1) & (lab != 2)] == 0)), "cut arms on a voxel that is not an unknown")
            require(bool(np.all(cuts[lab == 1] != 0)), "a boundary voxel without a cut arm")
            arms = [(cuts >> np.uint64(10 * k)) & np.uint64(1023) for k in range(6)]
            require(max(int(a.max()) for a in arms) <= 1023 and int(cuts.max() >> np.uint64(60)) == 0, "cuts use more than 60 bits")
            require(bool(np.all((phi[lab == 1] > 0.0) & (phi[lab == 1] <= 1.0))), "boundary phi outside (0, 1] in a run with cuts")
            out.append(f"cuts {list(cuts.shape)} uint64, arms only at unknowns")
        else:
            require(bool(np.all(phi[lab == 1] == 1.0)), "phi is not 1 on every boundary voxel")
        require(bool(np.all(phi[lab == 3] == 0.0)), "phi is not 0 on every center voxel")
        fin = ~np.isnan(phi)
        require(bool(np.allclose(phi[fin], 1.0 - u[fin], rtol=0, atol=1e-15)), "phi != 1 - u")
        inner = phi[lab == 2]
        require(inner.size == 0 or (inner.min() >= 0.0 and inner.max() <= 1.0), "interior phi outside [0, 1]")
        out.append(f"phi/u {list(phi.shape)} float64 consistent with the labels")
    if (run / "seeds" / "zarr.json").exists():
        cols = {c: root[f"seeds/{c}"][:] for c in ("position", "theta", "psi", "phi", "stop", "steps", "length", "end")}
        n = cols["theta"].shape[0]
        require(cols["position"].shape == (n, 3) and cols["end"].shape == (n, 3), "seeds/position or seeds/end is not [n, 3]")
        require(all(cols[c].shape == (n,) for c in ("psi", "phi", "stop", "steps", "length")), "seed columns differ in length")
        reached = cols["stop"] == 0
        require(bool(np.all(np.isfinite(cols["theta"][reached]))), "theta is NaN for a seed that reached the center")
        require(bool(np.all(np.isnan(cols["theta"][~reached]))), "theta is set for a seed that did not reach")
        c = np.array(h["center"])
        d = cols["end"][reached] - c
        th = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
        ps = np.arctan2(d[:, 1], d[:, 0])
        require(bool(np.allclose(th, cols["theta"][reached], atol=1e-9)), "theta is not the polar angle of end - center")
        require(bool(np.allclose(np.cos(ps - cols["psi"][reached]), 1.0, atol=1e-9)), "psi is not the azimuth of end - center")
        out.append(f"seeds: {n} rows, {int(reached.sum())} reached, angles match the end points")
    return "; ".join(out) if out else "not solved"


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[1] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stderr)
        return 2
    run = Path(argv[1])
    if not (run / "zarr.json").is_file():
        print(f"FAIL: {run}: no zarr.json (not a run directory)", file=sys.stderr)
        return 1
    try:
        json.loads((run / "zarr.json").read_text())
    except ValueError as e:
        print(f"FAIL: {run}/zarr.json is not JSON: {e}", file=sys.stderr)
        return 1
    try:
        h, summary = check_zarr(run)
        ok = [summary, check_solve_and_trace(run, h)]
        reader_err = models_err = None
        try:
            ok.append(check_ome_zarr_reader(run, h))
        except CheckError:
            raise
        except ImportError as e:
            reader_err = f"ome-zarr not importable ({e})"
        except Exception as e:  # noqa: BLE001
            reader_err = f"{type(e).__name__}: {e}"
        try:
            ok.append(check_ome_zarr_models(run, h))
        except CheckError:
            raise
        except ImportError as e:
            models_err = f"ome-zarr-models not importable ({e})"
        except Exception as e:  # noqa: BLE001
            raise CheckError(f"ome-zarr-models rejects {run}/labels as a v05 Image: {type(e).__name__}: {e}") from e
        if reader_err and models_err:
            raise CheckError(f"RUN/labels could not be read as OME-Zarr: ome-zarr Reader: {reader_err}; {models_err}")
        if reader_err:
            print(f"warning: ome-zarr Reader could not read {run}/labels ({reader_err}); validated with ome-zarr-models only", file=sys.stderr)
        if models_err:
            print(f"warning: {models_err}; validated with ome-zarr's Reader only", file=sys.stderr)
    except CheckError as e:
        print(f"FAIL: {e}", file=sys.stderr)
        return 1
    except ImportError as e:
        print(f"FAIL: a required package is missing: {e} (pip install 'zarr>=3,<4' numpy ome-zarr ome-zarr-models)", file=sys.stderr)
        return 1
    print(f"ok: {run}: " + "; ".join(ok))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
