//! A file written under a temporary name next to its destination and renamed into place
//! when whole: a killed export never leaves a truncated file under the real name, and
//! the next export to the same destination removes what a killed one left.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::ExportError;

/// A file written under a temporary name and renamed into place by [`Staged::commit`].
pub struct Staged {
    tmp: PathBuf,
    dest: PathBuf,
    pub(crate) out: BufWriter<fs::File>,
}

impl Staged {
    /// Create the temporary file for `dest`, after removing the temporary files that
    /// exports to `dest` killed earlier left.
    pub(crate) fn create(dest: &Path) -> Result<Self, ExportError> {
        super::safety::sweep_partials(dest);
        let tmp = super::safety::partial_name(dest);
        let f = fs::File::create(&tmp).map_err(|e| ExportError::Io {
            path: tmp.clone(),
            source: e,
        })?;
        Ok(Self {
            tmp,
            dest: dest.to_owned(),
            out: BufWriter::with_capacity(1 << 20, f),
        })
    }

    /// The error `e` of writing, named by the destination.
    pub(crate) fn io(&self, e: std::io::Error) -> ExportError {
        ExportError::Io {
            path: self.dest.clone(),
            source: e,
        }
    }

    /// Flush, sync and rename the file into place.
    pub(crate) fn commit(self) -> Result<(), ExportError> {
        let dest = self.dest.clone();
        let io = |e: std::io::Error| ExportError::Io {
            path: dest.clone(),
            source: e,
        };
        let mut me = self;
        me.out.flush().map_err(io)?;
        me.out.get_ref().sync_all().map_err(io)?;
        // After the rename the temporary name is gone, so the drop removes nothing.
        fs::rename(&me.tmp, &me.dest).map_err(io)
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        // Not committed (an error on the way): remove the partial file.
        let _ = fs::remove_file(&self.tmp);
    }
}
