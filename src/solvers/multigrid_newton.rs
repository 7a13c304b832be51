//! Newton multigrid with grid sequencing (`method = "multigrid"`) for
//! contact problems whose every constraint row acts through one interior
//! unknown of its own: the P1⊕B3–P0 membrane, one- or two-sided
//! (docs/formulation.md §3.3, "Newton multigrid").
//!
//! **Condensation.** The unknowns split into the skeleton u (outside the
//! interior groups) and one interior unknown b per group (an element's
//! bubble), which A couples to nothing (∫_T ∇b·∇φ = 0 for the P1 functions
//! φ): A = diag(K, D). Row i of the constraint reads c_iᵀu + β_i b ≥ g_i
//! with b its row's interior unknown and β_i ≠ 0. For a given u each b
//! minimises ½ d b² − f b between its bounds, so b = clamp(f/d, lo, hi) with
//! lo the largest (g_i − c_iᵀu)/β_i over its rows with β_i > 0 and hi the
//! smallest over those with β_i < 0. What remains is the convex, C¹,
//! piecewise quadratic
//!
//! ```text
//!     J(u) = ½ uᵀK u − Fᵀu + Σ_b (½ d b² − f b),   ∇J = K u − F − Σ_i λ_i c_i,
//! ```
//!
//! with λ_i = (d b − f)/β_i ≥ 0 on the row whose bound the clamp takes (0
//! on the others), and the generalised Hessian H = K + Σ_active (d/β_i²)
//! c_i c_iᵀ, symmetric positive definite. Every KKT measure but
//! stationarity holds by construction of (b, λ): ∇J = 0 is the discrete
//! KKT point, and the solve stops on the same relative KKT measure as the
//! other methods (`solvers::measures`), computed on the whole problem.
//!
//! **Newton.** Semismooth Newton on J with Armijo backtracking (a step that
//! keeps the active set is taken whole: J is then the quadratic CG solved
//! for, and decreases by ½ δᵀHδ, below the round-off of J's change near the
//! solution). Each step's
//! H δ = −∇J is solved by conjugate gradients preconditioned by one
//! V-cycle (`multigrid::Multigrid`) whose level operators are the Galerkin
//! operators of H: each coarser level's own K (for P1 on nested meshes the
//! Galerkin product of the finer K: each level's cycle is the one below it
//! with the level's K stacked on top, no products formed), plus each active
//! row's rank-one term restricted through the prolongations. On nested P1 meshes
//! the restriction of c_i stays on the vertices of the triangle's ancestor,
//! inside K's pattern at every level; a step adds or removes the terms of
//! the rows whose activity changed only. CG stops at the relative residual
//! η = 0.1 after a step that changed the active set, else η = max(min(0.1,
//! kkt), 0.1 tol/kkt): loose while the active set moves, as tight as the
//! tolerance needs at the end.
//!
//! **Grid sequencing.** The levels' own problems (each assembled on its mesh
//! of the hierarchy) are solved from the coarsest, each from the
//! prolongation of the previous level's u, the coarser ones to
//! `coarse_tol`, the given problem to `tol`. Where the previous level's u
//! touches an obstacle, the start follows the finer level's obstacle
//! instead of the interpolant of the coarser one (given the obstacles at
//! each level's skeleton, [`SkeletonObstacles`]): the interpolant misses a
//! curved obstacle by O(H²), and the contact set's rows would answer that
//! gap with multipliers of order gap/h².

use super::measures::{dual_step_norm, jacobi_dual_diagonal_of, kkt_measures_with, Products};
use super::monitor::{check_finite, Monitor};
use super::{Constraint, ContactProblem, DualNorm, KktMeasures, ReportBuilder, SolveReport};
use crate::error::{Error, Result};
use crate::linalg::{beside, cut, each_in_halves, mat_vec, on_paired_halves, MatrixKind};
use crate::linalg::{Multigrid, MultigridOptions, SweptLevel};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use std::sync::{Arc, Mutex};
use std::time::Instant;

const STAGE: &str = "multigrid";
const NONE: usize = usize::MAX;

/// The coarser levels of a nested hierarchy, as the pipeline assembles them.
pub struct MultigridLevels {
    /// The problems of the coarser levels, coarsest first, each assembled
    /// on its own mesh of the hierarchy.
    pub coarser: Vec<ContactProblem>,
    /// `prolongations[l]`: level l's skeleton unknowns to level l + 1's (the
    /// last one into the solved problem's), in the problems' numbering of
    /// their skeletons (their unknowns outside the interior groups, in order).
    pub prolongations: Vec<SparseColMat<usize, f64>>,
    /// `lifts[l]`: what the boundary values add to `prolongations[l] u` (the
    /// start of level l + 1 is the interpolant of level l's whole solution).
    pub lifts: Vec<Vec<f64>>,
    /// `obstacles[l]`: level l's obstacles at its skeleton unknowns, every
    /// level (the finest last), or none: then each level starts from the
    /// interpolant alone.
    pub obstacles: Option<Vec<SkeletonObstacles>>,
}

/// A level's obstacles at its skeleton unknowns: the values whose
/// interpolant the constraint rows integrate (for P1⊕B3–P0 the P1
/// interpolants at the free vertices). The start of each level follows
/// them where the level below touches (module docs, "Grid sequencing").
#[derive(Debug, Clone)]
pub struct SkeletonObstacles {
    pub lower: Vec<f64>,
    pub upper: Option<Vec<f64>>,
}

/// The coarser levels handed to one solve, which takes them: each coarser
/// problem is dropped once its level is solved, so the finest level's
/// Newton steps run without them (a third of the finest problem's memory).
#[derive(Clone)]
pub struct LevelsHandle(Arc<Mutex<Option<MultigridLevels>>>);

impl LevelsHandle {
    pub fn new(levels: MultigridLevels) -> Self {
        LevelsHandle(Arc::new(Mutex::new(Some(levels))))
    }

    /// The levels, once (None after a solve took them).
    fn take(&self) -> Option<MultigridLevels> {
        self.0
            .lock()
            .map(|mut levels| levels.take())
            .unwrap_or(None)
    }
}

impl std::fmt::Debug for LevelsHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0.try_lock() {
            Ok(levels) => levels.fmt(f),
            Err(_) => f.write_str("LevelsHandle(in use)"),
        }
    }
}

