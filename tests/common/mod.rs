//! Shapes and helpers shared by the integration tests.

#![allow(dead_code)]

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use std::sync::atomic::AtomicBool;

use harmap::grid::{BlockStore, GridSpec, MemBudget};
use harmap::input::starfish::uv_sphere;
use harmap::input::TriMesh;
use harmap::math::Vec3;
use harmap::pipeline::standard_ball_run;
use harmap::progress::Silent;
use harmap::run::RunDir;
use harmap::solve::{solve, SolveOptions};
use harmap::voxelize::StandardBall;

/// A UV sphere of `radius` around `c`, outward normals.
pub fn sphere(c: Vec3, radius: f64, rings: usize, segs: usize) -> TriMesh {
    uv_sphere(rings, segs, |t, p| {
        c + radius * Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    })
}

/// A torus around the z axis, outward normals.
pub fn torus(big: f64, small: f64, n: usize, m: usize) -> TriMesh {
    let mut v = Vec::new();
    for i in 0..n {
        let u = 2.0 * PI * i as f64 / n as f64;
        for j in 0..m {
            let w = 2.0 * PI * j as f64 / m as f64;
            let r = big + small * w.cos();
            v.push(Vec3::new(r * u.cos(), r * u.sin(), small * w.sin()));
        }
    }
    let id = |i: usize, j: usize| ((i % n) * m + j % m) as u32;
    let mut t = Vec::new();
    for i in 0..n {
        for j in 0..m {
            t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    TriMesh {
        vertices: v,
        triangles: t,
    }
}

/// Two meshes as one.
pub fn merge(a: &TriMesh, b: &TriMesh) -> TriMesh {
    let off = a.vertices.len() as u32;
    let mut m = a.clone();
    m.vertices.extend_from_slice(&b.vertices);
    m.triangles
        .extend(b.triangles.iter().map(|t| t.map(|i| i + off)));
    m
}

/// The mesh with every triangle's winding reversed.
pub fn flipped(m: &TriMesh) -> TriMesh {
    TriMesh {
        vertices: m.vertices.clone(),
        triangles: m.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect(),
    }
}

/// Write a mesh as OBJ text.
pub fn write_obj(path: &Path, m: &TriMesh) {
    let mut s = String::new();
    for v in &m.vertices {
        let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
    }
    for t in &m.triangles {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}

/// All labels of a run, C order, and the grid.
pub fn read_labels(run: &Path) -> (GridSpec, Vec<u8>) {
    let run = RunDir::open(run).unwrap();
    let store = run.open_image::<u8>("labels").unwrap();
    let spec = store.spec().clone();
    let s = spec.shape.map(|c| c as usize);
    let b = store.read_region([0, 0, 0], s, 255).unwrap();
    (spec, b.data)
}

/// Generalized winding number of `p` (solid angles of all triangles / 4 pi), the
/// independent inside test of Jacobson et al. (van Oosterom-Strackee formula).
pub fn winding_number(m: &TriMesh, p: Vec3) -> f64 {
    let mut w = 0.0;
    for t in &m.triangles {
        let [a, b, c] = t.map(|i| m.vertices[i as usize] - p);
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let num = a.dot(b.cross(c));
        let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
        w += 2.0 * num.atan2(den);
    }
    w / (4.0 * PI)
}

/// Distance from `p` to triangle `(a, b, c)` (Ericson, Real-Time Collision Detection,
/// section 5.1.5).
pub fn point_triangle_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f64 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (p - a).length();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (p - b).length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (p - (a + ab * (d1 / (d1 - d3)))).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (p - c).length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (p - (a + ac * (d2 / (d2 - d6)))).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).length();
    }
    let denom = 1.0 / (va + vb + vc);
    (p - (a + ab * (vb * denom) + ac * (vc * denom))).length()
}

/// Distance from `p` to the mesh (brute force).
pub fn mesh_distance(m: &TriMesh, p: Vec3) -> f64 {
    m.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.vertices[i as usize]);
            point_triangle_distance(p, a, b, c)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The folder of the project's shared test data: `HARMAP_DATA` if set, else
