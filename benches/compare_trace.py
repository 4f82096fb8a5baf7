#!/usr/bin/env python3
"""harmap's streamline tracer vs VTK's vtkStreamTracer (RK45) on the same field and seeds.

    python3 -m venv /tmp/cmpvenv
    /tmp/cmpvenv/bin/pip install numpy 'zarr>=3' vtk
    /tmp/cmpvenv/bin/python benches/compare_trace.py RUN [--sample 50000] [--threads 2] [--json out.json]

RUN is a harmap run directory (Zarr v3 group) that has been solved (RUN/u/0 or RUN/phi/0),
e.g. `harmap bench solve --n 256 --dir /tmp/b --keep` -> /tmp/b/bench-solve-256.harmap.
The script runs `harmap --threads T -q --progress never trace RUN --sample N` itself, which
(re)writes RUN/seeds/; VTK then traces from the very seeds harmap used (RUN/seeds/position).

harmap (the binary next to this script, target/release/harmap, or --harmap / $HARMAP):
  * seconds = wall time of the whole command, measured here: start-up, reading u, the
    node directions, tracing and writing RUN/seeds. "trace s" is the trace stage's own
    `seconds` from RUN/zarr.json. Peak RSS: the child's ru_maxrss through GNU
    /usr/bin/time -f %M (a small process, so the parent's memory, which Linux carries
    across fork + exec into ru_maxrss, does not inflate it); without /usr/bin/time it is
    os.wait4's ru_maxrss, an upper bound (marked "<=").
  * its field: node directions grad(u)/|grad(u)|, u = 1 - phi (central differences,
    one-sided next to a node without a value), trilinearly interpolated; Dormand-Prince
    RK45 on arc length (atol 1e-6 voxels, steps 1e-6..2 voxels, 20000 steps); a line
    stops on entering the stop ball (RUN's stages.trace.result.stop_radius voxels around
    `center`). steps/line = accepted RK45 steps (RUN/seeds/steps); reached = stop code 0.

VTK (vtkStreamTracer, in a child process that reports its own peak RSS, VmHWM):
  * read s: reading RUN/u/0 (float64 [z,y,x]) with zarr-python into numpy (RUN/phi/0,
    as 1 - phi, when there is no u). Not part of VTK's "seconds".
  * grad s: u's NaNs (outside the solved region) set to min(u) - eps, i.e. phi to
    max(phi) + eps (eps = the solve's exterior layer spacing, 1e-4): one more "exterior
    layer", so the field there still points inwards (repels) and no NaN reaches VTK;
    u wrapped zero-copy as the point scalars of a vtkImageData (origin and spacing from
    the grid: voxel (k,j,i) at origin + spacing (i,j,k)); then the gradient of u, which
    is -grad(phi), with vtkImageGradient (dimensionality 3, boundaries handled, central
    differences / spacing): about 7x faster than the generic vtkGradientFilter at N=256
    (0.2 s vs 1.4 s; --vtk-gradient generic picks it). The gradient goes on a fresh
    vtkImageData as its only array (active vectors), so the tracer interpolates nothing
    else onto the lines. --vtk-field unit normalizes the node vectors first (harmap's
    field); the default traces the raw -grad(phi). vtkStreamTracer normalizes the
    interpolated vector inside each step, but interpolating raw gradients (whose size
    varies like 1/r^2 here) is not interpolating unit vectors: at N=256 VTK takes ~30%
    fewer steps to the stop ball on the unit field, whose lines match harmap's to 0.015
    degrees (0.02 on the raw field). With the unit field no line stagnates on a small
    |grad phi|.
  * trace s: the vtkStreamTracer Update()s: vtkRungeKutta45, FORWARD, step unit
    CELL_LENGTH (VTK's cell length is the cell's diagonal, sqrt(3) voxels, so the maximum
    step is 3.5 voxels where harmap's is 2), initial / minimum / maximum step
    0.5 / 0.01 / 2 cell lengths (--vtk-step), MaximumError 1e-6, MaximumNumberOfSteps
    2000 (both VTK's defaults; harmap allows 20000 but its lines take ~100), maximum
    propagation 4 grid diagonals (VTK's default, 1 world unit, would cut lines on any
    grid larger than that; --vtk-max-propagation), terminal speed 1e-12 (VTK's default;
    speed = |grad phi| per world unit), vorticity off (on by default in VTK, which then
    also computes normals; harmap has nothing like it), default interpolator. Seeds:
    RUN/seeds/position as the points of a vtkPolyData, --vtk-batch (1000) seeds per
    Update() so that lines running to the step limit cannot exhaust the memory.
    vtkSMPTools backend STDThread, --threads threads: vtkStreamTracer (VTK >= 9.1)
    splits the seeds over the SMP threads; the CPU seconds of each busy thread are
    printed. VTK's "seconds" = grad s + trace s.
  * VTK has no stop ball. A line runs on into the center sink (phi = 0 within
    ~center_radius voxels) until it stagnates (speed below the terminal speed) or, when
    no cell there has an all-zero gradient, circles the center until the step limit:
    that can be most of VTK's time. So a seed "reached" the center if its line's last
    point lies within the stop radius + --slack voxels (1) of `center`; "in ball" counts
    lines with any point within the stop radius; steps/line = points - 1 (each accepted
    step adds a point); "to ball" = steps before the first point within the stop radius
    (all of them for a line that never gets there): the part harmap traces too.
  * --vtk-stop-ball adds a second VTK line, "VTK, stop ball": the same, on the field
    zeroed at the nodes inside the stop ball, so a line stagnates within about a cell of
    where harmap stops: the like-for-like cost. (It bends the field in the cells that
    straddle the stop sphere a little, so its arrival angles differ a bit more.)
  * arrival: for seeds both tools bring into the stop ball, the angle at `center`
    between harmap's end point (RUN/seeds/end, on the stop sphere) and the point where
    VTK's polyline first crosses the stop sphere (median, 99th percentile, max in
    degrees): small when the two tracers follow the same field.

Ratio = VTK seconds / harmap seconds (and with VTK's read included). On a shared machine
use --repeat 3: each tool then shows its run of median seconds, all listed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

EPS_DEFAULT = 1e-4


# ---------------------------------------------------------------------------------------
# Common
# ---------------------------------------------------------------------------------------


def peak_rss_self() -> int:
    """This process's peak RSS in bytes: VmHWM on Linux. Not getrusage's ru_maxrss, which
    in a child also counts its parent's memory at fork (Linux carries it across exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r if sys.platform == "darwin" else r * 1024


