//! The run directory: a Zarr v3 group holding every array of a run and its metadata.
//!
//! Layout (format version [`FORMAT_VERSION`], documented in `docs/format.md`):
//! ```text
//! RUN/zarr.json        group; attributes {"harmap": {format_version, grid, center,
//!                      input, stages}}
//! RUN/labels/zarr.json OME-Zarr 0.5 image group ("ome" multiscales, one level)
//! RUN/labels/0/        u8 labels [z, y, x]
//! ```
//! A new run is built under a staging name next to its destination and renamed into
//! place when whole, so an interrupted run never leaves a directory that looks complete.
//! Metadata updates go through a temporary file, fsync and rename.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::{json, Map, Value};

use crate::grid::{Compression, GridSpec, Scalar, ZarrStore};

/// Version of the on-disk layout this build writes and reads.
pub const FORMAT_VERSION: u64 = 1;

/// Errors of the run directory.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A filesystem operation failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// The path is not a harmap run directory.
    ///
    /// Fix: give the directory written by `harmap voxelize -o RUN`.
    #[error("{}: not a harmap run directory ({reason})", path.display())]
    NotARun {
        /// The path.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The destination exists.
    ///
    /// Fix: choose another `-o`, or pass `--force` to replace it.
    #[error("{}: already exists; choose another -o or pass --force to replace it", path.display())]
    Exists {
        /// The path.
        path: PathBuf,
    },
    /// Another harmap process is building the same run.
    ///
    /// Fix: wait for it, or choose another `-o`.
    #[error("{}: another harmap process is writing this run (its lock file is held); wait for it or choose another -o", path.display())]
    Busy {
        /// The run.
        path: PathBuf,
    },
    /// The directory that should hold the run does not exist.
    ///
    /// Fix: create it, or give another `-o`.
    #[error("{}: the directory for the run does not exist; create it or give another -o", path.display())]
    NoParent {
        /// The missing directory.
        path: PathBuf,
    },
    /// The run was written by an incompatible version of harmap.
    #[error("{}: format version {found}, this harmap reads version {FORMAT_VERSION}; redo the run with this version", path.display())]
    Version {
        /// The path.
        path: PathBuf,
        /// Version found.
        found: u64,
    },
    /// A stage this command needs has not been run.
    #[error("{}: stage '{stage}' has not completed; run `harmap {stage}` first", path.display())]
    StageMissing {
        /// The run.
        path: PathBuf,
        /// The stage.
        stage: String,
    },
}

impl RunError {
    /// Whether this is the user's mistake (exit code 2).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, RunError::Io { .. })
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Write `bytes` to `path` atomically: temporary file, fsync, rename, fsync directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RunError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        path.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        std::process::id()
    ));
    {
        let mut f = fs::File::create(&tmp).map_err(io(&tmp))?;
        f.write_all(bytes).map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))?;
    }
    fs::rename(&tmp, path).map_err(io(path))?;
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// The lock a stage holds on a run (see [`RunDir::lock`]).
#[derive(Debug)]
pub struct RunLock {
    file: fs::File,
    path: PathBuf,
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
        let _ = self.file.unlock();
    }
}

/// An open run directory.
#[derive(Clone, Debug)]
pub struct RunDir {
    root: PathBuf,
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
fn lock_file(dest: &Path) -> Result<(fs::File, PathBuf), RunError> {
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

impl RunDir {
    /// Open an existing run directory and check its format version.
    pub fn open(path: &Path) -> Result<Self, RunError> {
        let not = |reason: &str| RunError::NotARun {
            path: path.to_owned(),
            reason: reason.to_owned(),
        };
        let meta = path.join("zarr.json");
        let text = fs::read_to_string(&meta).map_err(|_| {
            if path.exists() {
                not("no zarr.json in it")
            } else {
                not("no such directory")
            }
        })?;
        let v: Value =
            serde_json::from_str(&text).map_err(|_| not("zarr.json is not valid JSON"))?;
        let version = v
            .pointer("/attributes/harmap/format_version")
            .and_then(Value::as_u64)
            .ok_or_else(|| not("zarr.json has no harmap attributes"))?;
        if version != FORMAT_VERSION {
            return Err(RunError::Version {
                path: path.to_owned(),
                found: version,
            });
        }
        Ok(Self {
            root: path.to_owned(),
        })
    }

    /// The directory.
    #[must_use]
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The `harmap` group attributes.
    pub fn attrs(&self) -> Result<Value, RunError> {
        let p = self.root.join("zarr.json");
        let text = fs::read_to_string(&p).map_err(io(&p))?;
        let v: Value = serde_json::from_str(&text).map_err(|e| RunError::NotARun {
            path: self.root.clone(),
            reason: format!("zarr.json: {e}"),
        })?;
        Ok(v.pointer("/attributes/harmap")
            .cloned()
            .unwrap_or(Value::Null))
    }

    fn write_group_attrs(&self, harmap: &Value) -> Result<(), RunError> {
        let doc = json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": { "harmap": harmap }
        });
        write_atomic(
            &self.root.join("zarr.json"),
            serde_json::to_string_pretty(&doc).expect("json").as_bytes(),
        )
    }

