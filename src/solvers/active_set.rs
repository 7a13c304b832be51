//! Primal–dual active set method (Hintermüller–Ito–Kunisch), i.e. the
//! semismooth Newton method on the complementarity function
//!
//! ```text
//!     A x − Cᵀλ = F,     λ − max(0, λ − c ḡ(x)) = 0,     ḡ_i = (C x − g)_i / w_i,
//! ```
//!
//! on the full system (SPEC §3 "beyond the thesis"). Given the active set
//! 𝒜_k = {i : λ_i − c_i ḡ_i > 0} of the previous iterate, step k solves
//!
//! ```text
//!     [ A    −Cᵀ S ] [x]   [F  ]        active row i:   s_i (C x)_i = s_i g_i
//!     [ Ĉ     D    ] [μ] = [ĝ  ]        inactive row i: d μ_i = 0,
//! ```
//!
//! λ = S μ, with S = diag(s_i) a row (and multiplier) scaling that gives
//! the constraint rows and multiplier columns the magnitude of A's entries
//! (s_i = max|A| / max_j |C_ij|, d = max|A|): partial-pivoting LU then sees
//! a balanced matrix also for the shell's saddle matrix. The matrix always
//! holds all of C (below A) and a diagonal in the multiplier block, with
//! explicit zeros for the entries the current active set switches off, so
//! its pattern is fixed: the symbolic LU analysis is done once and each step
//! is a numeric refactorisation only ([`ReusableLu`]), checked on a test
//! solve and followed by one step of iterative refinement.
//!
//! **Updates.** On large systems (n + m ≥ `update_min_size`) the last
//! numeric LU, of M_ref, is kept. The next Newton matrix differs from it
//! only in the constraint rows whose state changed since (a rank-r row
//! replacement), so it is solved by the Woodbury formula with M_ref and an
//! r × r capacitance matrix (`RowUpdate`; its entries are cached per
//! index until the next refactorisation, so an index costs two solves once),
//! then refined with the true matrix until the residual (equilibrium and
//! constraint rows measured separately) is within 10× that of the LU path.
//! This path is taken when its estimated cost (measured solve times) is
//! below that of a refactorisation; otherwise, or when it does not reach
//! the residual, the matrix is refactorised. The iterates are those of the
//! LU path up to round-off; `lu_steps`, `update_steps`, `update_fallbacks`
//! and `update_solves` are reported.
//!
//! **The constant c.** With an exact Newton step the active set after the
//! first step does not depend on c (λ_i = 0 off the set and ḡ_i = 0 on it).
//! c matters only when the caller gives an initial primal iterate: then
//! c_i = 1/S̃_ii with S̃ = W⁻¹ C diag(A)⁻¹ Cᵀ, the Jacobi estimate of the
//! mean-form dual operator, so that c_i ḡ_i is the multiplier change that
//! would close the gap of constraint i alone (the units of λ). A scalar c
//! can be given instead.
//!
//! **Start.** Without warm start the iteration starts from (x, λ) = (0, 0):
//! 𝒜_1 = {i : g_i > 0} (constraints violated by x = 0). With
//! `initial_lambda` only, 𝒜_1 = {λ⁰_i > 0}; with `initial_x` (and
//! optionally `initial_lambda`), 𝒜_1 = {λ⁰_i − c_i ḡ_i(x⁰) > 0}. For nested
//! iteration, pass the prolonged coarse solution.
//!
//! **Stopping.** Only on the relative KKT measure (`tol`). An active set that
//! does not change while the KKT measure is above `tol` is stagnation (the
//! linear solves are not accurate enough for `tol`); an active set seen at
//! an earlier iteration is cycling (possible when A is not an M-matrix);
//! both are errors that say so. `max_iter` gives a non-converged report.

use super::measures::{kkt_measures, History, KktMeasures};
use super::uzawa::solve_linear;
use super::{ContactProblem, SolveReport};
use crate::assembly::{mat_vec, norm_inf};
use crate::error::{Error, Result};
use crate::linalg::{
    factorize_checked, first_non_finite, residual, solve_refined, DenseLu, Factorization,
    ReusableLu,
};
use crate::progress::IterationProgress;
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use std::time::Instant;

