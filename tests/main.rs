//! Integration tests: one binary, topic modules.

mod cli;
mod common;

mod meshes;
mod voxelize;
