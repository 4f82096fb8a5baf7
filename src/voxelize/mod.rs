//! Voxelization: a shape -> the labelled grid of the run, with the shape center.
//!
//! Passes, each block by block within the memory budget (nothing holds a whole grid):
//! 1. solid occupancy into an uncompressed scratch grid ([`scanline`] for surfaces,
//!    [`from_volume`] for label volumes);
//! 2. enclosed background (cavities) filled ([`components`] on the background);
//! 3. pieces of the solid counted ([`components`] on the solid), and the Euler
//!    characteristic ([`euler`]) gives the genus; a solid that is not one genus-0 piece
//!    is repaired ([`repair`], growth through simple points, see [`simple`]; on large
//!    grids [`compact`]) or
//!    refused ([`topology`] decides which, from `--topology` and the input's own genus);
//! 4. the center: the deepest voxel ([`center`]) or `--center` ([`center_ball`]);
//! 5. the labels written to `RUN/labels/0` ([`classify`]);
//! 6. for meshes and molecules, where the true surface crosses the solve's stencil
//!    ([`cuts`], [`mol_cuts`]).
//!
//! [`stage`] runs them in order; [`prepare`] fits the grid to the shape first.

mod balls;
mod bricks;
mod center;
mod center_ball;
mod classify;
pub mod closing;
mod compact;
mod components;
pub mod cuts;
mod error;
mod euler;
mod from_volume;
mod grid_fit;
pub mod mesh_genus;
mod mol_cuts;
mod options;
mod prepare;
mod probe_band;
mod probes;
mod ranks;
mod repair;
mod report;
mod rounds;
mod scanline;
pub mod simple;
pub mod solvent;
pub mod spheres;
mod stage;
mod standard;
mod topology;
mod windows;

use serde::{Deserialize, Serialize};

pub(crate) use classify::worker_bytes as label_worker_bytes;
pub use classify::CenterBall;
pub use error::VoxelizeError;
pub use grid_fit::{fit_bbox, fit_volume, DEFAULT_RESOLUTION, MAX_AXIS, MAX_VOXELS, MIN_PADDING};
pub(crate) use options::scratch_grid;
pub use probes::probe_summary;
pub use ranks::{done as ranks_done, serve as serve_ranks};
pub use report::{ProbeTrial, RepairRegion, TopologyRepair, VoxelizeReport};
#[doc(hidden)]
pub use rounds::compact_repair_above;
pub use scanline::InsideRule;
pub use stage::{voxelize, voxelize_on};
pub use standard::{standard_ball, StandardBall};
pub use topology::summary as repair_summary;

use crate::grid::MemBudget;

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

/// Where intermediate grids live.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scratch {
    /// In memory when the grid (one byte a voxel) fits in half the budget, else on disk.
    #[default]
    Auto,
    /// Always in memory.
    Memory,
    /// Always in a scratch file, read and written block by block.
    Disk,
}

/// Radius (voxels) of the closing that locates handles when `--close` is not given.
pub const HANDLE_PROBE: u32 = 3;

/// For molecules, the same radius in Angstrom (so that it means the same at any
/// spacing: at 0.25 Angstrom, 3 voxels are 0.75 Angstrom, narrower than any tunnel a
/// 1.4 Angstrom probe leaves). Never below [`HANDLE_PROBE`] voxels.
pub const HANDLE_PROBE_ANGSTROM: f64 = 3.0;
