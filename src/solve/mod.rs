//! The potential phi (the paper's steps 4-5): Laplace's equation with Dirichlet
//! conditions from the labels.
//!
//! This module holds the numerical kernels; the out-of-core driver (block relaxation
//! with halo exchange, multigrid, checkpoints) that `harmap solve` will run is not built
//! yet.
//!
//! - [`dirichlet`]: what each label means for phi;
//! - [`relax`]: red-black SOR over blocks and two generations, exact and
//!   deterministic for any blocking and thread count;
//! - [`stencil`]: red-black SOR sweeps and residuals of the 7-point stencil on a haloed
//!   block, in voxel units (spacing drops out of Laplace's equation).

pub mod dirichlet;
pub mod relax;
pub mod stencil;
