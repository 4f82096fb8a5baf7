//! MPI ranks (`--features mpi`): `mpiexec -n 1/2/3 harmap run` gives the same bytes as
//! one process, and a killed rank takes the job down.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use harmap::grid::{read_table, BlockStore, Scalar};
use harmap::run::RunDir;
use harmap::voxelize::labels::{BOUNDARY, CENTER, INTERIOR};

use crate::common::shared_data;

/// `mpiexec` on the PATH; None (after saying so) when absent, a failure under
/// `CI=true`, where .ci/run installs MPICH.
fn mpiexec() -> Option<PathBuf> {
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join("mpiexec"))
            .find(|p| p.is_file())
    });
    if found.is_none() {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but mpiexec is missing: install mpich libmpich-dev (as .ci/run does)"
        );
        eprintln!("skipped: mpiexec not found");
    }
    found
}

static JOBS: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// One job at a time: the ranks of two would share the cores.
fn one_job() -> std::sync::MutexGuard<'static, ()> {
    JOBS.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn harmap() -> &'static str {
    env!("CARGO_BIN_EXE_harmap")
}

/// `harmap -q --progress never ARGS`, on `ranks` MPI ranks (0: one plain process).
fn run(mpiexec: &Path, ranks: usize, args: &[&str]) -> Output {
    run_with(mpiexec, ranks, args, &[])
}

