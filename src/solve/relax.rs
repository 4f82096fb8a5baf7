//! Out-of-core red-black SOR: block by block over two generations of phi.
//!
//! A half-sweep reads every block of generation A with a one-voxel halo, updates the
//! voxels of one color and writes the block to generation B; the other color goes from B
//! back to A. A red update reads only black neighbours (unchanged during the red
//! half-sweep), so the blocked sweep equals the global red-black sweep exactly, whatever
//! the blocks, their order and the thread count: the same bytes out. After each full
//! iteration the result is in A.
//!
//! Stops on the paper's criterion (max |phi_new - phi_old| over an iteration below
//! `tol`), on the relative residual `||r||_2 / ||r_0||_2 < rtol`, or at `max_iter`.

use serde::{Deserialize, Serialize};

use super::dirichlet::initial;
use super::stencil::{optimal_omega, residual, sor_half_sweep, Stats};
use crate::grid::{BlockStore, GridError};
use crate::parallel::map_bounded;
use crate::progress::Progress;

/// Options of the relaxation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RelaxOptions {
    /// Over-relaxation factor; `None`: the model problem's optimum for the grid's
    /// longest side.
    pub omega: Option<f64>,
    /// The paper's zeta: stop when the largest change of an iteration is below it
    /// (0 disables).
    pub tol: f64,
    /// Stop when the residual has fallen by this factor (0 disables).
    pub rtol: f64,
    /// Exterior layer spacing of the Dirichlet conditions.
    pub eps: f64,
    /// Iteration limit.
    pub max_iter: u64,
    /// Blocks in flight.
    pub workers: usize,
}

impl Default for RelaxOptions {
    fn default() -> Self {
        Self {
            omega: None,
            tol: 0.0,
            rtol: 1e-6,
            eps: 1e-4,
            max_iter: 100_000,
            workers: usize::MAX,
        }
    }
}

/// Why the relaxation stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The largest change of an iteration fell below `tol`.
    MaxChange,
    /// The relative residual fell below `rtol`.
    Residual,
    /// `max_iter` iterations ran.
    IterationLimit,
}

/// What the relaxation did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RelaxReport {
    /// Full iterations (a red and a black half-sweep each).
    pub iterations: u64,
    /// Largest change in the last iteration.
    pub max_change: f64,
    /// `||r||_2 / ||r_0||_2` after each iteration.
    pub residual_history: Vec<f64>,
    /// The over-relaxation factor used.
    pub omega: f64,
    /// Why it stopped.
    pub stopped_by: StopReason,
    /// Unknowns (interior voxels).
    pub unknowns: u64,
}

fn reduce(parts: Vec<Stats>) -> Stats {
    parts.into_iter().fold(Stats::default(), Stats::then)
}

/// Parity of `z + y + x` at the first voxel of block `b`'s one-voxel haloed box.
fn halo_parity(store: &dyn BlockStore<f64>, b: crate::math::Idx3) -> usize {
    let s = store.spec().block_start(b);
    ((s[0] + s[1] + s[2] + 1) % 2) as usize
}

/// Set every voxel of `phi` to its starting value from `labels`.
pub fn initialize(
    labels: &dyn BlockStore<u8>,
    phi: &dyn BlockStore<f64>,
    eps: f64,
    workers: usize,
) -> Result<(), GridError> {
    map_bounded(&phi.spec().block_indices(), workers, |&b| {
        let l = labels.read_block(b)?;
        phi.write_block(b, &l.iter().map(|&v| initial(v, eps)).collect::<Vec<_>>())
    })?;
    Ok(())
}

fn half_sweep(
    labels: &dyn BlockStore<u8>,
    src: &dyn BlockStore<f64>,
    dst: &dyn BlockStore<f64>,
    color: usize,
    omega: f64,
    workers: usize,
) -> Result<Stats, GridError> {
    let spec = src.spec();
    let parts = map_bounded(
        &spec.block_indices(),
        workers,
        |&b| -> Result<Stats, GridError> {
            let mut p = src.read_block_halo(b, 1, f64::NAN)?;
            let l = labels.read_block_halo(b, 1, 0)?;
            let st = sor_half_sweep(
                &mut p.data,
                &l.data,
                p.shape,
                1,
                halo_parity(src, b),
                color,
                omega,
            );
            let s = spec.block_shape(b).map(|c| c as usize);
            dst.write_block(b, &p.crop([1, 1, 1], s))?;
            Ok(st)
        },
    )?;
    Ok(reduce(parts))
}

/// Residual statistics of `phi` over the whole grid, reduced in block order.
pub fn residual_of(
    labels: &dyn BlockStore<u8>,
    phi: &dyn BlockStore<f64>,
    workers: usize,
) -> Result<Stats, GridError> {
    let parts = map_bounded(
        &phi.spec().block_indices(),
        workers,
        |&b| -> Result<Stats, GridError> {
            let p = phi.read_block_halo(b, 1, f64::NAN)?;
            let l = labels.read_block_halo(b, 1, 0)?;
            Ok(residual(&p.data, &l.data, p.shape, 1))
        },
    )?;
    Ok(reduce(parts))
}

/// Relax `a` (already initialized) with red-black SOR, using `b` as the second
/// generation. The answer ends in `a`.
pub fn relax_sor(
    labels: &dyn BlockStore<u8>,
    a: &dyn BlockStore<f64>,
    b: &dyn BlockStore<f64>,
    opts: &RelaxOptions,
    progress: &dyn Progress,
) -> Result<RelaxReport, GridError> {
    for (name, s) in [("labels", labels.spec()), ("second generation", b.spec())] {
        if s.shape != a.spec().shape || s.chunk != a.spec().chunk {
            return Err(GridError::Mismatch(format!(
                "{name} {:?} in blocks {:?}, phi {:?} in blocks {:?}",
                s.shape,
                s.chunk,
                a.spec().shape,
                a.spec().chunk
            )));
        }
    }
    let n = a.spec().shape.iter().copied().max().unwrap_or(1) as f64;
    let omega = opts.omega.unwrap_or_else(|| optimal_omega(n));
    let w = opts.workers;
    let r0 = residual_of(labels, a, w)?;
    let norm0 = r0.sum_sq.sqrt();
    let mut report = RelaxReport {
        iterations: 0,
        max_change: f64::INFINITY,
        residual_history: Vec::new(),
        omega,
        stopped_by: StopReason::IterationLimit,
        unknowns: r0.count,
    };
    if norm0 == 0.0 {
        report.stopped_by = StopReason::Residual;
        report.max_change = 0.0;
        return Ok(report);
    }
    progress.start("solve: red-black SOR", opts.max_iter);
    while report.iterations < opts.max_iter {
        let red = half_sweep(labels, a, b, 0, omega, w)?;
        let black = half_sweep(labels, b, a, 1, omega, w)?;
        report.iterations += 1;
        report.max_change = red.max_abs.max(black.max_abs);
        let rel = residual_of(labels, a, w)?.sum_sq.sqrt() / norm0;
        report.residual_history.push(rel);
        progress.advance(1);
        if opts.rtol > 0.0 && rel < opts.rtol {
            report.stopped_by = StopReason::Residual;
            break;
        }
        if opts.tol > 0.0 && report.max_change < opts.tol {
            report.stopped_by = StopReason::MaxChange;
            break;
        }
    }
    progress.finish();
    Ok(report)
}
