//! Point formats: XYZR (`x y z r`), XYZ (count, comment, `El x y z`) and CSV points.

use std::collections::BTreeMap;

use super::rules::{capitalize, note_missing, table_radius, Reader};
use super::{Atom, Molecule};
use crate::input::InputError;

/// Read an XYZR file.
pub(super) fn read_xyzr(r: &Reader<'_>, text: &str) -> Result<Molecule, InputError> {
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

/// Read an XYZ file.
pub(super) fn read_xyz(r: &Reader<'_>, text: &str) -> Result<Molecule, InputError> {
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

/// Read CSV points (x,y,z per line, an optional header).
pub(super) fn read_points(r: &Reader<'_>, text: &str) -> Result<Molecule, InputError> {
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
