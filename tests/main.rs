//! Integration tests: one binary, topic modules.

mod cli;
mod common;
mod interop;
mod meshes;
mod solve;
mod trace;
mod voxelize;
