//! theta and psi written block by block, as the directions of a block are done, and
//! the blocks left at the end.

use glam::DVec3;

use super::upwind::{is_set, is_target, Directions};
use crate::grid::{
    BlockStore, Compression, Decomposition, GridError, MemBudget, Scalar, ZarrStore,
};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;
use crate::run::RunDir;

/// theta and psi, written block by block: during the transport as blocks are done,
/// then the rest.
pub(super) struct Angles<T: Scalar> {
    theta: ZarrStore<T>,
    psi: ZarrStore<T>,
    /// Which blocks are written.
    written: Vec<std::sync::atomic::AtomicBool>,
    /// Target voxels and those with a direction, over the written blocks.
    counts: std::sync::Mutex<(u64, u64)>,
}

impl<T: Scalar> Angles<T> {
    pub(super) fn create(run: &RunDir, spec: &crate::grid::GridSpec) -> Result<Self, crate::Error> {
        let nan = T::from_f64(f64::NAN);
        Ok(Self {
            theta: run.create_image_staged("theta", spec, nan, Compression::Zstd(1))?,
            psi: run.create_image_staged("psi", spec, nan, Compression::Zstd(1))?,
            written: (0..spec.num_blocks())
                .map(|_| std::sync::atomic::AtomicBool::new(false))
                .collect(),
            counts: std::sync::Mutex::new((0, 0)),
        })
    }

    /// Bytes [`Angles::write`] holds for a block: theta, psi, and the labels and
    /// directions it is given.
    pub(super) fn block_bytes(spec: &crate::grid::GridSpec) -> u64 {
        volume(spec.chunk) * (2 * T::SIZE as u64 + 1 + 12)
    }

    /// Write block `b` from its labels and its [x, y, z] direction components (all three
    /// zero where a voxel has none).
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    pub(super) fn write(&self, b: Idx3, lab: &[u8], d: &[Vec<f32>; 3]) -> Result<(), GridError> {
        // In f32, the precision of the directions and of the stored angles.
        self.write_angles(b, lab, |i| {
            let v = [d[0][i], d[1][i], d[2][i]];
            is_set(v).then(|| {
                let (t, p) = crate::trace::angles_f32(v);
                (f64::from(t), f64::from(p))
            })
        })
    }

    /// Write block `b` from its labels and the direction of each voxel, if it has one.
    pub(super) fn write_with(
        &self,
        b: Idx3,
        lab: &[u8],
        dir: impl Fn(usize) -> Option<DVec3>,
    ) -> Result<(), GridError> {
        self.write_angles(b, lab, |i| dir(i).map(crate::trace::angles))
    }

    /// Write block `b` from its labels and the (theta, psi) of each voxel, if it has
    /// them.
    #[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    fn write_angles(
        &self,
        b: Idx3,
        lab: &[u8],
        angles: impl Fn(usize) -> Option<(f64, f64)>,
    ) -> Result<(), GridError> {
        let nan = T::from_f64(f64::NAN);
        let mut th = vec![nan; lab.len()];
        let mut ps = vec![nan; lab.len()];
        let (mut n, mut m) = (0, 0);
        for i in 0..lab.len() {
            if !is_target(lab[i]) {
                continue;
            }
            n += 1;
            if let Some((t, p)) = angles(i) {
                th[i] = T::from_f64(t);
                ps[i] = T::from_f64(p);
                m += 1;
            }
        }
        self.theta.write_block(b, &th)?;
        self.psi.write_block(b, &ps)?;
        let i = self.theta.spec().block_linear(b) as usize;
        self.written[i].store(true, std::sync::atomic::Ordering::Relaxed);
        let mut c = self
            .counts
            .lock()
            .expect("no writer panics holding the counts");
        c.0 += n;
        c.1 += m;
        Ok(())
    }

    /// Write the blocks `decomp` owns not written yet from `dirs` (without directions
    /// where there are none) and return the counts (target
    /// voxels, voxels with a direction) over this part's blocks.
    pub(super) fn finish(
        self,
        labels: &dyn BlockStore<u8>,
        dirs: Option<&Directions>,
        mem: MemBudget,
        progress: &dyn Progress,
        decomp: &dyn Decomposition,
    ) -> Result<(u64, u64), crate::Error> {
        let spec = labels.spec().clone();
        let rest: Vec<Idx3> = decomp
            .owned(&spec)
            .into_iter()
            .filter(|b| {
                !self.written[spec.block_linear(*b) as usize]
                    .load(std::sync::atomic::Ordering::Relaxed)
            })
            .collect();
        let workers = mem.workers(
            "writing theta and psi",
            0,
            Self::block_bytes(&spec),
            rayon::current_num_threads(),
        )?;
        progress.start("map (writing theta, psi)", rest.len() as u64);
        map_bounded(&rest, workers, |&b| -> Result<(), GridError> {
            let lab = labels.read_block(b)?;
            match dirs {
                Some(d) => self.write(b, &lab, &d.read(b)?)?,
                None => self.write_with(b, &lab, |_| None)?,
            }
            progress.advance(1);
            Ok(())
        })?;
        progress.finish();
        Ok(self
            .counts
            .into_inner()
            .expect("no writer panics holding the counts"))
    }
}
