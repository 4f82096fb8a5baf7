"""harmap: out-of-core harmonic volumetric parameterization, from Python.

Maps the volume of a genus-0 solid onto the unit ball (voxelize, solve Laplace's
equation, trace streamlines of -grad(phi), map every voxel). The stages are the ones of
the ``harmap`` command, with its options as keyword arguments and its defaults, and they
write the same run directory (a Zarr v3 group) with the same bytes.

    >>> import harmap
    >>> r = harmap.run("spot.obj", out="spot.harmap", resolution=64)
    >>> r.stages["solve"]["result"]["iterations"]
    >>> r.phi[32, 32, :]            # a zarr array, read lazily

Shapes may be a path, a ``(vertices, faces)`` pair of arrays, a mesh object with
``.vertices`` and ``.faces`` (trimesh), an ``(N, 4)`` array of atom centers and radii,
or a 3-D label array (numpy or zarr; anything > 0 is inside).

Errors raise :class:`HarmapError` (a ``ValueError``) with the command's message.
Progress goes to tqdm when it is installed (``progress=False`` turns it off). Long calls
release the GIL; Ctrl-C during a solve checkpoints it and raises ``KeyboardInterrupt``
(``solve(run, resume=True)`` continues); the other stages finish first, then raise it.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from . import _harmap
from ._harmap import HarmapError

__all__ = [
    "HarmapError",
    "Run",
    "open",
    "run",
    "voxelize",
    "solve",
    "trace",
    "map",
    "inverse",
    "export",
    "atlas",
    "report",
    "__version__",
]

__version__ = _harmap.version()

_STAGES = ("voxelize", "solve", "trace", "map")


# ----------------------------------------------------------------------------- progress


class _Bars:
    """Progress through tqdm: one bar per phase the library starts."""

    def __init__(self, enabled):
        self.bar = None
        self.phase = None
        self.tqdm = None
        if enabled:
            try:
                from tqdm.auto import tqdm
            except ImportError:
                tqdm = None
            self.tqdm = tqdm

    def __call__(self, phase, name, position, total, message):
        if self.tqdm is None:
            return
        if phase != self.phase:
            self.close()
            self.phase = phase
            self.bar = self.tqdm(total=total or None, desc=name, leave=False)
        b = self.bar
        if total and b.total != total:
            b.total = total
        if position != b.n:
            b.update(position - b.n)
        if message:
            b.set_postfix_str(message, refresh=False)

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self):
        return self if self.tqdm is not None else None

    def __exit__(self, *exc):
        self.close()
        return False


def _duration(v):
    """Seconds from 300, "90s", "10m" or "1h" (as --checkpoint-every takes them)."""
    if isinstance(v, (int, float)):
        if v < 0:
            raise HarmapError(f"checkpoint_every {v} is negative")
        return float(v)
    t = str(v).strip()
    mult = {"s": 1.0, "m": 60.0, "h": 3600.0}.get(t[-1:], None)
    num = t[:-1] if mult else t
    try:
        x = float(num) * (mult or 1.0)
    except ValueError:
        raise HarmapError(f"'{v}' is not a duration like 90s, 10m or 1h") from None
    if x < 0 or x != x:
        raise HarmapError(f"'{v}' is not a duration like 90s, 10m or 1h")
    return x


def _mem(v):
    return str(v) if not isinstance(v, int) else f"{v}B"


# ----------------------------------------------------------------------------- the run


class Run:
    """A run directory: its metadata, stage reports and fields.

    Opening reads only the group's ``zarr.json``; the fields are zarr arrays opened on
    first use (zarr-python is imported then), and read lazily.
    """

    def __init__(self, path):
        self.path = Path(path)
        meta = self.path / "zarr.json"
        try:
            with meta.open() as f:
                doc = json.load(f)
        except FileNotFoundError:
            raise HarmapError(
                f"{self.path}: not a harmap run (no zarr.json); make one with "
                "harmap.voxelize or harmap.run"
            ) from None
        except (OSError, ValueError) as e:
            raise HarmapError(f"{meta}: cannot read: {e}") from None
        attrs = doc.get("attributes", {}).get("harmap")
        if not isinstance(attrs, dict):
            raise HarmapError(f"{self.path}: a Zarr group but not a harmap run (no harmap attributes)")
        self.metadata = attrs
        #: What :func:`run` did with each stage (None for a run opened otherwise).
        self.pipeline = None
        self._arrays = {}

    def __repr__(self):
        done = [s for s in _STAGES if self.done(s)]
        return f"harmap.Run({str(self.path)!r}, stages={done})"

    def __fspath__(self):
        return os.fspath(self.path)

    def reload(self):
        """Read the metadata again (after a stage ran elsewhere)."""
        self.__init__(self.path)
        return self

    @property
    def stages(self):
        """Stage name -> its record (status, seconds, options, result, peak memory)."""
        return self.metadata.get("stages", {})

    def report(self, stage):
        """The result of ``stage`` (voxelize, solve, trace or map) as a dict."""
        try:
            return self.stages[stage]["result"]
        except KeyError:
            raise HarmapError(f"{self.path}: stage {stage} has not run") from None

    def done(self, stage):
        """Whether ``stage`` is done."""
        return self.stages.get(stage, {}).get("status") == "done"

    @property
    def grid(self):
        """The grid: shape (z, y, x), origin, spacing, chunk, unit."""
        return self.metadata.get("grid", {})

    @property
    def input(self):
        """What was voxelized: path, format, sha256."""
        return self.metadata.get("input", {})

    def _array(self, name):
        if name not in self._arrays:
            if not (self.path / name / "0").exists():
                raise HarmapError(f"{self.path}: no {name} yet (run the stage that makes it)")
            import zarr

            self._arrays[name] = zarr.open_array(str(self.path / name / "0"), mode="r")
        return self._arrays[name]

    @property
    def labels(self):
        """The voxel labels (uint8, z, y, x) as a read-only zarr array."""
        return self._array("labels")

    @property
    def phi(self):
        """phi (float64; NaN outside the problem) as a read-only zarr array."""
        return self._array("phi")

    @property
    def theta(self):
        """theta, the polar angle on the ball (float64), as a read-only zarr array."""
        return self._array("theta")

    @property
    def psi(self):
        """psi, the azimuth on the ball (float64), as a read-only zarr array."""
        return self._array("psi")

    @property
    def u(self):
        """u = 1 - phi (float64) as a read-only zarr array."""
        return self._array("u")

    @property
    def seeds(self):
        """The seed table: column name -> numpy array (one row per streamline)."""
        if not (self.path / "seeds").exists():
            raise HarmapError(f"{self.path}: no seed table yet (run harmap.trace)")
        import zarr

        g = zarr.open_group(str(self.path / "seeds"), mode="r")
        return {name: a[...] for name, a in sorted(g.arrays())}

    def seeds_frame(self):
        """The seed table as a pandas DataFrame (vector columns split into _x, _y, _z)."""
        import pandas as pd

        cols = {}
        for k, v in self.seeds.items():
            if v.ndim == 2 and v.shape[1] == 3:
                for j, ax in enumerate("xyz"):
                    cols[f"{k}_{ax}"] = v[:, j]
            elif v.ndim == 1:
                cols[k] = v
            else:
                for j in range(v.shape[1]):
                    cols[f"{k}_{j}"] = v[:, j]
        return pd.DataFrame(cols)


def open(run):  # noqa: A001 - the name of the API
    """Open a run directory (cheap: reads its metadata only)."""
    return Run(run)


# ----------------------------------------------------------------------------- shapes


def _temp_in(out, suffix):
    out = Path(out)
    parent = out.parent if str(out.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{out.name}.input-", suffix=suffix, dir=parent)
    os.close(fd)
    return Path(name)


def _write_obj(path, vertices, faces):
    import numpy as np

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise HarmapError(f"vertices: an (N, 3) array expected, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise HarmapError(f"faces: an (M, 3) array of vertex indices expected, got shape {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise HarmapError(f"faces: integer vertex indices expected, got {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise HarmapError(
            f"faces: vertex index {int(f.min()) if f.min() < 0 else int(f.max())} is outside "
            f"0..{len(v) - 1} (0-based indices into vertices)"
        )
    if not np.isfinite(v).all():
        raise HarmapError("vertices: not all finite (NaN or infinity)")
    # %.17g gives back the same float64 when read: the mesh is the one handed over.
    with path.open("w") as fh:
        fh.write("# written by harmap (Python) from arrays\n")
        np.savetxt(fh, v, fmt="v %.17g %.17g %.17g")
        np.savetxt(fh, f.astype(np.int64) + 1, fmt="f %d %d %d")


def _write_xyzr(path, atoms):
    import numpy as np

    a = np.asarray(atoms, dtype=np.float64)
    with path.open("w") as fh:
        fh.write("# x y z r, written by harmap (Python) from an (N, 4) array\n")
        np.savetxt(fh, a, fmt="%.17g %.17g %.17g %.17g")


_RAW = {
    "uint8": "u8",
    "bool": "u8",
    "uint16": "u16",
    "int16": "i16",
    "uint32": "u32",
    "int32": "i32",
    "float32": "f32",
    "float64": "f64",
}


def _write_raw(path, labels):
    import numpy as np

    a = np.asarray(labels)
    if a.ndim != 3:
        raise HarmapError(f"label volume: a 3-D array (z, y, x) expected, got shape {a.shape}")
    kind = _RAW.get(a.dtype.name)
    if kind is None:
        raise HarmapError(
            f"label volume: dtype {a.dtype} is not supported; use uint8, uint16, int16, "
            "uint32, int32, float32 or float64"
        )
    if a.dtype == bool:
        a = a.astype(np.uint8)
    a.astype(a.dtype.newbyteorder("<"), copy=False).tofile(path)
    return list(a.shape), kind


def _is_zarr_array(x):
    t = type(x)
    return t.__module__.startswith("zarr") and hasattr(x, "shape") and hasattr(x, "dtype")


def _classify(shape):
    """(kind, payload) of a shape argument."""
    if shape is None:
        return "starfish", None
    if isinstance(shape, (str, os.PathLike)):
        return "path", Path(shape)
    if hasattr(shape, "vertices") and hasattr(shape, "faces"):
        return "mesh", (shape.vertices, shape.faces)
    if isinstance(shape, (tuple, list)) and len(shape) == 2:
        return "mesh", (shape[0], shape[1])
    if _is_zarr_array(shape):
        return "labels", shape
    if hasattr(shape, "__array__") or hasattr(shape, "ndim"):
        import numpy as np

        a = np.asarray(shape)
        if a.ndim == 3:
            return "labels", a
        if a.ndim == 2 and a.shape[1] == 4:
            return "atoms", a
        raise HarmapError(
            f"an array of shape {a.shape}: expected an (N, 4) array of atom centers and "
            "radii or a 3-D label volume"
        )
    raise HarmapError(
        f"cannot use a {type(shape).__name__} as a shape: give a path, (vertices, faces), "
        "a mesh with .vertices and .faces, an (N, 4) atom array or a 3-D label array"
    )


# ----------------------------------------------------------------------------- stages


def voxelize(
    shape=None,
    out=None,
    *,
    force=False,
    resolution=None,
    spacing=None,
    padding=6,
    center=None,
    center_radius=2.0,
    topology="auto",
    allow_genus=False,
    keep_largest=False,
    close=0,
    unit=None,
    chunk=64,
    mem="1GiB",
    scratch="auto",
    raw_shape=None,
    raw_dtype=None,
    surface="ses",
    probe=1.4,
    model=None,
    keep_hetatm=False,
    radius=None,
    progress=True,
):
    """Voxelize ``shape`` into a new run directory ``out`` (``harmap voxelize``).

    ``shape``: a path (any format harmap reads), a ``(vertices, faces)`` pair, a mesh
    with ``.vertices``/``.faces``, an ``(N, 4)`` array of atom centers and radii, a 3-D
    label array, or None for the built-in starfish (centered at its middle). Shapes in
    memory are written into the run (``input.obj``, ``input.xyzr``, ``input.raw``) and
    read from there, exactly as the command reads a file. ``probe`` may be a list (a
    probe ladder). ``topology``: "auto", "repair" or "strict" (``--topology``).
    Returns the :class:`Run`.
    """
    kind, payload = _classify(shape)
    out = _default_out(kind, payload, out)
    probes = _probes(probe)
    with _Shape(kind, payload, out) as path:
        if kind == "labels":
            raw_shape, raw_dtype = path.raw
        with _Bars(progress) as bars:
            _harmap.voxelize(
                path.arg,
                str(out),
                force=force,
                resolution=resolution,
                spacing=spacing,
                padding=padding,
                center=None if center is None else [float(c) for c in center],
                center_radius=center_radius,
                topology=topology,
                allow_genus=allow_genus,
                keep_largest=keep_largest,
                close=close,
                unit=unit,
                chunk=chunk,
                mem=_mem(mem),
                scratch=scratch,
                raw_shape=None if raw_shape is None else [int(s) for s in raw_shape],
                raw_dtype=raw_dtype,
                surface=surface,
                probe=probes,
                model=model,
                keep_hetatm=keep_hetatm,
                radius=radius,
                progress=bars,
            )
    return Run(out)


def _default_out(kind, payload, out):
    """The run directory: ``out``, or the input's name with .harmap (as the command)."""
    if out is None:
        if kind == "path":
            return Path(payload.name.split(".")[0] + ".harmap")
        if kind == "starfish":
            return Path("starfish.harmap")
        raise HarmapError("out: give the run directory for a shape in memory")
    return Path(out)


