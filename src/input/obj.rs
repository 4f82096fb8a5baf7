//! OBJ reader: a line-numbered scan validates every record, then `tobj` builds the mesh.
//!
//! `tobj` reports errors without a line number, turns polylines (`l a b c`) into
//! triangles, and on some out-of-range texture or normal indices overflows an index
//! computation (a panic in builds with overflow checks). So every record `tobj` acts on
//! is checked here first with `tobj`'s own rules, and polylines are hidden from it: what
//! reaches `tobj` is known to be well formed, and any error names its line.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;

use super::{InputError, TriMesh};
use crate::math::Vec3;

/// Parse an OBJ file already read into memory (decompressed).
///
/// Polygons are fan-triangulated by `tobj`; texture and normal indices are ignored, so
/// texture seams do not split vertices. Groups, objects and materials are merged into one
/// surface.
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<TriMesh, InputError> {
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(InputError::invalid(
            path,
            "empty file: it holds no vertices and no faces; check that the export succeeded",
        ));
    }
    let scan = scan(path, bytes)?;
    if scan.faces == 0 {
        return Err(InputError::invalid(
            path,
            format!(
                "no triangles: the file has {} but no faces ('f' records); export the surface with its faces, not a point cloud",
                if scan.vertices == 1 { "1 vertex".to_owned() } else { format!("{} vertices", scan.vertices) }
            ),
        ));
    }
    // Hiding a polyline turns its keyword into `#`, which keeps every line number.
    let text: Cow<'_, [u8]> = if scan.polylines.is_empty() {
        Cow::Borrowed(bytes)
    } else {
        let mut copy = bytes.to_vec();
        for &at in &scan.polylines {
            copy[at] = b'#';
        }
        Cow::Owned(copy)
    };
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    // Materials are ignored; `collect` builds whichever map type tobj was built with.
    let (models, _materials) = tobj::load_obj_buf(&mut &text[..], &options, |_| {
        Ok((Vec::new(), std::iter::empty().collect()))
    })
    .map_err(|e| tobj_error(path, e, &scan))?;
    merge_models(path, &models)
}

/// Concatenate `tobj`'s models into one mesh.
///
/// `tobj` gives each object, group or material its own copy of the positions it uses, so
/// a vertex shared by two groups arrives twice; positions of different models with
/// bit-identical coordinates are reunited, or the seams between groups would be open.
/// Within one model vertices stay as the file has them.
fn merge_models(path: &Path, models: &[tobj::Model]) -> Result<TriMesh, InputError> {
    let mut mesh = TriMesh::default();
    let mut first_owner: HashMap<[u64; 3], (u32, usize)> = HashMap::new();
    let weld = models.len() > 1;
    for (k, model) in models.iter().enumerate() {
        let m = &model.mesh;
        let mut local = Vec::with_capacity(m.positions.len() / 3);
        for p in m.positions.chunks_exact(3) {
            // `+ 0.0` turns -0.0 into 0.0 so the two zeros weld.
            let v = Vec3::new(p[0] + 0.0, p[1] + 0.0, p[2] + 0.0);
            let key = v.to_array().map(f64::to_bits);
            let reuse = if weld {
                first_owner
                    .get(&key)
                    .filter(|&&(_, owner)| owner != k)
                    .map(|&(g, _)| g)
            } else {
                None
            };
            if let Some(g) = reuse {
                local.push(g);
                continue;
            }
            let g = u32::try_from(mesh.vertices.len()).map_err(|_| {
                InputError::invalid(path, "more than 2^32 vertices: split the mesh")
            })?;
            mesh.vertices.push(v);
            if weld {
                first_owner.entry(key).or_insert((g, k));
            }
            local.push(g);
        }
        for t in m.indices.chunks_exact(3) {
            let corner = |i: u32| {
                local.get(i as usize).copied().ok_or_else(|| {
                    InputError::invalid(
                        path,
                        format!("internal: the OBJ reader (tobj) returned index {i} past its {} positions", local.len()),
                    )
                })
            };
            mesh.triangles
                .push([corner(t[0])?, corner(t[1])?, corner(t[2])?]);
        }
    }
    Ok(mesh)
}

