//! Stage records in the run's attributes (`harmap.stages.<name>`), read back by type,
//! and the staleness of a stage whose inputs changed after it ran.
//!
//! Each record holds the stage's status, seconds, options and result, and `inputs`: the
//! digest of every stage whose outputs it read ([`inputs_of`]), taken when it finished.
//! A stage's digest ([`stage_digest`]) covers its options and its own inputs (for the
//! voxelization: the input file's sha256, the grid and the center), so it changes when
//! the stage is run again with other options or on other inputs, and not when it is run
//! again alike (the stages are deterministic: the same inputs and options give the same
//! bytes). A stage whose recorded input digests differ from the current ones is stale.

use std::collections::BTreeMap;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

use super::{RunDir, RunError};

/// The stages of a run, in pipeline order.
pub const STAGES: [&str; 4] = ["voxelize", "solve", "trace", "map"];

/// The stages whose outputs `stage` reads. The map reads phi (u) and the labels, not
/// the seed table, so a new trace leaves it fresh.
#[must_use]
pub fn inputs_of(stage: &str) -> &'static [&'static str] {
    match stage {
        "solve" => &["voxelize"],
        "trace" | "map" => &["solve"],
        _ => &[],
    }
}

/// One stage's record, `harmap.stages.<name>`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StageRecord {
    /// `done` when the stage finished.
    pub status: String,
    /// Wall-clock seconds.
    #[serde(default)]
    pub seconds: f64,
    /// The options it ran with (as the stage serialized them).
    #[serde(default)]
    pub options: Value,
    /// What it found (the stage's report).
    #[serde(default)]
    pub result: Value,
    /// Digest of each input stage when this one finished (empty in runs of older
    /// harmap versions, which are then never called stale).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub inputs: BTreeMap<String, String>,
}

/// Whether a stage's outputs can be used.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Freshness {
    /// Not run, or not finished.
    Missing,
    /// Done, from the current outputs of its inputs.
    Done,
    /// Done, but an input changed since; why.
    Stale(String),
}

/// The record of `stage` in the attributes `attrs`, if any.
#[must_use]
pub fn stage_record(attrs: &Value, stage: &str) -> Option<StageRecord> {
    let v = attrs.get("stages")?.get(stage)?;
    serde_json::from_value(v.clone()).ok()
}

/// Whether `harmap.stages.<stage>.status` is `done` in the attributes `attrs` (stale
/// or not; see [`freshness`]).
#[must_use]
pub fn stage_done(attrs: &Value, stage: &str) -> bool {
    attrs
        .get("stages")
        .and_then(|s| s.get(stage))
        .and_then(|s| s.get("status"))
        .and_then(Value::as_str)
        == Some("done")
}

/// The result of `stage` read as `T` (a stage's report type, or a struct of the few
/// fields a caller needs), if the stage recorded one that reads as `T`.
#[must_use]
pub fn report_in<T: DeserializeOwned>(attrs: &Value, stage: &str) -> Option<T> {
    let v = attrs.get("stages")?.get(stage)?.get("result")?;
    serde_json::from_value(v.clone()).ok()
}

/// The options of `stage` read as `T`, if recorded and readable as `T`.
#[must_use]
pub fn options_in<T: DeserializeOwned>(attrs: &Value, stage: &str) -> Option<T> {
    let v = attrs.get("stages")?.get(stage)?.get("options")?;
    serde_json::from_value(v.clone()).ok()
}

/// The digest of what `stage` produced (see the module docs), if it is done.
#[must_use]
pub fn stage_digest(attrs: &Value, stage: &str) -> Option<String> {
    if !stage_done(attrs, stage) {
        return None;
    }
    let rec = attrs.get("stages")?.get(stage)?;
    let mut v = json!({
        "stage": stage,
        "options": rec.get("options"),
        "inputs": rec.get("inputs"),
    });
    if stage == "voxelize" {
        v["input"] = attrs.get("input").cloned().unwrap_or(Value::Null);
        v["grid"] = attrs.get("grid").cloned().unwrap_or(Value::Null);
        v["center"] = attrs.get("center").cloned().unwrap_or(Value::Null);
    }
    Some(hex(&Sha256::digest(v.to_string().as_bytes())))
}

