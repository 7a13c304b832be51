//! Preconditioned conjugate gradients for a symmetric positive definite
//! matrix stored whole, with any symmetric positive definite preconditioner
//! (one V-cycle of [`super::Multigrid`]: `Multigrid::precondition`), and
//! the vector kernels it shares with the V-cycle.
//! Their loops run in halves on two threads (`kernels::cut`).

use super::kernels::{cut, each_in_halves, on_halves, on_paired_halves, sum_halves};
use faer::sparse::SparseColMat;
use faer::Index;

/// What [`pcg`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct CgReport {
    pub iterations: usize,
    /// ‖b − A x‖₂ / ‖b‖₂ of the returned x, computed afresh (not the
    /// recurrence's residual).
    pub relative_residual: f64,
    pub converged: bool,
}

/// Solves A x = b from the given x until ‖b − A x‖₂ ≤ `rtol` ‖b‖₂ or
/// `max_iter` iterations (all restarts together); `precondition(r, z)`
/// writes z = M⁻¹ r. Its vector work in halves on `threads` (module docs).
pub fn pcg<I: Index>(
    a: &SparseColMat<I, f64>,
    b: &[f64],
    x: &mut [f64],
    mut precondition: impl FnMut(&[f64], &mut [f64]),
    rtol: f64,
    max_iter: usize,
    threads: usize,
) -> CgReport {
    let (n, m) = (b.len(), cut(b.len()));
    let dot_halves = |u: &[f64], v: &[f64]| sum_halves(threads, n, |k| dot(&u[k.clone()], &v[k]));
    let norm_halves = |v: &[f64]| dot_halves(v, v).sqrt();
    let norm_b = norm_halves(b);
    let target = rtol * norm_b;
    // From x = 0 (a Newton step's solve) the residual is b: no product.
    let mut r = match x.iter().all(|&v| v == 0.0) {
        true => b.to_vec(),
        false => {
            let mut r = vec![0.0; n];
            residual(a, b, x, &mut r, threads);
            r
        }
    };
    let mut z = vec![0.0; n];
    let mut q = vec![0.0; n];
    let mut iterations = 0;
    // The recurrence's residual drifts from b − A x near round-off: CG
    // restarts from x until the true residual, computed afresh after each
    // run of iterations, meets the target (that one is the report's).
    while norm_b > 0.0 && iterations < max_iter && norm_halves(&r) > target {
        precondition(&r, &mut z);
        let mut p = z.clone();
        let mut rz = dot_halves(&r, &z);
        while iterations < max_iter {
            iterations += 1;
            product(a, &p, &mut q, threads);
            let pq = dot_halves(&p, &q);
            if pq.is_nan() || pq <= 0.0 {
                break; // not positive definite, or p = 0
            }
            let alpha = rz / pq;
            // x += α p and r −= α q, half by half, with ‖r‖² of the new r.
            let step = |offset: usize, x: &mut [f64], r: &mut [f64]| {
                let (p, q) = (&p[offset..], &q[offset..]);
                let mut rr = 0.0;
                for k in 0..x.len() {
                    x[k] += alpha * p[k];
                    r[k] -= alpha * q[k];
                    rr += r[k] * r[k];
                }
                rr
            };
            let rr = on_paired_halves(threads, x, &mut r, m, step, |a, b| a + b);
            if rr.sqrt() <= target {
                break;
            }
            precondition(&r, &mut z);
            let rz_next = dot_halves(&r, &z);
            let beta = rz_next / rz;
            rz = rz_next;
            on_halves(
                threads,
                &mut p,
                m,
                |offset, p| {
                    for (k, pk) in p.iter_mut().enumerate() {
                        *pk = z[offset + k] + beta * *pk;
                    }
                },
                |_, _| (),
            );
        }
        residual(a, b, x, &mut r, threads);
    }
    let relative_residual = match norm_b {
        0.0 => norm_halves(&r),
        _ => norm_halves(&r) / norm_b,
    };
    CgReport {
        iterations,
        relative_residual,
        converged: relative_residual <= rtol,
    }
}

fn dot(u: &[f64], v: &[f64]) -> f64 {
    u.iter().zip(v).map(|(a, b)| a * b).sum()
}

/// r = b − A x for a symmetric A stored whole in compressed columns:
/// column i is row i, so each r_i is one dot product (reads only, where
/// the column-oriented product scatters into r).
/// In halves on `threads` (module docs).
pub(crate) fn residual<I: Index>(
    a: &SparseColMat<I, f64>,
    b: &[f64],
    x: &[f64],
    r: &mut [f64],
    threads: usize,
) {
    each_in_halves(threads, r, |i| b[i] - row_dot(a, i, x));
}

/// q = A p for a symmetric A stored whole (as [`residual`]).
pub(crate) fn product<I: Index>(
    a: &SparseColMat<I, f64>,
    p: &[f64],
    q: &mut [f64],
    threads: usize,
) {
    each_in_halves(threads, q, |i| row_dot(a, i, p));
}

/// Row i of a symmetric A stored whole (its column i) times x.
#[inline]
fn row_dot<I: Index>(a: &SparseColMat<I, f64>, i: usize, x: &[f64]) -> f64 {
    let (col_ptr, rows, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let (start, end) = (col_ptr[i].zx(), col_ptr[i + 1].zx());
    rows[start..end]
        .iter()
        .zip(&values[start..end])
        .map(|(&j, &v)| v * x[j.zx()])
        .sum()
}

pub(crate) fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}
