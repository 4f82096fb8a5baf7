//! PLY reader (ASCII, binary little and big endian) on top of `ply-rs-bw`.
//!
//! The header is read first and checked for what a surface needs (`x`, `y`, `z` on the
//! vertex element, an integer list `vertex_indices` or `vertex_index` on the face
//! element), so that later errors can speak of vertices and faces rather than of
//! properties. Each element is then read with its own small record type, which keeps
//! memory at a few words per vertex and skips every other property. The library never
//! panics on short input (it reports `UnexpectedEof` and caps its preallocation), so the
//! sizes need no checking beforehand; its errors are translated into ones that name the
//! line (ASCII) or the element number (binary) and say what to do.

use std::io::Cursor;
use std::path::Path;

use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Encoding, Header, PropertyAccess, PropertyType, ScalarType};

use super::{InputError, TriMesh};
use crate::math::Vec3;

/// Names the face list may have; both are in common use.
const FACE_LISTS: [&str; 2] = ["vertex_indices", "vertex_index"];

/// Parse a PLY file already read into memory (decompressed).
///
/// Faces with more than three corners are fan-triangulated; properties other than the
/// coordinates and the face list, and elements other than `vertex` and `face`, are
/// skipped.
#[allow(clippy::too_many_lines)] // one pass over the PLY header and body, element by element
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<TriMesh, InputError> {
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(InputError::invalid(
            path,
            "empty file: it holds no vertices and no faces; check that the export succeeded",
        ));
    }
    if !bytes.starts_with(b"ply") {
        return Err(InputError::parse(
            path,
            1,
            "not a PLY file: it does not start with 'ply'; check the file and its extension",
        ));
    }
    let mut reader = Reader::new(Cursor::new(bytes));
    let header = Parser::<Skip>::new()
        .read_header(&mut reader)
        .map_err(|e| header_error(path, bytes, &e))?;
    check_header(path, &header)?;

    let mut vertices: Vec<Vec3> = Vec::new();
    let mut faces: Vec<Face> = Vec::new();
    let mut vertex_line = 0;
    let mut face_line = 0;
    for (name, def) in &header.elements {
        let at = Place {
            line: reader.line(),
            byte: reader.get_ref().position(),
        };
        let context = |e: ParseError| payload_error(path, bytes, &header, def, at, &e);
        match name.as_str() {
            "vertex" => {
                vertex_line = at.line;
                let raw = Parser::<Vertex>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(context)?;
                vertices = raw.into_iter().map(|v| Vec3::from_array(v.0)).collect();
            }
            "face" => {
                face_line = at.line;
                faces = Parser::<Face>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(context)?;
            }
            _ => {
                Parser::<Skip>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(context)?;
            }
        }
    }

    let ascii = header.encoding == Encoding::Ascii;
    // Where to point for record `i` of an element: its line, or its number.
    let locate = |first_line: usize, what: &str, i: usize, message: String| {
        if ascii {
            InputError::parse(path, (first_line + i) as u64, format!("{what} {message}"))
        } else {
            InputError::invalid(path, format!("{what} {} {message}", i + 1))
        }
    };
    for (i, v) in vertices.iter().enumerate() {
        if !v.is_finite() {
            return Err(locate(
                vertex_line,
                "vertex",
                i,
                format!(
                    "has a non-finite coordinate ({}, {}, {}); fix or remove the vertex",
                    v.x, v.y, v.z
                ),
            ));
        }
    }
    let n = vertices.len();
    if u32::try_from(n).is_err() {
        return Err(InputError::invalid(
            path,
            "more than 2^32 vertices: split the mesh",
        ));
    }
    let mut triangles = Vec::with_capacity(faces.len());
    for (i, face) in faces.iter().enumerate() {
        if face.0.len() < 3 {
            return Err(locate(
                face_line,
                "face",
                i,
                format!(
                    "has {} corners, fewer than 3; remove the face",
                    face.0.len()
                ),
            ));
        }
        let mut corners = Vec::with_capacity(face.0.len());
        for &k in &face.0 {
            match u32::try_from(k) {
                Ok(k) if (k as usize) < n => corners.push(k),
                _ => {
                    return Err(locate(
                        face_line,
                        "face",
                        i,
                        format!("refers to vertex {k}, but the file has vertices 0 to {}; fix the index", n.saturating_sub(1)),
                    ));
                }
            }
        }
        for w in corners[1..].windows(2) {
            triangles.push([corners[0], w[0], w[1]]);
        }
    }
    if triangles.is_empty() {
        return Err(InputError::invalid(
            path,
            format!("no triangles: the PLY has {n} vertices but no faces (a point cloud?); harmap needs a closed surface"),
        ));
    }
    Ok(TriMesh {
        vertices,
        triangles,
    })
}

