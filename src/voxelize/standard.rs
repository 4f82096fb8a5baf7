//! The standard problem of the solve, trace and map stages: an `N^3` grid holding the
//! ball of radius `0.45 N` around the grid center, with phi = 0 on the voxels within
//! `sink_radius` voxels of the grid center. With `sink_radius = 0.1 N` it is the
//! concentric-sphere problem, whose continuum solution is
//! `phi(r) = (1/r0 - 1/r) / (1/r0 - 1/R)`.
//!
//! Voxel `(k, j, i)` sits at world `(i, j, k)` (spacing 1, origin 0); the grid center is
//! `((N-1)/2, (N-1)/2, (N-1)/2)`, between voxels for even N. The labels are made by the
//! same passes as any voxelization (boundary, exterior layers by L1 distance, which
//! the grid edge cuts when `0.05 N < 4`).

use serde::{Deserialize, Serialize};

use super::{classify, components, euler, CenterBall, VoxelizeError, VoxelizeReport};
use crate::grid::{Compression, GridSpec, MemBudget};
use crate::progress::Progress;
use crate::run::RunDir;

/// Parameters of the standard problem.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StandardBall {
    /// Voxels per axis.
    pub n: u64,
    /// Radius (voxels) of the sink ball around the grid center: 2 for the standard
    /// problem, `0.1 N` for the concentric-sphere variant.
    pub sink_radius: f64,
    /// Block edge in voxels.
    pub chunk: u64,
    /// Memory budget.
    pub mem: MemBudget,
}

impl StandardBall {
    /// The ball's radius in voxels, `0.45 N`.
    #[must_use]
    pub fn radius(&self) -> f64 {
        0.45 * self.n as f64
    }

    /// The grid center in voxel coordinates.
    #[must_use]
    pub fn center(&self) -> f64 {
        (self.n as f64 - 1.0) / 2.0
    }
}

/// Write the labels of the standard problem into the new run `run`.
pub fn standard_ball(
    p: &StandardBall,
    run: &RunDir,
    progress: &dyn Progress,
) -> Result<VoxelizeReport, crate::Error> {
    let n = p.n;
    let (radius, c) = (p.radius(), p.center());
    if n < 8 || !(p.sink_radius >= 0.0 && p.sink_radius + 2.0 < radius) {
        return Err(VoxelizeError::Options(format!(
            "the standard ball needs N >= 8 and a sink radius below 0.45 N - 2 voxels (N = {n}, sink radius {})",
            p.sink_radius
        ))
        .into());
    }
    let spec = GridSpec {
        shape: [n; 3],
        origin: [0.0; 3],
        spacing: 1.0,
        chunk: [p.chunk; 3],
        unit: None,
    };
    super::grid_fit::check_shape(spec.shape, &format!("the standard ball of N = {n}"))?;
    let threads = rayon::current_num_threads();
    let cc = p.chunk;
    let in_memory = super::Scratch::Auto.in_memory(spec.num_voxels(), p.mem, 0);
    let held = if in_memory { spec.num_voxels() } else { 0 };
    let workers = p.mem.workers(
        "labelling one block",
        held,
        super::label_worker_bytes(cc).max(6 * cc * cc * cc),
        threads,
    )?;
    let scratch = run.root().join(".scratch");
    let solid = super::scratch_grid(&scratch, &spec, in_memory, "solid.u8")?;
    let solid = &*solid;
    crate::grid::fill_with(solid, workers, |v| {
        let d2 = v.iter().map(|&q| (q as f64 - c).powi(2)).sum::<f64>();
        u8::from(d2 <= radius * radius)
    })?;
    let limit = p.mem.work_bytes().saturating_sub(held);
    let pieces = components::find(
        solid,
        |v| v == 1,
        workers,
        limit,
        "standard ball: components",
        progress,
    )?;
    let chi = euler::euler_characteristic(solid, workers)?;
    let labels = run.create_image::<u8>("labels", &spec, 0, Compression::Zstd(3))?;
    let ball = CenterBall {
        center: [c; 3],
        radius: p.sink_radius,
    };
    let counts = classify::classify(solid, &labels, ball, workers, progress)?;
    let center_voxel = [c.round() as u64; 3];
    let depth = super::center::deepest_voxel(
        solid,
        &scratch.join("zdist.u16"),
        Some(center_voxel),
        progress,
    )?
    .query_depth
    .unwrap_or(0.0);
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(VoxelizeReport {
        center: [c; 3],
        center_voxel,
        center_depth: depth,
        grid: spec,
        counts,
        inside_rule: "standard-ball".into(),
        euler_characteristic: chi,
        components: pieces.sizes.len() as u64,
        genus: pieces.sizes.len() as i64 - chi,
        cavities_filled: 0,
        cavity_voxels: 0,
        probe_cavities: 0,
        pieces_removed: 0,
        removed_voxels: 0,
        closing_voxels: 0,
        handles: Vec::new(),
        handle_radius: 0,
        probe_trials: Vec::new(),
        surface_topology: None,
        repair: None,
        warnings: Vec::new(),
        timings: Vec::new(),
    })
}