/// What the validating scan learned about the file.
#[derive(Debug, Default)]
struct Scan {
    /// Number of `v` records.
    vertices: usize,
    /// Number of `f` records (each with at least three corners).
    faces: usize,
    /// Byte offsets of the `l` keywords to hide from `tobj`.
    polylines: Vec<usize>,
    /// First face corner that refers to a record defined further down: `tobj` accepts
    /// these only within one object, so this is the line to name if it refuses.
    first_forward: Option<(u64, String)>,
    /// First `v` record whose color presence differs from the first `v` record's.
    color_mismatch: Option<u64>,
}

/// Counts of `v`, `vt` and `vn` records.
#[derive(Clone, Copy, Debug, Default)]
struct Counts {
    v: usize,
    vt: usize,
    vn: usize,
}

/// The lines of `bytes` as `(1-based number, byte offset, text)`, split on `\n` as
/// `tobj` (`BufRead::lines`) does, so that line numbers agree.
fn lines(bytes: &[u8]) -> impl Iterator<Item = (u64, usize, &[u8])> {
    let mut offset = 0;
    bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .map(move |(i, raw)| {
            let at = offset;
            offset += raw.len() + 1;
            (i as u64 + 1, at, raw)
        })
}

/// The text of a line without its `\r`, or an error naming it if it is not UTF-8.
fn line_text<'a>(path: &Path, line: u64, raw: &'a [u8]) -> Result<&'a str, InputError> {
    let text = std::str::from_utf8(raw).map_err(|_| {
        InputError::parse(
            path,
            line,
            "the line is not UTF-8 text; is this really an OBJ file (not a binary format renamed)?",
        )
    })?;
    Ok(text.strip_suffix('\r').unwrap_or(text))
}

/// Validate every record with the rules `tobj` applies, naming the line of the first
/// problem; count vertices and faces and find polylines.
fn scan(path: &Path, bytes: &[u8]) -> Result<Scan, InputError> {
    // Positive indices may point forward, so the totals are needed before the faces.
    let mut total = Counts::default();
    for (n, _, raw) in lines(bytes) {
        match line_text(path, n, raw)?.split_whitespace().next() {
            Some("v") => total.v += 1,
            Some("vt") => total.vt += 1,
            Some("vn") => total.vn += 1,
            _ => {}
        }
    }
    let mut scan = Scan::default();
    let mut seen = Counts::default();
    let mut first_colored: Option<bool> = None;
    for (n, at, raw) in lines(bytes) {
        let line = line_text(path, n, raw)?;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let colored = check_vertex(path, n, line, words)?;
                match first_colored {
                    None => first_colored = Some(colored),
                    Some(c) if c != colored && scan.color_mismatch.is_none() => {
                        scan.color_mismatch = Some(n);
                    }
                    Some(_) => {}
                }
                seen.v += 1;
            }
            Some("vt") => {
                check_floats(path, n, line, words, 2, "texture coordinate")?;
                seen.vt += 1;
            }
            Some("vn") => {
                check_floats(path, n, line, words, 3, "normal")?;
                seen.vn += 1;
            }
            Some("f") => {
                check_face(path, n, line, words, seen, total, &mut scan)?;
                scan.faces += 1;
            }
            Some("l") => {
                let keyword = raw.iter().position(|&b| b == b'l').unwrap_or(0);
                scan.polylines.push(at + keyword);
            }
            // tobj's own test: the name follows the first space.
            Some("usemtl") if line.split_once(' ').unwrap_or_default().1.trim().is_empty() => {
                return Err(InputError::parse(
                    path,
                    n,
                    format!("'usemtl' without a material name: '{line}'; add the name after one space or delete the line"),
                ));
            }
            _ => {}
        }
    }
    scan.vertices = total.v;
    Ok(scan)
}

