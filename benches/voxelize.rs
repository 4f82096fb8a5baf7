//! Voxelization throughput (voxels/s): the whole `voxelize` stage, from a mesh in memory
//! to labels on disk, for the armadillo of ../shared/data when present, else the built-in
//! starfish. `harmap bench voxelize` gives the figures at 256^3 and 512^3.

// criterion_group! and criterion_main! generate undocumented functions.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use harmap::input::{load_mesh, starfish::starfish, TriMesh};
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::progress::Silent;
use harmap::voxelize::VoxelizeOptions;

fn mesh() -> (TriMesh, &'static str) {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/meshes/armadillo.obj.gz");
    match load_mesh(&p) {
        Ok(m) => (m, "armadillo"),
        Err(_) => (starfish(64, 240), "starfish"),
    }
}

fn bench(c: &mut Criterion) {
    let (m, name) = mesh();
    let dir = tempfile::tempdir().expect("temp dir");
    let mut g = c.benchmark_group("voxelize");
    g.sample_size(10);
    for n in [256u64, 512] {
        let opts = VoxelizeOptions {
            resolution: Some(n),
            ..VoxelizeOptions::default()
        };
        let out = dir.path().join(format!("{n}.harmap"));
        let (_, r) = voxelize_new_run(&Source::Mesh(&m, name), &opts, &out, true, &Silent)
            .expect("voxelize");
        g.throughput(Throughput::Elements(r.grid.num_voxels()));
        g.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
            b.iter(|| {
                voxelize_new_run(&Source::Mesh(&m, name), &opts, &out, true, &Silent)
                    .expect("voxelize")
            });
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
