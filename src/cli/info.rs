//! `harmap info`.

use std::io::Write;
use std::path::PathBuf;

use harmap::run::stages::{
    freshness, options_in, report_in, stage_record, stale_stages, Freshness,
};
use harmap::run::RunDir;
use harmap::trace::{SeedKind, TraceOptions};
use harmap::voxelize::labels::NAMES;
use harmap::voxelize::{ProbeTrial, TopologyRepair};
use serde_json::{json, Value};

use super::Global;

/// Describe a run: grid, labels, center, topology, input, stages and timings.
///
/// With --json, print the run's group attributes ("harmap") and a summary per stage as
/// one JSON object, for scripts.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run directory.
    pub run: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// The line that says where a stage's field took its boundary values from (`result`'s
/// `boundary`), if it recorded it.
fn boundary_line(out: &mut impl Write, label: &str, result: &Value) -> std::io::Result<()> {
    match result.get("boundary").and_then(Value::as_str) {
        Some(b) => writeln!(out, "{label} boundary nodes' sub-voxel values from the {b}"),
        None => Ok(()),
    }
}

fn summary(attrs: &Value) -> Value {
    let stale: serde_json::Map<String, Value> = stale_stages(attrs)
        .into_iter()
        .map(|(stage, why)| (stage.to_owned(), json!(why)))
        .collect();
    let mut s = json!({ "stale": stale });
    if let Some(v) = report_in::<Value>(attrs, "voxelize") {
        let counts: Vec<u64> = v["counts"]
            .as_array()
            .map(|a| a.iter().filter_map(Value::as_u64).collect())
            .unwrap_or_default();
        let by_name: serde_json::Map<String, Value> = NAMES
            .iter()
            .zip(&counts)
            .map(|(n, c)| ((*n).to_owned(), json!(c)))
            .collect();
        s["voxelize"] = json!({
            "status": stage_record(attrs, "voxelize").map(|r| r.status),
            "seconds": stage_record(attrs, "voxelize").map(|r| r.seconds),
            "labels": by_name,
            "euler_characteristic": v["euler_characteristic"],
            "genus": v["genus"],
            "components": v["components"],
            "cavities_filled": v["cavities_filled"],
            "probe_cavities": v.get("probe_cavities").cloned().unwrap_or(json!(0)),
            "closing_voxels": v.get("closing_voxels").cloned().unwrap_or(json!(0)),
            "handles": v.get("handles").cloned().unwrap_or(json!([])),
            "repair": v.get("repair").cloned().unwrap_or(Value::Null),
            "center_depth_voxels": v["center_depth"],
            "inside_rule": v["inside_rule"],
        });
    }
    if let Some(v) = report_in::<Value>(attrs, "solve") {
        s["solve"] = json!({
            "status": stage_record(attrs, "solve").map(|r| r.status),
            "seconds": stage_record(attrs, "solve").map(|r| r.seconds),
            "method": v["method"],
            "iterations": v["iterations"],
            "stopped_by": v["stopped_by"],
            "relative_residual": v["relative_residual"],
            "max_change": v["max_change"],
            "unknowns": v["unknowns"],
            "residual_history": v["residual_history"],
            "resumed_at": v["resumed_at"],
        });
    }
    if let Some(v) = report_in::<Value>(attrs, "trace") {
        s["trace"] = json!({
            "status": stage_record(attrs, "trace").map(|r| r.status),
            "seconds": stage_record(attrs, "trace").map(|r| r.seconds),
            "seeds": v["seeds"],
            "stops": v["stops"],
            "reached_fraction": v["reached_fraction"],
            "mean_steps": v["mean_steps"],
            "stop_radius": v["stop_radius"],
            "collisions": v["collisions"],
            "indistinguishable": v["indistinguishable"],
            "surface": v["surface"],
        });
    }
    s
}

