//! Chunked grid storage behind one block-access trait.
//!
//! - [`GridSpec`]: shape, placement in the world, block shape.
//! - [`BlockStore`]: read and write blocks, read boxes with a halo; backends
//!   [`ZarrStore`] (kept arrays), [`FileStore`] (scratch files), [`MemStore`] and
//!   [`FlatStore`] (memory); capabilities a backend may offer: [`Contiguous`] (the
//!   whole grid as one array) and [`BlockStore::map_block`] (blocks read in place).
//! - [`scratch()`]: the one factory of scratch grids, in memory or in a file
//!   ([`Residence`]).
//! - [`Scalar`]: the element types, plain numbers ([`bytemuck::Pod`]), sealed.
//! - [`open_external_array`]: a user's Zarr v3 array, read-only ([`ExternalArray`]).
//! - [`MemBudget`]: the `--mem` bound on what a run holds resident.
//! - [`Decomposition`]: which blocks this process owns ([`Whole`] in one process), and
//!   the halo-exchange hook that several processes plug into.

mod block;
mod budget;
mod decomposition;
mod external;
mod file;
mod flat;
mod mapped;
mod memory;
#[cfg(feature = "mpi")]
pub mod mpi;
mod scratch;
mod spec;
mod store;
mod zarr;

pub use block::{copy_overlap, to_usize, Block};
pub use budget::{human, release_freed_memory, MemBudget, BASE_BYTES};
pub use decomposition::{
    halo_planes, layer_planes, planes_read, set_world, solo, world, Decomposition, Field, HaloData,
    Reach, Slabs, Whole,
};
pub use external::{open_external_array, ExternalArray};
pub use file::FileStore;
pub use flat::{Array, FlatStore};
pub use mapped::MappedStore;
pub use memory::MemStore;
pub use scratch::{copy_blocks, scratch, Residence};
pub use spec::GridSpec;
pub use store::{fill_with, BlockStore, Contiguous, GridError, MappedBlock, Scalar};
pub use zarr::{fs_store, mark_complete, read_table, write_table, Compression, ZarrStore};

#[cfg(test)]
mod tests {
    use super::*;

