//! STL reader (ASCII and binary) on top of `stl_io`.
//!
//! `stl_io` decides ASCII versus binary by whether the first line starts with `"solid "`,
//! which misreads the many binary files whose free-text header also starts with "solid",
//! and ASCII files whose first line is a bare `solid`. Its errors carry no line numbers,
//! and its binary reader accepts NaN. So the format is decided here (a binary file has
//! exactly `84 + 50 N` bytes), the input is adjusted so `stl_io` takes the same view,
//! and its errors are located on their line by re-walking the ASCII grammar.

use std::borrow::Cow;
use std::collections::HashMap;
use std::io::Cursor;
use std::path::Path;

use super::{InputError, TriMesh};
use crate::math::Vec3;

/// Bytes before the first triangle of a binary STL: 80 of header, 4 of count.
const HEADER: u64 = 84;
/// Bytes per triangle of a binary STL: normal, three vertices, attribute count.
const RECORD: u64 = 50;

/// Parse a STL file already read into memory (decompressed).
///
/// STL stores each triangle's corners by value; corners with equal coordinates become
/// one vertex (with -0.0 equal to 0.0), so a closed surface comes out closed.
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<TriMesh, InputError> {
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(InputError::invalid(
            path,
            "empty file: it holds no triangles; check that the export succeeded",
        ));
    }
    let announced = (bytes.len() as u64 >= HEADER).then(|| {
        u64::from(u32::from_le_bytes([
            bytes[80], bytes[81], bytes[82], bytes[83],
        ]))
    });
    if announced.is_some_and(|n| HEADER + RECORD * n == bytes.len() as u64) {
        return read_binary(path, bytes);
    }
    if let Some(solid_line_end) = ascii_start(bytes) {
        return read_ascii(path, bytes, solid_line_end);
    }
    let Some(n) = announced else {
        return Err(InputError::invalid(
            path,
            format!(
                "neither an ASCII STL (it does not start with 'solid') nor a binary STL (it has {} bytes, fewer than the 84-byte header); the file is truncated or not an STL",
                bytes.len()
            ),
        ));
    };
    let expected = HEADER + RECORD * n;
    let found = bytes.len() as u64;
    if found < expected {
        return Err(InputError::invalid(
            path,
            format!(
                "truncated binary STL: the header announces {n} triangles ({expected} bytes) but the file has {found} bytes; re-export or re-download it"
            ),
        ));
    }
    if n == 0 {
        return Err(InputError::invalid(
            path,
            format!(
                "binary STL whose header announces 0 triangles, but {} bytes of data follow; the triangle count (bytes 80..84) is wrong, re-export the file",
                found - HEADER
            ),
        ));
    }
    // Longer than announced: trailing bytes after the last triangle are ignored, as by
    // every STL reader.
    read_binary(path, bytes)
}

/// If `bytes` look like ASCII STL (text whose first word is `solid`), the end offset of
/// the `solid` line.
fn ascii_start(bytes: &[u8]) -> Option<usize> {
    let body = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let start = bytes.len() - body.len() + body.iter().position(|b| !b.is_ascii_whitespace())?;
    if !bytes[start..].starts_with(b"solid") {
        return None;
    }
    // Binary floats almost always contain control bytes within the first facets.
    let head = &bytes[..bytes.len().min(1024)];
    if head
        .iter()
        .any(|&b| b < 0x20 && !matches!(b, b'\t' | b'\n' | b'\r' | 0x0c))
    {
        return None;
    }
    Some(
        bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |p| start + p),
    )
}

/// Read a binary STL whose size has been checked, through `stl_io`.
fn read_binary(path: &Path, bytes: &[u8]) -> Result<TriMesh, InputError> {
    // stl_io would take a header starting with "solid " for ASCII; the header is free
    // text, so blank its first byte.
    let input: Cow<'_, [u8]> = if bytes.starts_with(b"solid") {
        let mut copy = bytes.to_vec();
        copy[0] = b' ';
        Cow::Owned(copy)
    } else {
        Cow::Borrowed(bytes)
    };
    let mut cursor = Cursor::new(&input[..]);
    let triangles = stl_io::create_stl_reader(&mut cursor)
        .map_err(|e| InputError::invalid(path, format!("cannot read the binary STL: {e}")))?;
    let mut builder = Builder::default();
    for (t, triangle) in triangles.enumerate() {
        let triangle = triangle.map_err(|e| {
            InputError::invalid(
                path,
                format!(
                    "cannot read triangle {} of the binary STL: {e}; the file may be truncated",
                    t + 1
                ),
            )
        })?;
        for (c, v) in triangle.vertices.iter().enumerate() {
            if let Some(x) = v.0.iter().find(|x| !x.is_finite()) {
                return Err(InputError::invalid(
                    path,
                    format!(
                        "triangle {} (corner {}) has a non-finite coordinate {x}; fix or remove the triangle",
                        t + 1,
                        c + 1
                    ),
                ));
            }
        }
        builder.push(path, triangle.vertices.map(|v| v.0))?;
    }
    builder.finish(path)
}

