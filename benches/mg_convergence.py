#!/usr/bin/env python3
"""Why harmap's V-cycles converge at 0.2-0.3 a cycle on the standard ball, not at the
textbook 0.05-0.1: a NumPy model of the solve's multigrid, for trying coarse-level
treatments before building them into src/solve.

The model is harmap's cycle on the standard problem: an N^3 grid, unknowns inside the
ball of radius 0.45 N and outside the sink of radius --sink around the center (on an
even node, so it survives coarsening), u = 1 on the sink and 0 outside the ball; levels
vertex-centered (coarse node I on fine node 2I, an unknown when that one is), red-black
Gauss-Seidel V(2,2), full weighting of the defect (times 4), trilinear prolongation, the
coarsest level (at most 12 nodes an axis) relaxed by 200 sweeps. It prints the
residual's decrease per cycle.

  --coarse staircase   the coarse masks are injected and the coarse operator is the
                       7-point stencil (what harmap does)
  --coarse sw          each coarse unknown next to a fixed node gets a Shortley-Weller
                       arm of the length at which the finest level's boundary lies
                       (recursively: half the finer level's arm, or one plus it, halved)
  --boundary-sweeps K  after each smoothing, K more red-black sweeps over the unknowns
                       within 2 nodes of a fixed one

Measured (numpy, a few seconds at N = 128):

  N    sink  coarse     boundary sweeps  factor per cycle (cycles 6-8)
  64   2     staircase  0                0.13-0.14
  64   2     staircase  2                0.10
  64   2     sw         0                0.20
  128  2     staircase  0                0.20-0.26
  128  2     staircase  2                0.16-0.18
  128  2     sw         0                0.27
  128  6.4   staircase  0                0.31
  128  6.4   sw         0                0.10

So the slow mode is the sink: the factor grows with N at a fixed sink of 2 voxels and
is worse for a larger sink, which the arms fix when the sink spans a few coarse nodes
(0.31 to 0.10) but not when it is smaller than a coarse cell (a fixed coarse node then
stands for a larger sink than the fine level's).

  python3 benches/mg_convergence.py 128 --sink 6.4 --coarse sw
"""
import argparse

import numpy as np

AXES = [(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]


def shift(a, ax, d):
    """The neighbour at i + d along ax (0 past the edge)."""
    out = np.zeros_like(a)
    dst, src = [slice(None)] * 3, [slice(None)] * 3
    if d == 1:
        dst[ax], src[ax] = slice(0, -1), slice(1, None)
    else:
        dst[ax], src[ax] = slice(1, None), slice(0, -1)
    out[tuple(dst)] = a[tuple(src)]
    return out


def levels(unknown, sw):
    """The levels' unknowns and arms (in units of each level's spacing)."""
    out = []
    arms = {d: np.ones(unknown.shape) for d in AXES}
    while True:
        w = {}
        for ax in range(3):
            ap, am = arms[(ax, 1)], arms[(ax, -1)]
            w[(ax, 1)], w[(ax, -1)] = 2 / (ap * (ap + am)), 2 / (am * (ap + am))
        n = unknown.shape
        i, j, k = np.indices(n)
        out.append(dict(unk=unknown, w=w, diag=sum(w.values()), red=(i + j + k) % 2 == 0))
        if max(n) <= 12:
            return out
        coarse = {}
        for ax, d in AXES:
            between = shift(unknown, ax, d)
            far = shift(between, ax, d)
            t = np.where(~between, arms[(ax, d)] / 2,
                         np.where(~far, (1 + shift(arms[(ax, d)], ax, d)) / 2, 1.0))
            coarse[(ax, d)] = t[::2, ::2, ::2]
        unknown = unknown[::2, ::2, ::2].copy()
        arms = coarse if sw else {d: np.ones(unknown.shape) for d in AXES}


def apply(lv, u):
    out = lv["diag"] * u
    for d, w in lv["w"].items():
        out -= w * shift(u, *d)
    return np.where(lv["unk"], out, 0)


def smooth(lv, u, f, sweeps, extra):
    def half(mask):
        s = f.copy()
        for d, w in lv["w"].items():
            s += w * shift(u, *d)
        u[mask] = (s / lv["diag"])[mask]

    for _ in range(sweeps):
        for col in (lv["red"], ~lv["red"]):
            half(lv["unk"] & col)
    if extra:
        if "near" not in lv:
            g = ~lv["unk"]
            for _ in range(2):
                g = g | np.logical_or.reduce([shift(g, *d) for d in AXES])
            lv["near"] = g & lv["unk"]
        for _ in range(extra):
            for col in (lv["red"], ~lv["red"]):
                half(lv["near"] & col)
    return u


def restrict(r):
    w1 = [0.5, 1.0, 0.5]
    acc = np.zeros_like(r)
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            for c in (-1, 0, 1):
                t = r
                for ax, d in ((0, a), (1, b), (2, c)):
                    if d:
                        t = shift(t, ax, d)
                acc += w1[a + 1] * w1[b + 1] * w1[c + 1] * t
    return acc[::2, ::2, ::2] / 2  # the average (1/8) times the spacing ratio squared (4)


def prolong(e, shape):
    out = np.zeros(shape)
    out[::2, ::2, ::2] = e
    for ax in range(3):
        odd = [slice(None)] * 3
        odd[ax] = slice(1, None, 2)
        k = out[tuple(odd)].shape[ax]
        lo, hi = [slice(None)] * 3, [slice(None)] * 3
        lo[ax], hi[ax] = slice(0, 2 * k, 2), slice(2, 2 * k + 1, 2)
        a, bb = out[tuple(lo)], out[tuple(hi)]
        b = np.zeros_like(a)
        b[tuple(slice(0, s) for s in bb.shape)] = bb
        out[tuple(odd)] = 0.5 * (a + b)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("n", type=int, help="grid edge N")
    ap.add_argument("--sink", type=float, default=2.0, help="sink radius in voxels (default 2)")
    ap.add_argument("--coarse", choices=["staircase", "sw"], default="staircase")
    ap.add_argument("--boundary-sweeps", type=int, default=0)
    ap.add_argument("--cycles", type=int, default=8)
    a = ap.parse_args()
    n = a.n
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(float)
    c = 2 * round(n / 4)
    r = np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)
    unknown = (r < 0.45 * n) & (r > a.sink)
    L = levels(unknown, a.coarse == "sw")

    def cycle(k, u, f):
        lv = L[k]
        if k == len(L) - 1:
            return smooth(lv, u, f, 200, 0)
        u = smooth(lv, u, f, 2, a.boundary_sweeps)
        fc = restrict(np.where(lv["unk"], f - apply(lv, u), 0))
        ec = cycle(k + 1, np.zeros_like(fc), np.where(L[k + 1]["unk"], fc, 0))
        u = u + np.where(lv["unk"], prolong(ec, u.shape), 0)
        return smooth(lv, u, f, 2, a.boundary_sweeps)

    u = np.where(r <= a.sink, 1.0, 0.0)
    f = np.zeros_like(u)
    res = lambda u: np.linalg.norm(np.where(unknown, f - apply(L[0], u), 0))
    r0 = prev = res(u)
    print(f"N {n}, sink {a.sink}, coarse {a.coarse}, boundary sweeps {a.boundary_sweeps}, {len(L)} levels")
    for it in range(a.cycles):
        u = cycle(0, u, f)
        rr = res(u)
        print(f"cycle {it + 1}: relative residual {rr / r0:.2e}, factor {rr / prev:.3f}")
        prev = rr


if __name__ == "__main__":
    main()
