//! The topology repair's rounds: specks and cavities tidied, then rounds of windows
//! around the handles that closings find (see [`super::windows`]), larger closings when
//! a round removes none, and for what the windows leave the whole-grid repair
//! ([`super::repair`], grids up to 8 Mi voxels) or the compact cut ([`super::compact`],
//! larger grids); checked and tallied for the report. Grids over 32 Mi voxels, and the
//! grids of balls (molecules, points with radii) over 8 Mi, go straight to the compact
//! cut, without closings. [`super::topology`] decides whether
//! to repair; this file does it.

use std::cell::Cell;
use std::time::Instant;

use super::topology::{measure, summary, ClosingGrid, Env};
use super::{
    closing, compact, components, euler, repair, windows, RepairRegion, TopologyRepair,
    VoxelizeError, HANDLE_PROBE, HANDLE_PROBE_ANGSTROM,
};
use crate::grid::{human, GridSpec};
use crate::input::{Shape, TriMesh};
use crate::math::Idx3;

/// Rounds of windowed repair before the whole-grid fallback.
const MAX_ROUNDS: usize = 12;

/// The largest grid the repair takes whole in memory (after the windows), in voxels: 8
/// Mi voxels, 192 MiB at [`repair::BYTES_PER_VOXEL`], with the choice of cut or fill.
/// Larger grids whose handles the windows and the larger closings leave get the compact
/// cut. Fixed, so that the result never depends on `--mem`.
const WHOLE_GRID_VOXELS: u64 = 1 << 23;

/// Grids of more voxels than this (32 Mi) get the compact cut at once: no windows and
/// no closings, whose passes over so large a grid cost more than the cut and whose
/// windows miss tunnels wider than the closing (a protein's). Fixed, so that the result
/// never depends on `--mem`.
const NO_CLOSING_ABOVE: u64 = 1 << 25;

thread_local! {
    /// Grids of more voxels than this get the compact cut ([`compact`]) instead of the
    /// windows, closings and the grid-wide repair: [`NO_CLOSING_ABOVE`] but in
    /// the tests that lower it ([`compact_repair_above`]).
    static COMPACT_ABOVE: Cell<u64> = const { Cell::new(NO_CLOSING_ABOVE) };
}

/// For tests: the repairs that this thread runs from now on take the compact cut on
/// grids of more than `voxels` voxels (None: the default, 32 Mi voxels), so that a small
/// grid can go through it.
#[doc(hidden)]
pub fn compact_repair_above(voxels: Option<u64>) {
    COMPACT_ABOVE.with(|c| c.set(voxels.unwrap_or(NO_CLOSING_ABOVE)));
}

/// What the repair has changed so far.
#[derive(Default)]
struct Tally {
    removed: u64,
    added: u64,
    cut: i64,
    filled: i64,
    specks: u64,
    speck_voxels: u64,
    alternative: u64,
    brick_reads: Option<u64>,
    regions: Vec<repair::Region>,
}

impl Tally {
    fn window(&mut self, o: &windows::WindowOutcome) {
        self.removed += o.removed;
        self.added += o.added;
        if o.fill {
            self.filled += o.closes;
        } else {
            self.cut += o.closes;
        }
        self.alternative = self.alternative.saturating_add(o.alternative);
        self.regions.extend(o.regions.iter().cloned());
    }
}

/// Drop every piece but the largest (the first of equals), of a solid without cavities;
/// returns the solid's Euler characteristic afterwards.
fn tidy(env: &Env, tally: &mut Tally) -> Result<i64, crate::Error> {
    let pieces = components::find(
        env.solid,
        |v| v == 1,
        env.w_ccl,
        env.ccl_limit,
        "voxelize: repair: pieces",
        env.progress,
    )?;
    if pieces.sizes.len() > 1 {
        let largest = (0..pieces.sizes.len())
            .max_by_key(|&i| (pieces.sizes[i], std::cmp::Reverse(i)))
            .expect("non-empty") as u32;
        for (c, &n) in pieces.sizes.iter().enumerate() {
            if c as u32 != largest {
                tally.specks += 1;
                tally.speck_voxels += n;
                tally.removed += n;
            }
        }
        tally.regions.extend(components::first_voxels(
            env.solid,
            &pieces,
            |v| v == 1,
            largest,
            env.w_ccl,
        )?);
        components::rewrite(
            env.solid,
            &pieces,
            |v| v == 1,
            |c, v| if c == largest { v } else { 0 },
            env.w_ccl,
        )?;
    }
    // No cavity to fill: the stage filled them before the topology counts, and
    // dropping whole pieces (here, or --keep-largest's) cannot enclose background: what
    // a dropped piece leaves joins the background around it, which reaches the faces.
    euler::euler_characteristic(env.solid, env.w_ccl)
}

