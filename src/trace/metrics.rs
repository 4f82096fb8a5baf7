//! Bijectivity and distortion of the boundary -> sphere map (the paper's future work).
//!
//! - flipped triangles: a surface triangle whose image on the sphere (the flat triangle
//!   of its three sphere points) faces inward, when the surface's faces outward;
//! - collisions: seeds whose sphere points lie within a tiny angle of the sphere point
//!   of a seed that is far from them on the shape (two parts of the surface landing on
//!   one place of the sphere);
//! - area distortion: per triangle, log of (its share of the sphere's area) over (its
//!   share of the surface's area); 0 where the map preserves area;
//! - conformal distortion: per triangle, the ratio of the singular values of the linear
//!   map from the surface triangle to its sphere triangle; 1 where angles are kept.

use rayon::prelude::*;

use glam::{DVec2, DVec3};
use serde::Serialize;

/// Quantiles of a distribution.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Quantiles {
    /// 5th percentile.
    pub p05: f64,
    /// Median.
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Largest value.
    pub max: f64,
}

impl Quantiles {
    fn of(mut v: Vec<f64>) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
        Self {
            p05: q(0.05),
            p50: q(0.5),
            p95: q(0.95),
            max: v[v.len() - 1],
        }
    }
}

/// The numbers of a surface's sphere map.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SurfaceMetrics {
    /// Triangles of the surface.
    pub triangles: u64,
    /// Triangles with all three vertices on the sphere (reached the center).
    pub measured: u64,
    /// Triangles whose sphere image faces inward.
    pub flipped: u64,
    /// Triangles whose sphere image has no area.
    pub degenerate: u64,
    /// log(sphere area share / surface area share) per measured triangle.
    pub log_area_ratio: Quantiles,
    /// Ratio of singular values of the triangle map (1 = conformal).
    pub conformal: Quantiles,
}

/// Seeds landing on top of seeds from elsewhere.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Collisions {
    /// The angle below which two sphere points count as one place (degrees).
    pub angle_deg: f64,
    /// The distance on the shape beyond which two seeds count as different parts
    /// (voxels).
    pub far_voxels: f64,
    /// Seeds with such a neighbour.
    pub seeds: u64,
}

/// Seeds whose stored arrival direction cannot be told from another's.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Indistinguishable {
    /// The stored precision of theta and psi ("float64").
    pub precision: &'static str,
    /// Seeds whose stored (theta, psi) equal, bit for bit, those of a seed from another
    /// place (another position).
    pub seeds: u64,
}

/// Count the seeds whose stored angles `(theta, psi)` (NaN unless reached) equal those
/// of a seed at another position.
#[must_use]
pub fn indistinguishable(positions: &[DVec3], theta: &[f64], psi: &[f64]) -> Indistinguishable {
    let arrived = |i: &usize| theta[*i].is_finite() && psi[*i].is_finite();
    // 24 bytes a seed, allocated once.
    let mut keyed: Vec<(u64, u64, u32)> =
        Vec::with_capacity((0..theta.len()).filter(arrived).count());
    keyed.extend(
        (0..theta.len())
            .filter(arrived)
            // +0 and -0 are one stored direction.
            .map(|i| {
                (
                    (theta[i] + 0.0).to_bits(),
                    (psi[i] + 0.0).to_bits(),
                    i as u32,
                )
            }),
    );
    keyed.par_sort_unstable();
    let mut seeds = 0u64;
    let mut a = 0;
    while a < keyed.len() {
        let mut b = a + 1;
        while b < keyed.len() && keyed[b].0 == keyed[a].0 && keyed[b].1 == keyed[a].1 {
            b += 1;
        }
        let group = &keyed[a..b];
        for &(_, _, i) in group {
            if group
                .iter()
                .any(|&(_, _, j)| positions[j as usize] != positions[i as usize])
            {
                seeds += 1;
            }
        }
        a = b;
    }
    Indistinguishable {
        precision: "float64",
        seeds,
    }
}

