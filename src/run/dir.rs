//! An open run directory: its attributes, its images and its checkpoint files.

use std::fs;
use std::path::{Path, PathBuf};

use serde_json::{json, Map, Value};

use super::staging::lock_file;
use super::{
    io, ome_multiscales, write_atomic, CheckpointFiles, RunError, RunLock, FORMAT_VERSION,
};
use crate::grid::{world, Compression, GridSpec, Scalar, ZarrStore};

/// Wait for every MPI rank (nothing in one process). A failed barrier is an error of
/// the run's filesystem view: every rank stops.
pub(crate) fn sync(root: &Path) -> Result<(), RunError> {
    world().barrier().map_err(|e| RunError::Io {
        path: root.to_owned(),
        source: std::io::Error::other(e.to_string()),
    })
}

/// An open run directory.
#[derive(Clone, Debug)]
pub struct RunDir {
    pub(super) root: PathBuf,
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

    pub(super) fn write_group_attrs(&self, harmap: &Value) -> Result<(), RunError> {
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
    ///
    /// On MPI ranks every rank calls it at the same point; rank 0 writes, and every
    /// rank returns once the new attributes are there.
    pub fn update_attrs(&self, f: impl FnOnce(&mut Map<String, Value>)) -> Result<(), RunError> {
        if !world().is_root() {
            return sync(&self.root);
        }
        let r = self.update_attrs_here(f);
        sync(&self.root)?;
        r
    }

    fn update_attrs_here(&self, f: impl FnOnce(&mut Map<String, Value>)) -> Result<(), RunError> {
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
    ///
    /// On MPI ranks only rank 0 holds it (the others change only the chunks they own).
    pub fn lock(&self) -> Result<RunLock, RunError> {
        if !world().is_root() {
            return Ok(RunLock {
                file: None,
                path: self.root.clone(),
            });
        }
        let (file, path) = lock_file(&self.root)?;
        if file.try_lock().is_err() {
            return Err(RunError::Busy {
                path: self.root.clone(),
            });
        }
        Ok(RunLock {
            file: Some(file),
            path,
        })
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
        // MPI ranks: rank 0 makes the array, the others open it when it is there.
        let w = world();
        if !w.is_root() {
            sync(&self.root)?;
            return Ok(ZarrStore::open(
                &self.root,
                &format!("/{tmp}/0"),
                spec.clone(),
            )?);
        }
        // What a commit killed between its two renames left: the older image.
        super::atomic::sweep_dead(&self.root, &format!("{name}.old-"));
        if dir.exists() {
            fs::remove_dir_all(&dir).map_err(io(&dir))?;
        }
        let made = self.write_image(&tmp, name, spec, fill, compression);
        sync(&self.root)?;
        made
    }

    /// A guard that removes the staged images `names` (`RUN/NAME.partial/`) when it
    /// drops: a stage that fails on the way (a full disk) or stops leaves none of them
    /// behind. Images committed by then are no longer under their staging names, so
    /// it leaves them alone. Take it while holding the run's lock.
    pub fn staged_images(&self, names: &'static [&'static str]) -> StagedImages {
        StagedImages {
            dirs: names
                .iter()
                .map(|n| self.root.join(format!("{n}.partial")))
                .collect(),
        }
    }

    /// Move the image staged by [`RunDir::create_image_staged`] into place, replacing an
    /// older one.
    ///
    /// On MPI ranks: once every rank has written its chunks, rank 0 moves it; every
    /// rank returns once it is in place.
    pub fn commit_image(&self, name: &str) -> Result<(), RunError> {
        sync(&self.root)?;
        if !world().is_root() {
            return sync(&self.root);
        }
        let r = self.commit_image_here(name);
        sync(&self.root)?;
        r
    }

    fn commit_image_here(&self, name: &str) -> Result<(), RunError> {
        let tmp = self.root.join(format!("{name}.partial"));
        // On MPI ranks no rank wrote every chunk, so none marked the array whole.
        if world().parts() > 1 && tmp.join("0").join("zarr.json").exists() {
            crate::grid::mark_complete(&self.root, &format!("/{name}.partial/0")).map_err(|e| {
                RunError::Io {
                    path: tmp.clone(),
                    source: std::io::Error::other(e.to_string()),
                }
            })?;
        }
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

    /// Whether the run holds the image `name` (its array `name/0`; images are moved
    /// into place whole, see [`RunDir::commit_image`]).
    #[must_use]
    pub fn has_image(&self, name: &str) -> bool {
        self.root.join(name).join("0").exists()
    }

    /// Whether the run holds a seed table (`RUN/seeds/`, written by the trace).
    #[must_use]
    pub fn has_seed_table(&self) -> bool {
        self.root.join("seeds").exists()
    }

    /// Where the solve keeps its checkpoints (`RUN/solve/`).
    #[must_use]
    pub fn checkpoint_dir(&self) -> PathBuf {
        self.root.join("solve")
    }

    /// The checkpoint files of the solve (in [`RunDir::checkpoint_dir`]): every read
    /// and write of them goes through these.
    #[must_use]
    pub fn checkpoint_files(&self) -> CheckpointFiles {
        CheckpointFiles::new(self.checkpoint_dir())
    }

    /// Whether an interrupted solve left a checkpoint to resume from.
    #[must_use]
    pub fn has_checkpoint(&self) -> bool {
        self.checkpoint_files().has_manifest()
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

    /// Open the image staged by [`RunDir::create_image_staged`], not yet committed.
    pub fn open_staged_image<T: Scalar>(&self, name: &str) -> Result<ZarrStore<T>, crate::Error> {
        let spec = self.grid()?;
        Ok(ZarrStore::open(
            &self.root,
            &format!("/{name}.partial/0"),
            spec,
        )?)
    }

    /// Open the array of image `name`.
    pub fn open_image<T: Scalar>(&self, name: &str) -> Result<ZarrStore<T>, crate::Error> {
        let spec = self.grid()?;
        Ok(ZarrStore::open(&self.root, &format!("/{name}/0"), spec)?)
    }
}

/// Staged images (and a stage's scratch folders) removed on drop (see
/// [`RunDir::staged_images`]).
#[must_use = "the staged images are removed when the guard drops"]
pub struct StagedImages {
    dirs: Vec<PathBuf>,
}

impl StagedImages {
    /// Remove the folder `dir` too (a stage's scratch) when the guard drops.
    pub fn and_scratch(&mut self, dir: &Path) {
        self.dirs.push(dir.to_owned());
    }
}

impl Drop for StagedImages {
    fn drop(&mut self) {
        if !world().is_root() {
            return;
        }
        for dir in &self.dirs {
            if dir.exists() {
                let _ = fs::remove_dir_all(dir);
            }
        }
    }
}
