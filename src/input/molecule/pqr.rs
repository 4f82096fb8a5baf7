//! PQR: whitespace-separated ATOM/HETATM records ending in x, y, z, charge and radius.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::collections::BTreeMap;

use super::rules::{element_from_name, keep_hetero, note_missing, table_radius, Reader, WATERS};
use super::{Atom, Molecule, MoleculeOptions};
use crate::input::InputError;

/// Read the atoms of a PQR file.
pub(super) fn read_pqr(
    r: &Reader<'_>,
    text: &str,
    o: &MoleculeOptions,
) -> Result<Molecule, InputError> {
    let mut m = Molecule {
        format: "pqr",
        ..Molecule::default()
    };
    let mut missing = BTreeMap::new();
    let mut zero = 0usize;
    // Whether any record of the file has a radius: if none has, the file lacks radii.
    let mut any_radius = false;
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
        if radius > 0.0 {
            any_radius = true;
        }
        let res = f[3].to_owned();
        if (rec == "HETATM" || WATERS.contains(&res.as_str())) && !keep_hetero(&mut m, &res, o) {
            continue;
        }
        let element = element_from_name(&format!(" {:<3}", f[2]), false);
        if radius <= 0.0 {
            zero += 1;
        }
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
    if any_radius {
        // As in APBS: an atom of radius 0 (AMBER's hydroxyl hydrogens from pdb2pqr) has
        // no volume, so it is no ball.
        m.atoms.retain(|a| a.radius > 0.0);
        if zero > 0 {
            m.warnings.push(format!(
                "{zero} atoms have radius 0 in the PQR file: no volume, as in APBS (left out)"
            ));
        }
    } else if zero > 0 {
        // A file without radii: the table's.
        for a in &mut m.atoms {
            a.radius = table_radius(&a.element, &mut missing);
        }
        m.warnings.push(format!(
            "every radius in the PQR file is 0 (the file lacks radii): used the Bondi radius of each atom's element for all {zero}"
        ));
    }
    note_missing(&mut m, &missing);
    Ok(m)
}
