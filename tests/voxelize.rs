//! Voxelization on shapes with known answers: inside tests against the winding number,
//! topology (cavities, pieces, handles), orientation independence, determinism, and the
//! out-of-core path against the in-memory one.

use harmap::input::TriMesh;
use harmap::math::Vec3;
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::progress::Silent;
use harmap::voxelize::{labels, Scratch, VoxelizeOptions, VoxelizeReport};

use crate::common::{flipped, merge, read_labels, sphere, torus, winding_disagreements};

fn vox(
    mesh: &TriMesh,
    opts: &VoxelizeOptions,
) -> (
    tempfile::TempDir,
    std::path::PathBuf,
    Result<VoxelizeReport, harmap::Error>,
) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.harmap");
    let r = voxelize_new_run(&Source::Mesh(mesh, "test mesh"), opts, &out, false, &Silent)
        .map(|(_, r)| r);
    (dir, out, r)
}

fn res(n: u64) -> VoxelizeOptions {
    VoxelizeOptions {
        resolution: Some(n),
        ..VoxelizeOptions::default()
    }
}

#[test]
fn sphere_labels_match_the_analytic_ball() {
    let mesh = sphere(Vec3::new(0.1, -0.2, 0.3), 1.0, 96, 192);
    let (_d, out, r) = vox(&mesh, &res(40));
    let r = r.unwrap();
    assert_eq!((r.components, r.genus, r.euler_characteristic), (1, 0, 1));
    let (spec, lab) = read_labels(&out);
    // Inside the ball (away from the faceted surface by more than the facet sag and a
    // voxel) must be solid; outside must not.
    let h = spec.spacing;
    let mut n = [0u64; 8];
    for z in 0..spec.shape[0] {
        for y in 0..spec.shape[1] {
            for x in 0..spec.shape[2] {
                let l = lab[((z * spec.shape[1] + y) * spec.shape[2] + x) as usize];
                n[l as usize] += 1;
                let d = (spec.voxel_center([z, y, x]) - Vec3::new(0.1, -0.2, 0.3)).length();
                if d < 1.0 - 0.01 - h {
                    assert!(
                        matches!(l, 1..=3),
                        "voxel {z},{y},{x} at r = {d} labelled {l}"
                    );
                }
                if d > 1.0 + h {
                    assert!(
                        !matches!(l, 1..=3),
                        "voxel {z},{y},{x} at r = {d} labelled {l}"
                    );
                }
            }
        }
    }
    assert_eq!(n, r.counts);
    // The deepest voxel of a ball is at its center.
    let c = Vec3::from_array(r.center);
    assert!((c - Vec3::new(0.1, -0.2, 0.3)).length() < h, "center {c}");
    assert!(
        (r.center_depth - 1.0 / h).abs() < 1.5,
        "depth {}",
        r.center_depth
    );
    // The center ball of radius 2 voxels holds the 33 voxels of a digital ball.
    assert_eq!(r.counts[labels::CENTER as usize], 33);
    // Four exterior layers surround the solid.
    for k in 0..4 {
        assert!(r.counts[(labels::LAYER1 + k) as usize] > 0);
    }
}

#[test]
fn exterior_layers_are_l1_distances() {
    let mesh = sphere(Vec3::ZERO, 1.0, 32, 64);
    let (_d, out, r) = vox(&mesh, &res(20));
    r.unwrap();
    let (spec, lab) = read_labels(&out);
    let [nz, ny, nx] = spec.shape.map(|c| c as i64);
    let at = |z: i64, y: i64, x: i64| lab[((z * ny + y) * nx + x) as usize];
    // Brute force: L1 distance to the nearest solid voxel.
    let solid: Vec<[i64; 3]> = (0..nz)
        .flat_map(|z| (0..ny).flat_map(move |y| (0..nx).map(move |x| [z, y, x])))
        .filter(|&[z, y, x]| matches!(at(z, y, x), 1..=3))
        .collect();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let l = at(z, y, x);
                if matches!(l, 1..=3) {
                    continue;
                }
                let d = solid
                    .iter()
                    .map(|s| (s[0] - z).abs() + (s[1] - y).abs() + (s[2] - x).abs())
                    .min()
                    .unwrap();
                let want = if d <= 4 {
                    labels::LAYER1 + d as u8 - 1
                } else {
                    labels::EXTERIOR
                };
                assert_eq!(l, want, "voxel {z},{y},{x} at L1 distance {d}");
            }
        }
    }
}

#[test]
fn inward_winding_gives_the_same_labels() {
    let mesh = sphere(Vec3::ZERO, 1.0, 24, 48);
    let (_d1, out1, r1) = vox(&mesh, &res(24));
    let (_d2, out2, r2) = vox(&flipped(&mesh), &res(24));
    r1.unwrap();
    r2.unwrap();
    assert_eq!(read_labels(&out1).1, read_labels(&out2).1);
}

