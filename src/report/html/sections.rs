//! The sections of the report page, one function each, and the small helpers that turn
//! the run's metadata into table rows.

// Index arithmetic over the grid's axes: z, y, x and i, j, k read as in the formulas.
#![allow(clippy::many_single_char_names)]

use std::fmt::Write as _;

use serde_json::Value;

use super::{escape, plot, png_data_uri, slices, Colormap};
use crate::run::RunDir;

/// Keys of the voxelize result shown in the input, grid and topology tables; any other
/// key (a stage may record more) is shown as it is under "More records".
const VOXELIZE_SHOWN: &[&str] = &[
    "timings",
    "counts",
    "center_voxel",
    "center",
    "center_depth",
    "inside_rule",
    "euler_characteristic",
    "components",
    "genus",
    "cavities_filled",
    "cavity_voxels",
    "probe_cavities",
    "pieces_removed",
    "removed_voxels",
    "closing_voxels",
    "handles",
    "handle_radius",
    "probe_trials",
    "warnings",
    "repair",
    "surface_topology",
];

/// A JSON value as short text: numbers with a sensible precision, arrays inline.
fn text(v: &Value) -> String {
    match v {
        Value::Null => "—".into(),
        Value::String(s) => s.clone(),
        Value::Number(n) => match (n.as_u64(), n.as_i64(), n.as_f64()) {
            (Some(u), _, _) => u.to_string(),
            (None, Some(i), _) => i.to_string(),
            (_, _, Some(f)) => float(f),
            _ => n.to_string(),
        },
        Value::Bool(b) => b.to_string(),
        Value::Array(a) if a.len() <= 12 && a.iter().all(|x| !x.is_object() && !x.is_array()) => {
            format!("[{}]", a.iter().map(text).collect::<Vec<_>>().join(", "))
        }
        _ => serde_json::to_string(v).unwrap_or_default(),
    }
}

fn float(f: f64) -> String {
    if f == 0.0 || !f.is_finite() {
        return f.to_string();
    }
    let a = f.abs();
    if (1e-3..1e6).contains(&a) {
        let s = format!("{f:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        format!("{f:.3e}")
    }
}

/// A two-column table of `(label, value)` rows; values are escaped here.
fn kv(p: &mut String, rows: &[(&str, String)]) {
    p.push_str("<table class=\"kv\">");
    for (k, v) in rows {
        let _ = write!(p, "<tr><td>{}</td><td>{}</td></tr>", escape(k), escape(v));
    }
    p.push_str("</table>\n");
}

/// Any JSON value as nested tables (objects) or text: for records the page does not
/// know by name.
fn generic(p: &mut String, v: &Value) {
    match v {
        Value::Object(m) if !m.is_empty() => {
            p.push_str("<table class=\"kv\">");
            for (k, x) in m {
                let _ = write!(p, "<tr><td>{}</td><td>", escape(k));
                generic(p, x);
                p.push_str("</td></tr>");
            }
            p.push_str("</table>");
        }
        Value::Array(a) if a.iter().any(Value::is_object) => {
            for x in a {
                generic(p, x);
            }
        }
        _ => p.push_str(&escape(&text(v))),
    }
}

fn at<'a>(v: &'a Value, ptr: &str) -> &'a Value {
    v.pointer(ptr).unwrap_or(&Value::Null)
}

fn missing(p: &mut String, title: &str, stage: &str) {
    let _ = writeln!(
        p,
        "<section><h2>{title}</h2><p class=\"note\">The {stage} stage has not run on this \
         run yet (<code>harmap {stage} RUN</code> runs it).</p></section>"
    );
}

pub(super) fn input_section(p: &mut String, a: &Value) {
    let i = at(a, "/input");
    p.push_str("<section id=\"input\"><h2>Input</h2>");
    let path = match (i.get("path"), i.get("builtin")) {
        (_, Some(b)) if !b.is_null() => format!("built-in {}", text(b)),
        (Some(v), _) => text(v),
        _ => "—".into(),
    };
    let mut rows = vec![
        ("path", path),
        ("format", text(at(i, "/format"))),
        ("sha256", text(at(i, "/sha256"))),
    ];
    if let Some(m) = i.get("molecule").filter(|m| !m.is_null()) {
        rows.push(("molecule reading", text(m)));
    }
    kv(p, &rows);
    p.push_str("</section>\n");
}

