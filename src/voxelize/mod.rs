//! Voxelization: a shape -> the labelled grid of the run, with the shape center.
//!
//! Passes, each block by block within the memory budget (nothing holds a whole grid):
//! 1. solid occupancy into an uncompressed scratch grid ([`scanline`] for surfaces,
//!    [`from_volume`] for label volumes);
//! 2. enclosed background (cavities) filled ([`components`] on the background);
//! 3. pieces of the solid counted ([`components`] on the solid), and the Euler
//!    characteristic ([`euler`]) gives the genus;
//! 4. the center: the deepest voxel ([`center`]) or `--center`;
//! 5. the labels written to `RUN/labels/0` ([`classify`]).

mod center;
mod classify;
pub mod closing;
mod components;
mod error;
mod euler;
mod from_volume;
mod grid_fit;
mod scanline;
pub mod solvent;
pub mod spheres;
mod standard;

use std::time::Instant;

use serde::{Deserialize, Serialize};

pub use classify::CenterBall;
pub use error::VoxelizeError;
pub use grid_fit::{fit_bbox, fit_volume, DEFAULT_RESOLUTION, MAX_AXIS, MAX_VOXELS, MIN_PADDING};
pub use scanline::InsideRule;
pub use standard::{standard_ball, StandardBall};

use crate::grid::{BlockStore, Compression, GridSpec, MemBudget, MemStore, MmapStore};
use crate::input::Shape;
use crate::math::{Idx3, Vec3};
use crate::progress::Progress;
use crate::run::RunDir;

/// Label values of `RUN/labels/0`.
pub mod labels {
    /// Outside the solid and its four exterior layers.
    pub const EXTERIOR: u8 = 0;
    /// Solid voxel with a non-solid 6-neighbour (phi = 1).
    pub const BOUNDARY: u8 = 1;
    /// Solid voxel whose 6 neighbours are solid (phi unknown).
    pub const INTERIOR: u8 = 2;
    /// Interior voxel of the center ball (phi = 0).
    pub const CENTER: u8 = 3;
    /// First exterior layer (phi = 1 + eps); layers 2..4 are 5..7 (phi = 1 + k eps).
    pub const LAYER1: u8 = 4;
    /// Names of the label values, for reports.
    pub const NAMES: [&str; 8] = [
        "exterior", "boundary", "interior", "center", "layer1", "layer2", "layer3", "layer4",
    ];
}

/// Options of `harmap voxelize`. Stored verbatim in the run's metadata.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VoxelizeOptions {
    /// Voxels along the longest side of the shape's bounding box.
    pub resolution: Option<u64>,
    /// Voxel size in world units (instead of `resolution`).
    pub spacing: Option<f64>,
    /// Voxels added on every side (at least 5).
    pub padding: u64,
    /// Shape center in world coordinates (x, y, z); default: the deepest voxel.
    pub center: Option<[f64; 3]>,
    /// Radius (voxels) of the center ball where phi = 0.
    pub center_radius: f64,
    /// Go on when the solid is not one genus-0 piece.
    pub allow_genus: bool,
    /// Keep only the largest piece when the solid has several.
    pub keep_largest: bool,
    /// Block (chunk) edge in voxels.
    pub chunk: u64,
    /// Memory budget.
    pub mem: MemBudget,
    /// Unit of world coordinates (an OME-Zarr unit name), if known.
    pub unit: Option<String>,
    /// Where the intermediate solid grid lives.
    pub scratch: Scratch,
    /// Molecules: which solid (vdW, SAS or SES).
    #[serde(default)]
    pub surface: spheres::MolSurface,
    /// Molecules: the probe radius of SAS and SES (Angstrom).
    #[serde(default = "default_probe")]
    pub probe: f64,
    /// Close the solid by a ball of this many voxels before the topology check (0: no).
    #[serde(default)]
    pub close: u32,
    /// Molecules (SAS and SES): larger probe radii to try in turn, Angstrom, while the
    /// solid at `probe` is not one genus-0 piece (see
    /// [`crate::pipeline::voxelize_new_run`]).
    #[serde(default)]
    pub probe_ladder: Vec<f64>,
    /// Skip the search for where handles are (the probe ladder's trials that a larger
    /// probe follows).
    #[serde(skip)]
    pub skip_handle_search: bool,
}