def thread_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of each of this process's threads."""
    out = {}
    hz = os.sysconf("SC_CLK_TCK")
    try:
        for tid in os.listdir("/proc/self/task"):
            try:
                f = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
                out[int(tid)] = (int(f[11]) + int(f[12])) / hz
            except (OSError, IndexError, ValueError):
                pass
    except OSError:
        pass
    return out


def fail(msg: str) -> None:
    """Bad input: a message and exit code 2 (harmap's convention)."""
    print(f"error: {msg}", file=sys.stderr)
    sys.exit(2)


def run_attrs(run: Path) -> dict:
    return json.loads((run / "zarr.json").read_text()).get("attributes", {}).get("harmap", {})


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def thread_env(threads: int) -> dict:
    env = dict(os.environ)
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VTK_SMP_MAX_THREADS"):
        env[k] = str(threads)
    env["VTK_SMP_BACKEND_IN_USE"] = "STDThread"
    return env


# ---------------------------------------------------------------------------------------
# The VTK peer (run in a child process: `--worker-vtk`)
# ---------------------------------------------------------------------------------------


def vtk_worker(a) -> int:
    import zarr

    t_start = time.perf_counter()
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    t_import = time.perf_counter() - t_start
    st = vtk.vtkStreamTracer
    backend_ok = bool(vtk.vtkSMPTools.SetBackend("STDThread"))
    vtk.vtkSMPTools.Initialize(a.threads)
    vtk.vtkMultiThreader.SetGlobalMaximumNumberOfThreads(a.threads)
    vtk.vtkMultiThreader.SetGlobalDefaultNumberOfThreads(a.threads)

    run = Path(a.run)
    h = run_attrs(run)
    grid = h["grid"]
    shape = tuple(grid["shape"])  # z, y, x
    origin = [float(v) for v in grid["origin"]]
    spacing = float(grid["spacing"])
    center = np.array(h["center"], dtype=np.float64)
    eps = float(((h.get("stages", {}).get("solve") or {}).get("options") or {}).get("eps") or EPS_DEFAULT)
    r_stop = float(a.stop_radius) * spacing
    slack = float(a.slack) * spacing

    # Read the field.
    t0 = time.perf_counter()
    if (run / "u" / "0" / "zarr.json").is_file():
        u = np.ascontiguousarray(zarr.open_array(str(run / "u" / "0"), mode="r")[...], dtype=np.float64)
        source = "u/0"
    else:
        u = 1.0 - np.ascontiguousarray(zarr.open_array(str(run / "phi" / "0"), mode="r")[...], dtype=np.float64)
        source = "1 - phi/0"
    t_read = time.perf_counter() - t0
    if u.shape != shape:
        fail(f"{source} has shape {u.shape}, the grid {shape}")
    seeds = np.ascontiguousarray(zarr.open_array(str(run / "seeds" / "position"), mode="r")[...], dtype=np.float64)
    n = seeds.shape[0]

    # The field: the gradient of u (= -grad phi) on a vtkImageData.
    c0, t0 = time.process_time(), time.perf_counter()
    nan = np.isnan(u)
    n_nan = int(nan.sum())
    fill = float(np.nanmin(u)) - eps
    u[nan] = fill
    del nan
    image = vtk.vtkImageData()
    image.SetDimensions(shape[2], shape[1], shape[0])
    image.SetOrigin(*origin)
    image.SetSpacing(spacing, spacing, spacing)
    u_vtk = numpy_to_vtk(u.ravel(), deep=False)
    u_vtk.SetName("u")
    image.GetPointData().SetScalars(u_vtk)
    t_prepare = time.perf_counter() - t0
    t1 = time.perf_counter()
    if a.vtk_gradient == "image":
        gf = vtk.vtkImageGradient()
        gf.SetDimensionality(3)
        gf.HandleBoundariesOn()
        gf.SetNumberOfThreads(a.threads)
        gf.SetInputData(image)
        gf.Update()
        g_arr = gf.GetOutput().GetPointData().GetScalars()
    else:
        gf = vtk.vtkGradientFilter()
        gf.SetInputData(image)
        gf.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_POINTS, "u")
        gf.SetResultArrayName("v")
        gf.Update()
        g_arr = gf.GetOutput().GetPointData().GetArray("v")
    t_gradient_filter = time.perf_counter() - t1
    if a.vtk_field == "unit":
        g = vtk_to_numpy(g_arr)
        norm = np.sqrt(np.einsum("ij,ij->i", g, g))
        np.divide(g, norm[:, None], out=g, where=norm[:, None] > 0)
    n_ball = 0
    if a.vtk_stop_ball:
        # Zero the field at the nodes inside the stop ball: VTK's line then stagnates
        # there (its speed falls below the terminal speed), where harmap stops.
        g = vtk_to_numpy(g_arr).reshape(shape + (3,))
        lo = np.maximum(np.floor((center - r_stop - np.array(origin)) / spacing).astype(int), 0)
        hi = np.minimum(np.ceil((center + r_stop - np.array(origin)) / spacing).astype(int) + 1,
                        np.array(shape[::-1]))
        if (hi > lo).all():
            zz, yy, xx = np.meshgrid(*[np.arange(lo[ax], hi[ax]) * spacing + origin[ax] - center[ax]
                                       for ax in (2, 1, 0)], indexing="ij")
            ball = zz * zz + yy * yy + xx * xx < r_stop * r_stop
            box = g[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]]
            box[ball] = 0.0
            n_ball = int(ball.sum())
        g_arr.Modified()
    g_arr.SetName("v")
    field = vtk.vtkImageData()
    field.SetDimensions(shape[2], shape[1], shape[0])
    field.SetOrigin(*origin)
    field.SetSpacing(spacing, spacing, spacing)
    field.GetPointData().SetVectors(g_arr)
    del gf, image, u_vtk
    t_grad = time.perf_counter() - t0
    c_grad = time.process_time() - c0
    g_np = vtk_to_numpy(g_arr)
    speed_range = None
    if a.vtk_field != "unit":
        sp = np.sqrt(np.einsum("ij,ij->i", g_np, g_np))
        pos = sp[sp > 0]
        speed_range = [float(pos.min()) if pos.size else 0.0, float(sp.max())]
        n_below_terminal = int((sp <= a.vtk_terminal_speed).sum())
        del sp, pos
    else:
        n_below_terminal = int((np.abs(g_np).sum(axis=1) == 0).sum())
    del g_np

    nx, ny, nz = shape[2], shape[1], shape[0]
    diag = spacing * float(np.sqrt((nx - 1) ** 2 + (ny - 1) ** 2 + (nz - 1) ** 2))
    max_prop = a.vtk_max_propagation if a.vtk_max_propagation is not None else 4.0 * diag
    tr = vtk.vtkStreamTracer()
    tr.SetInputData(field)
    tr.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_POINTS, "v")
    tr.SetIntegratorTypeToRungeKutta45()
    tr.SetIntegrationDirection(st.FORWARD)
    tr.SetIntegrationStepUnit(st.CELL_LENGTH_UNIT)
    init, hmin, hmax = a.vtk_step
    tr.SetInitialIntegrationStep(init)
    tr.SetMinimumIntegrationStep(hmin)
    tr.SetMaximumIntegrationStep(hmax)
    tr.SetMaximumError(a.vtk_max_error)
    tr.SetMaximumNumberOfSteps(a.vtk_max_steps)
    tr.SetMaximumPropagation(max_prop)
    tr.SetTerminalSpeed(a.vtk_terminal_speed)
    tr.SetComputeVorticity(False)
    tr.SetForceSerialExecution(a.vtk_serial)

    per_seed = {
        "points": np.zeros(n, dtype=np.int64), "to_ball": np.zeros(n, dtype=np.int64),
        "reached": np.zeros(n, dtype=bool), "in_ball": np.zeros(n, dtype=bool),
        "reason": np.full(n, -1, dtype=np.int64), "cross": np.full((n, 3), np.nan),
    }
    t_trace = c_trace = 0.0
    n_lines = n_points = 0
    peak_rss = 0
    busy_by_thread: dict[int, float] = {}
    # The seeds go in batches of --vtk-batch, so that lines that run to the step limit
    # (up to 20000 points each) cannot exhaust the memory; only the Update()s are timed.
    for b0 in range(0, n, a.vtk_batch):
        b1 = min(n, b0 + a.vtk_batch)
        pts = vtk.vtkPoints()
        pts.SetData(numpy_to_vtk(seeds[b0:b1], deep=True))
        src = vtk.vtkPolyData()
        src.SetPoints(pts)
        tr.SetSourceData(src)
        th0 = thread_cpu()
        c0, t0 = time.process_time(), time.perf_counter()
        tr.Update()
        t_trace += time.perf_counter() - t0
        c_trace += time.process_time() - c0
        th1 = thread_cpu()
        for tid, c in th1.items():
            busy_by_thread[tid] = busy_by_thread.get(tid, 0.0) + c - th0.get(tid, 0.0)
        peak_rss = max(peak_rss, peak_rss_self())
        nl, npoints = analyse_lines(tr.GetOutput(), center, r_stop, slack, b0, per_seed, vtk_to_numpy)
        n_lines += nl
        n_points += npoints
    busy = sorted(busy_by_thread.values(), reverse=True)
    busy = [round(b, 2) for b in busy if b >= 0.05 * max(c_trace, 1e-9)]
    np.savez(Path(a.out) / "vtk_seeds.npz", **per_seed)
    reasons = per_seed["reason"]
    has_line = reasons >= 0

    names = {st.OUT_OF_DOMAIN: "out_of_domain", st.NOT_INITIALIZED: "not_initialized",
             st.UNEXPECTED_VALUE: "unexpected_value", st.OUT_OF_LENGTH: "out_of_length",
             st.OUT_OF_STEPS: "out_of_steps", st.STAGNATION: "stagnation"}
    r_counts = {names.get(int(r), str(int(r))): int(c)
                for r, c in zip(*np.unique(reasons[has_line], return_counts=True))}
    r_counts["no_line"] = int(n - has_line.sum())
    res = {
        "versions": {"vtk": vtk.vtkVersion.GetVTKVersion(), "numpy": np.__version__, "zarr": zarr.__version__},
        "smp_backend": vtk.vtkSMPTools.GetBackend(), "smp_backend_set": backend_ok,
        "smp_threads": int(vtk.vtkSMPTools.GetEstimatedNumberOfThreads()),
        "force_serial": bool(a.vtk_serial),
        "source": source, "nan_voxels": n_nan, "nan_fill_u": fill, "eps": eps,
        "gradient": "vtkImageGradient" if a.vtk_gradient == "image" else "vtkGradientFilter",
        "field": a.vtk_field, "speed_range": speed_range, "nodes_at_or_below_terminal_speed": n_below_terminal,
        "import_s": t_import, "read_s": t_read, "prepare_s": t_prepare, "gradient_filter_s": t_gradient_filter,
        "grad_s": t_grad, "grad_cpu_s": c_grad, "trace_s": t_trace, "trace_cpu_s": c_trace,
        "trace_thread_cpu_s": busy, "stop_ball": bool(a.vtk_stop_ball), "stop_ball_nodes": n_ball,
        "seconds": t_grad + t_trace, "seeds": n, "lines": n_lines, "points": n_points, "batch": a.vtk_batch,
        "mean_points": n_points / max(n_lines, 1),
        "mean_steps": float((per_seed["points"] - 1).clip(0).mean()),
        "mean_steps_to_ball": float(per_seed["to_ball"].mean()),
        "reached_fraction": float(per_seed["reached"].mean()),
        "in_ball_fraction": float(per_seed["in_ball"].mean()),
        "reasons": r_counts, "peak_rss": peak_rss,
        "params": {"integrator": tr.GetIntegrator().GetClassName(), "step_unit": "CELL_LENGTH",
                   "initial_step": init, "min_step": hmin, "max_step": hmax,
                   "max_error": tr.GetMaximumError(), "max_steps": tr.GetMaximumNumberOfSteps(),
                   "max_propagation": tr.GetMaximumPropagation(), "terminal_speed": tr.GetTerminalSpeed(),
                   "stop_radius": r_stop, "slack": slack},
    }
    (Path(a.out) / "vtk.json").write_text(json.dumps(res, indent=1))
    return 0