/// History columns after the KKT ones (`History::for_solver`). Row k is the iterate
/// of Newton step k: `active` = |𝒜_k|, the set used in step k; `changes` =
/// `added` + `removed` = |𝒜_k Δ 𝒜_{k−1}| (𝒜_0 = ∅); `linear_residual` =
/// ‖b − Mz‖∞/‖b‖∞ of the Newton solve after refinement; `dual_step` =
/// ‖λ^k − λ^{k−1}‖∞.
pub const EXTRA_COLUMNS: [&str; 5] = ["active", "changes", "added", "removed", "linear_residual"];

#[derive(Debug, Clone)]
pub struct ActiveSetOptions {
    /// Bound on the relative KKT measure.
    pub tol: f64,
    /// Maximum number of Newton steps (linear solves).
    pub max_iter: usize,
    /// Scalar c of the active-set rule; None: c_i = 1/S̃_ii (module docs).
    pub c: Option<f64>,
    /// Warm start: the initial multiplier (length m).
    pub initial_lambda: Option<Vec<f64>>,
    /// Warm start: the initial x (length n), used with c.
    pub initial_x: Option<Vec<f64>>,
    /// Steps of iterative refinement after each solve.
    pub refinement_steps: usize,
    /// Newton matrices of at least this size (n + m) may be solved as a
    /// row update of the last factorised one (module docs, "Updates")
    /// instead of being refactorised; smaller ones are refactorised at
    /// every step. usize::MAX: always refactorise.
    pub update_min_size: usize,
    pub show_progress: bool,
}

impl Default for ActiveSetOptions {
    fn default() -> Self {
        ActiveSetOptions {
            tol: 1e-10,
            max_iter: 50,
            c: None,
            initial_lambda: None,
            initial_x: None,
            refinement_steps: 1,
            update_min_size: 20_000,
            show_progress: false,
        }
    }
}

const STAGE: &str = "primal-dual active set";

/// The Newton matrix with its fixed pattern and the positions of the
/// entries an active set switches.
struct NewtonMatrix {
    matrix: SparseColMat<usize, f64>,
    /// For each constraint row i: (value position in the matrix, s_i C_ij)
    /// of the entries of row n + i.
    row_entries: Vec<Vec<(usize, f64)>>,
    /// For each constraint row i: (column j, s_i C_ij), sorted by j.
    row_cols: Vec<Vec<(usize, f64)>>,
    /// Value position of the diagonal entry (n + i, n + i).
    diagonal: Vec<usize>,
    /// The diagonal value d of inactive rows.
    d: f64,
    /// The scaling s_i (λ_i = s_i μ_i).
    scale: Vec<f64>,
}

