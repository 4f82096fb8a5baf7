//! The solid pass on MPI ranks.
//!
//! Rank 0 runs the voxelization. Before each solid pass (one per probe of a ladder) it
//! sends the other ranks what the pass computes: the grid, the options it reads, the
//! inside rule and the workers. Every rank computes the blocks of its slab of block
//! layers ([`Decomposition::z_layers`]) from the input it read itself, and rank 0
//! receives the others' layers, one layer at a time, into its solid grid; the other
//! ranks hold only their slab. The passes after it (cavities, topology, center, labels,
//! crossings) run on rank 0 alone; when it is done it tells the others, which then go
//! on to the solve. In one process the pass is the plain loop over every block.

use serde::{Deserialize, Serialize};

use super::{from_volume, scanline, spheres, InsideRule, VoxelizeOptions};
use crate::grid::{BlockStore, Decomposition, GridError, GridSpec, MemStore};
use crate::input::Shape;
use crate::math::{volume, Idx3};
use crate::progress::Progress;

/// What rank 0 asks of the others.
#[derive(Serialize, Deserialize)]
enum Request {
    /// A solid pass over this grid, with these options.
    Solid {
        spec: GridSpec,
        opts: Box<VoxelizeOptions>,
        rule: Option<InsideRule>,
        workers: usize,
    },
    /// The voxelization is done.
    Done,
}

/// What the solid pass counts beside the solid.
#[derive(Default)]
pub struct SolidCounts {
    /// Rows whose crossings did not sum to zero (meshes; over all ranks).
    pub unclosed: u64,
    /// Cavities of the probe-center space whose probes were left out (the SES).
    pub probe_cavities: u64,
    /// The SES's probe centers as the pass found them, for the boundary crossings
    /// (rank 0 keeps them; the other ranks drop theirs).
    pub probes: Option<spheres::ProbeSpace>,
}

/// The solid of `shape` (1 inside, 0 outside) into `solid`, every block of it: on MPI
/// ranks (`decomp` of more than one part; this is rank 0) each rank computes its slab
/// and sends it here.
pub fn solid(
    shape: &Shape,
    rule: Option<InsideRule>,
    opts: &VoxelizeOptions,
    solid: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<SolidCounts, crate::Error> {
    if decomp.parts() == 1 {
        return solid_blocks(shape, rule, opts, solid, workers, progress, decomp);
    }
    send(
        decomp,
        &Request::Solid {
            spec: solid.spec().clone(),
            opts: Box::new(opts.clone()),
            rule,
            workers,
        },
    )?;
    let mine = solid_blocks(shape, rule, opts, solid, workers, progress, decomp)?;
    gather_layers(solid, decomp)?;
    let unclosed = decomp.sum_u64(&[mine.unclosed])?[0];
    Ok(SolidCounts { unclosed, ..mine })
}

/// Rank 0 is done voxelizing: the other ranks stop serving ([`serve`]).
pub fn done(decomp: &dyn Decomposition) -> Result<(), crate::Error> {
    if decomp.parts() > 1 {
        send(decomp, &Request::Done)?;
    }
    Ok(())
}

/// On a rank other than 0: compute this rank's slab of each solid pass rank 0 asks for,
/// until it is done.
pub fn serve(
    shape: &Shape,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<(), crate::Error> {
    loop {
        match receive(decomp)? {
            Request::Done => return Ok(()),
            Request::Solid {
                spec,
                opts,
                rule,
                workers,
            } => {
                // Only this rank's blocks are ever written here.
                let local = MemStore::new(spec, 0u8);
                let mine = solid_blocks(shape, rule, &opts, &local, workers, progress, decomp)?;
                gather_layers(&local, decomp)?;
                decomp.sum_u64(&[mine.unclosed])?;
            }
        }
    }
}

/// Send `request` from rank 0 to the others (who call [`serve`]).
fn send(decomp: &dyn Decomposition, request: &Request) -> Result<(), crate::Error> {
    let bytes = serde_json::to_vec(request).expect("a request serializes");
    decomp.all_gather_bytes(bytes)?;
    Ok(())
}

/// The request rank 0 sent ([`send`]).
fn receive(decomp: &dyn Decomposition) -> Result<Request, crate::Error> {
    let all = decomp.all_gather_bytes(Vec::new())?;
    serde_json::from_slice(&all[0]).map_err(|e| {
        GridError::Ranks(format!(
            "rank 0 sent a voxelization request this rank cannot read ({e}); are all ranks the same harmap?"
        ))
        .into()
    })
}

/// The solid pass on the blocks `decomp` gives this process.
fn solid_blocks(
    shape: &Shape,
    rule: Option<InsideRule>,
    opts: &VoxelizeOptions,
    solid: &dyn BlockStore<u8>,
    workers: usize,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<SolidCounts, crate::Error> {
    let mut out = SolidCounts::default();
    match (shape, rule) {
        (Shape::Mesh(mesh), Some(rule)) => {
            out.unclosed = scanline::mesh_solid(mesh, rule, solid, workers, progress, decomp)?;
        }
        (Shape::Volume(v), _) => {
            from_volume::volume_solid(v, opts.padding, solid, workers, progress, decomp)?;
        }
        (Shape::Molecule(m), _) => {
            let (cav, probes) = spheres::molecule_solid(
                m,
                opts.surface,
                opts.probe,
                solid,
                workers,
                progress,
                decomp,
            )?;
            out.probe_cavities = cav.count;
            out.probes = probes;
        }
        (Shape::Mesh(_), None) => {
            return Err(GridError::Ranks(
                "a solid pass of a mesh came without its inside rule".into(),
            )
            .into())
        }
    }
    Ok(out)
}

/// Every block layer a rank other than 0 computed, from its owner into rank 0's
/// `solid`, one layer at a time (every rank takes part in each layer's gather).
fn gather_layers(solid: &dyn BlockStore<u8>, decomp: &dyn Decomposition) -> Result<(), GridError> {
    let spec = solid.spec().clone();
    let nb = spec.blocks();
    let me = decomp.part();
    for p in 1..decomp.parts() {
        for l in decomp.z_layers(p, nb) {
            let blocks: Vec<Idx3> = (0..nb[1])
                .flat_map(|y| (0..nb[2]).map(move |x| [l, y, x]))
                .collect();
            let mut mine = Vec::new();
            if me == p {
                for &b in &blocks {
                    mine.extend(solid.read_block(b)?);
                }
            }
            let all = decomp.all_gather_bytes(mine)?;
            if me != 0 {
                continue;
            }
            let bytes = &all[p];
            let mut at = 0;
            for &b in &blocks {
                let n = volume(spec.block_shape(b)) as usize;
                let block = bytes.get(at..at + n).ok_or_else(|| {
                    GridError::Ranks(format!(
                        "rank {p} sent {} bytes of the solid's block layer {l}, fewer than its blocks hold",
                        bytes.len()
                    ))
                })?;
                solid.write_block(b, block)?;
                at += n;
            }
        }
    }
    Ok(())
}