/// ../shared/data next to the crate (as benches/hash_outputs.sh finds it).
pub fn shared_data_dir() -> PathBuf {
    match std::env::var_os("HARMAP_DATA") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
    }
}

/// The project's shared test data `rel` (a file or folder under [`shared_data_dir`]),
/// if present. Missing, the caller skips its test with a note, except under `CI=true`,
/// where this panics: CI must run every test that needs the data (as the interop tests
/// must run with their Python).
pub fn shared_data(rel: &str) -> Option<PathBuf> {
    let p = shared_data_dir().join(rel);
    if p.exists() {
        return Some(p);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but the shared test data {} is missing: the tests that need it must run \
         in CI (put the data folder at ../shared/data or set HARMAP_DATA)",
        p.display()
    );
    eprintln!("skipped: {} not found", p.display());
    None
}

/// A mesh of ../shared/data voxelized at `resolution` and solved, in `dir`; None
/// (after saying so) when the data folder is absent, a failure under `CI=true`
/// ([`shared_data`]).
pub fn solved_mesh(dir: &Path, name: &str, resolution: u64) -> Option<PathBuf> {
    let mesh = shared_data(&format!("meshes/{name}"))?;
    let run = dir.join(format!("{name}.harmap"));
    let opts = harmap::voxelize::VoxelizeOptions {
        resolution: Some(resolution),
        ..harmap::voxelize::VoxelizeOptions::default()
    };
    let iopts = harmap::input::InputOptions::default();
    let source = harmap::pipeline::Source::File(&mesh, &iopts);
    harmap::pipeline::voxelize_new_run(&source, &opts, &run, false, &Silent).unwrap();
    let o = harmap::solve::SolveOptions {
        checkpoint_every: 0.0,
        ..harmap::solve::SolveOptions::default()
    };
    let r = harmap::run::RunDir::open(&run).unwrap();
    harmap::solve::solve(&r, &o, &AtomicBool::new(false), &Silent).unwrap();
    Some(run)
}

/// Small deterministic pseudo-random numbers (SplitMix64) for sampling.
pub struct Rng(pub u64);

impl Rng {
    /// Next value in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Check the labels of a voxelized mesh against its winding number on `samples` random
/// voxels whose centers are more than one voxel from the surface. Returns the number
/// of disagreements.
pub fn winding_disagreements(
    mesh: &TriMesh,
    spec: &GridSpec,
    labels: &[u8],
    samples: usize,
    seed: u64,
) -> usize {
    let mut rng = Rng(seed);
    let mut bad = 0;
    let mut checked = 0;
    while checked < samples {
        let v = spec
            .shape
            .map(|n| ((rng.next_f64() * n as f64) as u64).min(n - 1));
        let p = spec.voxel_center(v);
        if mesh_distance(mesh, p) <= spec.spacing {
            continue;
        }
        checked += 1;
        let inside = winding_number(mesh, p).abs() > 0.5;
        let l = labels[((v[0] * spec.shape[1] + v[1]) * spec.shape[2] + v[2]) as usize];
        let solid = matches!(l, 1..=3);
        if inside != solid {
            bad += 1;
        }
    }
    bad
}

/// The standard ball at N (blocks of `chunk`) in `dir`, solved to rtol 1e-8.
pub fn solved_ball(dir: &Path, n: u64, chunk: u64) -> PathBuf {
    solved_ball_with_sink(dir, n, chunk, 2.0)
}

/// [`solved_ball`] with a center (sink) of `sink_radius` voxels.
pub fn solved_ball_with_sink(dir: &Path, n: u64, chunk: u64, sink_radius: f64) -> PathBuf {
    let out = dir.join(format!("ball{n}-{chunk}-{sink_radius}.harmap"));
    let p = StandardBall {
        n,
        sink_radius,
        chunk,
        mem: MemBudget::default(),
    };
    standard_ball_run(&p, &out, true, &Silent).unwrap();
    let opts = SolveOptions {
        rtol: 1e-8,
        checkpoint_every: 0.0,
        ..SolveOptions::default()
    };
    let run = RunDir::open(&out).unwrap();
    solve(&run, &opts, &AtomicBool::new(false), &Silent).unwrap();
    out
}
