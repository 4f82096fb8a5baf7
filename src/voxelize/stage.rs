//! The stage itself: the passes of [`super`] in order, each within the memory budget.

use std::time::Instant;

use super::center_ball::check_center_ball;
use super::prepare::{self, Prepared};
use super::{
    center, classify, closing, components, cuts, mol_cuts, scratch_grid, spheres, topology,
    CenterBall, InsideRule, VoxelizeError, VoxelizeOptions, VoxelizeReport,
};
use crate::grid::{Compression, Decomposition, Whole};
use crate::input::Shape;
use crate::math::Vec3;
use crate::progress::Progress;
use crate::run::RunDir;

/// Voxelize `shape` into the run directory `run` (which must be new): writes
/// `labels/0` and returns the report. The caller records it in the run's attributes.
pub fn voxelize(
    shape: &Shape,
    source_name: &str,
    opts: &VoxelizeOptions,
    run: &RunDir,
    progress: &dyn Progress,
) -> Result<VoxelizeReport, crate::Error> {
    voxelize_on(shape, source_name, opts, run, progress, &Whole)
}

/// [`voxelize`] on rank 0 of the MPI ranks `decomp`: the other ranks compute their
/// slabs of the solid pass ([`super::serve_ranks`]); the other passes run here alone.
/// The caller ends the other ranks' service ([`super::ranks_done`]) when done.
#[allow(clippy::too_many_lines)] // the stage's passes in order; each pass is a call, the rest is their bookkeeping
pub fn voxelize_on(
    shape: &Shape,
    source_name: &str,
    opts: &VoxelizeOptions,
    run: &RunDir,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<VoxelizeReport, crate::Error> {
    let mut timings = Vec::new();
    let mut warnings = Vec::new();
    let mut t = Instant::now();
    let mut lap = |name: &str, t: &mut Instant| {
        timings.push((name.to_owned(), t.elapsed().as_secs_f64()));
        *t = Instant::now();
    };
    if opts.chunk < 8 || opts.chunk > 512 {
        return Err(VoxelizeError::Options(format!(
            "chunk edge {} must be between 8 and 512 voxels",
            opts.chunk
        ))
        .into());
    }
    if !(opts.center_radius.is_finite() && opts.center_radius >= 0.0) {
        return Err(VoxelizeError::Options(format!(
            "--center-radius must be >= 0, got {}",
            opts.center_radius
        ))
        .into());
    }
    let Prepared {
        spec,
        rule,
        shape_bytes,
        surface,
    } = prepare::prepare(shape, source_name, opts, &mut warnings)?;
    let threads = rayon::current_num_threads();
    let c = opts.chunk;
    let plane = spec.shape[1] * spec.shape[2];
    // The solid occupancy lives in memory when it fits in half of what the budget leaves
    // beside the shape, else in an uncompressed scratch file; both give the
    // same labels. What stays resident through every pass is charged to each of them.
    let in_memory = opts
        .scratch
        .in_memory(spec.num_voxels(), opts.mem, shape_bytes);
    let held = shape_bytes + if in_memory { spec.num_voxels() } else { 0 };
    let input_chunk = match shape {
        // A block may overlap up to 8 chunks of the input array, each decoded whole.
        Shape::Volume(v) => 8 * v.chunk_bytes(),
        Shape::Mesh(_) | Shape::Molecule(_) => 0,
    };
    let what = |s: &str| {
        if in_memory {
            format!("{s} (with the solid grid in memory; --scratch disk needs less)")
        } else {
            s.to_owned()
        }
    };
    // A molecule's block: the atoms' states and, for the SES, the probe band's transform.
    let molecule_block = match shape {
        Shape::Molecule(_) => {
            c * c * c
                + if opts.surface == spheres::MolSurface::Ses {
                    super::probe_band::worker_bytes(c, opts.probe, spec.spacing)
                } else {
                    0
                }
        }
        Shape::Mesh(_) | Shape::Volume(_) => 0,
    };
    let w_solid = opts.mem.workers(
        &what("the inside test of one block column"),
        held,
        (c * c * spec.shape[2] * 2 + c * c * 16).max(c * c * c + input_chunk + molecule_block),
        threads,
    )?;
    let w_ccl = opts.mem.workers(
        &what("component labelling of one block"),
        held,
        6 * c * c * c,
        threads,
    )?;
    let w_label = opts.mem.workers(
        &what("labelling one block"),
        held,
        super::label_worker_bytes(c),
        threads,
    )?;
    opts.mem.workers(
        &what("the distance transform (a few slices)"),
        held,
        40 * plane,
        1,
    )?;
    // What the component passes may keep beyond their workers' blocks.
    let ccl_limit = opts
        .mem
        .work_bytes()
        .saturating_sub(held + w_ccl as u64 * 6 * c * c * c);
    for w in [w_solid, w_ccl, w_label] {
        if w < threads {
            progress.info(&format!(
                "memory budget {} allows {w} of {threads} workers in some passes",
                opts.mem
            ));
        }
    }

    let scratch_dir = run.root().join(".scratch");
    let solid = scratch_grid(&scratch_dir, &spec, in_memory, "solid.u8")?;
    let solid = &*solid;

    // 1. Solid occupancy (on MPI ranks, each rank's slab).
    let solid_pass = super::ranks::solid(shape, rule, opts, solid, w_solid, progress, decomp)?;
    let unclosed = solid_pass.unclosed;
    if unclosed > 0 {
        warnings.push(format!(
            "{source_name}: {unclosed} rows of voxels crossed the surface an unbalanced number of times (coincident or self-intersecting faces); check the labels near them"
        ));
    }
    let probe_cavities = solid_pass.probe_cavities;
    lap("solid", &mut t);

    // 1b. Closing (before the cavities: a closing can shut the mouth of a pocket).
    // A second grid for a closing, and the workers that fit beside both grids.
    let closing_grid = |name: &str, r: u32| -> Result<_, crate::Error> {
        let mem = opts.scratch.in_memory(spec.num_voxels(), opts.mem, held);
        let grid = scratch_grid(&scratch_dir, &spec, mem, name)?;
        let fixed = held + if mem { spec.num_voxels() } else { 0 };
        let workers = opts.mem.workers(
            &what(&format!("closing one block by {r} voxels")),
            fixed,
            closing::worker_bytes(c, r),
            threads,
        )?;
        Ok((grid, workers, opts.mem.work_bytes().saturating_sub(fixed)))
    };
    let mut closing_voxels = 0;
    if opts.close > 0 {
        let (out, w, room) = closing_grid("closed.u8", opts.close)?;
        closing_voxels = closing::close(solid, &*out, opts.close, w, room, progress)?;
        closing::apply(solid, &*out, w)?;
        lap("closing", &mut t);
    }

    // 2. Fill enclosed cavities: background components that do not reach the grid faces.
    let bg = components::find(
        solid,
        |v| v != 1,
        w_ccl,
        ccl_limit,
        "voxelize: cavities",
        progress,
    )?;
    let cavities: Vec<u32> = (0..bg.sizes.len() as u32)
        .filter(|&c| !bg.touches_border[c as usize])
        .collect();
    let cavity_voxels: u64 = cavities.iter().map(|&c| bg.sizes[c as usize]).sum();
    if !cavities.is_empty() {
        let outside = &bg.touches_border;
        components::rewrite(
            solid,
            &bg,
            |v| v != 1,
            |c, v| if outside[c as usize] { v } else { 1 },
            w_ccl,
        )?;
    }
    drop(bg);
    lap("cavities", &mut t);

    // 3. Pieces and genus; refused, repaired or let go as the options say.
    let env = topology::Env {
        solid,
        opts,
        shape,
        spec: &spec,
        source_name,
        surface,
        w_ccl,
        ccl_limit,
        room: opts.mem.work_bytes().saturating_sub(held),
        scratch: &scratch_dir,
        progress,
    };
    let settled = topology::settle(&env, &closing_grid, &mut warnings, &mut |n| {
        lap(n, &mut t);
    })?;

    // 4. Center: the deepest voxel, or the one given (whose depth the same streamed
    // distance transform measures).
    let user_voxel = match opts.center {
        None => None,
        Some(p) => {
            let p = Vec3::from_array(p);
            Some(spec.nearest_voxel(p).ok_or_else(|| {
                VoxelizeError::Center(format!(
                    "--center {},{},{} lies outside the grid; give a point inside the shape",
                    p.x, p.y, p.z
                ))
            })?)
        }
    };
    let deep = center::deepest_voxel(solid, &scratch_dir.join("zdist.u16"), user_voxel, progress)?;
    let (center_voxel, depth) = match user_voxel {
        None => (deep.voxel, deep.depth),
        Some(v) => (v, deep.query_depth.unwrap_or(0.0)),
    };
    if depth == 0.0 {
        let p = spec.voxel_center(center_voxel);
        return Err(VoxelizeError::Center(format!(
            "--center {},{},{} is not inside the solid (voxel [{}, {}, {}] is outside); give a point well inside the shape",
            p.x, p.y, p.z, center_voxel[0], center_voxel[1], center_voxel[2]
        ))
        .into());
    }
    check_center_ball(solid, center_voxel, opts.center_radius, depth)?;
    lap("center", &mut t);

    // 5. Labels.
    let labels = run.create_image::<u8>("labels", &spec, 0, Compression::Zstd(3))?;
    let ball = CenterBall::at_voxel(center_voxel, opts.center_radius);
    let counts = classify::classify(solid, &labels, ball, w_label, progress)?;
    lap("labels", &mut t);
    // 6. Where the surface crosses the stencil's arms, for the solve's sub-voxel
    // boundary (meshes and molecules; a label volume keeps the staircase).
    let cut_worker = match shape {
        Shape::Mesh(_) => Some(cuts::worker_bytes(c)),
        Shape::Molecule(_) => {
            Some(cuts::worker_bytes(c) + mol_cuts::worker_bytes(c, spec.spacing, opts.surface))
        }
        Shape::Volume(_) => None,
    };
    if let Some(bytes) = cut_worker {
        let w_cuts = opts.mem.workers(
            &what("the boundary crossings of one block"),
            held,
            bytes,
            threads,
        )?;
        let store = run.create_image::<u64>(cuts::NAME, &spec, 0, Compression::Zstd(3))?;
        let (_, missed) = match shape {
            Shape::Mesh(mesh) => cuts::mesh_cuts(mesh, &labels, ball, &store, w_cuts, progress)?,
            Shape::Molecule(m) => mol_cuts::molecule_cuts(
                m,
                opts.surface,
                opts.probe,
                solid_pass.probes.as_ref(),
                &labels,
                ball,
                &store,
                w_cuts,
                progress,
            )?,
            Shape::Volume(_) => (0, 0),
        };
        if missed > 0 {
            let what = match shape {
                Shape::Mesh(_) => "met no triangle (voxels the closing or the repair added)",
                _ => "met no molecular surface (voxels the closing, the cavity fill or the repair added)",
            };
            warnings.push(format!(
                "{missed} stencil arms from the solid to the exterior {what}; the solve holds phi = 1 at those neighbours' centers"
            ));
        }
        lap("crossings", &mut t);
    }
    let _ = std::fs::remove_dir_all(&scratch_dir);

    Ok(VoxelizeReport {
        center: spec.voxel_center(center_voxel).to_array(),
        grid: spec,
        counts,
        center_voxel,
        center_depth: depth,
        inside_rule: rule.map_or("volume", InsideRule::name).to_owned(),
        euler_characteristic: settled.chi,
        components: settled.components,
        genus: settled.genus,
        cavities_filled: cavities.len() as u64,
        cavity_voxels,
        probe_cavities,
        pieces_removed: settled.pieces_removed,
        removed_voxels: settled.removed_voxels,
        closing_voxels,
        handles: settled.handles,
        handle_radius: settled.handle_radius,
        probe_trials: Vec::new(),
        surface_topology: surface.map(|s| (s.parts, s.genus)),
        repair: settled.repair,
        warnings,
        timings,
    })
}
