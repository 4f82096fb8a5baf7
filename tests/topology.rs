//! The topology step of voxelize: what counts as an artifact, the repair (one genus-0
//! piece, few changes, every change reported), refusals, and determinism.

use std::f64::consts::PI;

use harmap::input::TriMesh;
use harmap::math::Vec3;
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::progress::Silent;
use harmap::voxelize::{Scratch, TopologyMode, VoxelizeOptions, VoxelizeReport};

use crate::common::{read_labels, shared_data, sphere, torus, winding_disagreements};

fn vox(
    mesh: &TriMesh,
    opts: &VoxelizeOptions,
) -> (tempfile::TempDir, Result<VoxelizeReport, harmap::Error>) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.harmap");
    let r = voxelize_new_run(&Source::Mesh(mesh, "test mesh"), opts, &out, false, &Silent)
        .map(|(_, r)| r);
    (dir, r)
}

fn labels_of(dir: &tempfile::TempDir) -> Vec<u8> {
    read_labels(&dir.path().join("r.harmap")).1
}

fn res(n: u64) -> VoxelizeOptions {
    VoxelizeOptions {
        resolution: Some(n),
        ..VoxelizeOptions::default()
    }
}

/// Where [`c_ring`]'s gap is (radians from the x axis): oblique to the grid, so that
/// voxels straddle it (a gap on a plane of voxel centers would leave the ends apart).
const GAP_AT: f64 = 0.4;

/// A torus cut open by a gap of `gap` radians at [`GAP_AT`] and capped at both ends: a
/// closed genus-0 surface (a bent sausage) whose ends nearly touch. Outward normals.
fn c_ring(big: f64, small: f64, gap: f64, n: usize, m: usize) -> TriMesh {
    waisted_c_ring(big, small, small, gap, n, m)
}

