//! Integration tests: one binary, topic modules.

mod cli;
mod common;
mod interop;
mod map;
mod meshes;
mod molecules;
mod pipeline;
mod reliability;
mod report;
mod solve;
mod topology;
mod trace;
mod voxelize;