/// Pieces of the solid.
fn pieces(env: &Env) -> Result<usize, crate::Error> {
    Ok(components::find(
        env.solid,
        |v| v == 1,
        env.w_ccl,
        env.ccl_limit,
        "voxelize: repair: pieces",
        env.progress,
    )?
    .sizes
    .len())
}

/// The closing radius that finds the handles first.
pub(super) fn probe_radius(env: &Env) -> u32 {
    let opts = env.opts;
    if opts.close > 0 {
        2 * opts.close
    } else if matches!(env.shape, Shape::Molecule(_)) {
        HANDLE_PROBE.max((HANDLE_PROBE_ANGSTROM / env.spec.spacing).round() as u32)
    } else {
        HANDLE_PROBE
    }
}

/// The pieces of the background (everything but the solid): those not touching the
/// grid's border are cavities.
fn background(env: &Env) -> Result<components::Components, crate::Error> {
    components::find(
        env.solid,
        |v| v != 1,
        env.w_ccl,
        env.ccl_limit,
        "voxelize: repair: cavities",
        env.progress,
    )
}

/// Whether the solid is one piece (`pieces`) without cavities (`cavities`), as far as
/// asked.
fn intact(env: &Env, pieces: bool, cavities: bool) -> Result<bool, crate::Error> {
    if pieces && self::pieces(env)? > 1 {
        return Ok(false);
    }
    if cavities && background(env)?.touches_border.iter().any(|&t| !t) {
        return Ok(false);
    }
    Ok(true)
}

/// One round of windows around the handles a closing by `probe` finds, each kept only
/// when the solid stays one piece without cavities (so that the window's rise of the
/// Euler characteristic is the handles it removed). Returns the handles removed.
fn round(
    env: &Env,
    closing_grid: &ClosingGrid,
    probe: u32,
    tally: &mut Tally,
    history: &mut Vec<(Idx3, [usize; 3], Vec<bool>)>,
) -> Result<i64, crate::Error> {
    let (grid, w, room) = closing_grid("repair.u8", probe)?;
    closing::close(env.solid, &*grid, probe, w, room, env.progress)?;
    let handles = closing::handles(&*grid, 4096, env.w_ccl, env.ccl_limit, env.progress)?;
    drop(grid);
    let margin = u64::from(probe) + 2;
    let shape = env.spec.shape;
    let boxes: Vec<(Idx3, [usize; 3])> = handles
        .iter()
        .map(|h| windows::window(shape, h.lo, h.hi, margin))
        .filter(|(_, s)| s.iter().map(|&c| c as u64).product::<u64>() <= windows::MAX_WINDOW_VOXELS)
        .collect();
    let mut applied: Vec<(Idx3, [usize; 3], windows::WindowOutcome)> = Vec::new();
    let surface = mesh(env);
    for &(origin, wshape) in &boxes {
        check_room(env, wshape.iter().map(|&c| c as u64).product())?;
        if let Some(o) = windows::repair_window(env.solid, origin, wshape, surface)? {
            applied.push((origin, wshape, o));
        }
    }
    // Cuts that split a piece of their window may disconnect the solid; fills may
    // enclose a cavity beyond their window. Checked once for the round; when the check
    // fails, the round is undone and redone one window at a time.
    let split = applied.iter().any(|a| a.2.split);
    let fill = applied.iter().any(|a| a.2.fill);
    if (split || fill) && !intact(env, split, fill)? {
        for (origin, wshape, o) in applied.iter().rev() {
            windows::write_window(env.solid, *origin, *wshape, &o.before)?;
        }
        applied.clear();
        for &(origin, wshape) in &boxes {
            if let Some(o) = windows::repair_window(env.solid, origin, wshape, surface)? {
                if (o.split || o.fill) && !intact(env, o.split, o.fill)? {
                    windows::write_window(env.solid, origin, wshape, &o.before)?;
                    continue;
                }
                applied.push((origin, wshape, o));
            }
        }
    }
    for (_, _, o) in &applied {
        tally.window(o);
    }
    let closes = applied.iter().map(|a| a.2.closes).sum();
    history.extend(applied.into_iter().map(|(o, s, w)| (o, s, w.before)));
    Ok(closes)
}

