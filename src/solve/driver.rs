//! The iteration loop shared by the three methods: measure the residual of the current
//! state, decide (stop, checkpoint, go on), finish the iteration.
//!
//! The loop decides on the residual of the current state (generation `cur`), measured
//! by the pass that reads it (SOR, Jacobi, the first multigrid cycle) or, for later
//! multigrid cycles, by the pass that wrote it; nothing has overwritten that state when
//! the loop decides, so the answer, a checkpoint and an interruption all see one whole
//! iterate. The residual history is therefore `||r(x_k)|| / ||r(x_0)||` for the iterates
//! `x_0, x_1, ...` exactly.

use serde::{Deserialize, Serialize};

use super::jacobi::jacobi_pass;
use super::level::PassStats;
use super::multigrid::{Cycle, Hierarchy, FMG_CYCLES};
use super::stencil::optimal_omega;
/// Moved to [`crate::grid::copy_blocks`]; kept here for the callers of the old path.
pub use crate::grid::copy_blocks;
use crate::grid::GridError;

/// The iteration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// V-cycles of geometric multigrid (the default).
    #[default]
    Multigrid,
    /// Red-black successive over-relaxation with the model problem's optimal factor.
    Sor,
    /// The paper's iteration: every unknown becomes the mean of its neighbours.
    Jacobi,
}

impl Method {
    /// The name used on the command line and in the run's attributes.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Method::Multigrid => "multigrid",
            Method::Sor => "sor",
            Method::Jacobi => "jacobi",
        }
    }
}

/// Why the iteration stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The relative residual fell below `rtol`.
    Residual,
    /// The largest change of an iteration fell below `tol` (the paper's criterion).
    MaxChange,
    /// `max_iter` iterations ran.
    IterationLimit,
    /// Asked to stop (SIGINT or SIGTERM); a checkpoint holds the state.
    Interrupted,
    /// Full multigrid's algebraic error fell well below the discretization error.
    Discretization,
}

impl StopReason {
    /// The name in the run's attributes.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            StopReason::Residual => "residual",
            StopReason::MaxChange => "max_change",
            StopReason::IterationLimit => "iteration_limit",
            StopReason::Interrupted => "interrupted",
            StopReason::Discretization => "discretization",
        }
    }
}

/// The state of an iteration that a checkpoint records and a resume restores.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    /// Iterations completed.
    pub iterations: u64,
    /// `||r(x_0)||_2` (residual of the starting state), 0 before the first measure.
    pub r0: f64,
    /// `||r(x_k)||_2 / ||r(x_0)||_2` for `k = 0..` (as measured so far).
    pub residual: Vec<f64>,
    /// Largest |x_{k+1} - x_k| over the unknowns, per completed iteration.
    pub max_change: Vec<f64>,
    /// Which generation holds the state (0 or 1).
    pub cur: usize,
    /// Unknowns (interior voxels).
    #[serde(default)]
    pub unknowns: u64,
    /// The first iteration was full multigrid's coarse phase.
    #[serde(default)]
    pub fmg: bool,
}

/// What the loop should do after a measurement.
pub enum Decision {
    /// Finish this iteration and go on.
    Continue,
    /// Stop with the state as it is.
    Stop(StopReason),
}

/// One method over the finest level's stores.
pub struct Iteration<'a> {
    /// The hierarchy (only the finest level for SOR and Jacobi).
    pub h: &'a Hierarchy<'a>,
    /// Which iteration.
    pub method: Method,
    /// Over-relaxation factor of SOR.
    pub omega: f64,
}

