//! The report page (`harmap report`, and `harmap run` writing it beside the atlas): one
//! self-contained file, every picture an embedded PNG, the stages' numbers shown.

use std::path::Path;
use std::process::{Command, Output};

fn harmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_harmap"))
        .args(args)
        .output()
        .expect("the harmap binary runs")
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {:?}", c as char),
        }
    };
    let b = s.trim_end_matches('=').as_bytes();
    let mut out = Vec::new();
    for q in b.chunks(4) {
        let mut n = 0u32;
        for (k, &c) in q.iter().enumerate() {
            n |= val(c) << (18 - 6 * k);
        }
        for k in 0..q.len() - 1 {
            out.push((n >> (16 - 8 * k)) as u8);
        }
    }
    out
}

/// Check that `png` is a whole PNG file: the signature, then chunks with right CRCs,
/// IHDR first and IEND last, and image data that inflates. Returns (width, height).
fn check_png(png: &[u8]) -> (u32, u32) {
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    let mut at = 8;
    let mut kinds = Vec::new();
    let mut idat = Vec::new();
    while at < png.len() {
        let len = u32::from_be_bytes(png[at..at + 4].try_into().unwrap()) as usize;
        let kind = &png[at + 4..at + 8];
        let data = &png[at + 8..at + 8 + len];
        let crc = u32::from_be_bytes(png[at + 8 + len..at + 12 + len].try_into().unwrap());
        let mut c = flate2::Crc::new();
        c.update(kind);
        c.update(data);
        assert_eq!(
            c.sum(),
            crc,
            "CRC of chunk {}",
            String::from_utf8_lossy(kind)
        );
        if kind == b"IDAT" {
            idat.extend_from_slice(data);
        }
        kinds.push(String::from_utf8_lossy(kind).into_owned());
        at += 12 + len;
    }
    assert_eq!(kinds.first().map(String::as_str), Some("IHDR"));
    assert_eq!(kinds.last().map(String::as_str), Some("IEND"));
    let mut raw = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(&idat[..]), &mut raw)
        .expect("the image data inflates");
    assert!(!raw.is_empty());
    let w = u32::from_be_bytes(png[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(png[20..24].try_into().unwrap());
    (w, h)
}

/// Every `attr="..."` value in `page`.
fn attr_values<'a>(page: &'a str, attr: &str) -> Vec<&'a str> {
    let pat = format!(" {attr}=\"");
    page.match_indices(&pat)
        .map(|(i, _)| {
            let rest = &page[i + pat.len()..];
            &rest[..rest.find('"').expect("closed attribute")]
        })
        .collect()
}

fn check_self_contained(page: &str) -> usize {
    for attr in ["src", "href"] {
        for v in attr_values(page, attr) {
            assert!(
                v.starts_with("data:"),
                "{attr}=\"{}\" is not embedded",
                &v[..v.len().min(60)]
            );
        }
    }
    assert!(
        !page.contains("http://") && !page.contains("https://"),
        "no URL at all"
    );
    assert!(!page.contains("<script"), "no scripts");
    let imgs = page.matches("<img ").count();
    let srcs: Vec<String> = page
        .split("<img ")
        .skip(1)
        .map(|t| {
            let tag = format!(" {}", &t[..t.find('>').unwrap()]);
            let v = attr_values(&tag, "src");
            assert_eq!(v.len(), 1, "one src per <img>");
            v[0].to_owned()
        })
        .collect();
    assert_eq!(srcs.len(), imgs);
    for s in srcs {
        let b64 = s
            .strip_prefix("data:image/png;base64,")
            .expect("a PNG data URI");
        let (w, h) = check_png(&base64_decode(b64));
        assert!(w > 0 && h > 0);
    }
    imgs
}