/// [`c_ring`] whose tube narrows from radius `small` at the ends to `waist` opposite
/// the gap.
fn waisted_c_ring(big: f64, small: f64, waist: f64, gap: f64, n: usize, m: usize) -> TriMesh {
    let mut v = Vec::new();
    let u_at = |i: usize| GAP_AT + gap / 2.0 + (2.0 * PI - gap) * i as f64 / n as f64;
    for i in 0..=n {
        let u = u_at(i);
        // 1 at the ends, 0 opposite the gap.
        let t = 0.5 + 0.5 * (u - GAP_AT).cos();
        let small = waist + (small - waist) * t;
        for j in 0..m {
            let w = 2.0 * PI * j as f64 / m as f64;
            let r = big + small * w.cos();
            v.push(Vec3::new(r * u.cos(), r * u.sin(), small * w.sin()));
        }
    }
    let id = |i: usize, j: usize| (i * m + j % m) as u32;
    let mut t = Vec::new();
    for i in 0..n {
        for j in 0..m {
            t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    // Caps: a fan around each end's center, wound against the tube's edges there.
    let c0 = v.len() as u32;
    v.push(Vec3::new(big * u_at(0).cos(), big * u_at(0).sin(), 0.0));
    let c1 = v.len() as u32;
    v.push(Vec3::new(big * u_at(n).cos(), big * u_at(n).sin(), 0.0));
    for j in 0..m {
        t.push([c0, id(0, j), id(0, j + 1)]);
        t.push([c1, id(n, j + 1), id(n, j)]);
    }
    TriMesh {
        vertices: v,
        triangles: t,
    }
}

/// Solid voxels (labels 1..=3) where `a` and `b` differ.
fn solid_differences(a: &[u8], b: &[u8]) -> u64 {
    let solid = |l: u8| matches!(l, 1..=3);
    a.iter()
        .zip(b)
        .filter(|(&x, &y)| solid(x) != solid(y))
        .count() as u64
}

#[test]
fn a_genus_0_mesh_whose_ends_touch_is_repaired_where_they_touch() {
    // Ends 0.02 apart at the tube's center line, a quarter of a voxel at resolution 40.
    let (big, small, gap) = (1.0, 0.3, 0.02);
    let mesh = c_ring(big, small, gap, 96, 24);
    // The raw solid: the ends fuse into a handle.
    let raw = VoxelizeOptions {
        allow_genus: true,
        ..res(40)
    };
    let (draw, r) = vox(&mesh, &raw);
    let r = r.unwrap();
    assert!(
        r.components == 1 && r.genus >= 1,
        "the raw solid has spurious handles: {} piece(s), genus {}",
        r.components,
        r.genus
    );
    let raw_genus = r.genus;
    assert!(r.repair.is_none());

    let (drep, r) = vox(&mesh, &res(40));
    let r = r.unwrap();
    assert_eq!((r.components, r.genus, r.euler_characteristic), (1, 0, 1));
    assert_eq!(r.surface_topology, Some((1, 0)));
    let rep = r.repair.clone().expect("a repair is reported");
    assert_eq!((rep.components_before, rep.genus_before), (1, raw_genus));
    assert_eq!(rep.handles_cut + rep.handles_filled, raw_genus);
    // What is reported is what changed.
    let changed = solid_differences(&labels_of(&draw), &labels_of(&drep));
    assert_eq!(changed, rep.voxels_removed + rep.voxels_added);
    assert_eq!(
        rep.regions.iter().map(|g| g.voxels).sum::<u64>(),
        changed,
        "the regions cover the changes"
    );
    // Few changes: no more than one cross-section of the tube.
    let h = r.grid.spacing;
    let section = PI * (small / h).powi(2);
    assert!(
        changed > 0 && (changed as f64) < section,
        "{changed} voxels changed; a cross-section has {section:.0}"
    );
    // Where the ends touch: the largest change is within two voxels of the gap.
    let p = Vec3::from_array(rep.regions[0].position);
    let (c, s) = (GAP_AT.cos(), GAP_AT.sin());
    assert!(
        p.distance(Vec3::new(big * c, big * s, 0.0)) < small + 2.0 * h,
        "repair at {p:?}"
    );
    assert!(
        (-s * p.x + c * p.y).abs() < 2.0 * h,
        "the change lies across the gap: {p:?}"
    );
    // Strict refuses it as before, with the advice.
    let strict = VoxelizeOptions {
        topology: TopologyMode::Strict,
        ..res(40)
    };
    let msg = vox(&mesh, &strict).1.unwrap_err().to_string();
    assert!(
        msg.contains(&format!("genus {raw_genus}")) && msg.contains("--topology repair"),
        "{msg}"
    );
}

#[test]
fn a_fused_gap_is_cut_where_the_mesh_is_open_not_where_the_solid_is_thinnest() {
    // The tube is 4.6 voxels thick at the fused ends and 2.5 opposite them: the solid
    // alone is thinnest at the waist, but the mesh says the ends do not touch.
    let (big, small, waist, gap) = (1.0, 0.3, 0.165, 0.02);
    let mesh = waisted_c_ring(big, small, waist, gap, 192, 24);
    let (draw, r) = vox(
        &mesh,
        &VoxelizeOptions {
            allow_genus: true,
            ..res(40)
        },
    );
    assert!(r.unwrap().genus >= 1, "the ends fuse");
    let (drep, r) = vox(&mesh, &res(40));
    let r = r.unwrap();
    assert_eq!((r.components, r.genus), (1, 0));
    let rep = r.repair.expect("a repair is reported");
    // Every changed voxel lies at the gap, and within a voxel of the surface.
    let (spec, labels) = read_labels(&drep.path().join("r.harmap"));
    let (_, raw) = read_labels(&draw.path().join("r.harmap"));
    let solid = |l: u8| matches!(l, 1..=3);
    let (nyx, nx) = (spec.shape[1] * spec.shape[2], spec.shape[2]);
    let (c, s) = (GAP_AT.cos(), GAP_AT.sin());
    let mut changed = 0;
    for i in 0..labels.len() as u64 {
        if solid(labels[i as usize]) == solid(raw[i as usize]) {
            continue;
        }
        changed += 1;
        let p = spec.voxel_center([i / nyx, (i / nx) % spec.shape[1], i % nx]);
        assert!(
            (-s * p.x + c * p.y).abs() < 2.0 * spec.spacing && c * p.x + s * p.y > 0.0,
            "voxel {i} at {p:?} changed away from the gap ({rep:?})"
        );
        let d = crate::common::mesh_distance(&mesh, p);
        assert!(
            d <= spec.spacing,
            "voxel {i} at {p:?} changed {:.2} voxels from the surface",
            d / spec.spacing
        );
    }
    assert_eq!(changed, rep.voxels_removed + rep.voxels_added);
}

#[test]
fn a_real_torus_is_refused_by_default_and_repaired_on_request() {
    let mesh = torus(1.0, 0.35, 64, 32);
    let msg = vox(&mesh, &res(32)).1.unwrap_err().to_string();
    assert!(
        msg.contains("genus 1")
            && msg.contains("--topology repair")
            && msg.contains("--allow-genus"),
        "{msg}"
    );
    let (draw, raw) = vox(
        &mesh,
        &VoxelizeOptions {
            allow_genus: true,
            ..res(32)
        },
    );
    assert_eq!(raw.unwrap().genus, 1);
    let repair = VoxelizeOptions {
        topology: TopologyMode::Repair,
        ..res(32)
    };
    let (drep, r) = vox(&mesh, &repair);
    let r = r.unwrap();
    assert_eq!((r.components, r.genus), (1, 0));
    assert_eq!(r.surface_topology, Some((1, 1)));
    let rep = r.repair.unwrap();
    assert_eq!(rep.handles_cut + rep.handles_filled, 1);
    assert_eq!(
        solid_differences(&labels_of(&draw), &labels_of(&drep)),
        rep.voxels_removed + rep.voxels_added
    );
    // The smaller of the two ways: a cut of the tube (about pi 0.35^2 / h^2 voxels)
    // against a plug of the hole (pi 0.65^2 / h^2): cut.
    assert_eq!(rep.method, "cut");
    assert!(rep.alternative_voxels > rep.voxels_removed + rep.voxels_added);
    // A real handle's cut is large: said in a warning.
    assert!(
        r.warnings.iter().any(|w| w.contains("more than 0.1%")),
        "{:?}",
        r.warnings
    );
}

#[test]
fn specks_and_separate_pieces_are_dropped_and_reported() {
    let two = crate::common::merge(
        &sphere(Vec3::ZERO, 1.0, 16, 32),
        &sphere(Vec3::new(2.2, 0.0, 0.0), 0.2, 8, 16),
    );
    let (_d, r) = vox(&two, &res(32));
    let r = r.unwrap();
    assert_eq!((r.components, r.genus), (1, 0));
    let rep = r.repair.unwrap();
    assert_eq!((rep.components_before, rep.specks_dropped), (2, 1));
    assert_eq!(rep.voxels_removed, rep.speck_voxels);
    assert!(Vec3::from_array(rep.regions[0].position).distance(Vec3::new(2.2, 0.0, 0.0)) < 0.35);
    let strict = VoxelizeOptions {
        topology: TopologyMode::Strict,
        ..res(32)
    };
    let msg = vox(&two, &strict).1.unwrap_err().to_string();
    assert!(
        msg.contains("2 separate pieces") && msg.contains("--keep-largest"),
        "{msg}"
    );
}

#[test]
fn the_repair_is_the_same_for_any_thread_count_and_storage() {
    let mesh = c_ring(1.0, 0.3, 0.02, 96, 24);
    let run = |threads: usize, scratch: Scratch| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let (d, r) = vox(
                &mesh,
                &VoxelizeOptions {
                    scratch,
                    chunk: 16,
                    ..res(48)
                },
            );
            assert!(r.unwrap().repair.is_some());
            labels_of(&d)
        })
    };
    let a = run(1, Scratch::Memory);
    assert!(a == run(2, Scratch::Memory), "1 and 2 threads differ");
    assert!(a == run(2, Scratch::Disk), "disk and memory differ");
}