def analyse_lines(out, center, r_stop, slack, b0, per_seed, vtk_to_numpy) -> tuple[int, int]:
    """Fill per_seed for the lines of one vtkStreamTracer output whose seeds are numbered
    from b0: points, steps to the stop ball, reached, in ball, termination, where the line
    first crosses the stop sphere. Returns the numbers of lines and points."""
    lines = out.GetLines()
    if lines is None or lines.GetNumberOfCells() == 0:
        return 0, 0
    offsets = vtk_to_numpy(lines.GetOffsetsArray()).astype(np.int64)
    conn = vtk_to_numpy(lines.GetConnectivityArray()).astype(np.int64)
    P = vtk_to_numpy(out.GetPoints().GetData())
    nl = offsets.size - 1
    seed_ids = vtk_to_numpy(out.GetCellData().GetArray("SeedIds")).astype(np.int64) + b0
    reasons = vtk_to_numpy(out.GetCellData().GetArray("ReasonForTermination")).astype(np.int64)
    npts = np.diff(offsets)
    LP = P[conn].astype(np.float64)  # the lines' points, line after line
    d = np.linalg.norm(LP - center, axis=1)
    reached_line = d[offsets[1:] - 1] <= r_stop + slack
    inside = np.flatnonzero(d <= r_stop)
    line_of = np.searchsorted(offsets, inside, side="right") - 1
    first_line, first_at = np.unique(line_of, return_index=True)
    first_in = np.full(nl, -1, dtype=np.int64)
    first_in[first_line] = inside[first_at]
    in_ball = first_in >= 0
    to_ball = np.where(in_ball, first_in - offsets[:-1], npts - 1)
    # Where each line first crosses the stop sphere (between the last point outside and
    # the first inside; a line that starts inside has its first point).
    cross = np.full((nl, 3), np.nan)
    k = np.flatnonzero(in_ball)
    q = LP[first_in[k]]
    has_prev = first_in[k] > offsets[:-1][k]
    p = np.where(has_prev[:, None], LP[np.maximum(first_in[k] - 1, 0)], q)
    dv, w = q - p, p - center
    A = np.einsum("ij,ij->i", dv, dv)
    B = 2 * np.einsum("ij,ij->i", dv, w)
    C = np.einsum("ij,ij->i", w, w) - r_stop * r_stop
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(A > 0, (-B - np.sqrt(np.maximum(B * B - 4 * A * C, 0))) / (2 * A), 0.0)
    t = np.clip(np.nan_to_num(t), 0.0, 1.0)
    cross[k] = p + t[:, None] * dv
    per_seed["points"][seed_ids] = npts
    per_seed["to_ball"][seed_ids] = to_ball
    per_seed["reached"][seed_ids] = reached_line
    per_seed["in_ball"][seed_ids] = in_ball
    per_seed["reason"][seed_ids] = reasons
    per_seed["cross"][seed_ids] = cross
    return int(nl), int(conn.size)