impl std::fmt::Debug for MultigridLevels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let sizes: Vec<usize> = self.coarser.iter().map(ContactProblem::n).collect();
        f.debug_struct("MultigridLevels")
            .field("coarser_unknowns", &sizes)
            .finish()
    }
}

#[derive(Debug, Clone)]
pub struct MultigridNewtonOptions {
    /// Relative KKT tolerance of the given (finest) problem.
    pub tol: f64,
    /// Relative KKT tolerance of the coarser levels, whose solutions are
    /// starts (never below `tol`).
    pub coarse_tol: f64,
    /// Newton steps per level.
    pub max_iter: usize,
    /// CG iterations per Newton step.
    pub max_cg: usize,
    pub show_progress: bool,
    /// The hierarchy's coarser levels; the pipeline sets them (None, or
    /// taken by an earlier solve: an error naming what is missing).
    pub levels: Option<LevelsHandle>,
    pub cycle: MultigridOptions,
    /// With 2 or more, the finest level is set up (condensed, its K put in
    /// sweep order) on a second thread while the coarser levels solve.
    pub threads: usize,
}

/// A problem condensed to its skeleton (module docs). Its indices are 32
/// bits wide (checked): held through the solve, its arrays are among the
/// largest the finest level holds.
struct Condensed<'p> {
    /// The problem's unknown of skeleton unknown k.
    skeleton: Vec<u32>,
    /// F on the skeleton.
    load: Vec<f64>,
    /// Per interior unknown: its index in the problem, d = A_bb, f = F_b.
    interior: Vec<u32>,
    d: Vec<f64>,
    f: Vec<f64>,
    /// Per row: β_i, g_i (the problem's) and c_i (compressed rows on the
    /// skeleton).
    beta: Vec<f64>,
    g: &'p [f64],
    row_ptr: Vec<u32>,
    row_cols: Vec<u32>,
    row_vals: Vec<f64>,
    /// Per interior unknown: its rows (compressed).
    rows_ptr: Vec<u32>,
    rows: Vec<u32>,
    /// Whether the rows hold every entry of C, its columns' rows in
    /// ascending order: then [`Condensed::constraint_matrix`] is C again.
    holds_constraint: bool,
}

/// Column j of A's lower triangle, (i, a_ij) with i ≥ j, whichever way A
/// is stored (whole or its lower triangle).
fn lower_column(a: &SparseColMat<usize, f64>, j: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
    let range = a.symbolic().col_range(j);
    let rows = &a.symbolic().row_idx()[range.clone()];
    rows.iter()
        .zip(&a.val()[range])
        .filter(move |(&i, _)| i >= j)
        .map(|(&i, &v)| (i, v))
}

/// A skeleton iterate's interior values and active rows.
struct Clamped {
    /// c_iᵀ u of every row.
    s: Vec<f64>,
    b: Vec<f64>,
    /// Per interior unknown: the row whose bound it sits on, or NONE.
    active: Vec<usize>,
}

