//! Integration tests: one binary, topic modules.

mod cli;
mod common;
mod interop;
mod map;
mod meshes;
mod molecules;
mod report;
mod solve;
mod trace;
mod voxelize;