/// Flips and distortion of the map `sphere[v]` (unit vectors; `None` where the seed did
/// not reach the center) of a surface whose triangles face outward.
///
/// Two passes over the triangles, holding no per-triangle state but the distortion
/// values whose quantiles it reports (8 bytes a measured triangle, one distribution at
/// a time; [`SURFACE_TRIANGLE_BYTES`]).
#[must_use]
pub fn surface(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    sphere: &[Option<DVec3>],
) -> SurfaceMetrics {
    let mut m = SurfaceMetrics {
        triangles: triangles.len() as u64,
        ..SurfaceMetrics::default()
    };
    // A measured triangle with an orientation and area on the shape: its corners on the
    // shape and on the sphere, and its two areas.
    let kept = |t: &[u32; 3]| -> Option<(f64, f64, [DVec3; 3], [DVec3; 3])> {
        let [a, b, c] = t.map(|i| i as usize);
        let (sa, sb, sc) = (sphere[a]?, sphere[b]?, sphere[c]?);
        if orientation(sa, sb, sc) == 0.0 {
            return None;
        }
        let (pa, pb, pc) = (positions[a], positions[b], positions[c]);
        let am = 0.5 * (pb - pa).cross(pc - pa).length();
        let asph = 0.5 * (sb - sa).cross(sc - sa).length();
        (am > 0.0).then_some((am, asph, [pa, pb, pc], [sa, sb, sc]))
    };
    let (mut area_s, mut area_m) = (0.0, 0.0);
    let mut count = 0usize;
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let (Some(sa), Some(sb), Some(sc)) = (sphere[a], sphere[b], sphere[c]) else {
            continue;
        };
        m.measured += 1;
        let orient = orientation(sa, sb, sc);
        if orient == 0.0 {
            m.degenerate += 1;
            continue;
        }
        if orient < 0.0 {
            m.flipped += 1;
        }
        if let Some((am, asph, _, _)) = kept(t) {
            area_s += asph;
            area_m += am;
            count += 1;
        }
    }
    let mut values = Vec::with_capacity(count);
    values.extend(
        triangles
            .iter()
            .filter_map(kept)
            .map(|(am, asph, _, _)| ((asph / area_s) / (am / area_m)).ln()),
    );
    m.log_area_ratio = Quantiles::of(values);
    let mut values = Vec::with_capacity(count);
    values.extend(
        triangles
            .iter()
            .filter_map(kept)
            .map(|(_, _, p, s)| conformal_ratio(p, s)),
    );
    m.conformal = Quantiles::of(values);
    m
}

/// Bytes [`collisions`] holds a seed (its cell and index).
pub const COLLISION_SEED_BYTES: u64 = 16;

/// Bytes [`surface`] holds a triangle, at most (one distortion value).
pub const SURFACE_TRIANGLE_BYTES: u64 = 8;

/// Positive where the flat triangle of sphere points `a, b, c` faces outward (counter-
/// clockwise seen from outside), negative where it is flipped, zero when degenerate.
#[must_use]
pub fn orientation(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    (b - a).cross(c - a).dot(a + b + c)
}

/// Coordinates of a triangle in its own plane: a at 0, b on the first axis.
fn planar(t: [DVec3; 3]) -> Option<[DVec2; 2]> {
    let e1 = t[1] - t[0];
    let e2 = t[2] - t[0];
    let u = e1.try_normalize()?;
    let n = e1.cross(e2);
    let v = n.cross(u).try_normalize()?;
    Some([DVec2::new(e1.dot(u), 0.0), DVec2::new(e2.dot(u), e2.dot(v))])
}

/// The singular values (largest first) of a map from the plane, given the sum of its
/// squared entries `f2` (the squared Frobenius norm) and the area it gives a unit square
/// `det` (|determinant|; for a 3 x 2 Jacobian, the length of its columns' cross
/// product).
#[must_use]
pub fn singular_values(f2: f64, det: f64) -> (f64, f64) {
    let disc = (f2 * f2 - 4.0 * det * det).max(0.0).sqrt();
    (
        f64::midpoint(f2, disc).sqrt(),
        ((f2 - disc) / 2.0).max(0.0).sqrt(),
    )
}