impl<'p> Condensed<'p> {
    /// The condensation of `problem`, or an error naming what does not fit:
    /// equality multipliers, an interior group of more than one unknown, an
    /// interior unknown coupled to another, a row without (or with two)
    /// interior unknowns. With it each unknown's skeleton index (NONE for
    /// the interior ones). C is `taken` when the solve holds it apart from
    /// the problem, else the problem's.
    fn of(
        problem: &'p ContactProblem,
        taken: Option<&SparseColMat<usize, f64>>,
    ) -> Result<(Self, Vec<usize>)> {
        let refuse = |reason: String| {
            Error::numerical(
                STAGE,
                "structure",
                format!("{reason}: the multigrid method needs every constraint row to act through one interior unknown of its own that A couples to nothing (the P1⊕B3–P0 membrane)"),
            )
        };
        let c = problem
            .constraint
            .as_ref()
            .ok_or_else(|| refuse("the problem has no constraint".into()))?;
        if problem.n_primal != problem.n() {
            return Err(refuse("the problem has equality multipliers".into()));
        }
        if problem.kind != MatrixKind::SymmetricPositiveDefinite {
            return Err(refuse(format!("A is {}", problem.kind.describe())));
        }
        let n = problem.n();
        let cm = taken.unwrap_or(&c.matrix);
        let (m, c_entries) = (c.obstacle.len(), cm.compute_nnz());
        if u32::try_from(n.max(m).max(c_entries)).is_err() {
            return Err(Error::numerical(
                STAGE,
                "size",
                format!("{n} unknowns, {m} rows and {c_entries} entries of C: the condensed problem indexes them in 32 bits"),
            ));
        }
        let groups = problem
            .interior
            .as_ref()
            .ok_or_else(|| refuse("the problem declares no interior unknowns".into()))?;
        let mut interior_of = vec![NONE; n];
        let mut interior = Vec::with_capacity(groups.len());
        for g in 0..groups.len() {
            match groups.group(g) {
                [i] => {
                    interior_of[*i] = interior.len();
                    interior.push(*i);
                }
                group => {
                    return Err(refuse(format!(
                        "interior group {g} has {} unknowns",
                        group.len()
                    )))
                }
            }
        }
        let skeleton: Vec<usize> = (0..n).filter(|&i| interior_of[i] == NONE).collect();
        let mut skeleton_of = vec![NONE; n];
        for (k, &i) in skeleton.iter().enumerate() {
            skeleton_of[i] = k;
        }
        // A's diagonal, then each coupling of an interior unknown checked
        // against both diagonals.
        let a = &problem.matrix;
        let mut diagonal = vec![0.0; n];
        for (j, dj) in diagonal.iter_mut().enumerate() {
            *dj = lower_column(a, j)
                .find(|&(i, _)| i == j)
                .map_or(0.0, |(_, v)| v);
        }
        if let Some(b) = interior
            .iter()
            .position(|&i| diagonal[i].is_nan() || diagonal[i] <= 0.0)
        {
            return Err(refuse(format!(
                "the interior unknown {} has the diagonal {:e}",
                interior[b], diagonal[interior[b]]
            )));
        }
        let d: Vec<f64> = interior.iter().map(|&i| diagonal[i]).collect();
        for j in 0..n {
            for (i, v) in lower_column(a, j) {
                let (si, sj) = (skeleton_of[i], skeleton_of[j]);
                if si == NONE && sj == NONE {
                    if i != j && v != 0.0 {
                        return Err(refuse(format!(
                            "the interior unknowns {i} and {j} are coupled (A = {v:e})"
                        )));
                    }
                } else if (si == NONE || sj == NONE)
                    && v.abs() > 1e-10 * (diagonal[i] * diagonal[j]).abs().sqrt()
                {
                    let (interior_unknown, other) = if si == NONE { (i, j) } else { (j, i) };
                    return Err(refuse(format!(
                        "the interior unknown {interior_unknown} couples to the unknown {other} (A = {v:e})"
                    )));
                }
            }
        }
        // C row by row: its interior unknown and β, and c on the skeleton.
        let mut row_interior = vec![NONE; m];
        let mut beta = vec![0.0; m];
        let mut row_ptr = vec![0u32; m + 1];
        for j in 0..n {
            let range = cm.symbolic().col_range(j);
            for (&i, &v) in cm.symbolic().row_idx()[range.clone()]
                .iter()
                .zip(&cm.val()[range])
            {
                if v == 0.0 {
                    continue;
                }
                match interior_of[j] {
                    NONE => row_ptr[i + 1] += 1,
                    _ if row_interior[i] != NONE => {
                        return Err(refuse(format!(
                            "constraint row {i} acts on two interior unknowns"
                        )))
                    }
                    b => {
                        row_interior[i] = b;
                        beta[i] = v;
                    }
                }
            }
        }
        if let Some(i) = row_interior.iter().position(|&b| b == NONE) {
            return Err(refuse(format!(
                "constraint row {i} acts on no interior unknown"
            )));
        }
        for i in 0..m {
            row_ptr[i + 1] += row_ptr[i];
        }
        let mut next: Vec<usize> = row_ptr.iter().map(|&p| p as usize).collect();
        let mut row_cols = vec![0u32; row_ptr[m] as usize];
        let mut row_vals = vec![0.0; row_ptr[m] as usize];
        for j in 0..n {
            if interior_of[j] != NONE {
                continue;
            }
            let range = cm.symbolic().col_range(j);
            for (&i, &v) in cm.symbolic().row_idx()[range.clone()]
                .iter()
                .zip(&cm.val()[range])
            {
                if v != 0.0 {
                    row_cols[next[i]] = skeleton_of[j] as u32;
                    row_vals[next[i]] = v;
                    next[i] += 1;
                }
            }
        }
        let nb = interior.len();
        let mut rows_ptr = vec![0u32; nb + 1];
        for &b in &row_interior {
            rows_ptr[b + 1] += 1;
        }
        for b in 0..nb {
            rows_ptr[b + 1] += rows_ptr[b];
        }
        let mut next = rows_ptr.clone();
        let mut rows = vec![0u32; m];
        for (i, &b) in row_interior.iter().enumerate() {
            rows[next[b] as usize] = i as u32;
            next[b] += 1;
        }
        let ascending = (0..n).all(|j| {
            let rows = cm.symbolic().row_idx_of_col_raw(j);
            rows.windows(2).all(|w| w[0] < w[1])
        });
        let holds_constraint = c_entries == row_ptr[m] as usize + m && ascending;
        let condensed = Condensed {
            holds_constraint,
            load: skeleton.iter().map(|&i| problem.rhs[i]).collect(),
            f: interior.iter().map(|&i| problem.rhs[i]).collect(),
            skeleton: skeleton.into_iter().map(|i| i as u32).collect(),
            interior: interior.into_iter().map(|i| i as u32).collect(),
            d,
            beta,
            g: &c.obstacle,
            row_ptr,
            row_cols,
            row_vals,
            rows_ptr,
            rows,
        };
        Ok((condensed, skeleton_of))
    }

    fn n_skeleton(&self) -> usize {
        self.skeleton.len()
    }

    /// C (m × n, n the problem's unknowns) made again from the rows: entry
    /// for entry C when `holds_constraint`, each column's rows ascending.
    fn constraint_matrix(&self, n: usize) -> SparseColMat<usize, f64> {
        let m = self.g.len();
        let mut col_ptr = vec![0usize; n + 1];
        for p in 0..self.row_cols.len() {
            col_ptr[self.skeleton[self.row_cols[p] as usize] as usize + 1] += 1;
        }
        for (j, &b) in self.interior.iter().enumerate() {
            col_ptr[b as usize + 1] += self.rows_of(j).count();
        }
        for j in 0..n {
            col_ptr[j + 1] += col_ptr[j];
        }
        let mut next = col_ptr[..n].to_vec();
        let mut rows = vec![0usize; col_ptr[n]];
        let mut values = vec![0.0; col_ptr[n]];
        let mut place = |i: usize, j: usize, v: f64| {
            (rows[next[j]], values[next[j]]) = (i, v);
            next[j] += 1;
        };
        // A column is a skeleton unknown's or an interior one's: rows in
        // ascending order either way.
        for i in 0..m {
            for p in self.row_range(i) {
                place(
                    i,
                    self.skeleton[self.row_cols[p] as usize] as usize,
                    self.row_vals[p],
                );
            }
        }
        for (j, &b) in self.interior.iter().enumerate() {
            for i in self.rows_of(j) {
                place(i, b as usize, self.beta[i]);
            }
        }
        let symbolic = SymbolicSparseColMat::new_checked(m, n, col_ptr, None, rows);
        SparseColMat::new(symbolic, values)
    }

    /// The entries of row i in `row_cols` and `row_vals`.
    fn row_range(&self, i: usize) -> std::ops::Range<usize> {
        self.row_ptr[i] as usize..self.row_ptr[i + 1] as usize
    }