fn default_probe() -> f64 {
    1.4
}

/// Where intermediate grids live.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scratch {
    /// In memory when the grid (one byte a voxel) fits in half the budget, else on disk.
    #[default]
    Auto,
    /// Always in memory.
    Memory,
    /// Always in a memory-mapped file, read and written block by block.
    Disk,
}

impl Scratch {
    /// Whether a grid of `voxels` bytes is kept in memory under `mem`, next to `held`
    /// bytes that stay resident anyway (the input shape).
    #[must_use]
    pub fn in_memory(self, voxels: u64, mem: MemBudget, held: u64) -> bool {
        match self {
            Scratch::Auto => voxels <= mem.work_bytes().saturating_sub(held) / 2,
            Scratch::Memory => true,
            Scratch::Disk => false,
        }
    }
}

impl Default for VoxelizeOptions {
    fn default() -> Self {
        Self {
            resolution: None,
            spacing: None,
            padding: 6,
            center: None,
            center_radius: 2.0,
            allow_genus: false,
            keep_largest: false,
            chunk: 64,
            mem: MemBudget::default(),
            unit: None,
            scratch: Scratch::Auto,
            surface: spheres::MolSurface::Ses,
            probe: 1.4,
            close: 0,
            probe_ladder: Vec::new(),
            skip_handle_search: false,
        }
    }
}

/// What voxelization found. Stored in the run's metadata.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VoxelizeReport {
    /// The grid.
    pub grid: GridSpec,
    /// Voxels per label value 0..=7 (see [`labels`]).
    pub counts: [u64; 8],
    /// The center voxel `[z, y, x]`.
    pub center_voxel: Idx3,
    /// The center in world coordinates `(x, y, z)`.
    pub center: [f64; 3],
    /// Distance (voxels) from the center voxel to the nearest non-solid voxel.
    pub center_depth: f64,
    /// How inside was decided: "winding", "parity" or "volume".
    pub inside_rule: String,
    /// Euler characteristic of the final solid (6-connectivity).
    pub euler_characteristic: i64,
    /// 6-connected pieces of the final solid.
    pub components: u64,
    /// Genus (number of tunnels) of the final solid.
    pub genus: i64,
    /// Enclosed cavities filled, and their voxels.
    pub cavities_filled: u64,
    /// Voxels added by filling cavities.
    pub cavity_voxels: u64,
    /// SES: cavities of the probe-center space (room for a probe that cannot get in
    /// from the solvent), whose probes were left out, so they are solid already.
    #[serde(default)]
    pub probe_cavities: u64,
    /// Pieces removed by `keep_largest`, and their voxels.
    pub pieces_removed: u64,
    /// Voxels removed by `keep_largest`.
    pub removed_voxels: u64,
    /// Voxels added by `--close`.
    #[serde(default)]
    pub closing_voxels: u64,
    /// Where handles are, when the genus is above 0: places where a closing (by
    /// [`HANDLE_PROBE`] voxels, [`HANDLE_PROBE_ANGSTROM`] for molecules, or twice
    /// `--close`) would plug tunnels.
    #[serde(default)]
    pub handles: Vec<closing::Handle>,
    /// The radius (voxels) of the closing that located `handles`.
    #[serde(default)]
    pub handle_radius: u32,
    /// Molecules: the probes tried (`--probe` with several radii), in order, and what
    /// each gave; the last one made this solid.
    #[serde(default)]
    pub probe_trials: Vec<ProbeTrial>,
    /// Warnings given.
    pub warnings: Vec<String>,
    /// Seconds per pass.
    pub timings: Vec<(String, f64)>,
}

