//! Why surface triangles flip on the sphere: a diagnostic for docs/trace.md, not a
//! timing.
//!
//! ```sh
//! harmap voxelize cactus10k.obj -o cactus.harmap --resolution 128 && harmap solve cactus.harmap
//! cargo bench --bench flip_causes -- cactus.harmap
//! ```
//!
//! For a solved run whose input is a mesh, it traces the mesh's vertices with the default
//! integrator for surface seeds (RK45 with error control, then steps on levels of ln u),
//! on RK45's own steps at atol 1e-8 and 1e-6, and with fixed steps of 0.25 and 0.1 voxel
//! (no error control, so the sphere map is a smooth function of the seed). For each, it
//! prints:
//! - the flipped triangles;
//! - at their vertices, the local Jacobian of the surface -> sphere map, from two more
//!   streamlines started 1e-4 voxel away in the triangle's plane: how many flipped
//!   triangles have a vertex where it is negative (the map folds there: a real fold,
//!   not an artefact of the mesh's coarse triangles), and the median ratio of its
//!   singular values;
//! - the first step of each vertex's streamline against the mesh's inward normal: the
//!   share of flipped and of other triangles with a vertex where that step runs nearly
//!   along the surface (cosine under 0.2);
//! - the share of flipped and of other triangles with a vertex whose path crosses a
//!   place where the node directions nearly cancel (their interpolation shorter than
//!   0.5, so the unit field turns within a fraction of a voxel).
//!
//! Without an argument (as under a plain `cargo bench`) it prints this usage and stops.

use glam::DVec3;
use harmap::progress::Silent;
use harmap::run::RunDir;
use harmap::trace::field::Tile;
use harmap::trace::integrate::Rk45;
use harmap::trace::metrics::{orientation, singular_values};
use harmap::trace::seeds::SeedKind;
use harmap::trace::stage::{trace_seeds, TraceOptions, Tracer};
use harmap::trace::surface::Boundary;

/// Offset (voxels) of the two extra seeds around each vertex.
const D: f64 = 1e-4;