    /// The rows of interior unknown j.
    fn rows_of(&self, j: usize) -> impl Iterator<Item = usize> + '_ {
        let range = self.rows_ptr[j] as usize..self.rows_ptr[j + 1] as usize;
        self.rows[range].iter().map(|&i| i as usize)
    }

    /// c_iᵀ u.
    fn row_product(&self, i: usize, u: &[f64]) -> f64 {
        self.row_range(i)
            .map(|k| self.row_vals[k] * u[self.row_cols[k] as usize])
            .sum()
    }

    /// w_i = d/β_i² of row i's term w_i c_i c_iᵀ in the Hessian, j its
    /// interior unknown.
    fn term_weight(&self, j: usize, i: usize) -> f64 {
        self.d[j] / (self.beta[i] * self.beta[i])
    }

    /// Each interior unknown clamped between the bounds u gives it; in
    /// halves on `threads` (`linalg::cut`: the same numbers on one).
    fn clamp(&self, u: &[f64], threads: usize) -> Clamped {
        let mut s = vec![0.0; self.g.len()];
        each_in_halves(threads, &mut s, |i| self.row_product(i, u));
        let nb = self.interior.len();
        let (mut b, mut active) = (vec![0.0; nb], vec![NONE; nb]);
        let clamp_part = |offset: usize, b: &mut [f64], active: &mut [usize]| {
            for (k, (bk, ak)) in b.iter_mut().zip(active.iter_mut()).enumerate() {
                let j = offset + k;
                let (mut lo, mut lo_row) = (f64::NEG_INFINITY, NONE);
                let (mut hi, mut hi_row) = (f64::INFINITY, NONE);
                for i in self.rows_of(j) {
                    let bound = (self.g[i] - s[i]) / self.beta[i];
                    if self.beta[i] > 0.0 && bound > lo {
                        (lo, lo_row) = (bound, i);
                    } else if self.beta[i] < 0.0 && bound < hi {
                        (hi, hi_row) = (bound, i);
                    }
                }
                let free = self.f[j] / self.d[j];
                (*bk, *ak) = if free < lo {
                    (lo, lo_row)
                } else if free > hi {
                    (hi, hi_row)
                } else {
                    (free, NONE)
                };
            }
        };
        on_paired_halves(threads, &mut b, &mut active, cut(nb), clamp_part, |_, _| ());
        Clamped { s, b, active }
    }

    /// λ_i of every row: (d b − f)/β_i on the active rows, 0 elsewhere.
    fn multipliers(&self, clamped: &Clamped) -> Vec<f64> {
        let mut lambda = vec![0.0; self.g.len()];
        for (j, &i) in clamped.active.iter().enumerate() {
            if i != NONE {
                lambda[i] = (self.d[j] * clamped.b[j] - self.f[j]) / self.beta[i];
            }
        }
        lambda
    }

    /// J(u + tδ) − J(u) for the clamped values of u, without the
    /// cancellation of subtracting two values of J: t (K u − F)·δ + ½ t² δᵀK δ
    /// plus each interior unknown's change (b' − b)(½ d (b' + b) − f), given
    /// `residual_slope` = (K u − F)·δ and `curvature` = δᵀK δ. With the
    /// clamped values at u + tδ.
    fn change_along(
        &self,
        clamped: &Clamped,
        trial: &Clamped,
        t: f64,
        residual_slope: f64,
        curvature: f64,
    ) -> f64 {
        let interior: f64 = (0..self.d.len())
            .map(|j| {
                let (b, b_new) = (clamped.b[j], trial.b[j]);
                (b_new - b) * (0.5 * self.d[j] * (b_new + b) - self.f[j])
            })
            .sum();
        t * residual_slope + 0.5 * t * t * curvature + interior
    }

    /// The iterate of u with its clamped values, given K u.
    fn iterate(&self, ku: Vec<f64>, u: &[f64], clamped: &Clamped) -> Iterate {
        let n = self.skeleton.len() + self.interior.len();
        let lambda = self.multipliers(clamped);
        let (mut x, mut ax, mut ct_lambda) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut cx = clamped.s.clone();
        let mut gradient = vec![0.0; u.len()];
        for (k, &i) in self.skeleton.iter().enumerate() {
            (x[i as usize], ax[i as usize]) = (u[k], ku[k]);
        }
        for (j, &unknown) in self.interior.iter().enumerate() {
            let (unknown, b) = (unknown as usize, clamped.b[j]);
            (x[unknown], ax[unknown]) = (b, self.d[j] * b);
            for i in self.rows_of(j) {
                cx[i] += self.beta[i] * b;
                ct_lambda[unknown] += self.beta[i] * lambda[i];
                if lambda[i] != 0.0 {
                    for p in self.row_range(i) {
                        gradient[self.row_cols[p] as usize] -= lambda[i] * self.row_vals[p];
                    }
                }
            }
        }
        let mut residual = ku;
        for (k, &i) in self.skeleton.iter().enumerate() {
            residual[k] -= self.load[k];
            ct_lambda[i as usize] = -gradient[k];
            gradient[k] += residual[k];
        }
        Iterate {
            x,
            lambda,
            ax,
            cx,
            ct_lambda,
            residual,
            gradient,
        }
    }
}

/// An iterate of the whole problem and what its measures and the Newton
/// step read.
struct Iterate {
    x: Vec<f64>,
    lambda: Vec<f64>,
    /// A x, C x and Cᵀλ (the measures' products).
    ax: Vec<f64>,
    cx: Vec<f64>,
    ct_lambda: Vec<f64>,
    /// K u − F and ∇J = K u − F − Σ λ_i c_i, on the skeleton.
    residual: Vec<f64>,
    gradient: Vec<f64>,
}

/// The multigrid of one level's generalised Hessian: K's hierarchy plus the
/// active rows' terms, kept in step with the active set.
struct HessianCycle {
    mg: Multigrid,
    /// The finest level's sweep position of each skeleton unknown.
    position: Vec<usize>,
    /// `restrictions[l]`: Pᵀ of prolongation l (level l + 1 to l), sweep numbering.
    restrictions: Vec<SparseColMat<usize, f64>>,
    /// Per interior unknown: the row whose term the operators hold, or NONE.
    applied: Vec<usize>,
}