/// sigma_max / sigma_min of the linear map taking triangle `p` to triangle `s`.
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn conformal_ratio(p: [DVec3; 3], s: [DVec3; 3]) -> f64 {
    let (Some(a), Some(b)) = (planar(p), planar(s)) else {
        return f64::INFINITY;
    };
    // J * [a0 a1] = [b0 b1] (columns), J = B A^-1.
    let am = glam::DMat2::from_cols(a[0], a[1]);
    let bm = glam::DMat2::from_cols(b[0], b[1]);
    let j = bm * am.inverse();
    let (s1, s2) = singular_values(
        j.x_axis.length_squared() + j.y_axis.length_squared(),
        j.determinant().abs(),
    );
    if s2 > 0.0 {
        s1 / s2
    } else {
        f64::INFINITY
    }
}

/// Count the seeds whose sphere point lies within `angle_deg` of the sphere point of a
/// seed more than `far` away on the shape (`positions` in voxels).
#[must_use]
pub fn collisions(
    positions: &[DVec3],
    sphere: &[Option<DVec3>],
    angle_deg: f64,
    far: f64,
) -> Collisions {
    // A grid of cells of the chord length of the angle: neighbours within it are in the
    // 27 cells around a point's cell. The points sorted by cell (16 bytes a point,
    // [`COLLISION_SEED_BYTES`]); the points of a row of three cells along z are one run
    // of them, found by bisection.
    let chord = 2.0 * (angle_deg.to_radians() / 2.0).sin();
    let cell = |p: DVec3| -> [i32; 3] { (p / chord).floor().as_ivec3().to_array() };
    let mut sorted: Vec<([i32; 3], u32)> =
        Vec::with_capacity(sphere.iter().filter(|s| s.is_some()).count());
    sorted.extend(
        sphere
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|s| (cell(s), i as u32))),
    );
    sorted.par_sort_unstable();
    let count = sphere
        .par_iter()
        .enumerate()
        .filter(|&(i, s)| {
            let Some(s) = s else { return false };
            let c = cell(*s);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    let row = [c[0] + dx, c[1] + dy];
                    let first = sorted.partition_point(|&(k, _)| k < [row[0], row[1], c[2] - 1]);
                    let end = sorted.partition_point(|&(k, _)| k <= [row[0], row[1], c[2] + 1]);
                    for &(_, j) in &sorted[first..end] {
                        let j = j as usize;
                        if j != i
                            && (sphere[j].expect("sorted") - *s).length() <= chord
                            && (positions[j] - positions[i]).length() > far
                        {
                            return true;
                        }
                    }
                }
            }
            false
        })
        .count() as u64;
    Collisions {
        angle_deg,
        far_voxels: far,
        seeds: count,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::starfish::uv_sphere;

    /// The hash grid counts exactly the seeds a brute-force search over all pairs finds:
    /// random arrivals (a few missing), some planted within the angle of another seed
    /// from far away (counted), some from nearby (not counted), some just beyond the
    /// angle (not counted).
    #[test]
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn collisions_are_the_pairs_a_brute_force_search_finds() {
        let mut rng = crate::math::TestRng(0x2545_f491_4f6c_dd1d);
        let mut next = move || rng.next_f64();
        let (angle, far) = (0.05f64, 5.0);
        let mut sphere: Vec<Option<DVec3>> = Vec::new();
        let mut positions: Vec<DVec3> = Vec::new();
        for i in 0..3000 {
            let z = 2.0 * next() - 1.0;
            let a = std::f64::consts::TAU * next();
            let r = (1.0 - z * z).sqrt();
            let s = DVec3::new(r * a.cos(), r * a.sin(), z);
            let p = DVec3::new(next(), next(), next()) * 100.0;
            sphere.push((i % 97 != 0).then_some(s));
            positions.push(p);
            if i % 10 == 0 {
                // A twin: within (or, every third, just beyond) the angle, from far away
                // or (every other) from next door.
                let scale = if i % 30 == 0 { 1.2 } else { 0.6 };
                let off = s.any_orthonormal_vector() * (angle.to_radians() * scale);
                let q = if i % 20 == 0 {
                    p + DVec3::X
                } else {
                    p + DVec3::splat(50.0)
                };
                sphere.push(Some((s + off).normalize()));
                positions.push(q);
            }
        }
        let chord = 2.0 * (angle.to_radians() / 2.0).sin();
        let brute = (0..sphere.len())
            .filter(|&i| {
                let Some(s) = sphere[i] else { return false };
                (0..sphere.len()).any(|j| {
                    j != i
                        && sphere[j].is_some_and(|t| (t - s).length() <= chord)
                        && (positions[j] - positions[i]).length() > far
                })
            })
            .count() as u64;
        let c = collisions(&positions, &sphere, angle, far);
        assert_eq!(c.seeds, brute);
        // The planted far twins within the angle, both sides, and no others by chance.
        assert!(brute >= 2 * 50, "{brute}");
    }

    #[test]
    fn the_radial_map_of_a_sphere_has_no_flips_and_no_distortion_beyond_the_mesh() {
        let m = uv_sphere(16, 32, |t, p| 10.0 * crate::trace::unit(t, p));
        let sphere: Vec<Option<DVec3>> = m.vertices.iter().map(|v| Some(v.normalize())).collect();
        let s = surface(&m.vertices, &m.triangles, &sphere);
        assert_eq!(s.flipped, 0);
        assert_eq!(s.measured, s.triangles);
        assert!(s.log_area_ratio.max.abs() < 1e-9);
        assert!((s.conformal.max - 1.0).abs() < 1e-6, "{:?}", s.conformal);
        assert_eq!(collisions(&m.vertices, &sphere, 0.01, 1.0).seeds, 0);
    }

    #[test]
    fn a_mirrored_map_flips_every_triangle_and_stretching_shows() {
        let m = uv_sphere(8, 16, crate::trace::unit);
        // Mirror x: every triangle's orientation reverses.
        let mirrored: Vec<Option<DVec3>> = m
            .vertices
            .iter()
            .map(|v| Some(DVec3::new(-v.x, v.y, v.z)))
            .collect();
        let s = surface(&m.vertices, &m.triangles, &mirrored);
        assert_eq!(s.flipped, s.measured - s.degenerate);
        // An ellipsoid (z stretched 3x) mapped radially: areas and angles change.
        let ell: Vec<DVec3> = m
            .vertices
            .iter()
            .map(|v| DVec3::new(v.x, v.y, 3.0 * v.z))
            .collect();
        let sphere: Vec<Option<DVec3>> = ell.iter().map(|v| Some(v.normalize())).collect();
        let s = surface(&ell, &m.triangles, &sphere);
        assert_eq!(s.flipped, 0);
        assert!(s.conformal.max > 1.5, "{:?}", s.conformal);
        assert!(s.log_area_ratio.p95 - s.log_area_ratio.p05 > 0.5);
    }

    #[test]
    fn seeds_with_equal_stored_angles_from_other_places_are_indistinguishable() {
        let pos = vec![
            DVec3::ZERO,
            DVec3::X,
            DVec3::ZERO,
            DVec3::Y,
            DVec3::Z,
            DVec3::ONE,
        ];
        let theta = [1.0, 1.0, 1.0, 2.0, 2.0f64.next_up(), f64::NAN];
        let psi = [0.5, 0.5, 0.5, -0.0, -0.0, f64::NAN];
        // 0, 1, 2 share angles (0 and 2 from one place, 1 from another: all three
        // count); 3 and 4 differ by one ulp of theta; 5 did not arrive.
        assert_eq!(indistinguishable(&pos, &theta, &psi).seeds, 3);
        let theta = [1.0, 1.0, 1.0, 2.0, 2.0, f64::NAN];
        let psi = [0.5, 0.5, 0.5, -0.0, 0.0, f64::NAN];
        assert_eq!(indistinguishable(&pos, &theta, &psi).seeds, 5);
    }

    #[test]
    fn seeds_from_far_apart_landing_together_are_counted() {
        let pos = vec![
            DVec3::ZERO,
            DVec3::new(100.0, 0.0, 0.0),
            DVec3::new(0.5, 0.0, 0.0),
            DVec3::new(0.0, 50.0, 0.0),
        ];
        let x = DVec3::X;
        let sphere = vec![
            Some(x),
            Some((x + DVec3::new(0.0, 1e-5, 0.0)).normalize()), // far on the shape
            Some((x + DVec3::new(0.0, 0.0, 1e-5)).normalize()), // near on the shape
            Some(DVec3::Y),
        ];
        let c = collisions(&pos, &sphere, 0.01, 5.0);
        // 0 and 1 collide (far apart); 1 and 2 too; 2 is near 0 only on the shape.
        assert_eq!(c.seeds, 3);
    }
}
