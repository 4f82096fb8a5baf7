//! The options of `harmap solve`.

use serde::{Deserialize, Serialize};

use super::driver::Method;
use super::multigrid::CycleOptions;
use super::polish::PolishOptions;
use crate::grid::MemBudget;

/// Options of `harmap solve`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveOptions {
    /// The iteration.
    pub method: Method,
    /// The paper's zeta: stop when the largest change of an iteration is below it (0:
    /// off).
    pub tol: f64,
    /// Stop when `||r||_2 / ||r_0||_2` is below it (0: off).
    pub rtol: f64,
    /// Spacing of the exterior layers' values `1 + k eps`.
    pub eps: f64,
    /// Iteration limit (cycles for multigrid, sweeps otherwise).
    pub max_iter: u64,
    /// SOR factor (`None`: the optimum for the grid).
    pub omega: Option<f64>,
    /// Multigrid cycle.
    pub cycle: CycleOptions,
    /// Relaxing the tiny values after the solve.
    pub polish: PolishOptions,
    /// Memory budget.
    #[serde(skip)]
    pub mem: MemBudget,
    /// Seconds between checkpoints (0: only on interruption).
    #[serde(skip)]
    pub checkpoint_every: f64,
    /// Continue from the last checkpoint.
    #[serde(skip)]
    pub resume: bool,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            method: Method::Multigrid,
            tol: 0.0,
            rtol: 1e-6,
            eps: 1e-4,
            max_iter: 1000,
            omega: None,
            cycle: CycleOptions::default(),
            polish: PolishOptions::default(),
            mem: MemBudget::default(),
            checkpoint_every: 300.0,
            resume: false,
        }
    }
}
