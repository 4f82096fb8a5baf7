#!/usr/bin/env python3
"""harmap's molecular solids against APBS's, voxel by voxel.

    python benches/compare_apbs.py [--harmap target/release/harmap] [--spacing 0.5]
                                   [--work DIR] MOLECULE [MOLECULE ...]

MOLECULE is a .pqr file, or a .pdb file that pdb2pqr (PyPI `pdb2pqr`, PARSE force
field) turns into one first. Atoms of radius 0 (PARSE's hydrogens) are dropped, since
APBS skips them and harmap would give them table radii, and so are waters, which harmap
leaves out; both programs then read the same PQR, so the balls agree.

For each molecule:
1. `harmap voxelize X.pqr --spacing H --surface vdw|ses --probe 1.4 --allow-genus`;
2. APBS (`apbs`, Debian package) in mg-dummy mode writes its van der Waals map
   (`write vdw dx`) and molecular-surface map (`write smol dx`, `srfm mol`, `srad 1.4`)
   on a grid of the same spacing whose points coincide with harmap's voxel centers
   (APBS's dime is 32k+1, so its grid is a little larger and offset by whole voxels);
3. enclosed voids are filled on APBS's side as harmap fills them (scipy
   `binary_fill_holes`, whose default structure makes the background 6-connected, as in
   harmap's fill; APBS keeps every cavity a probe fits in, reachable or not, where
   harmap leaves the unreachable ones solid, so on APBS's side this fill is all that
   closes them), and
   the two solids are compared on the voxels near the molecule
   (inside either solid, or within 2 voxels of one), and on those of them more than one
   voxel from either surface.

Prints one line per molecule and surface: voxels compared, agreement, agreement away
from the surface. Needs: numpy, scipy, zarr, gridDataFormats, pdb2pqr (for .pdb), apbs.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import zarr
from gridData import Grid
from scipy import ndimage


def same_radii(pqr: Path, work: Path) -> Path:
    """The PQR without its radius-0 atoms (pdb2pqr's PARSE hydrogens), which APBS skips
    and harmap would give table radii, and without waters, which harmap leaves out."""
    out = work / (pqr.stem + ".same.pqr")
    lines = []
    for line in pqr.read_text().splitlines():
        f = line.split()
        if f and f[0] in ("ATOM", "HETATM") and (float(f[-1]) == 0.0 or f[3] in ("HOH", "WAT")):
            continue
        lines.append(line)
    out.write_text("\n".join(lines) + "\n")
    return out


def to_pqr(mol: Path, work: Path) -> Path:
    if mol.suffix.lower() == ".pqr":
        return same_radii(mol, work)
    out = work / (mol.stem + ".pqr")
    exe = shutil.which("pdb2pqr30") or shutil.which("pdb2pqr")
    if exe is None:
        sys.exit("pdb2pqr is needed for .pdb inputs (pip install pdb2pqr)")
    subprocess.run([exe, "--ff=PARSE", "--keep-chain", str(mol), str(out)], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return same_radii(out, work)


def harmap_solid(harmap: str, pqr: Path, surface: str, spacing: float, work: Path):
    run = work / f"{pqr.stem}-{surface}.harmap"
    subprocess.run([harmap, "-q", "--progress", "never", "voxelize", str(pqr), "-o", str(run),
                    "--spacing", str(spacing), "--surface", surface, "--probe", "1.4",
                    "--allow-genus", "--keep-largest", "--force"], check=True)
    g = zarr.open_group(str(run), mode="r")
    grid = g.attrs["harmap"]["grid"]
    lab = np.asarray(g["labels/0"])
    return np.isin(lab, [1, 2, 3]), np.array(grid["origin"]), float(grid["spacing"])


def apbs_maps(pqr: Path, shape_zyx, origin, h, work: Path):
    n = np.array(shape_zyx[::-1])  # x, y, z
    dime = ((n + 4 + 31) // 32) * 32 + 1
    off = (dime - n) // 2  # APBS index of harmap voxel 0, per axis
    glen = (dime - 1) * h
    lower = origin - off * h
    gcent = lower + glen / 2
    inp = work / f"{pqr.stem}.in"
    inp.write_text(f"""read
    mol pqr {pqr.resolve()}
end
elec name dummy
    mg-dummy
    dime {dime[0]} {dime[1]} {dime[2]}
    glen {glen[0]:.6f} {glen[1]:.6f} {glen[2]:.6f}
    gcent {gcent[0]:.6f} {gcent[1]:.6f} {gcent[2]:.6f}
    mol 1
    lpbe
    bcfl zero
    pdie 2.0
    sdie 78.54
    srfm mol
    chgm spl2
    srad 1.4
    swin 0.3
    sdens 10.0
    temp 298.15
    write smol dx {work / (pqr.stem + '-smol')}
    write vdw dx {work / (pqr.stem + '-vdw')}
end
quit
""")
    subprocess.run(["apbs", str(inp)], check=True, cwd=work, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    out = {}
    for name in ("smol", "vdw"):
        path = work / f"{pqr.stem}-{name}.dx"
        if not path.exists():  # APBS 3 names them -PE0.dx
            path = work / f"{pqr.stem}-{name}-PE0.dx"
        gr = Grid(str(path))
        assert np.allclose(gr.delta, h), gr.delta
        assert np.allclose(gr.origin, lower, atol=1e-4), (gr.origin, lower)
        inside = gr.grid < 0.5  # APBS: 0 inside the surface, 1 in the solvent
        inside = ndimage.binary_fill_holes(inside)
        sub = inside[off[0]:off[0] + n[0], off[1]:off[1] + n[1], off[2]:off[2] + n[2]]
        out[name] = sub.transpose(2, 1, 0)  # to z, y, x
    return out


def compare(a, b):
    near = ndimage.binary_dilation(a | b, iterations=2)
    agree = (a == b) & near
    # More than one voxel from either surface.
    def depth(s):
        # Distance to the other side: inside to the nearest outside voxel and back.
        return ndimage.distance_transform_edt(s) + ndimage.distance_transform_edt(~s)
    away = near & (depth(a) > 1.0) & (depth(b) > 1.0)
    return int(near.sum()), agree.sum() / near.sum(), (agree & away).sum() / max(away.sum(), 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("molecules", nargs="+", type=Path)
    ap.add_argument("--harmap", default="target/release/harmap")
    ap.add_argument("--spacing", type=float, default=0.5)
    ap.add_argument("--work", type=Path)
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="harmap-apbs-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"{'molecule':<14} {'surface':<8} {'voxels near':>12} {'agree':>8} {'agree >1 voxel from surface':>28}")
    for mol in a.molecules:
        pqr = to_pqr(mol, work)
        for surface, key in (("vdw", "vdw"), ("ses", "smol")):
            solid, origin, h = harmap_solid(a.harmap, pqr, surface, a.spacing, work)
            maps = apbs_maps(pqr, solid.shape, origin, h, work)
            n, agree, away = compare(solid, maps[key])
            print(f"{mol.stem:<14} {surface:<8} {n:>12} {100 * agree:>7.3f}% {100 * away:>27.3f}%")


if __name__ == "__main__":
    main()
