#!/usr/bin/env python3
"""harmap's Laplace solve vs two peers on the same discrete system: pyamg and a C SOR.

    python3 -m venv /tmp/cmpvenv
    /tmp/cmpvenv/bin/pip install numpy scipy pyamg 'zarr>=3'      # a C compiler: cc
    /tmp/cmpvenv/bin/python benches/compare_solve.py RUN [--harmap target/release/harmap]
        [--repeat 3] [--rtol 1e-6] [--eps 1e-4] [--json out.json] [--hypre]

RUN is a harmap run directory (Zarr v3 group) with RUN/labels/0, e.g. from
`harmap voxelize ... -o RUN`. With --harmap BIN, `BIN solve RUN` runs --repeat times,
interleaved with the peers, and its time is the solve stage's own (labels read to phi and
u stored, as RUN/zarr.json records it). Without it, a RUN/phi/0 already there is compared
with the time its run recorded.

The discrete system (harmap's, src/solve):
  * labels: 0 exterior (not part of the problem), 1 boundary (phi = 1), 2 interior
    (unknown), 3 center (phi = 0), 4..7 exterior layer k = 1..4 (phi = 1 + k eps);
  * at each unknown i: 6 phi_i - (sum of its 6 face neighbours) = 0, fixed neighbours
    moved to the right-hand side. So A is the 7-point Laplacian restricted to the
    unknowns (symmetric positive definite) and b_i is the sum of i's fixed neighbours.
    By construction an unknown's neighbours are on the grid and never label 0 (checked);
  * start x0 = 1 at every unknown (harmap's), and the stopping rule is the relative
    residual ||b - A x||_2 / ||b - A x0||_2 < rtol. harmap's residual, per unknown, is
    (mean of neighbours - phi) = (b - A x)_i / 6: the same ratio.

The peers, each in its own process, which reports its own peak RSS (VmHWM):
  * pyamg: `smoothed_aggregation_solver(A)` with its defaults, then `solve(b, x0=x0)`
    twice from the same hierarchy: plain V-cycles (accel=None, the main line) and
    V-cycle-preconditioned CG (accel='cg'). Setup = assembling A and b from the labels
    (vectorized numpy, CSR with int32 indices) + building the hierarchy. pyamg stops on
    ||b - A x|| < tol ||b|| (relative to b, not to the start), and here ||b - A x0|| is far
    smaller than ||b|| (only the unknowns next to the center start off balance), so tol
    is set to rtol ||b - A x0|| / ||b||. pyamg is mostly serial (its C++ kernels and
    scipy's sparse products are; numpy's BLAS gets --threads threads).
  * SOR: benches/sor.c, compiled here with `cc -O3 -march=native -ffp-contract=off
    -fopenmp` (without -fopenmp if that fails): red-black SOR with omega =
    2 / (1 + sin(pi / n)), n the grid's longest side, on --threads OpenMP threads, the
    residual checked every --check-every iterations (1, as harmap does). Same colors and
    omega as harmap's red-black SOR; the update is written differently, so the iterates
    agree to rounding, not bit for bit.

  * hypre (with --hypre): benches/compare_hypre.c, PFMG-preconditioned CG through
    hypre's Struct interface on --hypre-ranks MPI ranks (default 2, one thread each),
    each rank a slab of z planes. Every fixed voxel is an identity row, its value moved
    to its unknown neighbours' right-hand side (a symmetric matrix, as CG needs); label
    0 voxels are identity rows too (Struct grids are boxes). It solves for the
    correction from x0, so hypre's relative residual is exactly ||b - A x|| / ||b - A
    x0||. PFMG: one V(1,1) cycle per CG iteration, --hypre-relax (default 2, symmetric
    red-black Gauss-Seidel), --hypre-rap (default 1, the non-Galerkin 7-point coarse
    operators), skip-relax on: the fastest and leanest of the four relax/RAP pairs at
    N = 256 here. Setup is hypre's grid, matrix and vector assembly plus the PCG and
    PFMG setup; peak RSS is the sum of the ranks' VmHWM (each rank's is in the JSON).
    Debian: `apt-get install libhypre-dev`. Debian's hypre is built against Open MPI,
    so it is compiled with mpicc.openmpi and run with mpirun.openmpi (as root with
    OMPI_ALLOW_RUN_AS_ROOT=1 and OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1, set here); the script
    finds them from the MPI library libHYPRE.so links to (--mpicc and --mpiexec
    override). Installing libhypre-dev also switches Debian's `mpi` and `mpirun`
    alternatives to Open MPI when MPICH is installed: harmap's `mpi` feature wants
    MPICH (`update-alternatives --set mpi /usr/bin/mpicc.mpich` and `--set mpirun
    /usr/bin/mpirun.mpich` switch them back).

Reported per peer: setup, solve and total seconds (timed inside the process; the
process's wall time, with reading the labels and writing phi, is shown too), iterations,
peak RSS, the relative residual the peer reports and the one this script recomputes from
its phi with an independent matrix-free stencil, max |phi - phi_ref| with phi_ref a far
tighter solve (pyamg CG to --ref-rtol, untimed), and max |phi_a - phi_b| over the
unknowns for every pair (harmap's RUN/phi/0 included when it exists). pyamg's random
start vectors are seeded, so every run gives the same phi. On a shared machine use
--repeat 3: each line then shows the run of median total time, all totals listed.
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

INTERIOR = 2
EPS_DEFAULT = 1e-4


# ---------------------------------------------------------------------------------------
# The discrete system
# ---------------------------------------------------------------------------------------


def fixed_values(eps: float):
    """phi at each label, indexed by label: NaN where it is not a fixed value (0, 2)."""
    lut = np.full(256, np.nan)
    lut[1] = 1.0
    lut[3] = 0.0
    lut[4:8] = 1.0 + eps * np.arange(1, 5)
    return lut


def neighbour_offsets(shape):
    """Flat offsets of the 6 face neighbours in harmap's order (-x, +x, -y, +y, -z, +z)."""
    _, ny, nx = shape
    return (-1, 1, -nx, nx, -nx * ny, nx * ny)


