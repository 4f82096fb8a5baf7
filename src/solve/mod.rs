//! The potential phi (the paper's steps 4-5): Laplace's equation with Dirichlet
//! conditions from the labels.
//!
//! - [`dirichlet`]: what each label means for phi;
//! - [`boxops`]: the 7-point operator on a box read with a halo;
//! - [`multigrid`]: the level hierarchy and its passes;
//! - [`driver`]: the iteration loop of the three methods;
//! - [`polish`]: relative accuracy where u = 1 - phi is tiny (thin parts);
//! - [`stage`]: `harmap solve` on a run directory, with checkpoints and resume;
//! - [`stencil`]: the SOR factor.

pub mod boxops;
pub mod dirichlet;
pub mod driver;
pub mod flat;
pub mod multigrid;
pub mod polish;
pub mod stage;
pub mod stencil;

pub use stage::{solve, SolveError, SolveOptions, SolveReport};
