#!/usr/bin/env python3
"""Write a large label volume for the topology repair's out-of-core benchmark: a ball
with thin rings half sunk into its surface, each ring's outer arc a handle (genus = the
number of rings), as raw u8 bytes in C order (z, y, x), one slice at a time.

    benches/handles_volume.py OUT.raw [N] [RINGS]     (defaults: 1000 voxels, 8 rings)

The ball: center N/2, radius 0.44 N. Each ring: major radius 0.04 N, tube radius 2
voxels, centered on the ball's surface in a plane through the ball's center, so half of
it lies outside. Prints the shape for --raw-shape.
"""
import sys

import numpy as np

out = sys.argv[1]
n = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
rings = int(sys.argv[3]) if len(sys.argv) > 3 else 8
c = n / 2.0
big_r = 0.44 * n
ring_r = 0.04 * n
tube = 2.0
rng = np.random.default_rng(7)
specs = []
for _ in range(rings):
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    e = np.cross(d, rng.normal(size=3))
    e /= np.linalg.norm(e)
    # The ring lies in the plane of d and e, so its axis is their cross product.
    axis = np.cross(d, e)
    specs.append((c + big_r * d, axis))
ys, xs = np.meshgrid(np.arange(n, dtype=np.float32), np.arange(n, dtype=np.float32), indexing="ij")
with open(out, "wb") as f:
    for z in range(n):
        inside = (z - c) ** 2 + (ys - c) ** 2 + (xs - c) ** 2 <= big_r**2
        for center, axis in specs:
            if abs(z - center[2]) > ring_r + tube + 1:
                continue
            lo = np.maximum(np.floor(center[:2] - ring_r - tube - 1).astype(int), 0)
            hi = np.minimum(np.ceil(center[:2] + ring_r + tube + 2).astype(int), n)
            # Points as (x, y, z) against the center (x, y, z).
            px = xs[lo[1] : hi[1], lo[0] : hi[0]] - center[0]
            py = ys[lo[1] : hi[1], lo[0] : hi[0]] - center[1]
            pz = np.float32(z - center[2])
            along = px * axis[0] + py * axis[1] + pz * axis[2]
            radial = np.sqrt(np.maximum(px * px + py * py + pz * pz - along * along, 0))
            near = (radial - ring_r) ** 2 + along**2 <= tube**2
            inside[lo[1] : hi[1], lo[0] : hi[0]] |= near
        f.write(inside.astype(np.uint8).tobytes())
print(f"{n},{n},{n}")