# ---------------------------------------------------------------------------------------
# Running the tools
# ---------------------------------------------------------------------------------------


def find_harmap(arg: str | None) -> str:
    for c in (arg, os.environ.get("HARMAP"),
              str(Path(__file__).resolve().parent.parent / "target" / "release" / "harmap"), shutil.which("harmap")):
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return c
    fail("no harmap binary: build it (cargo build --release) or give --harmap")
    return ""


def gnu_time() -> str | None:
    t = shutil.which("time") or ("/usr/bin/time" if Path("/usr/bin/time").is_file() else None)
    if not t:
        return None
    p = subprocess.run([t, "-f", "%M", "true"], capture_output=True, text=True)
    return t if p.returncode == 0 and p.stderr.strip().isdigit() else None


def run_harmap(a, harmap: str, env, tmp: Path) -> dict:
    cmd = [harmap, "--threads", str(a.threads), "-q", "--progress", "never", "trace", a.run, "--seeds", "boundary", "--sample", str(a.sample)]
    if a.stop_radius is not None:
        cmd += ["--stop-radius", repr(a.stop_radius)]
    tfile = tmp / "harmap.time"
    tt = gnu_time()
    full = [tt, "-f", "%M", "-o", str(tfile), *cmd] if tt else cmd
    t0 = time.perf_counter()
    log = tmp / "harmap.log"
    with open(log, "w") as f:
        proc = subprocess.Popen(full, env=env, stdout=f, stderr=subprocess.STDOUT)
        _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        sys.exit(f"error: {' '.join(cmd)} failed ({code}):\n{log.read_text()}")
    if tt:
        rss, exact = int(tfile.read_text().split()[-1]) * 1024, True
    else:
        rss, exact = ru.ru_maxrss * 1024, False
    return {"cmd": cmd, "seconds": wall, "peak_rss": rss, "peak_rss_exact": exact}


