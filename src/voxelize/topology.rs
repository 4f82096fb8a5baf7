//! The topology step: pieces and genus of the solid, then, when it is not one genus-0
//! piece, what to do: go on (`--allow-genus`), refuse with where the handles are
//! (`--topology strict`, or a mesh whose own surface has handles), or repair
//! ([`super::repair`]) and check the result.
//!
//! What counts as an artifact: for a mesh whose parts are all genus 0 (by the surface's
//! Euler characteristic), every handle and extra piece of the voxel solid comes from the
//! grid; molecules, point sets and label volumes are repaired by default too (their
//! tunnels are real but not what a map onto the ball can show).

use super::closing::{self, Handle};
use super::mesh_genus::SurfaceTopology;
use super::rounds::{self, run_repair};
use super::{components, euler, TopologyMode, TopologyRepair, VoxelizeError, VoxelizeOptions};
use crate::grid::{BlockStore, GridSpec};
use crate::input::Shape;
use crate::progress::Progress;

/// A scratch grid for a closing, the workers that fit beside it, and the bytes the
/// closing may hold ([`closing::close`]'s room).
pub(super) type ClosingGrid<'a> =
    dyn Fn(&str, u32) -> Result<(Box<dyn BlockStore<u8>>, usize, u64), crate::Error> + 'a;

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
    /// Where the repair's scratch files go (the stage's scratch directory).
    pub scratch: &'a std::path::Path,
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
pub(super) fn measure(
    env: &Env,
    keep_largest: bool,
) -> Result<(u64, i64, Vec<u64>, u64, u64), crate::Error> {
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
    let probe_r = rounds::probe_radius(env);
    if genus > 0 && !opts.skip_handle_search {
        let (grid, w, room) = closing_grid("probe.u8", probe_r)?;
        closing::close(env.solid, &*grid, probe_r, w, room, env.progress)?;
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
