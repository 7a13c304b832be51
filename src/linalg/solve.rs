//! The solve phase: refinement against the unperturbed matrix to its
//! round-off level row by row, and how a solve is judged ([`SolveQuality`]:
//! relative, normwise and componentwise backward error) against the
//! acceptance bounds that pick a fallback.

use super::{difference, norm_inf, EntryScale, Factorization, Factors, MatrixKind, Storage};
use crate::error::{Error, Result};
use faer::sparse::SparseColMat;

/// How well a solution x of A x = b (b ≠ 0) satisfies it.
#[derive(Debug, Clone, Copy)]
pub(super) struct SolveQuality {
    /// ‖Ax − b‖∞/‖b‖∞.
    pub(super) relative: f64,
    /// ‖Ax − b‖∞/(‖A‖ ‖x‖∞ + ‖b‖∞), ‖A‖ the largest entry.
    pub(super) backward: f64,
    /// Componentwise (Oettli–Prager): max_i |Ax − b|_i/(|A| |x| + |b|)_i,
    /// each row against its own scale; computed (one more pass over A)
    /// only when the relative residual is above every acceptance bound.
    pub(super) componentwise: Option<f64>,
}

impl SolveQuality {
    pub(super) const EXACT: SolveQuality = SolveQuality {
        relative: 0.0,
        backward: 0.0,
        componentwise: Some(0.0),
    };

    pub(super) fn of(
        a: &SparseColMat<usize, f64>,
        storage: Storage,
        norm: f64,
        x: &[f64],
        b: &[f64],
        threads: usize,
    ) -> Self {
        Self::with_product(a, storage, norm, x, b, None, threads)
    }

    /// [`SolveQuality::of`], from A x when the solve's refinement computed it
    /// (one product with A less per factorisation).
    pub(super) fn with_product(
        a: &SparseColMat<usize, f64>,
        storage: Storage,
        norm: f64,
        x: &[f64],
        b: &[f64],
        ax: Option<&[f64]>,
        threads: usize,
    ) -> Self {
        let r = match ax {
            Some(ax) => difference(b, ax),
            None => storage.residual(a.as_ref(), x, b, threads),
        };
        let size = norm_inf(&r);
        let relative = size / norm_inf(b);
        let componentwise = (relative > LDLT_ACCEPTED.min(CONDENSED_ACCEPTED)).then(|| {
            let scale = storage.absolute_product(a.as_ref(), x);
            r.iter()
                .zip(&scale)
                .zip(b)
                .fold(0.0f64, |m, ((ri, si), bi)| match ri.abs() {
                    0.0 => m,
                    e => m.max(e / (si + bi.abs())),
                })
        });
        SolveQuality {
            relative,
            backward: size / (norm * norm_inf(x) + norm_inf(b)),
            componentwise,
        }
    }

    /// A refined LDLᵀ (or condensed) solve is kept when its relative
    /// residual is below `bound` ([`LDLT_ACCEPTED`], [`CONDENSED_ACCEPTED`]),
    /// or when it is accurate row by row ([`COMPONENTWISE_ACCEPTED`]): then
    /// it is as good as any backward-stable solve, LU's included.
    pub(super) fn accepted(self, bound: f64) -> bool {
        self.relative <= bound
            || self
                .componentwise
                .is_some_and(|c| c <= COMPONENTWISE_ACCEPTED)
    }

    /// A condensed solve (judged on A; S's own solve had relative residual
    /// `schur_relative`) is kept within [`CONDENSED_ACCEPTED`], or when the
    /// condensation lost at most [`CONDENSATION_LOSS`] of S's accuracy: what
    /// remains is S's conditioning, which A shares.
    pub(super) fn condensed_accepted(self, schur_relative: f64) -> bool {
        self.relative <= CONDENSED_ACCEPTED || self.relative <= CONDENSATION_LOSS * schur_relative
    }
}