impl NewtonMatrix {
    fn new(problem: &ContactProblem) -> Result<Self> {
        let c = problem.constraint.as_ref().expect("a constrained problem");
        let (n, m) = (problem.n(), c.obstacle.len());
        let a = &problem.matrix;
        let a_max = norm_inf(a.val()).max(f64::MIN_POSITIVE);
        // Rows of C (the multiplier columns are −Cᵀ S).
        let mut c_rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); m];
        let cs = c.matrix.symbolic();
        for j in 0..c.matrix.ncols() {
            for (i, v) in cs
                .row_idx_of_col(j)
                .zip(c.matrix.val_of_col(j).iter().copied())
            {
                c_rows[i].push((j, v));
            }
        }
        let mut scale = Vec::with_capacity(m);
        for (i, row) in c_rows.iter().enumerate() {
            let row_max = row.iter().fold(0.0f64, |s, &(_, v)| s.max(v.abs()));
            if row_max == 0.0 || !row_max.is_finite() {
                return Err(Error::numerical(
                    STAGE,
                    "constraint matrix",
                    format!("row {i} of C is empty or not finite"),
                ));
            }
            scale.push(a_max / row_max);
        }
        // Columns 0..n: A's column, then the rows n + i of C's column j.
        // Columns n..n+m: −s_i (row i of C)ᵀ, then the diagonal.
        let nnz_c: usize = c_rows.iter().map(Vec::len).sum();
        let nnz = a.val().len() + 2 * nnz_c + m;
        let mut col_ptr = Vec::with_capacity(n + m + 1);
        let mut row_idx = Vec::with_capacity(nnz);
        let mut values = Vec::with_capacity(nnz);
        let mut row_entries: Vec<Vec<(usize, f64)>> = vec![Vec::new(); m];
        let mut row_cols: Vec<Vec<(usize, f64)>> = vec![Vec::new(); m];
        col_ptr.push(0);
        let as_ = a.symbolic();
        for j in 0..n {
            let mut col: Vec<(usize, f64)> = as_
                .row_idx_of_col(j)
                .zip(a.val_of_col(j).iter().copied())
                .collect();
            col.sort_by_key(|e| e.0);
            for (r, v) in col {
                row_idx.push(r);
                values.push(v);
            }
            let mut cc: Vec<(usize, f64)> = cs
                .row_idx_of_col(j)
                .zip(c.matrix.val_of_col(j).iter().copied())
                .collect();
            cc.sort_by_key(|e| e.0);
            for (i, v) in cc {
                row_entries[i].push((values.len(), scale[i] * v));
                row_cols[i].push((j, scale[i] * v));
                row_idx.push(n + i);
                values.push(0.0);
            }
            col_ptr.push(row_idx.len());
        }
        let mut diagonal = Vec::with_capacity(m);
        for (i, row) in c_rows.iter_mut().enumerate() {
            row.sort_by_key(|e| e.0);
            for &(j, v) in row.iter() {
                row_idx.push(j);
                values.push(-scale[i] * v);
            }
            diagonal.push(values.len());
            row_idx.push(n + i);
            values.push(a_max);
            col_ptr.push(row_idx.len());
        }
        let symbolic = SymbolicSparseColMat::new_checked(n + m, n + m, col_ptr, None, row_idx);
        Ok(NewtonMatrix {
            matrix: SparseColMat::new(symbolic, values),
            row_entries,
            row_cols,
            diagonal,
            d: a_max,
            scale,
        })
    }

    /// Switches the constraint rows to the active set.
    fn set_active(&mut self, active: &[bool]) {
        let values = self.matrix.val_mut();
        for (i, &on) in active.iter().enumerate() {
            for &(pos, v) in &self.row_entries[i] {
                values[pos] = if on { v } else { 0.0 };
            }
            values[self.diagonal[i]] = if on { 0.0 } else { self.d };
        }
    }
}