/// Read an ASCII STL through `stl_io`; `solid_line_end` is where its first line ends.
fn read_ascii(path: &Path, bytes: &[u8], solid_line_end: usize) -> Result<TriMesh, InputError> {
    // stl_io wants the very first line to start with "solid " (with the space).
    let input: Cow<'_, [u8]> = if bytes.starts_with(b"solid ") {
        Cow::Borrowed(bytes)
    } else {
        let mut copy = b"solid harmap".to_vec();
        copy.extend_from_slice(&bytes[solid_line_end..]);
        Cow::Owned(copy)
    };
    let mut cursor = Cursor::new(&input[..]);
    let triangles = stl_io::create_stl_reader(&mut cursor)
        .map_err(|e| InputError::invalid(path, format!("cannot read the ASCII STL: {e}")))?;
    let mut builder = Builder::default();
    for (t, triangle) in triangles.enumerate() {
        let triangle = triangle.map_err(|e| locate_ascii_error(path, bytes, t, &e))?;
        builder.push(path, triangle.vertices.map(|v| v.0))?;
    }
    builder.finish(path)
}

/// Collects triangles, giving each distinct corner position one vertex index.
#[derive(Default)]
struct Builder {
    /// The mesh so far.
    mesh: TriMesh,
    /// Vertex index of each position seen, by the bits of its coordinates.
    index: HashMap<[u32; 3], u32>,
}

impl Builder {
    /// Add one triangle given by its corner positions.
    fn push(&mut self, path: &Path, corners: [[f32; 3]; 3]) -> Result<(), InputError> {
        let mut tri = [0; 3];
        for (slot, p) in tri.iter_mut().zip(corners) {
            // `+ 0.0` turns -0.0 into 0.0 so that both zeros are one vertex.
            let p = p.map(|x| x + 0.0);
            let next = u32::try_from(self.mesh.vertices.len()).map_err(|_| {
                InputError::invalid(path, "more than 2^32 vertices: split the mesh")
            })?;
            *slot = *self.index.entry(p.map(f32::to_bits)).or_insert_with(|| {
                self.mesh.vertices.push(Vec3::new(
                    f64::from(p[0]),
                    f64::from(p[1]),
                    f64::from(p[2]),
                ));
                next
            });
        }
        self.mesh.triangles.push(tri);
        Ok(())
    }

    /// The mesh, or an error if it has no triangle.
    fn finish(self, path: &Path) -> Result<TriMesh, InputError> {
        if self.mesh.triangles.is_empty() {
            return Err(InputError::invalid(
                path,
                "no triangles: the STL holds no facets; export the surface again",
            ));
        }
        Ok(self.mesh)
    }
}

/// The expected lines of one ASCII facet: keywords, then how many numbers follow.
const FACET: [(&[&str], usize); 7] = [
    (&["facet", "normal"], 3),
    (&["outer", "loop"], 0),
    (&["vertex"], 3),
    (&["vertex"], 3),
    (&["vertex"], 3),
    (&["endloop"], 0),
    (&["endfacet"], 0),
];