pub(super) fn grid_section(p: &mut String, a: &Value) {
    let g = at(a, "/grid");
    let r = at(a, "/stages/voxelize/result");
    let o = at(a, "/stages/voxelize/options");
    p.push_str("<section id=\"grid\"><h2>Grid</h2><div class=\"row\"><div>");
    let shape = g
        .get("shape")
        .and_then(Value::as_array)
        .map(|s| s.iter().map(text).collect::<Vec<_>>());
    let unit = g
        .get("unit")
        .and_then(Value::as_str)
        .unwrap_or("mesh units")
        .to_owned();
    let mut rows = vec![
        (
            "voxels (x × y × z)",
            shape.map_or_else(String::new, |s| {
                if s.len() == 3 {
                    format!("{} × {} × {}", s[2], s[1], s[0])
                } else {
                    s.join(" × ")
                }
            }),
        ),
        ("spacing", format!("{} {unit}", text(at(g, "/spacing")))),
        ("origin (x, y, z)", text(at(g, "/origin"))),
        ("chunk (z, y, x)", text(at(g, "/chunk"))),
        ("center (x, y, z)", text(at(a, "/center"))),
        ("center voxel (z, y, x)", text(at(a, "/center_voxel"))),
        ("center depth, voxels", text(at(r, "/center_depth"))),
        ("inside rule", text(at(r, "/inside_rule"))),
    ];
    // The molecule options (solid kind, probe) mean nothing for meshes and volumes.
    let molecule = at(a, "/input/format")
        .as_str()
        .is_some_and(crate::input::molecule::is_molecule);
    for k in ["resolution", "padding", "center_radius", "surface", "probe"] {
        if !molecule && matches!(k, "surface" | "probe") {
            continue;
        }
        if let Some(v) = o.get(k).filter(|v| !v.is_null()) {
            rows.push((k, text(v)));
        }
    }
    kv(p, &rows);
    p.push_str("</div>");
    if let Some(c) = r.get("counts").and_then(Value::as_array) {
        p.push_str("<table><tr><th>label</th><th>voxels</th></tr>");
        for (k, n) in c.iter().enumerate() {
            let name = crate::voxelize::labels::NAMES
                .get(k)
                .copied()
                .unwrap_or("other");
            let _ = write!(
                p,
                "<tr><td>{name}</td><td class=\"n\">{}</td></tr>",
                escape(&text(n))
            );
        }
        p.push_str("</table>");
    }
    p.push_str("</div></section>\n");
}