/// The compact cut of the whole solid (`solid` voxels after the tidying), when it fits
/// in what `--mem` leaves, of the solid with Euler characteristic `chi`; tallied.
fn compact_cut(env: &Env, tally: &mut Tally, chi: i64) -> Result<(), crate::Error> {
    let need = compact::bytes_needed(env.spec);
    if need > env.room {
        let [_, ny, nx] = env.spec.shape;
        return Err(VoxelizeError::Topology(format!(
            "{}: the topology repair of a grid of {} voxels holds at least {} ({} bytes a voxel of one {ny} x {nx} slice, and a cache of bricks), more than the {} --mem {} leaves; give more --mem, a coarser grid, or --topology strict / --allow-genus",
            env.source_name,
            env.spec.num_voxels(),
            human(need),
            compact::BYTES_PER_SLICE_VOXEL,
            human(env.room),
            env.opts.mem
        ))
        .into());
    }
    let o = compact::cut(env.solid, mesh(env), env.scratch, env.room, env.progress)?;
    tally.removed += o.removed;
    tally.cut += 1 - chi;
    // The fill is not tried on this path.
    tally.alternative = u64::MAX;
    tally.regions.extend(o.regions);
    if o.spilled {
        tally.brick_reads = Some(o.brick_reads);
    }
    Ok(())
}

/// The mesh and its grid when the input is a mesh: the depths the growths follow.
fn mesh<'a>(env: &Env<'a>) -> Option<(&'a TriMesh, &'a GridSpec)> {
    match env.shape {
        Shape::Mesh(m) => Some((m, env.spec)),
        _ => None,
    }
}

/// Refuse a window that does not fit in what `--mem` leaves.
fn check_room(env: &Env, voxels: u64) -> Result<(), crate::Error> {
    let need = voxels * windows::BYTES_PER_WINDOW_VOXEL;
    if need > env.room {
        return Err(VoxelizeError::Topology(format!(
            "{}: repairing a handle needs a window of {voxels} voxels, {} ({} bytes a voxel), more than the {} --mem {} leaves; give more --mem, or use --topology strict / --allow-genus",
            env.source_name,
            human(need),
            windows::BYTES_PER_WINDOW_VOXEL,
            human(env.room),
            env.opts.mem
        ))
        .into());
    }
    Ok(())
}