/// Check a `v` record (`x y z`, `x y z w` or `x y z r g b`, as `tobj` reads it); return
/// whether it carries a color.
fn check_vertex<'a>(
    path: &Path,
    n: u64,
    line: &str,
    words: impl Iterator<Item = &'a str>,
) -> Result<bool, InputError> {
    let words: Vec<&str> = words.collect();
    if words.len() < 3 {
        return Err(InputError::parse(
            path,
            n,
            format!(
                "a vertex needs 3 coordinates, found {}: '{line}'; complete or remove the vertex",
                words.len()
            ),
        ));
    }
    let mut xyz = [0.0; 3];
    for (c, w) in xyz.iter_mut().zip(&words) {
        *c = w.parse::<f64>().map_err(|_| {
            InputError::parse(
                path,
                n,
                format!(
                    "vertex coordinate '{w}' is not a number: '{line}'; fix or remove the vertex"
                ),
            )
        })?;
        if !c.is_finite() {
            return Err(InputError::parse(
                path,
                n,
                format!("vertex has a non-finite coordinate '{w}'; fix or remove the vertex"),
            ));
        }
    }
    match words.len() {
        3 => Ok(false),
        4 => {
            let w = words[3];
            let weight = w.parse::<f64>().map_err(|_| {
                InputError::parse(
                    path,
                    n,
                    format!("vertex weight w '{w}' is not a number: '{line}'; fix the vertex (OBJ comments must be on lines of their own)"),
                )
            })?;
            if weight == 0.0 || !weight.is_finite() {
                return Err(InputError::parse(
                    path,
                    n,
                    format!("vertex weight w is '{w}', which cannot divide the coordinates; use w = 1 or drop it"),
                ));
            }
            if xyz.iter().any(|c| !(c / weight).is_finite()) {
                return Err(InputError::parse(
                    path,
                    n,
                    format!("vertex has a non-finite coordinate after dividing by w = '{w}'; fix or remove the vertex"),
                ));
            }
            Ok(false)
        }
        6 => Ok(words[3..].iter().all(|w| w.parse::<f64>().is_ok())),
        k => Err(InputError::parse(
            path,
            n,
            format!("a vertex has {k} values: '{line}'; the OBJ reader takes 'v x y z', 'v x y z w' or 'v x y z r g b' (and comments only on lines of their own)"),
        )),
    }
}

/// Check that a `vt` or `vn` record starts with `count` numbers, as `tobj` requires.
fn check_floats<'a>(
    path: &Path,
    n: u64,
    line: &str,
    words: impl Iterator<Item = &'a str>,
    count: usize,
    what: &str,
) -> Result<(), InputError> {
    let mut found = 0;
    for w in words.take(count) {
        if w.parse::<f64>().is_err() {
            return Err(InputError::parse(
                path,
                n,
                format!("{what} component '{w}' is not a number: '{line}'; fix or delete the line"),
            ));
        }
        found += 1;
    }
    if found < count {
        return Err(InputError::parse(
            path,
            n,
            format!(
                "a {what} needs {count} numbers, found {found}: '{line}'; fix or delete the line"
            ),
        ));
    }
    Ok(())
}

