//! Reliability (issue 30): exports never destroy what they did not write, damaged or
//! missing chunks are errors naming the array and the chunk, inputs are read within
//! `--mem`, coordinates and grid sizes are checked before anything is allocated, and
//! `--threads` is capped. Small grids; every case runs the `harmap` binary and checks
//! the exit code, the message and what is left on disk.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use harmap::math::Vec3;

use crate::common::{sphere, write_obj};

fn harmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(["--progress", "never"])
        .args(args)
        .output()
        .expect("the harmap binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Run harmap; expect `code` and every piece of `expect` in stderr, and no panic.
fn expect(args: &[&str], code: i32, expect: &[&str]) -> String {
    let o = harmap(args);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?}:\n{err}");
    for e in expect {
        assert!(err.contains(e), "{args:?}: message lacks {e:?}:\n{err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    err
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `args` followed by `extra`.
fn with<'a>(extra: &[&'a str], args: &[&'a str]) -> Vec<&'a str> {
    [args, extra].concat()
}

/// A sphere run through every stage (`harmap run`) at a small resolution.
fn finished_run(dir: &Path) -> PathBuf {
    let obj = dir.join("ball.obj");
    write_obj(&obj, &sphere(Vec3::ZERO, 1.0, 16, 32));
    let run = dir.join("ball.harmap");
    expect(
        &["run", s(&obj), "-o", s(&run), "--resolution", "20"],
        0,
        &[],
    );
    run
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn exports_never_destroy_what_they_did_not_write() {
    let d = tempfile::tempdir().unwrap();
    let run = finished_run(d.path());
    let r = s(&run);
    let docs = d.path().join("docs");
    std::fs::create_dir(&docs).unwrap();
    std::fs::write(docs.join("thesis.txt"), b"years of work").unwrap();
    let notes = d.path().join("notes.nii");
    std::fs::write(&notes, b"not an image").unwrap();
    let before = snapshot(&run);
    for force in [&[][..], &["--force"][..]] {
        // A folder of someone's documents, the run itself, the run's metadata.
        expect(
            &with(
                force,
                &["export", r, "--format", "ome-zarr", "-o", s(&docs)],
            ),
            2,
            &["docs", "not a harmap ome-zarr export"],
        );
        expect(
            &with(force, &["export", r, "--format", "ome-zarr", "-o", r]),
            2,
            &["run directory"],
        );
        let meta = run.join("zarr.json");
        expect(
            &with(force, &["export", r, "--format", "nifti", "-o", s(&meta)]),
            2,
            &["zarr.json", "run"],
        );
    }
    assert_eq!(
        std::fs::read(docs.join("thesis.txt")).unwrap(),
        b"years of work"
    );
    assert_eq!(snapshot(&run), before, "the run was changed");
    // A file harmap did not write: only with --force.
    expect(
        &["export", r, "--format", "nifti", "-o", s(&notes)],
        2,
        &["not a harmap nifti export", "--force"],
    );
    assert_eq!(std::fs::read(&notes).unwrap(), b"not an image");
    expect(
        &["export", r, "--format", "nifti", "-o", s(&notes), "--force"],
        0,
        &[],
    );
    // Its own earlier output of the same format: replaced without --force; another
    // format's output is not its own.
    let out = d.path().join("out");
    std::fs::create_dir(&out).unwrap();
    for (fmt, name) in [
        ("nifti", "phi.nii"),
        ("nifti", "phi.nii.gz"),
        ("vti", "all.vti"),
        ("dx", "phi.dx"),
        ("csv", "seeds.csv"),
        ("obj-sphere", "sphere.obj"),
        ("ome-zarr", "img.ome.zarr"),
    ] {
        let p = out.join(name);
        for _ in 0..2 {
            expect(&["export", r, "--format", fmt, "-o", s(&p)], 0, &[]);
        }
    }
    expect(
        &["export", r, "--format", "dx", "-o", s(&out.join("phi.nii"))],
        2,
        &["not a harmap dx export"],
    );
    // Inside the run: a new file only with --force.
    let inside = run.join("extra.nii");
    expect(
        &["export", r, "--format", "nifti", "-o", s(&inside)],
        2,
        &["inside the run directory"],
    );
    assert!(!inside.exists());
    expect(
        &[
            "export",
            r,
            "--format",
            "nifti",
            "-o",
            s(&inside),
            "--force",
        ],
        0,
        &[],
    );
    // Nothing half-written is left anywhere.
    for dir in [d.path(), out.as_path(), run.as_path()] {
        for e in std::fs::read_dir(dir).unwrap() {
            let n = e.unwrap().file_name().to_string_lossy().into_owned();
            assert!(!n.contains(".partial"), "{n} left in {}", dir.display());
        }
    }
}

#[test]
fn partial_files_of_killed_exports_are_swept() {
    let d = tempfile::tempdir().unwrap();
    let run = finished_run(d.path());
    let out = d.path().join("phi.nii");
    // What exports killed earlier left: a file and (OME-Zarr) a folder. No process has
    // an id this large (Linux's limit is 2^22).
    let dead = d.path().join(".phi.nii.partial-999999999");
    std::fs::write(&dead, vec![7u8; 4096]).unwrap();
    let zdest = d.path().join("img.zarr");
    let zdead = d.path().join(".img.zarr.partial-999999998");
    std::fs::create_dir_all(zdead.join("phi")).unwrap();
    // Another destination's leftovers are not this export's to remove.
    let other = d.path().join(".other.nii.partial-999999999");
    std::fs::write(&other, b"x").unwrap();
    expect(
        &["export", s(&run), "--format", "nifti", "-o", s(&out)],
        0,
        &[],
    );
    expect(
        &["export", s(&run), "--format", "ome-zarr", "-o", s(&zdest)],
        0,
        &[],
    );
    assert!(out.is_file() && zdest.is_dir());
    assert!(!dead.exists() && !zdead.exists());
    assert!(other.exists());
}

/// Flip one byte in the middle of `file`.
fn flip(file: &Path) {
    let mut b = std::fs::read(file).unwrap();
    let k = b.len() / 2;
    b[k] ^= 0x40;
    std::fs::write(file, b).unwrap();
}

#[test]
fn damaged_and_missing_chunks_are_errors_naming_array_and_chunk() {
    let d = tempfile::tempdir().unwrap();
    let run = finished_run(d.path());
    let r = s(&run);
    let nii = d.path().join("x.nii");
    // A flipped byte in a phi chunk.
    flip(&run.join("phi/0/c/0/0/0"));
    expect(
        &["export", r, "--format", "nifti", "-o", s(&nii)],
        2,
        &["/phi/0", "[0, 0, 0]", "run the stage that writes"],
    );
    assert!(!nii.exists());
    // A deleted labels chunk: missing, not the fill value.
    std::fs::remove_file(run.join("labels/0/c/0/0/0")).unwrap();
    expect(
        &[
            "export",
            r,
            "--format",
            "nifti",
            "--field",
            "labels",
            "-o",
            s(&nii),
        ],
        2,
        &["/labels/0", "[0, 0, 0]", "missing"],
    );
    // One value changed in the raw u, which the map reads in place.
    let u = run.join("u/0/c/0/0/0");
    let mut b = std::fs::read(&u).unwrap();
    let k = (b.len() / 2) & !7;
    b[k..k + 8].copy_from_slice(&0.5f64.to_le_bytes());
    std::fs::write(&u, b).unwrap();
    expect(&["map", r], 2, &["/u/0", "[0, 0, 0]", "checksum"]);
}

/// A name with `ext` for the endless stream of zeros.
fn zeros(dir: &Path, ext: &str) -> PathBuf {
    let p = dir.join(format!("zero.{ext}"));
    std::os::unix::fs::symlink("/dev/zero", &p).unwrap();
    p
}

#[test]
fn endless_and_bomb_inputs_are_refused_within_memory() {
    let d = tempfile::tempdir().unwrap();
    let mut inputs: Vec<PathBuf> = ["obj", "stl", "pdb", "pqr", "ply"]
        .iter()
        .map(|e| zeros(d.path(), e))
        .collect();
    // 64 MiB of zeros, gzip-compressed to a few tens of KiB.
    let bomb = d.path().join("bomb.obj.gz");
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    std::io::Write::write_all(&mut enc, &vec![0u8; 64 << 20]).unwrap();
    std::fs::write(&bomb, enc.finish().unwrap()).unwrap();
    inputs.push(bomb);
    for input in &inputs {
        let out = d.path().join("r.harmap");
        let t = Instant::now();
        expect(
            &["voxelize", s(input), "-o", s(&out), "--mem", "64MiB"],
            2,
            &["larger than the readers may hold", "by byte", "--mem"],
        );
        assert!(
            t.elapsed() < Duration::from_secs(45),
            "{input:?} took {:?}",
            t.elapsed()
        );
        assert!(!out.exists());
    }
}

#[test]
fn far_atoms_and_huge_grids_are_refused_readably() {
    let d = tempfile::tempdir().unwrap();
    let atom = |x: &str| {
        format!("ATOM      1  CA  ALA A   1    {x:>8}   0.000   0.000  1.00  0.00           C\n")
    };
    let apart = d.path().join("apart.pdb");
    std::fs::write(&apart, atom("0.000") + &atom("1.0e15")).unwrap();
    let far = d.path().join("far.pdb");
    std::fs::write(&far, atom("1.0e9")).unwrap();
    let out = d.path().join("r.harmap");
    for pdb in [&apart, &far] {
        expect(
            &["voxelize", s(pdb), "-o", s(&out)],
            2,
            &[
                pdb.file_name().unwrap().to_str().unwrap(),
                "e",
                "from the origin",
            ],
        );
    }
    let obj = d.path().join("ball.obj");
    write_obj(&obj, &sphere(Vec3::ZERO, 1.0, 8, 16));
    let e = expect(
        &["voxelize", s(&obj), "-o", s(&out), "--resolution", "100000"],
        2,
        &["--resolution 100000", "e5 x"],
    );
    assert!(!e.contains("18446744073709551615"), "{e}");
    let e = expect(
        &["voxelize", s(&obj), "-o", s(&out), "--spacing", "1e-300"],
        2,
        &["--spacing 1e-300"],
    );
    assert!(e.len() < 1000, "{e}");
    assert!(!out.exists());
}

#[test]
fn pqr_radius_zero_means_no_volume_unless_every_radius_is_zero() {
    use harmap::input::molecule::{read, MoleculeOptions};
    let rec = |n: u32, name: &str, x: f64, r: f64| {
        format!("ATOM  {n:>5} {name:<4} ALA   1    {x:8.3} 0.000 0.000 0.0000 {r:.4}\n")
    };
    let o = MoleculeOptions::default();
    let mixed = rec(1, "N", 0.0, 1.85) + &rec(2, "HO", 0.9, 0.0) + &rec(3, "C", 1.5, 1.9);
    let m = read(Path::new("m.pqr"), "pqr", mixed.as_bytes(), &o).unwrap();
    assert_eq!(m.atoms.len(), 2, "{:?}", m.atoms);
    assert!(m.atoms.iter().all(|a| a.radius > 1.0));
    let none = rec(1, "N", 0.0, 0.0) + &rec(2, "HO", 0.9, 0.0);
    let m = read(Path::new("n.pqr"), "pqr", none.as_bytes(), &o).unwrap();
    let radii: Vec<f64> = m.atoms.iter().map(|a| a.radius).collect();
    assert_eq!(radii, vec![1.55, 1.2], "Bondi's N and H");
    assert!(m.warnings.iter().any(|w| w.contains("lacks radii")));
}

#[test]
fn threads_are_capped_with_a_warning() {
    let d = tempfile::tempdir().unwrap();
    let obj = d.path().join("ball.obj");
    write_obj(&obj, &sphere(Vec3::ZERO, 1.0, 8, 16));
    let out = d.path().join("r.harmap");
    let t = Instant::now();
    expect(
        &[
            "--threads",
            "10000",
            "voxelize",
            s(&obj),
            "-o",
            s(&out),
            "--resolution",
            "32",
        ],
        0,
        &["warning", "--threads 10000", "per core"],
    );
    assert!(t.elapsed() < Duration::from_secs(45), "{:?}", t.elapsed());
    assert!(out.is_dir());
}

/// Every file or folder under `dir` whose name holds a temporary mark: what a failed or
/// killed write left.
fn leftovers(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            if name.contains(".partial") || name.contains(".tmp-") || name.contains(".old-") {
                out.push(p.clone());
            }
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
    out
}

/// `harmap ARGS` with every file it writes limited to `kib` KiB (RLIMIT_FSIZE, as
/// `ulimit -f` sets it, with SIGXFSZ ignored so that writes fail with EFBIG): a disk
/// that fills up, without mounting anything.
fn with_file_limit(kib: u64, args: &[&str]) -> Output {
    let words: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    Command::new("sh")
        .arg("-c")
        .arg(format!(
            "trap '' XFSZ; ulimit -f {}; exec '{}' --progress never {}",
            2 * kib,
            env!("CARGO_BIN_EXE_harmap"),
            words.join(" ")
        ))
        .output()
        .expect("sh runs")
}

#[test]
fn failed_writes_on_a_full_disk_leave_nothing_and_leftovers_are_swept() {
    let d = tempfile::tempdir().unwrap();
    let run = finished_run(d.path());
    let r = s(&run);
    let before = snapshot(&run);
    let nii = d.path().join("phi.nii");
    let zarr = d.path().join("phi.zarr");
    let vti = d.path().join("phi.vti");
    // The map goes last: it forgets its record as it starts (a map stopped half-way
    // must not look done), so the run is no longer unchanged after it.
    let cases: [Vec<&str>; 6] = [
        vec!["export", r, "--format", "nifti", "-o", s(&nii)],
        vec!["export", r, "--format", "ome-zarr", "-o", s(&zarr)],
        vec!["export", r, "--format", "vti", "-o", s(&vti)],
        vec!["solve", r, "--rtol", "1e-7"],
        vec!["trace", r, "--seeds", "surface"],
        vec!["map", r, "--exact"],
    ];
    for args in &cases {
        // 8 KiB per file: every stage and export here writes a larger file.
        let o = with_file_limit(8, args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}:\n{err}");
        assert!(err.contains("File too large"), "{args:?}:\n{err}");
        assert!(!err.contains("panicked"), "{err}");
        let left = leftovers(d.path());
        assert!(left.is_empty(), "{args:?} left {left:?}");
        assert!(
            !run.join("map.scratch").exists(),
            "{args:?} left map.scratch"
        );
        assert!(!nii.exists() && !zarr.exists() && !vti.exists(), "{args:?}");
        if args[0] != "map" {
            assert!(snapshot(&run) == before, "{args:?} changed the run");
        }
    }
    // What killed writes left is swept by the next write of the same target.
    let dead = [
        run.join("phi.partial"),
        run.join("u.partial"),
        run.join("seeds.partial"),
        run.join("theta.partial"),
        run.join("phi.old-999999999"),
    ];
    for p in &dead {
        std::fs::create_dir_all(p.join("0")).unwrap();
        std::fs::write(p.join("0").join("junk"), vec![1u8; 4096]).unwrap();
    }
    let meta = run.join(".zarr.json.tmp-999999999");
    std::fs::write(&meta, b"{").unwrap();
    expect(&["solve", r, "--rtol", "1e-7"], 0, &[]);
    expect(&["trace", r, "--seeds", "surface"], 0, &[]);
    expect(&["map", r], 0, &[]);
    let left = leftovers(d.path());
    assert!(left.is_empty(), "left {left:?}");
}

/// A `harmap run` of `args` (after `--verbose --progress never`), signalled with
/// `signal` `after` the phase whose name starts with `phase` begins. Returns the exit
/// code, the seconds from the signal to the exit, and stderr.
fn signalled_run(
    args: &[String],
    phase: &str,
    after: Duration,
    signal: &str,
) -> (i32, f64, String) {
    use std::io::{BufRead, BufReader, Read};
    let mut child = Command::new(&args[0])
        .args(&args[1..])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut text = String::new();
    let mut line = String::new();
    let mut sent = None;
    while err.read_line(&mut line).unwrap() > 0 {
        text.push_str(&line);
        if line.starts_with(phase) {
            std::thread::sleep(after);
            let k = Command::new("kill")
                .args([signal, &child.id().to_string()])
                .status()
                .unwrap();
            assert!(k.success());
            sent = Some(Instant::now());
            break;
        }
        line.clear();
    }
    err.read_to_string(&mut text).unwrap();
    let status = child.wait().unwrap();
    let sent = sent.unwrap_or_else(|| panic!("no phase {phase:?} in:\n{text}"));
    (
        status.code().unwrap_or(-1),
        sent.elapsed().as_secs_f64(),
        text,
    )
}

#[test]
fn run_stops_within_a_second_in_every_stage_and_the_printed_command_continues() {
    let Some(pdb) = crate::common::shared_data("molecules/1crn.pdb") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("crn.harmap");
    // 100 x 86 x 100 voxels: each stage lasts a second or more here (the solve by SOR),
    // except voxelize, whose passes after the solid take a few hundred milliseconds: its
    // signal goes out 20 ms after the header line, during the probe-space pass.
    let first: Vec<String> = [
        env!("CARGO_BIN_EXE_harmap"),
        "--verbose",
        "--progress",
        "never",
        "run",
        s(&pdb),
        "-o",
        s(&run),
        "--resolution",
        "88",
        "--method",
        "sor",
    ]
    .map(str::to_owned)
    .to_vec();
    // Each stop continues with the command the previous stop printed.
    let moments = [
        ("voxelize: molecular solid", 20, "-INT", 130, "voxelize"),
        ("solve: sor", 300, "-TERM", 143, "solve"),
        ("trace ...", 800, "-INT", 130, "trace"),
        ("map (upwind)", 100, "-TERM", 143, "map"),
    ];
    let mut cmd = first.clone();
    for (phase, ms, signal, code, stage) in moments {
        let (got, secs, err) = signalled_run(&cmd, phase, Duration::from_millis(ms), signal);
        assert_eq!(got, code, "{signal} in {phase}:\n{err}");
        assert!(
            secs < 1.0,
            "{signal} in {phase}: exit after {secs:.2} s:\n{err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            err.contains(&format!("stopped during the {stage} stage")),
            "{phase}:\n{err}"
        );
        let printed = err
            .split("Continue with `")
            .nth(1)
            .and_then(|t| t.split('`').next())
            .unwrap_or_else(|| panic!("no command to continue with:\n{err}"));
        // The printed command is the run's own, shell-quoted: run it by the shell.
        cmd = vec!["sh".into(), "-c".into(), format!("exec {printed}")];
    }
    let o = Command::new(&cmd[0]).args(&cmd[1..]).output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "the last continue:\n{err}");
    for name in ["labels", "phi", "seeds", "theta", "psi"] {
        assert!(run.join(name).is_dir(), "{name} missing");
    }
    let left = leftovers(d.path());
    assert!(left.is_empty(), "left {left:?}");
}

#[test]
fn large_probes_stay_within_the_memory_budget() {
    let Some(pdb) = crate::common::shared_data("molecules/1crn.pdb") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("probe.harmap");
    // A probe of 40 A on a 3 A grid: the probe centers on the SAS spheres are sampled
    // at a fifth of the voxel, not at 0.1 A (which took 458 MiB here).
    let o = Command::new("/usr/bin/time")
        .args(["-f", "%M"])
        .arg(env!("CARGO_BIN_EXE_harmap"))
        .args(["-q", "voxelize", s(&pdb), "-o", s(&run)])
        .args(["--spacing", "3", "--probe", "40", "--mem", "256MiB"])
        .output()
        .expect("/usr/bin/time runs");
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{err}");
    let kib: u64 = err.lines().last().unwrap().trim().parse().unwrap();
    // --mem plus the fixed allowance of docs/guide.md.
    assert!(kib <= (256 + 64) * 1024, "peak {kib} KiB:\n{err}");
}

#[test]
fn a_second_writer_is_refused_at_once_and_inverse_fails_when_no_row_gets_a_point() {
    let d = tempfile::tempdir().unwrap();
    let run = finished_run(d.path());
    let r = s(&run);
    // Every row failing (u's chunks gone) is a failure, not exit 0.
    let pts = d.path().join("pts.csv");
    std::fs::write(&pts, "phi,theta,psi\n0.5,1.0,0.5\n0.3,2.0,1.0\n").unwrap();
    let out = d.path().join("out.csv");
    expect(&["inverse", r, "--points", s(&pts), "-o", s(&out)], 0, &[]);
    let other = d.path().join("other.harmap");
    copy_dir(&run, &other);
    std::fs::remove_dir_all(other.join("u").join("0").join("c")).unwrap();
    let o = harmap(&["inverse", s(&other), "--points", s(&pts), "-o", s(&out)]);
    let err = stderr(&o);
    assert_ne!(o.status.code(), Some(0), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    // A second process writing the same run is refused at once, naming the lock. The
    // first solves with no residual test, until it is killed.
    let mut first = Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args([
            "-q",
            "--progress",
            "never",
            "solve",
            r,
            "--method",
            "jacobi",
        ])
        .args(["--rtol", "0", "--tol", "1e-300", "--max-iter", "1000000000"])
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let t = Instant::now();
    expect(
        &["solve", r, "--rtol", "1e-9"],
        2,
        &["another harmap process"],
    );
    assert!(t.elapsed() < Duration::from_secs(5));
    first.kill().unwrap();
    first.wait().unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let dest = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &dest);
        } else {
            std::fs::copy(&p, &dest).unwrap();
        }
    }
}
