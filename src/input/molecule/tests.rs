//! Tests of the readers through [`super::read`].

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
    let e =
        pdb(&["ATOM      1  N   MET A   1      27.340     inf   2.614  1.00  9.67           N"])
            .unwrap_err()
            .to_string();
    assert!(e.contains("inf") && e.contains("finite"), "{e}");
    let e = pdb(&["REMARK nothing here"]).unwrap_err().to_string();
    assert!(e.contains("no atoms"), "{e}");
}

/// A non-ASCII character straddling the coordinate columns is an error naming the
/// line (it used to panic on a slice inside a character).
#[test]
fn non_ascii_near_the_coordinates_is_an_error() {
    for at in 28..33 {
        let mut line: Vec<char> =
            "ATOM      1  N   MET A   1      27.340  24.430   2.614  1.00  9.67           N"
                .chars()
                .collect();
        line[at] = '\u{e9}';
        let line: String = line.into_iter().collect();
        let e = pdb(&["REMARK ok", &line]).unwrap_err().to_string();
        assert!(e.contains("t.pdb:2"), "{e}");
    }
}

/// Coordinates far beyond the atoms' size are refused before anything is sized
/// from them.
#[test]
fn far_atoms_are_refused() {
    let e = pdb(&[
        "ATOM      1  N   MET A   1      27.340  24.430   2.614  1.00  9.67           N",
        "ATOM      2  N   MET A   1      27.340  24.430 9.9e+15  1.00  9.67           N",
    ])
    .unwrap_err()
    .to_string();
    assert!(e.contains("t.pdb:2") && e.contains("9.900e15"), "{e}");
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
    // Radius 0 beside real radii: no volume, as in APBS.
    assert_eq!(m.atoms.len(), 1, "{:?}", m.atoms);
    assert!((m.atoms[0].radius - 1.5).abs() < 1e-12);
    assert!(m.warnings.iter().any(|w| w.contains("radius 0")));
    // Every radius 0: the file lacks radii, and the table's are used.
    let none = "ATOM      1  N   ASP   152      21.554  34.953  27.691 -0.4000 0.0000\n\
                    ATOM     18  HA  ASP   152      21.052  36.602  28.719  0.0000 0.0000\n";
    let m = read(
        Path::new("x.pqr"),
        "pqr",
        none.as_bytes(),
        &MoleculeOptions::default(),
    )
    .unwrap();
    assert_eq!(m.atoms.len(), 2);
    assert!((m.atoms[0].radius - 1.55).abs() < 1e-12, "N's table radius");
    assert!((m.atoms[1].radius - 1.2).abs() < 1e-12, "H's table radius");
    assert!(m.warnings.iter().any(|w| w.contains("lacks radii")));

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