/// Find the line of an `stl_io` error met while reading facet `done + 1`, by walking the
/// ASCII grammar as `stl_io` does (one record per non-blank line, numbers as `f32`).
fn locate_ascii_error(path: &Path, bytes: &[u8], done: usize, e: &std::io::Error) -> InputError {
    let mut records = bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .map(|(i, raw)| (i as u64 + 1, String::from_utf8_lossy(raw)))
        .filter(|(_, text)| !text.trim().is_empty())
        .skip(1 + 7 * done);
    let facet = done + 1;
    let mut last_line = 1;
    let mut facet_start = None;
    for (k, (keywords, count)) in FACET.iter().enumerate() {
        let Some((line, text)) = records.next() else {
            let message = if k == 0 {
                "the file ends without 'endsolid': it is truncated; re-export it".to_owned()
            } else {
                format!(
                    "the file ends inside facet {facet} (begun on line {}): it is truncated; re-export it",
                    facet_start.unwrap_or(last_line)
                )
            };
            return InputError::parse(path, last_line, message);
        };
        last_line = line;
        facet_start.get_or_insert(line);
        let words: Vec<&str> = text.split_whitespace().collect();
        if k == 0 && words.first() == Some(&"endsolid") {
            break;
        }
        let want = keywords.join(" ");
        let shape_ok = words.len() == keywords.len() + count
            && words.iter().zip(*keywords).all(|(w, k)| w == k);
        if !shape_ok {
            let numbers = if *count > 0 {
                format!(" and {count} numbers")
            } else {
                String::new()
            };
            return InputError::parse(
                path,
                line,
                format!(
                    "expected '{want}'{numbers} (facet {facet}), found '{}'; repair the facet or re-export the file",
                    text.trim()
                ),
            );
        }
        for w in &words[keywords.len()..] {
            let what = if k == 0 { "facet normal" } else { "vertex" };
            match w.parse::<f32>() {
                Err(_) => {
                    return InputError::parse(
                        path,
                        line,
                        format!("{what} coordinate '{w}' is not a number: '{}'; fix or remove the facet", text.trim()),
                    );
                }
                Ok(x) if !x.is_finite() => {
                    return InputError::parse(
                        path,
                        line,
                        format!("{what} has a non-finite coordinate '{w}' (as 32-bit float); fix or remove the facet"),
                    );
                }
                Ok(_) => {}
            }
        }
    }
    InputError::parse(
        path,
        facet_start.unwrap_or(last_line),
        format!("cannot read facet {facet}: {e}; repair the facet or re-export the file"),
    )
}

#[cfg(test)]
mod tests {
    use std::fmt::Write;

    use super::*;

