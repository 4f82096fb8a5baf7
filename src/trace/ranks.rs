//! The trace across MPI ranks ([`Tracer::trace_across`]): each rank advances the lines
//! in the tiles it owns ([`trace_tiled_with`]); the lines that left for another rank's
//! tiles are gathered after each round and taken up by their owners, until no line is
//! in flight anywhere. Then every rank gathers every outcome, so each holds what one
//! process traces (a line's outcome does not depend on which part advanced it).

use glam::DVec3;

use super::integrate::{Line, Stop};
use super::stage::Tracer;
use super::tiles::{trace_tiled_with, Outcome, TileStats, Traced};
use crate::grid::{Decomposition, GridError};
use crate::progress::Progress;

const LINE: usize = 4 + 24 + 8 + 4 + 8 + 2 + 1 + 4 + 8;
const OUTCOME: usize = 4 + 1 + 24 + 4 + 8;

fn put_vec(out: &mut Vec<u8>, p: DVec3) {
    for v in [p.x, p.y, p.z] {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

fn vec_at(b: &[u8], at: usize) -> DVec3 {
    DVec3::new(f64_at(b, at), f64_at(b, at + 8), f64_at(b, at + 16))
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn put_line(out: &mut Vec<u8>, l: &Line) {
    out.extend_from_slice(&l.id.to_le_bytes());
    put_vec(out, l.p);
    out.extend_from_slice(&l.h.to_le_bytes());
    out.extend_from_slice(&l.steps.to_le_bytes());
    out.extend_from_slice(&l.length.to_le_bytes());
    out.extend_from_slice(&l.escapes.to_le_bytes());
    out.push(u8::from(l.level.is_some()));
    out.extend_from_slice(&l.level.unwrap_or(0).to_le_bytes());
    out.extend_from_slice(&l.level_from.to_le_bytes());
}

fn line_at(b: &[u8]) -> Line {
    Line {
        id: u32_at(b, 0),
        p: vec_at(b, 4),
        h: f64_at(b, 28),
        steps: u32_at(b, 36),
        length: f64_at(b, 40),
        escapes: u16::from_le_bytes([b[48], b[49]]),
        level: (b[50] == 1).then(|| i32::from_le_bytes(b[51..55].try_into().expect("4 bytes"))),
        level_from: f64_at(b, 55),
    }
}

fn put_outcome(out: &mut Vec<u8>, id: u32, o: &Outcome) {
    out.extend_from_slice(&id.to_le_bytes());
    out.push(o.stop as u8);
    put_vec(out, o.end);
    out.extend_from_slice(&o.steps.to_le_bytes());
    out.extend_from_slice(&o.length.to_le_bytes());
}

fn outcome_at(b: &[u8]) -> (u32, Outcome) {
    (
        u32_at(b, 0),
        Outcome {
            stop: Stop::ALL[b[4] as usize],
            end: vec_at(b, 5),
            steps: u32_at(b, 29),
            length: f64_at(b, 33),
        },
    )
}

impl Tracer {
    /// [`Tracer::trace`] across the ranks of `decomp` (every rank calls it with the same
    /// seeds): the same outcomes on every rank, no paths, the counters summed.
    pub fn trace_across(
        &self,
        seeds: &[DVec3],
        progress: &dyn Progress,
        decomp: &dyn Decomposition,
    ) -> Result<Traced, GridError> {
        let spec = crate::grid::BlockStore::spec(&self.u).clone();
        let ids = seeds.len();
        let mine = |l: &Line| {
            self.tiling
                .owned_by(self.tiling.tile_of(l.p), &spec, decomp)
        };
        let mut inbox: Vec<Line> = seeds
            .iter()
            .enumerate()
            .map(|(i, &p)| Line::new(i as u32, p, &self.rk))
            .filter(|l| mine(l))
            .collect();
        let mut outcomes: Vec<Option<Outcome>> = vec![None; ids];
        let mut stats = TileStats::default();
        loop {
            let part = trace_tiled_with(
                &self.u,
                self.boundary.index(),
                &self.tiling,
                &self.rk,
                &self.ball,
                std::mem::take(&mut inbox),
                ids,
                false,
                progress,
                decomp,
            )?;
            for (o, got) in outcomes.iter_mut().zip(part.outcomes) {
                if got.is_some() {
                    *o = got;
                }
            }
            stats.rounds += part.stats.rounds;
            stats.tiles_built += part.stats.tiles_built;
            stats.tiles_distinct += part.stats.tiles_distinct;
            stats.chunks_decoded += part.stats.chunks_decoded;
            stats.handoffs += part.stats.handoffs;
            let mut away = Vec::with_capacity(part.away.len() * LINE);
            for l in &part.away {
                put_line(&mut away, l);
            }
            let all = decomp.all_gather_bytes(away)?;
            if all.iter().all(Vec::is_empty) {
                break;
            }
            inbox = all
                .iter()
                .flat_map(|b| b.chunks_exact(LINE).map(line_at))
                .filter(|l| mine(l))
                .collect();
        }
        // Every outcome to every rank; the counters summed.
        let mut done = Vec::new();
        for (id, o) in outcomes.iter().enumerate() {
            if let Some(o) = o {
                put_outcome(&mut done, id as u32, o);
            }
        }
        for v in [
            stats.rounds,
            stats.tiles_built,
            stats.tiles_distinct,
            stats.chunks_decoded,
            stats.handoffs,
        ] {
            done.extend_from_slice(&v.to_le_bytes());
        }
        let all = decomp.all_gather_bytes(done)?;
        let mut out: Vec<Option<Outcome>> = vec![None; ids];
        let mut sum = [0u64; 5];
        for b in &all {
            let (lines, counters) = b.split_at(b.len() - 40);
            for c in lines.chunks_exact(OUTCOME) {
                let (id, o) = outcome_at(c);
                out[id as usize] = Some(o);
            }
            for (k, s) in sum.iter_mut().enumerate() {
                *s += u64::from_le_bytes(counters[k * 8..k * 8 + 8].try_into().expect("8"));
            }
        }
        let stats = TileStats {
            rounds: sum[0],
            tiles_built: sum[1],
            tiles_distinct: sum[2],
            chunks_decoded: sum[3],
            handoffs: sum[4],
        };
        let out = out
            .into_iter()
            .enumerate()
            .map(|(i, o)| {
                o.ok_or_else(|| GridError::Ranks(format!("streamline {i} ended on no rank")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok((out, None, stats))
    }
}
