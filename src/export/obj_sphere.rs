//! The boundary -> sphere map as an OBJ mesh.
// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

use glam::DVec3;

use super::{ExportError, Staged};
use crate::run::RunDir;
use crate::trace::read_seeds;

/// The first line of an OBJ sphere harmap wrote.
pub(super) const MARK: &str =
    "# harmap: boundary -> unit sphere map (vertices at their arrival directions)";

/// Write the boundary -> sphere map as an OBJ: the input surface's triangles with every
/// vertex on the unit sphere (at its arrival direction), and (psi, theta) as texture
/// coordinates u = (psi + pi) / 2 pi, v = 1 - theta / pi. Vertices whose streamline did
/// not reach the center sit at the origin (listed in a comment).
pub fn obj_sphere(run: &RunDir, dest: &Path) -> Result<u64, crate::Error> {
    let t = read_seeds(run)?;
    if t.vertex.is_empty() {
        return Err(ExportError::Unavailable(format!(
            "{}: the seeds are boundary voxels, which have no triangles; trace with --seeds surface for an OBJ sphere",
            run.root().display()
        ))
        .into());
    }
    let (mesh, _) = crate::trace::seeds::seed_surface(run)?;
    let mut sphere = vec![None; mesh.vertices.len()];
    for i in 0..t.vertex.len() {
        sphere[t.vertex[i] as usize] = t.sphere(i).map(|s| (s, t.theta[i], t.psi[i]));
    }
    let mut s = Staged::create(dest)?;
    let mut text = String::new();
    text += MARK;
    text.push('\n');
    let _ = writeln!(text, "# run: {}", run.root().display());
    let missing: Vec<usize> = (0..sphere.len()).filter(|&i| sphere[i].is_none()).collect();
    if !missing.is_empty() {
        let _ = writeln!(
            text,
            "# {} vertices did not reach the center (placed at the origin): {:?}",
            missing.len(),
            &missing[..missing.len().min(50)]
        );
    }
    for v in &sphere {
        let p = v.map_or(DVec3::ZERO, |x| x.0);
        let _ = writeln!(text, "v {} {} {}", p.x, p.y, p.z);
    }
    for v in &sphere {
        let (theta, psi) = v.map_or((0.0, 0.0), |x| (x.1, x.2));
        let _ = writeln!(
            text,
            "vt {} {}",
            (psi + std::f64::consts::PI) / std::f64::consts::TAU,
            1.0 - theta / std::f64::consts::PI
        );
    }
    for tri in &mesh.triangles {
        let [a, b, c] = tri.map(|i| i + 1);
        let _ = writeln!(text, "f {a}/{a} {b}/{b} {c}/{c}");
    }
    s.out.write_all(text.as_bytes()).map_err(|e| s.io(e))?;
    s.commit()?;
    Ok(mesh.triangles.len() as u64)
}