    const P: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    const T: [[usize; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];

    fn ascii_tet() -> String {
        let mut s = String::from("solid tet\n");
        for t in T {
            s.push_str("  facet normal 0 0 0\n    outer loop\n");
            for i in t {
                let [x, y, z] = P[i];
                writeln!(s, "      vertex {x} {y} {z}").unwrap();
            }
            s.push_str("    endloop\n  endfacet\n");
        }
        s.push_str("endsolid tet\n");
        s
    }

    fn binary(header: &[u8], count: u32, triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
        let mut b = vec![b' '; 80];
        b[..header.len()].copy_from_slice(header);
        b.extend_from_slice(&count.to_le_bytes());
        for t in triangles {
            b.extend_from_slice(&[0u8; 12]);
            for v in t {
                for x in v {
                    b.extend_from_slice(&x.to_le_bytes());
                }
            }
            b.extend_from_slice(&[0, 0]);
        }
        b
    }

    fn tet_triangles() -> Vec<[[f32; 3]; 3]> {
        T.iter().map(|t| t.map(|i| P[i])).collect()
    }

    fn check_tet(m: &TriMesh) {
        assert_eq!(m.vertices.len(), 4);
        assert_eq!(m.triangles.len(), 4);
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
        assert!((m.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
    }

    fn error(bytes: &[u8]) -> String {
        read(Path::new("t.stl"), bytes)
            .expect_err("the input should be rejected")
            .to_string()
    }

    #[test]
    fn ascii_tetrahedron() {
        check_tet(&read(Path::new("t.stl"), ascii_tet().as_bytes()).unwrap());
        let crlf = ascii_tet().replace('\n', "\r\n");
        check_tet(&read(Path::new("t.stl"), crlf.as_bytes()).unwrap());
        let bare = ascii_tet().replacen("solid tet", "solid", 1);
        check_tet(&read(Path::new("t.stl"), bare.as_bytes()).unwrap());
    }

    #[test]
    fn binary_tetrahedron() {
        check_tet(
            &read(
                Path::new("t.stl"),
                &binary(b"exported", 4, &tet_triangles()),
            )
            .unwrap(),
        );
    }

    #[test]
    fn binary_with_solid_header() {
        let bytes = binary(
            b"solid tet exported by a careless tool",
            4,
            &tet_triangles(),
        );
        assert!(bytes.starts_with(b"solid "));
        check_tet(&read(Path::new("t.stl"), &bytes).unwrap());
    }

    #[test]
    fn negative_zero_is_one_vertex() {
        let mut tris = tet_triangles();
        tris[1][0] = [-0.0, 0.0, -0.0];
        check_tet(&read(Path::new("t.stl"), &binary(b"", 4, &tris)).unwrap());
    }

    #[test]
    fn binary_trailing_bytes_are_ignored() {
        let mut bytes = binary(b"", 4, &tet_triangles());
        bytes.extend_from_slice(b"\0\0\0");
        check_tet(&read(Path::new("t.stl"), &bytes).unwrap());
    }

    #[test]
    fn truncated_binary() {
        let mut bytes = binary(b"", 12, &tet_triangles());
        bytes.truncate(200);
        assert_eq!(
            error(&bytes),
            "t.stl: truncated binary STL: the header announces 12 triangles (684 bytes) but the file has 200 bytes; re-export or re-download it"
        );
        let solid = binary(b"solid x", 12, &tet_triangles());
        assert!(error(&solid).contains("truncated binary STL"));
        assert!(error(&[1, 2, 3]).contains("fewer than the 84-byte header"));
        // A huge announced count must not be trusted for allocation.
        assert!(error(&binary(b"", u32::MAX, &tet_triangles())).contains("truncated"));
    }

    #[test]
    fn binary_zero_count_with_data() {
        let mut bytes = binary(b"", 0, &tet_triangles());
        bytes.push(0);
        assert!(error(&bytes).contains("announces 0 triangles"));
        assert!(error(&binary(b"", 0, &[])).contains("no triangles"));
    }

    #[test]
    fn binary_nan_names_the_triangle() {
        let mut tris = tet_triangles();
        tris[2][1][2] = f32::NAN;
        let e = error(&binary(b"", 4, &tris));
        assert!(
            e.contains("triangle 3 (corner 2)") && e.contains("NaN"),
            "{e}"
        );
        tris[2][1][2] = f32::INFINITY;
        assert!(error(&binary(b"", 4, &tris)).contains("non-finite"));
    }

    #[test]
    fn empty_files() {
        assert!(error(b"").contains("empty file"));
        assert!(error(b"\n  \n").contains("empty file"));
        assert!(error(b"solid empty\nendsolid empty\n").contains("no triangles"));
    }

    #[test]
    fn ascii_errors_name_the_line() {
        let text = ascii_tet();
        let line_of = |needle: &str| text.lines().position(|l| l.contains(needle)).unwrap() + 1;
        // Second facet's first vertex.
        let target = "vertex 1 0 0";
        let n = text
            .lines()
            .enumerate()
            .filter(|(_, l)| l.contains(target))
            .nth(1)
            .unwrap()
            .0
            + 1;
        let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
        lines[n - 1] = "      vertex 1 nan 0".into();
        let e = error(lines.join("\n").as_bytes());
        assert_eq!(e, format!("t.stl:{n}: vertex has a non-finite coordinate 'nan' (as 32-bit float); fix or remove the facet"));
        lines[n - 1] = "      vertex 1 abc 0".into();
        let e = error(lines.join("\n").as_bytes());
        assert!(
            e.starts_with(&format!("t.stl:{n}:")) && e.contains("'abc' is not a number"),
            "{e}"
        );
        lines[n - 1] = "      vertex 1 1e39 0".into();
        assert!(error(lines.join("\n").as_bytes()).contains("non-finite"));
        lines[n - 1] = "      vertex 1 0".into();
        let e = error(lines.join("\n").as_bytes());
        assert!(
            e.starts_with(&format!("t.stl:{n}:"))
                && e.contains("expected 'vertex' and 3 numbers (facet 2)"),
            "{e}"
        );
        // Missing endloop.
        let e = error(text.replacen("    endloop\n", "", 1).as_bytes());
        let endloop = line_of("endloop");
        assert!(
            e.starts_with(&format!("t.stl:{endloop}:")) && e.contains("expected 'endloop'"),
            "{e}"
        );
    }

    #[test]
    fn real_spot_as_binary_stl() {
        // STL repeats each corner per triangle; welding must give back the closed surface.
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes/spot.obj");
        let Ok(bytes) = std::fs::read(&path) else {
            return;
        };
        let obj = super::super::obj::read(&path, &bytes).unwrap();
        let tris: Vec<[[f32; 3]; 3]> = obj
            .triangles
            .iter()
            .map(|t| t.map(|i| obj.vertices[i as usize].as_vec3().to_array()))
            .collect();
        let count = u32::try_from(tris.len()).unwrap();
        let m = read(Path::new("spot.stl"), &binary(b"solid spot", count, &tris)).unwrap();
        assert_eq!(m.triangles.len(), 5856);
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
        assert!((m.signed_volume() - obj.signed_volume()).abs() < 1e-4);
    }

    #[test]
    fn ascii_truncated() {
        let text = ascii_tet();
        let cut = &text[..text.find("endloop").unwrap()];
        let e = error(cut.as_bytes());
        assert!(e.contains("ends inside facet 1 (begun on line 2)"), "{e}");
        let e = error(text.replace("endsolid tet\n", "").as_bytes());
        assert!(e.contains("without 'endsolid'"), "{e}");
    }
}