    /// Change the `harmap` attributes atomically.
    pub fn update_attrs(&self, f: impl FnOnce(&mut Map<String, Value>)) -> Result<(), RunError> {
        let mut v = self.attrs()?;
        let obj = v.as_object_mut().ok_or_else(|| RunError::NotARun {
            path: self.root.clone(),
            reason: "harmap attributes are not an object".into(),
        })?;
        f(obj);
        self.write_group_attrs(&v)
    }

    /// Record stage `name` as done: `harmap.stages.<name>` = status, seconds, options
    /// and result.
    pub fn record_stage(
        &self,
        name: &str,
        seconds: f64,
        options: impl serde::Serialize,
        result: impl serde::Serialize,
    ) -> Result<(), RunError> {
        let mut v =
            json!({"status": "done", "seconds": seconds, "options": options, "result": result});
        if let Some(peak) = take_peak_rss() {
            v["peak_rss_bytes"] = json!(peak);
        }
        self.update_attrs(|a| {
            let stages = a.entry("stages").or_insert_with(|| json!({}));
            stages[name] = v;
        })
    }

    /// The attributes, when stage `stage` is done; else the error that names it.
    pub fn require_stage(&self, stage: &str) -> Result<Value, RunError> {
        let attrs = self.attrs()?;
        if stage_done(&attrs, stage) {
            Ok(attrs)
        } else {
            Err(RunError::StageMissing {
                path: self.root.clone(),
                stage: stage.into(),
            })
        }
    }

    /// The grid of the run (from `harmap.grid`), with the chunk shape of `labels/0`.
    pub fn grid(&self) -> Result<GridSpec, RunError> {
        let a = self.attrs()?;
        let g = a.get("grid").ok_or_else(|| RunError::StageMissing {
            path: self.root.clone(),
            stage: "voxelize".into(),
        })?;
        serde_json::from_value(g.clone()).map_err(|e| RunError::NotARun {
            path: self.root.clone(),
            reason: format!("harmap.grid: {e}"),
        })
    }

    /// Create the OME-Zarr image group `name` with its single array `name/0`.
    pub fn create_image<T: Scalar>(
        &self,
        name: &str,
        spec: &GridSpec,
        fill: T,
        compression: Compression,
    ) -> Result<ZarrStore<T>, crate::Error> {
        self.write_image(name, name, spec, fill, compression)
    }

