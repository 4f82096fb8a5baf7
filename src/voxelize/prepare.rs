//! The grid a shape needs, how inside is decided, and what the input says about itself:
//! the checks of a mesh (closed, oriented, its genus), the molecule's notes.

use super::mesh_genus::{surface_topology, SurfaceTopology};
use super::{fit_bbox, fit_volume, spheres, InsideRule, VoxelizeError, VoxelizeOptions};
use crate::grid::GridSpec;
use crate::input::Shape;
use crate::math::Vec3;

/// What [`prepare`] found.
pub(super) struct Prepared {
    /// The grid.
    pub spec: GridSpec,
    /// Meshes: how inside is decided.
    pub rule: Option<InsideRule>,
    /// Bytes of the shape that stay resident through the passes.
    pub shape_bytes: u64,
    /// Meshes: parts and genus of the surface.
    pub surface: Option<SurfaceTopology>,
}

/// The grid for `shape` under `opts`, with the warnings about the input.
pub(super) fn prepare(
    shape: &Shape,
    source_name: &str,
    opts: &VoxelizeOptions,
    warnings: &mut Vec<String>,
) -> Result<Prepared, crate::Error> {
    let (mut spec, rule, shape_bytes) = match shape {
        Shape::Mesh(mesh) => {
            let topo = mesh.topology();
            if !topo.is_closed() {
                let odd = if topo.odd_edges > 0 {
                    format!(
                        " and {} more are used by an odd number of triangles",
                        topo.odd_edges
                    )
                } else {
                    String::new()
                };
                return Err(VoxelizeError::OpenSurface {
                    path: source_name.to_owned(),
                    boundary_edges: topo.boundary_edges,
                    example: topo.example_open_edge.unwrap_or([0, 0]),
                    odd,
                }
                .into());
            }
            let rule = if topo.is_oriented_closed() {
                InsideRule::Winding
            } else {
                warnings.push(format!(
                    "{source_name}: the triangles are not consistently oriented ({} edges are used twice in the same direction); inside is decided by crossing parity",
                    topo.unbalanced_edges
                ));
                InsideRule::Parity
            };
            if topo.nonmanifold_edges > 0 {
                warnings.push(format!(
                    "{source_name}: {} edges are shared by more than two triangles (non-manifold); overlapping parts are taken as their union",
                    topo.nonmanifold_edges
                ));
            }
            if topo.degenerate > 0 {
                warnings.push(format!(
                    "{source_name}: {} degenerate triangles (repeated vertex) skipped",
                    topo.degenerate
                ));
            }
            let (lo, hi) = mesh
                .bbox()
                .ok_or_else(|| VoxelizeError::Options(format!("{source_name}: no triangles")))?;
            let bytes = mesh.vertices.len() as u64 * 24 + mesh.triangles.len() as u64 * 160;
            (fit_bbox(lo, hi, opts)?, Some(rule), bytes)
        }
        Shape::Volume(v) => (fit_volume(v.shape(), opts)?, None, 0),
        Shape::Molecule(m) => {
            if !(opts.probe.is_finite() && opts.probe > 0.0) {
                return Err(VoxelizeError::Options(format!(
                    "--probe {}: give a positive radius",
                    opts.probe
                ))
                .into());
            }
            let grow = if opts.surface == spheres::MolSurface::Vdw {
                0.0
            } else {
                opts.probe
            };
            let mut lo = Vec3::splat(f64::INFINITY);
            let mut hi = Vec3::splat(f64::NEG_INFINITY);
            for a in &m.atoms {
                lo = lo.min(a.pos - Vec3::splat(a.radius + grow));
                hi = hi.max(a.pos + Vec3::splat(a.radius + grow));
            }
            (fit_bbox(lo, hi, opts)?, None, m.atoms.len() as u64 * 200)
        }
    };
    if let Shape::Molecule(m) = shape {
        if spec.unit.is_none() && m.format != "points" {
            spec.unit = Some("angstrom".into());
        }
        warnings.extend(m.warnings.iter().cloned());
        if !m.left_out.is_empty() {
            warnings.push(format!(
                "left out (hetero groups; --keep-hetatm keeps all but water): {}",
                crate::input::molecule::summary(&m.left_out)
            ));
        }
        if !m.hetero_kept.is_empty() {
            warnings.push(format!(
                "hetero groups kept: {}",
                crate::input::molecule::summary(&m.hetero_kept)
            ));
        }
    }
    let surface = match shape {
        Shape::Mesh(mesh) => Some(surface_topology(mesh)),
        _ => None,
    };
    Ok(Prepared {
        spec,
        rule,
        shape_bytes,
        surface,
    })
}