impl HessianCycle {
    /// The cycle of a level whose K is `level`: alone on the coarsest
    /// level, else on top of the level below's cycle (`below`, its terms
    /// taken off, and the prolongation to this level). The coarser
    /// operators are then the coarser levels' own K, which for nested P1
    /// meshes are the Galerkin products of this one (no products to form;
    /// the snapped circle of a disk makes them near). The hierarchy holds
    /// K in sweep order only: products with K are [`HessianCycle::k_product`].
    fn on(
        condensed: &Condensed,
        level: SweptLevel,
        below: Option<(HessianCycle, &SparseColMat<usize, f64>)>,
        options: MultigridOptions,
    ) -> Result<Self> {
        let (mg, mut restrictions) = match below {
            None => (Multigrid::on_coarsest(level, options)?, Vec::new()),
            Some((below, p)) => {
                debug_assert!(below.applied.iter().all(|&i| i == NONE), "terms taken off");
                (below.mg.stacked(level, p)?, below.restrictions)
            }
        };
        if let Some(l) = mg.n_levels().checked_sub(2) {
            restrictions.push(
                mg.prolongation_swept(l)
                    .as_ref()
                    .transpose()
                    .to_col_major()
                    .map_err(|e| Error::numerical(STAGE, "restriction", format!("{e:?}")))?,
            );
        }
        let mut position = vec![0; condensed.n_skeleton()];
        for (k, &i) in mg.finest_order().iter().enumerate() {
            position[i] = k;
        }
        Ok(HessianCycle {
            mg,
            position,
            restrictions,
            applied: vec![NONE; condensed.interior.len()],
        })
    }

    /// The cycle with every term taken off: K's hierarchy, for the next
    /// level to stand on.
    fn without_terms(mut self, condensed: &Condensed) -> Result<Self> {
        self.follow(condensed, &vec![NONE; self.applied.len()])?;
        Ok(self)
    }

    /// K u (skeleton numbering): the finest operator H = K + Σ w_i c_i c_iᵀ
    /// (the terms it holds) applied, the terms taken off. They are of K's
    /// size (w_i |c_i|² ~ d_T), so nothing cancels.
    fn k_product(&self, condensed: &Condensed, u: &[f64]) -> Vec<f64> {
        let mut ku = self.mg.apply(u);
        for (j, &i) in self.applied.iter().enumerate() {
            if i != NONE {
                let s = condensed.term_weight(j, i) * condensed.row_product(i, u);
                for p in condensed.row_range(i) {
                    ku[condensed.row_cols[p] as usize] -= s * condensed.row_vals[p];
                }
            }
        }
        ku
    }

    /// The operators made those of `active` (per interior unknown, the row
    /// whose bound it sits on, or NONE).
    fn follow(&mut self, condensed: &Condensed, active: &[usize]) -> Result<()> {
        // The changed terms in the sweep order of their rows' first
        // unknowns: the operators' columns are then read front by front,
        // not scattered (a whole contact set enters at a level's first step).
        let first_position = |i: usize| {
            let (k, end) = (condensed.row_range(i).start, condensed.row_range(i).end);
            match k < end {
                true => self.position[condensed.row_cols[k] as usize],
                false => 0,
            }
        };
        let mut changed: Vec<(usize, usize)> = (0..active.len())
            .filter(|&j| self.applied[j] != active[j])
            .map(|j| {
                let row = if active[j] != NONE {
                    active[j]
                } else {
                    self.applied[j]
                };
                (first_position(row), j)
            })
            .collect();
        changed.sort_unstable();
        if changed.is_empty() {
            return Ok(());
        }
        // The two finest levels take each term w r rᵀ (r = c_i restricted
        // to the level); the third, their sum Δ, whose position-wise values
        // it keeps; each coarser level then takes Pᵀ Δ P of the level above,
        // entry by entry: the terms of a contact zone share a coarse level's
        // entries, so a coarse level takes far fewer additions than terms.
        let finest = self.mg.n_levels() - 1;
        let summed = finest.checked_sub(2);
        let mut delta = summed.map_or_else(Vec::new, |l| vec![0.0; self.mg.level_entries(l)]);
        for &(_, j) in &changed {
            let (old, new) = (self.applied[j], active[j]);
            for (row, sign) in [(old, -1.0), (new, 1.0)] {
                if row != NONE {
                    let w = sign * condensed.term_weight(j, row);
                    self.add_term(condensed, row, w, &mut delta)?;
                }
            }
            self.applied[j] = new;
        }
        for l in (1..=summed.unwrap_or(0)).rev() {
            let mut entries = Vec::new();
            self.mg.for_each_entry(l, |k, a, b| {
                if delta[k] != 0.0 {
                    entries.push((a, b, delta[k]));
                }
            });
            let mut coarser = vec![0.0; self.mg.level_entries(l - 1)];
            let pt = &self.restrictions[l - 1];
            for (a, b, v) in entries {
                for (ca, pa) in restriction_of(pt, a) {
                    for (cb, pb) in restriction_of(pt, b) {
                        let k = self
                            .mg
                            .add_to_level(l - 1, ca, cb, v * pa * pb)
                            .ok_or_else(|| outside_pattern("the contact terms", l - 1, ca, cb))?;
                        coarser[k] += v * pa * pb;
                    }
                }
            }
            delta = coarser;
        }
        self.mg.operators_changed()
    }

    /// Adds w r rᵀ to the two finest levels and to the third, r the
    /// restriction of c_i to each, and to `delta` at the third level's
    /// positions ([`HessianCycle::follow`]); with fewer levels, to each.
    fn add_term(
        &mut self,
        condensed: &Condensed,
        i: usize,
        w: f64,
        delta: &mut [f64],
    ) -> Result<()> {
        let mut r: Vec<(usize, f64)> = condensed
            .row_range(i)
            .map(|k| {
                (
                    self.position[condensed.row_cols[k] as usize],
                    condensed.row_vals[k],
                )
            })
            .collect();
        let finest = self.mg.n_levels() - 1;
        let summed = finest.checked_sub(2);
        for l in (summed.unwrap_or(0)..=finest).rev() {
            for &(a, va) in &r {
                for &(b, vb) in &r {
                    let k = self.mg.add_to_level(l, a, b, w * va * vb).ok_or_else(|| {
                        outside_pattern(&format!("the term of constraint row {i}"), l, a, b)
                    })?;
                    if Some(l) == summed {
                        delta[k] += w * va * vb;
                    }
                }
            }
            if Some(l) == summed || l == 0 {
                break;
            }
            let pt = &self.restrictions[l - 1];
            let mut coarse: Vec<(usize, f64)> = Vec::with_capacity(2 * r.len());
            for &(a, va) in &r {
                for (j, p) in restriction_of(pt, a) {
                    match coarse.iter_mut().find(|e| e.0 == j) {
                        Some(e) => e.1 += va * p,
                        None => coarse.push((j, va * p)),
                    }
                }
            }
            r = coarse;
        }
        Ok(())
    }