    /// Every backend's `read_region` (overridden or default) equals brute force, for
    /// boxes inside, across block edges and off the grid.
    #[test]
    fn regions_agree_across_backends() {
        let spec = GridSpec {
            shape: [13, 10, 21],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 8, 8],
            unit: None,
        };
        let value = |z: u64, y: u64, x: u64| ((z * 31 + y * 7 + x) % 251) as u16 + 1;
        let dir = tempfile::tempdir().unwrap();
        let mem = MemStore::<u16>::new(spec.clone(), 0);
        let flat = FlatStore::<u16>::new(spec.clone(), 0);
        let mm = FileStore::<u16>::create(&dir.path().join("m"), spec.clone()).unwrap();
        let zs = ZarrStore::<u16>::create(
            dir.path(),
            "/a",
            spec.clone(),
            0,
            Compression::Zstd(1),
            serde_json::Map::new(),
        )
        .unwrap();
        // Stored raw, its full blocks are mapped (BlockStore::map_block).
        let raw = ZarrStore::<u16>::create(
            dir.path(),
            "/r",
            spec.clone(),
            0,
            Compression::None,
            serde_json::Map::new(),
        )
        .unwrap();
        for st in [&mem as &dyn BlockStore<u16>, &flat, &mm, &zs, &raw] {
            fill_with(st, 2, |[z, y, x]| value(z, y, x)).unwrap();
        }
        assert!(raw.map_block([0, 0, 0]).is_some());
        // Its maps kept: read-only, and nothing to keep for a compressed store.
        let kept = MappedStore::new(&raw).unwrap();
        assert!(kept.write_block([0, 0, 0], &[0; 256]).is_err());
        assert!(MappedStore::new(&zs).is_none());
        let stores: [&dyn BlockStore<u16>; 6] = [&mem, &flat, &mm, &zs, &raw, &kept];
        for st in stores {
            for b in spec.block_indices() {
                let s = spec.block_start(b);
                let sh = spec.block_shape(b);
                let got = st.read_block(b).unwrap();
                let mut i = 0;
                for z in s[0]..s[0] + sh[0] {
                    for y in s[1]..s[1] + sh[1] {
                        for x in s[2]..s[2] + sh[2] {
                            assert_eq!(got[i], value(z, y, x), "block {b:?}");
                            i += 1;
                        }
                    }
                }
            }
        }
        let boxes = [
            ([0, 0, 0], [13, 10, 21]),
            ([-3, -2, -5], [6, 5, 9]),
            ([3, 7, 6], [3, 3, 12]),
            ([11, 9, 19], [5, 5, 5]),
            ([20, 0, 0], [2, 2, 2]),
        ];
        for (o, s) in boxes {
            for st in stores {
                let r = st.read_region(o, s, 999).unwrap();
                for z in 0..s[0] {
                    for y in 0..s[1] {
                        for x in 0..s[2] {
                            let g = [o[0] + z as i64, o[1] + y as i64, o[2] + x as i64];
                            let want = if spec.contains(g) {
                                value(g[0] as u64, g[1] as u64, g[2] as u64)
                            } else {
                                999
                            };
                            assert_eq!(r.data[r.offset(z, y, x)], want, "box {o:?}+{s:?} at {g:?}");
                        }
                    }
                }
            }
        }
    }

    /// A raw array's full blocks map to the same values `read_block` gives; edge
    /// blocks, missing chunks, chunk files of the wrong size and compressed arrays are
    /// not mapped (read_block reads them, and reports what is wrong).
    #[test]
    fn mapped_blocks_are_the_stored_blocks() {
        let spec = GridSpec {
            shape: [12, 8, 20],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 8, 8],
            unit: None,
        };
        let dir = tempfile::tempdir().unwrap();
        let value = |[z, y, x]: [u64; 3]| (z * 1000 + y * 50 + x) as f64 * 0.5 - 7.0;
        let raw = ZarrStore::<f64>::create(
            dir.path(),
            "/raw",
            spec.clone(),
            f64::NAN,
            Compression::None,
            serde_json::Map::new(),
        )
        .unwrap();
        let packed = ZarrStore::<f64>::create(
            dir.path(),
            "/packed",
            spec.clone(),
            f64::NAN,
            Compression::Zstd(1),
            serde_json::Map::new(),
        )
        .unwrap();
        for st in [&raw, &packed] {
            fill_with(st as &dyn BlockStore<f64>, 2, value).unwrap();
        }
        // One chunk left unwritten: it reads as the fill value.
        let unwritten = [2, 0, 1];
        std::fs::remove_file(dir.path().join("raw/c/2/0/1")).unwrap();
        let mut mapped = 0;
        for b in spec.block_indices() {
            assert!(packed.map_block(b).is_none(), "compressed block {b:?}");
            let full = spec.block_shape(b) == spec.chunk;
            match raw.map_block(b) {
                Some(m) => {
                    assert!(full && b != unwritten, "block {b:?} should not map");
                    assert_eq!(&m.unwrap()[..], &raw.read_block(b).unwrap()[..], "{b:?}");
                    mapped += 1;
                }
                None => assert!(!full || b == unwritten, "full block {b:?} should map"),
            }
        }
        // 3 x 1 x 3 blocks; the last along x is an edge block; one was removed.
        assert_eq!(mapped, 3 * 2 - 1);
        // Every chunk was written, so the removed one is missing, not the fill value.
        assert!(raw.is_complete());
        let e = raw.read_block(unwritten).unwrap_err();
        assert!(
            matches!(&e, GridError::Corrupt { path, chunk, .. } if path == "/raw" && chunk == &[2, 0, 1]),
            "{e}"
        );
        let reopened = ZarrStore::<f64>::open(dir.path(), "/raw", spec.clone()).unwrap();
        assert!(reopened.is_complete());
        assert!(reopened.read_block(unwritten).is_err());
        // A chunk file cut short is not mapped, and reading it is an error.
        let cut = dir.path().join("raw/c/0/0/0");
        let bytes = std::fs::read(&cut).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() - 8]).unwrap();
        assert!(raw.map_block([0, 0, 0]).is_none());
        assert!(raw.read_block([0, 0, 0]).is_err());
        // A raw array of another type of the same size is not mapped as f64: decoding
        // reports the mismatch.
        let ints = ZarrStore::<u64>::create(
            dir.path(),
            "/ints",
            spec.clone(),
            0,
            Compression::None,
            serde_json::Map::new(),
        )
        .unwrap();
        fill_with(&ints as &dyn BlockStore<u64>, 2, |[z, y, x]| z + y + x + 1).unwrap();
        assert!(ints.map_block([0, 0, 0]).is_some());
        let wrong = ZarrStore::<f64>::open(dir.path(), "/ints", spec.clone()).unwrap();
        assert!(wrong.map_block([0, 0, 0]).is_none());
        assert!(wrong.read_block([0, 0, 0]).is_err());
        // A block off the grid is an error, not a panic.
        assert!(matches!(raw.map_block([9, 9, 9]), Some(Err(_))));
    }

    /// Every chunk carries its checksum: a changed byte is an error naming the array and
    /// the chunk, whether the chunk is mapped in place or decoded; a chunk missing from
    /// an array not yet whole reads as the fill value.
    #[test]
    fn damaged_and_missing_chunks_are_errors() {
        let spec = GridSpec {
            shape: [8, 8, 16],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [8, 8, 8],
            unit: None,
        };
        let dir = tempfile::tempdir().unwrap();
        for (name, compression) in [("/r", Compression::None), ("/z", Compression::Zstd(1))] {
            let st = ZarrStore::<f64>::create(
                dir.path(),
                name,
                spec.clone(),
                f64::NAN,
                compression,
                serde_json::Map::new(),
            )
            .unwrap();
            // One chunk written: not whole, so the other reads as the fill value.
            st.write_block([0, 0, 0], &[1.5; 512]).unwrap();
            assert!(!st.is_complete());
            assert!(st.read_block([0, 0, 1]).unwrap().iter().all(|v| v.is_nan()));
            // A chunk of fill values is written too, and then the array is whole.
            st.write_block([0, 0, 1], &[f64::NAN; 512]).unwrap();
            assert!(st.is_complete());
            let file = dir.path().join(&name[1..]).join("c/0/0/0");
            let mut bytes = std::fs::read(&file).unwrap();
            let k = bytes.len() / 2;
            bytes[k] ^= 0x10;
            std::fs::write(&file, &bytes).unwrap();
            let st = ZarrStore::<f64>::open(dir.path(), name, spec.clone()).unwrap();
            let e = st.read_block([0, 0, 0]).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains("[0, 0, 0]"), "{e}");
            if let Some(m) = st.map_block([0, 0, 0]) {
                let e = m.err().expect("a damaged chunk does not map").to_string();
                assert!(e.contains("checksum"), "{e}");
            }
            assert!(st.read_region([0, 0, 0], [8, 8, 16], 0.0).is_err());
        }
    }

    /// `write_block_from` (MemStore's override and the default) writes the block's part
    /// of a box, shows each row's old and new values, and leaves other blocks alone.
    #[test]
    fn write_block_from_agrees_across_backends() {
        let spec = GridSpec {
            shape: [9, 10, 11],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [4, 4, 8],
            unit: None,
        };
        let dir = tempfile::tempdir().unwrap();
        let mem = MemStore::<u16>::new(spec.clone(), 7);
        let flat = FlatStore::<u16>::new(spec.clone(), 7);
        let mm = FileStore::<u16>::create(&dir.path().join("m"), spec.clone()).unwrap();
        fill_with(&mm, 1, |_| 7).unwrap();
        let b = [1, 2, 0];
        // A box around block b with a halo of 2 (off the grid on the low x side).
        let s = spec.block_start(b).map(|c| c as i64);
        let bsh = spec.block_shape(b).map(|c| c as usize);
        let origin = s.map(|c| c - 2);
        let shape = bsh.map(|c| c + 4);
        let mut bx = Block::filled(origin, shape, 0u16);
        for (i, v) in bx.data.iter_mut().enumerate() {
            *v = (i % 1000) as u16 + 100;
        }
        for st in [&mem as &dyn BlockStore<u16>, &flat, &mm] {
            let mut rows = Vec::new();
            st.write_block_from(
                b,
                &bx,
                Some(&mut |r, old: &[u16], new: &[u16]| {
                    assert!(old.iter().all(|&v| v == 7));
                    rows.push((r, new.to_vec()));
                }),
            )
            .unwrap();
            assert_eq!(rows.len(), bsh[0] * bsh[1]);
            let got = st.read_block(b).unwrap();
            for z in 0..bsh[0] {
                for y in 0..bsh[1] {
                    let want = &bx.data[bx.offset(z + 2, y + 2, 2)..][..bsh[2]];
                    let r = z * bsh[1] + y;
                    assert_eq!(&got[r * bsh[2]..(r + 1) * bsh[2]], want);
                    assert_eq!(rows[r], (r, want.to_vec()));
                }
            }
            assert!(st.read_block([0, 0, 0]).unwrap().iter().all(|&v| v == 7));
        }
    }
}
