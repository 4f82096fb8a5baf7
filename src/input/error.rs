//! Errors of reading inputs. Each names the file, and the line where there is one.

use std::path::PathBuf;

/// Why an input could not be read.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// The file could not be opened or read.
    ///
    /// Fix: check the path and permissions.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        source: std::io::Error,
    },
    /// A record of a text format is malformed.
    ///
    /// Fix: repair the line named, or re-export the file from its source program.
    #[error("{}:{line}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// What is wrong, with the offending text.
        message: String,
    },
    /// The file is readable but its content cannot be used (truncated binary data, an
    /// index out of range in a binary file, no triangles, a count that does not match).
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The file decodes to more bytes than `--mem` lets the readers hold (an endless
    /// stream such as `/dev/zero`, a gzip bomb, or a shape too large for the budget).
    ///
    /// Fix: check that the file is the one meant; give a larger `--mem`.
    #[error("{}: the input is larger than the readers may hold under --mem ({limit} of decoded bytes): {seen} read by byte {position} of the file (line {line} of the text); check that this is the file you meant, or give a larger --mem (the readers may hold a third of it)", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Decoded bytes read when it was refused, human readable.
        seen: String,
        /// Bytes of the file itself (compressed, for `.gz`) read by then.
        position: u64,
        /// Lines of the decoded text read by then (1-based).
        line: u64,
        /// The bound, human readable.
        limit: String,
    },
    /// The file name does not say which format it is.
    #[error("{}: unknown input format '{ext}'; harmap reads .obj, .stl, .ply, TetGen .node/.ele, molecules and point sets (.pdb, .cif/.mmcif, .pqr, .xyzr, .xyz, .csv with --radius), Zarr label volumes (a directory with zarr.json) and .raw volumes (with --raw-shape and --raw-dtype), each of the files optionally gzip-compressed (.gz)", path.display())]
    UnknownFormat {
        /// The file.
        path: PathBuf,
        /// The extension found.
        ext: String,
    },
}

impl InputError {
    /// Shorthand for [`InputError::Invalid`].
    pub fn invalid(path: &std::path::Path, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.to_owned(),
            message: message.into(),
        }
    }

    /// Shorthand for [`InputError::Parse`].
    pub fn parse(path: &std::path::Path, line: u64, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.to_owned(),
            line,
            message: message.into(),
        }
    }

    /// Shorthand for [`InputError::Io`].
    #[must_use]
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_owned(),
            source,
        }
    }
}