def check_labels(labels) -> str | None:
    """Why `labels` is not a system this script (and harmap) can solve, or None."""
    if labels.ndim != 3 or labels.dtype != np.uint8:
        return f"labels must be a 3-d uint8 array, got {labels.dtype} {labels.shape}"
    if int(labels.max(initial=0)) > 7:
        return f"unknown label {int(labels.max())} (expected 0..7)"
    unk = labels == INTERIOR
    if not unk.any():
        return "no interior (label 2) voxels: nothing to solve"
    if any(unk[s].any() for s in (np.s_[[0, -1], :, :], np.s_[:, [0, -1], :], np.s_[:, :, [0, -1]])):
        return "an interior voxel lies on the grid's edge"
    flat = labels.ravel()
    p = np.flatnonzero(flat == INTERIOR)
    for off in neighbour_offsets(labels.shape):
        if (flat[p + off] == 0).any():
            return "an interior voxel has an exterior (label 0) neighbour"
    return None


def assemble(labels, eps: float):
    """A (CSR, int32 indices), b and the flat grid index of each unknown, in C order."""
    import scipy.sparse as sp

    flat = labels.ravel()
    p = np.flatnonzero(flat == INTERIOR)
    n = p.size
    index = np.full(flat.size, -1, dtype=np.int32)
    index[p] = np.arange(n, dtype=np.int32)
    lut = fixed_values(eps)
    # Columns of each row in increasing order: -z, -y, -x, diagonal, +x, +y, +z (the
    # unknowns are numbered in C order, so the column order is the offset order).
    nx, ny = labels.shape[2], labels.shape[1]
    offsets = (-nx * ny, -nx, -1, 0, 1, nx, nx * ny)
    cols = np.empty((n, 7), dtype=np.int32)
    b = np.zeros(n)
    for j, off in enumerate(offsets):
        if off == 0:
            cols[:, j] = np.arange(n, dtype=np.int32)
            continue
        q = p + off
        c = index[q]
        cols[:, j] = c
        fixed = c < 0
        b[fixed] += lut[flat[q[fixed]]]
    del index
    keep = cols >= 0
    counts = keep.sum(axis=1, dtype=np.int32)
    indptr = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(counts, out=indptr[1:])
    indices = cols[keep]
    del cols
    data = np.full(indices.size, -1.0)
    data[indptr[:-1] + keep[:, :3].sum(axis=1, dtype=np.int32)] = 6.0  # the diagonal
    A = sp.csr_matrix((data, indices, indptr), shape=(n, n))
    if not np.isfinite(b).all():
        raise ValueError("an interior voxel has an exterior neighbour")
    return A, b, p