#[test]
fn enclosed_cavity_is_filled() {
    // A hollow ball: outer sphere outward, inner sphere inward.
    let outer = sphere(Vec3::ZERO, 1.0, 48, 96);
    let inner = flipped(&sphere(Vec3::ZERO, 0.5, 24, 48));
    let (_d, out, r) = vox(&merge(&outer, &inner), &res(32));
    let r = r.unwrap();
    assert_eq!(r.cavities_filled, 1);
    assert!(r.cavity_voxels > 1000, "{}", r.cavity_voxels);
    let (spec, lab) = read_labels(&out);
    let c = spec.nearest_voxel(Vec3::ZERO).unwrap();
    let l = lab[((c[0] * spec.shape[1] + c[1]) * spec.shape[2] + c[2]) as usize];
    assert!(matches!(l, 2 | 3), "the filled cavity is interior, got {l}");
}

#[test]
fn overlapping_closed_parts_are_their_union() {
    let a = sphere(Vec3::ZERO, 1.0, 32, 64);
    let b = sphere(Vec3::new(1.0, 0.0, 0.0), 1.0, 32, 64);
    let m = merge(&a, &b);
    let (_d, out, r) = vox(&m, &res(40));
    let r = r.unwrap();
    assert_eq!((r.components, r.genus), (1, 0));
    let (spec, lab) = read_labels(&out);
    assert_eq!(winding_disagreements(&m, &spec, &lab, 300, 7), 0);
    // The lens where both overlap has winding number 2 and must be solid.
    let v = spec.nearest_voxel(Vec3::new(0.5, 0.0, 0.0)).unwrap();
    assert!(matches!(
        lab[((v[0] * spec.shape[1] + v[1]) * spec.shape[2] + v[2]) as usize],
        1..=3
    ));
}

#[test]
fn handles_and_pieces_are_refused_with_advice() {
    let (_d, out, r) = vox(&torus(1.0, 0.35, 64, 32), &res(32));
    let e = r.unwrap_err();
    let msg = e.to_string();
    assert!(e.is_bad_input());
    assert!(
        msg.contains("genus 1") && msg.contains("--allow-genus"),
        "{msg}"
    );
    assert!(!out.exists(), "a refused run must leave no run directory");
    assert!(!harmap::run::staging_path(&out).exists());

    let two = merge(
        &sphere(Vec3::ZERO, 1.0, 16, 32),
        &sphere(Vec3::new(3.0, 0.0, 0.0), 0.7, 16, 32),
    );
    let strict = VoxelizeOptions {
        topology: harmap::voxelize::TopologyMode::Strict,
        ..res(32)
    };
    let (_d, _out, r) = vox(&two, &strict);
    let msg = r.unwrap_err().to_string();
    assert!(
        msg.contains("2 separate pieces") && msg.contains("--keep-largest"),
        "{msg}"
    );

    let keep = VoxelizeOptions {
        keep_largest: true,
        ..res(32)
    };
    let (_d, out, r) = vox(&two, &keep);
    let r = r.unwrap();
    assert_eq!((r.components, r.pieces_removed), (1, 1));
    let (spec, _) = read_labels(&out);
    assert!(Vec3::from_array(r.center).distance(Vec3::ZERO) < 2.0 * spec.spacing);

    let allow = VoxelizeOptions {
        allow_genus: true,
        ..res(32)
    };
    let (_d, _out, r) = vox(&torus(1.0, 0.35, 64, 32), &allow);
    assert_eq!(r.unwrap().genus, 1);
}

#[test]
fn open_surface_is_refused() {
    let mut m = sphere(Vec3::ZERO, 1.0, 16, 32);
    m.triangles.truncate(m.triangles.len() - 3);
    let (_d, _o, r) = vox(&m, &res(16));
    let msg = r.unwrap_err().to_string();
    assert!(
        msg.contains("not closed") && msg.contains("edges belong to one triangle"),
        "{msg}"
    );
}

#[test]
fn center_options() {
    let m = sphere(Vec3::ZERO, 1.0, 32, 64);
    let at = VoxelizeOptions {
        center: Some([0.3, 0.0, 0.0]),
        ..res(32)
    };
    let (_d, _o, r) = vox(&m, &at);
    let r = r.unwrap();
    assert!((r.center[0] - 0.3).abs() <= r.grid.spacing);
    let outside = VoxelizeOptions {
        center: Some([2.0, 0.0, 0.0]),
        ..res(32)
    };
    let msg = vox(&m, &outside).2.unwrap_err().to_string();
    assert!(
        msg.contains("not inside the solid") || msg.contains("outside the grid"),
        "{msg}"
    );
    let too_big = VoxelizeOptions {
        center_radius: 40.0,
        ..res(32)
    };
    let msg = vox(&m, &too_big).2.unwrap_err().to_string();
    assert!(msg.contains("reaches the boundary"), "{msg}");
}