pub(super) fn topology_section(p: &mut String, a: &Value) {
    let r = at(a, "/stages/voxelize/result");
    p.push_str("<section id=\"topology\"><h2>Topology and repair</h2>");
    let mut rows = vec![
        ("genus of the solid", text(at(r, "/genus"))),
        ("pieces of the solid", text(at(r, "/components"))),
        ("Euler characteristic", text(at(r, "/euler_characteristic"))),
    ];
    for (label, key) in [
        ("cavities filled", "cavities_filled"),
        ("cavity voxels", "cavity_voxels"),
        ("probe cavities", "probe_cavities"),
        ("pieces removed by --keep-largest", "pieces_removed"),
        ("voxels removed by --keep-largest", "removed_voxels"),
        ("voxels added by closing", "closing_voxels"),
        ("handle search radius", "handle_radius"),
    ] {
        if let Some(v) = r.get(key) {
            rows.push((label, text(v)));
        }
    }
    kv(p, &rows);
    super::repair::repair_part(p, a);
    if let Some(h) = r
        .get("handles")
        .and_then(Value::as_array)
        .filter(|h| !h.is_empty())
    {
        p.push_str("<p>Handles found:</p>");
        generic(p, &Value::Array(h.clone()));
    }
    if let Some(t) = r
        .get("probe_trials")
        .and_then(Value::as_array)
        .filter(|t| !t.is_empty())
    {
        p.push_str("<table><tr><th>probe</th><th>genus</th><th>pieces</th></tr>");
        for x in t {
            let _ = write!(
                p,
                "<tr><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
                escape(&text(at(x, "/probe"))),
                escape(&text(at(x, "/genus"))),
                escape(&text(at(x, "/components")))
            );
        }
        p.push_str("</table>");
    }
    if let Some(w) = r
        .get("warnings")
        .and_then(Value::as_array)
        .filter(|w| !w.is_empty())
    {
        p.push_str("<ul class=\"warn\">");
        for x in w {
            let _ = write!(p, "<li>{}</li>", escape(&text(x)));
        }
        p.push_str("</ul>");
    }
    // Whatever else the voxelization recorded (a repair record, say), as it is.
    if let Some(m) = r.as_object() {
        let more: serde_json::Map<String, Value> = m
            .iter()
            .filter(|(k, _)| !VOXELIZE_SHOWN.contains(&k.as_str()))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        if !more.is_empty() {
            p.push_str("<h3>More records</h3>");
            generic(p, &Value::Object(more));
        }
    }
    p.push_str("</section>\n");
}

pub(super) fn solve_section(p: &mut String, a: &Value) {
    if !crate::run::stage_done(a, "solve") {
        missing(p, "Solve", "solve");
        return;
    }
    let r = at(a, "/stages/solve/result");
    let o = at(a, "/stages/solve/options");
    p.push_str("<section id=\"solve\"><h2>Solve</h2><div class=\"row\"><div>");
    kv(
        p,
        &[
            ("method", text(at(r, "/method"))),
            ("iterations", text(at(r, "/iterations"))),
            ("stopped by", text(at(r, "/stopped_by"))),
            ("relative residual", text(at(r, "/relative_residual"))),
            ("largest change", text(at(r, "/max_change"))),
            ("unknowns", text(at(r, "/unknowns"))),
            ("rtol", text(at(o, "/rtol"))),
            ("iteration limit", text(at(o, "/max_iter"))),
            ("resumed at", text(at(r, "/resumed_at"))),
            ("checkpoints", text(at(r, "/checkpoints"))),
        ],
    );
    p.push_str("</div><div>");
    let nums = |ptr: &str| -> Vec<f64> {
        at(r, ptr)
            .as_array()
            .map(|v| v.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect())
            .unwrap_or_default()
    };
    let res = nums("/residual_history");
    let chg = nums("/max_change_history");
    let svg = plot::log_history(
        &[
            plot::Series {
                name: "relative residual",
                color: "#1f77b4",
                values: &res,
            },
            plot::Series {
                name: "largest change",
                color: "#e15759",
                values: &chg,
            },
        ],
        at(o, "/rtol").as_f64(),
    );
    match svg {
        Some(s) => {
            p.push_str("<figure>");
            p.push_str(&s);
            p.push_str(
                "<figcaption>Convergence: the relative residual ‖r‖₂/‖r₀‖₂ and the largest \
                 change of phi per iteration (log scale); dashed: the stop tolerance.\
                 </figcaption></figure>",
            );
        }
        None => p.push_str("<p class=\"note\">No residual history recorded.</p>"),
    }
    p.push_str("</div></div>");
    if let Some(pol) = r.get("polish").filter(|v| !v.is_null()) {
        p.push_str("<h3>Polish</h3>");
        generic(p, pol);
    }
    p.push_str("</section>\n");
}