def residual_norm(labels_flat, p, offsets, lut, x) -> float:
    """||b - A x||_2 for unknown values x, matrix-free (independent of `assemble`)."""
    phi = lut[labels_flat]
    phi[p] = x
    r = -6.0 * phi[p]
    for off in offsets:
        r += phi[p + off]
    return float(np.linalg.norm(r))


# ---------------------------------------------------------------------------------------
# The pyamg peer (run in a child process: `--worker-pyamg`)
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


def pyamg_worker(a) -> int:
    import pyamg
    import scipy

    shape = tuple(a.shape)
    labels = np.fromfile(a.labels, dtype=np.uint8).reshape(shape)
    lut = fixed_values(a.eps)

    # pyamg estimates spectral radii from random vectors: seeded, runs repeat exactly.
    np.random.seed(0)
    t0 = time.perf_counter()
    A, b, p = assemble(labels, a.eps)
    t_assemble = time.perf_counter() - t0
    t0 = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(A)
    t_hierarchy = time.perf_counter() - t0
    out = {
        "versions": {"pyamg": pyamg.__version__, "numpy": np.__version__, "scipy": scipy.__version__},
        "unknowns": int(p.size),
        "nnz": int(A.nnz),
        "levels": [int(lv.A.shape[0]) for lv in ml.levels],
        "operator_complexity": float(ml.operator_complexity()),
        "grid_complexity": float(ml.grid_complexity()),
        "assemble_s": t_assemble,
        "hierarchy_s": t_hierarchy,
        "setup_s": t_assemble + t_hierarchy,
        "peak_rss_setup": peak_rss_self(),
        "solves": {},
    }
    x0 = np.ones(p.size)
    r0 = float(np.linalg.norm(b - A @ x0))
    normb = float(np.linalg.norm(b))
    # pyamg stops on ||b - A x|| < tol ||b||; we want ||b - A x|| < rtol ||b - A x0||.
    tol = a.rtol * r0 / normb
    out.update(residual0=r0, norm_b=normb, pyamg_tol=tol)
    for name, accel in (("vcycle", None), ("cg", "cg")):
        if accel and a.no_cg:
            continue
        residuals: list[float] = []
        t0 = time.perf_counter()
        x = ml.solve(b, x0=x0.copy(), tol=tol, maxiter=a.maxiter, accel=accel, residuals=residuals)
        t_solve = time.perf_counter() - t0
        rel = float(np.linalg.norm(b - A @ x)) / r0
        phi = lut[labels.ravel()]
        phi[p] = x
        phi.tofile(Path(a.out) / f"phi_pyamg_{name}.f64")
        del phi
        out["solves"][name] = {
            "accel": accel,
            "iterations": len(residuals) - 1,
            "solve_s": t_solve,
            "rel_residual": rel,
            "rel_residual_pyamg": residuals[-1] / r0,
            "converged": rel < a.rtol,
            "peak_rss": peak_rss_self(),
        }
    if a.ref_rtol > 0:
        # A far tighter solve: the yardstick for every peer's error in phi.
        residuals = []
        x = ml.solve(b, x0=x0.copy(), tol=a.ref_rtol * r0 / normb, maxiter=10 * a.maxiter, accel="cg",
                     residuals=residuals)
        phi = lut[labels.ravel()]
        phi[p] = x
        phi.tofile(Path(a.out) / "phi_reference.f64")
        out["reference"] = {"rtol": a.ref_rtol, "iterations": len(residuals) - 1,
                            "rel_residual": float(np.linalg.norm(b - A @ x)) / r0}
    out["peak_rss_process"] = peak_rss_self()
    (Path(a.out) / "pyamg.json").write_text(json.dumps(out, indent=1))
    return 0


# ---------------------------------------------------------------------------------------
# Running the peers
# ---------------------------------------------------------------------------------------


def run_child(cmd, env, log: Path) -> tuple[str, float]:
    """Run `cmd`; its stdout and wall seconds. (Each child reports its own peak RSS.)"""
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    log.write_text(p.stdout + p.stderr)
    if p.returncode != 0:
        sys.exit(f"error: {' '.join(map(str, cmd))} failed ({p.returncode}):\n{p.stderr}")
    return p.stdout, wall