/// Solves A x = b with `f` and checks it ([`judge_solve`]; b = 0: on a
/// fixed test right-hand side instead, x = 0). Returns x and how well it
/// solves.
pub(super) fn check_solve(
    a: &SparseColMat<usize, f64>,
    storage: Storage,
    norm: f64,
    f: &Factorization,
    b: &[f64],
    what: &str,
    threads: usize,
) -> Result<(Vec<f64>, SolveQuality)> {
    if b.is_empty() {
        // No unknowns (every dof fixed): x = () solves exactly. Without this
        // the b = 0 branch would retry on an empty test vector forever.
        return Ok((Vec::new(), SolveQuality::EXACT));
    }
    if norm_inf(b) == 0.0 {
        let quality = check_solve(a, storage, norm, f, &test_rhs(a.nrows()), what, threads)?.1;
        return Ok((vec![0.0; b.len()], quality));
    }
    let mut x = b.to_vec();
    // An LDLᵀ refines against all of A: its last product is the judge's
    // (a condensed one reads A's lower triangle only; judged on all of A).
    let ax = match f {
        Factorization::Ldlt(_) => f.solve_with_product(&mut x),
        _ => {
            f.solve_in_place(&mut x);
            None
        }
    };
    let quality = judge_solve(a, storage, norm, &x, b, ax.as_deref(), what, threads)?;
    Ok((x, quality))
}

/// How well x solves A x = b (b ≠ 0); an error when x is not finite, or
/// when the relative residual is above 1e-6 and the solve is not accurate
/// row by row either ([`COMPONENTWISE_ACCEPTED`]): a row whose right-hand
/// side is 0 and whose entries are huge against b (a constraint the active
/// set switches off by its diagonal, at the shell's ρ = 1e12: s_i (C x)_i
/// ~ 1e12 ‖x‖) keeps the round-off of its own sum, 3.7e-5 of ‖b‖∞ there,
/// at a componentwise error of 3e-16.
#[allow(clippy::too_many_arguments)]
pub(super) fn judge_solve(
    a: &SparseColMat<usize, f64>,
    storage: Storage,
    norm: f64,
    x: &[f64],
    b: &[f64],
    ax: Option<&[f64]>,
    what: &str,
    threads: usize,
) -> Result<SolveQuality> {
    if x.iter().any(|v| !v.is_finite()) {
        return Err(Error::numerical(
            what,
            "factorisation",
            "solve gives non-finite values: the matrix is singular",
        ));
    }
    let quality = SolveQuality::with_product(a, storage, norm, x, b, ax, threads);
    let (rel, componentwise) = (quality.relative, quality.componentwise);
    if rel > 1e-6 && !componentwise.is_some_and(|c| c <= COMPONENTWISE_ACCEPTED) {
        return Err(Error::numerical(
            what,
            "factorisation residual",
            format!(
                "‖Ax − b‖∞/‖b‖∞ = {rel:.3e} (componentwise {:.3e}) on a test solve: the matrix is singular or nearly so",
                componentwise.unwrap_or(f64::NAN)
            ),
        ));
    }
    Ok(quality)
}

/// A fixed, dense, non-trivial right-hand side for test solves.
pub(super) fn test_rhs(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| 1.0 + ((i * 7919) % 13) as f64 / 13.0)
        .collect()
}

/// `steps` steps of iterative refinement x ← x + A⁻¹(b − A x) of a solution
/// x of A x = b (A of `kind`: a symmetric one may be its lower triangle;
/// its products on `threads`); returns ‖b − A x‖∞/‖b‖∞ of the final x (‖·‖ for b = 0).
pub fn refine(
    a: &SparseColMat<usize, f64>,
    kind: MatrixKind,
    f: &dyn Factors,
    b: &[f64],
    x: &mut [f64],
    steps: usize,
    threads: usize,
) -> f64 {
    let storage = Storage::of(a.as_ref(), kind);
    let mut r = storage.residual(a.as_ref(), x, b, threads);
    for _ in 0..steps {
        let mut d = r;
        f.solve_in_place(&mut d);
        x.iter_mut().zip(&d).for_each(|(xi, dx)| *xi += dx);
        r = storage.residual(a.as_ref(), x, b, threads);
    }
    let scale = norm_inf(b);
    if scale > 0.0 {
        norm_inf(&r) / scale
    } else {
        norm_inf(&r)
    }
}

/// Relative residual up to which a refined LDLᵀ of a matrix factorised
/// whole is kept (else the next fallback): LDLᵀ and LU both leave
/// 1e-12 … 7e-10 on the shell matrices (docs/work-precision.md).
pub(super) const LDLT_ACCEPTED: f64 = 1e-8;