/// Check that the header describes a surface this reader can use.
fn check_header(path: &Path, header: &Header) -> Result<(), InputError> {
    let Some(vertex) = header.elements.get("vertex") else {
        return Err(InputError::invalid(
            path,
            "the PLY header declares no 'vertex' element; export the mesh with its vertices",
        ));
    };
    for axis in ["x", "y", "z"] {
        match vertex.properties.get(axis).map(|p| &p.data_type) {
            Some(PropertyType::Scalar(_)) => {}
            Some(PropertyType::List(..)) => {
                return Err(InputError::invalid(
                    path,
                    format!("the PLY vertex property '{axis}' is a list, not a number; re-export the mesh"),
                ));
            }
            None => {
                return Err(InputError::invalid(
                    path,
                    format!("the PLY vertex element has no property '{axis}'; re-export the mesh with vertex positions"),
                ));
            }
        }
    }
    let Some(face) = header.elements.get("face") else {
        return Err(InputError::invalid(
            path,
            format!(
                "no triangles: the PLY header declares {} vertices but no 'face' element (a point cloud?); harmap needs a closed surface",
                vertex.count
            ),
        ));
    };
    let Some(list) = FACE_LISTS
        .iter()
        .find_map(|name| face.properties.get(*name))
    else {
        return Err(InputError::invalid(
            path,
            "the PLY face element has no list property 'vertex_indices' (or 'vertex_index'); re-export the mesh",
        ));
    };
    let integer = |t: &ScalarType| !matches!(t, ScalarType::Float | ScalarType::Double);
    match &list.data_type {
        PropertyType::List(count, item) if integer(count) && integer(item) => Ok(()),
        other => Err(InputError::invalid(
            path,
            format!("the PLY face property '{}' is {other:?}, not a list of integers; re-export the mesh", list.name),
        )),
    }
}

/// Where an element's data starts: the line (counting binary elements as lines, as the
/// library does) and the byte offset.
#[derive(Clone, Copy, Debug)]
struct Place {
    /// 1-based line of the first record.
    line: usize,
    /// Byte offset of the first record.
    byte: u64,
}

/// The library's message without its `Line N:` prefix, on one line.
fn message(e: &ParseError) -> String {
    let text = e.to_string();
    let text = match e.line() {
        Some(line) => text
            .strip_prefix(&format!("Line {line}: "))
            .unwrap_or(&text)
            .to_owned(),
        None => text,
    };
    text.replace("\n\t", "; ").replace('\n', " ")
}

/// Translate an error of the header reader.
fn header_error(path: &Path, bytes: &[u8], e: &ParseError) -> InputError {
    let Some(line) = e.line() else {
        return InputError::invalid(
            path,
            format!(
                "cannot read the PLY header: {}; repair the header or re-export the file",
                message(e)
            ),
        );
    };
    if e.kind() == std::io::ErrorKind::UnexpectedEof {
        return InputError::parse(
            path,
            line as u64,
            format!(
                "{}; the header is truncated or the file is not a PLY",
                message(e)
            ),
        );
    }
    // The library's grammar dump is unreadable; the line itself says more.
    let text = line_text(bytes, line);
    InputError::parse(
        path,
        line as u64,
        format!(
            "cannot read the PLY header line '{text}'; header lines are 'format ascii|binary_little_endian|binary_big_endian 1.0', 'element <name> <count>', 'property <type> <name>', 'property list <type> <type> <name>', 'comment ...' and 'end_header'"
        ),
    )
}

/// Line `line` (1-based) of `bytes`, trimmed, for quoting in messages.
fn line_text(bytes: &[u8], line: usize) -> String {
    bytes
        .split(|&b| b == b'\n')
        .nth(line.saturating_sub(1))
        .map(|raw| String::from_utf8_lossy(raw).trim().to_owned())
        .unwrap_or_default()
}

