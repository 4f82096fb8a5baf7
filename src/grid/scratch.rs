//! Scratch grids: the intermediate fields a stage makes, uses and drops (the solver's
//! levels, the voxelizer's passes, the map's directions). One factory for all of them,
//! so the choice of backend — memory or a scratch file — is made in one place,
//! from where the stage's memory plan says the grid lives.

use std::path::Path;

use super::{BlockStore, FileStore, FlatStore, GridError, GridSpec, MemStore, Scalar};

/// Where a scratch grid lives.
#[derive(Clone, Copy, Debug)]
pub enum Residence<'a> {
    /// In memory, block by block ([`MemStore`]): blocks never written cost nothing.
    Blocks,
    /// In memory as one C-order array ([`FlatStore`]), which offers the
    /// [`Contiguous`](super::Contiguous) capability to kernels over the whole grid.
    Array,
    /// In a scratch file at this path ([`FileStore`]), created or truncated; the
    /// caller removes it (usually with its directory).
    File(&'a Path),
}

/// A new scratch grid of `spec` where every voxel reads `fill`, living where `at`
/// says.
///
/// # Performance
/// A file is created sparse and reads as zero bytes; a `fill` that is not all-zero
/// bytes is written through every block once.
pub fn scratch<T: Scalar>(
    spec: &GridSpec,
    fill: T,
    at: Residence<'_>,
) -> Result<Box<dyn BlockStore<T>>, GridError> {
    Ok(match at {
        Residence::Blocks => Box::new(MemStore::new(spec.clone(), fill)),
        Residence::Array => Box::new(FlatStore::new(spec.clone(), fill)),
        Residence::File(path) => {
            let s = FileStore::create(path, spec.clone())?;
            if bytemuck::bytes_of(&fill).iter().any(|&b| b != 0) {
                super::fill_with(&s, 1, |_| fill)?;
            }
            Box::new(s)
        }
    })
}

/// Copy every block of `src` into `dst` (same grid and blocks), at most `workers`
/// blocks in flight.
pub fn copy_blocks<T: Scalar>(
    src: &dyn BlockStore<T>,
    dst: &dyn BlockStore<T>,
    workers: usize,
) -> Result<(), GridError> {
    crate::parallel::map_bounded(&src.spec().block_indices(), workers, |&b| {
        dst.write_block(b, &src.read_block(b)?)
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every residence reads the fill value before any write, including a fill that is
    /// not zero bytes in a file (which starts as zeros), and keeps what is written.
    #[test]
    fn every_residence_reads_its_fill_and_keeps_writes() {
        let spec = GridSpec {
            shape: [5, 6, 7],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 4, 4],
            unit: None,
        };
        let dir = tempfile::tempdir().unwrap();
        for fill in [0.0, f64::NAN, -2.5] {
            let f = dir.path().join("s.bin");
            for at in [Residence::Blocks, Residence::Array, Residence::File(&f)] {
                let s = scratch(&spec, fill, at).unwrap();
                for b in spec.block_indices() {
                    let v = s.read_block(b).unwrap();
                    assert!(v.iter().all(|x| x.to_bits() == fill.to_bits()), "{at:?}");
                }
                let b = [1, 1, 1];
                let n = crate::math::volume(spec.block_shape(b)) as usize;
                let data: Vec<f64> = (0..n).map(|i| i as f64).collect();
                s.write_block(b, &data).unwrap();
                assert_eq!(s.read_block(b).unwrap(), data);
                // Planes into a block written whole and into one never written.
                s.write_block([0, 1, 1], &s.read_block([0, 1, 1]).unwrap())
                    .unwrap();
                for pb in [[0, 1, 1], [0, 0, 0]] {
                    let sh = spec.block_shape(pb).map(|c| c as usize);
                    let mut want = s.read_block(pb).unwrap();
                    let planes: Vec<f64> = (0..sh[1] * sh[2]).map(|i| -(i as f64)).collect();
                    want[sh[1] * sh[2]..2 * sh[1] * sh[2]].copy_from_slice(&planes);
                    s.write_planes(pb, 1..2, &planes).unwrap();
                    let got = s.read_block(pb).unwrap();
                    assert!(
                        got.iter()
                            .zip(&want)
                            .all(|(g, w)| g.to_bits() == w.to_bits()),
                        "{at:?}: planes of block {pb:?}"
                    );
                    assert!(s.write_planes(pb, 1..3, &planes).is_err());
                }
                s.write_block(b, &data).unwrap();
                let copy = scratch(&spec, 0.0, Residence::Blocks).unwrap();
                copy_blocks(&*s, &*copy, 2).unwrap();
                assert_eq!(copy.read_block(b).unwrap(), data);
                assert_eq!(
                    matches!(at, Residence::Array),
                    s.contiguous().is_some(),
                    "only the array offers the whole grid"
                );
            }
        }
    }
}
