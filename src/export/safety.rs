//! What an export may write over, and the sweep of temporary files that killed exports
//! left. The rules are in the module docs of [`crate::export`].

use super::marks::{first_line, starts_with_line};
use std::fs;
use std::path::{Path, PathBuf};

use super::image::ImageFormat;
use super::ExportError;

/// What an export writes, for recognising its own earlier output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportKind {
    /// The seed table as CSV.
    Csv,
    /// The boundary -> sphere map as OBJ.
    ObjSphere,
    /// Streamlines as VTK legacy polydata.
    VtkStreamlines,
    /// An image file (NIfTI, VTI, OpenDX).
    Image(ImageFormat),
    /// An OME-Zarr group (a folder).
    OmeZarr,
}

impl ExportKind {
    fn name(self) -> &'static str {
        match self {
            ExportKind::Csv => "csv",
            ExportKind::ObjSphere => "obj-sphere",
            ExportKind::VtkStreamlines => "vtk-streamlines",
            ExportKind::Image(ImageFormat::Nifti) => "nifti",
            ExportKind::Image(ImageFormat::Vti) => "vti",
            ExportKind::Image(ImageFormat::Dx) => "dx",
            ExportKind::OmeZarr => "ome-zarr",
        }
    }
}

/// Whether `path` is harmap's own earlier output of `kind` (its format's mark).
#[must_use]
pub fn is_own_output(path: &Path, kind: ExportKind) -> bool {
    if path.is_dir() != (kind == ExportKind::OmeZarr) {
        return false;
    }
    match kind {
        ExportKind::Csv => first_line(path).is_some_and(|l| l.starts_with(super::csv::HEADER)),
        ExportKind::ObjSphere => starts_with_line(path, 0, super::obj_sphere::MARK),
        ExportKind::VtkStreamlines => starts_with_line(path, 1, super::streamlines::TITLE),
        ExportKind::Image(f) => super::image::is_own_image(path, f),
        ExportKind::OmeZarr => fs::read(path.join("zarr.json"))
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .is_some_and(|d| d.pointer("/attributes/harmap_export").is_some()),
    }
}

/// Whether `dir` is a harmap run directory (its `zarr.json` carries `harmap` attributes).
fn is_run_dir(dir: &Path) -> bool {
    fs::read(dir.join("zarr.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .is_some_and(|d| d.pointer("/attributes/harmap").is_some())
}

/// The run directory `path` is in or is (the nearest ancestor that is one).
fn enclosing_run(path: &Path) -> Option<PathBuf> {
    // The deepest part that exists, with symbolic links resolved, so `R/../R/x` and a
    // link into a run are seen for what they are.
    let abs = std::path::absolute(path).ok()?;
    let mut existing = abs.as_path();
    let mut rest = Vec::new();
    while !existing.exists() {
        rest.push(existing.file_name()?.to_owned());
        existing = existing.parent()?;
    }
    let mut real = existing.canonicalize().ok()?;
    for r in rest.into_iter().rev() {
        real.push(r);
    }
    real.ancestors().find(|a| is_run_dir(a)).map(Path::to_owned)
}

/// Check that an export of `kind` may write `dest` (the rules of [`crate::export`]);
/// `force` lets it replace a file or an empty folder it did not write, or write inside
/// a run. Errors name the path and what to do.
pub fn check_target(dest: &Path, kind: ExportKind, force: bool) -> Result<(), ExportError> {
    let d = dest.display();
    let refuse = |why: String| Err(ExportError::Refused(why));
    if dest.is_dir() && is_run_dir(dest) {
        return refuse(format!(
            "{d} is a harmap run directory; an export never replaces a run, even with --force: choose another path"
        ));
    }
    let run = enclosing_run(dest);
    let exists = fs::symlink_metadata(dest).is_ok();
    if exists && is_own_output(dest, kind) && (run.is_none() || force) {
        return Ok(());
    }
    if let Some(r) = &run {
        if exists {
            return refuse(format!(
                "{d} belongs to the run directory {}; an export never writes over a run's files, even with --force: choose a path outside the run",
                r.display()
            ));
        }
        if !force {
            return refuse(format!(
                "{d} is inside the run directory {}; choose a path outside the run, or use --force to write a new file there",
                r.display()
            ));
        }
        return Ok(());
    }
    if !exists {
        return Ok(());
    }
    if dest.is_dir() {
        let empty = fs::read_dir(dest).is_ok_and(|mut e| e.next().is_none());
        if !empty {
            return refuse(format!(
                "{d} is a folder that is not a harmap {} export; an export never replaces a non-empty folder it did not write, even with --force: choose another path",
                kind.name()
            ));
        }
    }
    if force {
        return Ok(());
    }
    refuse(format!(
        "{d} exists and is not a harmap {} export; choose another path, or use --force to replace it",
        kind.name()
    ))
}

/// The temporary name of this process's export to `dest`: `.NAME.partial-PID` beside it.
pub(crate) fn partial_name(dest: &Path) -> PathBuf {
    dest.with_file_name(format!(
        ".{}.partial-{}",
        file_name(dest),
        std::process::id()
    ))
}

fn file_name(dest: &Path) -> String {
    dest.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Remove the temporary files (or folders) beside `dest` that exports to `dest` left
/// when killed: `.NAME.partial-PID` whose process is gone. Best effort: what cannot be
/// removed stays, and the export goes on.
pub(crate) fn sweep_partials(dest: &Path) {
    let prefix = format!(".{}.partial-", file_name(dest));
    let dir = match dest.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    crate::run::atomic::sweep_dead(dir, &prefix);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only the temporary files of dead processes for the same destination go.
    #[test]
    fn sweep_removes_dead_partials_only() {
        let d = tempfile::tempdir().unwrap();
        let dest = d.path().join("out.nii");
        // PID 0 is never a user process; the test's own is alive.
        let dead = d.path().join(".out.nii.partial-999999999");
        let mine = partial_name(&dest);
        let other = d.path().join(".other.nii.partial-999999999");
        for p in [&dead, &mine, &other] {
            fs::write(p, b"x").unwrap();
        }
        sweep_partials(&dest);
        assert!(!dead.exists());
        assert!(mine.exists());
        assert!(other.exists());
    }

    /// A run, a file of a run and a foreign non-empty folder are refused even with
    /// force; a foreign file only without force.
    #[test]
    fn targets_are_refused_by_the_rules() {
        let d = tempfile::tempdir().unwrap();
        let run = d.path().join("R");
        fs::create_dir(&run).unwrap();
        fs::write(
            run.join("zarr.json"),
            br#"{"zarr_format":3,"node_type":"group","attributes":{"harmap":{}}}"#,
        )
        .unwrap();
        let folder = d.path().join("docs");
        fs::create_dir(&folder).unwrap();
        fs::write(folder.join("a.txt"), b"mine").unwrap();
        let file = d.path().join("notes.nii");
        fs::write(&file, b"not an image").unwrap();
        let k = ExportKind::Image(ImageFormat::Nifti);
        for force in [false, true] {
            assert!(check_target(&run, ExportKind::OmeZarr, force).is_err());
            assert!(check_target(&run.join("zarr.json"), k, force).is_err());
            assert!(check_target(&folder, ExportKind::OmeZarr, force).is_err());
        }
        assert!(check_target(&run.join("new.nii"), k, false).is_err());
        assert!(check_target(&run.join("new.nii"), k, true).is_ok());
        assert!(check_target(&file, k, false).is_err());
        assert!(check_target(&file, k, true).is_ok());
        assert!(check_target(&d.path().join("new.nii"), k, false).is_ok());
    }
}