/// Byte size of one record of `def` if all its properties are scalars.
fn fixed_size(def: &ElementDef) -> Option<u64> {
    def.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => Some(match t {
                ScalarType::Char | ScalarType::UChar => 1,
                ScalarType::Short | ScalarType::UShort => 2,
                ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
                ScalarType::Double => 8,
            }),
            PropertyType::List(..) => None,
        })
        .sum()
}

/// Translate an error met while reading the records of `def`, which start at `at`.
fn payload_error(
    path: &Path,
    bytes: &[u8],
    header: &Header,
    def: &ElementDef,
    at: Place,
    e: &ParseError,
) -> InputError {
    let name = &def.name;
    let count = def.count;
    // The library counts one line per record, in binary files too.
    let index = e.line().map(|l| l.saturating_sub(at.line));
    let found = bytes.len() as u64;
    if header.encoding != Encoding::Ascii {
        let Some(i) = index else {
            return InputError::invalid(
                path,
                format!("cannot read the binary '{name}' elements: {}", message(e)),
            );
        };
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            let expected = fixed_size(def)
                .map(|size| {
                    format!(
                        " (the file needs at least {} bytes)",
                        at.byte.saturating_add(size.saturating_mul(count as u64))
                    )
                })
                .unwrap_or_default();
            return InputError::invalid(
                path,
                format!(
                    "truncated binary PLY: the header announces {count} '{name}' elements{expected} but the file has {found} bytes and ends inside element {}; re-export or re-download it",
                    i + 1
                ),
            );
        }
        return InputError::invalid(
            path,
            format!("cannot read '{name}' element {} of the binary PLY: {}; repair or re-export the file", i + 1, message(e)),
        );
    }
    let (Some(line), Some(i)) = (e.line(), index) else {
        return InputError::invalid(
            path,
            format!("cannot read the '{name}' elements: {}", message(e)),
        );
    };
    let text = line_text(bytes, line);
    let line = line as u64;
    if e.kind() == std::io::ErrorKind::UnexpectedEof || text.is_empty() {
        return InputError::parse(
            path,
            line,
            format!(
                "the file ends (or has a blank line) after {i} of the {count} '{name}' elements the header announces: it is truncated or the count is wrong; re-export it"
            ),
        );
    }
    InputError::parse(
        path,
        line,
        diagnose_ascii(def, &text).unwrap_or_else(|| {
            format!(
                "cannot read this '{name}' element: {}; repair the line or re-export the file",
                message(e)
            )
        }),
    )
}

/// Say what is wrong with an ASCII record, in terms of its values, when that is clear.
fn diagnose_ascii(def: &ElementDef, text: &str) -> Option<String> {
    let (what, fix) = match def.name.as_str() {
        "vertex" => ("vertex", "fix or remove the vertex"),
        "face" => ("face", "fix or remove the face"),
        _ => ("element", "fix the line"),
    };
    let integers_only = def.properties.values().all(|p| match &p.data_type {
        PropertyType::Scalar(t) | PropertyType::List(_, t) => {
            !matches!(t, ScalarType::Float | ScalarType::Double)
        }
    });
    let tokens: Vec<&str> = text.split_whitespace().collect();
    for &token in &tokens {
        match token.parse::<f64>() {
            Ok(x) if !x.is_finite() => {
                return Some(format!(
                    "{what} has a non-finite coordinate '{token}'; {fix}"
                ));
            }
            Ok(_) if !ply_number(token) => {
                return Some(format!(
                    "'{token}' is not written as the PLY reader expects ([-]digits[.digits][e[-]digits]): '{text}'; {fix}"
                ));
            }
            Ok(_) if integers_only && token.parse::<i64>().is_err() => {
                return Some(format!(
                    "'{token}' is not a whole number, but every property of the {what} is an integer: '{text}'; {fix}"
                ));
            }
            Ok(_) => {}
            Err(_) => return Some(format!("'{token}' is not a number: '{text}'; {fix}")),
        }
    }
    let scalars_only = def
        .properties
        .values()
        .all(|p| matches!(p.data_type, PropertyType::Scalar(_)));
    let declared = def.properties.len();
    if scalars_only && tokens.len() < declared {
        let names: Vec<&str> = def.properties.keys().map(String::as_str).collect();
        return Some(format!(
            "the {what} has {} values, but the header declares {declared} ({}): '{text}'; {fix}",
            tokens.len(),
            names.join(", ")
        ));
    }
    None
}

