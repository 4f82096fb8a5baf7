//! Relative accuracy where u = 1 - phi is tiny, at multigrid cost: nested solves on the
//! regions where u is below a falling threshold.
//!
//! A solve stopped on the global residual leaves an absolute error of about rtol times
//! the scale of u everywhere, so where u is 1e-20 the iterate is mostly error (see
//! [`super::polish`]). But the region where u is below a threshold `t` is a Dirichlet
//! problem of its own, with the values around it as its boundary values, and its
//! solution is of the scale `t`: multigrid on that region, with every other unknown held
//! at its value, reaches an absolute error of `1e-6 t` in a few V-cycles. And the
//! maximum principle carries relative accuracy inward: u is positive and harmonic in the
//! region, so boundary values right to a relative `e` give values right to a relative
//! `e` everywhere inside, however small.
//!
//! So after the solve, stage by stage with `t` = 1e-6, 1e-11, 1e-16, 1e-21 (each
//! [`DeepenOptions::factor`] below the one before): the unknowns with `u < t` (negatives
//! included) stay unknowns, the others are held (their mask value gets [`HELD`]), the
//! coarse masks are made again from that mask, and V-cycles from the current values run
//! until a cycle moves no value by more than [`DeepenOptions::rel`] times the next
//! threshold. The values at the next stage's border are then right to about that
//! relative accuracy, and the next stage starts from them. Each stage's region is inside
//! the one before (values outside it are held, so they are at least `t`). Afterwards the
//! mask is restored, and the polish ([`super::polish`]) relaxes only what is left below
//! the last stage's reach.
//!
//! Every pass is a pass of the multigrid hierarchy, so the result is the same bytes for
//! any thread count and budget.

use super::cuts::is_unknown;
use super::multigrid::Hierarchy;
use crate::grid::GridError;
use crate::progress::Progress;

/// Added to the mask value of an unknown held at its value during a stage (the
/// passes treat any mask value but `INTERIOR` and `CUT` as fixed).
pub const HELD: u8 = 0x80;

/// Settings of [`deepen`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeepenOptions {
    /// The first stage's threshold: the solve's absolute error is well below it.
    pub first: f64,
    /// Each stage's threshold is this times the one before.
    pub factor: f64,
    /// No stage below this threshold (the values below it are the polish's).
    pub last: f64,
    /// A stage stops when no value moves by more than this times the next stage's
    /// threshold in a V-cycle.
    pub rel: f64,
    /// V-cycles allowed per stage.
    pub max_cycles: u64,
}

impl Default for DeepenOptions {
    fn default() -> Self {
        Self {
            first: 1e-6,
            factor: 1e-5,
            last: 1e-21,
            rel: 1e-6,
            max_cycles: 40,
        }
    }
}

/// What one stage did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Stage {
    /// The threshold: unknowns with u below it were solved for.
    pub threshold: f64,
    /// Unknowns solved for.
    pub voxels: u64,
    /// V-cycles.
    pub cycles: u64,
    /// Largest change of the last V-cycle.
    pub last_change: f64,
}

/// What [`deepen`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeepenReport {
    /// The stages, first (largest threshold) first.
    pub stages: Vec<Stage>,
    /// Fine-grid sweep equivalents of all stages.
    pub sweep_equivalents: f64,
    /// Stopped between cycles because `stop` said so; u is then partly deepened.
    #[serde(skip)]
    pub interrupted: bool,
}

/// Hold the unknowns of the finest level whose u (generation 0) is at least `t`;
/// returns the unknowns left.
fn hold_above(h: &Hierarchy<'_>, t: f64) -> Result<u64, GridError> {
    let fine = &h.levels[0];
    let spec = &fine.spec;
    let counts = h.blocks.map(spec, |b| {
        let (mut m, u) = (fine.mask.read_block(b)?, fine.u[0].read_block(b)?);
        let mut left = 0u64;
        let mut changed = false;
        for (m, &u) in m.iter_mut().zip(&u) {
            if is_unknown(*m) {
                if u < t {
                    left += 1;
                } else {
                    *m |= HELD;
                    changed = true;
                }
            }
        }
        if changed {
            fine.mask.write_block(b, &m)?;
        }
        Ok(left as f64)
    })?;
    let left = h.blocks.gather(spec, counts)?.iter().sum::<f64>() as u64;
    h.blocks
        .exchange(&fine.field("mask"), &*fine.mask, &fine.reach)?;
    Ok(left)
}

