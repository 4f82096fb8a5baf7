//! The topology step: pieces and genus of the solid, then, when it is not one genus-0
//! piece, what to do: go on (`--allow-genus`), refuse with where the handles are
//! (`--topology strict`, or a mesh whose own surface has handles), or repair
//! ([`super::repair`]) and check the result.
//!
//! What counts as an artifact: for a mesh whose parts are all genus 0 (by the surface's
//! Euler characteristic), every handle and extra piece of the voxel solid comes from the
//! grid; molecules, point sets and label volumes are repaired by default too (their
//! tunnels are real but not what a map onto the ball can show).

use std::time::Instant;

use super::closing::{self, Handle};
use super::mesh_genus::SurfaceTopology;
use super::{
    components, euler, repair, windows, RepairRegion, TopologyMode, TopologyRepair, VoxelizeError,
    VoxelizeOptions, HANDLE_PROBE, HANDLE_PROBE_ANGSTROM,
};
use crate::grid::{human, BlockStore, GridSpec};
use crate::input::Shape;
use crate::math::Idx3;
use crate::progress::Progress;

/// A scratch grid for a closing and the workers that fit beside it.
pub(super) type ClosingGrid<'a> =
    dyn Fn(&str, u32) -> Result<(Box<dyn BlockStore<u8>>, usize), crate::Error> + 'a;

/// What the step needs from the stage.
pub(super) struct Env<'a> {
    pub solid: &'a dyn BlockStore<u8>,
    pub opts: &'a VoxelizeOptions,
    pub shape: &'a Shape,
    pub spec: &'a GridSpec,
    pub source_name: &'a str,
    pub surface: Option<SurfaceTopology>,
    pub w_ccl: usize,
    pub ccl_limit: u64,
    /// Bytes the repair may hold.
    pub room: u64,
    pub progress: &'a dyn Progress,
}

/// The topology of the solid the stage goes on with.
pub(super) struct Settled {
    pub components: u64,
    pub genus: i64,
    pub chi: i64,
    pub pieces_removed: u64,
    pub removed_voxels: u64,
    pub handles: Vec<Handle>,
    pub handle_radius: u32,
    pub repair: Option<TopologyRepair>,
}

/// Pieces (after `--keep-largest`) and Euler characteristic of the solid, and the
/// piece sizes, largest first.
fn measure(env: &Env, keep_largest: bool) -> Result<(u64, i64, Vec<u64>, u64, u64), crate::Error> {
    let pieces = components::find(
        env.solid,
        |v| v == 1,
        env.w_ccl,
        env.ccl_limit,
        "voxelize: components",
        env.progress,
    )?;
    if pieces.sizes.is_empty() {
        return Err(VoxelizeError::Empty {
            shape: env.spec.shape,
            spacing: env.spec.spacing,
        }
        .into());
    }
    let (mut pieces_removed, mut removed_voxels) = (0u64, 0);
    if pieces.sizes.len() > 1 && keep_largest {
        let largest = (0..pieces.sizes.len())
            .max_by_key(|&i| (pieces.sizes[i], std::cmp::Reverse(i)))
            .expect("non-empty") as u32;
        pieces_removed = pieces.sizes.len() as u64 - 1;
        removed_voxels = pieces.sizes.iter().sum::<u64>() - pieces.sizes[largest as usize];
        components::rewrite(
            env.solid,
            &pieces,
            |v| v == 1,
            |c, v| if c == largest { v } else { 0 },
            env.w_ccl,
        )?;
    }
    // After --keep-largest exactly one piece is left.
    let ncomp = if pieces_removed > 0 {
        1
    } else {
        pieces.sizes.len() as u64
    };
    let chi = euler::euler_characteristic(env.solid, env.w_ccl)?;
    let mut sizes = pieces.sizes.clone();
    sizes.sort_unstable_by(|a, b| b.cmp(a));
    Ok((ncomp, chi, sizes, pieces_removed, removed_voxels))
}