#[test]
fn horse_at_96_is_one_genus_0_piece_by_default() {
    let Some(path) = shared_data("meshes/horse.ply.gz") else {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "../shared/data/meshes/horse.ply.gz is missing"
        );
        eprintln!("skipped: ../shared/data/meshes/horse.ply.gz not found");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("horse.harmap");
    let iopts = harmap::input::InputOptions::default();
    let (_, r) =
        voxelize_new_run(&Source::File(&path, &iopts), &res(96), &out, false, &Silent).unwrap();
    assert_eq!((r.components, r.genus), (1, 0));
    let rep = r.repair.expect("the horse at 96 needs a repair");
    assert!(rep.fraction < 1e-3, "{rep:?}");
    let mesh = harmap::input::load_mesh(&path).unwrap();
    let (spec, labels) = read_labels(&out);
    assert_eq!(winding_disagreements(&mesh, &spec, &labels, 200, 7), 0);
}

#[test]
fn horse_at_96_repaired_the_same_for_threads_and_memory_budgets() {
    // The horse at 96 needs a repair (specks and a handle): the repaired labels are the
    // same bytes for 1 and 2 threads and for --mem 256MiB (solid grid on disk, windows
    // within the budget) against the default in-memory run.
    let Some(path) = shared_data("meshes/horse.ply.gz") else {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "../shared/data/meshes/horse.ply.gz is missing"
        );
        eprintln!("skipped: ../shared/data/meshes/horse.ply.gz not found");
        return;
    };
    let mesh = harmap::input::load_mesh(&path).unwrap();
    let run = |threads: usize, mem: Option<&str>| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut opts = res(96);
            if let Some(m) = mem {
                opts.mem = m.parse().unwrap();
                opts.scratch = Scratch::Disk;
            }
            let (d, r) = vox(&mesh, &opts);
            let rep = r.unwrap().repair.expect("the horse at 96 needs a repair");
            assert!(rep.handles_cut + rep.handles_filled >= 1, "{rep:?}");
            (labels_of(&d), rep.voxels_removed, rep.voxels_added)
        })
    };
    let a = run(1, None);
    assert!(a == run(2, None), "1 and 2 threads differ");
    assert!(
        a == run(2, Some("256MiB")),
        "--mem 256MiB and in memory differ"
    );
}