def run_vtk(a, env, tmp: Path, stop_radius: float, stop_ball: bool) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker-vtk", a.run, "--out", str(tmp),
           "--threads", str(a.threads), "--stop-radius-voxels", repr(stop_radius), "--slack", repr(a.slack),
           "--vtk-gradient", a.vtk_gradient, "--vtk-field", a.vtk_field, "--vtk-step", *map(repr, a.vtk_step),
           "--vtk-max-error", repr(a.vtk_max_error), "--vtk-max-steps", str(a.vtk_max_steps),
           "--vtk-batch", str(a.vtk_batch), "--vtk-terminal-speed", repr(a.vtk_terminal_speed)]
    if a.vtk_max_propagation is not None:
        cmd += ["--vtk-max-propagation", repr(a.vtk_max_propagation)]
    if a.vtk_serial:
        cmd.append("--vtk-serial")
    if stop_ball:
        cmd.append("--vtk-stop-ball")
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    (tmp / "vtk.log").write_text(p.stdout + p.stderr)
    if p.returncode != 0:
        sys.exit(f"error: the VTK worker failed ({p.returncode}):\n{p.stderr}")
    r = json.loads((tmp / "vtk.json").read_text())
    r["process_wall_s"] = wall
    (tmp / "vtk.json").rename(tmp / f"vtk{'_ball' if stop_ball else ''}.json")
    (tmp / "vtk_seeds.npz").rename(tmp / f"vtk_seeds{'_ball' if stop_ball else ''}.npz")
    return r


