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
    force: bool,
    committed: bool,
}

impl Staging {
    /// Start a new run that will live at `dest`. Fails if `dest` exists and `force` is
    /// not set. The staging directory is `dest` with `.partial` appended; a stale one
    /// from a killed run is removed first.
    pub fn begin(dest: &Path, force: bool) -> Result<Self, RunError> {
        if dest.exists() && !force {
            return Err(RunError::Exists {
                path: dest.to_owned(),
            });
        }
        let staging = staging_path(dest);
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
            dest: dest.to_owned(),
            force,
            committed: false,
        })
    }

    /// The run being built.
    #[must_use]
    pub fn run(&self) -> &RunDir {
        &self.run
    }

    /// Move the finished run into place (replacing an old one when forced).
    pub fn commit(mut self) -> Result<RunDir, RunError> {
        let old = self.dest.with_file_name(format!(
            "{}.old-{}",
            self.dest
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            std::process::id()
        ));
        let replacing = self.dest.exists();
        if replacing {
            debug_assert!(self.force);
            fs::rename(&self.dest, &old).map_err(io(&self.dest))?;
        }
        fs::rename(&self.run.root, &self.dest).map_err(io(&self.dest))?;
        if let Some(d) = self.dest.parent().and_then(|p| {
            fs::File::open(if p.as_os_str().is_empty() {
                Path::new(".")
            } else {
                p
            })
            .ok()
        }) {
            let _ = d.sync_all();
        }
        if replacing {
            fs::remove_dir_all(&old).map_err(io(&old))?;
        }
        self.committed = true;
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
    }
}

/// Where the run for `dest` is staged.
#[must_use]
pub fn staging_path(dest: &Path) -> PathBuf {
    let mut s = dest.as_os_str().to_owned();
    s.push(".partial");
    PathBuf::from(s)
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
        let dir = self.root.join(name);
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
            &format!("/{name}/0"),
            spec.clone(),
            fill,
            compression,
            Map::new(),
        )?)
    }

    /// Open the array of image `name`.
    pub fn open_image<T: Scalar>(&self, name: &str) -> Result<ZarrStore<T>, crate::Error> {
        let spec = self.grid()?;
        Ok(ZarrStore::open(&self.root, &format!("/{name}/0"), spec)?)
    }
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