/// The unknowns of the finest level whose u (generation 0) is below `t`.
fn count_below(h: &Hierarchy<'_>, t: f64) -> Result<u64, GridError> {
    let fine = &h.levels[0];
    let n = h.blocks.sum(&fine.spec, |b| {
        let (m, u) = (fine.mask.read_block(b)?, fine.u[0].read_block(b)?);
        Ok(m.iter()
            .zip(&u)
            .filter(|(&m, &u)| is_unknown(m) && u < t)
            .count() as f64)
    })?;
    Ok(n as u64)
}

/// Give the held unknowns of the finest level their mask values back.
fn release(h: &Hierarchy<'_>) -> Result<(), GridError> {
    let fine = &h.levels[0];
    h.blocks.each(&fine.spec, |b| {
        let mut m = fine.mask.read_block(b)?;
        if m.iter().any(|&v| v & HELD != 0 && is_unknown(v & !HELD)) {
            for v in &mut m {
                if *v & HELD != 0 && is_unknown(*v & !HELD) {
                    *v &= !HELD;
                }
            }
            fine.mask.write_block(b, &m)?;
        }
        Ok(())
    })?;
    h.blocks
        .exchange(&fine.field("mask"), &*fine.mask, &fine.reach)
}

/// The finest level's mask changed: make the coarse masks again, and let every level
/// rebuild what it derived from its mask.
fn remask(h: &mut Hierarchy<'_>) -> Result<(), GridError> {
    for k in 1..h.levels.len() {
        let (above, below) = h.levels.split_at(k);
        let (above, lvl) = (&above[k - 1], &below[0]);
        super::coarsen::coarsen_mask(
            above,
            &lvl.spec,
            (&*lvl.mask, lvl.cuts.as_deref()),
            &lvl.field("mask"),
            &lvl.reach,
            &h.blocks,
        )?;
    }
    for l in &mut h.levels {
        l.flat.mask_replaced();
    }
    Ok(())
}

/// Deepen the relative accuracy of the finest level's state (generation 0) where it is
/// tiny (see the module docs). `stop` is polled between cycles.
pub fn deepen(
    h: &mut Hierarchy<'_>,
    opts: &DeepenOptions,
    cycle_work: f64,
    stop: &(dyn Fn() -> bool + Sync),
    progress: &dyn Progress,
) -> Result<DeepenReport, GridError> {
    let mut report = DeepenReport::default();
    let mut t = opts.first;
    // Most problems have no tiny values: then the mask is left alone.
    if t < opts.last || h.levels.len() < 2 || count_below(h, t)? == 0 {
        return Ok(report);
    }
    while t >= opts.last && h.levels.len() > 1 {
        let voxels = hold_above(h, t)?;
        if voxels == 0 {
            break;
        }
        remask(h)?;
        let target = opts.rel * t * opts.factor;
        let mut stage = Stage {
            threshold: t,
            voxels,
            ..Stage::default()
        };
        h.pre_smooth_fine(false)?;
        loop {
            let (change, _) = h.finish_cycle()?;
            stage.cycles += 1;
            stage.last_change = change;
            progress.message(&format!(
                "solve: {voxels} values below {t:.0e}, cycle {}, largest change {change:.1e} (to {target:.0e})",
                stage.cycles
            ));
            if change <= target || stage.cycles >= opts.max_cycles {
                break;
            }
            if stop() {
                report.interrupted = true;
                break;
            }
            h.pre_smooth_fine(false)?;
        }
        report.sweep_equivalents += stage.cycles as f64 * cycle_work;
        report.stages.push(stage);
        if report.interrupted {
            break;
        }
        t *= opts.factor;
    }
    release(h)?;
    remask(h)?;
    Ok(report)
}
