//! Molecules and point sets: the three solids on balls with known answers, the shared
//! molecules' edge cases, PDB and PQR agreement, and errors that name the line.

use std::fmt::Write as _;
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
    // Radii 0 beside real radii in a PQR: no volume, as in APBS, with a warning.
    let o = voxelize(
        &dir.join("1A80.pqr"),
        &d.path().join("a.harmap"),
        &["--spacing", "0.5", "--allow-genus"],
    );
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("radius 0") && err.contains("APBS"), "{err}");
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
        ("empty.cif", "", "no atoms"),
        (
            "bad.cif",
            "data_x\nloop_\n_atom_site.type_symbol\n_atom_site.Cartn_x\n_atom_site.Cartn_y\n\
             _atom_site.Cartn_z\n_atom_site.B_iso_or_equiv\nC 1 2 3 inf\nC 1 ? 3 nan\n",
            "bad.cif:9: y (_atom_site.Cartn_y) is `?`, not a number",
        ),
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

/// A short tube, three rings of 18 carbon-sized balls 1.5 Angstrom apart, around a hole
/// 4.5 Angstrom from their centers: a probe of 1.4 or 2.5 passes through it (4.5 > r +
/// 1.7), so the SES keeps the tunnel (genus 1). A probe of 3.5 does not fit (5.2 > 4.5),
/// and from either end reaches only to 0.6 Angstrom of the middle, so the SES fills
/// the tunnel there (genus 0). `--probe
/// 1.4,2.5,3.5` takes the first genus-0 one, says so, and records the probe it kept;
/// one probe alone is refused with the advice to give several.
#[test]
fn a_probe_ladder_keeps_the_first_probe_that_gives_genus_0() {
    let d = tempfile::tempdir().unwrap();
    let mut ring = String::new();
    for k in 0..54 {
        let a = f64::from(k % 18) * std::f64::consts::TAU / 18.0;
        let z = 1.5 * f64::from(k / 18 - 1);
        writeln!(ring, "{:.4} {:.4} {z} 1.7", 4.5 * a.cos(), 4.5 * a.sin()).unwrap();
    }
    let xyzr = write(d.path(), "ring.xyzr", &ring);
    let out = d.path().join("ring.harmap");
    let one = voxelize(
        &xyzr,
        &out,
        &["--spacing", "0.3", "--probe", "1.4", "--topology", "strict"],
    );
    assert_eq!(one.status.code(), Some(2));
    let err = String::from_utf8_lossy(&one.stderr);
    assert!(
        err.contains("genus 1") && err.contains("--probe 1.4,2,3,4"),
        "{err}"
    );
    assert!(!out.exists());

    let o = voxelize(&xyzr, &out, &["--spacing", "0.3", "--probe", "1.4,2.5,3.5"]);
    ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("genus 0 at probe 3.5 Angstrom (tried 1.4: genus 1; 2.5: genus 1)"),
        "{said}"
    );
    let info = harmap(&["info", out.to_str().unwrap(), "--json"]);
    ok(&info);
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let stage = &v["harmap"]["stages"]["voxelize"];
    assert_eq!(stage["options"]["probe"], 3.5, "{stage}");
    assert_eq!(stage["result"]["genus"], 0);
    let trials = stage["result"]["probe_trials"].as_array().unwrap();
    let genus: Vec<i64> = trials
        .iter()
        .map(|t| t["genus"].as_i64().unwrap())
        .collect();
    assert_eq!(genus, [1, 1, 0]);
    let text = harmap(&["info", out.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&text.stdout).contains("probe:    genus 0 at probe 3.5"));

    // A probe ladder needs a solid that uses the probe.
    let vdw = voxelize(&xyzr, &out, &["--surface", "vdw", "--probe", "1,2"]);
    assert_eq!(vdw.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&vdw.stderr).contains("--surface vdw does not use the probe"));
}

/// One atom: (chain, residue number, element, x, y, z).
type TestAtom = (&'static str, i32, &'static str, f64, f64, f64);

/// A rod of carbon and nitrogen atoms along x: chain A then chain B, a residue per atom.
fn rod() -> Vec<TestAtom> {
    (0..11)
        .map(|k| {
            let x = 1.5 * f64::from(k);
            let chain = if k < 6 { "A" } else { "B" };
            let element = if k % 3 == 0 { "N" } else { "C" };
            (chain, k + 1, element, x, 0.3 * f64::from(k % 2), 0.0)
        })
        .collect()
}