pub(super) fn trace_section(p: &mut String, a: &Value) {
    if !crate::run::stage_done(a, "trace") {
        missing(p, "Trace", "trace");
        return;
    }
    let r = at(a, "/stages/trace/result");
    p.push_str("<section id=\"trace\"><h2>Trace</h2><div class=\"row\"><div>");
    let pct = at(r, "/reached_fraction")
        .as_f64()
        .map_or_else(|| "—".into(), |f| format!("{:.3} %", 100.0 * f));
    kv(
        p,
        &[
            ("seeds", text(at(a, "/stages/trace/options/seeds"))),
            ("streamlines", text(at(r, "/seeds"))),
            ("reached the center", pct),
            ("mean steps", text(at(r, "/mean_steps"))),
            ("mean length, voxels", text(at(r, "/mean_length"))),
            ("stop radius, voxels", text(at(r, "/stop_radius"))),
            ("colliding seeds", text(at(r, "/collisions/seeds"))),
            (
                "collision rule",
                format!(
                    "arrival directions within {}° from seeds more than {} voxels apart",
                    text(at(r, "/collisions/angle_deg")),
                    text(at(r, "/collisions/far_voxels"))
                ),
            ),
            ("field", text(at(r, "/field"))),
            ("boundary", text(at(r, "/boundary"))),
        ],
    );
    p.push_str("</div><div><table><tr><th>stop reason</th><th>lines</th></tr>");
    if let Some(s) = r.get("stops").and_then(Value::as_object) {
        for (k, v) in s {
            let _ = write!(
                p,
                "<tr><td>{}</td><td class=\"n\">{}</td></tr>",
                escape(&k.replace('_', " ")),
                escape(&text(v))
            );
        }
    }
    p.push_str("</table></div>");
    let s = at(r, "/surface");
    if s.is_null() {
        p.push_str(
            "<div><p class=\"note\">No surface measures: the seeds were not a surface \
             (boundary seeds).</p></div>",
        );
    } else {
        p.push_str("<div>");
        kv(
            p,
            &[
                ("surface triangles", text(at(s, "/triangles"))),
                ("measured", text(at(s, "/measured"))),
                ("flipped on the sphere", text(at(s, "/flipped"))),
                ("degenerate", text(at(s, "/degenerate"))),
            ],
        );
        let u = at(r, "/untangle");
        if !u.is_null() {
            kv(
                p,
                &[
                    (
                        "flipped as the streamlines arrived (before untangling)",
                        text(at(u, "/flipped_arrivals")),
                    ),
                    ("seeds moved by untangling", text(at(u, "/seeds_moved"))),
                    ("median move, degrees", text(at(u, "/median_move_deg"))),
                    ("largest move, degrees", text(at(u, "/max_move_deg"))),
                ],
            );
        }
        p.push_str(
            "<table><tr><th>distortion</th><th>p05</th><th>p50</th><th>p95</th><th>max</th></tr>",
        );
        for (label, key) in [
            ("log area ratio", "log_area_ratio"),
            ("conformal (σ₁/σ₂)", "conformal"),
        ] {
            let q = at(s, &format!("/{key}"));
            let _ = write!(p, "<tr><td>{label}</td>");
            for k in ["p05", "p50", "p95", "max"] {
                let _ = write!(
                    p,
                    "<td class=\"n\">{}</td>",
                    escape(&text(at(q, &format!("/{k}"))))
                );
            }
            p.push_str("</tr>");
        }
        p.push_str("</table></div>");
    }
    p.push_str("</div></section>\n");
}

