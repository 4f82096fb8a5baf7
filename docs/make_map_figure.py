"""Draw the map figure of docs/map.md from run directories, reading them with zarr-python.

    python docs/make_map_figure.py RUN [RUN ...] -o docs/img/map-slices.png

One row per run: phi and psi on the slice z = center voxel, theta on the slice
x = center voxel (theta varies from pole to pole, along z), with world axes from the
run's grid attributes; NaN (outside the solid) is white.
"""
import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import zarr


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+")
    ap.add_argument("-o", required=True)
    a = ap.parse_args()
    fig, axes = plt.subplots(len(a.runs), 3, figsize=(13, 4.2 * len(a.runs)), squeeze=False)
    for row, run in zip(axes, a.runs):
        root = zarr.open_group(run, mode="r")
        h = root.attrs["harmap"]
        g = h["grid"]
        cz, _, cx = h["center_voxel"]
        ox, oy, oz = g["origin"]
        s = g["spacing"]
        name = pathlib.Path(run).name.replace(".harmap", "")
        for ax, (field, cmap, lo, hi) in zip(
            row,
            [("phi", "viridis", 0, 1), ("theta", "magma", 0, np.pi), ("psi", "twilight", -np.pi, np.pi)],
        ):
            if field == "theta":
                lab = np.asarray(root["labels/0"][:, :, cx])
                v = np.asarray(root[f"{field}/0"][:, :, cx]).astype(float)
                n1, n0 = lab.shape
                ext = [oy - s / 2, oy + s * (n0 - 0.5), oz - s / 2, oz + s * (n1 - 0.5)]
                ax.set_title(f"{name}: theta (slice x = {cx})")
                ax.set_xlabel("y")
                ax.set_ylabel("z")
            else:
                lab = np.asarray(root["labels/0"][cz])
                v = np.asarray(root[f"{field}/0"][cz]).astype(float)
                n1, n0 = lab.shape
                ext = [ox - s / 2, ox + s * (n0 - 0.5), oy - s / 2, oy + s * (n1 - 0.5)]
                ax.set_title(f"{name}: {field} (slice z = {cz})")
                ax.set_xlabel("x")
                ax.set_ylabel("y")
            v[~np.isin(lab, [1, 2, 3])] = np.nan
            im = ax.imshow(v, origin="lower", extent=ext, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
            fig.colorbar(im, ax=ax, shrink=0.8, label="radians" if field != "phi" else "")
    fig.tight_layout()
    fig.savefig(a.o, dpi=90)


if __name__ == "__main__":
    main()