/// Check an `f` record: at least three corners, each `v`, `v/vt`, `v//vn` or `v/vt/vn`,
/// with every index `tobj` would use in range. Relative (negative) indices count back
/// from the records above the line, as in `tobj`.
fn check_face<'a>(
    path: &Path,
    n: u64,
    line: &str,
    words: impl Iterator<Item = &'a str>,
    seen: Counts,
    total: Counts,
    scan: &mut Scan,
) -> Result<(), InputError> {
    const KINDS: [&str; 3] = ["vertex", "texture coordinate", "normal"];
    let err = |msg: String| InputError::parse(path, n, msg);
    let mut corners = 0;
    for word in words {
        corners += 1;
        for (k, part) in word.split('/').enumerate() {
            if k >= 3 {
                return Err(err(format!(
                    "face corner '{word}' has more than three '/'-separated indices: '{line}'; use v, v/vt, v//vn or v/vt/vn"
                )));
            }
            if part.is_empty() {
                if k == 0 {
                    return Err(err(format!(
                        "face corner '{word}' has no vertex index: '{line}'; use v, v/vt, v//vn or v/vt/vn"
                    )));
                }
                continue;
            }
            let Ok(x) = part.parse::<isize>() else {
                let hint = if word.starts_with('#') {
                    "OBJ comments must be on lines of their own"
                } else {
                    "indices are whole numbers"
                };
                return Err(err(format!(
                    "'{part}' in face corner '{word}' is not an index: '{line}'; {hint}"
                )));
            };
            let (so_far, all) = [(seen.v, total.v), (seen.vt, total.vt), (seen.vn, total.vn)][k];
            // tobj ignores texture and normal indices when the file has none of them,
            // and takes index 0 of those as "missing".
            if k > 0 && (all == 0 || x == 0) {
                continue;
            }
            let kind = KINDS[k];
            if x == 0 {
                return Err(err(format!(
                    "face corner '{word}' uses index 0, but OBJ indices start at 1 (negative ones count back from the last vertex): '{line}'"
                )));
            }
            if x < 0 {
                if x.unsigned_abs() > so_far {
                    return Err(err(format!(
                        "face corner '{word}' counts back {} {kind} records, but only {so_far} are defined above this line; fix the index",
                        x.unsigned_abs()
                    )));
                }
            } else if x.unsigned_abs() > all {
                return Err(err(format!(
                    "face refers to {kind} {x}, but the file defines only {all}: '{line}'; fix the index or add the missing records"
                )));
            } else if x.unsigned_abs() > so_far && scan.first_forward.is_none() {
                scan.first_forward = Some((n, format!("{kind} {x}")));
            }
        }
    }
    if corners < 3 {
        return Err(err(format!(
            "a face needs at least 3 corners, found {corners}: '{line}'; delete the line or complete the face"
        )));
    }
    Ok(())
}