#[test]
fn repaired_meshes_agree_with_the_winding_number_away_from_the_surface() {
    // Meshes that need a repair at 64 or 96: every voxel the repair changed, and 200
    // random voxels, whose center lies more than a voxel from the surface, agree with the
    // mesh's winding number.
    for (name, n) in [
        ("cow.obj", 64),
        ("cow.obj", 96),
        ("nefertiti.obj.gz", 96),
        ("armadillo.obj.gz", 96),
    ] {
        let Some(path) = shared_data(&format!("meshes/{name}")) else {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "../shared/data/meshes/{name} is missing"
            );
            eprintln!("skipped: ../shared/data/meshes/{name} not found");
            return;
        };
        let mesh = harmap::input::load_mesh(&path).unwrap();
        let (draw, r) = vox(
            &mesh,
            &VoxelizeOptions {
                allow_genus: true,
                ..res(n)
            },
        );
        r.unwrap();
        let (drep, r) = vox(&mesh, &res(n));
        let r = r.unwrap();
        assert!(r.repair.is_some(), "{name} at {n} needs a repair");
        let (spec, labels) = read_labels(&drep.path().join("r.harmap"));
        let (_, raw) = read_labels(&draw.path().join("r.harmap"));
        let solid = |l: u8| matches!(l, 1..=3);
        let (nyx, nx) = (spec.shape[1] * spec.shape[2], spec.shape[2]);
        let mut checked = 0;
        for i in 0..labels.len() as u64 {
            if solid(labels[i as usize]) == solid(raw[i as usize]) {
                continue;
            }
            let p = spec.voxel_center([i / nyx, (i / nx) % spec.shape[1], i % nx]);
            if crate::common::mesh_distance(&mesh, p) <= spec.spacing {
                continue;
            }
            checked += 1;
            let inside = crate::common::winding_number(&mesh, p).abs() > 0.5;
            assert_eq!(
                inside,
                solid(labels[i as usize]),
                "{name} at {n}: changed voxel {i} disagrees with the winding number"
            );
        }
        eprintln!("{name} at {n}: {checked} changed voxels away from the surface checked");
        assert_eq!(
            winding_disagreements(&mesh, &spec, &labels, 200, 11),
            0,
            "{name} at {n}"
        );
    }
}