/// [`run`] with environment variables `env`.
fn run_with(mpiexec: &Path, ranks: usize, args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = if ranks == 0 {
        Command::new(harmap())
    } else {
        let mut c = Command::new(mpiexec);
        c.args(["-n", &ranks.to_string(), harmap()]);
        c
    };
    c.args(["-q", "--progress", "never"]).args(args);
    c.envs(env.iter().copied());
    let out = c.output().expect("start harmap");
    assert!(
        out.status.success(),
        "{ranks} ranks: {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn bytes_of<T: Scalar>(v: &[T]) -> Vec<u8> {
    bytemuck::cast_slice(v).to_vec()
}

/// An image of the run, every voxel's bytes.
fn image<T: Scalar>(run: &RunDir, name: &str, fill: T) -> Vec<u8> {
    let store = run.open_image::<T>(name).expect("image");
    let shape = store.spec().shape.map(|c| c as usize);
    bytes_of(&store.read_region([0; 3], shape, fill).expect("read").data)
}

/// A seed table column's values as bytes, whatever its type.
fn column(root: &Path, name: &str) -> Vec<u8> {
    let path = format!("/seeds/{name}");
    let meta = std::fs::read_to_string(root.join("seeds").join(name).join("zarr.json"))
        .expect("column metadata");
    let v: serde_json::Value = serde_json::from_str(&meta).expect("json");
    let bytes = match v["data_type"].as_str().expect("data_type") {
        "float64" => bytes_of(&read_table::<f64>(root, &path).expect("read").1),
        "float32" => bytes_of(&read_table::<f32>(root, &path).expect("read").1),
        "uint64" => bytes_of(&read_table::<u64>(root, &path).expect("read").1),
        "uint32" => bytes_of(&read_table::<u32>(root, &path).expect("read").1),
        "uint8" => bytes_of(&read_table::<u8>(root, &path).expect("read").1),
        t => panic!("seed column {name}: type {t} not compared"),
    };
    assert!(!bytes.is_empty(), "seed column {name} is empty");
    bytes
}

/// Every output the issue names: labels, phi, u, theta, psi and each seed column.
fn outputs(root: &Path) -> Vec<(String, Vec<u8>)> {
    let run = RunDir::open(root).expect("a run");
    let mut out = vec![
        ("labels".to_owned(), image::<u8>(&run, "labels", 0)),
        ("phi".to_owned(), image::<f64>(&run, "phi", f64::NAN)),
        ("u".to_owned(), image::<f64>(&run, "u", f64::NAN)),
        ("theta".to_owned(), image::<f64>(&run, "theta", f64::NAN)),
        ("psi".to_owned(), image::<f64>(&run, "psi", f64::NAN)),
    ];
    let mut names: Vec<String> = std::fs::read_dir(root.join("seeds"))
        .expect("seed table")
        .filter_map(Result::ok)
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert!(names.iter().any(|n| n == "theta"), "seed columns {names:?}");
    for n in names {
        let b = column(root, &n);
        out.push((format!("seeds/{n}"), b));
    }
    out.extend(reports(root));
    out
}

/// The counts the trace and map stages record: the trace's stop reasons, collisions
/// and sphere map, and the whole map report (the map's folded, traced and mapped
/// voxels; each rank counts its own blocks, the record must hold every rank's). Left
/// out: times, and the upwind transport's rounds and block visits (a schedule, which
/// differs on ranks).
fn reports(root: &Path) -> Vec<(String, Vec<u8>)> {
    let meta = std::fs::read_to_string(root.join("zarr.json")).expect("run metadata");
    let v: serde_json::Value = serde_json::from_str(&meta).expect("json");
    let stages = &v["attributes"]["harmap"]["stages"];
    let mut map = stages["map"]["result"].clone();
    let m = map.as_object_mut().expect("map report");
    m.remove("seconds_directions");
    if let Some(u) = m.get_mut("upwind").and_then(|u| u.as_object_mut()) {
        u.remove("rounds");
        u.remove("visits");
    }
    // The unfolding's timings (its counts and moves stay).
    if let Some(u) = m.get_mut("unfold").and_then(|u| u.as_object_mut()) {
        u.remove("seconds");
        u.remove("seconds_recount");
    }
    assert!(m["folded"]["measured"].as_u64().unwrap_or(0) > 0, "{map}");
    let trace = &stages["trace"]["result"];
    let mut out = vec![("map report".to_owned(), map.to_string().into_bytes())];
    for key in [
        "seeds",
        "stops",
        "collisions",
        "indistinguishable",
        "surface",
    ] {
        assert!(!trace[key].is_null(), "trace report without {key}: {trace}");
        out.push((
            format!("trace report: {key}"),
            trace[key].to_string().into_bytes(),
        ));
    }
    out
}

/// `harmap run INPUT ARGS` in one process and on each rank count of `ranks`: the same
/// bytes in every output.
/// `env` is set for the runs on ranks.
fn same_bytes_on_ranks(input: &Path, args: &[&str], ranks: &[usize], env: &[(&str, &str)]) {
    let Some(mpiexec) = mpiexec() else { return };
    let _one = one_job();
    let dir = tempfile::tempdir().unwrap();
    let go = |n: usize| {
        let out = dir.path().join(format!("r{n}.harmap"));
        let mut a = vec!["run", input.to_str().unwrap(), "-o", out.to_str().unwrap()];
        a.extend_from_slice(args);
        run_with(&mpiexec, n, &a, if n == 0 { &[] } else { env });
        outputs(&out)
    };
    let one = go(0);
    // The outputs differ from each other (a comparison that could not fail proves
    // nothing).
    assert_ne!(one[1].1, one[2].1, "phi and u");
    for &n in ranks {
        let many = go(n);
        assert_eq!(one.len(), many.len(), "{n} ranks: the outputs");
        for ((name, a), (_, b)) in one.iter().zip(&many) {
            assert!(a == b, "{n} ranks: {name} differs from one process's");
        }
    }
}

#[test]
fn spot_on_two_and_three_ranks_is_the_same_bytes_as_one_process() {
    let Some(spot) = shared_data("meshes/spot.obj") else {
        return;
    };
    // Halo exchanges in rounds of 4 KiB between each pair of ranks (2 MiB by default,
    // more than any halo here), so that the rounds' bookkeeping is tried too.
    same_bytes_on_ranks(
        &spot,
        &["--resolution", "96"],
        &[2, 3],
        &[("HARMAP_EXCHANGE_ROUND", "4096")],
    );
    // Blocks of 32: four block layers, most of whose blocks hold no unknown, which
    // the block passes of each rank skip as one process does. In 44 MiB the finest
    // level goes to scratch files, so its passes (with the cut unknowns) are the
    // block passes, in one process and on the ranks.
    same_bytes_on_ranks(
        &spot,
        &["--resolution", "96", "--chunk", "32", "--mem", "44MiB"],
        &[2, 3],
        &[],
    );
}

#[test]
fn crambin_on_one_two_and_three_ranks_is_the_same_bytes_as_one_process() {
    let Some(pdb) = shared_data("molecules/1crn.pdb") else {
        return;
    };
    // A molecule has cuts (its sub-voxel boundary): the finest level, in memory, runs
    // the whole-array passes with its cut unknowns on each rank's slab.
    same_bytes_on_ranks(&pdb, &["--spacing", "0.5"], &[1, 2, 3], &[]);
    // Its solid as a label volume, in blocks of 32: three block layers, so that on 3
    // ranks the middle one has two slab faces. A label volume solves on the
    // staircase, so the finest level in memory runs the whole-array passes on each
    // rank's slab (its tiny values deepened).
    let Some(mpiexec) = mpiexec() else { return };
    let dir = tempfile::tempdir().unwrap();
    let vox = dir.path().join("crambin.harmap");
    run(
        &mpiexec,
        0,
        &[
            "voxelize",
            pdb.to_str().unwrap(),
            "-o",
            vox.to_str().unwrap(),
            "--spacing",
            "0.5",
        ],
    );
    let r = RunDir::open(&vox).expect("run");
    let shape = r.open_image::<u8>("labels").expect("labels").spec().shape;
    let solid: Vec<u8> = image::<u8>(&r, "labels", 0)
        .iter()
        .map(|&l| u8::from(l == BOUNDARY || l == INTERIOR || l == CENTER))
        .collect();
    let raw = dir.path().join("crambin.raw");
    std::fs::write(&raw, solid).unwrap();
    let dims = format!("{},{},{}", shape[0], shape[1], shape[2]);
    same_bytes_on_ranks(
        &raw,
        &["--raw-shape", &dims, "--raw-dtype", "u8", "--chunk", "32"],
        &[2, 3],
        &[],
    );
}

/// `harmap bench trace` and `bench map` on 2 ranks: one table (rank 0 prints it) with a
/// line per rank after each row (seconds, bytes sent, peak memory), and the benchmark's
/// run removed once every rank is done with it.
#[test]
fn benchmarks_on_ranks_print_one_table_with_a_line_per_rank() {
    let Some(mpiexec) = mpiexec() else {
        return;
    };
    let _one = one_job();
    for what in [&["trace", "--sample", "500"][..], &["map"][..]] {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut args = vec!["--threads", "1", "bench"];
        args.extend_from_slice(what);
        args.extend_from_slice(&["--n", "48", "--dir", dir.path().to_str().unwrap()]);
        let out = run(&mpiexec, 2, &args);
        let text = String::from_utf8_lossy(&out.stdout);
        let count = |s: &str| text.lines().filter(|l| l.contains(s)).count();
        assert_eq!(count("harmap bench"), 1, "{what:?}: one title\n{text}");
        assert_eq!(count("2 MPI ranks"), 1, "{what:?}\n{text}");
        assert_eq!(count("rank 0:"), 1, "{what:?}\n{text}");
        assert_eq!(count("rank 1:"), 1, "{what:?}\n{text}");
        assert!(
            std::fs::read_dir(dir.path()).unwrap().next().is_none(),
            "{what:?}: the benchmark's run was left behind"
        );
    }
}

/// Options the ranks cannot run (blocks 9 voxels high do not line up with the next
/// multigrid level's) are bad usage: exit 2 from mpiexec, with the fix, and no phi.
#[test]
fn blocks_the_ranks_cannot_share_are_bad_usage() {
    let Some(mpiexec) = mpiexec() else {
        return;
    };
    let _one = one_job();
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("run");
    let status = Command::new(&mpiexec)
        .args(["-n", "2", harmap(), "-q", "--progress", "never", "run"])
        .args(["--resolution", "40", "--chunk", "9", "-o"])
        .arg(&out)
        .output()
        .expect("start mpiexec");
    let stderr = String::from_utf8_lossy(&status.stderr);
    assert_eq!(status.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("--chunk 32 or more"), "{stderr}");
    assert!(!out.join("phi").exists(), "a phi was left behind");
}

/// The harmap processes below `pid` (mpiexec's ranks, under its process proxy).
fn ranks_below(pid: u32) -> Vec<u32> {
    let parent_of = |p: u32| -> Option<u32> {
        let stat = std::fs::read_to_string(format!("/proc/{p}/stat")).ok()?;
        // pid (comm) state ppid ...: the comm may hold spaces, the fields after it not.
        stat.rsplit_once(')')?
            .1
            .split_whitespace()
            .nth(1)?
            .parse()
            .ok()
    };
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc")
        .expect("/proc")
        .filter_map(Result::ok)
    {
        let Some(p) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let comm = std::fs::read_to_string(format!("/proc/{p}/comm")).unwrap_or_default();
        if comm.trim() != "harmap" {
            continue;
        }
        let mut q = p;
        while let Some(up) = parent_of(q).filter(|&u| u > 1) {
            if up == pid {
                out.push(p);
                break;
            }
            q = up;
        }
    }
    out.sort_unstable();
    out
}

/// A rank killed during the solve ends the job on every rank, non-zero, within 30 s;
/// the solve resumed on 2 ranks (and on 3) from the checkpoint gives the bytes of an
/// uninterrupted solve in one process.
#[test]
fn a_killed_rank_ends_the_job_and_the_resumed_solve_gives_the_same_phi() {
    let Some(mpiexec) = mpiexec() else { return };
    let Some(spot) = shared_data("meshes/spot.obj") else {
        return;
    };
    let _one = one_job();
    let dir = tempfile::tempdir().unwrap();
    let solve = [
        "--method",
        "sor",
        "--rtol",
        "1e-12",
        "--max-iter",
        "600",
        "--checkpoint-every",
        "0.2",
    ];
    let voxelized = |name: &str| {
        let out = dir.path().join(name);
        let o = out.to_str().unwrap().to_owned();
        run(
            &mpiexec,
            0,
            &[
                "voxelize",
                spot.to_str().unwrap(),
                "-o",
                &o,
                "--resolution",
                "64",
            ],
        );
        o
    };
    let reference = voxelized("ref.harmap");
    run(
        &mpiexec,
        0,
        &[&["solve", reference.as_str()][..], &solve].concat(),
    );
    let phi = |r: &str| {
        let run = RunDir::open(Path::new(r)).unwrap();
        image::<f64>(&run, "phi", f64::NAN)
    };
    let want = phi(&reference);
    for resume_on in [2, 3] {
        let killed = voxelized(&format!("killed{resume_on}.harmap"));
        let mut child = Command::new(&mpiexec)
            .args([
                "-n",
                "3",
                harmap(),
                "-q",
                "--progress",
                "never",
                "solve",
                &killed,
            ])
            .args(solve)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("start mpiexec");
        // Kill rank 1 once a checkpoint is there.
        let manifest = Path::new(&killed).join("solve").join("manifest.json");
        let t = std::time::Instant::now();
        while !manifest.exists() {
            assert!(t.elapsed().as_secs() < 120, "no checkpoint after 120 s");
            assert!(
                child.try_wait().unwrap().is_none(),
                "the solve ended before a checkpoint"
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let ranks = ranks_below(child.id());
        assert_eq!(ranks.len(), 3, "three ranks under mpiexec: {ranks:?}");
        let killed_at = std::time::Instant::now();
        let k = Command::new("kill")
            .args(["-9", &ranks[1].to_string()])
            .status()
            .unwrap();
        assert!(k.success());
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(
                killed_at.elapsed().as_secs() < 30,
                "the job still runs 30 s after a rank was killed"
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        assert!(
            !status.success(),
            "mpiexec exited 0 after a rank was killed"
        );
        // (A rank's entry goes once its parent has reaped it.)
        let gone = || {
            ranks
                .iter()
                .all(|p| !Path::new(&format!("/proc/{p}")).exists())
        };
        while !gone() && killed_at.elapsed().as_secs() < 30 {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        assert!(gone(), "a rank outlived the job by 30 s");
        run(
            &mpiexec,
            resume_on,
            &[&["solve", killed.as_str(), "--resume"][..], &solve].concat(),
        );
        let got = phi(&killed);
        assert!(got == want, "resumed on {resume_on} ranks: phi differs");
    }
}

/// `harmap voxelize` under mpiexec: every rank computes its slab of the solid, rank 0
/// the rest; the labels are one process's, for a molecule (three block layers of 32),
/// a mesh, and a probe ladder (one solid pass per probe).
#[test]
fn voxelize_on_ranks_gives_one_process_labels() {
    let Some(mpiexec) = mpiexec() else { return };
    let (Some(pdb), Some(spot)) = (
        shared_data("molecules/1crn.pdb"),
        shared_data("meshes/spot.obj"),
    ) else {
        return;
    };
    let _one = one_job();
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&Path, &[&str]); 3] = [
        (&pdb, &["--spacing", "0.5", "--chunk", "32"]),
        (&spot, &["--resolution", "96", "--chunk", "32"]),
        (
            &pdb,
            &[
                "--spacing",
                "0.5",
                "--chunk",
                "32",
                "--probe",
                "0.5,1.4",
                "--allow-genus",
            ],
        ),
    ];
    for (k, (input, args)) in cases.iter().enumerate() {
        let labels = |ranks: usize| {
            let out = dir.path().join(format!("c{k}r{ranks}.harmap"));
            let mut a = vec![
                "voxelize",
                input.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ];
            a.extend_from_slice(args);
            run(&mpiexec, ranks, &a);
            let run = RunDir::open(&out).expect("a run");
            image::<u8>(&run, "labels", 0)
        };
        let one = labels(0);
        assert!(
            one.iter().any(|&l| l != 0),
            "case {k}: an empty solid proves nothing"
        );
        for ranks in [2, 3] {
            assert!(
                labels(ranks) == one,
                "case {k}, {ranks} ranks: the labels differ"
            );
        }
    }
}
