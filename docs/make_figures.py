"""Draw the README/guide figures from run directories, reading them with zarr-python.

    python docs/make_figures.py RUN [RUN ...] -o docs/img/labels.png

Each run gets one panel: the label slice through the shape center (z = center voxel),
colored by label, with world axes from the run's grid attributes.
"""
import argparse
import json
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import zarr
from matplotlib.colors import ListedColormap

NAMES = ["exterior", "boundary", "interior", "center", "layer 1", "layer 2", "layer 3", "layer 4"]
COLORS = ["#ffffff", "#08306b", "#9ecae1", "#000000", "#fdd49e", "#fdbb84", "#fc8d59", "#e34a33"]


def panel(ax, run):
    root = zarr.open_group(str(run), mode="r")
    h = root.attrs["harmap"]
    g = h["grid"]
    cz = h["center_voxel"][0]
    lab = np.asarray(root["labels/0"][cz, :, :])
    ox, oy, oz = g["origin"]
    s = g["spacing"]
    ny, nx = lab.shape
    extent = [ox - s / 2, ox + s * (nx - 0.5), oy - s / 2, oy + s * (ny - 0.5)]
    ax.imshow(lab, origin="lower", extent=extent, cmap=ListedColormap(COLORS), vmin=-0.5, vmax=7.5, interpolation="nearest")
    cx, cy, _ = h["center"]
    ax.plot([cx], [cy], "+", color="#2ca02c", ms=14, mew=2)
    name = pathlib.Path(h["input"]["path"] or "starfish").name
    r = h["stages"]["voxelize"]["result"]
    ax.set_title(f"{name}: slice z = {oz + s * cz:.3g}\n{nx}x{ny}x{g['shape'][0]} voxels, genus {r['genus']}", fontsize=9)
    ax.set_xlabel("x")
    ax.set_ylabel("y")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("runs", nargs="+")
    p.add_argument("-o", "--output", required=True)
    a = p.parse_args()
    fig, axes = plt.subplots(1, len(a.runs), figsize=(4.2 * len(a.runs), 4.4), squeeze=False)
    for ax, run in zip(axes[0], a.runs):
        panel(ax, run)
    handles = [plt.Rectangle((0, 0), 1, 1, fc=c, ec="#888888") for c in COLORS]
    fig.legend(handles, NAMES, loc="lower center", ncol=8, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    pathlib.Path(a.output).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.output, dpi=110)


if __name__ == "__main__":
    main()
