#!/usr/bin/env python3
"""Check harmap's exports with the tools their users read them with.

    python check_exports.py RUN OUTDIR

OUTDIR holds what `harmap export RUN` wrote: phi.nii, theta.nii.gz, all.vti, phi.dx,
lines.vtk and images.ome.zarr. Each is read with the reader of its community and
compared with the run's own Zarr arrays (read with zarr-python):

- nibabel: both NIfTI files, data (x, y, z order) and the affine that puts voxel (i, j, k)
  at origin + spacing * (i, j, k);
- VTK: the .vti (vtkXMLImageDataReader: extent, origin, spacing, phi/theta/psi/labels)
  and the streamlines (vtkPolyDataReader: lines, points, cell data);
- GridDataFormats (MDAnalysis' reader of APBS grids): the .dx, values and geometry;
- zarr-python and ome-zarr: the OME-Zarr export (values, scale and translation).

Exit status 0 and "ok: ..." on success; 1 and "FAIL: ..." on the first failed check.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


class CheckError(Exception):
    pass


def require(cond, msg):
    if not cond:
        raise CheckError(msg)


def same(a, b, what, rtol=0.0):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    require(a.shape == b.shape, f"{what}: shape {a.shape} != {b.shape}")
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    require((nan_a == nan_b).all(), f"{what}: NaN at different voxels ({(nan_a != nan_b).sum()})")
    ok = ~nan_a
    if rtol == 0.0:
        require((a[ok] == b[ok]).all(), f"{what}: values differ (max {np.abs(a[ok] - b[ok]).max()})")
    else:
        require(np.allclose(a[ok], b[ok], rtol=rtol, atol=rtol), f"{what}: values differ beyond {rtol}")


def main(run: Path, out: Path) -> str:
    import zarr

    g = zarr.open_group(str(run), mode="r")
    meta = g.attrs["harmap"]
    grid = meta["grid"]
    nz, ny, nx = grid["shape"]
    h = float(grid["spacing"])
    origin = np.array(grid["origin"], dtype=np.float64)  # x, y, z
    fields = {n: np.asarray(g[f"{n}/0"]) for n in ("phi", "theta", "psi", "labels")}
    stored = dict(fields)
    # The map stores theta and psi in f64; NIfTI, VTI and DX exports write them in f32,
    # value for value (the OME-Zarr export keeps the stored type).
    for n in ("theta", "psi"):
        fields[n] = fields[n].astype(np.float32)
    affine = np.eye(4)
    affine[:3, :3] *= h
    affine[:3, 3] = origin

    # NIfTI (nibabel): x fastest on disk, so the array is [x, y, z].
    import nibabel as nib

    img = nib.load(str(out / "phi.nii"))
    require(img.shape == (nx, ny, nz), f"phi.nii shape {img.shape}")
    require(np.allclose(img.affine, affine, atol=1e-5 * max(1.0, h)), f"phi.nii affine\n{img.affine}\n!=\n{affine}")
    require(img.header.get_data_dtype() == np.float64, "phi.nii is not float64")
    same(np.asarray(img.dataobj).transpose(2, 1, 0), fields["phi"], "phi.nii")
    # The voxel of a world point: a solid voxel's center goes back to its index.
    k, j, i = (int(c) for c in meta["center_voxel"])
    world = affine @ np.array([i, j, k, 1.0])
    back = np.linalg.inv(img.affine) @ world
    require(np.allclose(back[:3], [i, j, k], atol=1e-4), f"center voxel maps to {back[:3]}")
    img = nib.load(str(out / "theta.nii.gz"))
    require(img.header.get_data_dtype() == np.float32, "theta.nii.gz is not float32")
    same(np.asarray(img.dataobj).transpose(2, 1, 0), fields["theta"], "theta.nii.gz")

    # VTK image data and streamlines.
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    r = vtk.vtkXMLImageDataReader()
    r.SetFileName(str(out / "all.vti"))
    r.Update()
    im = r.GetOutput()
    require(im.GetDimensions() == (nx, ny, nz), f"all.vti dimensions {im.GetDimensions()}")
    require(np.allclose(im.GetOrigin(), origin), f"all.vti origin {im.GetOrigin()}")
    require(np.allclose(im.GetSpacing(), (h, h, h)), f"all.vti spacing {im.GetSpacing()}")
    pd = im.GetPointData()
    for name, arr in fields.items():
        a = pd.GetArray(name)
        require(a is not None, f"all.vti has no point array {name}")
        same(vtk_to_numpy(a).reshape(nz, ny, nx), arr, f"all.vti {name}")

    r = vtk.vtkPolyDataReader()
    r.SetFileName(str(out / "lines.vtk"))
    r.ReadAllScalarsOn()
    r.Update()
    poly = r.GetOutput()
    require(poly.GetNumberOfLines() > 0, "lines.vtk has no lines")
    pts = vtk_to_numpy(poly.GetPoints().GetData())
    require(np.isfinite(pts).all(), "lines.vtk has non-finite points")
    lo = origin - h
    hi = origin + h * np.array([nx, ny, nz])
    require(((pts >= lo) & (pts <= hi)).all(), "lines.vtk points outside the grid")
    stop = poly.GetCellData().GetArray("stop")
    require(stop is not None and stop.GetNumberOfTuples() == poly.GetNumberOfLines(), "lines.vtk: no stop per line")

    # OpenDX with GridDataFormats: counts nx ny nz, z fastest.
    from gridData import Grid

    dx = Grid(str(out / "phi.dx"))
    require(dx.grid.shape == (nx, ny, nz), f"phi.dx shape {dx.grid.shape}")
    require(np.allclose(dx.origin, origin), f"phi.dx origin {dx.origin}")
    require(np.allclose(dx.delta, (h, h, h)), f"phi.dx delta {dx.delta}")
    same(dx.grid.transpose(2, 1, 0), fields["phi"], "phi.dx", rtol=1e-11)

    # OME-Zarr export: the images with their values, scale and translation.
    eg = zarr.open_group(str(out / "images.ome.zarr"), mode="r")
    for name, arr in fields.items():
        same(np.asarray(eg[f"{name}/0"]), stored[name], f"images.ome.zarr/{name}")
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    nodes = list(Reader(parse_url(str(out / "images.ome.zarr" / "theta")))())
    require(nodes, "ome-zarr reads no image from images.ome.zarr/theta")
    ms = nodes[0].metadata
    ct = ms["coordinateTransformations"][0]
    scale = [t["scale"] for t in ct if t["type"] == "scale"][0]
    trans = [t["translation"] for t in ct if t["type"] == "translation"][0]
    require(np.allclose(scale, (h, h, h)), f"ome-zarr scale {scale}")
    require(np.allclose(trans, origin[::-1]), f"ome-zarr translation {trans}")

    return (
        f"NIfTI (nibabel {nib.__version__}), VTI and VTK (VTK {vtk.vtkVersion.GetVTKVersion()}), "
        f"DX (GridDataFormats), OME-Zarr (zarr {zarr.__version__}) match the run's "
        f"{nx}x{ny}x{nz} fields and geometry"
    )


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    try:
        print("ok: " + main(Path(sys.argv[1]), Path(sys.argv[2])))
    except CheckError as e:
        print(f"FAIL: {e}")
        sys.exit(1)
