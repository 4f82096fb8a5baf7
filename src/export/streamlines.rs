//! Streamlines as VTK legacy polydata (binary), traced again.

use std::io::Write;
use std::path::Path;

use glam::DVec3;

use super::Staged;
use crate::progress::Progress;
use crate::run::RunDir;
use crate::trace::stage::{trace_seeds, Traced};
use crate::trace::{SeedKind, Stop, TraceOptions};

/// The title line (the second) of streamlines harmap wrote.
pub(super) const TITLE: &str = "harmap streamlines (world coordinates)";

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
    // The trace's options, or boundary seeds for a run not traced.
    let mut opts: TraceOptions = crate::run::options_in(&attrs, "trace")
        .unwrap_or_else(|| TraceOptions::for_seeds(SeedKind::Boundary));
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
    bytes.extend_from_slice(format!("{TITLE}\nBINARY\nDATASET POLYDATA\n").as_bytes());
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
