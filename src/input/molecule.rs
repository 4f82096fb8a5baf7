//! Atoms and point sets: PDB, mmCIF, PQR, XYZR, XYZ and CSV points, each a set of balls.
//!
//! - PDB: ATOM/HETATM records by their fixed columns; the first model unless `model`;
//!   alternate locations: the first one met for each atom; element from columns 77-78,
//!   else from the atom name; chain from column 22 (else the segment id, columns
//!   73-76), residue number from columns 23-26. Columns harmap does not use (occupancy,
//!   B-factor) are not read, so values such as `inf` there do not matter.
//! - mmCIF: the `_atom_site` loop, with the PDB reader's rules (`super::mmcif`).
//! - PQR: whitespace-separated ATOM/HETATM records whose last five fields are x, y, z,
//!   charge and radius, the residue number before them and the chain after the residue
//!   name when there is one; a radius of 0 takes the table radius (with a warning).
//! - XYZR: `x y z r` per line. XYZ: a count line, a comment line, then `El x y z`.
//! - Points (`.csv`, or any of the above with `--radius`): every point gets that radius.
//!
//! Radii: Bondi's van der Waals radii (J. Phys. Chem. 68, 441, 1964) by element, with
//! 2.0 Angstrom (and a warning) for elements the table lacks. Waters are left out, and so
//! are other hetero groups unless `keep_hetatm`; what was left out is counted by residue.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Serialize;

use super::InputError;

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

pub(super) const WATERS: [&str; 6] = ["HOH", "WAT", "H2O", "DOD", "TIP3", "SOL"];