#[allow(clippy::too_many_lines, clippy::many_single_char_names)] // one diagnostic table, its columns named as in docs/trace.md
fn report(run: &RunDir, name: &str, rk: Rk45) -> Result<(), harmap::Error> {
    let opts = TraceOptions {
        seeds: SeedKind::Surface,
        rk,
        ..TraceOptions::default()
    };
    let t = trace_seeds(run, &opts, true, &Silent)?;
    let Some(mesh) = t.surface.as_ref() else {
        println!("the run's input is not a mesh");
        return Ok(());
    };
    let c = t.ball.center;
    let sphere: Vec<DVec3> = t.outcomes.iter().map(|o| (o.end - c).normalize()).collect();
    let is_flipped = |tr: &[u32; 3]| {
        let [a, b, s] = tr.map(|i| sphere[i as usize]);
        orientation(a, b, s) < 0.0
    };
    let flipped: Vec<[u32; 3]> = mesh.triangles.iter().copied().filter(is_flipped).collect();

    // Local Jacobians at the flipped triangles' vertices.
    let mut pts = Vec::with_capacity(flipped.len() * 9);
    for tr in &flipped {
        let [a, b, s] = tr.map(|i| t.seeds[i as usize]);
        let e1 = (b - a).normalize();
        let e2 = (b - a).cross(s - a).normalize().cross(e1);
        for v in [a, b, s] {
            pts.extend([v, v + e1 * D, v + e2 * D]);
        }
    }
    let tracer = Tracer::new(run, &opts, pts.len().max(1) as u64)?;
    let (out, _, _) = tracer.trace(&pts, false, &Silent)?;
    let q: Vec<DVec3> = out.iter().map(|o| (o.end - c).normalize()).collect();
    let mut folded = 0;
    let mut ratios = Vec::new();
    for k in 0..flipped.len() {
        let mut negative = false;
        for v in 0..3 {
            let i = (k * 3 + v) * 3;
            let (j1, j2) = ((q[i + 1] - q[i]) / D, (q[i + 2] - q[i]) / D);
            let n = j1.cross(j2);
            negative |= n.dot(q[i]) < 0.0;
            let (s1, s2) = singular_values(j1.length_squared() + j2.length_squared(), n.length());
            ratios.push(s2 / s1);
        }
        folded += usize::from(negative);
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios.get(ratios.len() / 2).copied().unwrap_or(f64::NAN);

    // First steps against the inward normals.
    let mut normal = vec![DVec3::ZERO; t.seeds.len()];
    for tr in &mesh.triangles {
        let [a, b, s] = tr.map(|i| t.seeds[i as usize]);
        for &i in tr {
            normal[i as usize] += (b - a).cross(s - a);
        }
    }
    let paths = t.paths.as_ref().expect("paths were recorded");
    let cosine: Vec<f64> = (0..t.seeds.len())
        .map(|i| match paths[i].as_slice() {
            [p0, p1, ..] => (*p1 - *p0).normalize().dot(-normal[i].normalize()),
            _ => f64::NAN,
        })
        .collect();
    let grazing = |tr: &[u32; 3]| tr.iter().any(|&i| cosine[i as usize] < 0.2);
    let share = |v: &[[u32; 3]]| {
        100.0 * v.iter().filter(|tr| grazing(tr)).count() as f64 / v.len().max(1) as f64
    };
    let others: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .copied()
        .filter(|tr| !is_flipped(tr))
        .collect();
    // Along each path, the weakest interpolated node direction before normalizing:
    // where node directions nearly cancel, the unit field turns within a fraction of a
    // voxel.
    let spec = run.grid()?;
    let u = run.open_image::<f64>("u")?;
    let shape = spec.shape.map(|n| n as usize);
    let (uo, us) = Tile::u_box([0; 3], shape);
    let ublock = harmap::grid::BlockStore::read_region(&u, uo, us, f64::NAN)?;
    // The field the lines followed: boundary values from the mesh.
    let boundary = Boundary::of_mesh(mesh, &spec, 0);
    let tile = Tile::from_u(&ublock, [0; 3], shape, boundary.index());
    let weakest: Vec<f64> = paths
        .iter()
        .map(|p| {
            let mut w = f64::INFINITY;
            for s in p.windows(2) {
                for k in 0..8 {
                    let q = s[0] + (s[1] - s[0]) * (f64::from(k) / 8.0);
                    // The field the lines followed, before it is normalized.
                    if let Ok(g) = tile.vector(q) {
                        w = w.min(g.length());
                    }
                }
            }
            w
        })
        .collect();
    let weak = |tr: &[u32; 3]| tr.iter().any(|&i| weakest[i as usize] < 0.5);
    let weak_share = |v: &[[u32; 3]]| {
        100.0 * v.iter().filter(|tr| weak(tr)).count() as f64 / v.len().max(1) as f64
    };
    let steps =
        t.outcomes.iter().map(|o| f64::from(o.steps)).sum::<f64>() / t.outcomes.len() as f64;
    println!(
        "{name}: {} of {} triangles flipped ({steps:.1} steps per line)",
        flipped.len(),
        mesh.triangles.len()
    );
    println!(
        "  local Jacobian (seeds {D:e} voxel apart) negative at a vertex: {folded} of {}; median sigma_min/sigma_max there {median:.2e}",
        flipped.len()
    );
    println!(
        "  a vertex whose first step runs along the surface (cos < 0.2 with the inward normal): {:.1}% of flipped, {:.1}% of other triangles",
        share(&flipped),
        share(&others)
    );
    println!(
        "  a vertex whose path meets interpolated node directions shorter than 0.5: {:.1}% of flipped, {:.1}% of other triangles",
        weak_share(&flipped),
        weak_share(&others)
    );
    Ok(())
}

fn main() -> Result<(), harmap::Error> {
    // `cargo bench` passes --bench; the run is the first other argument.
    let Some(path) = std::env::args().skip(1).find(|a| !a.starts_with("--")) else {
        println!("usage: cargo bench --bench flip_causes -- RUN (a solved run of a mesh)");
        return Ok(());
    };
    let run = RunDir::open(std::path::Path::new(&path))?;
    let default = Rk45::for_seeds(SeedKind::Surface);
    report(
        &run,
        &format!(
            "the default for surface seeds: RK45 at atol {:e}, then levels {} apart in ln u",
            default.atol, default.level_step
        ),
        default,
    )?;
    report(
        &run,
        &format!("RK45's own steps, atol {:e}", default.atol),
        Rk45 {
            level_step: 0.0,
            ..default
        },
    )?;
    report(&run, "RK45's own steps, atol 1e-6", Rk45::default())?;
    for h in [0.25, 0.1] {
        // An error allowance no step reaches: every step is h_max (an infinite one is
        // refused by the options' check).
        let fixed = Rk45 {
            atol: 1e300,
            h_max: h,
            ..Rk45::default()
        };
        report(&run, &format!("fixed steps of {h} voxel"), fixed)?;
    }
    Ok(())
}
