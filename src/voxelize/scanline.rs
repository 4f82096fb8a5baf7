//! Inside test of a closed surface by scanlines along x: the solid occupancy of every
//! voxel center, block column by block column.
//!
//! For each row of voxel centers (fixed y, z) the ray from x = -inf crosses the
//! triangles whose (y, z) projection contains the row point. Signs of the projected
//! edge functions are exact (Shewchuk's `orient2d`, crate `robust`), and a row point
//! lying exactly on a projected edge or vertex is given to exactly one of the triangles
//! around it by an antisymmetric tie rule on the edge's endpoints. So a closed surface
//! is crossed consistently (watertight) and the signed crossing count before a voxel
//! center is its exact winding number, whatever the face orientation:
//! - [`InsideRule::Winding`] (closed, consistently oriented surfaces): inside where the
//!   winding number is not 0. Overlapping or self-intersecting closed parts count as
//!   their union; inward-wound meshes (winding -1) work too.
//! - [`InsideRule::Parity`] (closed, inconsistently oriented): inside where the number of
//!   crossings is odd.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use robust::{orient2d, Coord};

use crate::grid::{BlockStore, Decomposition, GridSpec};
use crate::input::TriMesh;
use crate::math::Idx3;
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// How crossings along a row decide inside.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum InsideRule {
    /// Non-zero winding number (closed, consistently oriented surfaces).
    Winding,
    /// Odd number of crossings (closed surfaces with inconsistent orientation).
    Parity,
}

/// Inclusive row ranges `((y0, y1), (z0, z1))` a triangle may cross.
type RowRanges = ((u64, u64), (u64, u64));

impl InsideRule {
    /// The rule's name, as recorded in the run.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            InsideRule::Winding => "winding",
            InsideRule::Parity => "parity",
        }
    }
}

/// A triangle prepared for row tests: projected (y, z) corners and their x.
#[derive(Clone, Copy)]
struct Tri {
    p: [Coord<f64>; 3],
    x: [f64; 3],
}

/// Row index range `[lo, hi]` (inclusive, clamped to `0..n`) of voxel centers
/// `origin + h * i` inside `[a, b]`, widened by one row on each side so that rounding in
/// the division never drops a row the exact test would accept.
fn row_range(a: f64, b: f64, origin: f64, h: f64, n: u64) -> Option<(u64, u64)> {
    let lo = ((a - origin) / h).floor() - 1.0;
    let hi = ((b - origin) / h).ceil() + 1.0;
    if hi < 0.0 || lo > (n - 1) as f64 {
        return None;
    }
    Some((lo.max(0.0) as u64, (hi as u64).min(n - 1)))
}

/// Sign of the edge function of directed edge `a -> b` at `q`, never 0: an exact zero
/// takes the sign of the endpoint order, which is antisymmetric in (a, b), so of the two
/// triangles sharing an edge exactly one claims points on it.
#[inline]
fn edge_sign(a: Coord<f64>, b: Coord<f64>, q: Coord<f64>) -> (i8, f64) {
    let e = orient2d(a, b, q);
    let s = if e > 0.0 {
        1
    } else if e < 0.0 {
        -1
    } else if (a.x, a.y) < (b.x, b.y) {
        1
    } else {
        -1
    };
    (s, e)
}