def compile_sor(cc: str, tmp: Path) -> tuple[Path, list[str]]:
    src = Path(__file__).resolve().parent / "sor.c"
    exe = tmp / "sor"
    errors = []
    # -ffp-contract=off: no fused multiply-adds, as Rust, so the iterates are harmap's.
    base = ["-O3", "-march=native", "-ffp-contract=off"]
    for flags in ([*base, "-fopenmp"], base, ["-O3", "-ffp-contract=off"]):
        cmd = [cc, *flags, str(src), "-o", str(exe), "-lm"]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode == 0:
            return exe, flags
        errors.append(f"$ {' '.join(cmd)}\n{p.stderr}")
    sys.exit("error: cannot compile benches/sor.c:\n" + "\n".join(errors))


def hypre_mpi(a) -> tuple[str, str]:
    """The MPI compiler wrapper and launcher that match the MPI libHYPRE.so links to."""
    if a.mpicc and a.mpiexec:
        return a.mpicc, a.mpiexec
    flavour = None
    for lib in ("/usr/lib/x86_64-linux-gnu/libHYPRE.so", "/usr/lib/aarch64-linux-gnu/libHYPRE.so",
                "/usr/local/lib/libHYPRE.so"):
        if Path(lib).exists():
            out = subprocess.run(["ldd", lib], capture_output=True, text=True).stdout
            flavour = "openmpi" if "libmpi.so.40" in out else "mpich" if "libmpi.so.12" in out else None
            break
    cc = {"openmpi": "mpicc.openmpi", "mpich": "mpicc.mpich"}.get(flavour, "mpicc")
    run = {"openmpi": "mpirun.openmpi", "mpich": "mpiexec.mpich"}.get(flavour, "mpiexec")
    cc, run = a.mpicc or cc, a.mpiexec or run
    if shutil.which(cc) is None or shutil.which(run) is None:
        sys.exit(f"error: --hypre needs {cc} and {run} (Debian: apt-get install libhypre-dev); "
                 "or name them with --mpicc and --mpiexec")
    return cc, run


def compile_hypre(a, tmp: Path) -> tuple[Path, str, list[str]]:
    src = Path(__file__).resolve().parent / "compare_hypre.c"
    exe = tmp / "compare_hypre"
    cc, run = hypre_mpi(a)
    flags = ["-O3", "-march=native"]
    cmd = [cc, *flags, "-I/usr/include/hypre", str(src), "-o", str(exe), "-lHYPRE", "-lm"]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"error: cannot compile benches/compare_hypre.c (is libhypre-dev installed?):\n"
                 f"$ {' '.join(cmd)}\n{p.stderr}")
    return exe, run, [cc, *flags]


def thread_env(threads: int) -> dict:
    env = dict(os.environ)
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[k] = str(threads)
    return env


# ---------------------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------------------


def fail(msg: str) -> None:
    """Bad input: a message and exit code 2 (harmap's convention)."""
    print(f"error: {msg}", file=sys.stderr)
    sys.exit(2)


def mib(b) -> str:
    return f"{b / 2**20:.0f}"