#[test]
fn labels_do_not_depend_on_threads_block_size_or_budget() {
    let m = crate::common::torus(1.0, 0.5, 48, 24);
    let m = merge(&m, &sphere(Vec3::ZERO, 0.9, 24, 48)); // genus 0 blob: torus with a ball plugging the hole
    let base = VoxelizeOptions {
        allow_genus: true,
        ..res(48)
    };
    let run_with = |threads: usize, o: &VoxelizeOptions| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let (d, out, r) = pool.install(|| vox(&m, o));
        r.unwrap();
        let files = chunk_files(&out);
        drop(d);
        files
    };
    let one = run_with(1, &base);
    let two = run_with(2, &base);
    assert_eq!(
        one, two,
        "label chunks must be byte-identical for 1 and 2 threads"
    );
    // In memory against on disk with small blocks and a budget that admits one worker at
    // a time: the same values.
    let base = VoxelizeOptions {
        scratch: Scratch::Memory,
        ..base
    };
    let small = VoxelizeOptions {
        chunk: 16,
        mem: "40MiB".parse().unwrap(),
        scratch: Scratch::Disk,
        ..base.clone()
    };
    let (_d1, o1, r1) = vox(&m, &base);
    let (_d2, o2, r2) = vox(&m, &small);
    let (r1, r2) = (r1.unwrap(), r2.unwrap());
    assert_eq!(r1.counts, r2.counts);
    assert_eq!(r1.center_voxel, r2.center_voxel);
    assert_eq!(read_labels(&o1).1, read_labels(&o2).1);
}

/// Every chunk file of `labels/0` with its bytes, sorted by path.
fn chunk_files(run: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    let mut v = Vec::new();
    let mut stack = vec![run.join("labels/0")];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                v.push((
                    p.strip_prefix(run).unwrap().display().to_string(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    v.sort();
    v
}

#[test]
fn label_volume_input_keeps_its_voxels() {
    // A raw u8 ball of radius 6 in a 16^3 volume.
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("ball.raw");
    let n = 16u64;
    let inside = |z: u64, y: u64, x: u64| {
        [z, y, x]
            .iter()
            .map(|&c| (c as f64 - 7.5).powi(2))
            .sum::<f64>()
            < 36.0
    };
    let mut bytes = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                bytes.push(if inside(z, y, x) { 7 } else { 0 });
            }
        }
    }
    std::fs::write(&raw, &bytes).unwrap();
    let iopts = harmap::input::InputOptions {
        raw: Some(harmap::input::RawSpec {
            shape: [n; 3],
            dtype: harmap::input::RawDtype::U8,
        }),
        ..Default::default()
    };
    let out = dir.path().join("v.harmap");
    let opts = VoxelizeOptions {
        spacing: Some(0.5),
        ..VoxelizeOptions::default()
    };
    let (_, r) =
        voxelize_new_run(&Source::File(&raw, &iopts), &opts, &out, false, &Silent).unwrap();
    assert_eq!(r.grid.shape, [n + 12; 3]);
    assert!(
        r.grid.origin.iter().all(|&o| (o + 3.0).abs() < 1e-12),
        "{:?}",
        r.grid.origin
    );
    let (spec, lab) = read_labels(&out);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let g = [z + 6, y + 6, x + 6];
                let l = lab[((g[0] * spec.shape[1] + g[1]) * spec.shape[2] + g[2]) as usize];
                assert_eq!(
                    matches!(l, 1..=3),
                    inside(z, y, x),
                    "volume voxel {z},{y},{x}"
                );
            }
        }
    }
    // Volume voxel (k, j, i) sits at world (i, j, k) * spacing.
    assert_eq!(spec.voxel_center([6, 6, 7]), Vec3::new(0.5, 0.0, 0.0));
}