/// Solves a contact problem by the primal–dual active set method (module docs).
pub fn active_set(problem: &ContactProblem, options: &ActiveSetOptions) -> Result<SolveReport> {
    let start = Instant::now();
    let Some(c) = problem.constraint.as_ref() else {
        let t = Instant::now();
        let f = factorize_checked(&problem.matrix, problem.kind, "system matrix")?;
        let mut report = solve_linear(problem, &f, t.elapsed().as_secs_f64())?;
        report.wall_seconds = start.elapsed().as_secs_f64();
        return Ok(report);
    };
    let (n, m) = (problem.n(), c.obstacle.len());
    for (name, len, want) in [
        (
            "initial_lambda",
            options.initial_lambda.as_ref().map(Vec::len),
            m,
        ),
        ("initial_x", options.initial_x.as_ref().map(Vec::len), n),
    ] {
        if let Some(len) = len.filter(|&l| l != want) {
            return Err(Error::numerical(
                STAGE,
                name,
                format!("length {len}, expected {want}"),
            ));
        }
    }

    // c_i: the scalar option, or the Jacobi estimate 1/S̃_ii.
    let c_rule: Vec<f64> = match options.c {
        Some(v) => vec![v; m],
        None => jacobi_dual_diagonal(problem)
            .into_iter()
            .map(|s| if s > 0.0 { 1.0 / s } else { 1.0 })
            .collect(),
    };
    if c_rule.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(Error::numerical(STAGE, "c", "must be finite and > 0"));
    }

    // The first active set.
    let lambda0 = options
        .initial_lambda
        .clone()
        .unwrap_or_else(|| vec![0.0; m]);
    let mut active: Vec<bool> = match &options.initial_x {
        Some(x0) => {
            let cx = mat_vec(&c.matrix, x0);
            (0..m)
                .map(|i| lambda0[i] - c_rule[i] * c.mean_gap(&cx, i) > 0.0)
                .collect()
        }
        None if options.initial_lambda.is_some() => lambda0.iter().map(|&l| l > 0.0).collect(),
        None => c.obstacle.iter().map(|&g| g > 0.0).collect(),
    };

    let t = Instant::now();
    let mut newton = NewtonMatrix::new(problem)?;
    let mut lu = ReusableLu::analyze(&newton.matrix, "active-set Newton matrix")?;
    let mut factor_seconds = t.elapsed().as_secs_f64();

    let mut history = History::for_solver(&EXTRA_COLUMNS);
    let mut progress = IterationProgress::new(
        "Active set",
        options.max_iter,
        options.tol,
        options.show_progress,
    );
    let mut seen: Vec<Vec<bool>> = Vec::new();
    let mut previous = vec![false; m];
    let mut lambda = lambda0;
    let mut x = vec![0.0; n];
    let mut measures = KktMeasures::default();
    let mut iterations = 0;
    let mut stop_reason = "max_iter";
    let mut max_linear_residual = 0.0f64;
    let mut rhs = vec![0.0; n + m];
    let mut update: Option<RowUpdate> = None;
    let (mut factor_time, mut solve_time) = (0.0f64, 0.0f64);
    // Time per column of a block solve (measured; a guess until then).
    let mut column_time = 0.0f64;
    let (mut lu_steps, mut update_steps, mut update_fallbacks) = (0usize, 0usize, 0usize);
    let (mut update_solves, mut max_update_rank) = (0usize, 0usize);
    let mut update_seconds = 0.0f64;
    for k in 1..=options.max_iter {
        iterations = k;
        newton.set_active(&active);
        rhs[..n].copy_from_slice(&problem.rhs);
        for i in 0..m {
            rhs[n + i] = if active[i] {
                newton.scale[i] * c.obstacle[i]
            } else {
                0.0
            };
        }
        // The update path when it is estimated cheaper than a refactorisation.
        let mut solved: Option<(Vec<f64>, f64)> = None;
        if let Some(upd) = update.as_mut() {
            let diff = upd.differing(&active);
            let new = diff.iter().filter(|&&i| upd.slot[i] == usize::MAX).count();
            let estimate = 2.0 * new as f64 * column_time + 4.0 * solve_time;
            if diff.len() <= MAX_UPDATE_RANK
                && upd.indices.len() + new <= 2 * MAX_UPDATE_RANK
                && estimate < factor_time
            {
                let t = Instant::now();
                let target = (10.0 * upd.ref_residual).max(1e-13);
                solved = upd.solve(&newton, n, &diff, &active, &rhs, target);
                update_seconds += t.elapsed().as_secs_f64();
                if upd.block_columns > 0 {
                    column_time = upd.block_seconds / upd.block_columns as f64;
                }
                if solved.is_some() {
                    update_steps += 1;
                    max_update_rank = max_update_rank.max(diff.len());
                } else {
                    update_fallbacks += 1;
                }
            }
        }
        let (z, linear_residual) = match solved {
            Some(s) => s,
            None => {
                if let Some(upd) = update.take() {
                    update_solves += upd.solves;
                }
                let t = Instant::now();
                let (factorization, _) =
                    lu.factorize(&newton.matrix, "active-set Newton matrix")?;
                factor_time = t.elapsed().as_secs_f64();
                factor_seconds += factor_time;
                let mut z = rhs.clone();
                let t = Instant::now();
                let res = solve_refined(
                    &newton.matrix,
                    &factorization,
                    &mut z,
                    options.refinement_steps,
                );
                solve_time = t.elapsed().as_secs_f64() / (1 + options.refinement_steps) as f64;
                if column_time == 0.0 {
                    column_time = solve_time / 4.0;
                }
                lu_steps += 1;
                if n + m >= options.update_min_size {
                    let blockwise = block_residual(&residual(&newton.matrix, &z, &rhs), &rhs, n);
                    update = Some(RowUpdate::new(factorization, active.clone(), blockwise));
                }
                (z, res)
            }
        };
        max_linear_residual = max_linear_residual.max(linear_residual);
        if let Some(i) = first_non_finite(&z) {
            return Err(Error::numerical(
                STAGE,
                "Newton step",
                format!("non-finite value at index {i} in iteration {k}"),
            ));
        }
        x.copy_from_slice(&z[..n]);
        let new_lambda: Vec<f64> = (0..m)
            .map(|i| {
                if active[i] {
                    newton.scale[i] * z[n + i]
                } else {
                    0.0
                }
            })
            .collect();
        let dual_step = new_lambda
            .iter()
            .zip(&lambda)
            .fold(0.0f64, |s, (a, b)| s.max((a - b).abs()));
        lambda = new_lambda;
        let cx = mat_vec(&c.matrix, &x);
        measures = kkt_measures(problem, &x, &lambda, Some(&cx));
        let added = (0..m).filter(|&i| active[i] && !previous[i]).count();
        let removed = (0..m).filter(|&i| !active[i] && previous[i]).count();
        history.push_iteration(
            k,
            dual_step,
            &measures,
            &[
                active.iter().filter(|&&a| a).count() as f64,
                (added + removed) as f64,
                added as f64,
                removed as f64,
                linear_residual,
            ],
        );
        progress.update(k, measures.kkt, dual_step);
        if measures.kkt <= options.tol {
            stop_reason = "kkt";
            break;
        }
        // The next active set.
        let next: Vec<bool> = (0..m)
            .map(|i| lambda[i] - c_rule[i] * c.mean_gap(&cx, i) > 0.0)
            .collect();
        if next == active {
            progress.finish();
            return Err(Error::numerical(
                STAGE,
                "KKT measure",
                format!(
                    "stagnation at iteration {k}: the active set ({} constraints) did not change but the relative KKT measure is {:.3e} > tol {:.1e} (linear residual {linear_residual:.1e}): the tolerance is below the accuracy of the linear solves",
                    count(&active),
                    measures.kkt,
                    options.tol
                ),
            ));
        }
        seen.push(active.clone());
        if let Some(j) = seen.iter().position(|s| *s == next) {
            progress.finish();
            return Err(Error::numerical(
                STAGE,
                "active set 𝒜",
                format!(
                    "cycling at iteration {k}: the next active set ({} constraints) is the one of iteration {} (relative KKT measure {:.3e}); the semismooth Newton iteration is not globally convergent for this matrix, try a warm start or another solver",
                    count(&next),
                    j + 1,
                    measures.kkt
                ),
            ));
        }
        previous = std::mem::replace(&mut active, next);
    }
    progress.finish();
    if let Some(upd) = update.take() {
        update_solves += upd.solves;
    }
    let c_min = c_rule.iter().cloned().fold(f64::INFINITY, f64::min);
    let c_max = c_rule.iter().cloned().fold(0.0, f64::max);
    Ok(SolveReport {
        algorithm: "active-set".into(),
        x,
        lambda,
        iterations,
        converged: measures.kkt <= options.tol,
        stop_reason: stop_reason.into(),
        measures,
        history,
        factor_seconds,
        wall_seconds: start.elapsed().as_secs_f64(),
        parameters: vec![
            ("tol".into(), options.tol),
            ("c_min".into(), c_min),
            ("c_max".into(), c_max),
            ("symbolic_analyses".into(), lu.symbolic_analyses() as f64),
            (
                "numeric_factorizations".into(),
                lu.numeric_factorizations() as f64,
            ),
            ("max_linear_residual".into(), max_linear_residual),
            ("lu_steps".into(), lu_steps as f64),
            ("update_steps".into(), update_steps as f64),
            ("update_fallbacks".into(), update_fallbacks as f64),
            ("update_solves".into(), update_solves as f64),
            ("max_update_rank".into(), max_update_rank as f64),
            ("update_seconds".into(), update_seconds),
        ],
    })
}