/// Run `harmap info`.
#[allow(clippy::too_many_lines)] // one summary line per stage and field, in the order they print
pub fn run(a: &Args, _g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    let mut out = std::io::stdout().lock();
    if a.json {
        let doc = json!({"path": run.root(), "harmap": attrs, "summary": summary(&attrs)});
        writeln!(out, "{}", serde_json::to_string_pretty(&doc)?)?;
        return Ok(());
    }
    writeln!(out, "run:      {}", run.root().display())?;
    writeln!(out, "format:   harmap {}", attrs["format_version"])?;
    if let Some(i) = attrs.get("input") {
        let path = i["path"].as_str().map_or_else(
            || format!("built-in {}", i["builtin"].as_str().unwrap_or("?")),
            str::to_owned,
        );
        writeln!(out, "input:    {path}")?;
        if let Some(h) = i["sha256"].as_str() {
            writeln!(out, "sha256:   {h}")?;
        }
    }
    if let Ok(g) = run.grid() {
        writeln!(
            out,
            "grid:     {} x {} x {} (x, y, z) = {} voxels, spacing {}{}",
            g.shape[2],
            g.shape[1],
            g.shape[0],
            g.num_voxels(),
            g.spacing,
            g.unit
                .as_deref()
                .map(|u| format!(" {u}"))
                .unwrap_or_default()
        )?;
        writeln!(
            out,
            "origin:   ({}, {}, {}) (center of voxel [0, 0, 0])",
            g.origin[0], g.origin[1], g.origin[2]
        )?;
    }
    if let (Some(c), Some(v)) = (attrs.get("center"), attrs.get("center_voxel")) {
        let depth = report_in::<Value>(&attrs, "voxelize")
            .and_then(|v| v["center_depth"].as_f64())
            .unwrap_or(f64::NAN);
        writeln!(
            out,
            "center:   {c} = voxel {v} [z, y, x], {depth:.1} voxels deep"
        )?;
    }
    if let Some(v) = report_in::<Value>(&attrs, "voxelize") {
        write!(out, "labels:  ")?;
        if let Some(counts) = v["counts"].as_array() {
            for (n, c) in NAMES.iter().zip(counts) {
                write!(out, " {n} {c}")?;
            }
        }
        writeln!(out)?;
        writeln!(
            out,
            "topology: {} piece(s), genus {}, Euler characteristic {}, {} cavities filled ({} voxels), inside by {}",
            v["components"], v["genus"], v["euler_characteristic"], v["cavities_filled"], v["cavity_voxels"], v["inside_rule"].as_str().unwrap_or("?")
        )?;
        if let Some(r) = v
            .get("repair")
            .and_then(|r| serde_json::from_value::<TopologyRepair>(r.clone()).ok())
        {
            writeln!(out, "repair:   {}", harmap::voxelize::repair_summary(&r))?;
        }
        if let Some(p) = v
            .get("probe_trials")
            .and_then(|t| serde_json::from_value::<Vec<ProbeTrial>>(t.clone()).ok())
            .and_then(|t| harmap::voxelize::probe_summary(&t))
        {
            writeln!(out, "probe:    {p}")?;
        }
        if let Some(n) = v
            .get("probe_cavities")
            .and_then(Value::as_u64)
            .filter(|&n| n > 0)
        {
            writeln!(
                out,
                "ses:      {n} cavities with room for a probe that cannot get in from the solvent, left solid"
            )?;
        }
        if let Some(n) = v
            .get("closing_voxels")
            .and_then(Value::as_u64)
            .filter(|&n| n > 0)
        {
            writeln!(out, "closing: {n} voxels added")?;
        }
        if let Some(h) = v
            .get("handles")
            .and_then(Value::as_array)
            .filter(|h| !h.is_empty())
        {
            let at: Vec<String> = h
                .iter()
                .take(5)
                .map(|h| format!("{} at voxel {}", h["closes"], h["voxel"]))
                .collect();
            writeln!(out, "handles a closing would plug: {}", at.join(", "))?;
        }
    }
    if let Some(stages) = attrs.get("stages").and_then(Value::as_object) {
        for (name, st) in stages {
            let timings = st
                .get("result")
                .and_then(|r| r.get("timings"))
                .and_then(Value::as_array)
                .map(|t| {
                    t.iter()
                        .filter_map(|p| Some(format!("{} {:.2}s", p[0].as_str()?, p[1].as_f64()?)))
                        .collect::<Vec<_>>()
                        .join(", ")
                });
            let stale = match freshness(&attrs, name) {
                Freshness::Stale(why) => format!(", STALE: {why}; run `harmap {name}` again"),
                _ => String::new(),
            };
            writeln!(
                out,
                "stage:    {name} {} in {:.2}s{}{stale}",
                st["status"].as_str().unwrap_or("?"),
                st["seconds"].as_f64().unwrap_or(f64::NAN),
                timings.map(|t| format!(" ({t})")).unwrap_or_default()
            )?;
        }
    }
    if let Some(v) = report_in::<Value>(&attrs, "solve") {
        let hist: Vec<String> = v["residual_history"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(Value::as_f64)
                    .map(|r| format!("{r:.1e}"))
                    .collect()
            })
            .unwrap_or_default();
        writeln!(
            out,
            "solve:    {} {} iterations, stopped by {}: relative residual {:.2e}, largest change {:.2e}, {} unknowns",
            v["method"].as_str().unwrap_or("?"),
            v["iterations"],
            v["stopped_by"].as_str().unwrap_or("?"),
            v["relative_residual"].as_f64().unwrap_or(f64::NAN),
            v["max_change"].as_f64().unwrap_or(f64::NAN),
            v["unknowns"]
        )?;
        writeln!(out, "residual: {}", hist.join(" "))?;
    }
    if let Some(v) = report_in::<Value>(&attrs, "trace") {
        let stops: Vec<String> = v["stops"]
            .as_object()
            .map(|m| m.iter().map(|(k, n)| format!("{k} {n}")).collect())
            .unwrap_or_default();
        writeln!(
            out,
            "trace:    {} seeds ({}), {:.3}% reached the center; {}; {:.1} steps per line, stop radius {} voxels",
            v["seeds"],
            options_in::<TraceOptions>(&attrs, "trace")
                .map_or("?", |o| match o.seeds {
                    SeedKind::Boundary => "boundary",
                    SeedKind::Surface => "surface",
                }),
            100.0 * v["reached_fraction"].as_f64().unwrap_or(f64::NAN),
            stops.join(", "),
            v["mean_steps"].as_f64().unwrap_or(f64::NAN),
            v["stop_radius"]
        )?;
        boundary_line(&mut out, "field:   ", &v)?;
        writeln!(
            out,
            "sphere:   {} seeds within {} degrees of a seed more than {} voxels away",
            v["collisions"]["seeds"], v["collisions"]["angle_deg"], v["collisions"]["far_voxels"],
        )?;
        if let Some(d) = v.get("indistinguishable").filter(|d| !d.is_null()) {
            writeln!(
                out,
                "          {} seeds whose stored arrival directions ({}) equal those of a seed from elsewhere",
                d["seeds"],
                d["precision"].as_str().unwrap_or("?")
            )?;
        }
        if let Some(m) = v.get("surface").filter(|m| !m.is_null()) {
            let q = |k: &str, f: &str| m[k][f].as_f64().unwrap_or(f64::NAN);
            writeln!(
                out,
                "surface:  {} of {} triangles flipped ({} degenerate); log area ratio p05/p50/p95 {:.2}/{:.2}/{:.2}; conformal distortion p50/p95 {:.2}/{:.2}",
                m["flipped"],
                m["measured"],
                m["degenerate"],
                q("log_area_ratio", "p05"),
                q("log_area_ratio", "p50"),
                q("log_area_ratio", "p95"),
                q("conformal", "p50"),
                q("conformal", "p95"),
            )?;
        }
        if let Some(u) = v.get("untangle").filter(|u| !u.is_null()) {
            writeln!(
                out,
                "          untangled from {} flipped and {} degenerate as the streamlines arrived: {} seeds moved, median {:.3} and at most {:.2} degrees ({} regions re-embedded); {} left{}",
                u["flipped_arrivals"],
                u["degenerate_arrivals"],
                u["seeds_moved"],
                u["median_move_deg"].as_f64().unwrap_or(f64::NAN),
                u["max_move_deg"].as_f64().unwrap_or(f64::NAN),
                u["regions"].as_u64().unwrap_or(0),
                u["unresolved"],
                if u["out_of_work"].as_bool() == Some(true) {
                    " (stopped at its work bound)"
                } else {
                    ""
                },
            )?;
        }
    }
    if let Some(v) = report_in::<Value>(&attrs, "map") {
        write!(
            out,
            "map:      {} of {} voxels have (theta, psi) ({}",
            v["mapped"],
            v["voxels"],
            v["method"].as_str().unwrap_or("?")
        )?;
        if let Some(u) = v.get("upwind").filter(|u| !u.is_null()) {
            write!(
                out,
                ": {} from the stop ball, {} upwind, {} filled from neighbours",
                u["from_ball"], u["upwind"], u["filled"]
            )?;
        }
        if let Some(st) = v.get("stops").and_then(Value::as_object) {
            let s: Vec<String> = st.iter().map(|(k, n)| format!("{k} {n}")).collect();
            write!(out, ": {}", s.join(", "))?;
        }
        writeln!(out, "), stop radius {} voxels", v["stop_radius"])?;
        boundary_line(&mut out, "map field:", &v)?;
        if let Some(f) = v
            .get("folded")
            .and_then(|f| serde_json::from_value::<harmap::map::Folded>(f.clone()).ok())
        {
            writeln!(out, "folds:    {}", super::map::folded_line(&f))?;
        }
        if let Some(u) = v
            .get("unfold")
            .and_then(|u| serde_json::from_value::<harmap::map::Unfold>(u.clone()).ok())
        {
            writeln!(out, "          {}", super::map::unfold_line(&u))?;
        }
    }
    Ok(())
}
