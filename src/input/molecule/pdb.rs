//! PDB: ATOM/HETATM records by their fixed columns (the rules in [`super`]).
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::collections::BTreeMap;

use glam::DVec3;

use super::rules::{
    capitalize, element_from_name, keep_hetero, note_missing, table_radius, Reader, WATERS,
};
use super::{Atom, Molecule, MoleculeOptions};
use crate::input::InputError;

/// Bytes `cols` of `line` (line `n`) as text. Columns count bytes, and a character of
/// more than one byte (PDB files are ASCII; an editor's accent or a stray UTF-8 byte is
/// not) may straddle a column edge: that is an error naming the line, not a panic.
fn column<'t>(
    r: &Reader<'_>,
    n: usize,
    line: &'t str,
    cols: std::ops::Range<usize>,
) -> Result<&'t str, InputError> {
    line.get(cols.clone()).ok_or_else(|| {
        r.err(
            n,
            format!(
                "columns {}-{} hold a character that is not ASCII; PDB records are ASCII text with fixed columns: remove the character or re-export the file",
                cols.start + 1,
                cols.end
            ),
        )
    })
}

/// Read the atoms of a PDB file.
#[allow(clippy::too_many_lines)] // one pass over the file's columns, each field parsed where it stands
pub(super) fn read_pdb(
    r: &Reader<'_>,
    text: &str,
    o: &MoleculeOptions,
) -> Result<Molecule, InputError> {
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
        let x = r.number(n, "x (columns 31-38)", column(r, n, line, 30..38)?)?;
        let y = r.number(n, "y (columns 39-46)", column(r, n, line, 38..46)?)?;
        let z = r.number(n, "z (columns 47-54)", column(r, n, line, 46..54)?)?;
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