fn count(set: &[bool]) -> usize {
    set.iter().filter(|&&a| a).count()
}

/// S̃_ii = (1/w_i) Σ_j C_ij² / |A_jj|: the diagonal of the mean-form dual
/// operator W⁻¹ C A⁻¹ Cᵀ with A replaced by its diagonal (0 where C's row
/// meets no nonzero diagonal entry).
pub fn jacobi_dual_diagonal(problem: &ContactProblem) -> Vec<f64> {
    let Some(c) = problem.constraint.as_ref() else {
        return Vec::new();
    };
    let a = &problem.matrix;
    let diag: Vec<f64> = (0..a.ncols())
        .map(|j| {
            a.symbolic()
                .row_idx_of_col(j)
                .zip(a.val_of_col(j))
                .filter(|(r, _)| *r == j)
                .map(|(_, v)| v.abs())
                .sum()
        })
        .collect();
    let mut s = vec![0.0; c.obstacle.len()];
    for j in 0..c.matrix.ncols() {
        if diag[j] == 0.0 {
            continue;
        }
        for (i, v) in c
            .matrix
            .symbolic()
            .row_idx_of_col(j)
            .zip(c.matrix.val_of_col(j))
        {
            s[i] += v * v / diag[j];
        }
    }
    s.iter_mut().zip(&c.weights).for_each(|(si, w)| *si /= w);
    s
}

