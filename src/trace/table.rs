//! The seed table `RUN/seeds/`: one Zarr v3 array per column, written side by side
//! and read back.

use std::fs;
use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;
use serde_json::{json, Value};

use super::integrate::Stop;
use super::seeds::SeedKind;
use crate::grid::{read_table, write_table, GridError};
use crate::run::{write_atomic, RunDir};

/// The seed table as stored in `RUN/seeds/`.
#[derive(Clone, Debug, Default)]
pub struct SeedTable {
    /// World positions (x, y, z) of the seeds.
    pub position: Vec<DVec3>,
    /// Polar angle of arrival (radians; NaN where the seed did not reach the center).
    pub theta: Vec<f64>,
    /// Azimuth of arrival (radians; NaN where it did not reach).
    pub psi: Vec<f64>,
    /// Traced with `untangle`: the polar angle at which the streamline arrived, before
    /// untangling ([`super::untangle`]; else empty). `theta` differs from it only
    /// at the seeds the untangling moved.
    pub arrival_theta: Vec<f64>,
    /// Likewise the azimuth.
    pub arrival_psi: Vec<f64>,
    /// phi at the seed.
    pub phi: Vec<f64>,
    /// Stop reason codes ([`Stop`]).
    pub stop: Vec<u8>,
    /// Accepted steps.
    pub steps: Vec<u32>,
    /// Arc length (world units).
    pub length: Vec<f64>,
    /// World position where the streamline ended.
    pub end: Vec<DVec3>,
    /// For surface seeds: the vertex of the input surface each seed is (else empty).
    pub vertex: Vec<u32>,
}

impl SeedTable {
    /// The sphere point of seed `i`, if it reached the center.
    #[must_use]
    pub fn sphere(&self, i: usize) -> Option<DVec3> {
        (self.stop[i] == Stop::Reached as u8 && self.theta[i].is_finite())
            .then(|| super::unit(self.theta[i], self.psi[i]))
    }
}

/// Points as x, y, z triples.
fn flat(v: &[DVec3]) -> Vec<f64> {
    v.iter().flat_map(DVec3::to_array).collect()
}

/// x, y, z triples as points.
fn unflat(v: &[f64]) -> Vec<DVec3> {
    v.chunks_exact(3)
        .map(|c| DVec3::new(c[0], c[1], c[2]))
        .collect()
}

/// Writes one column of the seed table.
type Column<'a> = Box<dyn Fn() -> Result<(), GridError> + Send + Sync + 'a>;

/// Write the table as the group `dir_name` (Zarr v3) under the run root.
pub(super) fn write_seeds(
    root: &Path,
    dir_name: &str,
    t: &SeedTable,
    kind: SeedKind,
) -> Result<(), crate::Error> {
    let dir = root.join(dir_name);
    if dir.exists() {
        fs::remove_dir_all(&dir).map_err(|e| GridError::Io {
            path: dir.clone(),
            source: e,
        })?;
    }
    fs::create_dir_all(&dir).map_err(|e| GridError::Io {
        path: dir.clone(),
        source: e,
    })?;
    let stops: Value = Stop::ALL
        .iter()
        .map(|s| ((*s as u8).to_string(), Value::from(s.name())))
        .collect::<serde_json::Map<_, _>>()
        .into();
    let doc = json!({
        "zarr_format": 3,
        "node_type": "group",
        "attributes": {"harmap_seeds": {
            "kind": kind,
            "rows": t.position.len(),
            "columns": {
                "position": "world x, y, z of the seed",
                "theta": "polar angle on the sphere, radians (NaN: did not reach); of the untangled map when traced with --untangle",
                "psi": "azimuth on the sphere, radians (NaN: did not reach); of the untangled map when traced with --untangle",
                "arrival_theta": "traced with --untangle: polar angle at which the streamline arrived, before untangling",
                "arrival_psi": "traced with --untangle: azimuth at which the streamline arrived, before untangling",
                "phi": "phi at the seed",
                "stop": "stop reason code",
                "steps": "accepted RK45 steps",
                "length": "arc length, world units",
                "end": "world x, y, z where the streamline ended",
                "vertex": "surface seeds: vertex index in the seeds' surface (stages.trace.result.seed_surface)",
            },
            "stop_codes": stops,
        }}
    });
    write_atomic(
        &dir.join("zarr.json"),
        serde_json::to_string_pretty(&doc).expect("json").as_bytes(),
    )?;
    let p = |c: &str| format!("/{dir_name}/{c}");
    // The columns are separate arrays: compressed and written in parallel.
    let mut columns: Vec<Column<'_>> = vec![
        Box::new(|| write_table(root, &p("position"), 3, &flat(&t.position), f64::NAN)),
        Box::new(|| write_table(root, &p("theta"), 0, &t.theta, f64::NAN)),
        Box::new(|| write_table(root, &p("psi"), 0, &t.psi, f64::NAN)),
        Box::new(|| write_table(root, &p("phi"), 0, &t.phi, f64::NAN)),
        Box::new(|| write_table(root, &p("stop"), 0, &t.stop, 255u8)),
        Box::new(|| write_table(root, &p("steps"), 0, &t.steps, 0u32)),
        Box::new(|| write_table(root, &p("length"), 0, &t.length, f64::NAN)),
        Box::new(|| write_table(root, &p("end"), 3, &flat(&t.end), f64::NAN)),
    ];
    if !t.vertex.is_empty() {
        columns.push(Box::new(|| {
            write_table(root, &p("vertex"), 0, &t.vertex, u32::MAX)
        }));
    }
    if !t.arrival_theta.is_empty() {
        columns.push(Box::new(|| {
            write_table(root, &p("arrival_theta"), 0, &t.arrival_theta, f64::NAN)
        }));
        columns.push(Box::new(|| {
            write_table(root, &p("arrival_psi"), 0, &t.arrival_psi, f64::NAN)
        }));
    }
    columns
        .par_iter()
        .with_max_len(1)
        .map(|c| c())
        .collect::<Result<Vec<()>, GridError>>()?;
    Ok(())
}

/// Read the seed table of a traced run.
pub fn read_seeds(run: &RunDir) -> Result<SeedTable, crate::Error> {
    let root = run.root();
    if !root.join("seeds/zarr.json").exists() {
        return Err(crate::run::RunError::StageMissing {
            path: root.to_owned(),
            stage: "trace".into(),
        }
        .into());
    }
    run.refuse_stale("trace")?;
    let f64s = |c: &str| -> Result<Vec<f64>, GridError> {
        Ok(read_table::<f64>(root, &format!("/seeds/{c}"))?.1)
    };
    let vertex = if root.join("seeds/vertex").exists() {
        read_table::<u32>(root, "/seeds/vertex")?.1
    } else {
        Vec::new()
    };
    let (arrival_theta, arrival_psi) = if root.join("seeds/arrival_theta").exists() {
        (f64s("arrival_theta")?, f64s("arrival_psi")?)
    } else {
        (Vec::new(), Vec::new())
    };
    Ok(SeedTable {
        position: unflat(&f64s("position")?),
        theta: f64s("theta")?,
        psi: f64s("psi")?,
        arrival_theta,
        arrival_psi,
        phi: f64s("phi")?,
        stop: read_table::<u8>(root, "/seeds/stop")?.1,
        steps: read_table::<u32>(root, "/seeds/steps")?.1,
        length: f64s("length")?,
        end: unflat(&f64s("end")?),
        vertex,
    })
}