fn pdb_text(atoms: &[TestAtom]) -> String {
    let mut s = String::from("HEADER    TEST\n");
    for (k, &(chain, seq, el, x, y, z)) in atoms.iter().enumerate() {
        let _ = writeln!(
            s,
            "ATOM  {:>5} {:<4} ALA {}{:>4}    {:>8.3}{:>8.3}{:>8.3}  1.00 10.00          {:>2}",
            k + 1,
            el,
            chain,
            seq,
            x,
            y,
            z,
            el
        );
    }
    s + "END\n"
}

/// The same atoms as mmCIF, with the columns in another order than PDB's, quoted
/// values, a comment, and `inf` in a column harmap does not read.
fn cif_text(atoms: &[TestAtom]) -> String {
    let mut s = String::from(
        "data_test\n# written by the test\n_entry.id 'TEST ROD'\nloop_\n\
         _atom_site.group_PDB\n_atom_site.id\n_atom_site.Cartn_x\n_atom_site.Cartn_y\n\
         _atom_site.Cartn_z\n_atom_site.type_symbol\n_atom_site.label_atom_id\n\
         _atom_site.label_alt_id\n_atom_site.label_comp_id\n_atom_site.label_asym_id\n\
         _atom_site.label_seq_id\n_atom_site.B_iso_or_equiv\n_atom_site.auth_seq_id\n\
         _atom_site.auth_asym_id\n_atom_site.pdbx_PDB_model_num\n",
    );
    for (k, &(chain, seq, el, x, y, z)) in atoms.iter().enumerate() {
        let _ = writeln!(
            s,
            "ATOM {} {x:.3} {y:.3} {z:.3} {el} \"{el}\" . ALA {chain}x {seq} inf {seq} '{chain}' 1",
            k + 1
        );
    }
    s + "#\n"
}

