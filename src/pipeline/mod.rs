//! The pipeline: the stages chained over a run directory. `harmap run` calls [`run`];
//! the stage subcommands call the stages themselves (and [`voxelize_new_run`]), so a
//! stage run alone and a stage run by the pipeline write the same run.
//!
//! [`run`] skips the stages that are done with the same options and fresh inputs, runs
//! again those whose options changed or whose inputs were run again since (and says
//! why), resumes an interrupted solve from its checkpoint, stops at the next block or
//! tile when the caller's [`Interrupt`](crate::progress::Interrupt) is set, and draws
//! the atlas (by the molecule's residues when it can, else by the main axis).

mod chain;
mod checks;
mod new_run;

use std::path::{Path, PathBuf};

use crate::input::InputOptions;
use crate::map::{MapOptions, MapReport};
use crate::solve::{SolveOptions, SolveReport};
use crate::trace::{TraceOptions, TraceReport};
use crate::voxelize::{VoxelizeOptions, VoxelizeReport};

pub use chain::run;
pub use checks::{check_solve, check_stop_radius};
pub use new_run::{serve_voxelize, standard_ball_run, voxelize_new_run, voxelize_new_run_on};

/// Where the shape comes from.
#[derive(Clone, Debug)]
pub enum Source<'a> {
    /// A file (or a Zarr directory) to read.
    File(&'a Path, &'a InputOptions),
    /// The built-in five-armed starfish.
    Starfish,
    /// A surface already in memory, with a name for messages.
    Mesh(&'a crate::input::TriMesh, &'a str),
}

/// What [`run`] does: the run directory and every stage's options.
#[derive(Clone, Debug)]
pub struct PipelineOptions {
    /// The run directory.
    pub out: PathBuf,
    /// Start over: replace the run at `out` and run every stage.
    pub force: bool,
    /// The voxelization.
    pub voxelize: VoxelizeOptions,
    /// The solve (`resume` is ignored: a checkpoint left in the run is always used
    /// when it was made for these options).
    pub solve: SolveOptions,
    /// The trace.
    pub trace: TraceOptions,
    /// The map; `stop_radius: None` takes the trace's.
    pub map: MapOptions,
    /// Where to draw the atlas (`None`: no atlas).
    pub atlas: Option<PathBuf>,
    /// Where to write the report page ([`crate::report::html`]; `None`: no page).
    pub report: Option<PathBuf>,
}

/// What [`run`] did with one stage.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum StageRun {
    /// Done before with the same options and fresh inputs: skipped.
    Skipped,
    /// Run now. `again` says why when it had been done before (its options changed,
    /// or an input was run again since); `resumed` when the solve continued from a
    /// checkpoint.
    Ran {
        /// Why a stage done before was run again.
        again: Option<String>,
        /// The solve continued from a checkpoint.
        resumed: bool,
    },
}

/// The numbers of a finished run, read back from its records.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Seconds of each stage as recorded (voxelize, solve, trace, map).
    pub seconds: [f64; 4],
    /// Share of the streamlines that reached the center.
    pub reached_fraction: f64,
    /// Surface seeds: triangles flipped on the sphere, and triangles measured.
    pub flipped: Option<(u64, u64)>,
    /// Seeds landing within a tiny angle of seeds from elsewhere.
    pub colliding_seeds: u64,
    /// Voxels with (theta, psi), and voxels of the solid.
    pub mapped: (u64, u64),
}

/// What [`run`] did.
#[derive(Clone, Debug)]
pub struct PipelineReport {
    /// The run directory.
    pub run: PathBuf,
    /// Each stage (voxelize, solve, trace, map) and what was done with it.
    pub stages: Vec<(&'static str, StageRun)>,
    /// The voxelization's report, when it ran now.
    pub voxelize: Option<VoxelizeReport>,
    /// The solve's report and seconds, when it ran now.
    pub solve: Option<(SolveReport, f64)>,
    /// The trace's report and seconds, when it ran now.
    pub trace: Option<(TraceReport, f64)>,
    /// The map's report and seconds, when it ran now.
    pub map: Option<(MapReport, f64)>,
    /// The atlas drawn, if any.
    pub atlas: Option<PathBuf>,
    /// Why the atlas is colored by the main axis instead of the residues, if it is.
    pub atlas_fallback: Option<String>,
    /// The report page written, if any.
    pub report: Option<PathBuf>,
    /// The numbers of the finished run.
    pub summary: Summary,
}

/// Errors of [`run`].
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A stage failed.
    #[error(transparent)]
    Stage(#[from] crate::Error),
    /// The run directory holds a run of another input or other voxelization options.
    ///
    /// Fix: pass `--force` to start over, or choose another output.
    #[error("{}: holds a run of {what}; pass --force to redo every stage, or choose another -o", run.display())]
    OtherRun {
        /// The run.
        run: PathBuf,
        /// What differs.
        what: String,
    },
    /// The caller's interrupt was set (a signal): the run stopped in `stage`. Giving
    /// the same pipeline again continues it.
    #[error("{}: stopped during the {stage} stage", run.display())]
    Interrupted {
        /// The run.
        run: PathBuf,
        /// The stage that was stopped (or would have started).
        stage: &'static str,
        /// The signal that stopped it (0 when not a signal).
        signal: usize,
    },
}

impl PipelineError {
    /// Whether the user's input or options are at fault (exit code 2).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        match self {
            PipelineError::Stage(e) => e.is_bad_input(),
            PipelineError::OtherRun { .. } => true,
            PipelineError::Interrupted { .. } => false,
        }
    }
}