impl VoxelizeReport {
    /// For a probe ladder: which probe made the solid one genus-0 piece, and what the
    /// others gave, e.g. "genus 0 at probe 3 Angstrom (tried 1.4: genus 156; 2: genus
    /// 60)". `None` when one probe was given.
    #[must_use]
    pub fn probe_summary(&self) -> Option<String> {
        probe_summary(&self.probe_trials)
    }
}

/// What [`VoxelizeReport::probe_summary`] says of these trials.
#[must_use]
pub fn probe_summary(trials: &[ProbeTrial]) -> Option<String> {
    {
        let (kept, tried) = trials.split_last()?;
        let what = |t: &ProbeTrial| {
            if t.components > 1 {
                format!("{}: {} pieces, genus {}", t.probe, t.components, t.genus)
            } else {
                format!("{}: genus {}", t.probe, t.genus)
            }
        };
        let tried: Vec<String> = tried.iter().map(what).collect();
        let tried = if tried.is_empty() {
            String::new()
        } else {
            format!(" (tried {})", tried.join("; "))
        };
        Some(if kept.genus == 0 && kept.components == 1 {
            format!("genus 0 at probe {} Angstrom{tried}", kept.probe)
        } else {
            format!(
                "no probe gave one genus-0 piece{tried}; kept probe {} Angstrom ({})",
                kept.probe,
                what(kept)
            )
        })
    }
}

/// Radius (voxels) of the closing that locates handles when `--close` is not given.
pub const HANDLE_PROBE: u32 = 3;

/// For molecules, the same radius in Angstrom (so that it means the same at any
/// spacing: at 0.25 Angstrom, 3 voxels are 0.75 Angstrom, narrower than any tunnel a
/// 1.4 Angstrom probe leaves). Never below [`HANDLE_PROBE`] voxels.
pub const HANDLE_PROBE_ANGSTROM: f64 = 3.0;

/// One probe radius tried for a molecule, and the topology it gave.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeTrial {
    /// Probe radius, Angstrom.
    pub probe: f64,
    /// Genus of the solid.
    pub genus: i64,
    /// Pieces of the solid left (after `--keep-largest`).
    pub components: u64,
}

/// Bytes a worker of the label pass holds (haloed block, distances, output, codec).
pub(crate) fn label_worker_bytes(chunk: u64) -> u64 {
    let h = chunk + 2 * classify::HALO as u64;
    3 * h * h * h + 3 * chunk * chunk * chunk
}