impl Iteration<'_> {
    /// An iteration, given the method; `omega`: the SOR factor (`None`: the optimum for
    /// the grid's longest axis).
    #[must_use]
    pub fn new<'a>(h: &'a Hierarchy<'a>, method: Method, omega: Option<f64>) -> Iteration<'a> {
        let n = h.levels[0].spec.shape.iter().copied().max().unwrap_or(2) as f64;
        Iteration {
            h,
            method,
            omega: omega.unwrap_or_else(|| optimal_omega(n)),
        }
    }

    /// Fine-grid sweep equivalents of one iteration (work units: one red-black sweep of
    /// the finest level is 1).
    #[must_use]
    pub fn sweeps_per_iteration(&self) -> f64 {
        match self.method {
            Method::Sor | Method::Jacobi => 1.0,
            Method::Multigrid => self.cycle_work(0),
        }
    }

    /// The share of level `k`'s voxels in the finest level's.
    fn ratio(&self, k: usize) -> f64 {
        let n0 = self.h.levels[0].spec.num_voxels() as f64;
        self.h.levels[k].spec.num_voxels() as f64 / n0
    }

    /// Work of the coarsest level's relaxation, in its own sweeps.
    fn coarsest_sweeps(&self) -> f64 {
        let l = self.h.levels.last().expect("a level");
        let n = l.spec.shape.iter().copied().max().unwrap_or(2) as f64;
        (4.0 * n).max(20.0)
    }

    /// Fine-grid sweep equivalents of a V-cycle on level `k`: on each level its sweeps
    /// plus one for the residual of the restriction and the prolongation.
    fn cycle_work(&self, k: usize) -> f64 {
        let c = self.h.cycle;
        let last = self.h.levels.len() - 1;
        (k..=last)
            .map(|j| {
                let s = if j == last {
                    self.coarsest_sweeps()
                } else {
                    (c.pre + c.post) as f64 + 1.0
                };
                self.ratio(j) * s
            })
            .sum()
    }

    /// Fine-grid sweep equivalents of full multigrid's coarse phase: on the finest
    /// level the residual of the start, its restriction and the prolongation (2); on
    /// each coarse level a restriction and a prolongation (1) and [`FMG_CYCLES`]
    /// V-cycles; the coarsest level's relaxation once more.
    #[must_use]
    pub fn fmg_work(&self) -> f64 {
        let last = self.h.levels.len() - 1;
        let mut w = 2.0 + self.ratio(last) * self.coarsest_sweeps();
        for k in 1..last {
            w += self.ratio(k) + FMG_CYCLES as f64 * self.cycle_work(k);
        }
        w
    }

    /// Fine-grid sweep equivalents of the iterations in `hist`.
    #[must_use]
    pub fn work(&self, hist: &History) -> f64 {
        let per = self.sweeps_per_iteration();
        if hist.fmg && hist.iterations > 0 {
            self.fmg_work() + per * (hist.iterations - 1) as f64
        } else {
            per * hist.iterations as f64
        }
    }

    /// Whether the iteration starts with full multigrid's coarse phase: multigrid with
    /// `--cycle fmg`, a hierarchy of more than one level, and a fresh history (a resume
    /// goes on with V-cycles from the checkpoint).
    fn starts_with_fmg(&self, hist: &History) -> bool {
        self.method == Method::Multigrid
            && self.h.cycle.kind == Cycle::Fmg
            && self.h.levels.len() > 1
            && hist.residual.is_empty()
    }

    /// Run the iteration from `hist` (a fresh history, or one restored from a
    /// checkpoint) until `decide` says stop. `decide` sees the history after each
    /// measurement (the residual of the current state is its last entry).
    pub fn run(
        &self,
        hist: &mut History,
        mut decide: impl FnMut(&History) -> Result<Decision, GridError>,
    ) -> Result<StopReason, GridError> {
        let fine = &self.h.levels[0];
        let w = &self.h.blocks;
        // Multigrid: the residual of the current state as the last cycle measured it,
        // and whether this cycle's pre-smoothing is done.
        let mut measured: Option<PassStats> = None;
        let mut pre_done = false;
        if self.starts_with_fmg(hist) {
            // The coarse phase is the first iteration: x_0 is the starting state (its
            // residual is the reference r_0), x_1 full multigrid's result.
            let (start, change, after) = self.h.fmg_start()?;
            hist.fmg = true;
            hist.unknowns = start.count;
            hist.r0 = start.res_sq.sqrt();
            if hist.r0 == 0.0 {
                hist.residual.push(0.0);
                return Ok(StopReason::Residual);
            }
            hist.residual.push(1.0);
            hist.iterations += 1;
            hist.max_change.push(change);
            measured = Some(after);
        }
        loop {
            let cur = hist.cur;
            // The state's residual: measured by the first pass of the iteration, or (for
            // multigrid after the first cycle) by the last pass of the one before.
            let first = match self.method {
                Method::Multigrid => {
                    debug_assert_eq!(cur, 0);
                    if let Some(m) = measured.take() {
                        pre_done = false;
                        m
                    } else {
                        pre_done = true;
                        self.h.pre_smooth_fine(true)?
                    }
                }
                Method::Sor => fine.sor_pass(cur, 1 - cur, self.omega, w)?,
                Method::Jacobi => jacobi_pass(fine, cur, 1 - cur, w)?,
            };
            let norm = first.res_sq.sqrt();
            hist.unknowns = first.count;
            if hist.residual.is_empty() {
                hist.r0 = norm;
            }
            hist.residual
                .push(if hist.r0 > 0.0 { norm / hist.r0 } else { 0.0 });
            if hist.r0 == 0.0 {
                return Ok(StopReason::Residual);
            }
            if let Decision::Stop(why) = decide(hist)? {
                return Ok(why);
            }
            let change = match self.method {
                Method::Multigrid => {
                    if !pre_done {
                        self.h.pre_smooth_fine(false)?;
                    }
                    let (change, next) = self.h.finish_cycle()?;
                    measured = Some(next);
                    change
                }
                Method::Sor | Method::Jacobi => {
                    hist.cur = 1 - cur;
                    first.max_change
                }
            };
            hist.iterations += 1;
            hist.max_change.push(change);
        }
    }
}
