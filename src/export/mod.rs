//! Exports of a run's results for other tools: the seed table as CSV, the boundary ->
//! sphere map as an OBJ mesh, the streamlines as VTK legacy polydata, and the fields as
//! images ([`image`]: NIfTI-1, VTK image data, OpenDX, OME-Zarr).
//!
//! Every export is written to a temporary name next to the destination and renamed when
//! whole, so a killed export never leaves a truncated file under the real name.

pub mod image;

use std::fmt::Write as _;
use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use glam::DVec3;

use crate::progress::Progress;
use crate::run::RunDir;
use crate::trace::stage::{trace_seeds, Traced};
use crate::trace::{read_seeds, SeedKind, Stop, TraceOptions};

/// Errors of exports.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The run lacks what the format needs, or the options cannot work.
    #[error("{0}")]
    Unavailable(String),
    /// Writing failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// A file written under a temporary name and renamed into place by [`Staged::commit`].
pub(crate) struct Staged {
    tmp: PathBuf,
    dest: PathBuf,
    pub(crate) out: BufWriter<fs::File>,
}

impl Staged {
    pub(crate) fn create(dest: &Path) -> Result<Self, ExportError> {
        let name = dest
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = dest.with_file_name(format!(".{name}.partial-{}", std::process::id()));
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

    pub(crate) fn io(&self, e: std::io::Error) -> ExportError {
        ExportError::Io {
            path: self.dest.clone(),
            source: e,
        }
    }

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

/// Write the seed table as CSV: x, y, z (world), theta, psi (radians; empty where the
/// seed did not reach the center), phi, stop code and name, steps, length, and for
/// surface seeds the vertex index.
pub fn seeds_csv(run: &RunDir, dest: &Path) -> Result<u64, crate::Error> {
    let t = read_seeds(run)?;
    let mut s = Staged::create(dest)?;
    let surface = !t.vertex.is_empty();
    let w = |s: &mut Staged, text: &str| s.out.write_all(text.as_bytes()).map_err(|e| s.io(e));
    w(
        &mut s,
        if surface {
            "x,y,z,theta,psi,phi,stop,stop_name,steps,length,vertex\n"
        } else {
            "x,y,z,theta,psi,phi,stop,stop_name,steps,length\n"
        },
    )?;
    let num = |v: f64| {
        if v.is_finite() {
            format!("{v}")
        } else {
            String::new()
        }
    };
    for i in 0..t.position.len() {
        let p = t.position[i];
        let name = Stop::ALL
            .iter()
            .find(|s| **s as u8 == t.stop[i])
            .map_or("unknown", |s| s.name());
        let mut line = format!(
            "{},{},{},{},{},{},{},{},{},{}",
            p.x,
            p.y,
            p.z,
            num(t.theta[i]),
            num(t.psi[i]),
            num(t.phi[i]),
            t.stop[i],
            name,
            t.steps[i],
            num(t.length[i])
        );
        if surface {
            let _ = write!(line, ",{}", t.vertex[i]);
        }
        line.push('\n');
        w(&mut s, &line)?;
    }
    s.commit()?;
    Ok(t.position.len() as u64)
}

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
    text += "# harmap: boundary -> unit sphere map (vertices at their arrival directions)\n";
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

/// Trace the run's seeds again (with the options of its trace, or `sample` of them)
/// recording every point, and write the streamlines as VTK legacy polydata (binary):
/// one polyline per seed, with the cell data seed, stop, theta and psi and the point
/// data arc length. ParaView and VTK read it.
pub fn vtk_streamlines(
    run: &RunDir,
    dest: &Path,
    sample: Option<u64>,
    mem: crate::grid::MemBudget,
    progress: &dyn Progress,
) -> Result<u64, crate::Error> {
    let attrs = run.attrs()?;
    let mut opts: TraceOptions = attrs
        .pointer("/stages/trace/options")
        .and_then(|o| serde_json::from_value(o.clone()).ok())
        .unwrap_or_default();
    if attrs.pointer("/stages/trace/options").is_none() {
        opts.seeds = SeedKind::Boundary;
    }
    if sample.is_some() {
        opts.sample = sample;
    }
    opts.mem = mem;
    let tr: Traced = trace_seeds(run, &opts, true, progress)?;
    let spec = run.grid()?;
    let world = |p: DVec3| DVec3::from_array(spec.origin) + spec.spacing * p;
    let paths = tr.paths.as_ref().expect("asked for paths");
    let n_points: usize = paths.iter().map(Vec::len).sum();
    let mut s = Staged::create(dest)?;
    let mut bytes: Vec<u8> = Vec::with_capacity(n_points * 12 + 1024);
    bytes.extend_from_slice(b"# vtk DataFile Version 3.0\n");
    bytes.extend_from_slice(b"harmap streamlines (world coordinates)\nBINARY\nDATASET POLYDATA\n");
    bytes.extend_from_slice(format!("POINTS {n_points} float\n").as_bytes());
    for path in paths {
        for &p in path {
            for c in world(p).to_array() {
                bytes.extend_from_slice(&(c as f32).to_be_bytes());
            }
        }
    }
    bytes.extend_from_slice(
        format!("\nLINES {} {}\n", paths.len(), paths.len() + n_points).as_bytes(),
    );
    let mut k = 0i32;
    for path in paths {
        bytes.extend_from_slice(&(path.len() as i32).to_be_bytes());
        for _ in path {
            bytes.extend_from_slice(&k.to_be_bytes());
            k += 1;
        }
    }
    bytes.extend_from_slice(format!("\nCELL_DATA {}\n", paths.len()).as_bytes());
    bytes.extend_from_slice(b"SCALARS seed int 1\nLOOKUP_TABLE default\n");
    for i in 0..paths.len() {
        bytes.extend_from_slice(&(i as i32).to_be_bytes());
    }
    bytes.extend_from_slice(b"\nSCALARS stop int 1\nLOOKUP_TABLE default\n");
    for o in &tr.outcomes {
        bytes.extend_from_slice(&i32::from(o.stop as u8).to_be_bytes());
    }
    let c = tr.ball.center;
    let angles: Vec<(f64, f64)> = tr
        .outcomes
        .iter()
        .map(|o| {
            if o.stop == Stop::Reached {
                crate::trace::angles(o.end - c)
            } else {
                (f64::NAN, f64::NAN)
            }
        })
        .collect();
    for (name, pick) in [("theta", 0usize), ("psi", 1)] {
        bytes.extend_from_slice(
            format!("\nSCALARS {name} float 1\nLOOKUP_TABLE default\n").as_bytes(),
        );
        for a in &angles {
            let v = if pick == 0 { a.0 } else { a.1 };
            bytes.extend_from_slice(&(v as f32).to_be_bytes());
        }
    }
    bytes.extend_from_slice(format!("\nPOINT_DATA {n_points}\n").as_bytes());
    bytes.extend_from_slice(b"SCALARS arc_length float 1\nLOOKUP_TABLE default\n");
    for path in paths {
        let mut len = 0.0;
        let mut prev = path.first().copied().unwrap_or(DVec3::ZERO);
        for &p in path {
            len += (p - prev).length() * spec.spacing;
            prev = p;
            bytes.extend_from_slice(&(len as f32).to_be_bytes());
        }
    }
    bytes.push(b'\n');
    s.out.write_all(&bytes).map_err(|e| s.io(e))?;
    s.commit()?;
    Ok(paths.len() as u64)
}
