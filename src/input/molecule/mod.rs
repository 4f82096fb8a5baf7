//! Atoms and point sets: PDB, mmCIF, PQR, XYZR, XYZ and CSV points, each a set of balls.
//!
//! - PDB: ATOM/HETATM records by their fixed columns; the first model unless `model`;
//!   alternate locations: the first one met for each atom; element from columns 77-78,
//!   else from the atom name; chain from column 22 (else the segment id, columns
//!   73-76), residue number from columns 23-26. Columns harmap does not use (occupancy,
//!   B-factor) are not read, so values such as `inf` there do not matter.
//! - mmCIF: the `_atom_site` loop, with the PDB reader's rules (`mmcif.rs`).
//! - PQR: whitespace-separated ATOM/HETATM records whose last five fields are x, y, z,
//!   charge and radius, the residue number before them and the chain after the residue
//!   name when there is one; an atom of radius 0 has no volume and is left out (as in
//!   APBS), unless every radius in the file is 0: then the file lacks radii and every
//!   atom takes the table radius (with a warning).
//! - XYZR: `x y z r` per line. XYZ: a count line, a comment line, then `El x y z`.
//! - Points (`.csv`, or any of the above with `--radius`): every point gets that radius.
//!
//! Radii: Bondi's van der Waals radii (J. Phys. Chem. 68, 441, 1964) by element, with
//! 2.0 Angstrom (and a warning) for elements the table lacks. Waters are left out, and so
//! are other hetero groups unless `keep_hetatm`; what was left out is counted by residue.
//!
//! Bounds: an atom farther from the origin than 10^6 times the largest radius is refused
//! (no grid could hold it); the file's bytes are read within `--mem` by the caller
//! ([`crate::input::read_bytes_within`]).

mod mmcif;
mod pdb;
mod pqr;
mod rules;
#[cfg(test)]
mod tests;
mod xyz;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Serialize;

use super::InputError;
pub use rules::{bondi, is_molecule, summary, DEFAULT_RADIUS};

/// A ball: an atom or a point with a radius.
#[derive(Clone, Debug, PartialEq)]
pub struct Atom {
    /// Center (x, y, z), Angstrom (or the file's unit).
    pub pos: DVec3,
    /// Radius (van der Waals, from the file, or `--radius`).
    pub radius: f64,
    /// Element symbol (capitalized), or empty for plain points.
    pub element: String,
    /// Residue name (empty for points).
    pub residue: String,
    /// Chain id (empty where the format has none).
    pub chain: String,
    /// Residue sequence number (0 where the format has none, or it is not an integer).
    pub seq: i32,
    /// Line of the file (1-based).
    pub line: usize,
}

/// A molecule or point set.
#[derive(Clone, Debug, Default)]
pub struct Molecule {
    /// The balls kept.
    pub atoms: Vec<Atom>,
    /// Hetero residues left out (waters, ions, ligands), by residue name: atoms.
    pub left_out: BTreeMap<String, usize>,
    /// Hetero residues kept, by residue name: atoms.
    pub hetero_kept: BTreeMap<String, usize>,
    /// Things the user should know (radii defaulted, ...).
    pub warnings: Vec<String>,
    /// The file format read.
    pub format: &'static str,
}

/// How atoms are read.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct MoleculeOptions {
    /// PDB model number to read (default: the first).
    pub model: Option<u32>,
    /// Keep hetero groups other than water.
    pub keep_hetatm: bool,
    /// One radius for every point (point sets; overrides radii otherwise).
    pub radius: Option<f64>,
}

/// Read the molecule or point set at `path` (`ext` its format, e.g. from
/// [`super::extension`]), from the file's bytes.
pub fn read(
    path: &Path,
    ext: &str,
    bytes: &[u8],
    o: &MoleculeOptions,
) -> Result<Molecule, InputError> {
    let text = String::from_utf8_lossy(bytes);
    let r = rules::Reader { path };
    let mut m = match ext {
        "pdb" | "ent" => pdb::read_pdb(&r, &text, o)?,
        "cif" | "mmcif" => mmcif::read(&r, &text, o)?,
        "pqr" => pqr::read_pqr(&r, &text, o)?,
        "xyzr" => xyz::read_xyzr(&r, &text)?,
        "xyz" => xyz::read_xyz(&r, &text)?,
        "csv" => xyz::read_points(&r, &text)?,
        _ => {
            return Err(InputError::UnknownFormat {
                path: PathBuf::from(path),
                ext: ext.to_owned(),
            })
        }
    };
    if let Some(radius) = o.radius {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(InputError::invalid(
                path,
                format!("--radius {radius}: give a positive length"),
            ));
        }
        for a in &mut m.atoms {
            a.radius = radius;
        }
    } else if m.format == "points" {
        return Err(InputError::invalid(
            path,
            "a point set needs --radius R (the radius of the ball around every point)",
        ));
    }
    if m.atoms.is_empty() {
        let why = if m.left_out.is_empty() {
            String::new()
        } else {
            format!(
                " (left out: {}; --keep-hetatm keeps hetero groups)",
                summary(&m.left_out)
            )
        };
        return Err(InputError::invalid(path, format!("no atoms found{why}")));
    }
    rules::check_spread(path, &m)?;
    Ok(m)
}
