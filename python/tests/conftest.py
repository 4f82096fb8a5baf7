"""Shared fixtures: the harmap command (to compare against), the shared data folder,
and runs made once per session."""

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")


def _need(what, why):
    """Fail under CI (the data and the binary must be there), skip elsewhere."""
    if CI:
        pytest.fail(f"{what} is missing under CI=true: {why}")
    pytest.skip(f"{what} not found: {why}")


def harmap_bin():
    cands = [os.environ.get("HARMAP_BIN")]
    tgt = os.environ.get("CARGO_TARGET_DIR")
    if tgt:
        cands.append(str(Path(tgt) / "release" / "harmap"))
    cands.append(str(REPO / "target" / "release" / "harmap"))
    for c in cands:
        if c and Path(c).is_file():
            return c
    _need("the harmap binary", "build it with `cargo build --release` or set HARMAP_BIN")


def shared(rel):
    p = REPO.parent / "shared" / "data" / rel
    if not p.exists():
        p = REPO / ".." / "shared" / "data" / rel
    if not p.exists():
        _need(f"../shared/data/{rel}", "the project's shared test data")
    return p


def cli(*args, check=True):
    r = subprocess.run(
        [harmap_bin(), "--progress", "never", "-q", *map(str, args)],
        capture_output=True,
        text=True,
    )
    if check and r.returncode != 0:
        raise AssertionError(f"harmap {' '.join(map(str, args))} failed: {r.stderr}")
    return r


def read_obj(path):
    v, f = [], []
    for line in Path(path).read_text().splitlines():
        t = line.split()
        if not t:
            continue
        if t[0] == "v":
            v.append([float(x) for x in t[1:4]])
        elif t[0] == "f":
            f.append([int(x.split("/")[0]) - 1 for x in t[1:4]])
    return np.array(v, dtype=np.float64), np.array(f, dtype=np.int64)


def field_bytes(run, name):
    """The decoded array of a field as bytes (bit for bit, NaN included)."""
    import zarr

    return zarr.open_array(str(Path(run) / name / "0"), mode="r")[...].tobytes()


@pytest.fixture(scope="session")
def spot_runs(tmp_path_factory):
    """spot.obj at resolution 64 by the command, by harmap.run on the path, and by
    harmap.run on a (vertices, faces) pair."""
    import harmap

    spot = shared("meshes/spot.obj")
    d = tmp_path_factory.mktemp("spot")
    cli("run", spot, "-o", d / "cli.harmap", "--resolution", 64)
    harmap.run(spot, out=d / "path.harmap", resolution=64, progress=False)
    harmap.run(read_obj(spot), out=d / "arrays.harmap", resolution=64, progress=False)
    return d


@pytest.fixture(scope="session")
def chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    _need("chromium", "apt-get install -y chromium")