/// Voxelize `shape` into the run directory `run` (which must be new): writes
/// `labels/0` and returns the report. The caller records it in the run's attributes.
pub fn voxelize(
    shape: &Shape,
    source_name: &str,
    opts: &VoxelizeOptions,
    run: &RunDir,
    progress: &dyn Progress,
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
    let (mut spec, rule, shape_bytes) = match shape {
        Shape::Mesh(mesh) => {
            let topo = mesh.topology();
            if !topo.is_closed() {
                let odd = if topo.odd_edges > 0 {
                    format!(
                        " and {} more are used by an odd number of triangles",
                        topo.odd_edges
                    )
                } else {
                    String::new()
                };
                return Err(VoxelizeError::OpenSurface {
                    path: source_name.to_owned(),
                    boundary_edges: topo.boundary_edges,
                    example: topo.example_open_edge.unwrap_or([0, 0]),
                    odd,
                }
                .into());
            }
            let rule = if topo.is_oriented_closed() {
                InsideRule::Winding
            } else {
                warnings.push(format!(
                    "{source_name}: the triangles are not consistently oriented ({} edges are used twice in the same direction); inside is decided by crossing parity",
                    topo.unbalanced_edges
                ));
                InsideRule::Parity
            };
            if topo.nonmanifold_edges > 0 {
                warnings.push(format!(
                    "{source_name}: {} edges are shared by more than two triangles (non-manifold); overlapping parts are taken as their union",
                    topo.nonmanifold_edges
                ));
            }
            if topo.degenerate > 0 {
                warnings.push(format!(
                    "{source_name}: {} degenerate triangles (repeated vertex) skipped",
                    topo.degenerate
                ));
            }
            let (lo, hi) = mesh
                .bbox()
                .ok_or_else(|| VoxelizeError::Options(format!("{source_name}: no triangles")))?;
            let bytes = mesh.vertices.len() as u64 * 24 + mesh.triangles.len() as u64 * 160;
            (fit_bbox(lo, hi, opts)?, Some(rule), bytes)
        }
        Shape::Volume(v) => (fit_volume(v.shape(), opts)?, None, 0),
        Shape::Molecule(m) => {
            if !(opts.probe.is_finite() && opts.probe > 0.0) {
                return Err(VoxelizeError::Options(format!(
                    "--probe {}: give a positive radius",
                    opts.probe
                ))
                .into());
            }
            let grow = if opts.surface == spheres::MolSurface::Vdw {
                0.0
            } else {
                opts.probe
            };
            let mut lo = Vec3::splat(f64::INFINITY);
            let mut hi = Vec3::splat(f64::NEG_INFINITY);
            for a in &m.atoms {
                lo = lo.min(a.pos - Vec3::splat(a.radius + grow));
                hi = hi.max(a.pos + Vec3::splat(a.radius + grow));
            }
            (fit_bbox(lo, hi, opts)?, None, m.atoms.len() as u64 * 200)
        }
    };
    if let Shape::Molecule(m) = shape {
        if spec.unit.is_none() && m.format != "points" {
            spec.unit = Some("angstrom".into());
        }
        warnings.extend(m.warnings.iter().cloned());
        if !m.left_out.is_empty() {
            warnings.push(format!(
                "left out (hetero groups; --keep-hetatm keeps all but water): {}",
                crate::input::molecule::summary(&m.left_out)
            ));
        }
        if !m.hetero_kept.is_empty() {
            warnings.push(format!(
                "hetero groups kept: {}",
                crate::input::molecule::summary(&m.hetero_kept)
            ));
        }
    }
    let threads = rayon::current_num_threads();
    let c = opts.chunk;
    let plane = spec.shape[1] * spec.shape[2];
    // The solid occupancy lives in memory when it fits in half of what the budget leaves
    // beside the shape, else in an uncompressed memory-mapped scratch file; both give the
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
    let w_solid = opts.mem.workers(
        &what("the inside test of one block column"),
        held,
        (c * c * spec.shape[2] * 2 + c * c * 16).max(c * c * c + input_chunk),
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
        label_worker_bytes(c),
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

    // 1. Solid occupancy.
    let mut probe_cavities = 0;
    match (shape, rule) {
        (Shape::Mesh(mesh), Some(rule)) => {
            let unclosed = scanline::mesh_solid(mesh, rule, solid, w_solid, progress)?;
            if unclosed > 0 {
                warnings.push(format!(
                    "{source_name}: {unclosed} rows of voxels crossed the surface an unbalanced number of times (coincident or self-intersecting faces); check the labels near them"
                ));
            }
        }
        (Shape::Volume(v), _) => {
            from_volume::volume_solid(v, opts.padding, solid, w_solid, progress)?;
        }
        (Shape::Molecule(m), _) => {
            let cav =
                spheres::molecule_solid(m, opts.surface, opts.probe, solid, w_solid, progress)?;
            probe_cavities = cav.count;
        }
        (Shape::Mesh(_), None) => unreachable!("meshes always get a rule"),
    }
    lap("solid", &mut t);

    // 1b. Closing (before the cavities: a closing can shut the mouth of a pocket).
    // A second grid for a closing, and the workers that fit beside both grids.
    let closing_grid = |name: &str, r: u32| -> Result<_, crate::Error> {
        let mem = opts.scratch.in_memory(spec.num_voxels(), opts.mem, held);
        let grid = scratch_grid(&scratch_dir, &spec, mem, name)?;
        let workers = opts.mem.workers(
            &what(&format!("closing one block by {r} voxels")),
            held + if mem { spec.num_voxels() } else { 0 },
            closing::worker_bytes(c, r),
            threads,
        )?;
        Ok((grid, workers))
    };
    let mut closing_voxels = 0;
    if opts.close > 0 {
        let (out, w) = closing_grid("closed.u8", opts.close)?;
        closing_voxels = closing::close(solid, &*out, opts.close, w, progress)?;
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

    // 3. Pieces and genus.
    let pieces = components::find(
        solid,
        |v| v == 1,
        w_ccl,
        ccl_limit,
        "voxelize: components",
        progress,
    )?;
    if pieces.sizes.is_empty() {
        return Err(VoxelizeError::Empty {
            shape: spec.shape,
            spacing: spec.spacing,
        }
        .into());
    }
    let (mut pieces_removed, mut removed_voxels) = (0u64, 0);
    if pieces.sizes.len() > 1 && opts.keep_largest {
        let largest = (0..pieces.sizes.len())
            .max_by_key(|&i| (pieces.sizes[i], std::cmp::Reverse(i)))
            .expect("non-empty") as u32;
        pieces_removed = pieces.sizes.len() as u64 - 1;
        removed_voxels = pieces.sizes.iter().sum::<u64>() - pieces.sizes[largest as usize];
        components::rewrite(
            solid,
            &pieces,
            |v| v == 1,
            |c, v| if c == largest { v } else { 0 },
            w_ccl,
        )?;
        warnings.push(format!(
            "kept the largest of {} pieces; removed {removed_voxels} voxels",
            pieces_removed + 1
        ));
    }
    // After --keep-largest exactly one piece is left.
    let ncomp = if pieces_removed > 0 {
        1
    } else {
        pieces.sizes.len() as u64
    };
    let chi = euler::euler_characteristic(solid, w_ccl)?;
    let genus = ncomp as i64 - chi;
    lap("topology", &mut t);
    // Where the handles are: the pieces a closing adds that plug tunnels.
    let mut handles = Vec::new();
    let probe_r = if opts.close > 0 {
        2 * opts.close
    } else if matches!(shape, Shape::Molecule(_)) {
        HANDLE_PROBE.max((HANDLE_PROBE_ANGSTROM / spec.spacing).round() as u32)
    } else {
        HANDLE_PROBE
    };
    if genus > 0 && !opts.skip_handle_search {
        let (out, w) = closing_grid("probe.u8", probe_r)?;
        closing::close(solid, &*out, probe_r, w, progress)?;
        handles = closing::handles(&*out, 64, w_ccl, ccl_limit, progress)?;
        lap("handles", &mut t);
    }
    let closable: i64 = handles.iter().map(|h| h.closes).sum();
    let (by, larger) = if matches!(shape, Shape::Molecule(_)) {
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
    if (ncomp > 1 || genus != 0) && !opts.allow_genus {
        let mut sizes = pieces.sizes.clone();
        sizes.sort_unstable_by(|a, b| b.cmp(a));
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
        let advice = if ncomp > 1 {
            "use --keep-largest to keep the largest piece, a coarser --resolution to join them, or --allow-genus to go on anyway"
        } else {
            "repair the shape, try a coarser --resolution (it can close thin tunnels), or pass --allow-genus to go on anyway (streamlines around a handle do not map one-to-one)"
        };
        return Err(VoxelizeError::Topology(format!(
            "{source_name}: the voxel solid is not a single genus-0 piece: found {what}; harmap maps genus-0 solids; {advice}"
        ))
        .into());
    }
    if ncomp > 1 || genus != 0 {
        warnings.push(format!(
            "the solid has {ncomp} piece(s) and genus {genus}; going on because of --allow-genus"
        ));
        if genus > 0 {
            warnings.push(format!("handles: {where_}"));
        }
    }
    drop(pieces);

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
    let _ = std::fs::remove_dir_all(&scratch_dir);

    Ok(VoxelizeReport {
        center: spec.voxel_center(center_voxel).to_array(),
        grid: spec,
        counts,
        center_voxel,
        center_depth: depth,
        inside_rule: rule.map_or("volume", InsideRule::name).to_owned(),
        euler_characteristic: chi,
        components: ncomp,
        genus,
        cavities_filled: cavities.len() as u64,
        cavity_voxels,
        probe_cavities,
        pieces_removed,
        removed_voxels,
        closing_voxels,
        handles,
        handle_radius: if genus > 0 && !opts.skip_handle_search {
            probe_r
        } else {
            0
        },
        probe_trials: Vec::new(),
        warnings,
        timings,
    })
}

/// An intermediate u8 grid: in memory, or the memory-mapped file `name` in `dir` (which
/// is created either way).
pub(crate) fn scratch_grid(
    dir: &std::path::Path,
    spec: &GridSpec,
    in_memory: bool,
    name: &str,
) -> Result<Box<dyn BlockStore<u8>>, crate::Error> {
    // The directory also holds the distance transform's slices, so make it either way.
    std::fs::create_dir_all(dir).map_err(|e| crate::grid::GridError::Io {
        path: dir.to_owned(),
        source: e,
    })?;
    if in_memory {
        return Ok(Box::new(MemStore::<u8>::new(spec.clone(), 0)));
    }
    Ok(Box::new(MmapStore::<u8>::create(
        &dir.join(name),
        spec.clone(),
    )?))
}

/// Check that every voxel of the center ball is solid and not on the boundary, given
/// `depth`, the distance from the center voxel to the nearest non-solid voxel.
///
/// Every voxel closer than `depth` is solid, so a ball with `radius + 1 < depth` is
/// fine and one with `radius >= depth` holds a non-solid voxel. Only in between are
/// the voxels looked at, three slices of the ball's box at a time.
fn check_center_ball(
    solid: &dyn BlockStore<u8>,
    c: Idx3,
    radius: f64,
    depth: f64,
) -> Result<(), crate::Error> {
    let fail = |at: String| -> crate::Error {
        let advice = if radius >= 1.0 {
            "use a smaller --center-radius, another --center, or a finer --resolution"
        } else {
            "use another --center or a finer --resolution"
        };
        VoxelizeError::Center(format!(
            "the center ball (radius {radius} voxels around voxel [{}, {}, {}]) reaches the boundary{at}: the solid is {depth:.1} voxels deep there; {advice}",
            c[0], c[1], c[2]
        ))
        .into()
    };
    if radius + 1.0 < depth {
        return Ok(());
    }
    if radius >= depth {
        return Err(fail(String::new()));
    }
    let r = radius.ceil() as i64 + 1;
    let n = (2 * r + 1) as usize;
    let ball = CenterBall::at_voxel(c, radius);
    let ci = c.map(|v| v as i64);
    for dz in -r + 1..r {
        let slab = solid.read_region([ci[0] + dz - 1, ci[1] - r, ci[2] - r], [3, n, n], 0)?;
        for dy in -r + 1..r {
            for dx in -r + 1..r {
                let g = [ci[0] + dz, ci[1] + dy, ci[2] + dx];
                if !ball.contains(g) {
                    continue;
                }
                let nbrs = [
                    [0, 0, 0],
                    [1, 0, 0],
                    [-1, 0, 0],
                    [0, 1, 0],
                    [0, -1, 0],
                    [0, 0, 1],
                    [0, 0, -1],
                ];
                if nbrs
                    .iter()
                    .any(|d| slab.at_global([g[0] + d[0], g[1] + d[1], g[2] + d[2]]) != 1)
                {
                    return Err(fail(format!(" at voxel [{}, {}, {}]", g[0], g[1], g[2])));
                }
            }
        }
    }
    Ok(())
}
