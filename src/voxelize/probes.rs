//! What a ladder of probe radii gave, in words (see [`super::ProbeTrial`]).

use super::{ProbeTrial, VoxelizeReport};

impl VoxelizeReport {
    /// For a probe ladder: which probe made the solid one genus-0 piece, and what the
    /// others gave, e.g. "genus 0 at probe 3 Angstrom (tried 1.4: genus 156; 2: genus
    /// 60)". `None` when one probe was given.
    #[must_use]
    pub fn probe_summary(&self) -> Option<String> {
        probe_summary(&self.probe_trials)
    }
}

/// What [`VoxelizeReport::probe_summary`] says of these trials.
#[must_use]
pub fn probe_summary(trials: &[ProbeTrial]) -> Option<String> {
    {
        let (kept, tried) = trials.split_last()?;
        let what = |t: &ProbeTrial| {
            if t.components > 1 {
                format!("{}: {} pieces, genus {}", t.probe, t.components, t.genus)
            } else {
                format!("{}: genus {}", t.probe, t.genus)
            }
        };
        let tried: Vec<String> = tried.iter().map(what).collect();
        let tried = if tried.is_empty() {
            String::new()
        } else {
            format!(" (tried {})", tried.join("; "))
        };
        Some(if kept.genus == 0 && kept.components == 1 {
            format!("genus 0 at probe {} Angstrom{tried}", kept.probe)
        } else {
            format!(
                "no probe gave one genus-0 piece{tried}; kept probe {} Angstrom ({})",
                kept.probe,
                what(kept)
            )
        })
    }
}
