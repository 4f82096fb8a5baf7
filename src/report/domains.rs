//! The atom nearest each seed of a molecule run: which chain and residue a seed lies on.
//!
//! The run keeps no atoms, so this reads the run's input file again (`input.path`), with
//! the options it was read with (`input.molecule`), after checking that the file is
//! still there and its SHA-256 is the one recorded when it was voxelized.

use std::path::Path;

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use serde_json::Value;

use super::ReportError;
use crate::input::molecule::{self, Atom, Molecule, MoleculeOptions};
use crate::run::RunDir;

/// A named stretch of residues `first..=last`, of one chain or of every chain.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Domain {
    /// The name in the legend (several stretches may share one).
    pub name: String,
    /// The chain id, or `None` for any chain.
    pub chain: Option<String>,
    /// First residue number.
    pub first: i32,
    /// Last residue number.
    pub last: i32,
}

impl Domain {
    /// Whether `a` is in the domain.
    #[must_use]
    pub fn contains(&self, a: &Atom) -> bool {
        (self.first..=self.last).contains(&a.seq)
            && self.chain.as_ref().is_none_or(|c| *c == a.chain)
    }

    /// `A:30-59` or `30-59`.
    #[must_use]
    pub fn range(&self) -> String {
        match &self.chain {
            Some(c) => format!("{c}:{}-{}", self.first, self.last),
            None => format!("{}-{}", self.first, self.last),
        }
    }
}

/// Parse `NAME=[CHAIN:]FIRST-LAST,...` (`NMP=30-59,LID=122-159`, `hinge=A:1-9`).
pub fn parse_domains(s: &str) -> Result<Vec<Domain>, String> {
    let bad = |part: &str, why: &str| {
        format!("`{part}`: {why}; write domains as NAME=FIRST-LAST or NAME=CHAIN:FIRST-LAST, separated by commas (NMP=30-59,LID=122-159)")
    };
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (name, range) = part.split_once('=').ok_or_else(|| bad(part, "no `=`"))?;
        let name = name.trim();
        if name.is_empty() {
            return Err(bad(part, "no name before `=`"));
        }
        let (chain, range) = match range.split_once(':') {
            Some((c, r)) => (Some(c.trim().to_owned()), r),
            None => (None, range),
        };
        // A leading minus belongs to the first number (residue -3 exists).
        let cut = range
            .char_indices()
            .skip(1)
            .find(|&(_, c)| c == '-')
            .map(|(k, _)| k)
            .ok_or_else(|| bad(part, "no `-` between the first and last residue"))?;
        let number = |t: &str| {
            t.trim()
                .parse::<i32>()
                .map_err(|_| bad(part, &format!("`{}` is not a residue number", t.trim())))
        };
        let (first, last) = (number(&range[..cut])?, number(&range[cut + 1..])?);
        if first > last {
            return Err(bad(part, "the first residue is after the last"));
        }
        out.push(Domain {
            name: name.to_owned(),
            chain,
            first,
            last,
        });
    }
    if out.is_empty() {
        return Err(
            "no domains given; write them as NAME=FIRST-LAST,... (NMP=30-59,LID=122-159)".into(),
        );
    }
    Ok(out)
}

/// The run's input molecule, as it was read for the voxelization. `what` names the
/// coloring that needs it, for messages.
pub fn input_molecule(run: &RunDir, what: &str) -> Result<Molecule, crate::Error> {
    let attrs = run.attrs()?;
    let input = attrs.get("input").cloned().unwrap_or(Value::Null);
    let format = input.get("format").and_then(Value::as_str).unwrap_or("");
    let unavailable = |m: String| crate::Error::from(ReportError::Unavailable(m));
    let path = input.get("path").and_then(Value::as_str);
    let Some(path) = path.filter(|_| molecule::is_molecule(format)) else {
        let what_input = match (input.get("builtin").and_then(Value::as_str), path) {
            (Some(b), _) => format!("the built-in {b}"),
            (None, Some(p)) => p.to_owned(),
            (None, None) => "not a file".to_owned(),
        };
        return Err(unavailable(format!(
            "{}: --color {what} colors by the atoms of a molecule, and this run's input is {what_input}; use --color axis, z or distance",
            run.root().display()
        )));
    };
    let path = Path::new(path);
    if !path.is_file() {
        return Err(unavailable(format!(
            "{}: the run's input molecule is not there (the path recorded when it was voxelized); --color {what} reads its atoms again: put the file back, or use --color axis, z or distance",
            path.display()
        )));
    }
    if let Some(want) = input.get("sha256").and_then(Value::as_str) {
        if crate::input::sha256_file(path)? != want {
            return Err(unavailable(format!(
                "{}: the file changed since it was voxelized (sha256 differs), so its atoms may not be the run's; voxelize it again, or use --color axis, z or distance",
                path.display()
            )));
        }
    }
    let opts: MoleculeOptions = input
        .get("molecule")
        .and_then(|o| serde_json::from_value(o.clone()).ok())
        .unwrap_or_default();
    let bytes = crate::input::read_bytes(path)?;
    Ok(molecule::read(path, format, &bytes, &opts)?)
}

/// For each of `points` (world coordinates), the index of the atom of `m` whose center
/// is nearest.
///
/// # Performance
/// A k-d tree of the atom centers; O(log atoms) per point, points in parallel.
#[must_use]
pub fn nearest_atoms(m: &Molecule, points: &[DVec3]) -> Vec<usize> {
    let centers: Vec<[f64; 3]> = m.atoms.iter().map(|a| a.pos.to_array()).collect();
    if centers.is_empty() {
        return Vec::new();
    }
    let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&centers);
    points
        .par_iter()
        .map(|p| tree.nearest_one::<SquaredEuclidean>(&p.to_array()).item as usize)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::molecule::Atom;

    #[test]
    fn domains_parse_and_contain() {
        let d = parse_domains("NMP=30-59, LID=A:122-159,neg=-5--1").unwrap();
        assert_eq!(d.len(), 3);
        assert_eq!((d[0].first, d[0].last, d[0].chain.clone()), (30, 59, None));
        assert_eq!(d[1].range(), "A:122-159");
        assert_eq!((d[2].first, d[2].last), (-5, -1));
        let mut a = Atom {
            pos: DVec3::ZERO,
            radius: 1.5,
            element: "C".into(),
            residue: "GLY".into(),
            chain: "B".into(),
            seq: 130,
            line: 1,
        };
        assert!(!d[1].contains(&a), "chain B is not in A:122-159");
        a.chain = "A".into();
        assert!(d[1].contains(&a));
        for bad in ["", "NMP", "=1-2", "X=1", "X=a-3", "X=9-3"] {
            assert!(parse_domains(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn each_point_gets_the_nearest_center() {
        let atom = |x: f64, seq: i32| Atom {
            pos: DVec3::new(x, 0.0, 0.0),
            radius: 1.5,
            element: "C".into(),
            residue: "GLY".into(),
            chain: "A".into(),
            seq,
            line: 1,
        };
        let m = Molecule {
            atoms: vec![atom(0.0, 1), atom(10.0, 2), atom(10.0, 3), atom(20.0, 4)],
            ..Molecule::default()
        };
        let near = nearest_atoms(
            &m,
            &[
                DVec3::new(-3.0, 1.0, 0.0),
                DVec3::new(16.0, 0.0, 2.0),
                DVec3::new(9.0, -1.0, 0.0),
            ],
        );
        assert_eq!(near[0], 0);
        assert_eq!(near[1], 3);
        assert!(near[2] == 1 || near[2] == 2, "{near:?}");
    }
}
