"""The Python stages write the same bytes as the command, for every kind of shape."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import harmap
from conftest import cli, field_bytes, shared

FIELDS = ("labels", "phi", "theta", "psi")


@pytest.mark.parametrize("which", ["path", "arrays"])
def test_spot_at_64_gives_the_commands_bytes(spot_runs, which):
    for f in FIELDS:
        assert field_bytes(spot_runs / f"{which}.harmap", f) == field_bytes(
            spot_runs / "cli.harmap", f
        ), f"{f} differs from `harmap run`"
    a = harmap.open(spot_runs / f"{which}.harmap")
    c = harmap.open(spot_runs / "cli.harmap")
    # Same seeds (the input mesh's vertices, read back from the file in the run).
    sa, sc = a.seeds, c.seeds
    assert sa.keys() == sc.keys()
    for k in sc:
        assert sa[k].tobytes() == sc[k].tobytes(), k
    assert a.report("trace")["surface"] == c.report("trace")["surface"]
    assert a.stages["voxelize"]["options"] == c.stages["voxelize"]["options"]
    if which == "arrays":
        assert a.input["format"] == "obj"
        assert Path(a.input["path"]).parent == a.path
    # harmap.run writes the atlas and the report beside the run, as the command does.
    assert (spot_runs / f"{which}.atlas.png").stat().st_size > 0
    assert (spot_runs / f"{which}.report.html").stat().st_size > 0


def test_open_gives_metadata_reports_and_lazy_fields(spot_runs):
    r = harmap.open(spot_runs / "path.harmap")
    assert all(r.done(s) for s in ("voxelize", "solve", "trace", "map"))
    shape = tuple(r.grid["shape"])
    assert r.phi.shape == shape and r.phi.dtype == np.float64
    assert r.theta.dtype == np.float64 and r.labels.dtype == np.uint8
    # A mesh run places phi = 1 on the mesh itself (the `cuts` array holds where it
    # crosses the stencil): its boundary voxels, whose centers lie inside, are unknowns
    # just below 1. phi = 0 in the center ball, and 0 < phi < 1 at every other unknown.
    assert (r.path / "cuts" / "zarr.json").exists()
    lab = r.labels[...]
    phi = r.phi[...]
    boundary = phi[lab == 1]
    assert np.all((boundary > 0.5) & (boundary <= 1.0)), (boundary.min(), boundary.max())
    assert boundary.mean() > 0.9
    assert np.all(phi[lab == 3] == 0.0)
    inner = phi[lab == 2]
    assert np.all((inner > 0.0) & (inner < 1.0))
    assert r.report("solve")["relative_residual"] <= 1e-6
    t = r.seeds
    n = r.report("trace")["seeds"]
    assert all(len(v) == n for v in t.values())
    try:
        import pandas  # noqa: F401
    except ImportError:
        return
    df = r.seeds_frame()
    assert len(df) == n


def test_an_atom_array_voxelizes_as_the_same_atoms_in_a_file(tmp_path):
    # 1crn's heavy atoms with radii by element, handed over as an (N, 4) array.
    radii = {"C": 1.7, "N": 1.55, "O": 1.52, "S": 1.8}
    atoms = []
    for line in shared("molecules/1crn.pdb").read_text().splitlines():
        if line.startswith("ATOM"):
            el = line[76:78].strip() or line[12:14].strip()[0]
            xyz = [float(line[30:38]), float(line[38:46]), float(line[46:54])]
            atoms.append(xyz + [radii.get(el, 1.8)])
    atoms = np.array(atoms)
    assert len(atoms) > 300
    r = harmap.voxelize(atoms, tmp_path / "py.harmap", spacing=0.5, progress=False)
    assert r.input["format"] == "xyzr"
    xyzr = tmp_path / "atoms.xyzr"
    np.savetxt(xyzr, atoms, fmt="%.17g")
    cli("voxelize", xyzr, "-o", tmp_path / "cli.harmap", "--spacing", 0.5)
    assert field_bytes(r.path, "labels") == field_bytes(tmp_path / "cli.harmap", "labels")
    assert r.report("voxelize")["genus"] == 0
    assert r.report("voxelize")["components"] == 1


def ball(n, radius):
    z, y, x = np.mgrid[:n, :n, :n] - (n - 1) / 2
    return (x * x + y * y + z * z <= radius * radius).astype(np.uint8)


def test_a_numpy_label_volume_is_voxelized_and_solved(tmp_path):
    vol = ball(40, 14)
    r = harmap.voxelize(vol, tmp_path / "ball.harmap", progress=False)
    assert r.input["format"] == "label-volume"
    raw = tmp_path / "ball.raw"
    vol.tofile(raw)
    cli("voxelize", raw, "-o", tmp_path / "cli.harmap", "--raw-shape", "40,40,40", "--raw-dtype", "u8")
    assert field_bytes(r.path, "labels") == field_bytes(tmp_path / "cli.harmap", "labels")
    # The solid is the ball: every voxel inside is labeled solid (boundary, interior or
    # center) and none outside.
    lab = r.labels[...]
    pad = r.grid["shape"][0] - 40
    assert pad >= 0
    assert int(((lab >= 1) & (lab <= 3)).sum()) == int(vol.sum())
    rep = harmap.solve(r, progress=False)
    assert rep["relative_residual"] <= 1e-6
    phi = r.phi[...]
    inside = (lab == 2)
    assert np.all((phi[inside] > 0) & (phi[inside] < 1)), "maximum principle"


def test_a_zarr_label_array_is_accepted(tmp_path):
    import zarr

    z = zarr.create_array(store=str(tmp_path / "vol.zarr"), shape=(32, 32, 32), dtype="uint8", chunks=(16, 16, 16))
    z[...] = ball(32, 11)
    r = harmap.voxelize(z, tmp_path / "z.harmap", progress=False)
    assert int(((r.labels[...] >= 1) & (r.labels[...] <= 3)).sum()) == int(ball(32, 11).sum())


def test_inverse_on_arrays_matches_the_command_and_lands_at_the_voxels(spot_runs, tmp_path):
    run = spot_runs / "path.harmap"
    r = harmap.open(run)
    lab = r.labels[...]
    idx = np.argwhere(lab == 2)[::997][:40]
    phi = np.array([r.phi[tuple(i)] for i in idx])
    theta = np.array([r.theta[tuple(i)] for i in idx], dtype=np.float64)
    psi = np.array([r.psi[tuple(i)] for i in idx], dtype=np.float64)
    pts, status = harmap.inverse(run, phi, theta, psi, progress=False)
    assert pts.shape == (len(idx), 3)
    g = r.grid
    origin = np.array(g["origin"])
    centers = origin + g["spacing"] * idx[:, ::-1]  # (z, y, x) -> x, y, z
    ok = np.array([s == "" for s in status])
    assert ok.mean() > 0.9, status
    err = np.linalg.norm(pts[ok] - centers[ok], axis=1) / g["spacing"]
    assert np.median(err) < 1.0, err
    # The command on the same numbers gives the same points.
    csv = tmp_path / "in.csv"
    with csv.open("w") as f:
        f.write("phi,theta,psi\n")
        for a, b, c in zip(phi, theta, psi):
            f.write(f"{float(a)!r},{float(b)!r},{float(c)!r}\n")
    cli("inverse", run, "--points", csv, "-o", tmp_path / "out.csv")
    rows = (tmp_path / "out.csv").read_text().splitlines()[1:]
    for row, p, s in zip(rows, pts, status):
        c = row.split(",")
        if c[6] == "ok":
            assert [float(x) for x in c[3:6]] == list(p)
        else:
            assert s and np.isnan(p).all()


def test_export_writes_what_the_command_writes(spot_runs, tmp_path):
    run = spot_runs / "path.harmap"
    n = harmap.export(run, tmp_path / "py.csv", "csv", progress=False)
    cli("export", run, "--format", "csv", "-o", tmp_path / "cli.csv")
    assert n == harmap.open(run).report("trace")["seeds"]
    assert (tmp_path / "py.csv").read_bytes() == (tmp_path / "cli.csv").read_bytes()