/// The compact cut (the repair of grids over 32 Mi voxels, without closings), forced
/// on small grids: the solid ends as one genus-0 piece, what is reported is what changed,
/// and the result is the same bytes for 1 and 2 threads and for disk and memory.
#[test]
fn the_compact_cut_of_large_grids_repairs_a_small_one_forced_through_it() {
    let mesh = torus(1.0, 0.35, 64, 32);
    let repair = VoxelizeOptions {
        topology: TopologyMode::Repair,
        ..res(32)
    };
    let (draw, raw) = vox(
        &mesh,
        &VoxelizeOptions {
            allow_genus: true,
            ..res(32)
        },
    );
    assert_eq!(raw.unwrap().genus, 1);
    harmap::voxelize::compact_repair_above(Some(0));
    let (drep, r) = vox(&mesh, &repair);
    harmap::voxelize::compact_repair_above(None);
    let r = r.unwrap();
    assert_eq!((r.components, r.genus, r.euler_characteristic), (1, 0, 1));
    let rep = r.repair.unwrap();
    assert_eq!(
        (rep.handles_cut, rep.handles_filled, rep.voxels_added),
        (1, 0, 0)
    );
    assert_eq!(rep.method, "cut");
    // The compact path tries no fill (the default path here reports one).
    assert_eq!(rep.alternative_voxels, u64::MAX);
    let changed = solid_differences(&labels_of(&draw), &labels_of(&drep));
    assert_eq!(changed, rep.voxels_removed);
    assert_eq!(rep.regions.iter().map(|g| g.voxels).sum::<u64>(), changed);
    // One sheet across the tube: about a cross-section, pi 0.35^2 / h^2 voxels.
    let h = r.grid.spacing;
    let section = PI * (0.35 / h).powi(2);
    assert!(
        (changed as f64) > 0.5 * section && (changed as f64) < 2.5 * section,
        "{changed} voxels removed; a cross-section has {section:.0}"
    );

    // A genus-0 mesh whose ends fuse, with a speck: the same bytes however run.
    let ring = crate::common::merge(
        &c_ring(1.0, 0.3, 0.02, 96, 24),
        &sphere(Vec3::new(0.0, 0.0, 0.9), 0.06, 8, 16),
    );
    let run = |threads: usize, scratch: Scratch| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            harmap::voxelize::compact_repair_above(Some(0));
            let (d, r) = vox(
                &ring,
                &VoxelizeOptions {
                    scratch,
                    chunk: 16,
                    ..res(48)
                },
            );
            harmap::voxelize::compact_repair_above(None);
            let r = r.unwrap();
            assert_eq!((r.components, r.genus), (1, 0));
            let rep = r.repair.unwrap();
            assert!(rep.handles_cut >= 1, "{rep:?}");
            (labels_of(&d), rep.voxels_removed)
        })
    };
    let a = run(1, Scratch::Memory);
    assert!(a == run(2, Scratch::Memory), "1 and 2 threads differ");
    assert!(a == run(2, Scratch::Disk), "disk and memory differ");
}
