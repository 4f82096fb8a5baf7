//! Streamlines from the boundary down -grad(phi) to the center, and the angles at which
//! they arrive (the paper's steps 6-8).
//!
//! - [`field`]: unit node directions of -grad(phi), approximated between the nodes by a
//!   quadratic B-spline (a C1 field);
//! - [`surface`]: sub-voxel values of u at the boundary nodes, for the field, from the
//!   input mesh or the smoothed voxel solid;
//! - `boundary`: whether those values come from the mesh or the smoothed solid;
//! - [`nearest`]: the nearest point of a triangle surface (a bounding volume hierarchy);
//! - [`integrate`]: Dormand–Prince RK45 by arc length, with error control, stop reasons;
//! - [`tiles`]: streamlines queued per tile, tiles built into a cache within the budget;
//! - [`seeds`]: boundary voxels or surface vertices, and deterministic sampling;
//! - `table`: the seed table `RUN/seeds/`, written and read;
//! - [`stage`]: the stage (options, budget, the tracer, the report);
//! - [`extract`]: surface nets of the labels, for seeds without an input mesh;
//! - [`metrics`]: flipped triangles, collisions and distortion of the sphere map;
//! - [`untangle`]: the surface's sphere map made one-to-one where its flat triangles
//!   turn over (Tutte's embedding of each tangled patch).
//!
//! `trace` writes the seed table `RUN/seeds/` and records `harmap.stages.trace`.

mod boundary;
pub mod extract;
pub mod field;
pub mod integrate;
pub mod metrics;
pub mod nearest;
pub mod ranks;
pub mod seeds;
pub mod stage;
pub mod surface;
mod table;
pub mod tiles;
pub mod untangle;

pub use integrate::{Rk45, Stop};
pub use seeds::SeedKind;
pub use stage::{
    read_seeds, trace, SeedTable, TraceError, TraceOptions, TraceReport, DEFAULT_SEEDS,
};

/// The polar and azimuthal angles of direction `d` (physical x, y, z): theta =
/// atan2(sqrt(x^2 + y^2), z) in [0, pi], psi = atan2(y, x) in (-pi, pi].
#[must_use]
pub fn angles(d: glam::DVec3) -> (f64, f64) {
    (d.x.hypot(d.y).atan2(d.z), d.y.atan2(d.x))
}

/// [`angles`] in f32, for directions held in f32 (the upwind map's): f32's atan2 takes
/// half the time of f64's. The components are those of a unit vector, so x^2 + y^2
/// needs no hypot.
#[must_use]
pub fn angles_f32([x, y, z]: [f32; 3]) -> (f32, f32) {
    ((x * x + y * y).sqrt().atan2(z), y.atan2(x))
}

/// The unit vector of angles `(theta, psi)`.
#[must_use]
pub fn unit(theta: f64, psi: f64) -> glam::DVec3 {
    glam::DVec3::new(
        theta.sin() * psi.cos(),
        theta.sin() * psi.sin(),
        theta.cos(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_and_unit_vectors_round_trip() {
        for (t, p) in [(0.3, -2.5), (1.2, 0.0), (2.9, 3.0), (1.5, -0.1)] {
            let (t2, p2) = angles(unit(t, p) * 7.5);
            assert!((t - t2).abs() < 1e-12 && (p - p2).abs() < 1e-12);
        }
        assert_eq!(angles(glam::DVec3::Z), (0.0, 0.0));
    }
}
