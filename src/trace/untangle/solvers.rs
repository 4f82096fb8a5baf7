//! The linear solvers of a region's embedding: a Dirichlet graph Laplacian with
//! positive weights, each coordinate of the plane its own system.

use glam::DVec2;

/// Iterations of a region's solver, at most: a solve that has not converged by then
/// leaves an embedding that the count of bad triangles judges, as any other.
const MAX_SOLVER_ITERATIONS: usize = 2000;

/// Solve `A x = b` for the symmetric positive definite `apply` (a Dirichlet graph
/// Laplacian with diagonal `diag`) by conjugate gradients preconditioned by the
/// diagonal, from `x`, both coordinates at once, to a residual of 1e-14 of `b`'s; returns the iterations.
#[allow(clippy::many_single_char_names)] // the method's names
pub(super) fn cg(
    apply: &dyn Fn(&[DVec2], &mut [DVec2]),
    diag: &[f64],
    b: &[DVec2],
    x: &mut [DVec2],
) -> usize {
    let n = b.len();
    let dot = |a: &[DVec2], c: &[DVec2]| -> DVec2 {
        a.iter().zip(c).fold(DVec2::ZERO, |s, (p, q)| s + *p * *q)
    };
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    let mut ax = vec![DVec2::ZERO; n];
    apply(x, &mut ax);
    let mut r: Vec<DVec2> = b.iter().zip(&ax).map(|(p, q)| *p - *q).collect();
    let mut z: Vec<DVec2> = r.iter().zip(diag).map(|(q, d)| *q / *d).collect();
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let bb = dot(b, b) * 1e-28;
    let mut ap = vec![DVec2::ZERO; n];
    let mut iterations = 0;
    for _ in 0..(4 * n + 100).min(MAX_SOLVER_ITERATIONS) {
        let rr = dot(&r, &r);
        if (rr.x <= bb.x && rr.y <= bb.y) || !rr.is_finite() {
            break;
        }
        iterations += 1;
        apply(&p, &mut ap);
        let pap = dot(&p, &ap);
        // Each coordinate is its own system with the same matrix.
        let alpha = DVec2::new(ratio(rz.x, pap.x), ratio(rz.y, pap.y));
        for k in 0..n {
            x[k] += alpha * p[k];
            r[k] -= alpha * ap[k];
            z[k] = r[k] / diag[k];
        }
        let rz_new = dot(&r, &z);
        let beta = DVec2::new(ratio(rz_new.x, rz.x), ratio(rz_new.y, rz.y));
        for k in 0..n {
            p[k] = z[k] + beta * p[k];
        }
        rz = rz_new;
    }
    iterations
}

/// Solve `A x = b` for the nonsymmetric `apply` (a Dirichlet graph Laplacian with
/// positive weights and diagonal `diag`) by BiCGSTAB preconditioned by the diagonal,
/// from `x`, each coordinate its own system, to a residual of 1e-14 of `b`'s; returns the iterations.
#[allow(clippy::many_single_char_names)] // the method's names
pub(super) fn bicgstab(
    apply: &dyn Fn(&[DVec2], &mut [DVec2]),
    diag: &[f64],
    b: &[DVec2],
    x: &mut [DVec2],
) -> usize {
    let n = b.len();
    let dot = |a: &[DVec2], c: &[DVec2]| -> DVec2 {
        a.iter().zip(c).fold(DVec2::ZERO, |s, (p, q)| s + *p * *q)
    };
    let ratio = |a: DVec2, b: DVec2| {
        DVec2::new(
            if b.x == 0.0 { 0.0 } else { a.x / b.x },
            if b.y == 0.0 { 0.0 } else { a.y / b.y },
        )
    };
    let mut t = vec![DVec2::ZERO; n];
    apply(x, &mut t);
    let mut r: Vec<DVec2> = b.iter().zip(&t).map(|(p, q)| *p - *q).collect();
    let r0 = r.clone();
    let bb = dot(b, b) * 1e-28;
    let (mut rho, mut alpha, mut omega) = (DVec2::ONE, DVec2::ONE, DVec2::ONE);
    let mut v = vec![DVec2::ZERO; n];
    let mut p = vec![DVec2::ZERO; n];
    let mut y = vec![DVec2::ZERO; n];
    let mut z = vec![DVec2::ZERO; n];
    let mut sv = vec![DVec2::ZERO; n];
    let mut iterations = 0;
    for _ in 0..(4 * n + 100).min(MAX_SOLVER_ITERATIONS) {
        let rr = dot(&r, &r);
        if (rr.x <= bb.x && rr.y <= bb.y) || !rr.is_finite() {
            break;
        }
        iterations += 1;
        let rho_new = dot(&r0, &r);
        let beta = ratio(rho_new, rho) * ratio(alpha, omega);
        rho = rho_new;
        for k in 0..n {
            p[k] = r[k] + beta * (p[k] - omega * v[k]);
            y[k] = p[k] / diag[k];
        }
        apply(&y, &mut v);
        alpha = ratio(rho, dot(&r0, &v));
        for k in 0..n {
            sv[k] = r[k] - alpha * v[k];
            z[k] = sv[k] / diag[k];
        }
        apply(&z, &mut t);
        omega = ratio(dot(&t, &sv), dot(&t, &t));
        for k in 0..n {
            x[k] += alpha * y[k] + omega * z[k];
            r[k] = sv[k] - omega * t[k];
        }
        if !omega.is_finite() || (omega.x == 0.0 && omega.y == 0.0) {
            break;
        }
    }
    iterations
}
