//! Interoperability: a run directory written by `harmap voxelize`, `solve` and `trace`
//! opens in zarr-python 3, ome-zarr's Reader and ome-zarr-models
//! (`tests/interop/check_run.py`): labels, phi, u and the seed table. The exports of a
//! mapped run open in nibabel (NIfTI), VTK (.vti and streamline .vtk), GridDataFormats
//! (.dx) and zarr-python / ome-zarr (OME-Zarr) with the run's values and geometry
//! (`tests/interop/check_exports.py`).
//!
//! Needs a Python with `zarr>=3,<4 numpy ome-zarr ome-zarr-models nibabel vtk
//! gridDataFormats`, named by the
//! environment variable `HARMAP_PYTHON` (`.ci/run` sets it up). Without it the test is
//! skipped with a note, except under `CI=true`, where it fails.
//!
//! Writes its own input (a unit cube), so it needs no shared test data.

use std::path::Path;
use std::process::Command;

/// The unit cube as six outward-wound quads.
const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n\
f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

/// The Python to run the check with, or `None` to skip (panics under CI).
fn python() -> Option<String> {
    match std::env::var("HARMAP_PYTHON") {
        Ok(p) if !p.trim().is_empty() => Some(p),
        _ => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI=true but HARMAP_PYTHON is not set: the interop check must run in CI \
                 (.ci/run creates .venv with zarr, ome-zarr, ome-zarr-models and sets it)"
            );
            eprintln!(
                "note: skipping the zarr-python / ome-zarr interop check: set HARMAP_PYTHON to a Python \
                 with `zarr>=3,<4 numpy ome-zarr ome-zarr-models` (or run .ci/run)"
            );
            None
        }
    }
}

fn check_with_python(python: &str, script: &str, args: &[&Path]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/interop")
        .join(script);
    let o = Command::new(python)
        .arg(&script)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot start HARMAP_PYTHON={python}: {e}"));
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success(),
        "{} {} {args:?} exited with {}\n--- stdout\n{out}--- stderr\n{err}",
        python,
        script.display(),
        o.status
    );
    assert!(
        out.starts_with("ok: "),
        "unexpected output of {}:\n{out}{err}",
        script.display()
    );
    eprintln!("{out}{err}");
}

#[test]
fn run_directory_opens_in_zarr_python_and_ome_zarr() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let run = traced_cube(dir.path(), "24", "500");
    check_with_python(&python, "check_run.py", &[&run]);
}

/// The cube at `resolution`, voxelized, solved and traced from `sample` seeds in `dir`.
fn traced_cube(dir: &std::path::Path, resolution: &str, sample: &str) -> std::path::PathBuf {
    let obj = dir.join("cube.obj");
    std::fs::write(&obj, CUBE_OBJ).unwrap();
    let run = dir.join("cube.harmap");
    let r = run.to_str().unwrap();
    harmap(&[
        "voxelize",
        obj.to_str().unwrap(),
        "-o",
        r,
        "--resolution",
        resolution,
    ]);
    harmap(&["solve", r]);
    harmap(&["trace", r, "--seeds", "boundary", "--sample", sample]);
    run
}

/// Run the harmap binary; panics with its stderr when it fails.
fn harmap(args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(args)
        .args(["--progress", "never"])
        .output()
        .expect("the harmap binary runs");
    assert!(
        o.status.success(),
        "harmap {args:?} failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn exports_open_in_nibabel_vtk_griddata_and_ome_zarr() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let run = traced_cube(dir.path(), "20", "200");
    let r = run.to_str().unwrap();
    harmap(&["map", r]);
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let o = |name: &str| out.join(name).to_str().unwrap().to_owned();
    harmap(&["export", r, "--format", "nifti", "-o", &o("phi.nii")]);
    harmap(&[
        "export",
        r,
        "--format",
        "nifti",
        "--field",
        "theta",
        "-o",
        &o("theta.nii.gz"),
    ]);
    harmap(&["export", r, "--format", "vti", "-o", &o("all.vti")]);
    harmap(&["export", r, "--format", "dx", "-o", &o("phi.dx")]);
    harmap(&[
        "export",
        r,
        "--format",
        "vtk-streamlines",
        "--sample",
        "50",
        "-o",
        &o("lines.vtk"),
    ]);
    harmap(&[
        "export",
        r,
        "--format",
        "ome-zarr",
        "-o",
        &o("images.ome.zarr"),
    ]);
    // Nothing half-written is left next to the outputs.
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 6, "{names:?}");
    check_with_python(&python, "check_exports.py", &[&run, &out]);
}