/// Count pieces and genus, then go on, refuse or repair as the options and the input
/// say. `closing_grid` gives the scratch grid of the handle search; `lap` records a
/// pass's time.
#[allow(clippy::too_many_lines)] // the topology checks and the repair decision read the same counts
pub(super) fn settle(
    env: &Env,
    closing_grid: &ClosingGrid,
    warnings: &mut Vec<String>,
    lap: &mut dyn FnMut(&str),
) -> Result<Settled, crate::Error> {
    let opts = env.opts;
    let (ncomp, chi, sizes, pieces_removed, removed_voxels) = measure(env, opts.keep_largest)?;
    if pieces_removed > 0 {
        warnings.push(format!(
            "kept the largest of {} pieces; removed {removed_voxels} voxels",
            pieces_removed + 1
        ));
    }
    let genus = ncomp as i64 - chi;
    lap("topology");
    let mut out = Settled {
        components: ncomp,
        genus,
        chi,
        pieces_removed,
        removed_voxels,
        handles: Vec::new(),
        handle_radius: 0,
        repair: None,
    };
    if ncomp == 1 && genus == 0 {
        return Ok(out);
    }
    // A mesh whose own surface has handles makes handles that are no artifacts.
    let real_genus = env.surface.map_or(0, |s| s.genus);
    let repair = !opts.allow_genus
        && match opts.topology {
            TopologyMode::Repair => true,
            TopologyMode::Strict => false,
            TopologyMode::Auto => real_genus == 0 || genus <= 0,
        };
    if repair {
        out.repair = Some(run_repair(
            env,
            closing_grid,
            ncomp,
            genus,
            sizes.iter().sum(),
            warnings,
        )?);
        out.components = 1;
        out.genus = 0;
        out.chi = 1;
        lap("repair");
        return Ok(out);
    }

    // Where the handles are: the pieces a closing adds that plug tunnels.
    let spec = env.spec;
    let molecule = matches!(env.shape, Shape::Molecule(_));
    let probe_r = if opts.close > 0 {
        2 * opts.close
    } else if molecule {
        HANDLE_PROBE.max((HANDLE_PROBE_ANGSTROM / spec.spacing).round() as u32)
    } else {
        HANDLE_PROBE
    };
    if genus > 0 && !opts.skip_handle_search {
        let (grid, w) = closing_grid("probe.u8", probe_r)?;
        closing::close(env.solid, &*grid, probe_r, w, env.progress)?;
        out.handles = closing::handles(&*grid, 64, env.w_ccl, env.ccl_limit, env.progress)?;
        out.handle_radius = probe_r;
        lap("handles");
    }
    let handles = &out.handles;
    let closable: i64 = handles.iter().map(|h| h.closes).sum();
    let (by, larger) = if molecule {
        (
            format!(
                "{probe_r} voxels ({} {})",
                f64::from(probe_r) * spec.spacing,
                spec.unit.as_deref().unwrap_or("units")
            ),
            ", or a larger probe, e.g. --probe 1.4,2,3,4 to take the first that gives genus 0",
        )
    } else {
        (format!("{probe_r} voxels"), "")
    };
    let where_ = if opts.skip_handle_search {
        "not searched".to_owned()
    } else if handles.is_empty() {
        format!("a closing by {by} plugs none of them (the tunnels are wider){larger}")
    } else {
        format!(
            "a closing by {by} plugs {closable} of them, at voxel(s) {}{} (pass --close {probe_r}{larger})",
            handles
                .iter()
                .take(5)
                .map(|h| format!("[{}, {}, {}]", h.voxel[0], h.voxel[1], h.voxel[2]))
                .collect::<Vec<_>>()
                .join(", "),
            if handles.len() > 5 { ", ..." } else { "" }
        )
    };
    if !opts.allow_genus {
        let what = if ncomp > 1 {
            format!(
                "{ncomp} separate pieces (voxels: {}{})",
                sizes
                    .iter()
                    .take(5)
                    .map(u64::to_string)
                    .collect::<Vec<_>>()
                    .join(", "),
                if ncomp > 5 { ", ..." } else { "" }
            )
        } else {
            format!("one piece of genus {genus} ({genus} tunnel(s) or handle(s); Euler characteristic {chi}); {where_}")
        };
        let advice = if opts.topology == TopologyMode::Auto {
            format!(
                "the surface itself has genus {real_genus} (by its Euler characteristic), so its handles are real; pass --topology repair to cut or fill them anyway (every change is reported), or --allow-genus to go on with them (streamlines around a handle do not map one-to-one)"
            )
        } else if ncomp > 1 {
            "use --topology repair to drop the small pieces and cut or fill handles, --keep-largest to keep the largest piece, a coarser --resolution to join them, or --allow-genus to go on anyway".to_owned()
        } else {
            "use --topology repair to cut or fill the handles (every change is reported), repair the shape, try a coarser --resolution (it can close thin tunnels), or pass --allow-genus to go on anyway (streamlines around a handle do not map one-to-one)".to_owned()
        };
        return Err(VoxelizeError::Topology(format!(
            "{}: the voxel solid is not a single genus-0 piece: found {what}; harmap maps genus-0 solids; {advice}",
            env.source_name
        ))
        .into());
    }
    warnings.push(format!(
        "the solid has {ncomp} piece(s) and genus {genus}; going on because of --allow-genus"
    ));
    if genus > 0 {
        warnings.push(format!("handles: {where_}"));
    }
    Ok(out)
}

