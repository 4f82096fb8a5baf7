//! harmap: out-of-core harmonic volumetric parameterization.
//!
//! Maps the volume of a genus-0 solid onto the unit ball following Gupta, Voruganti and
//! Dasgupta, "Domain Mapping for Volumetric Parameterization using Harmonic Functions":
//! voxelize, solve Laplace's equation with Dirichlet conditions (boundary 1, center 0),
//! trace streamlines of -grad(phi) to the center, and read off the arrival angles.
//!
//! Stages are modules ([`input`], [`voxelize`], ...) with one entry function and an
//! `*Options` struct each; grids live behind [`grid::BlockStore`] so no stage holds a
//! whole grid in memory. This crate knows nothing of the command line.

pub mod export;
pub mod grid;
pub mod input;
pub mod map;
pub mod math;
pub mod pipeline;
pub mod progress;
pub mod report;
pub mod run;
pub mod solve;
pub mod trace;
pub mod voxelize;

mod error;
pub use error::Error;
mod parallel;
