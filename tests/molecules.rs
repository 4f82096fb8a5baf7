//! Molecules and point sets: the three solids on balls with known answers, the shared
//! molecules' edge cases, PDB and PQR agreement, and errors that name the line.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use harmap::input::molecule::{read, MoleculeOptions};

fn harmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(["--progress", "never"])
        .args(args)
        .output()
        .expect("the harmap binary runs")
}

fn solid(run: &Path) -> Vec<bool> {
    crate::common::read_labels(run)
        .1
        .iter()
        .map(|&l| (1..=3).contains(&l))
        .collect()
}

fn voxelize(input: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "voxelize",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--force",
    ];
    args.extend_from_slice(extra);
    harmap(&args)
}

fn ok(o: &Output) {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// One ball: vdW, SAS and SES are balls of radius r, r + probe and r (a probe rolling on
/// a single sphere touches all of it). Voxel counts against the volumes, and SES = vdW
/// voxel for voxel.
#[test]
fn one_atom_gives_balls_and_its_ses_is_its_vdw_ball() {
    let d = tempfile::tempdir().unwrap();
    let xyzr = write(d.path(), "one.xyzr", "0 0 0 3.0\n");
    let mut counts = Vec::new();
    for s in ["vdw", "sas", "ses"] {
        let out = d.path().join(format!("{s}.harmap"));
        ok(&voxelize(
            &xyzr,
            &out,
            &["--spacing", "0.25", "--surface", s, "--probe", "1.0"],
        ));
        let v = solid(&out);
        counts.push(v.iter().filter(|&&b| b).count() as f64 * 0.25f64.powi(3));
    }
    let ball = |r: f64| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    assert!(
        (counts[0] / ball(3.0) - 1.0).abs() < 0.02,
        "vdW volume {}",
        counts[0]
    );
    assert!(
        (counts[1] / ball(4.0) - 1.0).abs() < 0.02,
        "SAS volume {}",
        counts[1]
    );
    // The grids differ (SES and SAS runs are padded by the probe, 4 voxels) but their
    // voxel centers lie on the same lattice around the atom: the SES has exactly the
    // vdW voxels.
    assert!(
        (counts[0] - counts[2]).abs() < 1e-9,
        "SES of one atom differs from its vdW ball: {} vs {}",
        counts[0],
        counts[2]
    );
}

/// Two touching atoms: the SES fills the crevice between them (more than vdW) and stays
/// inside the SAS; a probe larger than the gap's reach closes more of it.
#[test]
fn two_atoms_ses_fills_the_crevice() {
    let d = tempfile::tempdir().unwrap();
    let xyzr = write(d.path(), "two.xyzr", "0 0 0 2.0\n3.5 0 0 2.0\n");
    let count = |s: &str, probe: &str| {
        let out = d.path().join(format!("{s}-{probe}.harmap"));
        ok(&voxelize(
            &xyzr,
            &out,
            &[
                "--spacing",
                "0.2",
                "--surface",
                s,
                "--probe",
                probe,
                "--padding",
                "30",
            ],
        ));
        solid(&out).iter().filter(|&&b| b).count()
    };
    let (vdw, ses, sas) = (
        count("vdw", "1.4"),
        count("ses", "1.4"),
        count("sas", "1.4"),
    );
    let ses_big = count("ses", "3.0");
    assert!(vdw < ses && ses < sas, "vdw {vdw} ses {ses} sas {sas}");
    assert!(
        ses_big > ses,
        "a larger probe reaches less of the crevice: {ses_big} vs {ses}"
    );
    // The crevice volume of two spheres of radius a at distance c with probe p is a
    // solid of revolution; it is a few percent of the vdW volume here.
    let extra = (ses - vdw) as f64 / vdw as f64;
    assert!(extra > 0.01 && extra < 0.2, "crevice share {extra}");
}

#[test]
fn shared_molecules_and_their_edge_cases() {
    let Some(dir) = crate::common::shared_data("molecules") else {
        eprintln!("skipped: ../shared/data/molecules not found");
        return;
    };
    let d = tempfile::tempdir().unwrap();
    // The hollow C60 cage: its occupancy and B-factor columns hold inf; the cavity is
    // filled. In the SES, the cage's inside has room for a probe that cannot get in: a
    // cavity of the probe-center space, solid from the start; in the vdW solid, an
    // enclosed void the voxel fill fills.
    let result = |surface: &str| {
        let out = d.path().join(format!("c60-{surface}.harmap"));
        let o = voxelize(
            &dir.join("fullerene.pdb.gz"),
            &out,
            &["--spacing", "0.5", "--surface", surface],
        );
        ok(&o);
        let attrs = harmap::run::RunDir::open(&out).unwrap().attrs().unwrap();
        let n = |k: &str| {
            attrs
                .pointer(&format!("/stages/voxelize/result/{k}"))
                .and_then(serde_json::Value::as_u64)
                .unwrap()
        };
        (
            n("probe_cavities"),
            n("cavities_filled"),
            solid(&out),
            attrs,
        )
    };
    let (probe_cavities, filled, ses, attrs) = result("ses");
    assert_eq!(
        (probe_cavities, filled),
        (1, 0),
        "the cage's inside is a probe cavity"
    );
    let (probe_cavities, filled, vdw, _) = result("vdw");
    assert_eq!(probe_cavities, 0);
    assert!(filled >= 1, "the cage's cavity was not filled");
    let inside = |s: &[bool]| s.iter().filter(|&&b| b).count();
    assert!(
        inside(&ses) > inside(&vdw),
        "the SES fills the cage's crevices too"
    );
    assert_eq!(
        attrs.pointer("/grid/unit").and_then(|u| u.as_str()),
        Some("angstrom")
    );
    // Radii 0 in a PQR: table radii with a warning.
    let o = voxelize(
        &dir.join("1A80.pqr"),
        &d.path().join("a.harmap"),
        &["--spacing", "0.5", "--allow-genus"],
    );
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("radius 0") && err.contains("Bondi"), "{err}");
    // Waters are left out and said so.
    let o = voxelize(
        &dir.join("1aki.pdb"),
        &d.path().join("k.harmap"),
        &["--spacing", "0.7"],
    );
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("HOH x78"));
}