/// max(‖r_x‖∞/‖b_x‖∞, ‖r_μ‖∞/‖b_μ‖∞): the relative residual of the
/// equilibrium rows and of the constraint rows separately (the scaled
/// obstacle rows can dominate ‖b‖∞).
fn block_residual(r: &[f64], b: &[f64], n: usize) -> f64 {
    let part = |r: &[f64], b: &[f64]| {
        let s = norm_inf(b);
        if s > 0.0 {
            norm_inf(r) / s
        } else {
            norm_inf(r)
        }
    };
    part(&r[..n], &b[..n]).max(part(&r[n..], &b[n..]))
}

/// Ranks above this are always refactorised (the dense capacitance matrix
/// and its O(r³) factorisation).
const MAX_UPDATE_RANK: usize = 2000;
/// Refinement sweeps of an update-path solve before it falls back to a
/// refactorisation.
const MAX_UPDATE_SWEEPS: usize = 6;
/// Right-hand sides per block solve when the cache grows.
const UPDATE_BLOCK: usize = 32;

/// The Newton matrix M of the current active set as a row update of the
/// last factorised one, M_ref (active set 𝒜_ref): the constraint rows
/// n + i with i ∈ R = 𝒜 Δ 𝒜_ref differ, M = M_ref + Σ_{i∈R} e_{n+i} D_i,
/// with D_i = σ_i (s_i C_i − d e_{n+i}ᵀ), σ_i = +1 if i ∉ 𝒜_ref (the row is
/// switched on), −1 otherwise. Woodbury:
///
/// ```text
///     M⁻¹ b = y − M_ref⁻¹ P (I + G_RR)⁻¹ D_R y,   y = M_ref⁻¹ b,
///     G_ab = D_a M_ref⁻¹ e_{n+b},
/// ```
///
/// two solves with M_ref per application. D_i depends only on i and
/// 𝒜_ref, so the entries of G are cached for every index met since the
/// last refactorisation: an index new to R costs one solve (column
/// M_ref⁻¹ e_{n+j}) and one transposed solve (row D_j M_ref⁻¹).
struct RowUpdate {
    reference: Factorization,
    ref_active: Vec<bool>,
    /// Block residual (block_residual) of the last LU-path solve: the
    /// accuracy an update-path solve must match.
    ref_residual: f64,
    /// Cache slot of each constraint index (usize::MAX: none).
    slot: Vec<usize>,
    /// Constraint index of each slot.
    indices: Vec<usize>,
    /// g[a][b] = D_{indices[a]} · M_ref⁻¹ e_{n + indices[b]}.
    g: Vec<Vec<f64>>,
    /// Solves with M_ref or its transpose done for this reference.
    solves: usize,
    /// Columns of block solves and their time.
    block_columns: usize,
    block_seconds: f64,
}

impl RowUpdate {
    fn new(reference: Factorization, ref_active: Vec<bool>, ref_residual: f64) -> RowUpdate {
        let m = ref_active.len();
        RowUpdate {
            reference,
            ref_active,
            ref_residual,
            slot: vec![usize::MAX; m],
            indices: Vec::new(),
            g: Vec::new(),
            solves: 0,
            block_columns: 0,
            block_seconds: 0.0,
        }
    }

    /// D_i · w.
    fn d_dot(&self, newton: &NewtonMatrix, n: usize, i: usize, w: &[f64]) -> f64 {
        let sigma = if self.ref_active[i] { -1.0 } else { 1.0 };
        let s: f64 = newton.row_cols[i].iter().map(|&(j, v)| v * w[j]).sum();
        sigma * (s - newton.d * w[n + i])
    }

