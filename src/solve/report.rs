//! What a solve did, as recorded in the run's attributes.

use serde::{Deserialize, Serialize};

use super::deepen::DeepenReport;
use super::driver::{Method, StopReason};
use super::polish::PolishReport;

/// What the solve did, as recorded in the run's attributes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveReport {
    /// The method.
    pub method: Method,
    /// Iterations (cycles or sweeps).
    pub iterations: u64,
    /// Why it stopped.
    pub stopped_by: StopReason,
    /// Final `||r||_2 / ||r_0||_2`.
    pub relative_residual: f64,
    /// Largest change of the last iteration.
    pub max_change: f64,
    /// `||r||_2 / ||r_0||_2` per iterate.
    pub residual_history: Vec<f64>,
    /// Largest change per iteration.
    pub max_change_history: Vec<f64>,
    /// Unknowns (interior voxels).
    pub unknowns: u64,
    /// Level shapes (multigrid).
    pub levels: Vec<[u64; 3]>,
    /// Work in fine-grid sweep equivalents.
    pub sweep_equivalents: f64,
    /// Iterations done before a resume, if resumed.
    pub resumed_at: Option<u64>,
    /// Checkpoints written.
    pub checkpoints: u64,
    /// Blocks in flight.
    pub workers: usize,
    /// Levels held in memory (the rest in scratch files).
    pub in_memory: Vec<bool>,
    /// Multigrid on the regions where u is tiny, after the solve.
    #[serde(default)]
    pub deepen: DeepenReport,
    /// The relaxation of tiny values after the solve.
    pub polish: PolishReport,
}
