//! A surface for runs without an input mesh (label volumes, molecules, the standard
//! ball): surface nets over the solid's labels, block by block.
//!
//! Every cell of the grid (the cube between 2 x 2 x 2 voxel centers) whose corners are
//! part solid (labels 1-3) and part not gets one vertex: the mean of the midpoints of its
//! edges that cross between the two. Every pair of neighbouring voxels of which one is
//! solid gets a quad (two triangles) joining the vertices of the four cells around the
//! edge between them, wound so that its normal points out of the solid. The vertices lie
//! on the boundary between the solid's voxels and the outside, half a voxel from both.
//!
//! Out of core: a block reads its labels with one more voxel on every side and yields
//! the vertices of the cells whose lowest corner it holds and the quads of the edges
//! whose lower end it holds. The vertices are then numbered in the grid's C order of
//! their cells and the quads sorted by their edges, so the mesh does not depend on the
//! blocks or the threads. It takes memory in proportion to the surface, not the grid.
//! (Crates for surface nets work on one array in memory, with the seams between chunks
//! left to the caller; the seams are what this module is about.)

use glam::DVec3;

use crate::grid::{BlockStore, GridError};
use crate::input::TriMesh;

/// Whether a label is part of the solid (boundary, interior, center).
fn solid(label: u8) -> bool {
    matches!(label, 1..=3)
}

/// Corner k of a cell (bits: x, y, z) as an offset (x, y, z).
fn corner(k: usize) -> DVec3 {
    DVec3::new((k & 1) as f64, (k >> 1 & 1) as f64, (k >> 2) as f64)
}

/// The edges (i, j) of a cell between a solid and an outside corner, for the cell's
/// solid corners `m` (bit k for corner k).
fn crossing_edges(m: u8) -> impl Iterator<Item = (usize, usize)> {
    (0..8usize).flat_map(move |i| {
        [1usize, 2, 4]
            .into_iter()
            .filter(move |&bit| i & bit == 0)
            .map(move |bit| (i, i | bit))
            .filter(move |&(i, j)| (m >> i & 1) != (m >> j & 1))
    })
}

/// For every pattern of solid corners of a cell, the component of each solid corner
/// (corners joined by the cell's edges: the solid is 6-connected, as the voxelizer counts
/// it), numbered from 0 in the order of their lowest corners. A cell whose solid corners
/// touch only across a face's or the cube's diagonal gets one vertex per component, so
/// voxels touching only along an edge or at a corner do not pinch the surface.
fn components() -> &'static [[u8; 8]; 256] {
    static TABLE: std::sync::OnceLock<[[u8; 8]; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut table = [[u8::MAX; 8]; 256];
        for (m, row) in table.iter_mut().enumerate() {
            let mut next = 0u8;
            for k in 0..8usize {
                if m >> k & 1 == 0 || row[k] != u8::MAX {
                    continue;
                }
                // Flood the component of k along the cell's edges.
                let mut stack = vec![k];
                row[k] = next;
                while let Some(i) = stack.pop() {
                    for bit in [1usize, 2, 4] {
                        let j = i ^ bit;
                        if m >> j & 1 == 1 && row[j] == u8::MAX {
                            row[j] = next;
                            stack.push(j);
                        }
                    }
                }
                next += 1;
            }
        }
        table
    })
}

/// What a block yields: vertices (cell key, voxel position x, y, z) and quads (edge key,
/// the four cell keys in order around the edge, normal outward).
type Part = (Vec<(u64, DVec3)>, Vec<(u64, [u64; 4])>);