/// Write the solid occupancy (1 inside, 0 outside) of every voxel of `spec` into `out`,
/// on the block layers `decomp` gives this process.
/// Returns the number of rows whose crossings did not sum to zero (a sign of a surface
/// that is not closed at that row; 0 for a closed surface).
pub fn mesh_solid(
    mesh: &TriMesh,
    rule: InsideRule,
    out: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<u64, crate::Error> {
    let spec = out.spec().clone();
    let h = spec.spacing;
    let nb = spec.blocks();
    let c = spec.chunk;
    // Prepare triangles and bin them into block columns (bz, by) by their (y, z) rows.
    let mut tris = Vec::with_capacity(mesh.triangles.len());
    let mut ranges = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        let v = t.map(|i| mesh.vertices[i as usize]);
        let p = v.map(|v| Coord { x: v.y, y: v.z });
        if orient2d(p[0], p[1], p[2]) == 0.0 {
            continue; // edge-on in the (y, z) projection: no ray crosses it
        }
        let (ylo, yhi) = (
            v[0].y.min(v[1].y).min(v[2].y),
            v[0].y.max(v[1].y).max(v[2].y),
        );
        let (zlo, zhi) = (
            v[0].z.min(v[1].z).min(v[2].z),
            v[0].z.max(v[1].z).max(v[2].z),
        );
        let (Some(jr), Some(kr)) = (
            row_range(ylo, yhi, spec.origin[1], h, spec.shape[1]),
            row_range(zlo, zhi, spec.origin[2], h, spec.shape[0]),
        ) else {
            continue;
        };
        tris.push(Tri {
            p,
            x: v.map(|v| v.x),
        });
        ranges.push((jr, kr));
    }
    let ncols = (nb[0] * nb[1]) as usize;
    let mut counts = vec![0usize; ncols + 1];
    let cols_of = |&((j0, j1), (k0, k1)): &((u64, u64), (u64, u64))| {
        (k0 / c[0]..=k1 / c[0])
            .flat_map(move |bz| (j0 / c[1]..=j1 / c[1]).map(move |by| (bz * nb[1] + by) as usize))
    };
    for r in &ranges {
        for col in cols_of(r) {
            counts[col + 1] += 1;
        }
    }
    for i in 0..ncols {
        counts[i + 1] += counts[i];
    }
    let mut fill = counts.clone();
    let mut col_tris = vec![0u32; counts[ncols]];
    for (t, r) in ranges.iter().enumerate() {
        for col in cols_of(r) {
            col_tris[fill[col]] = t as u32;
            fill[col] += 1;
        }
    }
    drop(fill);

    // The columns of the block layers this process owns.
    let columns: Vec<(u64, u64)> = decomp
        .z_layers(decomp.part(), nb)
        .flat_map(|bz| (0..nb[1]).map(move |by| (bz, by)))
        .collect();
    progress.start("voxelize: inside test", columns.len() as u64);
    let unclosed = map_bounded(
        &columns,
        workers,
        |&(bz, by)| -> Result<u64, crate::Error> {
            // A stop request (Ctrl-C) ends the pass at the next block.
            crate::progress::check_interrupt(progress)?;
            let col = (bz * nb[1] + by) as usize;
            let list = &col_tris[counts[col]..counts[col + 1]];
            let r = column(&spec, &tris, &ranges, list, [bz, by], rule, out)?;
            progress.advance(1);
            Ok(r)
        },
    )?;
    progress.finish();
    Ok(unclosed.iter().sum())
}