    /// H δ = rhs by CG with the V-cycle; δ and rhs in skeleton numbering.
    fn solve(&self, rhs: &[f64], rtol: f64, max_cg: usize) -> (Vec<f64>, usize) {
        let b = self.mg.to_swept(rhs);
        let mut x = vec![0.0; b.len()];
        let report = self.mg.pcg_swept(&b, &mut x, rtol, max_cg);
        let mut delta = vec![0.0; b.len()];
        self.mg.from_swept(&x, &mut delta);
        (delta, report.iterations)
    }
}

/// The coarser level's unknowns that unknown `a` restricts to through
/// `pt` (Pᵀ in compressed columns), with their weights: column a of Pᵀ.
fn restriction_of(
    pt: &SparseColMat<usize, f64>,
    a: usize,
) -> impl Iterator<Item = (usize, f64)> + '_ {
    let range = pt.symbolic().col_range(a);
    pt.symbolic().row_idx()[range.clone()]
        .iter()
        .copied()
        .zip(pt.val()[range].iter().copied())
}

/// The error of a contact term outside a level's operator pattern.
fn outside_pattern(what: &str, l: usize, a: usize, b: usize) -> Error {
    Error::numerical(
        STAGE,
        "pattern",
        format!("{what} falls outside level {l}'s operator pattern at ({a}, {b}): the levels are not nested P1 meshes"),
    )
}

/// What one level's Newton iteration did.
struct LevelSolve {
    u: Vec<f64>,
    /// The level's cycle without its terms, below the finest level.
    cycle: Option<HessianCycle>,
    x: Vec<f64>,
    lambda: Vec<f64>,
    measures: KktMeasures,
    newton_steps: usize,
    cg_iterations: usize,
    converged: bool,
    /// On the finest level, C made again from the condensed rows when they
    /// hold it.
    constraint_matrix: Option<SparseColMat<usize, f64>>,
}

/// Solves `problem` (constraint rows through interior unknowns, module
/// docs) by Newton multigrid over the levels of `options`, and gives it
/// back. Its C is read into the finest level's condensed rows and, when
/// they hold every entry of it, not kept beside them: it is made again from
/// them at the end, entry for entry (at 1025², C is 160 MB; the solve
/// peaks at 1.2 GB without it).
pub fn multigrid_newton(
    mut given: ContactProblem,
    options: &MultigridNewtonOptions,
) -> Result<(ContactProblem, SolveReport)> {
    let clock = Instant::now();
    let levels = options
        .levels
        .as_ref()
        .and_then(LevelsHandle::take)
        .ok_or_else(|| {
            Error::numerical(
                STAGE,
                "levels",
                "no hierarchy: the multigrid method solves on the meshes of mesh.refine, given with the problem of the finest (once)",
            )
        })?;
    let MultigridLevels {
        coarser,
        prolongations,
        lifts,
        obstacles,
    } = levels;
    let n_obstacles = obstacles.as_ref().map_or(coarser.len() + 1, Vec::len);
    if prolongations.len() != coarser.len()
        || lifts.len() != coarser.len()
        || n_obstacles != coarser.len() + 1
    {
        return Err(Error::numerical(
            STAGE,
            "levels",
            format!(
                "{} coarser problems but {} prolongations, {} lifts and the obstacles of {n_obstacles} levels",
                coarser.len(),
                prolongations.len(),
                lifts.len()
            ),
        ));
    }
    let finest = coarser.len();
    let taken_c = given.constraint.as_mut().map(Constraint::take_matrix);
    let problem = &given;
    let transfers = Transfers {
        prolongations: &prolongations,
        lifts: &lifts,
        obstacles: obstacles.as_deref(),
    };
    let mut builder = ReportBuilder::new("multigrid", clock, 0.0, 0.0)
        .with_history(&["level", "cg_iterations", "step_length", "active_changes"])
        .iterating(
            "multigrid",
            options.max_iter * (finest + 1),
            options.tol,
            options.show_progress,
        );
    let mut per_level = Vec::with_capacity(finest + 1);
    // Levels 0 … finest − 1 from the coarsest, each from the previous one's
    // u and on its cycle, each problem dropped once solved; the finest
    // level's set-up (most of a level's cost before its first Newton step)
    // is made meanwhile on a second thread when there is one.
    let solve_coarser = |builder: &mut ReportBuilder,
                         per_level: &mut Vec<(usize, usize)>|
     -> Result<(Vec<f64>, Option<HessianCycle>)> {
        let (mut u, mut cycle) = (Vec::new(), None);
        for (l, level_problem) in coarser.into_iter().enumerate() {
            let (setup, _) = LevelSetup::new(&level_problem, None, l, options)?;
            let started = Started::on(setup, cycle, &u, &transfers, options)?;
            let solved = solve_level(started, &level_problem, false, options, builder)?;
            per_level.push((solved.newton_steps, solved.cg_iterations));
            (u, cycle) = (solved.u, solved.cycle);
        }
        Ok((u, cycle))
    };
    let (coarser_solved, finest_setup) = beside(
        options.threads,
        || solve_coarser(&mut builder, &mut per_level),
        || LevelSetup::new(problem, taken_c, finest, options),
    );
    let ((u, cycle), (finest_setup, kept_c)) = (coarser_solved?, finest_setup?);
    let started = Started::on(finest_setup, cycle, &u, &transfers, options)?;
    // The transfers served the start and the cycle: not held through the
    // finest level's Newton steps (at 1025², 70 MB).
    drop((u, prolongations, lifts, obstacles));
    let solved = solve_level(started, problem, true, options, &mut builder)?;
    let restored_c = kept_c.or(solved.constraint_matrix);
    per_level.push((solved.newton_steps, solved.cg_iterations));
    builder.iterations = solved.newton_steps;
    builder.measures = solved.measures;
    if solved.converged {
        builder.stop("kkt");
    }
    let mut parameters = vec![("levels".to_string(), (finest + 1) as f64)];
    for (l, (steps, cg)) in per_level.iter().enumerate() {
        parameters.push((format!("newton_steps_level_{l}"), *steps as f64));
        parameters.push((format!("cg_iterations_level_{l}"), *cg as f64));
    }
    let cg_total: usize = per_level.iter().map(|p| p.1).sum();
    parameters.push(("cg_iterations".into(), cg_total as f64));
    let report = builder.finish(solved.x, solved.lambda, parameters);
    if let (Some(c), Some(matrix)) = (given.constraint.as_mut(), restored_c) {
        c.matrix = matrix;
    }
    Ok((given, report))
}