/// The surface of the solid in `labels`, in world coordinates, triangles wound outward.
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub fn from_labels(labels: &dyn BlockStore<u8>, workers: usize) -> Result<TriMesh, GridError> {
    let spec = labels.spec();
    let n = spec.shape.map(|s| s as i64);
    // Keys of cells and edges: the linear index of their lowest corner on the grid with
    // one more node before and after on every axis (a cell may start at -1). A vertex's
    // key is its cell's times 4 plus its component in the cell.
    let key = |v: [i64; 3]| -> u64 {
        (((v[0] + 1) * (n[1] + 2) + (v[1] + 1)) * (n[2] + 2) + (v[2] + 1)) as u64
    };
    let parts = crate::parallel::map_bounded(&spec.block_indices(), workers, |&b| {
        let st = spec.block_start(b).map(|c| c as i64);
        let sh = spec.block_shape(b).map(|c| c as usize);
        let origin = st.map(|c| c - 1);
        let shape = sh.map(|c| c + 2);
        let block = labels.read_region(origin, shape, 0)?;
        let at = |v: [i64; 3]| -> bool {
            let l: [usize; 3] = std::array::from_fn(|a| (v[a] - origin[a]) as usize);
            solid(block.data[block.offset(l[0], l[1], l[2])])
        };
        // The solid corners of the cell from u, as bits.
        let mask = |u: [i64; 3]| -> u8 {
            (0..8).fold(0u8, |m, k| {
                m | u8::from(at([u[0] + (k >> 2), u[1] + (k >> 1 & 1), u[2] + (k & 1)])) << k
            })
        };
        // A block holds the cells and edges from its own voxels, and on the grid's low
        // faces also those from -1 (outside the grid, where the labels read 0).
        let lo: [i64; 3] = std::array::from_fn(|a| if st[a] == 0 { -1 } else { st[a] });
        let mut part: Part = (Vec::new(), Vec::new());
        for z in lo[0]..st[0] + sh[0] as i64 {
            for y in lo[1]..st[1] + sh[1] as i64 {
                for x in lo[2]..st[2] + sh[2] as i64 {
                    let v = [z, y, x];
                    let m = mask(v);
                    if m != 0 && m != 0xff {
                        let comps = &components()[m as usize];
                        let mut sums = [(DVec3::ZERO, 0.0f64); 4];
                        for (i, j) in crossing_edges(m) {
                            let c = comps[if m >> i & 1 == 1 { i } else { j }];
                            let s = &mut sums[c as usize];
                            s.0 += (corner(i) + corner(j)) * 0.5;
                            s.1 += 1.0;
                        }
                        let base = DVec3::new(x as f64, y as f64, z as f64);
                        for (c, (sum, count)) in sums.iter().enumerate() {
                            if *count > 0.0 {
                                part.0.push((key(v) * 4 + c as u64, base + *sum / *count));
                            }
                        }
                    }
                    // The edges from v along z, y and x.
                    let here = m & 1 == 1;
                    for a in 0..3 {
                        let mut w = v;
                        w[a] += 1;
                        if here == at(w) {
                            continue;
                        }
                        // The solid end, and the other two axes in cyclic order.
                        let s = if here { v } else { w };
                        let (ab, ac) = ((a + 1) % 3, (a + 2) % 3);
                        // The vertex of the cell from v - i e_b - j e_c that holds s.
                        let cell = |i: i64, j: i64| {
                            let mut u = v;
                            u[ab] -= i;
                            u[ac] -= j;
                            let k =
                                ((s[0] - u[0]) << 2 | (s[1] - u[1]) << 1 | (s[2] - u[2])) as usize;
                            key(u) * 4 + u64::from(components()[mask(u) as usize][k])
                        };
                        // The unreversed loop's normal is -a (in world x, y, z); reversed
                        // when the solid is at the lower end, the normal points out of it.
                        let q = [cell(0, 0), cell(1, 0), cell(1, 1), cell(0, 1)];
                        let q = if here { [q[0], q[3], q[2], q[1]] } else { q };
                        part.1.push((key(v) * 3 + a as u64, q));
                    }
                }
            }
        }
        Ok::<_, GridError>(part)
    })?;
    let (mut verts, mut quads): Part = (Vec::new(), Vec::new());
    for (v, q) in parts {
        verts.extend(v);
        quads.extend(q);
    }
    verts.sort_unstable_by_key(|v| v.0);
    quads.sort_unstable_by_key(|q| q.0);
    let id = |k: u64| {
        verts
            .binary_search_by_key(&k, |v| v.0)
            .ok()
            .map(|i| i as u32)
    };
    let mut triangles = Vec::with_capacity(quads.len() * 2);
    for (_, q) in &quads {
        let (Some(a), Some(b), Some(c), Some(d)) = (id(q[0]), id(q[1]), id(q[2]), id(q[3])) else {
            // Every cell around a crossing edge has the vertex of its solid end.
            debug_assert!(false, "a quad without its vertices");
            continue;
        };
        triangles.push([a, b, c]);
        triangles.push([a, c, d]);
    }
    let o = DVec3::from_array(spec.origin);
    Ok(TriMesh {
        vertices: verts.iter().map(|(_, p)| o + *p * spec.spacing).collect(),
        triangles,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{fill_with, GridSpec, MemStore};

    /// Labels 2 where `inside` holds ([z, y, x]), 0 elsewhere, on an `n`^3 grid from
    /// `origin` with `spacing`, in blocks of `chunk`.
    fn labels(
        n: u64,
        chunk: u64,
        origin: [f64; 3],
        spacing: f64,
        inside: impl Fn([u64; 3]) -> bool + Sync + Send,
    ) -> MemStore<u8> {
        let spec = GridSpec {
            shape: [n; 3],
            origin,
            spacing,
            chunk: [chunk; 3],
            unit: None,
        };
        let store = MemStore::new(spec, 0u8);
        fill_with(&store, 1, |v| if inside(v) { 2 } else { 0 }).unwrap();
        store
    }

    /// A ball of radius `r` voxels around the grid's middle, and its voxel count.
    fn ball(n: u64, r: f64, chunk: u64) -> (MemStore<u8>, u64) {
        let c = (n as f64 - 1.0) / 2.0;
        let inside = |v: [u64; 3]| {
            let p = v.map(|v| v as f64 - c);
            (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() <= r
        };
        let count = (0..n * n * n)
            .filter(|i| inside([i / (n * n), i / n % n, i % n]))
            .count() as u64;
        (labels(n, chunk, [-1.0, 2.0, 0.5], 0.5, inside), count)
    }

    #[test]
    fn the_surface_of_a_ball_is_closed_outward_and_on_its_voxels_edge() {
        let (store, count) = ball(24, 8.3, 8);
        let m = from_labels(&store, 2).unwrap();
        // A closed 2-manifold of genus 0.
        assert_eq!(manifold_euler(&m), 2);
        // Wound outward, around about the solid voxels' volume (spacing 0.5).
        let v = m.signed_volume();
        let voxels = count as f64 * 0.125;
        assert!(v > 0.0, "inward: {v}");
        assert!((v / voxels - 1.0).abs() < 0.1, "{v} against {voxels}");
        // Every vertex within a voxel of the sphere through the voxels' outer faces.
        let c = DVec3::new(-1.0, 2.0, 0.5) + DVec3::splat(11.5 * 0.5);
        for p in &m.vertices {
            let r = (*p - c).length() / 0.5;
            assert!((r - 8.3).abs() < 1.0, "{p}: {r} voxels from the center");
        }
    }

    /// Labels 2 at `voxels` ([z, y, x]) in an `n`^3 grid of blocks of `chunk`.
    fn voxels(n: u64, chunk: u64, voxels: &[[u64; 3]]) -> MemStore<u8> {
        labels(n, chunk, [0.0; 3], 1.0, |v| voxels.contains(&v))
    }

    /// Every edge in exactly two triangles, once each way (a closed, consistently wound
    /// 2-manifold), and V - E + F.
    fn manifold_euler(m: &TriMesh) -> i64 {
        let mut edges = std::collections::HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "edge {a}-{b} used {n} times the same way");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
        }
        m.vertices.len() as i64 - (edges.len() / 2) as i64 + m.triangles.len() as i64
    }

    /// Voxels that touch only along an edge or at a corner are two pieces of surface (the
    /// solid is 6-connected), each a sphere; a solid on the grid's low faces is closed.
    #[test]
    fn diagonal_contacts_and_grid_faces_keep_the_surface_a_manifold() {
        for (case, vox, pieces) in [
            ("one voxel", vec![[3, 3, 3]], 1),
            ("along an edge", vec![[3, 3, 3], [3, 4, 4]], 2),
            ("at a corner", vec![[3, 3, 3], [4, 4, 4]], 2),
            ("an L", vec![[3, 3, 3], [3, 3, 4], [3, 4, 4]], 1),
            ("on the low faces", vec![[0, 0, 0], [0, 0, 1], [1, 0, 0]], 1),
            ("on the high faces", vec![[7, 7, 7], [7, 6, 7]], 1),
        ] {
            for chunk in [3, 8] {
                let m = from_labels(&voxels(8, chunk, &vox), 2).unwrap();
                assert_eq!(manifold_euler(&m), 2 * pieces, "{case}, blocks of {chunk}");
                assert!(m.signed_volume() > 0.0, "{case}");
            }
        }
    }

    #[test]
    fn the_surface_does_not_depend_on_the_blocks_or_threads() {
        let (a, _) = ball(24, 8.3, 8);
        let (b, _) = ball(24, 8.3, 5);
        let (ma, mb) = (from_labels(&a, 2).unwrap(), from_labels(&b, 1).unwrap());
        assert_eq!(ma.triangles, mb.triangles);
        assert_eq!(ma.vertices, mb.vertices);
        assert!(!ma.triangles.is_empty());
    }
}
