//! The options of `harmap solve`.

use serde::{Deserialize, Serialize};

use super::deepen::DeepenOptions;
use super::driver::Method;
use super::multigrid::{Cycle, CycleOptions};
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
    /// Stop when `||r||_2 / ||r_0||_2` is below it (0: off; full multigrid then stops
    /// at the discretization error, see [`SolveOptions::stops_at_discretization`]).
    pub rtol: f64,
    /// Spacing of the exterior layers' values `1 + k eps`.
    pub eps: f64,
    /// Iteration limit (cycles for multigrid, sweeps otherwise).
    pub max_iter: u64,
    /// SOR factor (`None`: the optimum for the grid).
    pub omega: Option<f64>,
    /// Multigrid cycle.
    pub cycle: CycleOptions,
    /// Multigrid on the regions where u is tiny, after the solve.
    #[serde(default)]
    pub deepen: DeepenOptions,
    /// Relaxing the tiny values after the solve (below the last deepening stage).
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

impl SolveOptions {
    /// Whether the solve stops on the discretization criterion: full multigrid with
    /// `--rtol 0` (phi within the discretization error, in about 15 fine-grid sweeps;
    /// not the relative accuracy of tiny values the trace needs, which the default
    /// residual target gives).
    #[must_use]
    pub fn stops_at_discretization(&self) -> bool {
        self.method == Method::Multigrid && self.cycle.kind == Cycle::Fmg && self.rtol == 0.0
    }
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
            deepen: DeepenOptions::default(),
            polish: PolishOptions::default(),
            mem: MemBudget::default(),
            checkpoint_every: 300.0,
            resume: false,
        }
    }
}