/// The hierarchy's prolongations, lifts and obstacles (as
/// [`MultigridLevels`]).
struct Transfers<'a> {
    prolongations: &'a [SparseColMat<usize, f64>],
    lifts: &'a [Vec<f64>],
    obstacles: Option<&'a [SkeletonObstacles]>,
}

impl Transfers<'_> {
    /// The start of level `level` above the coarsest: the interpolant of
    /// the level below's skeleton solution `coarse_u`, P u + lift, kept on
    /// the fine obstacles' side where `coarse_u` touches its own. There the
    /// interpolant follows the coarse obstacle's, which misses the fine
    /// obstacle by O(H²) (its curvature times the coarse mesh size
    /// squared): the fine rows would see that gap, the bubbles fill it at
    /// λ ~ gap/h², and Newton's first steps would go to taking it back
    /// (a quarter of the contact set leaving, then returning). So each unknown is
    /// kept at or above φ_h + P min(0, u − φ_H), the fine obstacle less the
    /// interpolated penetration of the coarse solution (strictly inside
    /// the contact set, as the solution is); the upper obstacle mirrored.
    /// Away from contact the interpolant is above that bound and stays.
    /// The fixed unknowns are not in P: their distance counts as 0 (the
    /// boundary values lie between the obstacles).
    fn start(&self, level: usize, coarse_u: &[f64], n_skeleton: usize) -> Result<Vec<f64>> {
        let below = level - 1;
        let (p, lift) = (&self.prolongations[below], &self.lifts[below]);
        let obstacles = self.obstacles.map(|o| (&o[below], &o[level]));
        let obstacle_sizes = obstacles.map_or((coarse_u.len(), n_skeleton), |(coarse, fine)| {
            (coarse.lower.len(), fine.lower.len())
        });
        if p.nrows() != n_skeleton
            || p.ncols() != coarse_u.len()
            || lift.len() != p.nrows()
            || obstacle_sizes != (coarse_u.len(), n_skeleton)
        {
            return Err(Error::numerical(
                STAGE,
                "prolongation",
                format!(
                    "prolongation {below} is {} × {} with a lift of {} and obstacles at {} and {} unknowns; the levels have {} and {n_skeleton} skeleton unknowns",
                    p.nrows(),
                    p.ncols(),
                    lift.len(),
                    obstacle_sizes.0,
                    obstacle_sizes.1,
                    coarse_u.len(),
                ),
            ));
        }
        let mut start = mat_vec(p, coarse_u);
        start.iter_mut().zip(lift).for_each(|(s, l)| *s += l);
        let Some((coarse, fine)) = obstacles else {
            return Ok(start);
        };
        // σ = 1: u ≥ φ; σ = −1: u ≤ ψ.
        let mut follow = |coarse: &[f64], fine: &[f64], sigma: f64| {
            let penetration: Vec<f64> = (coarse_u.iter().zip(coarse))
                .map(|(u, b)| sigma * (sigma * (u - b)).min(0.0))
                .collect();
            let shift = mat_vec(p, &penetration);
            for ((s, b), d) in start.iter_mut().zip(fine).zip(&shift) {
                if sigma * (b + d - *s) > 0.0 {
                    *s = b + d;
                }
            }
        };
        follow(&coarse.lower, &fine.lower, 1.0);
        if let (Some(coarse), Some(fine)) = (&coarse.upper, &fine.upper) {
            follow(coarse, fine, -1.0);
        }
        Ok(start)
    }
}

/// A level made ready for Newton: its problem condensed, its K in sweep
/// order (the top of its V-cycle), the dual diagonal of its KKT measure.
struct LevelSetup<'p> {
    level: usize,
    condensed: Condensed<'p>,
    k: SweptLevel,
    compliance: Vec<f64>,
}

impl<'p> LevelSetup<'p> {
    /// Level `level` of `problem`, whose C is `taken` when the solve holds
    /// it apart from the problem: given back unless the condensed rows hold
    /// it ([`Condensed::constraint_matrix`]), dropped before K is put in
    /// sweep order (the set-up's largest allocation).
    fn new(
        problem: &'p ContactProblem,
        taken: Option<SparseColMat<usize, f64>>,
        level: usize,
        options: &MultigridNewtonOptions,
    ) -> Result<(Self, Option<SparseColMat<usize, f64>>)> {
        let (condensed, skeleton_of) = Condensed::of(problem, taken.as_ref())?;
        let c = problem
            .constraint
            .as_ref()
            .expect("condensed: a constraint");
        let compliance = jacobi_dual_diagonal_of(
            &problem.matrix,
            taken.as_ref().unwrap_or(&c.matrix),
            &c.weights,
        );
        let taken = taken.filter(|_| !condensed.holds_constraint);
        // K, the skeleton block of A, from A's lower triangle straight into
        // sweep order.
        let a = &problem.matrix;
        let skeleton_lower = |visit: &mut dyn FnMut(usize, usize, f64)| {
            for j in 0..a.ncols() {
                let sj = skeleton_of[j];
                if sj == NONE {
                    continue;
                }
                for (i, v) in lower_column(a, j) {
                    if skeleton_of[i] != NONE {
                        visit(skeleton_of[i], sj, v);
                    }
                }
            }
        };
        let n_skeleton = condensed.n_skeleton();
        let k = SweptLevel::from_lower(level, n_skeleton, skeleton_lower, options.cycle.order)?;
        let setup = LevelSetup {
            level,
            compliance,
            condensed,
            k,
        };
        Ok((setup, taken))
    }
}

/// A level ready for its first Newton step: its cycle and its start.
struct Started<'p> {
    level: usize,
    condensed: Condensed<'p>,
    cycle: HessianCycle,
    u: Vec<f64>,
    compliance: Vec<f64>,
}

