//! The rules every molecule reader shares: Bondi's radii, the element of an atom name,
//! which hetero groups are kept, and the reader's errors naming file and line.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{Molecule, MoleculeOptions};
use crate::input::InputError;

/// Bondi's van der Waals radii (Angstrom).
const BONDI: &[(&str, f64)] = &[
    ("H", 1.20),
    ("He", 1.40),
    ("Li", 1.82),
    ("C", 1.70),
    ("N", 1.55),
    ("O", 1.52),
    ("F", 1.47),
    ("Ne", 1.54),
    ("Na", 2.27),
    ("Mg", 1.73),
    ("Si", 2.10),
    ("P", 1.80),
    ("S", 1.80),
    ("Cl", 1.75),
    ("Ar", 1.88),
    ("K", 2.75),
    ("Ni", 1.63),
    ("Cu", 1.40),
    ("Zn", 1.39),
    ("Ga", 1.87),
    ("As", 1.85),
    ("Se", 1.90),
    ("Br", 1.85),
    ("Kr", 2.02),
    ("Pd", 1.63),
    ("Ag", 1.72),
    ("Cd", 1.58),
    ("In", 1.93),
    ("Sn", 2.17),
    ("Te", 2.06),
    ("I", 1.98),
    ("Xe", 2.16),
    ("Pt", 1.75),
    ("Au", 1.66),
    ("Hg", 1.55),
    ("Tl", 1.96),
    ("Pb", 2.02),
    ("U", 1.86),
];

/// The radius for elements the table lacks.
pub const DEFAULT_RADIUS: f64 = 2.0;

/// Bondi radius of `element` (any case), if tabulated.
#[must_use]
pub fn bondi(element: &str) -> Option<f64> {
    BONDI
        .iter()
        .find(|(e, _)| e.eq_ignore_ascii_case(element))
        .map(|&(_, r)| r)
}

pub(crate) const WATERS: [&str; 6] = ["HOH", "WAT", "H2O", "DOD", "TIP3", "SOL"];

/// The element of a PDB atom name (columns 13-16) when the element column is empty.
pub(crate) fn element_from_name(name: &str, het: bool) -> String {
    let raw = name;
    let t = raw.trim();
    // Names of one-letter elements start in column 14 (a space or digit in 13);
    // two-letter elements (FE, CL, ...) start in column 13, mostly in HETATM records.
    let first = raw.chars().next().unwrap_or(' ');
    let letters: String = t.chars().filter(char::is_ascii_alphabetic).collect();
    if letters.is_empty() {
        return String::new();
    }
    if het && first != ' ' && !first.is_ascii_digit() && letters.len() >= 2 {
        let two = capitalize(&letters[..2]);
        if bondi(&two).is_some()
            || ["Fe", "Ca", "Mn", "Co", "Mo", "Cr", "W"].contains(&two.as_str())
        {
            return two;
        }
    }
    capitalize(&letters[..1])
}

pub(crate) fn capitalize(s: &str) -> String {
    let mut c = s.chars();
    match c.next() {
        Some(f) => f.to_ascii_uppercase().to_string() + &c.as_str().to_ascii_lowercase(),
        None => String::new(),
    }
}

/// Whether `path` names a molecule or point format harmap reads.
#[must_use]
pub fn is_molecule(ext: &str) -> bool {
    matches!(
        ext,
        "pdb" | "ent" | "cif" | "mmcif" | "pqr" | "xyzr" | "xyz" | "csv"
    )
}

/// The file being read, for errors that name it and the line.
pub(crate) struct Reader<'a> {
    pub(crate) path: &'a Path,
}

impl Reader<'_> {
    pub(crate) fn err(&self, line: usize, msg: impl Into<String>) -> InputError {
        InputError::Parse {
            path: PathBuf::from(self.path),
            line: line as u64,
            message: msg.into(),
        }
    }

    pub(crate) fn number(&self, line: usize, what: &str, s: &str) -> Result<f64, InputError> {
        let t = s.trim();
        match t.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(self.err(line, format!("{what} is `{t}`, not a finite number"))),
            Err(_) if t.is_empty() => {
                Err(self.err(line, format!("{what} is missing (truncated line?)")))
            }
            Err(_) => Err(self.err(line, format!("{what} is `{t}`, not a number"))),
        }
    }

    /// The position whose x, y and z are the three fields of `f`.
    pub(crate) fn position(&self, line: usize, f: &[&str]) -> Result<DVec3, InputError> {
        Ok(DVec3::new(
            self.number(line, "x", f[0])?,
            self.number(line, "y", f[1])?,
            self.number(line, "z", f[2])?,
        ))
    }
}

/// `NAME xN, ...` of a residue count map.
#[must_use]
pub fn summary(m: &BTreeMap<String, usize>) -> String {
    m.iter()
        .map(|(k, v)| format!("{k} x{v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Table radius of an atom, noting elements the table lacks.
pub(crate) fn table_radius(element: &str, missing: &mut BTreeMap<String, usize>) -> f64 {
    bondi(element).unwrap_or_else(|| {
        *missing
            .entry(if element.is_empty() {
                "?".into()
            } else {
                element.to_owned()
            })
            .or_default() += 1;
        DEFAULT_RADIUS
    })
}

pub(crate) fn note_missing(m: &mut Molecule, missing: &BTreeMap<String, usize>) {
    if !missing.is_empty() {
        m.warnings.push(format!(
            "no Bondi radius for {}: used {DEFAULT_RADIUS} Angstrom",
            summary(missing)
        ));
    }
}

/// Whether a hetero residue is kept; counts it either way.
pub(crate) fn keep_hetero(m: &mut Molecule, res: &str, o: &MoleculeOptions) -> bool {
    let water = WATERS.contains(&res);
    if water || !o.keep_hetatm {
        *m.left_out.entry(res.to_owned()).or_default() += 1;
        false
    } else {
        *m.hetero_kept.entry(res.to_owned()).or_default() += 1;
        true
    }
}

/// How far from the origin an atom may be, in multiples of the largest radius: a
/// thousand times the size of the largest structures (about 1e3 Angstrom), so only
/// coordinates that no grid could hold are refused, before anything is sized from them.
pub(crate) const MAX_SPREAD: f64 = 1e6;

/// Refuse atoms so far from the origin (relative to the radii) that no grid could hold
/// them, naming the first one's line, with the numbers in scientific notation.
pub(crate) fn check_spread(path: &Path, m: &Molecule) -> Result<(), InputError> {
    let rmax = m.atoms.iter().map(|a| a.radius).fold(0.0, f64::max);
    let bound = MAX_SPREAD * rmax;
    let Some(a) = m.atoms.iter().find(|a| a.pos.abs().max_element() > bound) else {
        return Ok(());
    };
    let p = a.pos;
    Err(InputError::parse(
        path,
        a.line as u64,
        format!(
            "an atom at ({:.3e}, {:.3e}, {:.3e}) lies more than {bound:.3e} from the origin (10^6 times the largest radius, {rmax}); no grid can hold atoms this far apart: check the coordinates (PDB, mmCIF and PQR files are in Angstrom)",
            p.x, p.y, p.z
        ),
    ))
}
