//! Errors of voxelization: options that cannot make a grid, and shapes harmap cannot map.

/// Why a shape could not be voxelized.
#[derive(Debug, thiserror::Error)]
pub enum VoxelizeError {
    /// The options cannot make a grid (resolution 0, absurd size, padding below 5...).
    ///
    /// Fix: as the message says.
    #[error("{0}")]
    Options(String),
    /// The surface has holes, so its inside is undefined.
    ///
    /// Fix: close the holes (MeshLab "Close Holes", PyMeshFix) and voxelize again.
    #[error("{path}: the surface is not closed: {boundary_edges} edges belong to one triangle only (e.g. the edge between vertices {} and {}, counting from 1){odd}, so its inside is undefined; close the holes (e.g. MeshLab's \"Close Holes\" or PyMeshFix) and try again", example[0] + 1, example[1] + 1)]
    OpenSurface {
        /// The input file.
        path: String,
        /// Edges used by one triangle.
        boundary_edges: u64,
        /// An example open edge (0-based vertex indices).
        example: [u32; 2],
        /// Extra detail about other odd edges.
        odd: String,
    },
    /// No voxel center lies inside the shape.
    ///
    /// Fix: a finer `--resolution` (or smaller `--spacing`).
    #[error("no voxel is inside the shape on this grid ({shape:?} voxels of size {spacing}); use a finer --resolution or a smaller --spacing")]
    Empty {
        /// The grid shape.
        shape: [u64; 3],
        /// The spacing.
        spacing: f64,
    },
    /// The voxel solid is not one genus-0 piece.
    ///
    /// Fix: `--keep-largest`, `--allow-genus`, another resolution, or a repaired shape.
    #[error("{0}")]
    Topology(String),
    /// The center given, or the center ball, is not inside the solid.
    ///
    /// Fix: another `--center` or a smaller `--center-radius`.
    #[error("{0}")]
    Center(String),
}

impl VoxelizeError {
    /// Every voxelize error is about the input or the options (exit code 2).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        true
    }
}