impl<'p> Started<'p> {
    /// The level of `setup` started from the interpolant of the level
    /// below's skeleton solution `coarse_u` (from 0 on level 0), its cycle
    /// stacked on the level below's (`below`, without its terms).
    fn on(
        setup: LevelSetup<'p>,
        below: Option<HessianCycle>,
        coarse_u: &[f64],
        transfers: &Transfers,
        options: &MultigridNewtonOptions,
    ) -> Result<Self> {
        let LevelSetup {
            level,
            condensed,
            k,
            compliance,
        } = setup;
        let below = level.checked_sub(1).map(|l| {
            let cycle = below.expect("every level above the coarsest has the cycle below");
            (cycle, &transfers.prolongations[l])
        });
        let cycle = HessianCycle::on(&condensed, k, below, options.cycle)?;
        let u = match level {
            0 => vec![0.0; condensed.n_skeleton()],
            _ => transfers.start(level, coarse_u, condensed.n_skeleton())?,
        };
        Ok(Started {
            level,
            condensed,
            cycle,
            u,
            compliance,
        })
    }
}

/// Newton on the `started` level (module docs); `finest`: the given
/// problem's level (its tolerance, and no cycle kept for a level above).
fn solve_level(
    started: Started,
    problem: &ContactProblem,
    finest: bool,
    options: &MultigridNewtonOptions,
    builder: &mut ReportBuilder,
) -> Result<LevelSolve> {
    let Started {
        level,
        condensed,
        mut cycle,
        mut u,
        compliance,
    } = started;
    let condensed = &condensed;
    let tol = if finest {
        options.tol
    } else {
        options.coarse_tol.max(options.tol)
    };
    let constraint = problem
        .constraint
        .as_ref()
        .expect("condensed: a constraint");
    // Newton converges in finitely many steps on a piecewise quadratic:
    // ten without a 1 % better KKT measure is a tolerance the solves
    // cannot reach.
    let mut monitor = Monitor::new(STAGE, "KKT measure").with_stagnation_window(10);
    let mut clamped = condensed.clamp(&u, options.threads);
    let mut old_lambda = vec![0.0; condensed.g.len()];
    let (mut newton_steps, mut cg_iterations) = (0, 0);
    let (mut step_length, mut active_changes, mut cg_step) = (0.0, 0usize, 0usize);
    loop {
        let Iterate {
            x,
            lambda,
            ax,
            cx,
            ct_lambda,
            residual,
            gradient,
        } = condensed.iterate(cycle.k_product(condensed, &u), &u, &clamped);
        check_finite(STAGE, newton_steps, "x", &x)?;
        let measures = kkt_measures_with(
            problem,
            &x,
            &lambda,
            Products {
                ax: Some(&ax),
                cx: Some(&cx),
                ct_lambda: Some(&ct_lambda),
                compliance: Some(&compliance),
            },
            options.threads,
        );
        let dual_step = dual_step_norm(&lambda, &old_lambda, &constraint.weights, DualNorm::L2);
        builder.record(
            builder.iterations + 1,
            dual_step,
            measures,
            &[
                level as f64,
                cg_step as f64,
                step_length,
                active_changes as f64,
            ],
        );
        let converged = measures.kkt <= tol;
        if converged || newton_steps >= options.max_iter {
            // C is made again once the cycle and the products are gone.
            drop((ax, cx, ct_lambda, residual, gradient, clamped));
            let cycle = match finest {
                true => {
                    drop(cycle);
                    None
                }
                false => Some(cycle.without_terms(condensed)?),
            };
            let constraint_matrix = (finest && condensed.holds_constraint)
                .then(|| condensed.constraint_matrix(problem.n()));
            return Ok(LevelSolve {
                u,
                cycle,
                x,
                lambda,
                measures,
                newton_steps,
                cg_iterations,
                converged,
                constraint_matrix,
            });
        }
        monitor.stagnation(newton_steps, measures.kkt, tol)?;
        // The whole problem's vectors served the measures: not held through
        // the step's solve (at 2049² they are 0.4 GB).
        drop((x, ax, cx, ct_lambda));
        old_lambda = lambda;
        cycle.follow(condensed, &clamped.active)?;
        let rhs: Vec<f64> = gradient.iter().map(|g| -g).collect();
        // While the active set moves, the step mostly moves it: a loose
        // solve. Once it holds, as tight as the KKT measure needs.
        let eta = if active_changes > 0 {
            0.1
        } else {
            measures.kkt.min(0.1).max(0.1 * tol / measures.kkt)
        };
        let (delta, its) = cycle.solve(&rhs, eta, options.max_cg);
        check_finite(STAGE, newton_steps, "the Newton step", &delta)?;
        let slope: f64 = gradient.iter().zip(&delta).map(|(g, d)| g * d).sum();
        if slope >= 0.0 {
            return Err(Error::numerical(
                STAGE,
                "Newton step",
                format!("level {level}, step {}: not a descent direction (∇J·δ = {slope:e}; CG made {its} iterations)", newton_steps + 1),
            ));
        }
        // Armijo backtracking on J, its change computed without cancellation.
        let residual_slope: f64 = residual.iter().zip(&delta).map(|(r, d)| r * d).sum();
        // δᵀKδ, a product with K: only for a trial that moves the active set.
        let mut curvature = None;
        let mut t = 1.0;
        let (trial, next) = loop {
            let trial: Vec<f64> = u.iter().zip(&delta).map(|(a, d)| a + t * d).collect();
            let next = condensed.clamp(&trial, options.threads);
            // On the same active set J is the quadratic whose Hessian CG
            // solved with: a CG step decreases it by ½ δᵀHδ > 0, and near the
            // solution that decrease lies below the round-off of J's change.
            if next.active == clamped.active {
                break (trial, next);
            }
            let curvature = *curvature.get_or_insert_with(|| {
                let k_delta = cycle.k_product(condensed, &delta);
                k_delta.iter().zip(&delta).map(|(a, d)| a * d).sum::<f64>()
            });
            let change = condensed.change_along(&clamped, &next, t, residual_slope, curvature);
            if change <= 1e-4 * t * slope {
                break (trial, next);
            }
            t *= 0.5;
            if t < 1e-12 {
                return Err(Error::numerical(
                    STAGE,
                    "line search",
                    format!("level {level}, step {}: J does not decrease along the Newton step (slope {slope:e}, KKT measure {:.3e})", newton_steps + 1, measures.kkt),
                ));
            }
        };
        u = trial;
        active_changes = next
            .active
            .iter()
            .zip(&clamped.active)
            .filter(|(a, b)| a != b)
            .count();
        clamped = next;
        newton_steps += 1;
        cg_iterations += its;
        (step_length, cg_step) = (t, its);
    }
}
