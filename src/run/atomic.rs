//! Writing files whole (a temporary name, fsync, rename), and the sweep of the
//! temporary files that killed writers left.

use std::fs;
use std::io::Write;
use std::path::Path;

use super::{io, RunError};

/// Write `bytes` to `path` atomically: temporary file, fsync, rename, fsync directory.
/// A failed write (a full disk) removes its temporary file; those that killed writers
/// of the same `path` left (`.NAME.tmp-PID` of a process that is gone) are swept first.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RunError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let prefix = format!(
        ".{}.tmp-",
        path.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    );
    sweep_dead(dir, &prefix);
    let tmp = dir.join(format!("{prefix}{}", std::process::id()));
    let written = (|| {
        let mut f = fs::File::create(&tmp).map_err(io(&tmp))?;
        f.write_all(bytes).map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))
    })();
    if let Err(e) = written {
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    fs::rename(&tmp, path).map_err(io(path))?;
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Whether process `pid` is running (None where this cannot be told: no `/proc`).
pub(crate) fn alive(pid: u32) -> Option<bool> {
    let proc = Path::new("/proc");
    proc.join("self")
        .exists()
        .then(|| proc.join(pid.to_string()).exists())
}

/// Remove the files (or folders) in `dir` named `PREFIX` + the id of a process that is
/// gone: what killed writers left. Best effort: what cannot be removed stays.
pub(crate) fn sweep_dead(dir: &Path, prefix: &str) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix(prefix)
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == std::process::id() || alive(pid) != Some(false) {
            continue;
        }
        let p = e.path();
        let _ = if p.is_dir() {
            fs::remove_dir_all(&p)
        } else {
            fs::remove_file(&p)
        };
    }
}
