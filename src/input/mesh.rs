//! `TriMesh`: a triangle surface, and the checks that say how far it is from a closed,
//! consistently oriented surface (which decides the inside test the voxelizer uses).

use crate::math::Vec3;

/// A triangle surface in world coordinates `(x, y, z)`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub vertices: Vec<Vec3>,
    /// Triangles as vertex indices (in the file's winding order).
    pub triangles: Vec<[u32; 3]>,
}

/// Edge topology of a mesh, from which the voxelizer picks its inside rule.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MeshTopology {
    /// Triangles with two equal vertex indices (skipped).
    pub degenerate: u64,
    /// Undirected edges used by exactly one triangle (holes).
    pub boundary_edges: u64,
    /// Undirected edges used by an odd number of triangles other than one.
    pub odd_edges: u64,
    /// Undirected edges used by more than two triangles.
    pub nonmanifold_edges: u64,
    /// Edges whose two directions are not used equally often (inconsistent winding).
    pub unbalanced_edges: u64,
    /// An example boundary edge, as vertex indices (0-based).
    pub example_open_edge: Option<[u32; 2]>,
}

impl MeshTopology {
    /// Every undirected edge is used an even number of times: a closed surface mod 2,
    /// so the crossing parity along a ray is well defined.
    #[must_use]
    pub fn is_closed(&self) -> bool {
        self.boundary_edges == 0 && self.odd_edges == 0
    }

    /// Closed, and each edge is used as often in one direction as in the other: the
    /// signed crossing count along a ray is the exact winding number.
    #[must_use]
    pub fn is_oriented_closed(&self) -> bool {
        self.is_closed() && self.unbalanced_edges == 0
    }
}

impl TriMesh {
    /// Axis-aligned bounding box of the referenced vertices, `(min, max)`.
    #[must_use]
    pub fn bbox(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self
            .triangles
            .iter()
            .flatten()
            .map(|&i| self.vertices[i as usize]);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }

    /// Signed volume (positive when the triangles wind counter-clockwise seen from
    /// outside, i.e. normals point outward).
    #[must_use]
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Edge-use counts of the surface.
    #[must_use]
    pub fn topology(&self) -> MeshTopology {
        let mut edges: Vec<(u32, u32, i32)> = Vec::with_capacity(self.triangles.len() * 3);
        let mut topo = MeshTopology::default();
        for t in &self.triangles {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                topo.degenerate += 1;
                continue;
            }
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                if a < b {
                    edges.push((a, b, 1));
                } else {
                    edges.push((b, a, -1));
                }
            }
        }
        edges.sort_unstable();
        let mut i = 0;
        while i < edges.len() {
            let (a, b, _) = edges[i];
            let mut j = i;
            let mut net = 0;
            while j < edges.len() && edges[j].0 == a && edges[j].1 == b {
                net += edges[j].2;
                j += 1;
            }
            let uses = (j - i) as u64;
            if uses == 1 {
                topo.boundary_edges += 1;
                topo.example_open_edge.get_or_insert([a, b]);
            } else if uses % 2 == 1 {
                topo.odd_edges += 1;
            }
            if uses > 2 {
                topo.nonmanifold_edges += 1;
            }
            if net != 0 {
                topo.unbalanced_edges += 1;
            }
            i = j;
        }
        topo
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn tetrahedron() -> TriMesh {
        TriMesh {
            vertices: vec![
                Vec3::ZERO,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        }
    }

    #[test]
    fn closed_oriented_tetrahedron() {
        let m = tetrahedron();
        let t = m.topology();
        assert!(t.is_oriented_closed(), "{t:?}");
        assert!((m.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn flipped_face_and_hole_are_seen() {
        let mut m = tetrahedron();
        m.triangles[0] = [0, 1, 2];
        let t = m.topology();
        assert!(t.is_closed() && !t.is_oriented_closed());
        assert_eq!(t.unbalanced_edges, 3);
        m.triangles.pop();
        let t = m.topology();
        assert_eq!(t.boundary_edges, 3);
        assert!(!t.is_closed());
    }
}
