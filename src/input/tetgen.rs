//! TetGen `.node`/`.ele` reader: the boundary of a tetrahedral mesh as a surface.
//!
//! No maintained crate reads TetGen files, and the format is a few whitespace-separated
//! columns, so it is parsed here. The voxelizer needs only the outside of the solid: the
//! faces used by exactly one tetrahedron, wound outward whatever the orientation of the
//! tetrahedra in the file.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::{extension, read_bytes_within, InputError, TriMesh};
use crate::math::Vec3;

/// Read a TetGen mesh given either its `.node` or `.ele` file (each possibly `.gz`).
pub(super) fn read(path: &Path, limit: u64) -> Result<TriMesh, InputError> {
    let (ext, _) = extension(path);
    let (node_path, ele_path) = if ext == "node" {
        (path.to_owned(), sibling(path, "ele")?)
    } else {
        (sibling(path, "node")?, path.to_owned())
    };
    let nodes = parse_node(&node_path, &read_bytes_within(&node_path, limit)?)?;
    let tets = parse_ele(&ele_path, &read_bytes_within(&ele_path, limit)?, &nodes)?;
    Ok(boundary(nodes.points, &tets))
}

/// The file next to `path` with the same stem and extension `ext`, plain or gzipped.
fn sibling(path: &Path, ext: &str) -> Result<PathBuf, InputError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = name
        .strip_suffix(".gz")
        .or_else(|| name.strip_suffix(".GZ"))
        .unwrap_or(&name);
    let stem = Path::new(name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let candidates: Vec<PathBuf> = [ext.to_owned(), ext.to_uppercase()]
        .iter()
        .flat_map(|e| [format!("{stem}.{e}"), format!("{stem}.{e}.gz")])
        .map(|n| path.with_file_name(n))
        .collect();
    candidates.iter().find(|c| c.is_file()).cloned().ok_or_else(|| {
        InputError::invalid(
            path,
            format!(
                "a TetGen mesh needs both its .node and .ele files, but neither {} nor {} exists; put them side by side with the same stem",
                candidates[0].display(),
                candidates[1].display()
            ),
        )
    })
}

