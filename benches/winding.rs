//! The topology repair against the mesh's winding number: every closed genus-0 mesh of
//! ../shared/data/meshes (all but rocker-arm, two_spheres and maxFace) voxelized at
//! 64, 96, 128 and 256 with the default options (the repair), and once more with
//! `--allow-genus` (the raw solid). Prints a Markdown table: what the repair did, and
//! how many of the checked voxels disagree with the winding number.
//!
//! Checked voxels: every voxel the repair changed, and a deterministic sample of the
//! others (a hash of the voxel index picks about `SAMPLE` of them); of these, those
//! whose center lies more than one voxel (`spacing`) from the surface. The winding
//! number is the sum of the triangles' solid angles (van Oosterom and Strackee) over
//! 4 pi, evaluated with a bounding-volume tree: exactly for the triangles of every tree
//! node nearer than 2.5 times its radius, and by the node's dipole (its area-weighted
//! normal at its area centroid) beyond (Barill et al. 2018); an error far below the 0.5
//! threshold at points more than a voxel away.
//!
//! `cargo bench --bench winding [-- MESH...] ` (names under the meshes folder; default
//! all eleven). Resolutions from `HARMAP_WINDING_RES` (comma-separated; default
//! 64,96,128,256).

#![allow(missing_docs)]
#![allow(clippy::many_single_char_names)]

use std::f64::consts::PI;
use std::path::Path;

use harmap::grid::BlockStore;
use harmap::input::{load_mesh, TriMesh};
use harmap::math::Vec3;
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::progress::Silent;
use harmap::run::RunDir;
use harmap::voxelize::VoxelizeOptions;
use rayon::prelude::*;

/// About how many voxels the sample holds.
const SAMPLE: u64 = 200_000;
/// A node farther than this many radii is taken as its dipole.
const BETA: f64 = 2.5;
const LEAF: usize = 8;

struct Node {
    lo: Vec3,
    hi: Vec3,
    center: Vec3,
    radius: f64,
    area: Vec3,
    /// Children, or (when `leaf`) the range of `order`.
    a: usize,
    b: usize,
    leaf: bool,
}

struct Tree<'a> {
    m: &'a TriMesh,
    order: Vec<usize>,
    nodes: Vec<Node>,
}

fn tri(m: &TriMesh, t: usize) -> [Vec3; 3] {
    m.triangles[t].map(|i| m.vertices[i as usize])
}

impl<'a> Tree<'a> {
    fn new(m: &'a TriMesh) -> Self {
        let mut t = Tree {
            m,
            order: (0..m.triangles.len()).collect(),
            nodes: Vec::new(),
        };
        t.build(0, m.triangles.len());
        t
    }

    fn build(&mut self, s: usize, e: usize) -> usize {
        let (mut lo, mut hi) = (Vec3::splat(f64::INFINITY), Vec3::splat(f64::NEG_INFINITY));
        let (mut area, mut wc, mut wsum) = (Vec3::ZERO, Vec3::ZERO, 0.0);
        for &t in &self.order[s..e] {
            let [a, b, c] = tri(self.m, t);
            for v in [a, b, c] {
                lo = lo.min(v);
                hi = hi.max(v);
            }
            let n = (b - a).cross(c - a) * 0.5;
            let w = n.length();
            area += n;
            wc += (a + b + c) * (w / 3.0);
            wsum += w;
        }
        let center = if wsum > 0.0 {
            wc / wsum
        } else {
            (lo + hi) * 0.5
        };
        let radius = [lo.x, hi.x]
            .iter()
            .flat_map(|&x| [lo.y, hi.y].map(move |y| (x, y)))
            .flat_map(|(x, y)| [lo.z, hi.z].map(move |z| Vec3::new(x, y, z)))
            .map(|c| c.distance(center))
            .fold(0.0, f64::max);
        let id = self.nodes.len();
        self.nodes.push(Node {
            lo,
            hi,
            center,
            radius,
            area,
            a: s,
            b: e,
            leaf: true,
        });
        if e - s > LEAF {
            let ext = hi - lo;
            let axis = if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let m = self.m;
            let key = |t: usize| {
                let [a, b, c] = tri(m, t);
                (a + b + c).to_array()[axis]
            };
            let mid = usize::midpoint(s, e);
            self.order[s..e].select_nth_unstable_by(mid - s, |&x, &y| key(x).total_cmp(&key(y)));
            let l = self.build(s, mid);
            let r = self.build(mid, e);
            let n = &mut self.nodes[id];
            n.a = l;
            n.b = r;
            n.leaf = false;
        }
        id
    }

