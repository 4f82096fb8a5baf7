//! Integration tests: one binary, topic modules.

mod cli;
mod common;
mod interop;
mod map;
mod pipeline;
mod meshes;
mod molecules;
mod solve;
mod trace;
mod voxelize;