    /// Adds the indices `new` to the cache: per index one solve (column
    /// M_ref⁻¹ e_{n+j}) and one transposed solve (row D_j M_ref⁻¹), done in
    /// blocks of right-hand sides.
    fn add(&mut self, newton: &NewtonMatrix, n: usize, new: &[usize]) {
        let size = n + newton.diagonal.len();
        for block in new.chunks(UPDATE_BLOCK) {
            let k = block.len();
            let mut w = vec![0.0; size * k];
            let mut v = vec![0.0; size * k];
            for (c, &j) in block.iter().enumerate() {
                w[c * size + n + j] = 1.0;
                let sigma = if self.ref_active[j] { -1.0 } else { 1.0 };
                let col = &mut v[c * size..(c + 1) * size];
                for &(jj, val) in &newton.row_cols[j] {
                    col[jj] += sigma * val;
                }
                col[n + j] -= sigma * newton.d;
            }
            let t = Instant::now();
            self.reference.solve_block_in_place(&mut w, k);
            self.reference.solve_transpose_block_in_place(&mut v, k);
            self.block_seconds += t.elapsed().as_secs_f64();
            self.block_columns += 2 * k;
            self.solves += 2 * k;
            for (c, &j) in block.iter().enumerate() {
                let wc = &w[c * size..(c + 1) * size];
                let vc = &v[c * size..(c + 1) * size];
                let new_slot = self.indices.len();
                self.slot[j] = new_slot;
                self.indices.push(j);
                let mut row: Vec<f64> = self.indices.iter().map(|&i| vc[n + i]).collect();
                row[new_slot] = self.d_dot(newton, n, j, wc);
                for a in 0..new_slot {
                    let value = self.d_dot(newton, n, self.indices[a], wc);
                    self.g[a].push(value);
                }
                self.g.push(row);
            }
        }
    }

    /// The indices where `active` differs from the reference.
    fn differing(&self, active: &[bool]) -> Vec<usize> {
        (0..active.len())
            .filter(|&i| active[i] != self.ref_active[i])
            .collect()
    }

    /// Solves M z = b, M the current Newton matrix (= M_ref + rows `diff`),
    /// by Woodbury with the cached G, followed by refinement sweeps with
    /// the true M until the relative residual is at most `target`. None when
    /// the capacitance matrix is singular or the residual is not reached.
    fn solve(
        &mut self,
        newton: &NewtonMatrix,
        n: usize,
        diff: &[usize],
        active: &[bool],
        b: &[f64],
        target: f64,
    ) -> Option<(Vec<f64>, f64)> {
        let new: Vec<usize> = diff
            .iter()
            .copied()
            .filter(|&i| self.slot[i] == usize::MAX)
            .collect();
        self.add(newton, n, &new);
        let r = diff.len();
        let slots: Vec<usize> = diff.iter().map(|&i| self.slot[i]).collect();
        let mut cap = vec![0.0; r * r];
        for (a, &sa) in slots.iter().enumerate() {
            for (bb, &sb) in slots.iter().enumerate() {
                cap[a * r + bb] = self.g[sa][sb] + if a == bb { 1.0 } else { 0.0 };
            }
        }
        let capacitance = DenseLu::new(cap, r)?;
        let apply = |this: &mut RowUpdate, rhs: &[f64]| -> Vec<f64> {
            let mut y = rhs.to_vec();
            this.reference.solve_in_place(&mut y);
            let t: Vec<f64> = diff.iter().map(|&i| this.d_dot(newton, n, i, &y)).collect();
            let c = capacitance.solve(&t);
            let mut u = vec![0.0; rhs.len()];
            for (&i, &ci) in diff.iter().zip(&c) {
                u[n + i] = ci;
            }
            this.reference.solve_in_place(&mut u);
            this.solves += 2;
            y.iter_mut().zip(&u).for_each(|(yi, ui)| *yi -= ui);
            // Inactive rows read d μ_i = 0: μ_i = 0 exactly, as in the LU path.
            for (i, &on) in active.iter().enumerate() {
                if !on {
                    y[n + i] = 0.0;
                }
            }
            y
        };
        let mut z = apply(self, b);
        let mut rel = f64::INFINITY;
        for _ in 0..MAX_UPDATE_SWEEPS {
            let res = residual(&newton.matrix, &z, b);
            rel = block_residual(&res, b, n);
            if !rel.is_finite() {
                return None;
            }
            if rel <= target {
                break;
            }
            let dz = apply(self, &res);
            z.iter_mut().zip(&dz).for_each(|(zi, di)| *zi += di);
        }
        if rel > target {
            let res = residual(&newton.matrix, &z, b);
            rel = block_residual(&res, b, n);
        }
        (rel <= target && first_non_finite(&z).is_none()).then_some((z, rel))
    }
}