/// The digests of the inputs of `stage`, as they are now (what [`RunDir::record_stage`]
/// stores).
#[must_use]
pub fn input_digests(attrs: &Value, stage: &str) -> BTreeMap<String, String> {
    inputs_of(stage)
        .iter()
        .filter_map(|d| Some(((*d).to_owned(), stage_digest(attrs, d)?)))
        .collect()
}

/// Whether `stage` is missing, done, or done but stale (an input was run again with
/// other options since, or is itself stale, or is gone).
#[must_use]
pub fn freshness(attrs: &Value, stage: &str) -> Freshness {
    if !stage_done(attrs, stage) {
        return Freshness::Missing;
    }
    let Some(rec) = stage_record(attrs, stage) else {
        return Freshness::Done;
    };
    if rec.inputs.is_empty() {
        return Freshness::Done;
    }
    for d in inputs_of(stage) {
        match freshness(attrs, d) {
            Freshness::Missing => {
                return Freshness::Stale(format!("{d} is not done any more"));
            }
            Freshness::Stale(why) => {
                return Freshness::Stale(format!("{d} is out of date ({why})"));
            }
            Freshness::Done => {}
        }
        if let Some(recorded) = rec.inputs.get(*d) {
            if stage_digest(attrs, d).as_ref() != Some(recorded) {
                return Freshness::Stale(format!("{d} was run again with other options after it"));
            }
        }
    }
    Freshness::Done
}

/// The stages that are done but stale, with why, in pipeline order.
#[must_use]
pub fn stale_stages(attrs: &Value) -> Vec<(&'static str, String)> {
    STAGES
        .iter()
        .filter_map(|s| match freshness(attrs, s) {
            Freshness::Stale(why) => Some((*s, why)),
            _ => None,
        })
        .collect()
}

fn hex(b: &[u8]) -> String {
    use std::fmt::Write as _;
    b.iter().fold(String::new(), |mut s, x| {
        let _ = write!(s, "{x:02x}");
        s
    })
}

impl RunDir {
    /// Record stage `name` as done: `harmap.stages.<name>` = status, seconds, options,
    /// result, and the digests of its inputs (which later tell whether it is stale).
    pub fn record_stage(
        &self,
        name: &str,
        seconds: f64,
        options: impl Serialize,
        result: impl Serialize,
    ) -> Result<(), RunError> {
        let options = serde_json::to_value(options).unwrap_or(Value::Null);
        let result = serde_json::to_value(result).unwrap_or(Value::Null);
        let peak = peak_rss();
        self.update_attrs(|a| {
            let now = Value::Object(a.clone());
            let inputs = input_digests(&now, name);
            let stages = a.entry("stages").or_insert_with(|| json!({}));
            stages[name] = json!({
                "status": "done",
                "seconds": seconds,
                "options": options,
                "result": result,
                "inputs": inputs,
            });
            if let Some(peak) = peak {
                stages[name]["peak_rss_bytes"] = json!(peak);
            }
        })
    }

    /// The attributes, when stage `stage` is done and not stale; else the error that
    /// names it and says what to run.
    pub fn require_stage(&self, stage: &str) -> Result<Value, RunError> {
        let attrs = self.attrs()?;
        match freshness(&attrs, stage) {
            Freshness::Done => Ok(attrs),
            Freshness::Missing => Err(RunError::StageMissing {
                path: self.root.clone(),
                stage: stage.into(),
            }),
            Freshness::Stale(why) => Err(RunError::StageStale {
                path: self.root.clone(),
                stage: stage.into(),
                why,
            }),
        }
    }

    /// The result of stage `stage` read as `T` (its report type, or a struct of the
    /// fields wanted: unknown fields are ignored).
    pub fn stage_report<T: DeserializeOwned>(&self, stage: &str) -> Result<T, RunError> {
        let attrs = self.attrs()?;
        let v = attrs
            .get("stages")
            .and_then(|s| s.get(stage))
            .and_then(|s| s.get("result"))
            .ok_or_else(|| RunError::StageMissing {
                path: self.root.clone(),
                stage: stage.into(),
            })?;
        serde_json::from_value(v.clone()).map_err(|e| RunError::NotARun {
            path: self.root.clone(),
            reason: format!("the {stage} stage's result does not read: {e}"),
        })
    }

