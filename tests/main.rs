//! Integration tests: one binary, topic modules.
// Tests build grids in z, y, x loops and spell their cases out in full.
#![allow(clippy::many_single_char_names, clippy::too_many_lines)]

mod cli;
mod common;
mod interop;
mod map;
mod meshes;
mod molecules;
#[cfg(feature = "mpi")]
mod mpi;
mod pipeline;
mod reliability;
mod report;
mod solve;
mod subvoxel;
mod topology;
mod trace;
mod voxelize;