/// issue 6: an mmCIF file and a PDB file of the same atoms give the same atoms and the
/// same solid, plain, as .mmcif and gzipped.
#[test]
fn mmcif_and_pdb_of_the_same_atoms_give_the_same_solid() {
    let d = tempfile::tempdir().unwrap();
    let atoms = rod();
    let pdb = write(d.path(), "rod.pdb", &pdb_text(&atoms));
    let cif = cif_text(&atoms);
    let o = MoleculeOptions::default();
    let a = read(&pdb, "pdb", pdb_text(&atoms).as_bytes(), &o).unwrap();
    let b = read(Path::new("rod.cif"), "cif", cif.as_bytes(), &o).unwrap();
    let key = |m: &harmap::input::molecule::Molecule| {
        m.atoms
            .iter()
            .map(|a| {
                (
                    a.pos.to_array(),
                    a.radius,
                    a.element.clone(),
                    a.chain.clone(),
                    a.seq,
                )
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(key(&a), key(&b));
    assert_eq!(b.atoms[7].chain, "B");
    let gz = d.path().join("rod.mmcif.gz");
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut enc, cif.as_bytes()).unwrap();
    std::fs::write(&gz, enc.finish().unwrap()).unwrap();
    let flags = ["--spacing", "0.5"];
    let runs: Vec<PathBuf> = [pdb, write(d.path(), "rod.cif", &cif), gz]
        .iter()
        .enumerate()
        .map(|(k, input)| {
            let out = d.path().join(format!("{k}.harmap"));
            ok(&voxelize(input, &out, &flags));
            out
        })
        .collect();
    let labels = crate::common::read_labels(&runs[0]).1;
    for r in &runs[1..] {
        assert!(crate::common::read_labels(r).1 == labels, "{}", r.display());
    }
    let attrs = harmap::run::RunDir::open(&runs[2])
        .unwrap()
        .attrs()
        .unwrap();
    assert_eq!(attrs.pointer("/input/format").unwrap(), "mmcif");
    assert_eq!(
        attrs.pointer("/input/molecule/keep_hetatm"),
        Some(&serde_json::Value::Bool(false))
    );
}

/// issue 6: the atlas of a molecule run colored by the chain, residue or named domain of
/// the atom nearest each seed; refused with exit 2 for runs without atoms, for atoms
/// without residue numbers, and when the input moved or changed.
#[test]
fn the_atlas_colors_a_molecule_by_chain_residue_and_domain() {
    let d = tempfile::tempdir().unwrap();
    let pdb = write(d.path(), "rod.pdb", &pdb_text(&rod()));
    let run = d.path().join("rod.harmap");
    let r = run.to_str().unwrap();
    let o = harmap(&["run", pdb.to_str().unwrap(), "-o", r, "--spacing", "0.5"]);
    ok(&o);
    assert!(
        !String::from_utf8_lossy(&o.stderr).contains("atlas colored by the main axis"),
        "harmap run colors a PDB's atlas by residue: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(d.path().join("rod.atlas.png").is_file());
    // Every seed lies within an atom's radius plus the probe (and a voxel) of the atom
    // found for it, and the seeds at the two ends get the two chains.
    let rd = harmap::run::RunDir::open(&run).unwrap();
    let m = harmap::report::domains::input_molecule(&rd, "chain").unwrap();
    let seeds = harmap::trace::read_seeds(&rd).unwrap();
    let near = harmap::report::domains::nearest_atoms(&m, &seeds.position);
    for (p, &i) in seeds.position.iter().zip(&near) {
        let dist = (*p - m.atoms[i].pos).length();
        assert!(dist <= 1.7 + 1.4 + 0.5, "seed {p} is {dist} from its atom");
        if p.x < -1.0 {
            assert_eq!(m.atoms[i].chain, "A");
        }
        if p.x > 16.0 {
            assert_eq!(m.atoms[i].chain, "B");
        }
    }
    for extra in [
        &["--color", "chain"][..],
        &["--color", "residue"],
        &["--color", "residue", "--sphere"],
        &["--color", "domain", "--domains", "head=1-3,tail=B:9-11"],
    ] {
        let png = d.path().join("a.png");
        let _ = std::fs::remove_file(&png);
        let mut args = vec!["atlas", r, "-o", png.to_str().unwrap()];
        args.extend_from_slice(extra);
        ok(&harmap(&args));
        assert!(png.is_file(), "{extra:?}");
    }
    let refused = |run: &str, extra: &[&str], expect: &str| {
        let mut args = vec!["atlas", run, "-o", "/nonexistent/never.png"];
        args.extend_from_slice(extra);
        let o = harmap(&args);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(expect), "{extra:?}: {err}");
    };
    refused(r, &["--color", "domain"], "--domains");
    refused(
        r,
        &["--color", "chain", "--domains", "x=1-2"],
        "--color domain",
    );
    refused(r, &["--color", "domain", "--domains", "x=5"], "x=5");
    // The input changed, then moved.
    let text = std::fs::read_to_string(&pdb).unwrap();
    std::fs::write(&pdb, text.replace("HEADER    TEST", "HEADER    EDITED")).unwrap();
    refused(r, &["--color", "chain"], "sha256");
    std::fs::remove_file(&pdb).unwrap();
    refused(r, &["--color", "residue"], pdb.to_str().unwrap());
    // Balls without residues, and a mesh.
    let xyzr = write(d.path(), "two.xyzr", "0 0 0 2.0\n3 0 0 2.0\n");
    let xr = d.path().join("xyzr.harmap");
    ok(&harmap(&[
        "run",
        xyzr.to_str().unwrap(),
        "-o",
        xr.to_str().unwrap(),
        "--spacing",
        "0.4",
    ]));
    refused(
        xr.to_str().unwrap(),
        &["--color", "residue"],
        "residue number",
    );
    refused(xr.to_str().unwrap(), &["--color", "chain"], "chain id");
    let obj = d.path().join("ball.obj");
    crate::common::write_obj(
        &obj,
        &crate::common::sphere(harmap::math::Vec3::ZERO, 1.0, 12, 24),
    );
    let mr = d.path().join("ball.harmap");
    ok(&harmap(&[
        "run",
        obj.to_str().unwrap(),
        "-o",
        mr.to_str().unwrap(),
        "--resolution",
        "20",
    ]));
    refused(mr.to_str().unwrap(), &["--color", "chain"], "molecule");
}