/// The element of a PDB atom name (columns 13-16) when the element column is empty.
pub(super) fn element_from_name(name: &str, het: bool) -> String {
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

pub(super) fn capitalize(s: &str) -> String {
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
pub(super) struct Reader<'a> {
    pub(super) path: &'a Path,
}

impl Reader<'_> {
    pub(super) fn err(&self, line: usize, msg: impl Into<String>) -> InputError {
        InputError::Parse {
            path: PathBuf::from(self.path),
            line: line as u64,
            message: msg.into(),
        }
    }

    pub(super) fn number(&self, line: usize, what: &str, s: &str) -> Result<f64, InputError> {
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
    fn position(&self, line: usize, f: &[&str]) -> Result<DVec3, InputError> {
        Ok(DVec3::new(
            self.number(line, "x", f[0])?,
            self.number(line, "y", f[1])?,
            self.number(line, "z", f[2])?,
        ))
    }
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
    let r = Reader { path };
    let mut m = match ext {
        "pdb" | "ent" => read_pdb(&r, &text, o)?,
        "cif" | "mmcif" => super::mmcif::read(&r, &text, o)?,
        "pqr" => read_pqr(&r, &text, o)?,
        "xyzr" => read_xyzr(&r, &text)?,
        "xyz" => read_xyz(&r, &text)?,
        "csv" => read_points(&r, &text)?,
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
    Ok(m)
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
pub(super) fn table_radius(element: &str, missing: &mut BTreeMap<String, usize>) -> f64 {
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

pub(super) fn note_missing(m: &mut Molecule, missing: &BTreeMap<String, usize>) {
    if !missing.is_empty() {
        m.warnings.push(format!(
            "no Bondi radius for {}: used {DEFAULT_RADIUS} Angstrom",
            summary(missing)
        ));
    }
}

/// Whether a hetero residue is kept; counts it either way.
pub(super) fn keep_hetero(m: &mut Molecule, res: &str, o: &MoleculeOptions) -> bool {
    let water = WATERS.contains(&res);
    if water || !o.keep_hetatm {
        *m.left_out.entry(res.to_owned()).or_default() += 1;
        false
    } else {
        *m.hetero_kept.entry(res.to_owned()).or_default() += 1;
        true
    }
}

fn read_pdb(r: &Reader<'_>, text: &str, o: &MoleculeOptions) -> Result<Molecule, InputError> {
    let mut m = Molecule {
        format: "pdb",
        ..Molecule::default()
    };
    let mut missing = BTreeMap::new();
    let mut model: Option<u32> = None;
    let mut models_seen = 0u32;
    let want = o.model;
    let mut seen_atoms: std::collections::HashSet<(String, String, String, String)> =
        std::collections::HashSet::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let rec = line.get(0..6).unwrap_or(line).trim_end();
        match rec {
            "MODEL" => {
                models_seen += 1;
                let num = line
                    .get(10..14)
                    .unwrap_or("")
                    .trim()
                    .parse::<u32>()
                    .unwrap_or(models_seen);
                model = Some(num);
                continue;
            }
            "ENDMDL" => {
                if (want.is_none() || model == want) && !m.atoms.is_empty() {
                    break;
                }
                continue;
            }
            "ATOM" | "HETATM" => {}
            _ => continue,
        }
        if let (Some(w), Some(cur)) = (want, model) {
            if w != cur {
                continue;
            }
        } else if want.is_some() && model.is_none() && want != Some(1) {
            continue;
        }
        if line.len() < 54 {
            return Err(r.err(n, format!("{rec} record of {} characters; the coordinates end at column 54 (truncated line?)", line.len())));
        }
        let het = rec == "HETATM";
        let name = line.get(12..16).unwrap_or("");
        let alt = line.get(16..17).unwrap_or(" ");
        let res = line.get(17..20).unwrap_or("").trim().to_owned();
        let chain = line.get(21..22).unwrap_or(" ").to_owned();
        let seq = line.get(22..27).unwrap_or("").trim().to_owned();
        let x = r.number(n, "x (columns 31-38)", &line[30..38])?;
        let y = r.number(n, "y (columns 39-46)", &line[38..46])?;
        let z = r.number(n, "z (columns 47-54)", &line[46..54])?;
        let pos = DVec3::new(x, y, z);
        // Alternate locations: the first met for each atom.
        if alt != " "
            && !seen_atoms.insert((
                chain.clone(),
                seq.clone(),
                res.clone(),
                name.trim().to_owned(),
            ))
        {
            continue;
        }
        if (het || WATERS.contains(&res.as_str())) && !keep_hetero(&mut m, &res, o) {
            continue;
        }
        let element = line
            .get(76..78)
            .map(str::trim)
            .filter(|e| !e.is_empty() && e.chars().all(|c| c.is_ascii_alphabetic()))
            .map_or_else(|| element_from_name(name, het), capitalize);
        let radius = table_radius(&element, &mut missing);
        let chain_id = match chain.trim() {
            "" => line.get(72..76).unwrap_or("").trim().to_owned(),
            c => c.to_owned(),
        };
        m.atoms.push(Atom {
            pos,
            radius,
            element,
            residue: res,
            chain: chain_id,
            seq: line.get(22..26).unwrap_or("").trim().parse().unwrap_or(0),
            line: n,
        });
    }
    if let Some(w) = want {
        if m.atoms.is_empty() && models_seen > 0 {
            return Err(InputError::invalid(
                r.path,
                format!("--model {w}: the file has {models_seen} model(s) and none numbered {w}"),
            ));
        }
    }
    if models_seen > 1 && want.is_none() {
        m.warnings.push(format!(
            "{models_seen} models: read the first (--model N for another)"
        ));
    }
    note_missing(&mut m, &missing);
    Ok(m)
}

fn read_pqr(r: &Reader<'_>, text: &str, o: &MoleculeOptions) -> Result<Molecule, InputError> {
    let mut m = Molecule {
        format: "pqr",
        ..Molecule::default()
    };
    let mut missing = BTreeMap::new();
    let mut zero = 0usize;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let f: Vec<&str> = line.split_whitespace().collect();
        let Some(&rec) = f.first() else { continue };
        if rec != "ATOM" && rec != "HETATM" {
            continue;
        }
        if f.len() < 10 {
            return Err(r.err(
                n,
                format!("{rec} record with {} fields; PQR needs serial, name, residue, number, x, y, z, charge and radius (truncated line?)", f.len()),
            ));
        }
        let k = f.len();
        let pos = r.position(n, &f[k - 5..k - 2])?;
        r.number(n, "charge", f[k - 2])?;
        let radius = r.number(n, "radius", f[k - 1])?;
        if radius < 0.0 {
            return Err(r.err(n, format!("radius {radius} is negative")));
        }
        let res = f[3].to_owned();
        if (rec == "HETATM" || WATERS.contains(&res.as_str())) && !keep_hetero(&mut m, &res, o) {
            continue;
        }
        let element = element_from_name(&format!(" {:<3}", f[2]), false);
        let radius = if radius > 0.0 {
            radius
        } else {
            zero += 1;
            table_radius(&element, &mut missing)
        };
        m.atoms.push(Atom {
            pos,
            radius,
            element,
            residue: res,
            // serial, name, residue, [chain,] number, x, y, z, charge, radius.
            chain: if k > 10 {
                f[4].to_owned()
            } else {
                String::new()
            },
            seq: f[k - 6].parse().unwrap_or(0),
            line: n,
        });
    }
    if zero > 0 {
        m.warnings.push(format!(
            "{zero} atoms have radius 0 in the PQR file: used the Bondi radius of their element"
        ));
    }
    note_missing(&mut m, &missing);
    Ok(m)
}

fn read_xyzr(r: &Reader<'_>, text: &str) -> Result<Molecule, InputError> {
    let mut m = Molecule {
        format: "xyzr",
        ..Molecule::default()
    };
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.is_empty() || f[0].starts_with('#') {
            continue;
        }
        if f.len() < 4 {
            return Err(r.err(n, format!("{} fields; XYZR needs x y z r", f.len())));
        }
        let radius = r.number(n, "r", f[3])?;
        if radius <= 0.0 {
            return Err(r.err(n, format!("radius {radius} is not positive")));
        }
        m.atoms.push(Atom {
            pos: r.position(n, &f[0..3])?,
            radius,
            element: String::new(),
            residue: String::new(),
            chain: String::new(),
            seq: 0,
            line: n,
        });
    }
    Ok(m)
}

fn read_xyz(r: &Reader<'_>, text: &str) -> Result<Molecule, InputError> {
    let mut m = Molecule {
        format: "xyz",
        ..Molecule::default()
    };
    let mut missing = BTreeMap::new();
    let mut lines = text.lines().enumerate();
    let count = match lines.next() {
        Some((_, l)) => l.trim().parse::<usize>().map_err(|_| {
            r.err(
                1,
                format!(
                    "the first line of an XYZ file is the atom count, not `{}`",
                    l.trim()
                ),
            )
        })?,
        None => return Err(InputError::invalid(r.path, "empty file")),
    };
    lines.next(); // comment
    for (i, line) in lines {
        let n = i + 1;
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.is_empty() {
            continue;
        }
        if f.len() < 4 {
            return Err(r.err(n, format!("{} fields; XYZ needs element x y z", f.len())));
        }
        let element = capitalize(f[0].trim_matches(|c: char| !c.is_ascii_alphabetic()));
        let radius = table_radius(&element, &mut missing);
        m.atoms.push(Atom {
            pos: r.position(n, &f[1..4])?,
            radius,
            element,
            residue: String::new(),
            chain: String::new(),
            seq: 0,
            line: n,
        });
    }
    if m.atoms.len() != count {
        m.warnings.push(format!(
            "the count line says {count} atoms, the file has {}",
            m.atoms.len()
        ));
    }
    note_missing(&mut m, &missing);
    Ok(m)
}

fn read_points(r: &Reader<'_>, text: &str) -> Result<Molecule, InputError> {
    let mut m = Molecule {
        format: "points",
        ..Molecule::default()
    };
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.iter().all(|s| s.is_empty()) || f[0].starts_with('#') {
            continue;
        }
        // A header line (x,y,z) is skipped.
        if n == 1 && f[0].parse::<f64>().is_err() {
            continue;
        }
        if f.len() < 3 {
            return Err(r.err(n, format!("{} columns; a point needs x,y,z", f.len())));
        }
        m.atoms.push(Atom {
            pos: r.position(n, &f[0..3])?,
            radius: 0.0,
            element: String::new(),
            residue: String::new(),
            chain: String::new(),
            seq: 0,
            line: n,
        });
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pdb(lines: &[&str]) -> Result<Molecule, InputError> {
        read(
            Path::new("t.pdb"),
            "pdb",
            lines.join("\n").as_bytes(),
            &MoleculeOptions::default(),
        )
    }

    #[test]
    fn pdb_columns_elements_altlocs_and_waters() {
        let m = pdb(&[
            "ATOM      1  N   MET A   1      27.340  24.430   2.614  1.00  9.67           N",
            "ATOM      2  CA AMET A   1      26.266  25.413   2.842  0.50 10.38           C",
            "ATOM      3  CA BMET A   1      26.300  25.400   2.800  0.50 10.38           C",
            "ATOM      4 HT1  MET A   1      26.000  25.000   2.000   inf   inf",
            "HETATM    5 FE   HEM A 200      10.000  10.000  10.000  1.00  9.00",
            "HETATM    6  O   HOH A 301      45.747  30.081  19.708  1.00 12.43           O",
        ])
        .unwrap();
        assert_eq!(m.atoms.len(), 3, "{:?}", m.atoms);
        assert_eq!(m.atoms[0].element, "N");
        assert!((m.atoms[0].radius - 1.55).abs() < 1e-12);
        assert!(
            (m.atoms[1].pos.x - 26.266).abs() < 1e-12,
            "first altloc kept"
        );
        assert_eq!(m.atoms[2].element, "H");
        assert_eq!(m.left_out.get("HOH"), Some(&1));
        assert_eq!(m.left_out.get("HEM"), Some(&1));
    }

    #[test]
    fn bad_records_name_their_line() {
        let e = pdb(&[
            "ATOM      1  N   MET A   1      27.340  24.430   2.614  1.00  9.67           N",
            "ATOM      2  CA  MET A   1      26.266  abcdef   2.842  1.00 10.38           C",
        ])
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("t.pdb") && e.contains('2') && e.contains("abcdef"),
            "{e}"
        );
        let e = pdb(&["ATOM      1  N   MET A   1      27.340  24.430"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated"), "{e}");
        let e = pdb(&[
            "ATOM      1  N   MET A   1      27.340     inf   2.614  1.00  9.67           N",
        ])
        .unwrap_err()
        .to_string();
        assert!(e.contains("inf") && e.contains("finite"), "{e}");
        let e = pdb(&["REMARK nothing here"]).unwrap_err().to_string();
        assert!(e.contains("no atoms"), "{e}");
    }

    #[test]
    fn models_pqr_radii_and_points() {
        let two = [
            "MODEL        1",
            "ATOM      1  C   MOL A   1       0.000   0.000   0.000  1.00  0.00           C",
            "ENDMDL",
            "MODEL        2",
            "ATOM      1  C   MOL A   1       5.000   0.000   0.000  1.00  0.00           C",
            "ENDMDL",
        ]
        .join("\n");
        let first = read(
            Path::new("m.pdb"),
            "pdb",
            two.as_bytes(),
            &MoleculeOptions::default(),
        )
        .unwrap();
        assert_eq!(first.atoms.len(), 1);
        assert!(first.atoms[0].pos.x.abs() < 1e-12);
        let o = MoleculeOptions {
            model: Some(2),
            ..MoleculeOptions::default()
        };
        let second = read(Path::new("m.pdb"), "pdb", two.as_bytes(), &o).unwrap();
        assert!((second.atoms[0].pos.x - 5.0).abs() < 1e-12);

        let pqr = "ATOM      1  N   ASP   152      21.554  34.953  27.691 -0.4000 1.5000\n\
                   ATOM     18  HA  ASP   152      21.052  36.602  28.719  0.0000 0.0000\n";
        let m = read(
            Path::new("x.pqr"),
            "pqr",
            pqr.as_bytes(),
            &MoleculeOptions::default(),
        )
        .unwrap();
        assert!((m.atoms[0].radius - 1.5).abs() < 1e-12);
        assert!(
            (m.atoms[1].radius - 1.2).abs() < 1e-12,
            "radius 0 takes H's table radius"
        );
        assert!(m.warnings.iter().any(|w| w.contains("radius 0")));

        let pts = "x,y,z\n0,0,0\n1,2,3\n";
        let e = read(
            Path::new("p.csv"),
            "csv",
            pts.as_bytes(),
            &MoleculeOptions::default(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("--radius"));
        let o = MoleculeOptions {
            radius: Some(0.5),
            ..MoleculeOptions::default()
        };
        let m = read(Path::new("p.csv"), "csv", pts.as_bytes(), &o).unwrap();
        assert_eq!(m.atoms.len(), 2);
        assert!((m.atoms[1].radius - 0.5).abs() < 1e-12);
    }
}