/// Rounds of windowed repair before the whole-grid fallback.
const MAX_ROUNDS: usize = 12;

/// The largest grid the repair takes whole (after the windows), in voxels: 8 Mi voxels,
/// 128 MiB at [`repair::BYTES_PER_VOXEL`]. Fixed, so that the result never depends on
/// `--mem`.
const WHOLE_GRID_VOXELS: u64 = 1 << 23;

/// The largest grid the repair takes whole when the windows and the larger closings
/// leave handles (on larger grids that is a refusal): 32 Mi voxels, 768 MiB at
/// [`repair::BYTES_PER_VOXEL`], refused with "give more --mem" when `--mem` leaves less.
/// Fixed, so that the result never depends on `--mem`: it is this repair or a refusal.
const WHOLE_GRID_FALLBACK_VOXELS: u64 = 1 << 25;

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

/// Drop every piece but the largest (the first of equals) and fill the background's
/// cavities; returns the solid's Euler characteristic afterwards.
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
    let bg = background(env)?;
    if bg.touches_border.iter().any(|&t| !t) {
        let outside = &bg.touches_border;
        for (c, &n) in bg.sizes.iter().enumerate() {
            if !outside[c] {
                tally.added += n;
            }
        }
        components::rewrite(
            env.solid,
            &bg,
            |v| v != 1,
            |c, v| if outside[c as usize] { v } else { 1 },
            env.w_ccl,
        )?;
    }
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
fn probe_radius(env: &Env) -> u32 {
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
    let (grid, w) = closing_grid("repair.u8", probe)?;
    closing::close(env.solid, &*grid, probe, w, env.progress)?;
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
    // The mesh, when the input is one: the depths the growths follow.
    let surface = match env.shape {
        Shape::Mesh(m) => Some((m, env.spec)),
        _ => None,
    };
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
fn run_repair(
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
    // The largest closing tried, and the one that did not fit in --mem if that ended
    // the ladder.
    let mut tried = probe;
    let mut too_big: Option<(u32, String)> = None;
    // A grid this small is repaired whole when windows around the voxel-scale handles
    // leave some; a larger one tries larger closings and windows first.
    let whole_grid = env.spec.num_voxels() <= WHOLE_GRID_VOXELS;
    let mut chi = tidy(env, &mut tally)?;
    let chi_tidy = chi;
    let mut windowed = Tally::default();
    let mut history = Vec::new();
    for _ in 0..MAX_ROUNDS {
        if chi == 1 {
            break;
        }
        let removed = match round(env, closing_grid, probe, &mut windowed, &mut history) {
            Ok(n) => n,
            // A closing larger than the first that does not fit in --mem ends the
            // ladder: the refusal below says what is left, not that the budget is short.
            Err(crate::Error::Grid(crate::grid::GridError::Budget { needed, .. }))
                if probe > first_probe =>
            {
                too_big = Some((probe, needed));
                break;
            }
            Err(e) => return Err(e),
        };
        tried = probe;
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
        // Handles the windows did not remove: the whole grid, when it fits.
        let need = env.spec.num_voxels() * repair::BYTES_PER_VOXEL;
        if env.spec.num_voxels() > WHOLE_GRID_FALLBACK_VOXELS {
            let budget = too_big.as_ref().map_or(String::new(), |(r, needed)| {
                format!(
                    " (a closing by {r} voxels would need {needed}, more than --mem {})",
                    env.opts.mem
                )
            });
            return Err(VoxelizeError::Topology(format!(
                "{}: the voxel solid has {ncomp} piece(s) and genus {genus}; the repair in windows around the handles (found by closings of up to {tried} voxels{budget}) left genus {}: tunnels too wide for a local repair, on a grid of {} voxels, more than the {} the repair takes whole; use --close VOXELS, a coarser grid, or --topology strict / --allow-genus",
                env.source_name,
                1 - chi,
                env.spec.num_voxels(),
                WHOLE_GRID_FALLBACK_VOXELS
            ))
            .into());
        }
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
        // From the solid before the windows: the whole-grid repair replaces them.
        for (origin, wshape, before) in history.iter().rev() {
            windows::write_window(env.solid, *origin, *wshape, before)?;
        }
        windowed = Tally::default();
        chi = chi_tidy;
        let surface = match env.shape {
            Shape::Mesh(m) => Some((m, env.spec)),
            _ => None,
        };
        let o = repair::repair(env.solid, surface)?;
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

/// One line on what a repair did, e.g. "genus 2 -> 0 by cutting 2 handles (14 voxels
/// removed), 1 speck dropped (2 voxels); largest change: 9 voxels removed at voxel [..]".
#[must_use]
pub fn summary(r: &TopologyRepair) -> String {
    let mut parts = Vec::new();
    if r.handles_cut > 0 {
        parts.push(format!("{} handle(s) cut", r.handles_cut));
    }
    if r.handles_filled > 0 {
        parts.push(format!("{} tunnel(s) filled", r.handles_filled));
    }
    if r.specks_dropped > 0 {
        parts.push(format!(
            "{} speck(s) dropped ({} voxels)",
            r.specks_dropped, r.speck_voxels
        ));
    }
    let largest = r
        .regions
        .iter()
        .take(3)
        .map(|g| {
            format!(
                "{} {} at voxel [{}, {}, {}] ({:.4}, {:.4}, {:.4})",
                g.voxels,
                g.kind,
                g.voxel[0],
                g.voxel[1],
                g.voxel[2],
                g.position[0],
                g.position[1],
                g.position[2]
            )
        })
        .collect::<Vec<_>>()
        .join("; ");
    format!(
        "{} piece(s), genus {} -> one genus-0 piece by {}: {}; {} voxels removed, {} added ({:.3}% of the solid; the other way would change {}){}",
        r.components_before,
        r.genus_before,
        r.method,
        if parts.is_empty() {
            "no handle".to_owned()
        } else {
            parts.join(", ")
        },
        r.voxels_removed,
        r.voxels_added,
        100.0 * r.fraction,
        if r.alternative_voxels == u64::MAX {
            "-".to_owned()
        } else {
            r.alternative_voxels.to_string()
        },
        if largest.is_empty() {
            String::new()
        } else {
            format!("; largest: {largest}")
        }
    )
}
