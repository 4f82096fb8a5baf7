//! Options that would run but mean nothing, refused before a stage starts: the stage
//! commands and [`super::run`] call these, so both refuse alike (exit code 2).

use serde::Deserialize;
use serde_json::Value;

use crate::solve::{SolveError, SolveOptions};
use crate::trace::TraceError;

/// Refuse solve options whose result would mean nothing: a relative residual target
/// that is not below 1 (the start is 1: the solve would stop at once), not a finite
/// number or negative; a negative or non-finite change target; no iterations.
pub fn check_solve(o: &SolveOptions) -> Result<(), crate::Error> {
    let bad = |m: String| Err(SolveError::Options(m).into());
    if !(o.rtol.is_finite() && (0.0..1.0).contains(&o.rtol)) {
        return bad(format!(
            "--rtol {}: the relative residual starts at 1, so a target must lie in [0, 1) to mean anything; give e.g. 1e-6 (0 turns it off when --tol is given)",
            o.rtol
        ));
    }
    if !(o.tol.is_finite() && o.tol >= 0.0) {
        return bad(format!(
            "--tol {}: give a finite change target of 0 (off) or more, e.g. 1e-6",
            o.tol
        ));
    }
    if o.max_iter == 0 {
        return bad(
            "--max-iter 0: the solve would do nothing; give at least 1 (default 1000)".into(),
        );
    }
    Ok(())
}

/// The voxelization's result fields the stop radius is checked against.
#[derive(Deserialize)]
struct Depth {
    center_depth: f64,
}

/// Refuse a stop radius that is not a positive number of voxels, or that reaches the
/// boundary: the center of the run with attributes `attrs` is `center_depth` voxels
/// deep, and a stop ball that deep holds the seeds themselves (every streamline would
/// "reach" the center without a step).
pub fn check_stop_radius(attrs: &Value, stop_radius: Option<f64>) -> Result<(), crate::Error> {
    let Some(r) = stop_radius else {
        return Ok(());
    };
    let bad = |m: String| Err(TraceError::Options(m).into());
    if !(r.is_finite() && r > 0.0) {
        return bad(format!(
            "--stop-radius {r}: give a positive number of voxels (default: 4 center radii, at most half the center's depth)"
        ));
    }
    if let Some(d) = crate::run::stages::report_in::<Depth>(attrs, "voxelize") {
        if r >= d.center_depth {
            return bad(format!(
                "--stop-radius {r}: the center is only {:.1} voxels deep, so the stop ball would reach the boundary and hold the seeds themselves; give less than {:.1} (default: 4 center radii, at most half the depth)",
                d.center_depth, d.center_depth
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn meaningless_solve_options_are_refused() {
        let ok = SolveOptions::default();
        assert!(check_solve(&ok).is_ok());
        for rtol in [1.0, 2.0, f64::INFINITY, f64::NAN, -1e-6] {
            let e = check_solve(&SolveOptions { rtol, ..ok.clone() }).unwrap_err();
            assert!(e.is_bad_input() && e.to_string().contains("--rtol"), "{e}");
        }
        let e = check_solve(&SolveOptions {
            max_iter: 0,
            ..ok.clone()
        })
        .unwrap_err();
        assert!(
            e.is_bad_input() && e.to_string().contains("--max-iter 0"),
            "{e}"
        );
        assert!(check_solve(&SolveOptions {
            tol: f64::NAN,
            ..ok
        })
        .is_err());
    }

    #[test]
    fn a_stop_ball_as_deep_as_the_center_is_refused() {
        let attrs = serde_json::json!({"stages": {"voxelize": {"status": "done",
            "result": {"center_depth": 20.6}}}});
        assert!(check_stop_radius(&attrs, None).is_ok());
        assert!(check_stop_radius(&attrs, Some(3.0)).is_ok());
        let e = check_stop_radius(&attrs, Some(1000.0)).unwrap_err();
        assert!(
            e.is_bad_input() && e.to_string().contains("20.6 voxels deep"),
            "{e}"
        );
        assert!(check_stop_radius(&attrs, Some(20.6)).is_err());
        assert!(check_stop_radius(&attrs, Some(-1.0)).is_err());
        assert!(check_stop_radius(&attrs, Some(f64::NAN)).is_err());
    }
}