def _probes(probe):
    return [float(p) for p in (probe if isinstance(probe, (list, tuple)) else [probe])]


class _Shape:
    """A shape as the file the library reads: a path as it is, a shape in memory
    written to a temporary file beside ``out``. On leaving, a temporary file that the
    run at ``out`` now names as its input is moved into the run (``input.<ext>``), so
    the later stages (and a later call) find it; otherwise it is removed."""

    _SUFFIX = {"mesh": ".obj", "atoms": ".xyzr", "labels": ".raw"}

    def __init__(self, kind, payload, out):
        self.kind, self.payload, self.out = kind, payload, Path(out)
        self.temp = None
        self.raw = None

    def __enter__(self):
        if self.kind == "path":
            self.arg = str(self.payload)
        elif self.kind == "starfish":
            self.arg = None
        else:
            self.temp = _temp_in(self.out, self._SUFFIX[self.kind])
            self.arg = str(self.temp)
            try:
                if self.kind == "mesh":
                    _write_obj(self.temp, *self.payload)
                elif self.kind == "atoms":
                    _write_xyzr(self.temp, self.payload)
                else:
                    self.raw = _write_raw(self.temp, self.payload)
            except BaseException:
                self.temp.unlink(missing_ok=True)
                raise
        return self

    def __exit__(self, *exc):
        if self.temp is None:
            return False
        try:
            recorded = Run(self.out).metadata.get("input", {}).get("path")
        except Exception:  # no run there (the voxelization failed)
            recorded = None
        if recorded and Path(recorded).resolve() == self.temp.resolve():
            _harmap.adopt_input(str(self.out), str(self.temp), self.kind)
        else:
            self.temp.unlink(missing_ok=True)
        return False