pub(super) fn map_section(p: &mut String, a: &Value) {
    if !crate::run::stage_done(a, "map") {
        missing(p, "Map", "map");
        return;
    }
    let r = at(a, "/stages/map/result");
    p.push_str("<section id=\"map\"><h2>Map</h2>");
    kv(
        p,
        &[
            ("method", text(at(r, "/method"))),
            ("voxels", text(at(r, "/voxels"))),
            ("mapped", text(at(r, "/mapped"))),
            ("stop radius, voxels", text(at(r, "/stop_radius"))),
            ("boundary", text(at(r, "/boundary"))),
        ],
    );
    // The folded voxels (negative Jacobian outside the stop ball) and the unfolding.
    let folded = at(r, "/folded");
    if !folded.is_null() {
        p.push_str("<h3>folded voxels</h3>");
        let clusters = folded
            .get("clusters")
            .and_then(Value::as_array)
            .map_or_else(String::new, |c| {
                c.iter()
                    .take(5)
                    .map(|k| format!("{} at {}", text(at(k, "/voxels")), text(at(k, "/center"))))
                    .collect::<Vec<_>>()
                    .join("; ")
            });
        kv(
            p,
            &[
                ("measured", text(at(folded, "/measured"))),
                ("folded", text(at(folded, "/voxels"))),
                ("degenerate", text(at(folded, "/degenerate"))),
                ("largest clusters (voxels at x, y, z)", clusters),
            ],
        );
    }
    for k in ["unfold", "upwind", "stops"] {
        if let Some(v) = r.get(k).filter(|v| !v.is_null()) {
            let _ = write!(p, "<h3>{k}</h3>");
            generic(p, v);
        }
    }
    p.push_str("</section>\n");
}

/// The atlas and the sphere view, drawn by [`crate::report::atlas`] into a private temporary
/// directory and embedded.
pub(super) fn pictures_section(p: &mut String, run: &RunDir, a: &Value) {
    if !crate::run::stage_done(a, "trace") {
        return;
    }
    p.push_str("<section id=\"pictures\"><h2>Atlas and sphere</h2>");
    let by = crate::report::default_coloring(a);
    for (sphere, caption) in [
        (
            false,
            "The θ–ψ atlas: where each seed's streamline arrives at the center ball.",
        ),
        (true, "The mapped sphere from four viewpoints."),
    ] {
        match draw(run, sphere, &by) {
            Ok(png) => {
                let _ = write!(
                    p,
                    "<figure><img class=\"photo\" alt=\"{}\" src=\"{}\"><figcaption>{caption}</figcaption></figure>",
                    if sphere { "sphere view" } else { "atlas" },
                    png_data_uri(&png)
                );
            }
            Err(e) => {
                let _ = write!(
                    p,
                    "<p class=\"warn\">{}</p>",
                    escape(&format!("Not drawn: {e}"))
                );
            }
        }
    }
    p.push_str("</section>\n");
}

fn draw(run: &RunDir, sphere: bool, by: &crate::report::ColorBy) -> Result<Vec<u8>, crate::Error> {
    let io = |e: std::io::Error| {
        crate::Error::from(crate::report::ReportError::Unavailable(format!(
            "a temporary file for the picture: {e}"
        )))
    };
    let dir = tempfile::tempdir().map_err(io)?;
    let png = dir.path().join("picture.png");
    match crate::report::atlas(run, &png, sphere, by) {
        Ok(_) => {}
        // A molecule's residues need its file; the main axis colors it otherwise.
        Err(e) if *by != crate::report::ColorBy::Axis && e.is_bad_input() => {
            crate::report::atlas(run, &png, sphere, &crate::report::ColorBy::Axis)?;
        }
        Err(e) => return Err(e),
    }
    std::fs::read(&png).map_err(io)
}

/// A field of the slices: its name, the stage that writes it, its colors, the ends of
/// its color bar and what it is.
type SliceField<'a> = (&'a str, &'a str, Colormap, (&'a str, &'a str), &'a str);