#[test]
fn the_starfish_run_writes_a_self_contained_report_beside_its_atlas() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("starfish.harmap");
    let o = harmap(&["run", "-o", run.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page_path = dir.path().join("starfish.report.html");
    let page = std::fs::read_to_string(&page_path).expect("harmap run wrote the report");
    // The atlas, the sphere and three slices of each of phi, theta and psi.
    assert_eq!(check_self_contained(&page), 2 + 9);
    let attrs = harmap::run::RunDir::open(&run).unwrap().attrs().unwrap();
    // The numbers of the run appear on the page.
    let n = |p: &str| attrs.pointer(p).unwrap().to_string();
    for (what, needle) in [
        (
            "genus",
            format!(
                "<td>genus of the solid</td><td>{}</td>",
                n("/stages/voxelize/result/genus")
            ),
        ),
        (
            "iterations",
            format!(
                "<td>iterations</td><td>{}</td>",
                n("/stages/solve/result/iterations")
            ),
        ),
        (
            "flipped triangles",
            format!(
                "<td>flipped on the sphere</td><td>{}</td>",
                n("/stages/trace/result/surface/flipped")
            ),
        ),
        (
            "colliding seeds",
            format!(
                "<td>colliding seeds</td><td>{}</td>",
                n("/stages/trace/result/collisions/seeds")
            ),
        ),
        (
            "folded voxels",
            format!(
                "<td>folded</td><td>{}</td>",
                n("/stages/map/result/folded/voxels")
            ),
        ),
        (
            "folded before unfolding",
            format!(
                "<td>folded_before</td><td>{}</td>",
                n("/stages/map/result/unfold/folded_before")
            ),
        ),
    ] {
        assert!(page.contains(&needle), "{what}: {needle} not on the page");
    }
    // The convergence plot has a point per recorded iteration.
    let hist = attrs
        .pointer("/stages/solve/result/residual_history")
        .unwrap()
        .as_array()
        .unwrap()
        .len();
    let poly = page.split("<polyline").nth(1).expect("a plot line");
    let pts = poly.split("points=\"").nth(1).unwrap();
    assert_eq!(pts[..pts.find('"').unwrap()].split(' ').count(), hist);
    // Every stage records its peak memory on Linux, and the page shows it.
    for s in ["voxelize", "solve", "trace", "map"] {
        let peak = attrs.pointer(&format!("/stages/{s}/peak_rss_bytes"));
        if cfg!(target_os = "linux") {
            assert!(peak.and_then(serde_json::Value::as_u64).unwrap() > 0, "{s}");
        }
    }
    assert!(!page.contains("not recorded"));

    // `harmap report` writes the same page again (-o elsewhere).
    let again = dir.path().join("again.html");
    let o = harmap(&[
        "report",
        run.to_str().unwrap(),
        "-o",
        again.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page2 = std::fs::read_to_string(&again).unwrap();
    assert_eq!(page2, page, "the page depends on the run only");
}

#[test]
fn a_run_only_voxelized_gets_a_page_that_names_the_missing_stages() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("ball.obj");
    let m = crate::common::sphere(harmap::math::Vec3::ZERO, 1.0, 24, 48);
    crate::common::write_obj(&mesh, &m);
    let run = dir.path().join("ball.harmap");
    let o = harmap(&[
        "voxelize",
        mesh.to_str().unwrap(),
        "-o",
        run.to_str().unwrap(),
        "--resolution",
        "32",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = harmap(&["report", run.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page = std::fs::read_to_string(dir.path().join("ball.report.html")).unwrap();
    assert_eq!(
        check_self_contained(&page),
        0,
        "nothing solved: no pictures"
    );
    for stage in ["solve", "trace", "map"] {
        assert!(
            page.contains(&format!("The {stage} stage has not run")),
            "{stage} missing"
        );
    }
    assert!(page.contains(&harmap::input::sha256_file(&mesh).unwrap()));
    // One genus-0 piece: the page says no repair was needed.
    assert!(page.contains("Repair: none"), "no repair line");
    // A mesh: no molecule options.
    assert!(
        !page.contains("<td>probe</td>"),
        "molecule options shown for a mesh"
    );
}

/// A repaired solid gets a visible repair section: what changed, from the record.
#[test]
fn a_repaired_solid_shows_its_repair() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("two.obj");
    let big = crate::common::sphere(harmap::math::Vec3::ZERO, 1.0, 24, 48);
    let speck = crate::common::sphere(harmap::math::Vec3::new(1.6, 0.0, 0.0), 0.2, 8, 16);
    crate::common::write_obj(&mesh, &crate::common::merge(&big, &speck));
    let run = dir.path().join("two.harmap");
    let r = run.to_str().unwrap();
    let o = harmap(&[
        "voxelize",
        mesh.to_str().unwrap(),
        "-o",
        r,
        "--resolution",
        "40",
        "--topology",
        "repair",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = harmap(&["report", r]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page = std::fs::read_to_string(dir.path().join("two.report.html")).unwrap();
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("zarr.json")).unwrap()).unwrap();
    let rep = meta
        .pointer("/attributes/harmap/stages/voxelize/result/repair")
        .expect("the speck is repaired");
    let specks = rep["specks_dropped"].as_u64().unwrap();
    assert!(specks >= 1, "{rep}");
    assert!(
        page.contains("<h3 id=\"repair\">Repair</h3>"),
        "no repair section"
    );
    assert!(
        page.contains(&format!("<td>specks dropped</td><td>{specks}</td>")),
        "specks dropped not shown"
    );
    assert!(
        page.contains("<td>removed</td>"),
        "the changed regions are not listed"
    );
}

#[test]
fn report_of_a_directory_that_is_no_run_is_refused_with_exit_code_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.html");
    let o = harmap(&[
        "report",
        dir.path().to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(&dir.path().display().to_string()), "{err}");
    assert!(!Path::new(&out).exists(), "nothing written");
}