def solve(
    run,
    *,
    method="multigrid",
    cycle="fmg",
    rtol=1e-6,
    tol=0.0,
    eps=1e-4,
    max_iter=1000,
    omega=None,
    checkpoint_every="5m",
    mem="1GiB",
    resume=False,
    progress=True,
):
    """Solve Laplace's equation for phi (``harmap solve``); returns the solve's report.

    Ctrl-C writes a checkpoint and raises KeyboardInterrupt; ``resume=True`` continues
    from it and gives the same bytes as an uninterrupted solve.
    """
    with _Bars(progress) as bars:
        r = _harmap.solve(
            os.fspath(run),
            method=method,
            cycle=cycle,
            rtol=rtol,
            tol=tol,
            eps=eps,
            max_iter=max_iter,
            omega=omega,
            checkpoint_every=_duration(checkpoint_every),
            mem=_mem(mem),
            resume=resume,
            progress=bars,
        )
    return json.loads(r)


def trace(
    run,
    *,
    seeds="surface",
    sample=None,
    stop_radius=None,
    tile=None,
    mem="1GiB",
    atol=None,
    rtol=0.0,
    h_min=1e-6,
    h_max=2.0,
    max_steps=20000,
    level_step=None,
    untangle=False,
    no_untangle=False,
    progress=True,
):
    """Trace streamlines from the seeds to the center (``harmap trace``); returns the
    trace's report. ``seeds``: "surface" (the input mesh's vertices, or the labels'
    surface nets; the command's default, whose triangles give the flip counts) or
    "boundary" (every boundary voxel). ``atol`` and ``level_step`` default by the
    seeds, as the command's. A whole surface's sphere map (surface seeds without a
    sample) is untangled by default, as the command's: theta and psi become the
    untangled map, arrival_theta and arrival_psi keep the arrivals; ``no_untangle=True``
    keeps the arrivals as the map (``--no-untangle``); ``untangle=True`` asks for it and
    is refused with boundary seeds or a sample. Ctrl-C stops it within about a second
    (KeyboardInterrupt)."""
    with _Bars(progress) as bars:
        r = _harmap.trace(
            os.fspath(run),
            seeds=seeds,
            sample=sample,
            stop_radius=stop_radius,
            tile=tile,
            mem=_mem(mem),
            atol=atol,
            rtol=rtol,
            h_min=h_min,
            h_max=h_max,
            max_steps=max_steps,
            level_step=level_step,
            untangle=untangle,
            no_untangle=no_untangle,
            progress=bars,
        )
    return json.loads(r)


