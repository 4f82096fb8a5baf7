//! Reading the mark an export leaves in its file's first lines, by which a later export
//! knows its own earlier output ([`super::safety`]).

use std::fs;
use std::io::Read;
use std::path::Path;

/// The first bytes of a file: enough for every format's mark.
fn head(path: &Path, n: usize) -> Option<Vec<u8>> {
    let f = fs::File::open(path).ok()?;
    let mut buf = Vec::with_capacity(n);
    f.take(n as u64).read_to_end(&mut buf).ok()?;
    Some(buf)
}

/// The first line of the file at `path` (without its end), if it is text.
pub(crate) fn first_line(path: &Path) -> Option<String> {
    line(path, 0)
}

fn line(path: &Path, k: usize) -> Option<String> {
    let bytes = head(path, 4096)?;
    let text = String::from_utf8_lossy(&bytes);
    text.split('\n')
        .nth(k)
        .map(|l| l.trim_end_matches('\r').to_owned())
}

/// Whether line `k` (from 0) of the file at `path` is `text`.
pub(crate) fn starts_with_line(path: &Path, k: usize, text: &str) -> bool {
    line(path, k).is_some_and(|l| l == text)
}