/// Whether `s` has the form `ply-rs-bw` accepts in ASCII data: `[+-]d+[.d+][(e|E)[+-]d+]`.
fn ply_number(s: &str) -> bool {
    fn digits(s: &str) -> (usize, &str) {
        let n = s.bytes().take_while(u8::is_ascii_digit).count();
        (n, &s[n..])
    }
    let s = s.strip_prefix(['+', '-']).unwrap_or(s);
    let (n, mut rest) = digits(s);
    if n == 0 {
        return false;
    }
    if let Some(r) = rest.strip_prefix('.') {
        let (n, r) = digits(r);
        if n == 0 {
            return false;
        }
        rest = r;
    }
    if let Some(r) = rest.strip_prefix(['e', 'E']) {
        let (n, r) = digits(r.strip_prefix(['+', '-']).unwrap_or(r));
        if n == 0 {
            return false;
        }
        rest = r;
    }
    rest.is_empty()
}

/// A vertex record: only the coordinates are kept.
#[derive(Debug, Default)]
struct Vertex([f64; 3]);

impl Vertex {
    /// Store `value` if `name` is a coordinate.
    fn set(&mut self, name: &str, value: f64) -> ply_rs_bw::ply::PropertyAccessResult {
        use ply_rs_bw::ply::PropertyAccessResult as R;
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return R::Ignored,
        };
        self.0[axis] = value;
        R::Set
    }
}

/// Coordinates may be stored as any scalar type; all become `f64`.
impl PropertyAccess for Vertex {
    fn new() -> Self {
        Self::default()
    }
    fn set_char(&mut self, name: &str, v: i8) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_uchar(&mut self, name: &str, v: u8) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_short(&mut self, name: &str, v: i16) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_ushort(&mut self, name: &str, v: u16) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_int(&mut self, name: &str, v: i32) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_uint(&mut self, name: &str, v: u32) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_float(&mut self, name: &str, v: f32) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, f64::from(v))
    }
    fn set_double(&mut self, name: &str, v: f64) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
}

/// A face record: only the corner list is kept, widened so negative indices survive to
/// be reported.
#[derive(Debug, Default)]
struct Face(Vec<i64>);

impl Face {
    /// Store `values` if `name` is the corner list.
    fn set<T: Into<i64>>(
        &mut self,
        name: &str,
        values: Vec<T>,
    ) -> ply_rs_bw::ply::PropertyAccessResult {
        if FACE_LISTS.contains(&name) {
            self.0 = values.into_iter().map(Into::into).collect();
            ply_rs_bw::ply::PropertyAccessResult::Set
        } else {
            ply_rs_bw::ply::PropertyAccessResult::Ignored
        }
    }
}

/// The corner list may use any integer type.
impl PropertyAccess for Face {
    fn new() -> Self {
        Self::default()
    }
    fn set_list_char(&mut self, name: &str, v: Vec<i8>) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
    fn set_list_uchar(&mut self, name: &str, v: Vec<u8>) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
    fn set_list_short(&mut self, name: &str, v: Vec<i16>) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
    fn set_list_ushort(&mut self, name: &str, v: Vec<u16>) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
    fn set_list_int(&mut self, name: &str, v: Vec<i32>) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
    fn set_list_uint(&mut self, name: &str, v: Vec<u32>) -> ply_rs_bw::ply::PropertyAccessResult {
        self.set(name, v)
    }
}

/// A record of an element this reader does not use: everything is dropped.
#[derive(Debug, Default)]
struct Skip;