def map(run, *, exact=False, mem="1GiB", progress=True):  # noqa: A001 - the stage's name
    """Map every voxel to (theta, psi) (``harmap map``); returns the map's report."""
    with _Bars(progress) as bars:
        r = _harmap.map(os.fspath(run), exact=exact, mem=_mem(mem), progress=bars)
    return json.loads(r)


def inverse(run, phi, theta, psi, *, mem="1GiB", progress=True):
    """Points of the solid for coordinates (phi, theta, psi) (``harmap inverse``).

    ``phi``, ``theta`` and ``psi`` are arrays of one shape (or broadcast to one).
    Returns ``(points, status)``: points of that shape plus a last axis of 3 (x, y, z;
    NaN where there is no point) and a list with the reason for each row without a
    point ("" for the others).
    """
    import numpy as np

    p, t, s = np.broadcast_arrays(
        np.asarray(phi, dtype=np.float64),
        np.asarray(theta, dtype=np.float64),
        np.asarray(psi, dtype=np.float64),
    )
    shape = p.shape
    flat = [np.ascontiguousarray(x).reshape(-1) for x in (p, t, s)]
    with _Bars(progress) as bars:
        pts, status = _harmap.inverse(os.fspath(run), *flat, mem=_mem(mem), progress=bars)
    return pts.reshape(shape + (3,)), status