def fmt_s(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def run_peers(a, labels_path: Path, shape, tmp: Path, report: dict) -> dict[str, list[dict]]:
    """Run the peers --repeat times, interleaved; every run of every line of the table.
    Their phi are left in `tmp` (the runs are deterministic: the same every time)."""
    env = thread_env(a.threads)
    runs: dict[str, list[dict]] = {}
    if "sor" not in a.skip:
        exe, flags = compile_sor(a.cc, tmp)
    if a.hypre:
        hexe, hrun, hflags = compile_hypre(a, tmp)
    for rep in range(a.repeat):
        tag = f" (run {rep + 1} of {a.repeat})" if a.repeat > 1 else ""
        if "pyamg" not in a.skip:
            print(f"pyamg: assembling, building the hierarchy, solving{tag} ...", flush=True)
            ref = a.ref_rtol if rep == 0 else 0.0  # the reference is the same every time
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker-pyamg", "--labels", str(labels_path),
                   "--shape", *map(str, shape), "--eps", repr(a.eps), "--rtol", repr(a.rtol), "--out", str(tmp),
                   "--maxiter", str(a.maxiter), "--ref-rtol", repr(ref)] + (["--no-cg"] if a.no_cg else [])
            _, wall = run_child(cmd, env, tmp / "pyamg.log")
            w = json.loads((tmp / "pyamg.json").read_text())
            if rep == 0:
                report["pyamg"] = {k: v for k, v in w.items() if k != "solves"}
            for name, r in w["solves"].items():
                key = "pyamg SA" + (" + CG" if r["accel"] else " V-cycle")
                runs.setdefault(key, []).append({
                    "setup_s": w["setup_s"], "solve_s": r["solve_s"], "total_s": w["setup_s"] + r["solve_s"],
                    "assemble_s": w["assemble_s"], "hierarchy_s": w["hierarchy_s"],
                    "iterations": r["iterations"], "peak_rss": r["peak_rss"], "rel_residual": r["rel_residual"],
                    "converged": r["converged"], "process_wall_s": wall, "file": f"phi_pyamg_{name}.f64"})
        if "sor" not in a.skip:
            print(f"SOR: {a.cc} {' '.join(flags)}; solving{tag} ...", flush=True)
            cmd = [str(exe), str(labels_path), *map(str, shape), repr(a.eps), repr(a.rtol),
                   str(tmp / "phi_sor.f64"), str(a.check_every), str(a.sor_max_iter)]
            out, wall = run_child(cmd, env, tmp / "sor.log")
            r = json.loads(out)
            report["sor"] = r | {"flags": flags}
            runs.setdefault("SOR red-black (C)", []).append({
                "setup_s": r["setup_s"], "solve_s": r["solve_s"], "total_s": r["setup_s"] + r["solve_s"],
                "iterations": r["iterations"], "peak_rss": r["peak_rss"], "rel_residual": r["rel_residual"],
                "converged": r["converged"], "residual_check_s": r["residual_check_s"],
                "process_wall_s": wall, "file": "phi_sor.f64"})
        if a.hypre:
            print(f"hypre: PFMG-CG on {a.hypre_ranks} ranks ({hrun}){tag} ...", flush=True)
            henv = thread_env(1) | {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1"}
            cmd = [hrun, "-n", str(a.hypre_ranks), str(hexe), str(labels_path), *map(str, shape), repr(a.eps),
                   repr(a.rtol), str(tmp / "phi_hypre.f64"), str(a.hypre_relax), str(a.hypre_rap), "1"]
            out, wall = run_child(cmd, henv, tmp / "hypre.log")
            r = json.loads(out.strip().splitlines()[-1])
            report["hypre"] = r | {"compiler": hflags, "launcher": hrun}
            runs.setdefault(f"hypre PFMG-CG {a.hypre_ranks}r", []).append({
                "setup_s": r["setup_s"], "solve_s": r["solve_s"], "total_s": r["setup_s"] + r["solve_s"],
                "iterations": r["iterations"], "peak_rss": r["peak_rss"], "rel_residual": r["rel_residual"],
                "converged": r["converged"], "process_wall_s": wall, "file": "phi_hypre.f64"})
        if a.harmap:
            print(f"harmap: {a.harmap} solve{tag} ...", flush=True)
            runs.setdefault("harmap", []).append(run_harmap(a, env, tmp))
    return runs


def run_harmap(a, env, tmp: Path) -> dict:
    """`harmap solve RUN` once (it replaces RUN's phi): its stage time, iterations and
    peak RSS. The peak is the child's VmHWM, read from /proc every 10 ms while it runs
    (a high-water mark, so the last reading is the peak up to a few ms before the end;
    where /proc is missing, none)."""
    cmd = [a.harmap, "-q", "--threads", str(a.threads), "solve", a.run, "--rtol", repr(a.rtol),
           "--eps", repr(a.eps), "--mem", a.harmap_mem]
    t0 = time.perf_counter()
    peak = None
    with open(tmp / "harmap.log", "w") as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
        status = Path(f"/proc/{proc.pid}/status")
        while proc.poll() is None:
            try:
                for line in status.read_text().splitlines():
                    if line.startswith("VmHWM:"):
                        peak = max(peak or 0, int(line.split()[1]) * 1024)
            except OSError:
                pass
            time.sleep(0.01)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"error: {' '.join(cmd)} failed ({proc.returncode}):\n{(tmp / 'harmap.log').read_text()}")
    stage = json.loads((Path(a.run) / "zarr.json").read_text())["attributes"]["harmap"]["stages"]["solve"]
    result = stage.get("result") or {}
    return {"setup_s": None, "solve_s": stage["seconds"], "total_s": stage["seconds"],
            "iterations": result.get("iterations"), "peak_rss": peak,
            "rel_residual": result.get("relative_residual"), "method": result.get("method"),
            "in_memory": result.get("in_memory"), "process_wall_s": wall}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", nargs="?", help="harmap run directory (with labels/0)")
    ap.add_argument("--rtol", type=float, default=1e-6, help="stop at ||b-Ax|| / ||b-Ax0|| < RTOL (default 1e-6)")
    ap.add_argument("--eps", type=float, default=EPS_DEFAULT, help="exterior layer spacing (default 1e-4)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    ap.add_argument("--threads", type=int, default=2,
                    help="OpenMP threads of the SOR, BLAS threads of pyamg's process (default 2)")
    ap.add_argument("--check-every", type=int, default=1,
                    help="SOR: residual check interval in iterations (default 1)")
    ap.add_argument("--maxiter", type=int, default=500, help="pyamg: cycle / CG iteration limit (default 500)")
    ap.add_argument("--sor-max-iter", type=int, default=100000, help="SOR iteration limit (default 100000)")
    ap.add_argument("--no-cg", action="store_true", help="skip pyamg's CG-accelerated solve")
    ap.add_argument("--ref-rtol", type=float, default=1e-11,
                    help="pyamg also solves to this relative residual (CG, untimed) as the reference each peer's "
                         "phi is compared to (0: no reference; default 1e-11)")
    ap.add_argument("--hypre", action="store_true",
                    help="also run hypre's PFMG-CG (benches/compare_hypre.c; Debian: libhypre-dev)")
    ap.add_argument("--hypre-ranks", type=int, default=2, help="hypre: MPI ranks (default 2)")
    ap.add_argument("--hypre-relax", type=int, default=2,
                    help="hypre PFMG relaxation: 1 weighted Jacobi, 2 symmetric red-black GS (default 2)")
    ap.add_argument("--hypre-rap", type=int, default=1,
                    help="hypre PFMG coarse operators: 0 Galerkin, 1 non-Galerkin 7-point (default 1)")
    ap.add_argument("--mpicc", help="hypre: MPI compiler wrapper (default: the one matching libHYPRE.so)")
    ap.add_argument("--mpiexec", help="hypre: MPI launcher (default: the one matching libHYPRE.so)")
    ap.add_argument("--skip", choices=["pyamg", "sor"], action="append", default=[], help="skip a peer")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run every peer this many times, interleaved, and report the run of median total time "
                         "(default 1)")
    ap.add_argument("--cc", default=os.environ.get("CC", "cc"), help="C compiler (default $CC or cc)")
    ap.add_argument("--harmap", metavar="BIN",
                    help="run `BIN solve RUN` too, --repeat times interleaved with the peers (replaces RUN's phi)")
    ap.add_argument("--harmap-mem", default="1GiB", metavar="SIZE",
                    help="harmap's --mem (default 1GiB, its own default: at N = 256 every level fits; the peers "
                         "have no limit)")
    ap.add_argument("--keep", metavar="DIR", help="keep the scratch files (labels, phi of each peer) in DIR")
    # The pyamg child process.
    ap.add_argument("--worker-pyamg", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--labels", help=argparse.SUPPRESS)
    ap.add_argument("--shape", type=int, nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker_pyamg:
        return pyamg_worker(a)
    if a.run is None:
        ap.error("the run directory is required")

    import zarr

    run = Path(a.run)
    if not (run / "zarr.json").is_file():
        fail(f"{run} is not a harmap run directory (no zarr.json)")
    if not (run / "labels" / "0" / "zarr.json").is_file():
        fail(f"{run} has no labels array labels/0 (run `harmap voxelize` first)")
    labels = np.ascontiguousarray(zarr.open_array(str(run / "labels" / "0"), mode="r")[...])
    why = check_labels(labels)
    if why:
        fail(f"{run}/labels/0: {why}")
    shape = labels.shape
    flat = labels.ravel()
    p = np.flatnonzero(flat == INTERIOR)
    n = int(p.size)
    offsets = neighbour_offsets(shape)
    lut = fixed_values(a.eps)
    r0 = residual_norm(flat, p, offsets, lut, np.ones(n))
    print(f"{run}: grid {shape[0]}x{shape[1]}x{shape[2]}, {n} unknowns, ||b - A x0|| = {r0:.6g}, "
          f"rtol {a.rtol:g}, eps {a.eps:g}, {a.threads} threads", flush=True)

    tmp = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="harmap-cmp-"))
    tmp.mkdir(parents=True, exist_ok=True)
    peers: dict[str, dict] = {}
    phis: dict[str, np.ndarray] = {}
    phis_ref = None
    report = {"run": str(run), "shape": list(shape), "unknowns": n, "rtol": a.rtol, "eps": a.eps,
              "threads": a.threads, "repeat": a.repeat, "residual0": r0, "harmap_bin": a.harmap,
              "harmap_mem": a.harmap_mem,
              "machine": {"cpu": cpu_name(), "cores": os.cpu_count(), "python": platform.python_version()},
              "peers": peers}
    try:
        labels_path = tmp / "labels.u8"
        labels.tofile(labels_path)
        runs = run_peers(a, labels_path, shape, tmp, report)
        # Each line: the repeat with the median total time (the machine may be shared);
        # every total is kept in the JSON. The peers are deterministic: phi is the same.
        for key, rs in runs.items():
            med = sorted(rs, key=lambda r: r["total_s"])[(len(rs) - 1) // 2]
            peers[key] = med | {"total_s_runs": [r["total_s"] for r in rs]}
        for key, peer in peers.items():
            if "file" in peer:
                phis[key] = np.fromfile(tmp / peer.pop("file"), dtype=np.float64)[p]
        if report.get("pyamg", {}).get("reference"):
            phis_ref = np.fromfile(tmp / "phi_reference.f64", dtype=np.float64)[p]
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    # harmap's own phi, when its solve stage has run.
    harmap_phi = run / "phi" / "0"
    if (harmap_phi / "zarr.json").is_file():
        h = zarr.open_array(str(harmap_phi), mode="r")
        if tuple(h.shape) != shape:
            fail(f"{harmap_phi} has shape {h.shape}, labels {shape}")
        phis["harmap"] = np.asarray(h[...], dtype=np.float64).ravel()[p]
        stage = json.loads((run / "zarr.json").read_text()).get("attributes", {}).get("harmap", {}) \
            .get("stages", {}).get("solve", {})
        result = stage.get("result") or {}
        rel = result.get("relative_residual", (result.get("residual_history") or [None])[-1])
        if "harmap" not in peers:
            peers["harmap"] = {"setup_s": None, "solve_s": stage.get("seconds"), "total_s": stage.get("seconds"),
                               "iterations": result.get("iterations"), "peak_rss": None, "rel_residual": rel,
                               "method": result.get("method")}
        report["harmap_solve_stage"] = stage
    else:
        print(f"harmap: no {harmap_phi} (harmap's solve has not run on this run directory)")

    # The same residual, recomputed from every phi by one matrix-free stencil.
    for key, x in phis.items():
        peers[key]["rel_residual_check"] = residual_norm(flat, p, offsets, lut, x) / r0
        peers[key]["phi_range"] = [float(np.nanmin(x)), float(np.nanmax(x))]
        if phis_ref is not None:
            peers[key]["max_abs_diff_reference"] = float(np.max(np.abs(x - phis_ref)))
    keys = list(phis)
    diffs = {}
    for i, ka in enumerate(keys):
        for kb in keys[i + 1:]:
            diffs[f"{ka} | {kb}"] = float(np.max(np.abs(phis[ka] - phis[kb])))
    report["max_abs_diff"] = diffs

    print_table(peers, report)
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {a.json}")
    return 0


def print_table(peers: dict, report: dict) -> None:
    print()
    head = f"{'peer':<20} {'setup s':>8} {'solve s':>8} {'total s':>8} {'iters':>6} {'peak MiB':>9} " \
           f"{'rel.res':>9} {'(check)':>9} {'|d ref|':>9}"
    print(head)
    print("-" * len(head))
    for key, r in peers.items():
        rr = "-" if r.get("rel_residual") is None else f"{r['rel_residual']:.2e}"
        if r.get("converged") is False:
            rr += "!"
        rc = "-" if r.get("rel_residual_check") is None else f"{r['rel_residual_check']:.2e}"
        it = "-" if r.get("iterations") is None else str(r["iterations"])
        rss = "-" if (r.get("peak_rss") or -1) < 0 else mib(r["peak_rss"])
        dr = "-" if r.get("max_abs_diff_reference") is None else f"{r['max_abs_diff_reference']:.2e}"
        print(f"{key:<20} {fmt_s(r['setup_s']):>8} {fmt_s(r['solve_s']):>8} {fmt_s(r['total_s']):>8} {it:>6} "
              f"{rss:>9} {rr:>9} {rc:>9} {dr:>9}")
    print()
    for key, r in peers.items():
        if key.startswith("pyamg"):
            w = report["pyamg"]
            print(f"{key}: setup = assemble {r['assemble_s']:.2f} s + hierarchy {r['hierarchy_s']:.2f} s; "
                  f"process wall {r['process_wall_s']:.2f} s.")
    if "pyamg" in report:
        print(f"pyamg {w['versions']['pyamg']}: {len(w['levels'])} levels {w['levels']}, operator complexity "
              f"{w['operator_complexity']:.2f}; the two solves share one setup in one process, peak RSS is "
              f"the process's up to the end of that solve; tol = {w['pyamg_tol']:.3g} "
              f"(= rtol ||b-Ax0|| / ||b||, ||b|| = {w['norm_b']:.4g}).")
    if "hypre" in report:
        h = report["hypre"]
        print(f"hypre {h['hypre']}: PFMG-CG on {h['ranks']} ranks ({h['launcher']}), relax type {h['relax_type']}, "
              f"RAP type {h['rap_type']}, skip-relax {h['skip_relax']}; peak = the sum of the ranks' VmHWM "
              f"({', '.join(mib(x) for x in h['peak_rss_ranks'])} MiB); its time excludes reading labels and "
              f"writing phi.")
    if "sor" in report:
        s, r = report["sor"], peers["SOR red-black (C)"]
        print(f"SOR: omega {s['omega']:.6f}, {s['threads']} threads ({' '.join(s['flags'])}), residual checked "
              f"every {s['check_every']} iteration(s), {r['residual_check_s']:.2f} s of the solve in checks; "
              f"process wall {r['process_wall_s']:.2f} s.")
    if "harmap" in peers:
        h = peers["harmap"]
        if h.get("total_s_runs"):
            print(f"harmap: `{report['harmap_bin']} solve RUN --mem {report['harmap_mem']}` (method "
                  f"{h.get('method')}; levels in memory {h.get('in_memory')}), run here; time: the solve stage's own "
                  f"(labels read to phi and u stored), process wall {h['process_wall_s']:.2f} s; peak: its VmHWM.")
        else:
            print(f"harmap: RUN/phi/0; time, iterations and rel.res from RUN/zarr.json (stages.solve, method "
                  f"{h.get('method')}), as that run recorded them on whatever machine and load it had.")
    if peers.get("harmap", {}).get("total_s_runs"):  # harmap ran here, with the peers
        t = peers["harmap"]["total_s"]
        ratios = [f"{k} {r['total_s'] / t:.1f}x" for k, r in peers.items() if k != "harmap" and r.get("total_s")]
        if ratios:
            print("harmap faster than (total / harmap's total): " + ", ".join(ratios))
    if report.get("repeat", 1) > 1:
        print(f"Times: the run of median total of {report['repeat']}, interleaved; all totals (s):")
        for key, r in peers.items():
            if r.get("total_s_runs"):
                print(f"  {key:<20} " + " ".join(f"{t:.2f}" for t in r["total_s_runs"]))
    print("rel.res: ||b - A x|| / ||b - A x0|| as the peer computed it (!: not below rtol, the iteration limit "
          "stopped it); (check): recomputed here, matrix-free.")
    if report.get("pyamg", {}).get("reference"):
        ref = report["pyamg"]["reference"]
        print(f"|d ref|: max |phi - phi_ref| over the unknowns, phi_ref from pyamg SA + CG to rel.res "
              f"{ref['rel_residual']:.1e} ({ref['iterations']} iterations, untimed).")
    if report["max_abs_diff"]:
        print("\nmax |phi_a - phi_b| over the unknowns:")
        for k, v in report["max_abs_diff"].items():
            print(f"  {k:<45} {v:.3e}")


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


if __name__ == "__main__":
    sys.exit(main())