    /// The image group `name` (OME metadata and array `0`) in the directory `dir_name`.
    fn write_image<T: Scalar>(
        &self,
        dir_name: &str,
        name: &str,
        spec: &GridSpec,
        fill: T,
        compression: Compression,
    ) -> Result<ZarrStore<T>, crate::Error> {
        let dir = self.root.join(dir_name);
        fs::create_dir_all(&dir).map_err(io(&dir))?;
        let doc = json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": { "ome": ome_multiscales(name, spec) }
        });
        write_atomic(
            &dir.join("zarr.json"),
            serde_json::to_string_pretty(&doc).expect("json").as_bytes(),
        )?;
        Ok(ZarrStore::create(
            &self.root,
            &format!("/{dir_name}/0"),
            spec.clone(),
            fill,
            compression,
            Map::new(),
        )?)
    }

    /// Hold the run's lock file (`RUN.lock`) while a stage changes the run, so two
    /// harmap processes never write the same run. Released when the guard drops.
    pub fn lock(&self) -> Result<RunLock, RunError> {
        let (file, path) = lock_file(&self.root)?;
        if file.try_lock().is_err() {
            return Err(RunError::Busy {
                path: self.root.clone(),
            });
        }
        Ok(RunLock { file, path })
    }

    /// Create the image `name` under a temporary directory name; [`RunDir::commit_image`]
    /// moves it into place once whole, so a killed stage never leaves a partial image
    /// under the real name.
    pub fn create_image_staged<T: Scalar>(
        &self,
        name: &str,
        spec: &GridSpec,
        fill: T,
        compression: Compression,
    ) -> Result<ZarrStore<T>, crate::Error> {
        let tmp = format!("{name}.partial");
        let dir = self.root.join(&tmp);
        if dir.exists() {
            fs::remove_dir_all(&dir).map_err(io(&dir))?;
        }
        self.write_image(&tmp, name, spec, fill, compression)
    }

    /// Move the image staged by [`RunDir::create_image_staged`] into place, replacing an
    /// older one.
    pub fn commit_image(&self, name: &str) -> Result<(), RunError> {
        let tmp = self.root.join(format!("{name}.partial"));
        let dest = self.root.join(name);
        let old = self.root.join(format!("{name}.old-{}", std::process::id()));
        let replacing = dest.exists();
        if replacing {
            fs::rename(&dest, &old).map_err(io(&dest))?;
        }
        fs::rename(&tmp, &dest).map_err(io(&dest))?;
        if let Ok(d) = fs::File::open(&self.root) {
            let _ = d.sync_all();
        }
        if replacing {
            fs::remove_dir_all(&old).map_err(io(&old))?;
        }
        Ok(())
    }

    /// The Zarr data type of image `name` (`float32`, `float64`, `uint8`, ...).
    pub fn image_data_type(&self, name: &str) -> Result<String, crate::Error> {
        let path = self.root.join(name).join("0").join("zarr.json");
        let text = fs::read_to_string(&path).map_err(io(&path))?;
        let meta: Value =
            serde_json::from_str(&text).map_err(|e| crate::grid::GridError::Zarr {
                path: path.display().to_string(),
                message: e.to_string(),
            })?;
        meta.get("data_type")
            .and_then(Value::as_str)
            .map(str::to_owned)
            .ok_or_else(|| {
                crate::grid::GridError::Zarr {
                    path: path.display().to_string(),
                    message: "no data_type".into(),
                }
                .into()
            })
    }

    /// Open the array of image `name`.
    pub fn open_image<T: Scalar>(&self, name: &str) -> Result<ZarrStore<T>, crate::Error> {
        let spec = self.grid()?;
        Ok(ZarrStore::open(&self.root, &format!("/{name}/0"), spec)?)
    }
}

/// The process's peak resident memory, bytes, since the last call (or since it
/// started), and the peak measure restarted, so that each stage recorded by a process
/// that runs several gets its own peak. Linux only (`VmHWM` of /proc/self/status, reset
/// through /proc/self/clear_refs); None elsewhere or when /proc cannot be read. When
/// the reset is refused the peak stays that of the whole process so far.
#[must_use]
pub fn take_peak_rss() -> Option<u64> {
    let status = fs::read_to_string("/proc/self/status").ok()?;
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    // "5" resets the peak to the current resident set (Linux 4.0 and later).
    let _ = fs::write("/proc/self/clear_refs", "5");
    Some(kib * 1024)
}

/// Whether `harmap.stages.<stage>.status` is `done` in the attributes `attrs`.
#[must_use]
pub fn stage_done(attrs: &Value, stage: &str) -> bool {
    attrs
        .get("stages")
        .and_then(|s| s.get(stage))
        .and_then(|s| s.get("status"))
        .and_then(Value::as_str)
        == Some("done")
}

/// OME-Zarr 0.5 `ome` attributes for a single-level image of the grid: axes z, y, x with
/// the grid's unit, scale = spacing, translation = world position of voxel (0, 0, 0).
#[must_use]
pub fn ome_multiscales(name: &str, spec: &GridSpec) -> Value {
    let axes: Vec<Value> = ["z", "y", "x"]
        .iter()
        .map(|a| match &spec.unit {
            Some(u) => json!({"name": a, "type": "space", "unit": u}),
            None => json!({"name": a, "type": "space"}),
        })
        .collect();
    json!({
        "version": "0.5",
        "multiscales": [{
            "name": name,
            "axes": axes,
            "datasets": [{
                "path": "0",
                "coordinateTransformations": [
                    {"type": "scale", "scale": [spec.spacing, spec.spacing, spec.spacing]},
                    {"type": "translation", "translation": [spec.origin[2], spec.origin[1], spec.origin[0]]}
                ]
            }]
        }]
    })
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
