//! The `harmap` command: exit codes and messages for every kind of bad input, and the
//! rule that a failed run leaves no run directory behind.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use harmap::math::Vec3;
use harmap::run::RunDir;

use crate::common::{sphere, torus, write_obj};

fn harmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(args)
        .output()
        .expect("the harmap binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Run `harmap voxelize INPUT -o RUN extra...` and expect exit code 2 with every piece of
/// `expect` in the message, and no run directory (nor a staging one) left behind.
fn refused(input: &Path, extra: &[&str], expect: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.harmap");
    let mut args = vec![
        "voxelize",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = harmap(&args);
    let err = stderr(&o);
    assert_eq!(
        o.status.code(),
        Some(2),
        "exit code for {args:?}; stderr:\n{err}"
    );
    for e in expect {
        assert!(err.contains(e), "message for {args:?} lacks {e:?}:\n{err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        !out.exists() && !harmap::run::staging_path(&out).exists(),
        "a failed run left a directory"
    );
}

fn file(dir: &Path, name: &str, content: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, content).unwrap();
    p
}

fn cube_obj() -> String {
    let mut s = String::new();
    for z in [0, 1] {
        for y in [0, 1] {
            for x in [0, 1] {
                let _ = writeln!(s, "v {x} {y} {z}");
            }
        }
    }
    // Outward-wound quads of the unit cube, as OBJ polygons.
    s.push_str("f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n");
    s
}

#[test]
fn voxelize_and_info_work() {
    let dir = tempfile::tempdir().unwrap();
    let cube = file(dir.path(), "cube.obj", cube_obj().as_bytes());
    let out = dir.path().join("cube.harmap");
    let o = harmap(&[
        "voxelize",
        cube.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "16",
        "--center-radius",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = info_json(&out);
    assert_eq!(
        v["harmap"]["grid"]["shape"],
        serde_json::json!([28, 28, 28])
    );
    assert_eq!(v["summary"]["voxelize"]["genus"], 0);
    assert_eq!(v["summary"]["voxelize"]["labels"]["center"], 7);
    assert_eq!(
        v["summary"]["voxelize"]["labels"]["interior"]
            .as_u64()
            .unwrap()
            + 7
            + v["summary"]["voxelize"]["labels"]["boundary"]
                .as_u64()
                .unwrap(),
        16 * 16 * 16
    );
    let text = harmap(&["info", out.to_str().unwrap()]);
    let t = String::from_utf8_lossy(&text.stdout);
    assert!(t.contains("genus 0") && t.contains("sha256"), "{t}");
    // An existing run is not overwritten without --force.
    let o = harmap(&[
        "voxelize",
        cube.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "16",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("already exists"), "{}", stderr(&o));
}

#[test]
fn bad_files_are_refused_with_the_file_and_line() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    refused(&dir.join("missing.obj"), &[], &["missing.obj"]);
    refused(
        &file(dir, "shape.xyz3", b"1 2 3"),
        &[],
        &["shape.xyz3", "unknown input format"],
    );
    refused(&file(dir, "empty.obj", b""), &[], &["empty.obj"]);
    refused(
        &file(
            dir,
            "nan.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 3\n",
        ),
        &[],
        &["nan.obj:3"],
    );
    refused(
        &file(
            dir,
            "inf.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 inf\nf 1 2 3\n",
        ),
        &[],
        &["inf.obj:4"],
    );
    refused(
        &file(
            dir,
            "range.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n",
        ),
        &[],
        &["range.obj:5"],
    );
    refused(
        &file(dir, "text.obj", b"v 0 0 0\nv 1 zero 0\n"),
        &[],
        &["text.obj:2"],
    );
    // Binary STL whose header announces more triangles than the file holds.
    let mut stl = vec![0u8; 80];
    stl.extend_from_slice(&12u32.to_le_bytes());
    stl.extend_from_slice(&[0u8; 100]);
    refused(&file(dir, "cut.stl", &stl), &[], &["cut.stl", "truncated"]);
    // Binary PLY cut short.
    let mut ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    ply.extend_from_slice(&[0u8; 20]);
    refused(&file(dir, "cut.ply", &ply), &[], &["cut.ply"]);
    // TetGen: the header announces 5 nodes, the file has 4.
    file(
        dir,
        "t.node",
        b"5 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n",
    );
    file(dir, "t.ele", b"1 4 0\n1 1 2 3 4\n");
    refused(&dir.join("t.node"), &[], &["t.node"]);
    // A gzip file that is not gzip.
    refused(
        &file(dir, "bad.obj.gz", b"not gzip at all"),
        &[],
        &["bad.obj.gz", "gunzip"],
    );
}

#[test]
fn bad_options_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let cube = file(d.path(), "cube.obj", cube_obj().as_bytes());
    refused(
        &cube,
        &["--resolution", "0"],
        &["--resolution must be at least 1"],
    );
    refused(&cube, &["--resolution", "100000"], &["largest grid"]);
    refused(
        &cube,
        &["--resolution", "16", "--mem", "1MiB"],
        &["memory budget 1MiB is too small", "--mem"],
    );
    refused(
        &cube,
        &["--resolution", "16", "--padding", "2"],
        &["--padding 2 is too small"],
    );
    refused(
        &cube,
        &["--resolution", "16", "--center", "5,5,5"],
        &["--center"],
    );
    refused(&cube, &["--mem", "lots"], &["lots"]);
    // The usage errors of clap are exit code 2 too.
    let o = harmap(&["voxelize"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn shapes_harmap_cannot_map_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let t = d.path().join("torus.obj");
    write_obj(&t, &torus(1.0, 0.4, 48, 24));
    refused(
        &t,
        &["--resolution", "32"],
        &["torus.obj", "genus 1", "--allow-genus"],
    );
    let mut open = sphere(Vec3::ZERO, 1.0, 12, 24);
    open.triangles.pop();
    let o = d.path().join("open.obj");
    write_obj(&o, &open);
    refused(&o, &["--resolution", "16"], &["open.obj", "not closed"]);
}

#[test]
fn force_replaces_only_runs_and_trailing_slashes_are_fine() {
    let d = tempfile::tempdir().unwrap();
    let cube = file(d.path(), "cube.obj", cube_obj().as_bytes());
    let c = cube.to_str().unwrap();
    // A directory that is not a run survives --force.
    let precious = d.path().join("precious");
    std::fs::create_dir(&precious).unwrap();
    std::fs::write(precious.join("thesis.tex"), "x").unwrap();
    let o = harmap(&[
        "voxelize",
        c,
        "-o",
        precious.to_str().unwrap(),
        "--force",
        "--resolution",
        "8",
        "--center-radius",
        "0",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--force replaces only a harmap run"),
        "{}",
        stderr(&o)
    );
    assert!(precious.join("thesis.tex").exists());
    // `-o run/` makes `run`, and `--force` on it replaces it.
    let slash = format!("{}/", d.path().join("r.harmap").display());
    for extra in [&[][..], &["--force"][..]] {
        let mut args = vec![
            "voxelize",
            c,
            "-o",
            &slash,
            "--resolution",
            "8",
            "--center-radius",
            "0",
        ];
        args.extend_from_slice(extra);
        let o = harmap(&args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(harmap::run::RunDir::open(&d.path().join("r.harmap")).is_ok());
    }
    let left: Vec<_> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert!(
        left.iter()
            .all(|n| !n.contains(".partial") && !n.contains(".old") && !n.contains(".lock")),
        "{left:?}"
    );
}

#[test]
fn huge_values_are_refused_not_allocated() {
    let d = tempfile::tempdir().unwrap();
    let cube = file(d.path(), "cube.obj", cube_obj().as_bytes());
    refused(
        &cube,
        &["--resolution", "16", "--center-radius", "1e300"],
        &["reaches the boundary"],
    );
    refused(
        &cube,
        &["--resolution", "16", "--padding", "9223372036854775808"],
        &["--padding"],
    );
    // A checkerboard falls apart into a million pieces: refused within the budget.
    let n = 100usize;
    let board: Vec<u8> = (0..n * n * n)
        .map(|i| u8::from((i % n + (i / n) % n + i / (n * n)).is_multiple_of(2)))
        .collect();
    let raw = file(d.path(), "board.raw", &board);
    refused(
        &raw,
        &[
            "--raw-shape",
            "100,100,100",
            "--raw-dtype",
            "u8",
            "--mem",
            "40MiB",
        ],
        &["too many separate pieces"],
    );
}

#[test]
fn run_reuses_only_a_matching_voxelization() {
    let d = tempfile::tempdir().unwrap();
    let cube = file(d.path(), "cube.obj", cube_obj().as_bytes());
    let out = d.path().join("c.harmap");
    let (c, o) = (cube.to_str().unwrap(), out.to_str().unwrap());
    let base = [
        "run",
        c,
        "-o",
        o,
        "--resolution",
        "8",
        "--center-radius",
        "0",
    ];
    assert!(harmap(&base).status.success());
    let again = harmap(&base);
    assert!(
        String::from_utf8_lossy(&again.stdout).contains("skipped"),
        "{}",
        String::from_utf8_lossy(&again.stdout)
    );
    let other = harmap(&[
        "run",
        c,
        "-o",
        o,
        "--resolution",
        "10",
        "--center-radius",
        "0",
    ]);
    assert_eq!(other.status.code(), Some(2));
    assert!(
        stderr(&other).contains("other voxelization options (resolution 8 -> 10)")
            && stderr(&other).contains("--force"),
        "{}",
        stderr(&other)
    );
    let spot = d.path().join("s.obj");
    write_obj(&spot, &sphere(Vec3::ZERO, 1.0, 12, 24));
    let other = harmap(&[
        "run",
        spot.to_str().unwrap(),
        "-o",
        o,
        "--resolution",
        "8",
        "--center-radius",
        "0",
    ]);
    assert!(
        stderr(&other).contains("another input"),
        "{}",
        stderr(&other)
    );
}

/// `harmap run` killed (SIGKILL) during its solve and started again with the same
/// command: the voxelization is kept, the solve resumes from its checkpoint, and the run
/// finishes with every stage.
#[test]
fn a_killed_run_resumes_without_voxelizing_again() {
    let d = tempfile::tempdir().unwrap();
    let shape = d.path().join("s.obj");
    write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 16, 32));
    let out = d.path().join("s.harmap");
    let (s, o) = (shape.to_str().unwrap(), out.to_str().unwrap());
    // A slow solve (Jacobi to a tight residual) with checkpoints every 20 ms.
    let args = [
        "-q",
        "--progress",
        "never",
        "run",
        s,
        "-o",
        o,
        "--resolution",
        "36",
        "--method",
        "jacobi",
        "--rtol",
        "1e-9",
        "--max-iter",
        "100000",
        "--checkpoint-every",
        "0.02s",
    ];
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(args)
        .spawn()
        .unwrap();
    let manifest = out.join("solve/manifest.json");
    let t = std::time::Instant::now();
    while !manifest.exists() {
        assert!(t.elapsed().as_secs() < 60, "no checkpoint appeared");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    std::thread::sleep(std::time::Duration::from_millis(50));
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        !out.join("phi").exists(),
        "the solve finished before the kill"
    );
    let labels_before = std::fs::metadata(out.join("labels/zarr.json"))
        .unwrap()
        .modified()
        .unwrap();
    let mut again: Vec<&str> = args.to_vec();
    again.retain(|a| *a != "-q");
    let r = harmap(&again);
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}{}", text, stderr(&r));
    assert!(text.contains("voxelize: already done"), "{text}");
    let attrs = RunDir::open(&out).unwrap().attrs().unwrap();
    assert!(
        attrs
            .pointer("/stages/solve/result/resumed_at")
            .and_then(serde_json::Value::as_u64)
            .unwrap()
            > 0,
        "the solve did not resume"
    );
    for stage in ["voxelize", "solve", "trace", "map"] {
        assert!(harmap::run::stage_done(&attrs, stage), "{stage} not done");
    }
    let labels_after = std::fs::metadata(out.join("labels/zarr.json"))
        .unwrap()
        .modified()
        .unwrap();
    assert_eq!(labels_before, labels_after, "labels were written again");
}

#[test]
fn handles_are_located_and_closing_plugs_them() {
    let d = tempfile::tempdir().unwrap();
    // A fat ring whose hole (radius 0.15) is about 3 voxels across at resolution 40.
    let t = d.path().join("ring.obj");
    write_obj(&t, &torus(1.0, 0.85, 64, 32));
    let t = t.to_str().unwrap();
    refused(
        Path::new(t),
        &["--resolution", "40"],
        &["genus 1", "plugs 1 of them, at voxel(s) [", "--close 3"],
    );
    // Going on anyway records where the handle is: in the hole, on the ring's axis.
    let run = d.path().join("open.harmap");
    let o = harmap(&[
        "voxelize",
        t,
        "-o",
        run.to_str().unwrap(),
        "--resolution",
        "40",
        "--allow-genus",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = info_json(&run);
    let h = &v["summary"]["voxelize"]["handles"];
    assert_eq!(h.as_array().map(Vec::len), Some(1), "{v}");
    assert_eq!(h[0]["closes"], 1);
    let p: Vec<f64> = (0..3)
        .map(|a| h[0]["position"][a].as_f64().unwrap())
        .collect();
    assert!(
        p[0].hypot(p[1]) < 0.5 && p[2].abs() < 0.85,
        "handle at {p:?}"
    );
    // --close 3 plugs it: genus 0.
    let run = d.path().join("closed.harmap");
    let o = harmap(&[
        "voxelize",
        t,
        "-o",
        run.to_str().unwrap(),
        "--resolution",
        "40",
        "--close",
        "3",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("closing by 3 voxels added"));
    let v = info_json(&run);
    assert_eq!(v["summary"]["voxelize"]["genus"], 0);
    assert!(v["summary"]["voxelize"]["closing_voxels"].as_u64().unwrap() > 0);
}

fn info_json(run: &Path) -> serde_json::Value {
    let o = harmap(&["info", run.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// `harmap run --help` lists every flag of the stages it runs.
#[test]
fn run_takes_every_stage_flag() {
    let o = harmap(&["run", "--help"]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    for flag in [
        // voxelize
        "--resolution",
        "--spacing",
        "--padding",
        "--center",
        "--center-radius",
        "--allow-genus",
        "--keep-largest",
        "--close",
        "--chunk",
        "--mem",
        "--surface",
        "--probe",
        // solve
        "--method",
        "--rtol",
        "--tol",
        "--eps",
        "--max-iter",
        "--omega",
        "--checkpoint-every",
        // trace
        "--seeds",
        "--sample",
        "--stop-radius",
        "--tile",
        "--atol",
        "--trace-rtol",
        "--h-min",
        "--h-max",
        "--max-steps",
        "--level-step",
        // map
        "--exact",
    ] {
        assert!(
            help.contains(&format!("{flag} ")) || help.contains(&format!("{flag}\n")),
            "`harmap run --help` lacks {flag}"
        );
    }
    for heading in ["Voxelize:", "Solve:", "Trace:", "Integrator:", "Map:"] {
        assert!(help.contains(heading), "no {heading} heading");
    }
}

/// A small sphere run, for the tests below: (tempdir, shape, run).
fn sphere_run(extra: &[&str]) -> (tempfile::TempDir, PathBuf, PathBuf) {
    let d = tempfile::tempdir().unwrap();
    let shape = d.path().join("s.obj");
    write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 12, 24));
    let out = d.path().join("s.harmap");
    let mut args = vec![
        "--progress",
        "never",
        "run",
        shape.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "20",
    ];
    args.extend_from_slice(extra);
    let o = harmap(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    (d, shape, out)
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `harmap run` again with other solve, trace or map options runs the stages they
/// affect again and says why, instead of skipping them as done.
#[test]
fn run_with_changed_options_runs_the_affected_stages_again() {
    let (_d, shape, out) = sphere_run(&[]);
    let (s, o) = (shape.to_str().unwrap(), out.to_str().unwrap());
    let run = |extra: &[&str]| {
        let mut a = vec![
            "--progress",
            "never",
            "run",
            s,
            "-o",
            o,
            "--resolution",
            "20",
        ];
        a.extend_from_slice(extra);
        let r = harmap(&a);
        assert!(r.status.success(), "{extra:?}: {}", stderr(&r));
        stdout(&r)
    };
    let text = run(&["--method", "sor"]);
    assert!(
        text.contains("solve: run again: its options changed: method"),
        "{text}"
    );
    assert!(text.contains("trace: run again: out of date"), "{text}");
    assert!(text.contains("map: run again: out of date"), "{text}");
    assert!(!text.contains("solve: already done"), "{text}");
    // Back to the default solve: the solve runs again; then only the trace options.
    run(&[]);
    let text = run(&["--seeds", "boundary"]);
    assert!(text.contains("solve: already done"), "{text}");
    assert!(
        text.contains("trace: run again: its options changed:")
            && text.contains("seeds \"surface\" -> \"boundary\""),
        "{text}"
    );
    let text = run(&["--seeds", "boundary", "--stop-radius", "3"]);
    assert!(
        text.contains("trace: run again: its options changed: stop_radius"),
        "{text}"
    );
    assert!(
        text.contains("map: run again: its options changed: stop_radius"),
        "{text}"
    );
    let text = run(&["--seeds", "boundary", "--stop-radius", "3", "--exact"]);
    assert!(text.contains("trace: already done"), "{text}");
    assert!(
        text.contains("map: run again: its options changed: method"),
        "{text}"
    );
    let text = run(&["--seeds", "boundary", "--stop-radius", "3", "--exact"]);
    for stage in ["voxelize", "solve", "trace", "map"] {
        assert!(text.contains(&format!("{stage}: already done")), "{text}");
    }
}

/// `harmap solve RUN --rtol ...` after a run: `info` shows the trace and the map
/// stale, an export of the seeds is refused with the command to run, and `harmap run`
/// with those options runs them again.
#[test]
fn a_new_solve_makes_later_stages_stale_in_info() {
    let (d, _shape, out) = sphere_run(&[]);
    let o = out.to_str().unwrap();
    assert!(
        harmap(&["--progress", "never", "solve", o, "--rtol", "1e-3"])
            .status
            .success()
    );
    let info = stdout(&harmap(&["info", o]));
    assert!(
        info.contains("stage:    trace done") && info.contains("STALE"),
        "{info}"
    );
    assert_eq!(info.matches("STALE").count(), 2, "{info}");
    let json = info_json(&out);
    let stale = json.pointer("/summary/stale").unwrap().as_object().unwrap();
    assert!(
        stale.contains_key("trace") && stale.contains_key("map"),
        "{json}"
    );
    let csv = d.path().join("seeds.csv");
    let e = harmap(&["export", o, "--format", "csv", "-o", csv.to_str().unwrap()]);
    assert_eq!(e.status.code(), Some(2), "{}", stderr(&e));
    assert!(
        stderr(&e).contains("out of date") && stderr(&e).contains("harmap trace"),
        "{}",
        stderr(&e)
    );
    assert!(!csv.exists());
}

/// Values that would run and mean nothing are refused with exit code 2 and a message
/// naming the flag, before anything is written.
#[test]
fn meaningless_flags_are_refused() {
    let (d, shape, out) = sphere_run(&[]);
    let o = out.to_str().unwrap();
    for bad in [
        &["--rtol", "2"][..],
        &["--rtol", "inf"],
        &["--rtol", "NaN"],
        &["--rtol", "1"],
        &["--max-iter", "0"],
    ] {
        let mut a = vec!["solve", o];
        a.extend_from_slice(bad);
        let r = harmap(&a);
        assert_eq!(r.status.code(), Some(2), "{bad:?}: {}", stderr(&r));
        assert!(stderr(&r).contains(bad[0]), "{bad:?}: {}", stderr(&r));
        // The same through `harmap run`, into a new run: nothing is created.
        let fresh = d.path().join("new.harmap");
        let mut a = vec![
            "run",
            shape.to_str().unwrap(),
            "-o",
            fresh.to_str().unwrap(),
        ];
        a.extend_from_slice(bad);
        let r = harmap(&a);
        assert_eq!(r.status.code(), Some(2), "run {bad:?}: {}", stderr(&r));
        assert!(!fresh.exists());
    }
    let r = harmap(&["trace", o, "--stop-radius", "1000"]);
    assert_eq!(r.status.code(), Some(2), "{}", stderr(&r));
    assert!(stderr(&r).contains("voxels deep"), "{}", stderr(&r));
    let info = info_json(&out);
    assert!(info
        .pointer("/summary/stale")
        .unwrap()
        .as_object()
        .unwrap()
        .is_empty());
}

/// `solve --resume` with no checkpoint says to run without --resume.
#[test]
fn resume_without_a_checkpoint_says_what_to_do() {
    let d = tempfile::tempdir().unwrap();
    let cube = file(d.path(), "cube.obj", cube_obj().as_bytes());
    let out = d.path().join("c.harmap");
    let o = out.to_str().unwrap();
    assert!(harmap(&[
        "voxelize",
        cube.to_str().unwrap(),
        "-o",
        o,
        "--resolution",
        "8",
        "--center-radius",
        "0"
    ])
    .status
    .success());
    let r = harmap(&["solve", o, "--resume"]);
    assert_eq!(r.status.code(), Some(2), "{}", stderr(&r));
    assert!(stderr(&r).contains("without --resume"), "{}", stderr(&r));
}

/// Spawn harmap with `args`, with stderr read line by line on a thread; returns the
/// child and a receiver of the lines.
fn spawn(args: &[&str]) -> (std::process::Child, std::sync::mpsc::Receiver<String>) {
    use std::io::BufRead;
    let mut child = Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let err = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(err).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    (child, rx)
}

/// The command between the last pair of backticks of `text`, split on spaces (the
/// paths of these tests have none).
fn command_in(text: &str) -> Vec<String> {
    let end = text.rfind('`').expect("a command in backticks");
    let start = text[..end].rfind('`').expect("a command in backticks");
    text[start + 1..end].split(' ').map(str::to_owned).collect()
}

/// SIGINT and SIGTERM during the trace of `harmap run`: it stops within a second,
/// exits 130 or 143, and prints the command that continues; that command finishes the
/// run without solving again.
#[test]
fn a_signal_during_the_trace_of_run_stops_it_and_the_printed_command_continues() {
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let d = tempfile::tempdir().unwrap();
        let shape = d.path().join("s.obj");
        write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 16, 32));
        let out = d.path().join("s.harmap");
        // A trace of some seconds: every boundary voxel of a sphere 64 voxels across,
        // at a tight tolerance.
        let args = [
            "-v",
            "--progress",
            "never",
            "run",
            shape.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--resolution",
            "64",
            "--seeds",
            "boundary",
            "--atol",
            "1e-10",
            "--rtol",
            "1e-7",
        ];
        let (mut child, lines) = spawn(&args);
        let mut text = String::new();
        loop {
            let line = lines
                .recv_timeout(std::time::Duration::from_mins(2))
                .expect("the trace started");
            text.push_str(&line);
            text.push('\n');
            if line.starts_with("trace") {
                break;
            }
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
        let t = std::time::Instant::now();
        let k = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(k.success());
        let status = child.wait().unwrap();
        let took = t.elapsed();
        while let Ok(line) = lines.recv_timeout(std::time::Duration::from_secs(5)) {
            text.push_str(&line);
            text.push('\n');
        }
        assert_eq!(status.code(), Some(code), "{signal}: {text}");
        assert!(took.as_secs_f64() < 1.0, "{signal}: stopped after {took:?}");
        assert!(text.contains("stopped during the trace stage"), "{text}");
        let attrs = RunDir::open(&out).unwrap().attrs().unwrap();
        assert!(harmap::run::stage_done(&attrs, "solve"));
        assert!(!harmap::run::stage_done(&attrs, "trace"));
        // The printed command keeps the options (the solve is not redone) and
        // finishes the run.
        let cmd = command_in(&text);
        assert!(
            cmd.windows(2).any(|w| w[0] == "--rtol" && w[1] == "1e-7"),
            "{cmd:?}"
        );
        let again: Vec<&str> = cmd[1..].iter().map(String::as_str).collect();
        let r = harmap(&again);
        assert!(r.status.success(), "{}", stderr(&r));
        let o = stdout(&r);
        assert!(o.contains("solve: already done"), "{o}");
        let attrs = RunDir::open(&out).unwrap().attrs().unwrap();
        for stage in ["trace", "map"] {
            assert!(
                harmap::run::stage_done(&attrs, stage),
                "{stage} not done: {o}"
            );
        }
    }
}

/// An interrupted `harmap solve` with other than default options prints the command
/// that continues it with those options, and that command resumes.
#[test]
fn an_interrupted_solve_prints_a_resume_command_that_works() {
    let d = tempfile::tempdir().unwrap();
    let shape = d.path().join("s.obj");
    write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 16, 32));
    let out = d.path().join("s.harmap");
    let o = out.to_str().unwrap();
    assert!(harmap(&[
        "voxelize",
        shape.to_str().unwrap(),
        "-o",
        o,
        "--resolution",
        "24"
    ])
    .status
    .success());
    let args = [
        "--progress",
        "never",
        "solve",
        o,
        "--method",
        "jacobi",
        "--rtol",
        "1e-7",
        "--max-iter",
        "100000",
        "--checkpoint-every",
        "0.02s",
    ];
    let (mut child, lines) = spawn(&args);
    let manifest = out.join("solve/manifest.json");
    let t = std::time::Instant::now();
    while !manifest.exists() {
        assert!(t.elapsed().as_secs() < 60, "no checkpoint appeared");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let k = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(k.success());
    let status = child.wait().unwrap();
    let mut text = String::new();
    while let Ok(line) = lines.recv_timeout(std::time::Duration::from_secs(5)) {
        text.push_str(&line);
        text.push('\n');
    }
    assert_eq!(status.code(), Some(130), "{text}");
    let cmd = command_in(&text);
    for a in ["jacobi", "1e-7", "--resume"] {
        assert!(cmd.iter().any(|c| c == a), "{a} missing from {cmd:?}");
    }
    let again: Vec<&str> = cmd[1..].iter().map(String::as_str).collect();
    let r = harmap(&again);
    assert!(r.status.success(), "{}", stderr(&r));
    let attrs = RunDir::open(&out).unwrap().attrs().unwrap();
    let resumed: Option<u64> = harmap::run::stages::report_in::<serde_json::Value>(&attrs, "solve")
        .and_then(|v| v.get("resumed_at").and_then(serde_json::Value::as_u64));
    assert!(resumed.is_some_and(|n| n > 0), "the solve did not resume");
}
