//! `harmap::Error`: the errors of every stage, composed.

/// Any error of the library. The CLI maps [`Error::is_bad_input`] to exit code 2.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading the input shape failed.
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    /// Grid storage failed.
    #[error(transparent)]
    Grid(#[from] crate::grid::GridError),
    /// The run directory is missing, damaged or of another version.
    #[error(transparent)]
    Run(#[from] crate::run::RunError),
    /// Voxelization failed or found a shape it cannot use.
    #[error(transparent)]
    Voxelize(#[from] crate::voxelize::VoxelizeError),
    /// The solve failed, was interrupted, or cannot resume.
    #[error(transparent)]
    Solve(#[from] crate::solve::SolveError),
    /// Tracing failed or was asked for something it cannot do.
    #[error(transparent)]
    Trace(#[from] crate::trace::TraceError),
    /// The map or the inverse map cannot work with the run or its inputs.
    #[error(transparent)]
    Map(#[from] crate::map::MapError),
    /// An export cannot be made or written.
    #[error(transparent)]
    Export(#[from] crate::export::ExportError),
    /// A picture cannot be drawn or written.
    #[error(transparent)]
    Report(#[from] crate::report::ReportError),
}

impl Error {
    /// Whether the error is the user's input or options (exit code 2) rather than a
    /// failure of the run (exit code 1).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        match self {
            Error::Input(_) | Error::Trace(_) => true,
            Error::Grid(e) => matches!(
                e,
                crate::grid::GridError::Budget { .. }
                    | crate::grid::GridError::Corrupt { .. }
                    | crate::grid::GridError::RankLayout(_)
            ),
            Error::Run(e) => e.is_bad_input(),
            Error::Voxelize(e) => e.is_bad_input(),
            Error::Solve(e) => e.is_bad_input(),
            Error::Map(e) => e.is_bad_input(),
            Error::Export(e) => matches!(
                e,
                crate::export::ExportError::Unavailable(_) | crate::export::ExportError::Refused(_)
            ),
            Error::Report(e) => matches!(e, crate::report::ReportError::Unavailable(_)),
        }
    }
}
