//! `map`: (theta, psi) for every voxel of the solid (the paper's steps 8-9).
//!
//! - [`upwind`] (default): the arrival direction transported up u = 1 - phi from the
//!   stop ball, block by block; one visit per block and a few rounds. Then, where the
//!   upwind direction turns slowly across the flow (`squeeze`: an angular error would
//!   move the point by more than a third of a voxel), a streamline from the voxel with
//!   the exact map's tracer replaces it (the hybrid map).
//! - `exact`: a streamline from every voxel with the tracer of `trace` (the reference).
//!
//! Both write `RUN/theta/0` and `RUN/psi/0` (radians, NaN outside the solid and where no
//! direction was found) and record `harmap.stages.map`. Both write f64: the traced
//! streamlines step on levels of ln u from the voxel on, so [`inverse`] can undo them
//! step by step, and down a thin arm neighbouring voxels differ in direction by less
//! than f32 resolves (1e-10 radians and below).
//!
//! Files: `stage` (the stage: checks, budget, record), [`upwind`] (the transport),
//! `exact` (a streamline per voxel, or per squeezed voxel), `squeeze` (where the
//! upwind map is traced instead), `angles` (theta and psi written block by block),
//! `folds` (voxels where the map folds),
//! [`inverse`] (from (phi, theta, psi) back to a point), `error`.
//!
//! Across processes ([`map_with`] and a [`crate::grid::Decomposition`]) each part maps
//! the blocks it owns; in the upwind map a voxel's direction crosses to another part
//! when a block there reads it within its halo, after the exchange that ends every
//! round of the transport.

mod angles;
mod error;
mod exact;
mod folds;
pub mod inverse;
mod squeeze;
mod stage;
mod unfold;
pub mod upwind;

use serde::{Deserialize, Serialize};

use crate::grid::MemBudget;
use crate::trace::Rk45;
use upwind::TransportStats;

pub use error::MapError;
pub use exact::exact_integrator;
pub use folds::{FoldCluster, Folded};
pub use stage::{map, map_with};
pub use unfold::Unfold;

/// How the full-volume map is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MapMethod {
    /// Upwind transport of the arrival direction (fast).
    #[default]
    Upwind,
    /// A streamline from every voxel (the reference).
    Exact,
}

/// Options of `harmap map`.
#[derive(Clone, Debug, Serialize, Deserialize, Default)]
pub struct MapOptions {
    /// Upwind transport or exact tracing.
    pub method: MapMethod,
    /// Radius of the stop ball (voxels; default as in `trace`). Inside it the direction
    /// is the one from the center.
    pub stop_radius: Option<f64>,
    /// Memory budget.
    #[serde(skip)]
    pub mem: MemBudget,
}

/// Where the default map traced streamlines: the voxels where the upwind direction
/// turns by less than `squeeze_below` radians per voxel across the flow.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Hybrid {
    /// The threshold (radians per voxel).
    pub squeeze_below: f64,
    /// Voxels traced exactly (outside the stop ball).
    pub traced: u64,
    /// Their share of the solid's voxels.
    pub traced_fraction: f64,
}

/// What a map did.
#[derive(Clone, Debug, Serialize)]
pub struct MapReport {
    /// The method.
    pub method: MapMethod,
    /// Voxels of the solid (boundary, interior, center).
    pub voxels: u64,
    /// Voxels that have (theta, psi).
    pub mapped: u64,
    /// The stop ball's radius (voxels).
    pub stop_radius: f64,
    /// Upwind counters (upwind method).
    pub upwind: Option<TransportStats>,
    /// The voxels the default map traced exactly (upwind method).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hybrid: Option<Hybrid>,
    /// Streamlines per stop reason (the exact map's, and the default map's where it
    /// traced; voxels inside the stop ball count as reached without a streamline).
    pub stops: Option<std::collections::BTreeMap<&'static str, u64>>,
    /// Seconds spent computing directions (upwind: with the theta and psi of the blocks
    /// written as they are done, that is nearly all of them).
    pub seconds_directions: f64,
    /// Where the direction field's boundary values came from
    /// ([`crate::trace::surface::Boundary::name`]).
    pub boundary: &'static str,
    /// The integrator of the exact map's streamlines, which `harmap inverse` undoes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub integrator: Option<Rk45>,
    /// The voxels where the map x -> ball point folds (a negative Jacobian determinant),
    /// outside the stop ball; counted in one process only (None across processes).
    pub folded: Option<Folded>,
    /// Where the map folded: the directions moved around the folds before `folded`
    /// was counted (None where nothing folded).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unfold: Option<Unfold>,
}