#[test]
fn zarr_and_gzipped_raw_label_volumes_give_the_same_labels() {
    use harmap::grid::{fill_with, Compression, GridSpec, ZarrStore};
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let shape = [14u64, 18, 16];
    let inside = |z: u64, y: u64, x: u64| {
        let d = [
            (z as f64 - 6.5) / 5.5,
            (y as f64 - 8.5) / 7.5,
            (x as f64 - 7.5) / 6.5,
        ];
        d.iter().map(|c| c * c).sum::<f64>() < 1.0
    };
    // A Zarr v3 int32 array of "label ids" (0 outside, 5 inside), chunks that do not
    // divide the shape.
    let spec = GridSpec {
        shape,
        origin: [0.0; 3],
        spacing: 1.0,
        chunk: [5, 7, 6],
        unit: None,
    };
    let zroot = dir.path().join("seg.zarr");
    std::fs::create_dir_all(&zroot).unwrap();
    let z = ZarrStore::<i32>::create(
        &zroot,
        "/",
        spec.clone(),
        0,
        Compression::Zstd(1),
        serde_json::Map::new(),
    )
    .unwrap();
    fill_with(&z, 1, |[k, j, i]| if inside(k, j, i) { 5 } else { 0 }).unwrap();
    let mut raw = Vec::new();
    for k in 0..shape[0] {
        for j in 0..shape[1] {
            for i in 0..shape[2] {
                raw.extend_from_slice(&(if inside(k, j, i) { 2.5f32 } else { -1.0 }).to_le_bytes());
            }
        }
    }
    let gz = dir.path().join("seg.raw.gz");
    let mut enc = flate2::write::GzEncoder::new(
        std::fs::File::create(&gz).unwrap(),
        flate2::Compression::fast(),
    );
    enc.write_all(&raw).unwrap();
    enc.finish().unwrap();

    let opts = VoxelizeOptions {
        spacing: Some(0.25),
        ..VoxelizeOptions::default()
    };
    let none = harmap::input::InputOptions::default();
    let rawopts = harmap::input::InputOptions {
        raw: Some(harmap::input::RawSpec {
            shape,
            dtype: harmap::input::RawDtype::F32,
        }),
        ..Default::default()
    };
    let (o1, o2) = (dir.path().join("a.harmap"), dir.path().join("b.harmap"));
    let (_, r1) =
        voxelize_new_run(&Source::File(&zroot, &none), &opts, &o1, false, &Silent).unwrap();
    let (_, r2) =
        voxelize_new_run(&Source::File(&gz, &rawopts), &opts, &o2, false, &Silent).unwrap();
    let solid = (0..shape[0])
        .flat_map(|k| (0..shape[1]).flat_map(move |j| (0..shape[2]).map(move |i| (k, j, i))))
        .filter(|&(k, j, i)| inside(k, j, i))
        .count() as u64;
    assert_eq!(r1.counts[1] + r1.counts[2] + r1.counts[3], solid);
    assert_eq!(r1.counts, r2.counts);
    assert_eq!(read_labels(&o1).1, read_labels(&o2).1);
    // A raw file whose size does not match the layout is refused, naming both.
    let bad = harmap::input::InputOptions {
        raw: Some(harmap::input::RawSpec {
            shape: [14, 18, 17],
            dtype: harmap::input::RawDtype::F32,
        }),
        ..Default::default()
    };
    let e = voxelize_new_run(
        &Source::File(&gz, &bad),
        &opts,
        &dir.path().join("c"),
        false,
        &Silent,
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("seg.raw.gz") && e.to_string().contains("--raw-shape"),
        "{e}"
    );
}

#[test]
fn standard_ball_has_the_analytic_labels() {
    use harmap::grid::MemBudget;
    use harmap::pipeline::standard_ball_run;
    use harmap::voxelize::StandardBall;
    for (n, sink) in [(32u64, 2.0), (33, 2.0), (40, 4.0)] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ball.harmap");
        let p = StandardBall {
            n,
            sink_radius: sink,
            chunk: 16,
            mem: MemBudget::default(),
        };
        let (_, r) = standard_ball_run(&p, &out, false, &Silent).unwrap();
        assert_eq!(
            (r.components, r.genus, r.euler_characteristic),
            (1, 0, 1),
            "N = {n}"
        );
        let c = (n as f64 - 1.0) / 2.0;
        let (spec, lab) = read_labels(&out);
        assert_eq!(spec.shape, [n; 3]);
        let (mut solid, mut sinks) = (0u64, 0u64);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let d = ([z, y, x]
                        .iter()
                        .map(|&q| (q as f64 - c).powi(2))
                        .sum::<f64>())
                    .sqrt();
                    let l = lab[((z * n + y) * n + x) as usize];
                    solid += u64::from(d <= 0.45 * n as f64);
                    sinks += u64::from(d <= sink + 1e-9);
                    assert_eq!(
                        matches!(l, 1..=3),
                        d <= 0.45 * n as f64,
                        "N = {n}, voxel {z},{y},{x}"
                    );
                    assert_eq!(
                        l == labels::CENTER,
                        d <= sink + 1e-9,
                        "N = {n}, voxel {z},{y},{x}"
                    );
                }
            }
        }
        assert_eq!(r.counts[1] + r.counts[2] + r.counts[3], solid);
        assert_eq!(r.counts[labels::CENTER as usize], sinks);
        assert!(
            (r.center_depth - 0.45 * n as f64).abs() < 2.0,
            "depth {}",
            r.center_depth
        );
    }
}