def harmap_results(run: Path, n_expected: int) -> tuple[dict, dict]:
    """harmap's trace stage record and its per-seed table."""
    import zarr

    stage = run_attrs(run).get("stages", {}).get("trace") or {}
    g = zarr.open_group(str(run), mode="r")
    seeds = {k: np.asarray(g[f"seeds/{k}"][...]) for k in ("position", "stop", "steps", "end")}
    if seeds["position"].shape[0] != n_expected and n_expected:
        print(f"harmap traced all {seeds['position'].shape[0]} boundary seeds (fewer than --sample {n_expected})")
    return stage, seeds


def arrival_angles(center, hs: dict, vs: dict) -> np.ndarray:
    both = (hs["stop"] == 0) & vs["in_ball"]
    a = hs["end"][both] - center
    b = vs["cross"][both] - center
    cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


# ---------------------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------------------


def mib(b) -> str:
    return f"{b / 2**20:.0f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", nargs="?", help="harmap run directory (solved: u/0 or phi/0)")
    ap.add_argument("--sample", type=int, default=50000, help="seeds: harmap's deterministic subset (default 50000)")
    ap.add_argument("--threads", type=int, default=2, help="threads of both tools (default 2)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    ap.add_argument("--harmap", help="the harmap binary (default: target/release/harmap, $HARMAP, PATH)")
    ap.add_argument("--stop-radius", type=float, help="harmap trace --stop-radius (voxels; default harmap's)")
    ap.add_argument("--slack", type=float, default=1.0,
                    help="VTK: a line reached the center if it ends within stop radius + SLACK voxels (default 1)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run both tools this many times, interleaved; report each one's run of median seconds")
    ap.add_argument("--vtk-gradient", choices=["image", "generic"], default="image",
                    help="vtkImageGradient (default) or vtkGradientFilter")
    ap.add_argument("--vtk-field", choices=["grad", "unit"], default="grad",
                    help="trace -grad(phi) (default) or its normalized direction, as harmap does")
    ap.add_argument("--vtk-step", type=float, nargs=3, default=[0.5, 0.01, 2.0], metavar=("INIT", "MIN", "MAX"),
                    help="initial, minimum, maximum step in cell lengths (default 0.5 0.01 2)")
    ap.add_argument("--vtk-max-error", type=float, default=1e-6, help="RK45 MaximumError (default 1e-6)")
    ap.add_argument("--vtk-max-steps", type=int, default=2000,
                    help="MaximumNumberOfSteps (default 2000, VTK's default)")
    ap.add_argument("--vtk-max-propagation", type=float,
                    help="MaximumPropagation, world units (default 4 grid diagonals; VTK's default is 1)")
    ap.add_argument("--vtk-batch", type=int, default=1000,
                    help="seeds per vtkStreamTracer Update() (default 1000): bounds VTK's memory")
    ap.add_argument("--vtk-terminal-speed", type=float, default=1e-12, help="TerminalSpeed (default 1e-12)")
    ap.add_argument("--vtk-serial", action="store_true", help="vtkStreamTracer ForceSerialExecution")
    ap.add_argument("--vtk-stop-ball", action="store_true",
                    help="also run VTK on the field zeroed inside the stop ball (a second VTK line: it then stops "
                         "about where harmap stops)")
    ap.add_argument("--keep", metavar="DIR", help="keep the scratch files (logs, VTK's per-seed table) in DIR")
    # The VTK child process.
    ap.add_argument("--worker-vtk", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--stop-radius-voxels", type=float, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.run is None:
        ap.error("the run directory is required")
    run = Path(a.run)
    if a.worker_vtk:
        a.stop_radius = a.stop_radius_voxels  # voxels, resolved by the parent
        return vtk_worker(a)

    if not (run / "zarr.json").is_file():
        fail(f"{run} is not a harmap run directory (no zarr.json)")
    if not any((run / d / "0" / "zarr.json").is_file() for d in ("u", "phi")):
        fail(f"{run} has no u/0 or phi/0 (run `harmap solve` first)")
    import importlib.util

    if importlib.util.find_spec("vtk") is None:
        fail(f"no vtk in {sys.executable}: pip install vtk")
    harmap = find_harmap(a.harmap)
    h = run_attrs(run)
    grid = h["grid"]
    center = np.array(h["center"], dtype=np.float64)
    print(f"{run}: grid {'x'.join(map(str, grid['shape']))} (z,y,x), spacing {grid['spacing']:.6g}, "
          f"--sample {a.sample}, {a.threads} threads; harmap {harmap}", flush=True)

    tmp = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="harmap-cmpt-"))
    tmp.mkdir(parents=True, exist_ok=True)
    env = thread_env(a.threads)
    variants = ["vtk"] + (["vtk_stop_ball"] if a.vtk_stop_ball else [])
    hruns: list[dict] = []
    vruns: dict[str, list[dict]] = {k: [] for k in variants}
    vseeds: dict[str, dict] = {}
    try:
        for rep in range(a.repeat):
            tag = f" (run {rep + 1} of {a.repeat})" if a.repeat > 1 else ""
            print(f"harmap: trace{tag} ...", flush=True)
            hr = run_harmap(a, harmap, env, tmp)
            stage, hseeds = harmap_results(run, a.sample)
            hr["trace_s"] = stage.get("seconds")
            hr["stop_radius"] = (stage.get("result") or {}).get("stop_radius")
            hruns.append(hr)
            if hr["stop_radius"] is None:
                fail(f"{run}/zarr.json has no stages.trace.result.stop_radius")
            for key in variants:
                ball = key == "vtk_stop_ball"
                print(f"VTK: gradient + vtkStreamTracer{' (field zeroed in the stop ball)' if ball else ''}{tag} ...",
                      flush=True)
                vruns[key].append(run_vtk(a, env, tmp, hr["stop_radius"], ball))
                vseeds[key] = dict(np.load(tmp / f"vtk_seeds{'_ball' if ball else ''}.npz"))
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    def median(rs, key):
        return sorted(rs, key=lambda r: r[key])[(len(rs) - 1) // 2]

    hr = median(hruns, "seconds")
    n = int(hseeds["position"].shape[0])
    res = stage.get("result") or {}
    harmap_row = {
        "seconds": hr["seconds"], "trace_s": hr["trace_s"], "lines_per_s": n / hr["seconds"],
        "mean_steps": float(hseeds["steps"].mean()), "mean_steps_to_ball": float(hseeds["steps"].mean()),
        "reached_fraction": float((hseeds["stop"] == 0).mean()),
        "stops": res.get("stops"), "peak_rss": hr["peak_rss"], "peak_rss_exact": hr["peak_rss_exact"],
        "seconds_runs": [r["seconds"] for r in hruns], "cmd": " ".join(hr["cmd"]),
        "rk": (stage.get("options") or {}).get("rk"), "stop_radius_voxels": hr["stop_radius"],
        "runs": [{k: x[k] for k in ("seconds", "trace_s", "peak_rss")} for x in hruns],
    }
    report = {
        "run": str(run), "shape": grid["shape"], "spacing": grid["spacing"], "sample": a.sample, "seeds": n,
        "threads": a.threads, "repeat": a.repeat,
        "machine": {"cpu": cpu_name(), "cores": os.cpu_count(), "python": platform.python_version()},
        "harmap": harmap_row,
    }
    hreached = hseeds["stop"] == 0
    for key in variants:
        vr, vs = median(vruns[key], "seconds"), vseeds[key]
        ang = arrival_angles(center, hseeds, vs)
        report[key] = vr | {
            "lines_per_s": n / vr["seconds"], "seconds_runs": [r["seconds"] for r in vruns[key]],
            "runs": [{k: x[k] for k in ("read_s", "grad_s", "trace_s", "trace_cpu_s", "trace_thread_cpu_s",
                                        "peak_rss")} for x in vruns[key]],
            "ratio_over_harmap": vr["seconds"] / harmap_row["seconds"],
            "ratio_with_read_over_harmap": (vr["seconds"] + vr["read_s"]) / harmap_row["seconds"],
            "arrival_angle_deg": {"seeds": int(ang.size),
                                  "median": float(np.median(ang)) if ang.size else None,
                                  "p99": float(np.percentile(ang, 99)) if ang.size else None,
                                  "max": float(ang.max()) if ang.size else None},
            "both_reached": int((hreached & vs["reached"]).sum()),
            "only_harmap_reached": int((hreached & ~vs["reached"]).sum()),
            "only_vtk_reached": int((~hreached & vs["reached"]).sum()),
        }
    print_table(report, variants)
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {a.json}")
    return 0


def print_table(r: dict, variants: list[str]) -> None:
    h = r["harmap"]
    label = {"vtk": "VTK", "vtk_stop_ball": "VTK, stop ball"}
    print()
    print(f"{r['seeds']} seeds, {r['threads']} threads, {r['machine']['cpu']} ({r['machine']['cores']} cores)")
    print()
    print("| tool | read s | grad s | trace s | seconds | lines/s | steps/line | to ball | reached | in ball "
          "| peak MiB |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    rss = ("" if h["peak_rss_exact"] else "<=") + mib(h["peak_rss"])
    print(f"| harmap | - | - | {h['trace_s']:.2f} | {h['seconds']:.2f} | {h['lines_per_s']:.0f} | "
          f"{h['mean_steps']:.1f} | {h['mean_steps_to_ball']:.1f} | {100 * h['reached_fraction']:.1f}% | "
          f"{100 * h['reached_fraction']:.1f}% | {rss} |")
    for key in variants:
        v = r[key]
        print(f"| {label[key]} | {v['read_s']:.2f} | {v['grad_s']:.2f} | {v['trace_s']:.2f} | "
              f"{v['seconds']:.2f} | {v['lines_per_s']:.0f} | {v['mean_steps']:.1f} | "
              f"{v['mean_steps_to_ball']:.1f} | {100 * v['reached_fraction']:.1f}% | "
              f"{100 * v['in_ball_fraction']:.1f}% | {mib(v['peak_rss'])} |")
    print()
    for key in variants:
        v = r[key]
        print(f"{label[key]} seconds / harmap seconds = {v['ratio_over_harmap']:.2f} "
              f"({v['ratio_with_read_over_harmap']:.2f} with VTK's read).")
    print(f"harmap: seconds = wall of `{h['cmd']}` (read, trace, write); trace s = the stage's own time; "
          f"stop radius {h['stop_radius_voxels']:g} voxels; stops {h['stops']}.")
    v = r["vtk"]
    p = v["params"]
    print(f"VTK {v['versions']['vtk']}: {v['gradient']} ({v['grad_s'] - v['gradient_filter_s']:.2f} s of grad s "
          f"is NaN fill + wrap{' + normalizing' if v['field'] == 'unit' else ''}, cpu/wall "
          f"{v['grad_cpu_s'] / v['grad_s']:.2f}); field {'-grad(phi)' if v['field'] == 'grad' else '-grad(phi)/|grad(phi)|'}; "
          f"{p['integrator']}, steps {p['initial_step']:g}/{p['min_step']:g}/{p['max_step']:g} cell lengths, "
          f"max error {p['max_error']:g}, terminal speed {p['terminal_speed']:g}, max steps {p['max_steps']}; "
          f"SMP {v['smp_backend']} x{v['smp_threads']}{' (ForceSerialExecution)' if v['force_serial'] else ''}; "
          f"process wall {v['process_wall_s']:.2f} s (import vtk {v['import_s']:.2f} s).")
    for key in variants:
        v = r[key]
        print(f"{label[key]}: trace wall {v['trace_s']:.2f} s, cpu {v['trace_cpu_s']:.2f} s, CPU s per busy thread "
              f"{v['trace_thread_cpu_s']}.")
    v = r["vtk"]
    if v["speed_range"]:
        print(f"VTK: |grad phi| over the nodes {v['speed_range'][0]:.2e} .. {v['speed_range'][1]:.2e} per world "
              f"unit; {v['nodes_at_or_below_terminal_speed']} nodes at or below the terminal speed; "
              f"{v['nan_voxels']} NaN voxels filled with u = {v['nan_fill_u']:.6g}.")
    print(f"reached (VTK): last point within stop radius + {p['slack'] / r['spacing']:g} voxel(s); in ball: any "
          f"point within the stop radius; to ball: steps before the first point within it.")
    for key in variants:
        v = r[key]
        aa = v["arrival_angle_deg"]
        extra = f" ({v['stop_ball_nodes']} nodes zeroed)" if v.get("stop_ball") else ""
        print(f"{label[key]}{extra}: terminations {v['reasons']}; mean points/line {v['mean_points']:.1f}; "
              f"reached by both {v['both_reached']}, only harmap {v['only_harmap_reached']}, only VTK "
              f"{v['only_vtk_reached']}.")
        if aa["seeds"]:
            print(f"  arrival on the stop sphere vs harmap's, {aa['seeds']} seeds both brought in: angle median "
                  f"{aa['median']:.3f} deg, 99% {aa['p99']:.3f}, max {aa['max']:.3f}.")
    if r["repeat"] > 1:
        print(f"Times: each tool's run of median seconds of {r['repeat']}, interleaved; all (s): harmap "
              + " ".join(f"{t:.2f}" for t in h["seconds_runs"]) + "; "
              + "; ".join(f"{label[k]} " + " ".join(f"{t:.2f}" for t in r[k]["seconds_runs"]) for k in variants))


if __name__ == "__main__":
    sys.exit(main())