/// The bound of a condensed factorisation (S's LDLᵀ, and the condensed
/// solve judged on A), whose fallback is the whole matrix: the large
/// shells' S stays within it, a cancelling S (ρ = 1e12) does not.
pub(super) const CONDENSED_ACCEPTED: f64 = 3e-8;

/// How many times S's own relative residual a condensed solve (judged on
/// A) may have above [`CONDENSED_ACCEPTED`]: cancellation in S shows as a
/// large ratio (24× at ρ = 1e12), growing conditioning does not (≤ 1.3×).
pub(super) const CONDENSATION_LOSS: f64 = 4.0;

/// Backward error ‖Ax − b‖∞/(‖A‖ ‖x‖∞ + ‖b‖∞) up to which the SPD fallback
/// (equilibrated, refined LDLᵀ of a matrix plain Cholesky could not solve
/// to 1e-6) is accepted.
pub(super) const BACKWARD_ACCEPTED: f64 = 1e-12;

/// Componentwise backward error (Oettli–Prager, [`SolveQuality`]) up to
/// which a refined solve is kept whatever its relative residual, which
/// grows with the conditioning even at round-off: x then solves a matrix
/// and right-hand side perturbed by < 4e-13 in every entry, as any
/// backward-stable solve does; regularised pivots the refinement cannot
/// undo leave ~4× more (docs/work-precision.md).
pub(super) const COMPONENTWISE_ACCEPTED: f64 = 4e-13;

/// Refinement steps at most; they stop earlier at round-off level.
pub(super) const MAX_REFINEMENT: usize = 6;

/// Solves A x = b in place with `raw_solve` (an approximate inverse), then
/// refines against `product` (A x) to round-off ([`refine_to_round_off`]);
/// returns A x of the final x.
pub(super) fn solve_refined(
    b: &mut [f64],
    product: impl Fn(&[f64]) -> Vec<f64>,
    diagonal: impl Fn(usize) -> f64,
    entry_scale: &EntryScale,
    raw_solve: impl Fn(&mut [f64]),
) -> Vec<f64> {
    let rhs = b.to_vec();
    raw_solve(b);
    refine_to_round_off(product, diagonal, entry_scale, b, &rhs, raw_solve)
}

/// Iterative refinement x ← x + M⁻¹(b − A x) of a solution x of A x = b,
/// M⁻¹ = `solve` (in place) an approximate inverse, until the residual
/// stops falling or is at round-off level ([`EntryScale::excess`] ≤ 1),
/// at most [`MAX_REFINEMENT`] steps.
/// Returns A x of the final x (the product its last residual used: callers
/// that need A x, Uzawa's KKT measures, take it instead of a second product).
pub(super) fn refine_to_round_off(
    product: impl Fn(&[f64]) -> Vec<f64>,
    diagonal: impl Fn(usize) -> f64,
    entry_scale: &EntryScale,
    x: &mut [f64],
    b: &[f64],
    solve: impl Fn(&mut [f64]),
) -> Vec<f64> {
    let mut ax = product(x);
    let mut r = difference(b, &ax);
    let mut size = entry_scale.excess(&r, x, b, &diagonal);
    for _ in 0..MAX_REFINEMENT {
        // (NaN stops too: NaN <= 1 is false, so test "done" first.)
        if size.is_nan() || size <= 1.0 {
            break;
        }
        let mut dx = r;
        solve(&mut dx);
        let candidate: Vec<f64> = x.iter().zip(&dx).map(|(xi, di)| xi + di).collect();
        let ax_new = product(&candidate);
        let r_new = difference(b, &ax_new);
        let size_new = entry_scale.excess(&r_new, &candidate, b, &diagonal);
        // Keep the step only while it pays: at the accuracy the
        // conditioning allows, refinement stalls or oscillates. (A step to
        // round-off is kept: below it `excess` is a bound, not a value.)
        if size_new.is_nan() || (size_new > 0.5 * size && size_new > 1.0) {
            break;
        }
        x.copy_from_slice(&candidate);
        (ax, r, size) = (ax_new, r_new, size_new);
    }
    ax
}
