//! The built-in example shape: a five-armed starfish, like the paper's (section 6).
//!
//! A closed, genus-0 triangle surface generated in code, so `harmap run` works on a
//! fresh machine with no input file.

use std::f64::consts::PI;

use super::TriMesh;
use crate::math::Vec3;

/// A five-armed starfish about 2 units across and 0.75 thick, centered at the origin.
///
/// A sphere whose radius in the equatorial plane swells into five arms
/// (`r = 0.42 + 0.58 a(psi)`, `a` = 1 on an arm's axis, 0 between arms) and which is flattened along z
/// (more at the tips than at the domed body). `rings` and `segments` set the tessellation.
#[must_use]
pub fn starfish(rings: usize, segments: usize) -> TriMesh {
    let arms = 5.0;
    uv_sphere(rings, segments, |theta, psi| {
        // Arm profile: 1 on an arm's axis, 0 between arms, with rounded tips.
        let arm = (0.5 * (1.0 + (arms * psi).cos())).powf(2.5);
        let radial = 0.42 + 0.58 * arm;
        let (st, ct) = theta.sin_cos();
        // Thinner arms than body, and a domed body.
        let thickness = (0.28 - 0.16 * arm) * (1.0 + 0.35 * ct * ct);
        Vec3::new(
            radial * st * psi.cos(),
            radial * st * psi.sin(),
            thickness * ct,
        )
    })
}

/// A closed genus-0 surface given in spherical coordinates: `point(theta, psi)` for
/// polar angle `theta` in `[0, pi]` and azimuth `psi` in `[0, 2 pi)`, sampled on
/// `rings` x `segments` (poles included once). Outward-wound when `point` is a radial
/// graph (a star-shaped surface).
#[must_use]
pub fn uv_sphere(rings: usize, segments: usize, point: impl Fn(f64, f64) -> Vec3) -> TriMesh {
    let mut vertices = Vec::with_capacity(rings * segments + 2);
    vertices.push(point(0.0, 0.0));
    for r in 1..rings {
        let theta = PI * r as f64 / rings as f64;
        for s in 0..segments {
            vertices.push(point(theta, 2.0 * PI * s as f64 / segments as f64));
        }
    }
    vertices.push(point(PI, 0.0));
    let south = (vertices.len() - 1) as u32;
    let ring = |r: usize, s: usize| (1 + (r - 1) * segments + s % segments) as u32;
    let mut triangles = Vec::with_capacity(2 * rings * segments);
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (
                ring(r, s),
                ring(r, s + 1),
                ring(r + 1, s),
                ring(r + 1, s + 1),
            );
            triangles.push([a, c, d]);
            triangles.push([a, d, b]);
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn starfish_is_closed_and_outward() {
        let m = starfish(48, 160);
        assert!(m.topology().is_oriented_closed());
        assert!(m.signed_volume() > 0.0, "normals must point outward");
    }
}
