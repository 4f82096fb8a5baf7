//! Reading shapes: triangle meshes (OBJ, STL, PLY), tetrahedral meshes (TetGen),
//! molecules and point sets (PDB, mmCIF, PQR, XYZR, XYZ, CSV), and label volumes that
//! are already voxelized (Zarr v3 arrays, raw bytes).
//!
//! Every reader returns an [`InputError`] naming the file (and the line, for text
//! formats) on bad input; none panics. Any file may be gzip-compressed (`.gz`).

mod error;
mod mesh;
pub mod molecule;
mod obj;
mod ply;
mod source;
pub mod starfish;
mod stl;
mod tetgen;
mod volume;

use std::path::{Path, PathBuf};

pub use error::InputError;
pub use mesh::{MeshTopology, TriMesh};
pub use source::{extension, input_limit, read_bytes, read_bytes_within, sha256_file};
pub use volume::{LabelVolume, RawDtype, RawSpec};

/// A shape to voxelize.
#[derive(Debug)]
pub enum Shape {
    /// A triangle surface (for a tetrahedral mesh: its boundary faces, wound outward).
    Mesh(TriMesh),
    /// A label volume: "anything > 0 is inside", one voxel per array element.
    Volume(LabelVolume),
    /// Balls: the atoms of a molecule, or points with a radius.
    Molecule(molecule::Molecule),
}

/// How to read inputs whose file does not describe itself.
#[derive(Clone, Debug, Default)]
pub struct InputOptions {
    /// Shape and data type of a `.raw` volume.
    pub raw: Option<RawSpec>,
    /// How atoms and points are read.
    pub molecule: molecule::MoleculeOptions,
    /// The memory budget (`--mem`; None: the default): the decoded bytes of a file may
    /// take a third of it ([`input_limit`]).
    pub mem: Option<crate::grid::MemBudget>,
}

impl InputOptions {
    /// The most decoded bytes an input file may have.
    #[must_use]
    pub fn limit(&self) -> u64 {
        input_limit(self.mem.unwrap_or_default())
    }
}

/// Read the shape at `path`, choosing the reader by extension.
pub fn load(path: &Path, options: &InputOptions) -> Result<Shape, InputError> {
    if path.is_dir() {
        return LabelVolume::open_zarr(path).map(Shape::Volume);
    }
    if !path.exists() {
        return Err(InputError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    let (ext, _) = extension(path);
    match ext.as_str() {
        "raw" | "bin" => {
            let spec = options.raw.clone().ok_or_else(|| {
                InputError::invalid(
                    path,
                    "a raw volume needs its layout: give --raw-shape Z,Y,X and --raw-dtype (u8, u16, i16, u32, i32, f32 or f64)",
                )
            })?;
            LabelVolume::open_raw(path, &spec).map(Shape::Volume)
        }
        e if molecule::is_molecule(e) || options.molecule.radius.is_some() => {
            let bytes = read_bytes_within(path, options.limit())?;
            molecule::read(path, e, &bytes, &options.molecule).map(Shape::Molecule)
        }
        _ => mesh_within(path, options.limit()).map(Shape::Mesh),
    }
}

/// Read a surface (or the boundary of a tetrahedral mesh) from `path`, and check that
/// every coordinate is finite and every index in range.
/// The file's decoded bytes may take a third of the default `--mem`.
pub fn load_mesh(path: &Path) -> Result<TriMesh, InputError> {
    mesh_within(path, input_limit(crate::grid::MemBudget::default()))
}

fn mesh_within(path: &Path, limit: u64) -> Result<TriMesh, InputError> {
    let (ext, _) = extension(path);
    let bytes = |p: &Path| read_bytes_within(p, limit);
    let mesh = match ext.as_str() {
        "obj" => obj::read(path, &bytes(path)?)?,
        "stl" => stl::read(path, &bytes(path)?)?,
        "ply" => ply::read(path, &bytes(path)?)?,
        "node" | "ele" => tetgen::read(path, limit)?,
        _ => {
            return Err(InputError::UnknownFormat {
                path: PathBuf::from(path),
                ext,
            })
        }
    };
    if mesh.triangles.is_empty() {
        return Err(InputError::invalid(
            path,
            "no triangles found: the file holds no surface",
        ));
    }
    Ok(mesh)
}
