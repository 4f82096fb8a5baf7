//! The potential phi (the paper's steps 4-5): Laplace's equation with Dirichlet
//! conditions from the labels, solved out of core.
//!
//! Files, one algorithm each:
//! - [`dirichlet`]: what each label means for phi, and the starting state;
//! - [`stencil`]: the 7-point stencil at a voxel, and the SOR factor;
//! - [`cuts`]: the Shortley-Weller stencil next to a sub-voxel boundary (mesh runs);
//! - [`boxops`]: the stencil's kernels on a box read with a halo;
//! - [`jacobi`]: the paper's iteration, block by block;
//! - [`level`]: one level of the hierarchy and what its passes read;
//! - [`coarsen`]: the coarse levels' shapes and masks;
//! - [`smooth`]: red-black smoothing passes over the blocks (and SOR);
//! - [`transfer`]: restriction and the coarse correction's length, over blocks;
//! - [`flat`]: the same passes on levels held in memory as whole arrays;
//! - [`multigrid`]: the V-cycle over the levels;
//! - [`driver`]: the iteration loop of the three methods;
//! - [`deepen`]: relative accuracy where u is tiny, by multigrid on shrinking regions;
//! - [`polish`]: relative accuracy where u = 1 - phi is tiny (thin parts);
//! - [`blocks`]: how passes visit blocks (the decomposition seam, below);
//! - [`plan`]: what lives in memory under the budget;
//! - [`checkpoint`]: the checkpoint format;
//! - [`stage`]: `harmap solve` on a run directory, with checkpoints and resume.
//!
//! # The decomposition seam
//!
//! Every pass over the blocks of a level — smoothing, residual, restriction, the
//! correction's length, the Jacobi sweep, the starting state, the coarse masks, the
//! polish — goes through a [`blocks::BlockLoop`], which visits the blocks
//! [`Decomposition::owned`](crate::grid::Decomposition::owned) gives this process. The
//! solve takes the decomposition as an argument of [`solve_with`]; [`solve`] passes
//! [`Whole`](crate::grid::Whole) (one process owns every block; nothing else changes).
//!
//! - **Halo exchange.** A pass reads one generation of a field with a halo and writes
//!   another, so a block's neighbours must be whole before the next pass reads them.
//!   After each pass that writes a field, the pass calls
//!   [`Decomposition::exchange`](crate::grid::Decomposition::exchange) with the field's
//!   name and the widest halo any later pass reads it with: `u0@k`, `u1@k` (the two
//!   generations of u on level `k`, 0 finest), `f@k` (the coarse right-hand side),
//!   `mask@k`; the polish exchanges `u` after each of its colour phases. The exchange
//!   must return only when the blocks other processes wrote are readable here within
//!   that halo of this process's blocks (halo messages, or a barrier over a shared
//!   filesystem), and every process must call it at the same points.
//! - **Reductions.** Per-block numbers (residual sums and counts, largest changes,
//!   the correction's length, the polish's per-block state) are gathered into one
//!   entry per block with
//!   [`Decomposition::reduce_in_block_order`](crate::grid::Decomposition::reduce_in_block_order)
//!   and added in block order, so every process sees the same totals and they do not
//!   depend on the number of processes.
//! - **Whole arrays.** Levels held in memory as whole arrays ([`flat`]) are used only
//!   when this process owns every block; otherwise every level goes block by block.
//! - **Not decomposed.** Checkpoints write and read every block of the state from one
//!   process, and the output images are written by each process for its own blocks.

pub mod blocks;
pub mod boxops;
pub mod checkpoint;
pub mod coarsen;
pub mod cuts;
pub mod deepen;
pub mod dirichlet;
pub mod driver;
mod error;
pub mod flat;
pub mod jacobi;
pub mod level;
pub mod multigrid;
mod options;
pub mod plan;
pub mod polish;
mod report;
pub mod smooth;
pub mod stage;
pub mod stencil;
pub mod transfer;

pub use deepen::{DeepenOptions, DeepenReport};
pub use driver::{Method, StopReason};
pub use error::SolveError;
pub use multigrid::{Cycle, CycleOptions};
pub use options::SolveOptions;
pub use polish::{PolishOptions, PolishReport};
pub use report::SolveReport;
pub use stage::{solve, solve_with};
