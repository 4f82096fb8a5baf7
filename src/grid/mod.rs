//! Chunked grid storage behind one block-access trait.
//!
//! - [`GridSpec`]: shape, placement in the world, block shape.
//! - [`BlockStore`]: read and write blocks, read boxes with a halo; three backends
//!   ([`ZarrStore`], [`MmapStore`], [`MemStore`]).
//! - [`MemBudget`]: the `--mem` bound on what a run holds resident.

mod block;
mod budget;
mod memory;
mod mmap;
mod spec;
mod store;
mod zarr;

pub use block::{copy_overlap, to_usize, Block};
pub use budget::{human, MemBudget, BASE_BYTES};
pub use memory::MemStore;
pub use mmap::MmapStore;
pub use spec::GridSpec;
pub use store::{BlockStore, GridError, Scalar};
pub use zarr::{fs_store, Compression, ZarrStore};
