//! OME-Zarr export: the run's image groups (OME-Zarr 0.5, as stored in the run) copied
//! into a new Zarr v3 group whose attribute `harmap_export` marks it as harmap's own.

use std::path::Path;

use super::source::Source;
use super::Field;
use crate::export::{is_own_output, ExportError, ExportKind};
use crate::run::RunDir;

/// Copy the image groups of `fields` (OME-Zarr 0.5, as stored in the run) into a new
/// Zarr v3 group at `dest`, checking each one's metadata first. Built under a temporary
/// name and renamed when whole. Returns the number of images.
pub fn export_ome_zarr(run: &RunDir, fields: &[Field], dest: &Path) -> Result<u64, crate::Error> {
    let spec = run.grid()?;
    for &f in fields {
        Source::open(run, f)?;
        let meta = run.root().join(f.name()).join("zarr.json");
        let doc: serde_json::Value = std::fs::read(&meta)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_default();
        let ome = doc.pointer("/attributes/ome").cloned().unwrap_or_default();
        if ome != crate::run::ome_multiscales(f.name(), &spec) {
            return Err(ExportError::Unavailable(format!(
                "{}: the OME-Zarr metadata is not the one harmap writes for this grid",
                meta.display()
            ))
            .into());
        }
    }
    let io = |p: &Path| {
        let p = p.to_owned();
        move |e: std::io::Error| ExportError::Io { path: p, source: e }
    };
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    crate::export::safety::sweep_partials(dest);
    let tmp = crate::export::safety::partial_name(dest);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let result = (|| -> Result<(), crate::Error> {
        let doc = serde_json::json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": {"harmap_export": {
                "run": run.root().display().to_string(),
                "images": fields.iter().map(|f| f.name()).collect::<Vec<_>>(),
                "grid": spec,
            }}
        });
        std::fs::write(
            tmp.join("zarr.json"),
            serde_json::to_string_pretty(&doc).expect("json"),
        )
        .map_err(io(&tmp))?;
        for f in fields {
            copy_tree(&run.root().join(f.name()), &tmp.join(f.name()))?;
        }
        // What is replaced must be this export's own earlier output (or, as the caller
        // allowed with force, a file or an empty folder): never anything else, whatever
        // the caller checked before.
        if std::fs::symlink_metadata(dest).is_ok() {
            let own = is_own_output(dest, ExportKind::OmeZarr);
            if dest.is_dir()
                && !own
                && std::fs::read_dir(dest).map_or(true, |mut e| e.next().is_some())
            {
                return Err(ExportError::Refused(format!(
                    "{}: a folder that is not a harmap ome-zarr export is never replaced",
                    dest.display()
                ))
                .into());
            }
            let old = dest.with_file_name(format!(".{name}.old-{}", std::process::id()));
            std::fs::rename(dest, &old).map_err(io(dest))?;
            std::fs::rename(&tmp, dest).map_err(io(dest))?;
            if old.is_dir() {
                std::fs::remove_dir_all(&old).map_err(io(&old))?;
            } else {
                std::fs::remove_file(&old).map_err(io(&old))?;
            }
        } else {
            std::fs::rename(&tmp, dest).map_err(io(dest))?;
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result?;
    Ok(fields.len() as u64)
}

fn copy_tree(from: &Path, to: &Path) -> Result<(), ExportError> {
    let io = |p: &Path| {
        let p = p.to_owned();
        move |e: std::io::Error| ExportError::Io { path: p, source: e }
    };
    std::fs::create_dir_all(to).map_err(io(to))?;
    for e in std::fs::read_dir(from).map_err(io(from))? {
        let e = e.map_err(io(from))?;
        let dest = to.join(e.file_name());
        if e.file_type().map_err(io(&e.path()))?.is_dir() {
            copy_tree(&e.path(), &dest)?;
        } else {
            std::fs::copy(e.path(), &dest).map_err(io(&dest))?;
        }
    }
    Ok(())
}
