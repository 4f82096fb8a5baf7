//! Intermediate grids of the stage: in memory or memory-mapped (see [`super::Scratch`]).

use crate::grid::{BlockStore, GridSpec, MemStore, MmapStore};

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
