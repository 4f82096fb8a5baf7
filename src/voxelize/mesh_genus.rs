//! The topology of a closed triangle surface, from its Euler characteristic: for each
//! connected part (triangles sharing vertices), chi = V - E + F, and a closed orientable
//! surface of genus g has chi = 2 - 2 g. What the voxel solid should be follows from it:
//! a mesh of genus-0 parts makes a solid whose handles are discretization artifacts.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use crate::input::TriMesh;

/// Parts and total genus of a closed surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SurfaceTopology {
    /// Connected parts (triangles joined through shared vertices).
    pub parts: u64,
    /// Sum over the parts of their genus, `(2 - chi) / 2` each (never below 0).
    pub genus: i64,
}

/// Root of `a` in the parent forest `p`, halving paths on the way.
fn root(p: &mut [u32], mut a: u32) -> u32 {
    while p[a as usize] != a {
        p[a as usize] = p[p[a as usize] as usize];
        a = p[a as usize];
    }
    a
}

/// Parts and genus of `mesh` (degenerate triangles skipped; the mesh is assumed closed).
#[must_use]
pub fn surface_topology(mesh: &TriMesh) -> SurfaceTopology {
    let nv = mesh.vertices.len();
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    let tris: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .copied()
        .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
        .collect();
    for t in &tris {
        for k in 1..3 {
            let (a, b) = (root(&mut parent, t[0]), root(&mut parent, t[k]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    // Per part (keyed by its root vertex): V, E, F.
    let mut used = vec![false; nv];
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(tris.len() * 3);
    for t in &tris {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            edges.push((a.min(b), a.max(b)));
        }
        for &v in t {
            used[v as usize] = true;
        }
    }
    edges.sort_unstable();
    edges.dedup();
    let mut chi = std::collections::BTreeMap::<u32, i64>::new();
    for v in 0..nv as u32 {
        if used[v as usize] {
            *chi.entry(root(&mut parent, v)).or_default() += 1;
        }
    }
    for &(a, _) in &edges {
        *chi.entry(root(&mut parent, a)).or_default() -= 1;
    }
    for t in &tris {
        *chi.entry(root(&mut parent, t[0])).or_default() += 1;
    }
    SurfaceTopology {
        parts: chi.len() as u64,
        genus: chi.values().map(|&c| ((2 - c) / 2).max(0)).sum(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vec3;

    /// A torus of `n` x `m` quads, split into triangles.
    fn torus(n: u32, m: u32) -> TriMesh {
        let mut mesh = TriMesh::default();
        for i in 0..n {
            for j in 0..m {
                let (u, v) = (
                    f64::from(i) / f64::from(n) * std::f64::consts::TAU,
                    f64::from(j) / f64::from(m) * std::f64::consts::TAU,
                );
                let r = 3.0 + v.cos();
                mesh.vertices
                    .push(Vec3::new(r * u.cos(), r * u.sin(), v.sin()));
            }
        }
        let id = |i: u32, j: u32| (i % n) * m + (j % m);
        for i in 0..n {
            for j in 0..m {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                mesh.triangles.push([a, b, c]);
                mesh.triangles.push([a, c, d]);
            }
        }
        mesh
    }

    #[test]
    fn tetrahedra_and_torus() {
        let tet = |o: f64, base: u32| {
            (
                vec![
                    Vec3::splat(o),
                    Vec3::new(o + 1.0, o, o),
                    Vec3::new(o, o + 1.0, o),
                    Vec3::new(o, o, o + 1.0),
                ],
                [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]].map(|t: [u32; 3]| t.map(|v| v + base)),
            )
        };
        let (v1, t1) = tet(0.0, 0);
        let (v2, t2) = tet(5.0, 4);
        let two = TriMesh {
            vertices: [v1, v2].concat(),
            triangles: [t1, t2].concat(),
        };
        assert_eq!(
            surface_topology(&two),
            SurfaceTopology { parts: 2, genus: 0 }
        );
        assert_eq!(
            surface_topology(&torus(12, 8)),
            SurfaceTopology { parts: 1, genus: 1 }
        );
    }
}