    fn winding(&self, p: Vec3) -> f64 {
        let mut w = 0.0;
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i];
            let d = n.center - p;
            let dl = d.length();
            if dl > BETA * n.radius {
                w += n.area.dot(d) / (dl * dl * dl);
            } else if n.leaf {
                for &t in &self.order[n.a..n.b] {
                    let [a, b, c] = tri(self.m, t).map(|v| v - p);
                    let (la, lb, lc) = (a.length(), b.length(), c.length());
                    let num = a.dot(b.cross(c));
                    let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
                    w += 2.0 * num.atan2(den);
                }
            } else {
                stack.push(n.a);
                stack.push(n.b);
            }
        }
        w / (4.0 * PI)
    }

    /// Whether the surface comes within `r` of `p`.
    fn near(&self, p: Vec3, r: f64) -> bool {
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i];
            let q = p.max(n.lo).min(n.hi);
            if q.distance(p) > r {
                continue;
            }
            if n.leaf {
                for &t in &self.order[n.a..n.b] {
                    let [a, b, c] = tri(self.m, t);
                    if point_triangle_distance(p, a, b, c) <= r {
                        return true;
                    }
                }
            } else {
                stack.push(n.a);
                stack.push(n.b);
            }
        }
        false
    }
}

/// Distance from `p` to triangle `(a, b, c)` (Ericson, Real-Time Collision Detection,
/// section 5.1.5).
fn point_triangle_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f64 {
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
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (p - c).length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).length();
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (p - (a + ab * v + ac * w)).length()
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn labels(run: &Path) -> (harmap::grid::GridSpec, Vec<bool>) {
    let run = RunDir::open(run).expect("run");
    let store = run.open_image::<u8>("labels").expect("labels");
    let spec = store.spec().clone();
    let s = spec.shape.map(|c| c as usize);
    let b = store.read_region([0, 0, 0], s, 0).expect("read");
    (spec, b.data.iter().map(|&l| matches!(l, 1..=3)).collect())
}

#[allow(clippy::too_many_lines)] // one table: the runs, the checks and the row
fn main() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes");
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let names: Vec<String> = if args.is_empty() {
        let mut v: Vec<String> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| {
                !["rocker-arm", "two_spheres", "maxFace"]
                    .iter()
                    .any(|x| n.starts_with(x))
            })
            .collect();
        v.sort();
        v
    } else {
        args
    };
    let res: Vec<u64> = std::env::var("HARMAP_WINDING_RES")
        .unwrap_or_else(|_| "64,96,128,256".into())
        .split(',')
        .map(|s| s.trim().parse().expect("resolution"))
        .collect();
    let tmp = tempfile::tempdir().expect("temp dir");
    println!("| mesh | resolution | result | before | repair (removed / added, % of the solid) | changed voxels checked | sampled voxels checked | disagree |");
    println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
    let mut total_bad = 0;
    for name in &names {
        let m = load_mesh(&dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let tree = Tree::new(&m);
        for &n in &res {
            let opts = VoxelizeOptions {
                resolution: Some(n),
                ..VoxelizeOptions::default()
            };
            let raw_opts = VoxelizeOptions {
                allow_genus: true,
                ..opts.clone()
            };
            let src = Source::Mesh(&m, name);
            let out = tmp.path().join("r.harmap");
            let raw = tmp.path().join("raw.harmap");
            let r = match voxelize_new_run(&src, &opts, &out, true, &Silent) {
                Ok((_, r)) => r,
                Err(e) => {
                    println!("| {name} | {n} | error: {e} | | | | | |");
                    total_bad += 1;
                    continue;
                }
            };
            voxelize_new_run(&src, &raw_opts, &raw, true, &Silent).expect("raw solid");
            let (spec, rep) = labels(&out);
            let (_, before) = labels(&raw);
            let step = (spec.num_voxels() / SAMPLE).max(1);
            let nyx = spec.shape[1] * spec.shape[2];
            let nx = spec.shape[2];
            let picks: Vec<(u64, bool)> = (0..spec.num_voxels())
                .filter_map(|i| {
                    let changed = rep[i as usize] != before[i as usize];
                    (changed || splitmix(i).is_multiple_of(step)).then_some((i, changed))
                })
                .collect();
            let results: Vec<(bool, bool)> = picks
                .par_iter()
                .filter_map(|&(i, changed)| {
                    let v = [i / nyx, (i / nx) % spec.shape[1], i % nx];
                    let p = spec.voxel_center(v);
                    if tree.near(p, spec.spacing) {
                        return None;
                    }
                    let inside = tree.winding(p).abs() > 0.5;
                    Some((changed, inside != rep[i as usize]))
                })
                .collect();
            let changed_checked = results.iter().filter(|r| r.0).count();
            let sampled = results.len() - changed_checked;
            let bad = results.iter().filter(|r| r.1).count();
            total_bad += bad;
            let (before_t, what) = match &r.repair {
                None => (format!("{} / {}", r.components, r.genus), "none".to_owned()),
                Some(x) => (
                    format!("{} / {}", x.components_before, x.genus_before),
                    format!(
                        "{}: -{} +{} ({:.4}%); {} cut, {} filled, {} speck(s)",
                        x.method,
                        x.voxels_removed,
                        x.voxels_added,
                        100.0 * x.fraction,
                        x.handles_cut,
                        x.handles_filled,
                        x.specks_dropped
                    ),
                ),
            };
            println!(
                "| {name} | {n} | {} / {} | {before_t} | {what} | {changed_checked} | {sampled} | {bad} |",
                r.components, r.genus
            );
        }
    }
    if total_bad > 0 {
        eprintln!("{total_bad} disagreement(s) or failure(s)");
        std::process::exit(1);
    }
}
