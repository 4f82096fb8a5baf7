//! Where streamlines start: every boundary voxel, or the vertices of the input surface;
//! and the deterministic subset `--sample N` takes.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::grid::{BlockStore, GridError};
use crate::input::TriMesh;

/// Which seeds to trace.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SeedKind {
    /// Every boundary voxel (label 1), at its center.
    #[default]
    Boundary,
    /// The vertices of the input surface (its triangles give the bijectivity numbers).
    Surface,
}

/// Voxel coordinates (x, y, z) of every boundary voxel, in C order of the grid (z
/// slowest), whatever the chunking.
pub fn boundary(labels: &dyn BlockStore<u8>, workers: usize) -> Result<Vec<DVec3>, GridError> {
    let spec = labels.spec();
    let per_block = crate::parallel::map_bounded(&spec.block_indices(), workers, |&b| {
        let st = spec.block_start(b);
        let sh = spec.block_shape(b);
        let data = labels.read_block(b)?;
        let mut v = Vec::new();
        let mut o = 0;
        for z in 0..sh[0] {
            for y in 0..sh[1] {
                for x in 0..sh[2] {
                    if data[o] == 1 {
                        v.push([st[0] + z, st[1] + y, st[2] + x]);
                    }
                    o += 1;
                }
            }
        }
        Ok::<_, GridError>(v)
    })?;
    let mut all: Vec<[u64; 3]> = per_block.into_iter().flatten().collect();
    all.sort_unstable();
    Ok(all
        .into_iter()
        .map(|[z, y, x]| DVec3::new(x as f64, y as f64, z as f64))
        .collect())
}

/// The indices of a deterministic pseudo-random subset of `n` of `total` seeds, in
/// increasing order (all of them when `n >= total`).
#[must_use]
pub fn sample(total: usize, n: usize) -> Vec<usize> {
    if n >= total {
        return (0..total).collect();
    }
    let mut keyed: Vec<(u64, usize)> = (0..total).map(|i| (splitmix(i as u64), i)).collect();
    keyed.select_nth_unstable(n);
    let mut v: Vec<usize> = keyed[..n].iter().map(|k| k.1).collect();
    v.sort_unstable();
    v
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// The surface of a run's input, when it has one: the mesh as read (or the built-in
/// starfish), with triangles wound so that their normals point outward.
pub fn input_surface(attrs: &serde_json::Value) -> Result<Option<TriMesh>, String> {
    let input = attrs.get("input").cloned().unwrap_or_default();
    if input.get("builtin").and_then(|b| b.as_str()) == Some("starfish") {
        return Ok(Some(crate::input::starfish::starfish(64, 240)));
    }
    let Some(path) = input.get("path").and_then(|p| p.as_str()) else {
        return Ok(None);
    };
    let path = std::path::Path::new(path);
    let format = input.get("format").and_then(|f| f.as_str()).unwrap_or("");
    // Label volumes, molecules, and meshes handed over in memory (no file to read again).
    if path.is_dir()
        || format == "label-volume"
        || format == "memory"
        || crate::input::molecule::is_molecule(format)
    {
        return Ok(None);
    }
    if !path.exists() {
        return Err(format!("{}: the run's input mesh is gone", path.display()));
    }
    if let Some(want) = input.get("sha256").and_then(|s| s.as_str()) {
        let got = crate::input::sha256_file(path).map_err(|e| e.to_string())?;
        if got != want {
            return Err(format!(
                "{}: the file changed since it was voxelized (sha256 differs); voxelize it again",
                path.display()
            ));
        }
    }
    let mut mesh = crate::input::load_mesh(path).map_err(|e| e.to_string())?;
    if mesh.signed_volume() < 0.0 {
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
    }
    Ok(Some(mesh))
}

/// The surface whose vertices surface seeds start from, and whether it is the input's
/// own: the input mesh (or the built-in starfish), or for other inputs (label volumes,
/// molecules, the standard ball) the surface nets of the solid's labels
/// ([`super::extract`]).
pub fn seed_surface(run: &crate::run::RunDir) -> Result<(TriMesh, bool), crate::Error> {
    let attrs = run.attrs()?;
    match input_surface(&attrs) {
        Ok(Some(mesh)) => Ok((mesh, true)),
        Ok(None) => {
            let labels = run.open_image::<u8>("labels")?;
            let workers = rayon::current_num_threads();
            Ok((super::extract::from_labels(&labels, workers)?, false))
        }
        Err(e) => Err(super::TraceError::Options(e).into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only mesh files are read again: molecules, label volumes and meshes handed over
    /// in memory have no surface to give (and no warning that it is gone).
    #[test]
    fn only_mesh_inputs_have_a_surface() {
        let input = |path: &str, format: &str| serde_json::json!({"input": {"path": path, "format": format, "sha256": null}});
        for (path, format) in [
            ("/nonexistent/1crn.pdb", "pdb"),
            ("/nonexistent/7pbl.cif", "cif"),
            ("/nonexistent/labels.nii.gz", "label-volume"),
            ("a mesh from a test", "memory"),
        ] {
            assert!(
                matches!(input_surface(&input(path, format)), Ok(None)),
                "{format}"
            );
        }
        let gone = input_surface(&input("/nonexistent/spot.obj", "obj"));
        assert!(gone.is_err_and(|e| e.contains("is gone")));
        let star = serde_json::json!({"input": {"path": null, "builtin": "starfish"}});
        assert!(input_surface(&star).is_ok_and(|m| m.is_some()));
    }

    #[test]
    fn samples_are_deterministic_sorted_and_spread() {
        let a = sample(10_000, 1000);
        assert_eq!(a, sample(10_000, 1000));
        assert_eq!(a.len(), 1000);
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        // Spread: each tenth of the range holds about a tenth of the sample.
        for d in 0..10 {
            let k = a.iter().filter(|&&i| i / 1000 == d).count();
            assert!((60..=140).contains(&k), "decile {d}: {k}");
        }
        assert_eq!(sample(5, 10), vec![0, 1, 2, 3, 4]);
    }
}