/// Fill one block column and write its blocks. Returns the count of unclosed rows.
#[allow(clippy::too_many_arguments)]
#[allow(clippy::too_many_lines)] // one scanline column: crossings, parity and runs in one loop
fn column(
    spec: &GridSpec,
    tris: &[Tri],
    ranges: &[RowRanges],
    list: &[u32],
    [bz, by]: [u64; 2],
    rule: InsideRule,
    out: &dyn BlockStore<u8>,
) -> Result<u64, crate::Error> {
    let c = spec.chunk;
    let z0 = bz * c[0];
    let y0 = by * c[1];
    let nz = (spec.shape[0] - z0).min(c[0]) as usize;
    let ny = (spec.shape[1] - y0).min(c[1]) as usize;
    let nx = spec.shape[2] as usize;
    // Bin the column's triangles by row (CSR).
    let mut start = vec![0usize; nz * ny + 1];
    let rows_of = |t: u32| {
        let ((j0, j1), (k0, k1)) = ranges[t as usize];
        let (k0, k1) = (k0.max(z0), k1.min(z0 + nz as u64 - 1));
        let (j0, j1) = (j0.max(y0), j1.min(y0 + ny as u64 - 1));
        (k0..=k1)
            .flat_map(move |k| (j0..=j1).map(move |j| ((k - z0) as usize) * ny + (j - y0) as usize))
    };
    for &t in list {
        for r in rows_of(t) {
            start[r + 1] += 1;
        }
    }
    for i in 0..nz * ny {
        start[i + 1] += start[i];
    }
    let mut pos = start.clone();
    let mut row_tris = vec![0u32; start[nz * ny]];
    for &t in list {
        for r in rows_of(t) {
            row_tris[pos[r]] = t;
            pos[r] += 1;
        }
    }
    let mut buf = vec![0u8; nz * ny * nx];
    let mut crossings: Vec<(f64, i8)> = Vec::new();
    let mut unclosed = 0;
    let h = spec.spacing;
    for kz in 0..nz {
        let qz = spec.origin[2] + h * (z0 + kz as u64) as f64;
        for jy in 0..ny {
            let qy = spec.origin[1] + h * (y0 + jy as u64) as f64;
            let q = Coord { x: qy, y: qz };
            let r = kz * ny + jy;
            crossings.clear();
            for &t in &row_tris[start[r]..start[r + 1]] {
                let Tri { p, x } = tris[t as usize];
                let (s0, e0) = edge_sign(p[1], p[2], q);
                let (s1, e1) = edge_sign(p[2], p[0], q);
                if s1 != s0 {
                    continue;
                }
                let (s2, e2) = edge_sign(p[0], p[1], q);
                if s2 != s0 {
                    continue;
                }
                let sum = e0 + e1 + e2;
                let xc = if sum == 0.0 {
                    (x[0] + x[1] + x[2]) / 3.0
                } else {
                    (e0 * x[0] + e1 * x[1] + e2 * x[2]) / sum
                };
                crossings.push((xc, s0));
            }
            if crossings.is_empty() {
                continue;
            }
            crossings.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let total: i64 = crossings.iter().map(|&(_, s)| i64::from(s)).sum();
            if (rule == InsideRule::Winding && total != 0)
                || (rule == InsideRule::Parity && !crossings.len().is_multiple_of(2))
            {
                unclosed += 1;
            }
            let row = &mut buf[r * nx..(r + 1) * nx];
            let mut idx = 0;
            let mut winding: i64 = 0;
            let mut count = 0usize;
            let first = ((crossings[0].0 - spec.origin[0]) / h).floor().max(0.0) as usize;
            for (i, v) in row.iter_mut().enumerate().skip(first.min(nx)) {
                let xi = spec.origin[0] + h * i as f64;
                while idx < crossings.len() && crossings[idx].0 < xi {
                    // An outward normal has +x where the ray leaves the solid.
                    winding -= i64::from(crossings[idx].1);
                    count += 1;
                    idx += 1;
                }
                if idx == crossings.len() && winding == 0 && count.is_multiple_of(2) {
                    break;
                }
                let inside = match rule {
                    InsideRule::Winding => winding != 0,
                    InsideRule::Parity => count % 2 == 1,
                };
                *v = u8::from(inside);
            }
        }
    }
    // Hand the column to the store block by block.
    let bx_n = spec.blocks()[2];
    for bx in 0..bx_n {
        let x0 = (bx * spec.chunk[2]) as usize;
        let w = (nx - x0).min(spec.chunk[2] as usize);
        let mut block = Vec::with_capacity(nz * ny * w);
        for r in 0..nz * ny {
            block.extend_from_slice(&buf[r * nx + x0..r * nx + x0 + w]);
        }
        let b: Idx3 = [bz, by, bx];
        out.write_block(b, &block)?;
    }
    Ok(unclosed)
}