/// The non-empty records of a TetGen file: `(1-based line, columns)`, with `#` comments
/// removed.
fn records<'a>(
    path: &'a Path,
    bytes: &'a [u8],
) -> impl Iterator<Item = Result<(u64, Vec<&'a str>), InputError>> + 'a {
    bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .filter_map(move |(i, raw)| {
            let line = i as u64 + 1;
            let Ok(text) = std::str::from_utf8(raw) else {
                return Some(Err(InputError::parse(
                    path,
                    line,
                    "the line is not UTF-8 text; is this really a TetGen file?",
                )));
            };
            let text = text.split('#').next().unwrap_or_default();
            let cols: Vec<&str> = text.split_whitespace().collect();
            (!cols.is_empty()).then_some(Ok((line, cols)))
        })
}

/// One column of a record as a number, or an error naming the line and the text.
fn column<T: std::str::FromStr>(
    path: &Path,
    line: u64,
    cols: &[&str],
    k: usize,
    what: &str,
) -> Result<T, InputError> {
    cols[k].parse().map_err(|_| {
        InputError::parse(
            path,
            line,
            format!(
                "{what} '{}' is not a valid number: '{}'; fix the line",
                cols[k],
                cols.join(" ")
            ),
        )
    })
}

/// Error for a record with fewer columns than the header implies.
fn too_few(path: &Path, line: u64, cols: &[&str], need: usize, layout: &str) -> InputError {
    InputError::parse(
        path,
        line,
        format!(
            "expected {need} columns ({layout}), found {}: '{}'; fix the line or the header",
            cols.len(),
            cols.join(" ")
        ),
    )
}

/// Points of a `.node` file and the number of their first index (0 or 1).
#[derive(Debug)]
struct Nodes {
    /// Positions, in file order.
    points: Vec<Vec3>,
    /// Index of the first point; the `.ele` file uses the same numbering.
    first: i64,
}

/// Parse a `.node` file: `<#points> <dim> <#attributes> <#markers>`, then
/// `<index> <x> <y> <z> [attributes] [marker]` per point.
#[allow(clippy::too_many_lines)] // the .node header, its attributes and rows in one pass with one error context
fn parse_node(path: &Path, bytes: &[u8]) -> Result<Nodes, InputError> {
    let mut recs = records(path, bytes);
    let Some(head) = recs.next() else {
        return Err(InputError::invalid(
            path,
            "empty file: a TetGen .node file starts with '<#points> 3 <#attributes> <0|1>'",
        ));
    };
    let (head_line, head) = head?;
    let count: usize = column(path, head_line, &head, 0, "point count")?;
    // TetGen itself takes missing header fields as 3, 0 and 0.
    let dim: u64 = if head.len() > 1 {
        column(path, head_line, &head, 1, "dimension")?
    } else {
        3
    };
    let attrs: usize = if head.len() > 2 {
        column(path, head_line, &head, 2, "attribute count")?
    } else {
        0
    };
    let markers: usize = if head.len() > 3 {
        column(path, head_line, &head, 3, "boundary marker flag")?
    } else {
        0
    };
    if dim != 3 {
        return Err(InputError::parse(
            path,
            head_line,
            format!("dimension is {dim}, but a tetrahedral mesh needs 3"),
        ));
    }
    if count == 0 {
        return Err(InputError::parse(
            path,
            head_line,
            "the header announces 0 points (TetGen then keeps them in a .poly or .smesh file, which harmap does not read); write the points into the .node file",
        ));
    }
    let need = 4 + attrs + markers.min(1);
    let mut points = Vec::with_capacity(count.min(bytes.len() / 8));
    let mut first = 0;
    for rec in recs {
        let (line, cols) = rec?;
        if points.len() == count {
            return Err(InputError::parse(
                path,
                line,
                format!("more points than the {count} the header (line {head_line}) announces; fix the count or remove the extra lines"),
            ));
        }
        if cols.len() < need {
            return Err(too_few(
                path,
                line,
                &cols,
                need,
                "index, x, y, z, attributes, marker",
            ));
        }
        let index: i64 = column(path, line, &cols, 0, "point index")?;
        if points.is_empty() {
            if index != 0 && index != 1 {
                return Err(InputError::parse(
                    path,
                    line,
                    format!("the first point has index {index}; TetGen numbers points from 0 or 1"),
                ));
            }
            first = index;
        }
        let expected = first + points.len() as i64;
        if index != expected {
            return Err(InputError::parse(
                path,
                line,
                format!("point index {index} is out of sequence (expected {expected}); TetGen numbers points consecutively"),
            ));
        }
        let mut p = [0.0_f64; 3];
        for (k, c) in p.iter_mut().enumerate() {
            *c = column(path, line, &cols, k + 1, "coordinate")?;
            if !c.is_finite() {
                return Err(InputError::parse(
                    path,
                    line,
                    format!(
                        "point has a non-finite coordinate '{}'; fix or remove the point",
                        cols[k + 1]
                    ),
                ));
            }
        }
        points.push(Vec3::from_array(p));
    }
    if points.len() < count {
        return Err(InputError::parse(
            path,
            head_line,
            format!("the header announces {count} points but the file holds only {}; it is truncated or the count is wrong", points.len()),
        ));
    }
    if u32::try_from(points.len()).is_err() {
        return Err(InputError::invalid(
            path,
            "more than 2^32 points: split the mesh",
        ));
    }
    Ok(Nodes { points, first })
}

/// Parse an `.ele` file: `<#tets> <4|10> <0|1>`, then `<index> <n1> ... [region]` per
/// tetrahedron; return the first four corners of each as 0-based point indices.
fn parse_ele(path: &Path, bytes: &[u8], nodes: &Nodes) -> Result<Vec<[u32; 4]>, InputError> {
    let mut recs = records(path, bytes);
    let Some(head) = recs.next() else {
        return Err(InputError::invalid(
            path,
            "empty file: a TetGen .ele file starts with '<#tetrahedra> <4|10> <0|1>'",
        ));
    };
    let (head_line, head) = head?;
    let count: usize = column(path, head_line, &head, 0, "tetrahedron count")?;
    let per: usize = if head.len() > 1 {
        column(path, head_line, &head, 1, "nodes per tetrahedron")?
    } else {
        4
    };
    let region: usize = if head.len() > 2 {
        column(path, head_line, &head, 2, "region attribute flag")?
    } else {
        0
    };
    if per != 4 && per != 10 {
        return Err(InputError::parse(
            path,
            head_line,
            format!("{per} nodes per tetrahedron; TetGen writes 4 (linear) or 10 (quadratic)"),
        ));
    }
    if count == 0 {
        return Err(InputError::parse(
            path,
            head_line,
            "no triangles: the header announces 0 tetrahedra; mesh the solid with tetgen first",
        ));
    }
    let need = 1 + per + region.min(1);
    let n = nodes.points.len() as i64;
    let mut tets = Vec::with_capacity(count.min(bytes.len() / 8));
    for rec in recs {
        let (line, cols) = rec?;
        if tets.len() == count {
            return Err(InputError::parse(
                path,
                line,
                format!("more tetrahedra than the {count} the header (line {head_line}) announces; fix the count or remove the extra lines"),
            ));
        }
        if cols.len() < need {
            return Err(too_few(path, line, &cols, need, "index, corners, region"));
        }
        let mut tet = [0; 4];
        for (k, t) in tet.iter_mut().enumerate() {
            let index: i64 = column(path, line, &cols, k + 1, "node index")?;
            let local = index - nodes.first;
            if !(0..n).contains(&local) {
                return Err(InputError::parse(
                    path,
                    line,
                    format!(
                        "tetrahedron refers to node {index}, but the .node file has nodes {} to {}; fix the index or use the matching .node file",
                        nodes.first,
                        nodes.first + n - 1
                    ),
                ));
            }
            *t = local as u32;
        }
        tets.push(tet);
    }
    if tets.len() < count {
        return Err(InputError::parse(
            path,
            head_line,
            format!("the header announces {count} tetrahedra but the file holds only {}; it is truncated or the count is wrong", tets.len()),
        ));
    }
    Ok(tets)
}

/// The faces used by exactly one tetrahedron, wound so their normals point out of the
/// solid. All points are kept, so indices need no remapping.
fn boundary(points: Vec<Vec3>, tets: &[[u32; 4]]) -> TriMesh {
    let oriented = |&[a, b, c, d]: &[u32; 4]| {
        let [pa, pb, pc, pd] = [a, b, c, d].map(|i| points[i as usize]);
        // A flat tetrahedron has no outside; its faces keep the file's order.
        if (pb - pa).dot((pc - pa).cross(pd - pa)) < 0.0 {
            [b, a, c, d]
        } else {
            [a, b, c, d]
        }
    };
    // The faces of a positively oriented (a, b, c, d), each seen from outside.
    let faces = |[a, b, c, d]: [u32; 4]| [[b, c, d], [a, d, c], [a, b, d], [a, c, b]];
    let key = |f: [u32; 3]| {
        let mut k = f;
        k.sort_unstable();
        k
    };
    let mut uses: HashMap<[u32; 3], u32> = HashMap::with_capacity(tets.len() * 2);
    for tet in tets {
        for f in faces(oriented(tet)) {
            *uses.entry(key(f)).or_insert(0) += 1;
        }
    }
    let mut triangles = Vec::new();
    for tet in tets {
        for f in faces(oriented(tet)) {
            if uses[&key(f)] == 1 {
                triangles.push(f);
            }
        }
    }
    TriMesh {
        vertices: points,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two tetrahedra sharing the face (1, 2, 3), the second listed with negative
    /// orientation; comments and blank lines in between.
    const NODE: &str = "# two tets\n5 3 0 1\n1 0 0 0 0\n2 1 0 0 0\n3 0 1 0 1  # on the boundary\n\n4 0 0 1 1\n5 1 1 1 0\n";
    const ELE: &str = "2 4 0\n1 1 2 3 4\n2 2 4 3 5\n# Generated by hand\n";

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    fn pair(node: &str, ele: &str) -> (tempfile::TempDir, PathBuf, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let n = write(dir.path(), "m.node", node);
        let e = write(dir.path(), "m.ele", ele);
        (dir, n, e)
    }

    fn error(node: &str, ele: &str) -> String {
        let (_dir, n, _) = pair(node, ele);
        read(&n, u64::MAX)
            .expect_err("the input should be rejected")
            .to_string()
    }

    #[test]
    fn single_tet_boundary_is_outward() {
        for ele in ["1 4 0\n1 1 2 3 4\n", "1 4 0\n1 2 1 3 4\n"] {
            let (_dir, n, _) = pair("4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", ele);
            let m = read(&n, u64::MAX).unwrap();
            assert_eq!(m.triangles.len(), 4);
            assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
            assert!(
                (m.signed_volume() - 1.0 / 6.0).abs() < 1e-12,
                "{}",
                m.signed_volume()
            );
        }
    }

    #[test]
    fn two_tets_share_an_interior_face() {
        let (_dir, n, e) = pair(NODE, ELE);
        for path in [&n, &e] {
            let m = read(path, u64::MAX).unwrap();
            assert_eq!(m.triangles.len(), 6);
            assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
            assert!(
                (m.signed_volume() - 0.5).abs() < 1e-12,
                "{}",
                m.signed_volume()
            );
        }
    }

    #[test]
    fn zero_based_quadratic_gzipped() {
        use std::io::Write;
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "q.1.node",
            "4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n",
        );
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        gz.write_all(b"1 10 1\n0 0 1 2 3 0 1 2 3 0 1 7\n").unwrap();
        std::fs::write(dir.path().join("q.1.ele.gz"), gz.finish().unwrap()).unwrap();
        let m = read(&dir.path().join("q.1.node"), u64::MAX).unwrap();
        assert_eq!(m.triangles.len(), 4);
        assert!(m.signed_volume() > 0.0);
        let m = read(&dir.path().join("q.1.ele.gz"), u64::MAX).unwrap();
        assert_eq!(m.triangles.len(), 4);
    }

    #[test]
    fn missing_sibling() {
        let dir = tempfile::tempdir().unwrap();
        let n = write(dir.path(), "alone.node", "1 3 0 0\n1 0 0 0\n");
        let e = read(&n, u64::MAX).unwrap_err().to_string();
        assert!(e.contains("alone.ele") && e.contains("alone.ele.gz"), "{e}");
    }

    #[test]
    fn wrong_counts() {
        let e = error(
            "6 3 0 1\n1 0 0 0 0\n2 1 0 0 0\n3 0 1 0 1\n4 0 0 1 1\n5 1 1 1 0\n",
            ELE,
        );
        assert!(e.ends_with("m.node:1: the header announces 6 points but the file holds only 5; it is truncated or the count is wrong"), "{e}");
        let e = error(NODE, "3 4 0\n1 1 2 3 4\n2 2 4 3 5\n");
        assert!(
            e.contains("m.ele:1: the header announces 3 tetrahedra but the file holds only 2"),
            "{e}"
        );
        let e = error(NODE, "1 4 0\n1 1 2 3 4\n2 2 4 3 5\n");
        assert!(e.contains("m.ele:3: more tetrahedra"), "{e}");
    }

    #[test]
    fn missing_node() {
        let e = error(NODE, "2 4 0\n1 1 2 3 4\n2 2 4 3 6\n");
        assert!(
            e.contains(
                "m.ele:3: tetrahedron refers to node 6, but the .node file has nodes 1 to 5"
            ),
            "{e}"
        );
        let e = error(NODE, "1 4 0\n1 0 2 3 4\n");
        assert!(e.contains("m.ele:2: tetrahedron refers to node 0"), "{e}");
    }

    #[test]
    fn too_few_columns() {
        let e = error(
            "4 3 0 1\n1 0 0 0 0\n2 1 0 0\n3 0 1 0 1\n4 0 0 1 1\n",
            "1 4 0\n1 1 2 3 4\n",
        );
        assert!(e.contains("m.node:3: expected 5 columns"), "{e}");
        let e = error(NODE, "1 4 1\n1 1 2 3 4\n");
        assert!(e.contains("m.ele:2: expected 6 columns"), "{e}");
    }

    #[test]
    fn bad_numbers() {
        let e = error(
            "4 3 0 0\n1 0 0 0\n2 1 nan 0\n3 0 1 0\n4 0 0 1\n",
            "1 4 0\n1 1 2 3 4\n",
        );
        assert!(
            e.contains("m.node:3: point has a non-finite coordinate 'nan'"),
            "{e}"
        );
        let e = error(
            "4 3 0 0\n1 0 0 0\n2 1 abc 0\n3 0 1 0\n4 0 0 1\n",
            "1 4 0\n1 1 2 3 4\n",
        );
        assert!(
            e.contains("m.node:3: coordinate 'abc' is not a valid number"),
            "{e}"
        );
        let e = error(NODE, "1 4 0\n1 1 2 x 4\n");
        assert!(e.contains("m.ele:2: node index 'x'"), "{e}");
        let e = error("4 3 0 0\n1 0 0 0\n3 1 0 0\n", "1 4 0\n1 1 2 3 4\n");
        assert!(
            e.contains("m.node:3: point index 3 is out of sequence"),
            "{e}"
        );
        let e = error("4 2 0 0\n", "1 4 0\n1 1 2 3 4\n");
        assert!(e.contains("m.node:1: dimension is 2"), "{e}");
    }

    #[test]
    fn empty_files() {
        assert!(error("", ELE).contains("empty file"));
        assert!(error("# only a comment\n\n", ELE).contains("empty file"));
        assert!(error(NODE, "").contains("m.ele: empty file"));
        assert!(error(NODE, "0 4 0\n").contains("no triangles"));
    }

    #[test]
    fn generated_by_tetgen_if_installed() {
        // Exercises real TetGen output when the tool is around; nothing is kept.
        let dir = tempfile::tempdir().unwrap();
        let poly = write(
            dir.path(),
            "cube.poly",
            "8 3 0 0\n1 0 0 0\n2 1 0 0\n3 1 1 0\n4 0 1 0\n5 0 0 1\n6 1 0 1\n7 1 1 1\n8 0 1 1\n6 0\n1\n4 1 2 3 4\n1\n4 5 6 7 8\n1\n4 1 2 6 5\n1\n4 2 3 7 6\n1\n4 3 4 8 7\n1\n4 4 1 5 8\n0\n0\n",
        );
        let Ok(status) = std::process::Command::new("tetgen")
            .arg("-pQ")
            .arg(&poly)
            .stdout(std::process::Stdio::null())
            .status()
        else {
            return;
        };
        assert!(status.success());
        let m = read(&dir.path().join("cube.1.ele"), u64::MAX).unwrap();
        assert!(m.topology().is_oriented_closed(), "{:?}", m.topology());
        assert!(
            (m.signed_volume() - 1.0).abs() < 1e-9,
            "{}",
            m.signed_volume()
        );
    }
}
