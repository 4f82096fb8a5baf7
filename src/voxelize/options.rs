//! Defaults of the options, and where scratch grids live.

use super::{spheres, Scratch, TopologyMode, VoxelizeOptions};
use crate::grid::{BlockStore, GridSpec, MemBudget, Residence};

/// The default probe radius (Angstrom), for runs recorded before it was an option.
pub(super) fn default_probe() -> f64 {
    1.4
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
            topology: TopologyMode::Auto,
        }
    }
}

/// An intermediate u8 grid: in memory, or the scratch file `name` in `dir` (which
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
    let path = dir.join(name);
    let at = if in_memory {
        Residence::Blocks
    } else {
        Residence::File(&path)
    };
    Ok(crate::grid::scratch(spec, 0u8, at)?)
}