def export(run, dest, format, *, field=None, sample=None, mem="1GiB", force=False, progress=True):  # noqa: A002
    """Export (``harmap export``): format "csv", "obj-sphere", "vtk-streamlines",
    "nifti", "vti", "dx" or "ome-zarr"; returns the count the command prints.

    As the command, it refuses (ValueError) an existing ``dest`` that is not its own
    earlier output of the same format, and anything inside a run directory, unless
    ``force=True``; even then it never deletes a run or a folder it did not write."""
    with _Bars(progress) as bars:
        return _harmap.export(
            os.fspath(run),
            os.fspath(dest),
            format,
            field=field,
            sample=sample,
            mem=_mem(mem),
            force=force,
            progress=bars,
        )


def atlas(run, dest, *, sphere=False, color=None):
    """Draw the theta-psi atlas (or with ``sphere=True`` the sphere view) to ``dest``
    (.png or .svg); returns the number of points drawn."""
    return _harmap.atlas(os.fspath(run), os.fspath(dest), sphere=sphere, color=color)


def report(run, dest=None):
    """Write the run's report page (``harmap report``; default: the run's name with
    .report.html); returns its path."""
    run = Path(os.fspath(run))
    dest = Path(dest) if dest is not None else run.with_suffix(".report.html")
    _harmap.report_page(str(run), str(dest))
    return dest


