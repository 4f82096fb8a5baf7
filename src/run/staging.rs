//! A new run built under a staging name and renamed into place when whole, and the lock
//! file that keeps two harmap processes from writing the same run.

use std::fs;
use std::path::{Path, PathBuf};

use serde_json::json;

use super::{io, RunDir, RunError, FORMAT_VERSION};

/// The lock a stage holds on a run (see [`RunDir::lock`]).
#[derive(Debug)]
pub struct RunLock {
    /// None on the MPI ranks other than 0, which hold no lock of their own.
    pub(super) file: Option<fs::File>,
    pub(super) path: PathBuf,
}

impl Drop for RunLock {
    fn drop(&mut self) {
        if let Some(file) = &self.file {
            let _ = fs::remove_file(&self.path);
            let _ = file.unlock();
        }
    }
}

/// The staging directory of a run being created; [`Staging::commit`] renames it into
/// place. Dropped without commit, it is removed.
#[derive(Debug)]
pub struct Staging {
    run: RunDir,
    dest: PathBuf,
    lock: Option<(fs::File, PathBuf)>,
    committed: bool,
}

impl Staging {
    /// Start a new run that will live at `dest`.
    ///
    /// `dest` must name a directory (not `.`, `..` or a path ending in one). If it
    /// exists, it is replaced only when `force` is set **and** it is a harmap run
    /// directory (or empty): `--force` never deletes anything else. A lock file
    /// (`dest.lock`) keeps two harmap processes from building the same run; a staging
    /// directory left by a killed run is removed.
    pub fn begin(dest: &Path, force: bool) -> Result<Self, RunError> {
        let name = dest
            .file_name()
            .filter(|n| !n.is_empty() && *n != "." && *n != "..")
            .ok_or_else(|| RunError::NotARun {
                path: dest.to_owned(),
                reason: "the output must name a directory, like shape.harmap".into(),
            })?;
        let dest = dest.with_file_name(name);
        if dest.exists() {
            if !force {
                return Err(RunError::Exists { path: dest });
            }
            let empty_dir = fs::read_dir(&dest).is_ok_and(|mut d| d.next().is_none());
            if !empty_dir && RunDir::open(&dest).is_err() {
                return Err(RunError::NotARun {
                    path: dest,
                    reason: "--force replaces only a harmap run directory (or an empty one), and this is neither; choose another -o".into(),
                });
            }
        }
        let (lock, lock_path) = lock_file(&dest)?;
        if lock.try_lock().is_err() {
            return Err(RunError::Busy { path: dest });
        }
        let staging = staging_path(&dest);
        if staging.exists() {
            fs::remove_dir_all(&staging).map_err(io(&staging))?;
        }
        fs::create_dir_all(&staging).map_err(io(&staging))?;
        let run = RunDir { root: staging };
        run.write_group_attrs(&json!({
            "format_version": FORMAT_VERSION,
            "stages": {}
        }))?;
        Ok(Self {
            run,
            dest,
            lock: Some((lock, lock_path)),
            committed: false,
        })
    }

    /// The run being built.
    #[must_use]
    pub fn run(&self) -> &RunDir {
        &self.run
    }

    /// Move the finished run into place, replacing an old run (checked in `begin`).
    /// If the new run cannot be moved in, the old one is put back.
    pub fn commit(mut self) -> Result<RunDir, RunError> {
        let old = sibling(&self.dest, &format!("old-{}", std::process::id()));
        let replacing = self.dest.exists();
        if replacing {
            fs::rename(&self.dest, &old).map_err(io(&self.dest))?;
        }
        if let Err(e) = fs::rename(&self.run.root, &self.dest) {
            if replacing {
                let _ = fs::rename(&old, &self.dest);
            }
            return Err(io(&self.dest)(e));
        }
        let parent = self
            .dest
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if let Ok(d) = fs::File::open(parent) {
            let _ = d.sync_all();
        }
        self.committed = true;
        if replacing {
            fs::remove_dir_all(&old).map_err(io(&old))?;
        }
        Ok(RunDir {
            root: self.dest.clone(),
        })
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.run.root);
        }
        if let Some((lock, path)) = self.lock.take() {
            let _ = fs::remove_file(&path);
            drop(lock);
        }
    }
}

/// `dest` with `.suffix` appended to its last component (`a/b.harmap` ->
/// `a/b.harmap.partial`), whatever trailing slash `dest` was written with.
fn sibling(dest: &Path, suffix: &str) -> PathBuf {
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    dest.with_file_name(format!("{name}.{suffix}"))
}

/// The lock file of the run `dest` (next to it), created if missing, not yet locked.
pub(super) fn lock_file(dest: &Path) -> Result<(fs::File, PathBuf), RunError> {
    let path = sibling(dest, "lock");
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        // Only a parent that is not there: other failures (a file in the way, no
        // permission) are reported by the create below, as the OS says them.
        if fs::metadata(parent).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound) {
            return Err(RunError::NoParent {
                path: parent.to_path_buf(),
            });
        }
    }
    let file = fs::File::create(&path).map_err(io(&path))?;
    Ok((file, path))
}

/// Where the run for `dest` is staged.
#[must_use]
pub fn staging_path(dest: &Path) -> PathBuf {
    sibling(dest, "partial")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_being_built_is_locked() {
        let d = tempfile::tempdir().unwrap();
        let dest = d.path().join("x.harmap");
        let first = Staging::begin(&dest, false).unwrap();
        let second = Staging::begin(&dest, false).unwrap_err();
        assert!(matches!(second, RunError::Busy { .. }), "{second}");
        first.commit().unwrap();
        assert!(RunDir::open(&dest).is_ok());
        assert!(!d.path().join("x.harmap.lock").exists());
        // Dropped without commit: nothing is left.
        drop(Staging::begin(&d.path().join("y.harmap"), false).unwrap());
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
    }

    /// A run whose directory does not exist is refused with that directory's name, and
    /// nothing is created.
    #[test]
    fn a_missing_parent_directory_is_named() {
        let d = tempfile::tempdir().unwrap();
        let parent = d.path().join("no-such-dir");
        let e = Staging::begin(&parent.join("x.harmap"), false).unwrap_err();
        assert!(
            matches!(&e, RunError::NoParent { path } if *path == parent),
            "{e}"
        );
        assert!(e.is_bad_input());
        assert!(e.to_string().contains("does not exist"), "{e}");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 0);
    }
}