    /// `Err` when `stage` is done but stale (a missing stage is left to the caller,
    /// which may have its own message for it): what reads a stage's outputs calls it.
    pub fn refuse_stale(&self, stage: &str) -> Result<(), RunError> {
        match freshness(&self.attrs()?, stage) {
            Freshness::Stale(why) => Err(RunError::StageStale {
                path: self.root.clone(),
                stage: stage.into(),
                why,
            }),
            _ => Ok(()),
        }
    }

    /// The freshness of `stage` (see [`freshness`]).
    pub fn freshness(&self, stage: &str) -> Result<Freshness, RunError> {
        Ok(freshness(&self.attrs()?, stage))
    }
}

/// The process's peak resident memory so far, bytes (Linux `VmHWM` of
/// /proc/self/status); None elsewhere or when /proc cannot be read. For a stage run
/// alone by its subcommand this is the stage's peak; in `harmap run`, the largest of
/// the stages so far. The kernel's high-water mark is not reset between stages: that
/// would also hide the process's true peak from `/usr/bin/time` and the benchmarks.
#[must_use]
pub fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_with(stages: &Value) -> Value {
        json!({"input": {"sha256": "ab"}, "grid": {"shape": [1, 1, 1]}, "stages": stages.clone()})
    }

    /// A stage recorded after its input is fresh; the input run again with other
    /// options makes it (and what reads it) stale; run again alike, it is fresh again.
    #[test]
    fn a_changed_input_makes_the_stages_after_it_stale() {
        let mut a = run_with(&json!({"voxelize": {"status": "done", "options": {"r": 1}}}));
        let solve = |a: &Value, rtol: f64| json!({"status": "done", "options": {"rtol": rtol}, "inputs": input_digests(a, "solve")});
        a["stages"]["solve"] = solve(&a, 1e-6);
        a["stages"]["trace"] =
            json!({"status": "done", "options": {}, "inputs": input_digests(&a, "trace")});
        assert_eq!(freshness(&a, "solve"), Freshness::Done);
        assert_eq!(freshness(&a, "trace"), Freshness::Done);
        assert_eq!(freshness(&a, "map"), Freshness::Missing);
        assert!(stale_stages(&a).is_empty());

        a["stages"]["solve"] = solve(&a, 1e-3);
        assert_eq!(freshness(&a, "solve"), Freshness::Done);
        let Freshness::Stale(why) = freshness(&a, "trace") else {
            panic!("trace should be stale");
        };
        assert!(why.contains("solve was run again"), "{why}");
        assert_eq!(stale_stages(&a).len(), 1);

        a["stages"]["solve"] = solve(&a, 1e-6);
        assert_eq!(freshness(&a, "trace"), Freshness::Done);

        // The voxelization's input file changed: everything after it is stale.
        a["input"]["sha256"] = json!("cd");
        assert!(matches!(freshness(&a, "solve"), Freshness::Stale(_)));
        assert!(
            matches!(freshness(&a, "trace"), Freshness::Stale(w) if w.contains("solve is out of date"))
        );
    }

    /// Records of older versions (no inputs) are never stale; a typed report reads the
    /// fields it names.
    #[test]
    fn old_records_are_fresh_and_reports_read_by_type() {
        #[derive(Deserialize)]
        struct Few {
            iterations: u64,
        }
        let a = run_with(&json!({
            "voxelize": {"status": "done", "options": {}},
            "solve": {"status": "done", "seconds": 2.5, "result": {"iterations": 7, "other": 1}}
        }));
        assert_eq!(freshness(&a, "solve"), Freshness::Done);
        assert_eq!(report_in::<Few>(&a, "solve").unwrap().iterations, 7);
        assert!(report_in::<Few>(&a, "trace").is_none());
        assert!((stage_record(&a, "solve").unwrap().seconds - 2.5).abs() < 1e-12);
    }
}
