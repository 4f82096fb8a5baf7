//! What voxelization reports: the grid, the label counts, the center, the topology and
//! what its repair changed. Stored in the run's metadata (`stages.voxelize.result`).

use serde::{Deserialize, Serialize};

use crate::grid::GridSpec;
use crate::math::Idx3;

/// What the topology repair changed (see docs/topology.md).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TopologyRepair {
    /// Pieces of the solid before the repair.
    pub components_before: u64,
    /// Genus of the solid before the repair.
    pub genus_before: i64,
    /// "cut" (handles cut, specks dropped) or "fill" (tunnels plugged).
    pub method: String,
    /// Voxels taken out of the solid (specks included).
    pub voxels_removed: u64,
    /// Voxels added to the solid.
    pub voxels_added: u64,
    /// Handles cut.
    pub handles_cut: i64,
    /// Tunnels filled.
    pub handles_filled: i64,
    /// Pieces other than the main one, dropped.
    pub specks_dropped: u64,
    /// Their voxels.
    pub speck_voxels: u64,
    /// Voxels the other method would have changed; `u64::MAX` when it was not tried
    /// (the compact cut of large grids).
    pub alternative_voxels: u64,
    /// Changed voxels over the solid's voxels before the repair.
    pub fraction: f64,
    /// The largest connected regions of changed voxels, largest first (at most 8).
    pub regions: Vec<RepairRegion>,
    /// Seconds the repair took.
    pub seconds: f64,
    /// Bricks of 16^3 voxels the compact cut read back from its scratch file (its
    /// cache's misses), when the cut's records did not all fit in memory; absent
    /// otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scratch_brick_reads: Option<u64>,
}

/// One connected region of voxels the repair changed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RepairRegion {
    /// "added" or "removed".
    pub kind: String,
    /// Voxels in it.
    pub voxels: u64,
    /// Its first voxel in C order, `[z, y, x]`.
    pub voxel: Idx3,
    /// That voxel's center in world coordinates `(x, y, z)`.
    pub position: [f64; 3],
}

/// What voxelization found. Stored in the run's metadata.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VoxelizeReport {
    /// The grid.
    pub grid: GridSpec,
    /// Voxels per label value 0..=7 (see [`labels`](super::labels)).
    pub counts: [u64; 8],
    /// The center voxel `[z, y, x]`.
    pub center_voxel: Idx3,
    /// The center in world coordinates `(x, y, z)`.
    pub center: [f64; 3],
    /// Distance (voxels) from the center voxel to the nearest non-solid voxel.
    pub center_depth: f64,
    /// How inside was decided: "winding", "parity" or "volume".
    pub inside_rule: String,
    /// Euler characteristic of the final solid (6-connectivity).
    pub euler_characteristic: i64,
    /// 6-connected pieces of the final solid.
    pub components: u64,
    /// Genus (number of tunnels) of the final solid.
    pub genus: i64,
    /// Enclosed cavities filled, and their voxels.
    pub cavities_filled: u64,
    /// Voxels added by filling cavities.
    pub cavity_voxels: u64,
    /// SES: cavities of the probe-center space (room for a probe that cannot get in
    /// from the solvent), whose probes were left out, so they are solid already.
    #[serde(default)]
    pub probe_cavities: u64,
    /// Pieces removed by `keep_largest`, and their voxels.
    pub pieces_removed: u64,
    /// Voxels removed by `keep_largest`.
    pub removed_voxels: u64,
    /// Voxels added by `--close`.
    #[serde(default)]
    pub closing_voxels: u64,
    /// Where handles are, when the genus is above 0: places where a closing (by
    /// [`HANDLE_PROBE`](super::HANDLE_PROBE) voxels, [`HANDLE_PROBE_ANGSTROM`](super::HANDLE_PROBE_ANGSTROM) for molecules, or twice
    /// `--close`) would plug tunnels.
    #[serde(default)]
    pub handles: Vec<super::closing::Handle>,
    /// The radius (voxels) of the closing that located `handles`.
    #[serde(default)]
    pub handle_radius: u32,
    /// Molecules: the probes tried (`--probe` with several radii), in order, and what
    /// each gave; the last one made this solid.
    #[serde(default)]
    pub probe_trials: Vec<ProbeTrial>,
    /// Meshes: connected parts of the surface and their total genus, from its Euler
    /// characteristic (what decides whether handles of the solid are artifacts).
    #[serde(default)]
    pub surface_topology: Option<(u64, i64)>,
    /// What the topology repair changed, when the solid needed it.
    #[serde(default)]
    pub repair: Option<TopologyRepair>,
    /// Warnings given.
    pub warnings: Vec<String>,
    /// Seconds per pass.
    pub timings: Vec<(String, f64)>,
}

/// One probe radius tried for a molecule, and the topology it gave.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeTrial {
    /// Probe radius, Angstrom.
    pub probe: f64,
    /// Genus of the solid.
    pub genus: i64,
    /// Pieces of the solid left (after `--keep-largest`).
    pub components: u64,
}