/// adk_open.pdb and adk_open.pqr hold the same heavy atoms (pdb2pqr moved some
/// hydrogens): with the hydrogens left out of both and the PQR's radii set to the table
/// radii harmap gives the PDB's atoms, the two readers give the same labels.
#[test]
fn pdb_and_pqr_of_one_molecule_give_the_same_labels() {
    let Some(dir) = crate::common::shared_data("molecules") else {
        eprintln!("skipped: ../shared/data/molecules not found");
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let hydrogen = |name: &str| {
        name.trim_start_matches(|c: char| c.is_ascii_digit())
            .starts_with('H')
    };
    let pdb_text = std::fs::read_to_string(dir.join("adk_open.pdb")).unwrap();
    let heavy_pdb: String = pdb_text
        .lines()
        .filter(|l| !(l.starts_with("ATOM") && hydrogen(l[12..16].trim())))
        .map(|l| l.to_owned() + "\n")
        .collect();
    let pdb_path = write(d.path(), "adk_heavy.pdb", &heavy_pdb);
    let pdb = read(
        &pdb_path,
        "pdb",
        heavy_pdb.as_bytes(),
        &MoleculeOptions::default(),
    )
    .unwrap();
    let key = |x: f64, y: f64, z: f64| [x, y, z].map(|c| (c * 1000.0).round() as i64);
    let radius: std::collections::HashMap<[i64; 3], f64> = pdb
        .atoms
        .iter()
        .map(|a| (key(a.pos.x, a.pos.y, a.pos.z), a.radius))
        .collect();
    let mut out = String::new();
    let mut k = 0;
    for line in std::fs::read_to_string(dir.join("adk_open.pqr"))
        .unwrap()
        .lines()
    {
        let f: Vec<&str> = line.split_whitespace().collect();
        if !f.first().is_some_and(|r| *r == "ATOM" || *r == "HETATM") || hydrogen(f[2]) {
            continue;
        }
        k += 1;
        let n = f.len();
        let c: Vec<f64> = f[n - 5..n - 2].iter().map(|v| v.parse().unwrap()).collect();
        let r = radius
            .get(&key(c[0], c[1], c[2]))
            .unwrap_or_else(|| panic!("PQR heavy atom {k} at {c:?} is not in the PDB"));
        let mut g: Vec<String> = f.iter().map(|s| (*s).to_owned()).collect();
        g[n - 1] = format!("{r:.4}");
        out += &(g.join(" ") + "\n");
    }
    assert_eq!(k, pdb.atoms.len());
    let pqr = write(d.path(), "adk_heavy.pqr", &out);
    let flags = ["--spacing", "0.7", "--keep-largest", "--allow-genus"];
    let (a, b) = (d.path().join("pdb.harmap"), d.path().join("pqr.harmap"));
    ok(&voxelize(&pdb_path, &a, &flags));
    ok(&voxelize(&pqr, &b, &flags));
    assert!(
        crate::common::read_labels(&a).1 == crate::common::read_labels(&b).1,
        "labels differ"
    );
}

/// adk_open at 0.5 Angstrom: a pocket of about 1,000 voxels behind a mouth that passes a
/// probe of 1.10 Angstrom, not 1.4 (atoms ND2 ASN 102, CD LYS 97, HB3 ASN 190), whose
/// probe balls come within a voxel of the solvent's. It is a cavity of the
/// probe-center space, so solid; the voxel fill alone saw it open, and a tunnel (genus
/// 1) through its mouth.
#[test]
fn adk_open_pocket_behind_a_narrow_mouth_is_solid() {
    let Some(dir) = crate::common::shared_data("molecules") else {
        eprintln!("skipped: ../shared/data/molecules not found");
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("adk.harmap");
    // Genus 0 now: no --allow-genus (one stray voxel needs --keep-largest).
    ok(&voxelize(
        &dir.join("adk_open.pqr"),
        &out,
        &["--spacing", "0.5", "--keep-largest"],
    ));
    let attrs = harmap::run::RunDir::open(&out).unwrap().attrs().unwrap();
    let cavities = attrs
        .pointer("/stages/voxelize/result/probe_cavities")
        .and_then(serde_json::Value::as_u64)
        .unwrap();
    assert!(cavities >= 1, "{cavities}");
    let (spec, labels) = crate::common::read_labels(&out);
    let at = |x: f64, y: f64, z: f64| {
        let v = spec
            .nearest_voxel(harmap::math::Vec3::new(x, y, z))
            .unwrap();
        let s = spec.shape;
        labels[((v[0] * s[1] + v[1]) * s[2] + v[2]) as usize]
    };
    // The pocket's deepest probe center, and its middle.
    for p in [(1.77, 25.65, 7.25), (1.63, 24.82, 6.78)] {
        assert!((1..=3).contains(&at(p.0, p.1, p.2)), "{p:?} is not solid");
    }
}

#[test]
fn bad_molecule_files_are_refused_with_the_line() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("x.harmap");
    for (name, text, expect) in [
        ("empty.pdb", "", "no atoms"),
        (
            "none.pdb",
            "HEADER    NOTHING\nREMARK   1\nEND\n",
            "no atoms",
        ),
        (
            "text.pdb",
            "ATOM      1  N   MET A   1      27.340  24.430   2.614  1.00  9.67           N\n\
             ATOM      2  CA  MET A   1      26.266  2x.413   2.842  1.00 10.38           C\n",
            "text.pdb:2: y (columns 39-46) is `2x.413`",
        ),
        ("short.pqr", "ATOM 1 N MET 1 1.0 2.0\n", "short.pqr:1:"),
        (
            "bad.xyzr",
            "1 2 3 1.5\n1 2 nan 1.5\n",
            "bad.xyzr:2: z is `nan`",
        ),
        ("pts.csv", "x,y,z\n1,2,3\n", "--radius"),
    ] {
        let p = write(d.path(), name, text);
        let o = voxelize(&p, &run, &[]);
        assert_eq!(
            o.status.code(),
            Some(2),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(expect), "{name}: {err}");
        assert!(!run.exists(), "{name}: a run was left behind");
    }
    // A point set with a radius works.
    let p = write(d.path(), "pts.csv", "x,y,z\n0,0,0\n1.5,0,0\n");
    ok(&voxelize(
        &p,
        &run,
        &["--radius", "1.0", "--spacing", "0.2"],
    ));
}