/// Every setter keeps its default, which ignores the value.
impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
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
    const T: [[u32; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];

    fn ascii_tet() -> String {
        let mut s = String::from(
            "ply\nformat ascii 1.0\ncomment a tetrahedron\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n",
        );
        for [x, y, z] in P {
            writeln!(s, "{x} {y} {z} 0.5").unwrap();
        }
        for [a, b, c] in T {
            writeln!(s, "3 {a} {b} {c}").unwrap();
        }
        s
    }

    /// A binary tetrahedron; `big` picks the byte order. Coordinates are doubles, the
    /// list is `uchar uint`, and an extra `edge` element must be skipped.
    fn binary_tet(big: bool, points: [[f64; 3]; 4]) -> Vec<u8> {
        let order = if big {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut b = format!(
            "ply\nformat {order} 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\nelement edge 1\nproperty int a\nproperty int b\nelement face 4\nproperty list uchar uint vertex_index\nend_header\n"
        )
        .into_bytes();
        for p in points {
            for x in p {
                b.extend_from_slice(&if big {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                });
            }
            b.push(7);
        }
        for v in [0i32, 1] {
            b.extend_from_slice(&if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            });
        }
        for t in T {
            b.push(3);
            for i in t {
                b.extend_from_slice(&if big {
                    i.to_be_bytes()
                } else {
                    i.to_le_bytes()
                });
            }
        }
        b
    }

    fn points() -> [[f64; 3]; 4] {
        P.map(|p| p.map(f64::from))
    }

    fn check_tet(m: &TriMesh) {
        assert_eq!(m.vertices.len(), 4);
        assert_eq!(m.triangles.len(), 4);
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
        assert!((m.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
    }

    fn parse(bytes: &[u8]) -> Result<TriMesh, InputError> {
        read(Path::new("t.ply"), bytes)
    }

    fn error(bytes: &[u8]) -> String {
        parse(bytes)
            .expect_err("the input should be rejected")
            .to_string()
    }

    #[test]
    fn ascii_tetrahedron() {
        check_tet(&parse(ascii_tet().as_bytes()).unwrap());
        check_tet(&parse(ascii_tet().replace('\n', "\r\n").as_bytes()).unwrap());
    }

    #[test]
    fn binary_tetrahedra() {
        check_tet(&parse(&binary_tet(false, points())).unwrap());
        check_tet(&parse(&binary_tet(true, points())).unwrap());
    }

    #[test]
    fn integer_coordinates_and_polygons() {
        let text = "ply\nformat ascii 1.0\nelement vertex 5\nproperty short x\nproperty short y\nproperty short z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n2 1 0\n1 2 0\n0 1 0\n5 0 1 2 3 4\n";
        let m = parse(text.as_bytes()).unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
        assert_eq!(m.vertices[2], Vec3::new(2.0, 1.0, 0.0));
    }

    #[test]
    fn empty_and_not_ply() {
        assert!(error(b"").contains("empty file"));
        assert!(error(b"solid x\n").contains("not a PLY file"));
    }

    #[test]
    fn no_faces() {
        let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n";
        assert!(error(text.as_bytes()).contains("no triangles"));
        let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n";
        assert!(error(text.as_bytes()).contains("no triangles"));
    }

    #[test]
    fn header_problems() {
        let e = error(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n");
        assert!(e.contains("no property 'z'"), "{e}");
        let e = error(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty flaot x\nend_header\n");
        assert!(e.starts_with("t.ply:4: cannot read the PLY header"), "{e}");
        let e = error(b"ply\nformat ascii 1.0\nelement vertex 1\n");
        assert!(e.contains("end_header"), "{e}");
    }

    #[test]
    fn ascii_nan_and_text_name_the_line() {
        let text = ascii_tet();
        // Header is 11 lines; the third vertex is on line 14.
        let bad = text.replace("0 1 0 0.5", "0 nan 0 0.5");
        assert_eq!(
            error(bad.as_bytes()),
            "t.ply:14: vertex has a non-finite coordinate 'nan'; fix or remove the vertex"
        );
        let bad = text.replace("0 1 0 0.5", "0 abc 0 0.5");
        let e = error(bad.as_bytes());
        assert!(
            e.starts_with("t.ply:14:") && e.contains("'abc' is not a number"),
            "{e}"
        );
        // Overflows f32 to infinity: caught after parsing.
        let bad = text.replace("0 1 0 0.5", "0 1e39 0 0.5");
        let e = error(bad.as_bytes());
        assert!(
            e.starts_with("t.ply:14: vertex has a non-finite coordinate"),
            "{e}"
        );
    }

    #[test]
    fn ascii_short_record_and_fractional_index() {
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n";
        let e = error(text.as_bytes());
        assert!(
            e.starts_with("t.ply:11: the vertex has 2 values, but the header declares 3 (x, y, z)"),
            "{e}"
        );
        let text = text
            .replace("1 0\n", "1 0 0\n")
            .replace("3 0 1 2", "3 0 1.5 2");
        let e = error(text.as_bytes());
        assert!(
            e.starts_with("t.ply:13: '1.5' is not a whole number"),
            "{e}"
        );
    }

    #[test]
    fn ascii_face_index_out_of_range() {
        let bad = ascii_tet().replace("3 1 2 3\n", "3 1 2 9\n");
        let e = error(bad.as_bytes());
        assert!(e.starts_with("t.ply:19: face refers to vertex 9"), "{e}");
        let bad = ascii_tet().replace("3 1 2 3\n", "3 1 2 -1\n");
        assert!(error(bad.as_bytes()).starts_with("t.ply:19: face refers to vertex -1"));
        let bad = ascii_tet().replace("3 1 2 3\n", "2 1 2\n");
        assert!(error(bad.as_bytes()).starts_with("t.ply:19: face has 2 corners"));
    }

    #[test]
    fn ascii_truncated() {
        let text = ascii_tet();
        let cut = &text[..text.rfind("3 1 2 3").unwrap()];
        let e = error(cut.as_bytes());
        assert!(e.contains("after 3 of the 4 'face' elements"), "{e}");
    }

    #[test]
    fn binary_nan_names_the_vertex() {
        let mut p = points();
        p[2][0] = f64::NAN;
        let e = error(&binary_tet(false, p));
        assert!(
            e.starts_with("t.ply: vertex 3 has a non-finite coordinate"),
            "{e}"
        );
        p[2][0] = f64::NEG_INFINITY;
        assert!(error(&binary_tet(true, p)).contains("vertex 3 has a non-finite"));
    }

    #[test]
    fn binary_index_out_of_range() {
        let mut b = binary_tet(false, points());
        let n = b.len();
        b[n - 4..].copy_from_slice(&9u32.to_le_bytes());
        let e = error(&b);
        assert!(e.contains("face 4 refers to vertex 9"), "{e}");
    }

    #[test]
    fn binary_truncated() {
        let full = binary_tet(false, points());
        let header = full.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        // Inside the vertices: they have a fixed size, so the byte count is known.
        let e = error(&full[..header + 30]);
        assert!(
            e.contains("truncated binary PLY")
                && e.contains("4 'vertex' elements (the file needs at least")
                && e.contains("ends inside element 2"),
            "{e}"
        );
        // Inside the faces.
        for cut in [1, 5, 13] {
            let e = error(&full[..full.len() - cut]);
            assert!(
                e.contains("truncated binary PLY") && e.contains("'face'"),
                "{e}"
            );
        }
        // A huge announced count must not be trusted for allocation.
        let mut bytes = String::from_utf8_lossy(&full[..header])
            .replace("element face 4", "element face 4000000000")
            .into_bytes();
        bytes.extend_from_slice(&full[header..]);
        assert!(error(&bytes).contains("truncated binary PLY"));
    }

    #[test]
    fn ply_number_form() {
        for ok in ["1", "-1", "+1.5", "1.5e-3", "2E7"] {
            assert!(ply_number(ok), "{ok}");
        }
        for bad in [".5", "5.", "1e", "nan", "1.5f", ""] {
            assert!(!ply_number(bad), "{bad}");
        }
        let e = error(ascii_tet().replace("0 1 0 0.5", "0 .5 0 0.5").as_bytes());
        assert!(e.starts_with("t.ply:14: '.5' is not written"), "{e}");
    }

    #[test]
    fn real_horse() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes/horse.ply.gz");
        let Ok(bytes) = super::super::read_bytes(&path) else {
            return;
        };
        let m = read(&path, &bytes).unwrap();
        assert_eq!(m.triangles.len(), 96966);
        assert!(
            m.signed_volume() < 0.0,
            "the horse's faces are wound inward"
        );
    }
}