/// Turn an error of `tobj` (on a file the scan accepted) into a message naming the line
/// where the scan saw its likely cause.
fn tobj_error(path: &Path, e: tobj::LoadError, scan: &Scan) -> InputError {
    use tobj::LoadError as E;
    match (e, &scan.first_forward, scan.color_mismatch) {
        (E::FaceVertexOutOfBounds | E::FaceTexCoordOutOfBounds | E::FaceNormalOutOfBounds, Some((line, what)), _) => {
            InputError::parse(
                path,
                *line,
                format!("face refers to {what}, which is defined further down the file after an 'o', 'g' or 'usemtl' line; move the records above the faces that use them"),
            )
        }
        (E::FaceColorOutOfBounds, _, Some(line)) => InputError::parse(
            path,
            line,
            "some vertices carry colors ('v x y z r g b') and others do not, which the OBJ reader (tobj) cannot index; remove the colors from all vertices",
        ),
        _ => InputError::invalid(
            path,
            format!("the OBJ reader (tobj) rejected the file: {e}; re-export it as a plain OBJ with 'v' and 'f' records"),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<TriMesh, InputError> {
        read(Path::new("t.obj"), text.as_bytes())
    }

    fn error(text: &str) -> String {
        parse(text)
            .expect_err("the input should be rejected")
            .to_string()
    }

    const TET: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";

    const CUBE_V: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n";

    const CUBE_F: [&str; 6] = [
        "f 1 4 3 2\n",
        "f 5 6 7 8\n",
        "f 1 2 6 5\n",
        "f 2 3 7 6\n",
        "f 3 4 8 7\n",
        "f 4 1 5 8\n",
    ];

    #[test]
    fn tetrahedron() {
        let m = parse(TET).unwrap();
        assert_eq!(m.vertices.len(), 4);
        assert_eq!(m.triangles.len(), 4);
        assert!(m.topology().is_oriented_closed());
        assert!((m.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn quads_are_triangulated() {
        let text = format!("{CUBE_V}{}", CUBE_F.concat());
        let m = parse(&text).unwrap();
        assert_eq!(m.vertices.len(), 8);
        assert_eq!(m.triangles.len(), 12);
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
        assert!((m.signed_volume() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn pentagon_is_fan_triangulated() {
        let text = "v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 1 0\nf 1 2 3 4 5\n";
        assert_eq!(parse(text).unwrap().triangles.len(), 3);
    }

    #[test]
    fn texture_seams_do_not_split_vertices() {
        // Every corner gets its own texture coordinate, as at a seam.
        let mut text = String::from(TET);
        text = text.replace("f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n", "");
        for _ in 0..12 {
            text.push_str("vt 0.5 0.5\n");
        }
        text.push_str("vn 0 0 1\n");
        text.push_str("f 1/1/1 3/2/1 2/3/1\nf 1/4 2/5 4/6\nf 1//1 4//1 3//1\nf 2/10 3/11 4/12\n");
        let m = parse(&text).unwrap();
        assert_eq!(m.vertices.len(), 4);
        assert!(m.topology().is_oriented_closed());
    }

    #[test]
    fn relative_indices() {
        let text =
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf -4 -2 -3\nf -4 -3 -1\nf -4 -1 -2\nf -3 -2 -1\n";
        let m = parse(text).unwrap();
        assert_eq!(m, parse(TET).unwrap());
    }

    #[test]
    fn groups_are_merged_and_welded() {
        let mut text = format!("{CUBE_V}o top\n");
        for f in &CUBE_F[..3] {
            text.push_str(f);
        }
        text.push_str("g other\nusemtl steel\n");
        for f in &CUBE_F[3..] {
            text.push_str(f);
        }
        let m = parse(&text).unwrap();
        assert_eq!(m.triangles.len(), 12);
        assert_eq!(m.vertices.len(), 8);
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
    }

    #[test]
    fn polylines_points_and_materials_are_ignored() {
        let text = format!("mtllib missing.mtl\n{TET}l 1 2 3 4\nl 1 2\np 1\n");
        let m = parse(&text).unwrap();
        assert_eq!(m.triangles.len(), 4);
    }

    #[test]
    fn crlf_and_comments() {
        let text = format!("# a comment\r\n\r\n{}", TET.replace('\n', "\r\n"));
        assert_eq!(parse(&text).unwrap().triangles.len(), 4);
    }

    #[test]
    fn weight_divides() {
        let m = parse("v 0 0 0 2\nv 2 0 0 2\nv 0 2 0 2\nf 1 2 3\n").unwrap();
        assert_eq!(m.vertices[1], Vec3::new(1.0, 0.0, 0.0));
    }

    #[test]
    fn empty_file() {
        assert!(error("").contains("empty file"));
        assert!(error("  \n\n").contains("empty file"));
    }

    #[test]
    fn no_faces() {
        let e = error("v 0 0 0\nv 1 0 0\n# nothing else\n");
        assert!(
            e.contains("no triangles") && e.contains("2 vertices"),
            "{e}"
        );
    }

    #[test]
    fn nan_vertex_names_the_line() {
        let e = error("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
        assert_eq!(
            e,
            "t.obj:3: vertex has a non-finite coordinate 'nan'; fix or remove the vertex"
        );
        let e = error("v 0 0 0\nv 1 inf 0\nv 0 1 0\nf 1 2 3\n");
        assert!(e.starts_with("t.obj:2:") && e.contains("'inf'"), "{e}");
    }

    #[test]
    fn text_in_number_column() {
        let e = error("v 0 0 0\nv 1.0 abc 2.0\nv 0 1 0\nf 1 2 3\n");
        assert!(
            e.starts_with("t.obj:2:") && e.contains("'abc' is not a number"),
            "{e}"
        );
    }

    #[test]
    fn index_out_of_range_names_the_line() {
        let e = error("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 7\n");
        assert!(
            e.starts_with("t.obj:5:") && e.contains("vertex 7") && e.contains("only 3"),
            "{e}"
        );
        let e = error("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
        assert!(e.starts_with("t.obj:4:") && e.contains("index 0"), "{e}");
        let e = error("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n");
        assert!(
            e.starts_with("t.obj:3:") && e.contains("counts back 3"),
            "{e}"
        );
        let e = error("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x3\n");
        assert!(e.starts_with("t.obj:4:") && e.contains("'x3'"), "{e}");
    }

    #[test]
    fn bad_texture_indices_do_not_overflow_tobj() {
        let base = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n";
        for f in [
            "f 1/-100 2/1 3/1\n",
            "f 1/4611686018427387904 2/1 3/1\n",
            "f 1//-9 2//1 3//1\n",
            "f 1//9223372036854775807 2//1 3//1\n",
        ] {
            let e = error(&format!("{base}{f}"));
            assert!(e.starts_with("t.obj:6:"), "{f}: {e}");
        }
        // Texture indices with no texture coordinates at all are ignored, as tobj does.
        assert!(parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/7 2/7 3/7\n").is_ok());
    }

    #[test]
    fn forward_reference_across_objects_names_the_line() {
        // Within one object tobj resolves forward references...
        assert!(parse("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").is_ok());
        // ...but not once the object is closed before the vertex appears.
        let e = error("v 0 0 0\nv 1 0 0\nf 1 2 3\no next\nv 0 1 0\nf 1 2 3\n");
        assert!(
            e.starts_with("t.obj:3:") && e.contains("further down"),
            "{e}"
        );
    }

    #[test]
    fn malformed_records() {
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        let cases = [
            ("f 1 2\n", "at least 3 corners"),
            (
                "f 1 2 3 # trailing comment\n",
                "comments must be on lines of their own",
            ),
            ("f 1/1/1/1 2 3\n", "more than three"),
            ("f /1 2 3\n", "no vertex index"),
            ("vt 0.5\nf 1 2 3\n", "needs 2 numbers"),
            ("vn 0 0 x\nf 1 2 3\n", "'x' is not a number"),
            ("v 1 2 3 0\nf 1 2 3\n", "cannot divide"),
            ("v 1 2 3 4 5\nf 1 2 3\n", "5 values"),
            ("v 1 2\nf 1 2 3\n", "3 coordinates"),
            ("usemtl\nf 1 2 3\n", "material name"),
        ];
        for (tail, want) in cases {
            let e = error(&format!("{tri}{tail}"));
            assert!(
                e.starts_with("t.obj:4:") && e.contains(want),
                "{tail:?}: {e}"
            );
        }
    }

    #[test]
    fn not_utf8() {
        let mut bytes = b"v 0 0 0\nv 1 0 0\n".to_vec();
        bytes.extend_from_slice(&[0xff, 0xfe, b'\n']);
        let e = read(Path::new("t.obj"), &bytes).unwrap_err().to_string();
        assert!(e.starts_with("t.obj:3:") && e.contains("UTF-8"), "{e}");
    }

    #[test]
    fn mixed_vertex_colors() {
        let text = "v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 0 1 0\nf 1 2 3\n";
        match parse(text) {
            Ok(m) => assert_eq!(m.triangles.len(), 1),
            Err(e) => assert!(e.to_string().starts_with("t.obj:3:"), "{e}"),
        }
    }

    fn real(name: &str) -> Option<TriMesh> {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/meshes")
            .join(name);
        let bytes = super::super::read_bytes(&path).ok()?;
        Some(read(&path, &bytes).unwrap())
    }

    #[test]
    fn real_spot() {
        let Some(m) = real("spot.obj") else { return };
        assert_eq!(m.triangles.len(), 5856);
        assert!(m.vertices.len() <= 2930);
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
        assert!(m.signed_volume() > 0.0);
    }

    #[test]
    fn real_cubespikes_quads() {
        let Some(m) = real("cubespikes.obj") else {
            return;
        };
        assert_eq!(m.triangles.len(), 2384);
    }
}