def run(
    shape=None,
    out=None,
    *,
    force=False,
    resolution=None,
    spacing=None,
    padding=6,
    center=None,
    center_radius=2.0,
    topology="auto",
    allow_genus=False,
    keep_largest=False,
    close=0,
    unit=None,
    chunk=64,
    mem="1GiB",
    scratch="auto",
    raw_shape=None,
    raw_dtype=None,
    surface="ses",
    probe=1.4,
    model=None,
    keep_hetatm=False,
    radius=None,
    method="multigrid",
    cycle="fmg",
    rtol=1e-6,
    tol=0.0,
    eps=1e-4,
    max_iter=1000,
    omega=None,
    checkpoint_every="5m",
    seeds="surface",
    sample=None,
    stop_radius=None,
    tile=None,
    atol=None,
    h_min=1e-6,
    h_max=2.0,
    max_steps=20000,
    level_step=None,
    untangle=False,
    no_untangle=False,
    trace_rtol=0.0,
    exact=False,
    progress=True,
):
    """The whole pipeline (``harmap run``, through the same library call): voxelize,
    solve, trace (surface seeds by default), map, the atlas (``<out>.atlas.png``) and
    the report page (``<out>.report.html``). The keyword arguments are the command's
    flags with the same defaults (``trace_rtol`` is the trace's ``rtol``; ``rtol`` is
    the solve's).

    As the command: stages already done in ``out`` with the same options are skipped
    (so calling again finishes a stopped run), a stage whose options changed runs again
    with the stages that read it, an interrupted solve is continued from its
    checkpoint, and a run of another input or other voxelization options is refused
    unless ``force=True``. Ctrl-C stops the stage running within about a second
    (KeyboardInterrupt); the finished stages are kept. Returns the :class:`Run`, whose
    ``pipeline`` attribute says what was done with each stage.
    """
    kind, payload = _classify(shape)
    out = _default_out(kind, payload, out)
    with _Shape(kind, payload, out) as path:
        if kind == "labels":
            raw_shape, raw_dtype = path.raw
        with _Bars(progress) as bars:
            done = _harmap.run(
                path.arg,
                str(out),
                force=force,
                resolution=resolution,
                spacing=spacing,
                padding=padding,
                center=None if center is None else [float(c) for c in center],
                center_radius=center_radius,
                topology=topology,
                allow_genus=allow_genus,
                keep_largest=keep_largest,
                close=close,
                unit=unit,
                chunk=chunk,
                mem=_mem(mem),
                scratch=scratch,
                raw_shape=None if raw_shape is None else [int(s) for s in raw_shape],
                raw_dtype=raw_dtype,
                surface=surface,
                probe=_probes(probe),
                model=model,
                keep_hetatm=keep_hetatm,
                radius=radius,
                method=method,
                cycle=cycle,
                rtol=rtol,
                tol=tol,
                eps=eps,
                max_iter=max_iter,
                omega=omega,
                checkpoint_every=_duration(checkpoint_every),
                seeds=seeds,
                sample=sample,
                stop_radius=stop_radius,
                tile=tile,
                atol=atol,
                h_min=h_min,
                h_max=h_max,
                max_steps=max_steps,
                level_step=level_step,
                untangle=untangle,
                no_untangle=no_untangle,
                trace_rtol=trace_rtol,
                exact=exact,
                atlas=str(out.with_suffix(".atlas.png")),
                report=str(out.with_suffix(".report.html")),
                progress=bars,
            )
    r = Run(out)
    r.pipeline = json.loads(done)
    return r
