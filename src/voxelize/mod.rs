//! Voxelization: a shape -> the labelled grid of the run, with the shape center.
//!
//! Passes, each block by block within the memory budget (nothing holds a whole grid):
//! 1. solid occupancy into an uncompressed scratch grid ([`scanline`] for surfaces,
//!    [`from_volume`] for label volumes);
//! 2. enclosed background (cavities) filled ([`components`] on the background);
//! 3. pieces of the solid counted ([`components`] on the solid), and the Euler
//!    characteristic ([`euler`]) gives the genus; a solid that is not one genus-0 piece
//!    is repaired ([`repair`], growth through simple points, see [`simple`]) or
//!    refused ([`topology`] decides which, from `--topology` and the input's own genus);
//! 4. the center: the deepest voxel ([`center`]) or `--center` ([`center_ball`]);
//! 5. the labels written to `RUN/labels/0` ([`classify`]).
//!
//! [`stage`] runs them in order; [`prepare`] fits the grid to the shape first.

mod balls;
mod center;
mod center_ball;
mod classify;
pub mod closing;
mod components;
mod error;
mod euler;
mod from_volume;
mod grid_fit;
pub mod mesh_genus;
mod options;
mod prepare;
mod probes;
mod repair;
mod scanline;
pub mod simple;
pub mod solvent;
pub mod spheres;
mod stage;
mod standard;
mod topology;

use serde::{Deserialize, Serialize};

pub(crate) use classify::worker_bytes as label_worker_bytes;
pub use classify::CenterBall;
pub use error::VoxelizeError;
pub use grid_fit::{fit_bbox, fit_volume, DEFAULT_RESOLUTION, MAX_AXIS, MAX_VOXELS, MIN_PADDING};
pub(crate) use options::scratch_grid;
pub use probes::probe_summary;
pub use scanline::InsideRule;
pub use stage::voxelize;
pub use standard::{standard_ball, StandardBall};
pub use topology::summary as repair_summary;

use crate::grid::{GridSpec, MemBudget};
use crate::math::Idx3;

/// Label values of `RUN/labels/0`.
pub mod labels {
    /// Outside the solid and its four exterior layers.
    pub const EXTERIOR: u8 = 0;
    /// Solid voxel with a non-solid 6-neighbour (phi = 1).
    pub const BOUNDARY: u8 = 1;
    /// Solid voxel whose 6 neighbours are solid (phi unknown).
    pub const INTERIOR: u8 = 2;
    /// Interior voxel of the center ball (phi = 0).
    pub const CENTER: u8 = 3;
    /// First exterior layer (phi = 1 + eps); layers 2..4 are 5..7 (phi = 1 + k eps).
    pub const LAYER1: u8 = 4;
    /// Names of the label values, for reports.
    pub const NAMES: [&str; 8] = [
        "exterior", "boundary", "interior", "center", "layer1", "layer2", "layer3", "layer4",
    ];
}

/// Options of `harmap voxelize`. Stored verbatim in the run's metadata.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VoxelizeOptions {
    /// Voxels along the longest side of the shape's bounding box.
    pub resolution: Option<u64>,
    /// Voxel size in world units (instead of `resolution`).
    pub spacing: Option<f64>,
    /// Voxels added on every side (at least 5).
    pub padding: u64,
    /// Shape center in world coordinates (x, y, z); default: the deepest voxel.
    pub center: Option<[f64; 3]>,
    /// Radius (voxels) of the center ball where phi = 0.
    pub center_radius: f64,
    /// Go on when the solid is not one genus-0 piece.
    pub allow_genus: bool,
    /// Keep only the largest piece when the solid has several.
    pub keep_largest: bool,
    /// Block (chunk) edge in voxels.
    pub chunk: u64,
    /// Memory budget.
    pub mem: MemBudget,
    /// Unit of world coordinates (an OME-Zarr unit name), if known.
    pub unit: Option<String>,
    /// Where the intermediate solid grid lives.
    pub scratch: Scratch,
    /// Molecules: which solid (vdW, SAS or SES).
    #[serde(default)]
    pub surface: spheres::MolSurface,
    /// Molecules: the probe radius of SAS and SES (Angstrom).
    #[serde(default = "options::default_probe")]
    pub probe: f64,
    /// Close the solid by a ball of this many voxels before the topology check (0: no).
    #[serde(default)]
    pub close: u32,
    /// Molecules (SAS and SES): larger probe radii to try in turn, Angstrom, while the
    /// solid at `probe` is not one genus-0 piece (see
    /// [`crate::pipeline::voxelize_new_run`]).
    #[serde(default)]
    pub probe_ladder: Vec<f64>,
    /// Skip the search for where handles are (the probe ladder's trials that a larger
    /// probe follows).
    #[serde(skip)]
    pub skip_handle_search: bool,
    /// What to do when the voxel solid is not one genus-0 piece (`--topology`).
    #[serde(default)]
    pub topology: TopologyMode,
}

/// `--topology`: what to do when the voxel solid is not one genus-0 piece (and neither
/// `--allow-genus` nor `--keep-largest` says otherwise).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TopologyMode {
    /// Repair, except a mesh whose own surface has handles (then refuse, as `strict`):
    /// the default.
    #[default]
    Auto,
    /// Repair whatever the input (asked for explicitly).
    Repair,
    /// Refuse, saying where the handles are.
    Strict,
}

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
    /// Voxels the other method would have changed.
    pub alternative_voxels: u64,
    /// Changed voxels over the solid's voxels before the repair.
    pub fraction: f64,
    /// The largest connected regions of changed voxels, largest first (at most 8).
    pub regions: Vec<RepairRegion>,
    /// Seconds the repair took.
    pub seconds: f64,
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

/// Where intermediate grids live.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scratch {
    /// In memory when the grid (one byte a voxel) fits in half the budget, else on disk.
    #[default]
    Auto,
    /// Always in memory.
    Memory,
    /// Always in a memory-mapped file, read and written block by block.
    Disk,
}

/// What voxelization found. Stored in the run's metadata.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VoxelizeReport {
    /// The grid.
    pub grid: GridSpec,
    /// Voxels per label value 0..=7 (see [`labels`]).
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
    /// [`HANDLE_PROBE`] voxels, [`HANDLE_PROBE_ANGSTROM`] for molecules, or twice
    /// `--close`) would plug tunnels.
    #[serde(default)]
    pub handles: Vec<closing::Handle>,
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

/// Radius (voxels) of the closing that locates handles when `--close` is not given.
pub const HANDLE_PROBE: u32 = 3;

/// For molecules, the same radius in Angstrom (so that it means the same at any
/// spacing: at 0.25 Angstrom, 3 voxels are 0.75 Angstrom, narrower than any tunnel a
/// 1.4 Angstrom probe leaves). Never below [`HANDLE_PROBE`] voxels.
pub const HANDLE_PROBE_ANGSTROM: f64 = 3.0;

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