pub(super) fn slices_section(p: &mut String, run: &RunDir, a: &Value) {
    let Some(c) = a
        .get("center_voxel")
        .and_then(Value::as_array)
        .filter(|c| c.len() == 3)
        .map(|c| [0, 1, 2].map(|k| c[k].as_u64().unwrap_or(0)))
    else {
        return;
    };
    let pi = std::f64::consts::PI;
    let fields: [SliceField<'_>; 3] = [
        (
            "phi",
            "solve",
            Colormap::Viridis { lo: 0.0, hi: 1.0 },
            ("0 (center)", "1 (boundary)"),
            "the harmonic function",
        ),
        (
            "theta",
            "map",
            Colormap::Viridis { lo: 0.0, hi: pi },
            ("0", "π"),
            "polar angle of the arrival direction",
        ),
        (
            "psi",
            "map",
            Colormap::Cyclic,
            ("−π", "π"),
            "azimuth of the arrival direction (cyclic colors)",
        ),
    ];
    p.push_str(
        "<section id=\"slices\"><h2>Slices through the center voxel</h2>\
         <p class=\"note\">Light gray: outside the problem or not mapped.</p>",
    );
    for (name, stage, map, (lo, hi), what) in fields {
        if !crate::run::stage_done(a, stage) || !run.has_image(name) {
            let _ = write!(p, "<p class=\"note\">{name}: not computed yet.</p>");
            continue;
        }
        let got = match run.image_data_type(name).as_deref() {
            Ok("float64") => slices::center_slices::<f64>(run, name, c, map),
            Ok(_) => slices::center_slices::<f32>(run, name, c, map),
            Err(e) => Err(crate::Error::from(crate::report::ReportError::Unavailable(
                e.to_string(),
            ))),
        };
        let _ = write!(p, "<h3>{name}: {what}</h3><div class=\"row\">");
        match got {
            Ok(sl) => {
                for s in sl {
                    let _ = write!(
                        p,
                        "<figure><img alt=\"{name} {plane}\" width=\"{w}\" height=\"{h}\" src=\"{uri}\"><figcaption>{plane}</figcaption></figure>",
                        plane = escape(&s.plane),
                        w = s.size.0,
                        h = s.size.1,
                        uri = png_data_uri(&s.png)
                    );
                }
                let _ = write!(
                    p,
                    "<figure><div class=\"bar\" style=\"background:{}\"></div><div class=\"ends\"><span>{lo}</span><span>{hi}</span></div><figcaption>{name}</figcaption></figure>",
                    map.css_gradient()
                );
            }
            Err(e) => {
                let _ = write!(p, "<p class=\"warn\">{}</p>", escape(&e.to_string()));
            }
        }
        p.push_str("</div>");
    }
    p.push_str("</section>\n");
}

pub(super) fn timings_section(p: &mut String, a: &Value) {
    p.push_str(
        "<section id=\"timings\"><h2>Time and memory</h2><table><tr><th>stage</th>\
         <th>seconds</th><th>peak resident memory</th></tr>",
    );
    let mut any_peak = false;
    let mut total = 0.0;
    if let Some(st) = a.get("stages").and_then(Value::as_object) {
        for (name, s) in st {
            let secs = s.get("seconds").and_then(Value::as_f64);
            total += secs.unwrap_or(0.0);
            let peak = s.get("peak_rss_bytes").and_then(Value::as_u64);
            any_peak |= peak.is_some();
            let _ = write!(
                p,
                "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
                escape(name),
                secs.map_or_else(|| "—".into(), |x| format!("{x:.2}")),
                peak.map_or_else(|| "not recorded".into(), crate::grid::human)
            );
        }
    }
    let _ = write!(
        p,
        "<tr><th>total</th><th class=\"n\">{total:.2}</th><th></th></tr></table>"
    );
    p.push_str(if any_peak {
        "<p class=\"note\">Peak memory: the process's peak resident set during the stage \
         (Linux; a stage run in a process that had already held more shows no less).</p>"
    } else {
        "<p class=\"note\">This run's stages did not record their peak memory (runs made \
         by older versions).</p>"
    });
    if let Some(t) = at(a, "/stages/voxelize/result/timings")
        .as_array()
        .filter(|t| !t.is_empty())
    {
        p.push_str("<table><tr><th>voxelize step</th><th>seconds</th></tr>");
        for x in t {
            let _ = write!(
                p,
                "<tr><td>{}</td><td class=\"n\">{}</td></tr>",
                escape(&text(at(x, "/0"))),
                at(x, "/1")
                    .as_f64()
                    .map_or_else(|| "—".into(), |s| format!("{s:.3}"))
            );
        }
        p.push_str("</table>");
    }
    p.push_str("</section>\n");
}