/// Repair the solid, check it is one genus-0 piece, and say what changed: specks
/// dropped, then rounds of windows around the handles (see [`windows`]), larger
/// closings when a round leaves handles, and the whole-grid repair when windows do not
/// get there (if the grid fits in memory).
#[allow(clippy::too_many_lines)] // the rounds, the fallback, the check and the report read the same tallies
pub(super) fn run_repair(
    env: &Env,
    closing_grid: &ClosingGrid,
    ncomp: u64,
    genus: i64,
    solid_voxels: u64,
    warnings: &mut Vec<String>,
) -> Result<TopologyRepair, crate::Error> {
    let t = Instant::now();
    let mut tally = Tally::default();
    let mut probe = probe_radius(env);
    let first_probe = probe;
    let max_probe = probe.max(8) * 8;
    // A grid this small is repaired whole when windows around the voxel-scale handles
    // leave some; a larger one tries larger closings and windows first.
    let whole_grid = env.spec.num_voxels() <= WHOLE_GRID_VOXELS;
    let mut chi = tidy(env, &mut tally)?;
    let chi_tidy = chi;
    let mut windowed = Tally::default();
    let mut history = Vec::new();
    // A large grid, or a grid of balls (a molecule's) too large to repair whole: the
    // compact cut, without closings. A solvent-excluded solid's tunnels are wider than the closings
    // (adk_open at 0.25 A: closings by 12, 24 and 48 voxels found none of its 5
    // handles, and took three quarters of the stage), and the cut is small beside a
    // fill that would plug them.
    let molecule = matches!(env.shape, Shape::Molecule(_));
    let compact =
        env.spec.num_voxels() > COMPACT_ABOVE.with(Cell::get) || (molecule && !whole_grid);
    if compact && chi != 1 {
        compact_cut(env, &mut tally, chi)?;
        chi = 1;
    }
    for _ in 0..MAX_ROUNDS {
        if chi == 1 {
            break;
        }
        let removed = match round(env, closing_grid, probe, &mut windowed, &mut history) {
            Ok(n) => n,
            // A closing larger than the first that does not fit in --mem ends the
            // ladder: the compact cut below takes what is left.
            Err(crate::Error::Grid(crate::grid::GridError::Budget { .. }))
                if probe > first_probe =>
            {
                break;
            }
            Err(e) => return Err(e),
        };
        chi = euler::euler_characteristic(env.solid, env.w_ccl)?;
        if removed == 0 {
            if whole_grid {
                break;
            }
            // No handle removed: larger closings find wider tunnels, in larger windows.
            probe *= 2;
            if probe > max_probe {
                break;
            }
        }
    }
    if chi != 1 {
        // Handles the windows did not remove: the whole solid, from before the windows
        // (the whole-grid repair replaces them).
        for (origin, wshape, before) in history.iter().rev() {
            windows::write_window(env.solid, *origin, *wshape, before)?;
        }
        windowed = Tally::default();
        chi = chi_tidy;
    }
    if chi != 1 && !whole_grid {
        // Larger than the grid-wide repair takes: the compact cut.
        compact_cut(env, &mut tally, chi)?;
        chi = 1;
    }
    if chi != 1 {
        let need = env.spec.num_voxels() * repair::BYTES_PER_VOXEL;
        if need > env.room {
            return Err(VoxelizeError::Topology(format!(
                "{}: the voxel solid has {ncomp} piece(s) and genus {genus}; the repair in windows around the handles left genus {}, and repairing the whole grid at once holds it in memory, {} ({} bytes a voxel), more than the {} --mem {} leaves; give more --mem, a coarser grid, or --topology strict / --allow-genus",
                env.source_name,
                1 - chi,
                human(need),
                repair::BYTES_PER_VOXEL,
                human(env.room),
                env.opts.mem
            ))
            .into());
        }
        let o = repair::repair(env.solid, mesh(env))?;
        tally.removed += o.removed;
        tally.added += o.added;
        tally.specks += o.specks;
        tally.speck_voxels += o.speck_voxels;
        tally.alternative = tally.alternative.saturating_add(o.alternative);
        if o.method == "fill" {
            tally.filled += 1 - chi;
        } else {
            tally.cut += 1 - chi;
        }
        tally.regions.extend(o.regions);
    }
    tally.removed += windowed.removed;
    tally.added += windowed.added;
    tally.cut += windowed.cut;
    tally.filled += windowed.filled;
    tally.alternative = tally.alternative.saturating_add(windowed.alternative);
    tally.regions.extend(windowed.regions);
    // Check what the repair promises with the passes that found the defects.
    let (after, chi, _, _, _) = measure(env, false)?;
    // (No cavity: the whole-grid growths cannot make one, and a window is kept only
    // when the solid has none afterwards.)
    if after != 1 || chi != 1 {
        return Err(VoxelizeError::Topology(format!(
            "{}: the topology repair left {after} piece(s) with Euler characteristic {chi} (expected one genus-0 piece); this is a bug in harmap: please report it, and use --allow-genus or --topology strict meanwhile",
            env.source_name
        ))
        .into());
    }
    let spec = env.spec;
    let changed = tally.removed + tally.added;
    let fraction = changed as f64 / solid_voxels.max(1) as f64;
    let mut regions = tally.regions;
    regions.sort_by_key(|r| (std::cmp::Reverse(r.voxels), r.voxel));
    let regions: Vec<RepairRegion> = regions
        .iter()
        .take(8)
        .map(|r| RepairRegion {
            kind: if r.added { "added" } else { "removed" }.to_owned(),
            voxels: r.voxels,
            voxel: r.voxel,
            position: spec.voxel_center(r.voxel).to_array(),
        })
        .collect();
    let method = match (tally.cut > 0, tally.filled > 0) {
        (true, true) => "cut and fill",
        (false, true) => "fill",
        _ => "cut",
    };
    let report = TopologyRepair {
        components_before: ncomp,
        genus_before: genus.max(0),
        method: method.to_owned(),
        voxels_removed: tally.removed,
        voxels_added: tally.added,
        handles_cut: tally.cut,
        handles_filled: tally.filled,
        specks_dropped: tally.specks,
        speck_voxels: tally.speck_voxels,
        alternative_voxels: tally.alternative,
        fraction,
        regions,
        seconds: t.elapsed().as_secs_f64(),
        scratch_brick_reads: tally.brick_reads,
    };
    if fraction > 1e-3 {
        warnings.push(format!(
            "the topology repair changed {changed} voxels, {:.2}% of the solid (more than 0.1%): {}; check the labels there, or use a finer grid, --topology strict or --allow-genus",
            100.0 * fraction,
            summary(&report)
        ));
    }
    Ok(report)
}
