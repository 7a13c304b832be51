//! The Newton matrix of the active set and the solves of its steps: the
//! matrix (A, the scaled constraint rows, the multiplier diagonal that alone
//! changes between steps), and each PDAS step's solve, with the last
//! factorisation where few constraints switched ([`SwitchedSolve`]), else
//! factorised anew through the linear-solver seam.

use super::{ActiveSetOptions, STAGE};
use crate::error::{Error, Result};
use crate::linalg::{norm_inf, refine, Changed, Factors, LinearSolver, MatrixKind};
use crate::solvers::{Constraint, ContactProblem};
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use std::sync::Arc;
use std::time::Instant;

/// The Newton matrix with its fixed entries and the positions of the
/// multiplier diagonal, the one part that changes from step to step.
/// Symmetric (A symmetric): stored as its lower triangle, the storage
/// every symmetric factorisation reads (`linalg`). Its leading block is
/// the problem's A itself: [`NewtonMatrix::lend`] builds it in A's own
/// arrays and [`NewtonMatrix::give_back`] returns them, so the solve holds
/// one copy of A, not two (the shell at n = 64, active set: peak RSS
/// 235 → 206 MB).
pub(super) struct NewtonMatrix {
    /// Shared with each step's factorisation for its refinement.
    pub(super) matrix: Arc<SparseColMat<usize, f64>>,
    pub(super) kind: MatrixKind,
    /// The order n of A, the leading block.
    pub(super) n: usize,
    /// Value position of the diagonal entry (n + i, n + i).
    pub(super) diagonal: Vec<usize>,
    /// The diagonal d_off of an inactive row (`active_set` module docs).
    pub(super) switched_off: f64,
    /// The scaling s_i (λ_i = s_i μ_i).
    pub(super) scale: Vec<f64>,
    /// S̃ of A for the measures (`measures::jacobi_dual_diagonal`), made
    /// before A is lent.
    pub(super) compliance: Vec<f64>,
    /// The threads of its products (`solver.threads`).
    pub(super) threads: usize,
}

impl NewtonMatrix {
    /// The Newton matrix of `problem`, built in the arrays of its A, which
    /// it takes: `problem.matrix` is 0 × 0 until [`NewtonMatrix::give_back`]
    /// (read A x through [`NewtonMatrix::a_product`] meanwhile). A symmetric
    /// A is first kept as its lower triangle.
    pub(super) fn lend(
        problem: &mut ContactProblem,
        kind: MatrixKind,
        compliance: Vec<f64>,
        threads: usize,
    ) -> Result<Self> {
        let lower = kind != MatrixKind::General;
        if lower {
            problem.store_lower_triangle();
        }
        let (n, m) = (problem.n(), problem.n_multipliers());
        // A's arrays, compressed (no unused room per column); rows are
        // sorted within each column, as in every matrix `linalg` reads. The
        // pipeline's A is compressed already: no pass over it then.
        let a = problem.take_matrix();
        let a = match a.symbolic().col_nnz() {
            Some(_) => crate::linalg::retain_entries(a, n, n, |_, _| true),
            None => a,
        };
        let a_max = norm_inf(a.val()).max(f64::MIN_POSITIVE);
        let c = problem.constraint.as_ref().expect("a constrained problem");
        let scale = constraint_scaling(c, a_max)?;
        // The rows of C, for a whole matrix's multiplier columns.
        let c_rows = match lower {
            true => None,
            false => Some(constraint_rows(c)?),
        };
        let cs = c.matrix.symbolic();
        let (symbolic, mut values) = a.into_parts();
        let (_, _, a_col_ptr, _, mut row_idx) = symbolic.into_parts();
        // Columns 0..n: A's column, then the rows n + i of C's column j,
        // s_i C_ij. Columns n..n+m: s_i (row i of C)ᵀ (whole only), then
        // the diagonal (set by each step).
        let mut col_ptr = Vec::with_capacity(n + m + 1);
        col_ptr.push(0);
        for j in 0..n {
            let c_before = col_ptr[j] - a_col_ptr[j];
            col_ptr.push(a_col_ptr[j + 1] + c_before + cs.row_idx_of_col_raw(j).len());
        }
        let nnz = col_ptr[n] + m + c_rows.as_ref().map_or(0, |rows| rows.val().len());
        // (Exact: `resize` alone would double the capacity.)
        row_idx.reserve_exact(nnz - row_idx.len());
        values.reserve_exact(nnz - values.len());
        row_idx.resize(nnz, 0);
        values.resize(nnz, 0.0);
        // The multiplier columns lie past every entry of A: written first.
        let mut diagonal = Vec::with_capacity(m);
        let mut k = col_ptr[n];
        for i in 0..m {
            if let Some(rows) = &c_rows {
                for (j, &v) in rows.symbolic().row_idx_of_col(i).zip(rows.val_of_col(i)) {
                    (row_idx[k], values[k]) = (j, scale[i] * v);
                    k += 1;
                }
            }
            diagonal.push(k);
            (row_idx[k], values[k]) = (n + i, 0.0);
            k += 1;
            col_ptr.push(k);
        }
        // A's columns move back from the last one: column j's new place
        // starts at or after its old one and ends before column j + 1's.
        for j in (0..n).rev() {
            let (old, to) = (a_col_ptr[j]..a_col_ptr[j + 1], col_ptr[j]);
            let mut k = to + old.len();
            row_idx.copy_within(old.clone(), to);
            values.copy_within(old, to);
            for (i, &v) in cs.row_idx_of_col(j).zip(c.matrix.val_of_col(j)) {
                (row_idx[k], values[k]) = (n + i, scale[i] * v);
                k += 1;
            }
            debug_assert_eq!(k, col_ptr[j + 1]);
        }
        let symbolic = SymbolicSparseColMat::new_checked(n + m, n + m, col_ptr, None, row_idx);
        Ok(NewtonMatrix {
            matrix: Arc::new(SparseColMat::new(symbolic, values)),
            kind,
            n,
            diagonal,
            switched_off: a_max / (f64::EPSILON * f64::EPSILON),
            scale,
            compliance,
            threads,
        })
    }

    /// Gives `problem` its A back: the leading block, in the same arrays
    /// (the entries of C and the multiplier columns dropped). Every
    /// factorisation sharing the matrix is dropped first.
    pub(super) fn give_back(self, problem: &mut ContactProblem) {
        let matrix = Arc::try_unwrap(self.matrix)
            .unwrap_or_else(|_| panic!("a factorisation still shares the Newton matrix"));
        let n = self.n;
        problem.matrix = crate::linalg::retain_entries(matrix, n, n, |i, _| i < n);
    }

    /// A x, from the leading block: the product with (x, 0).
    pub(super) fn a_product(&self, x: &[f64]) -> Vec<f64> {
        let mut z = x.to_vec();
        z.resize(self.matrix.ncols(), 0.0);
        let mut y = crate::linalg::product(&self.matrix, self.kind, &z, self.threads);
        y.truncate(self.n);
        y
    }

    /// The multiplier diagonal −Δ_i of an interior-point step.
    pub(super) fn set_barrier(&mut self, delta: &[f64]) {
        self.set_diagonal(|i| -delta[i]);
    }

    /// The multiplier diagonal of the active set: 0 on it, −d_off off it.
    pub(super) fn set_active(&mut self, active: &[bool]) {
        let off = self.switched_off;
        self.set_diagonal(|i| if active[i] { 0.0 } else { -off });
    }

    pub(super) fn set_diagonal(&mut self, value: impl Fn(usize) -> f64) {
        let values = Arc::get_mut(&mut self.matrix)
            .expect("the previous step's factorisation is dropped")
            .val_mut();
        for (i, &pos) in self.diagonal.iter().enumerate() {
            values[pos] = value(i);
        }
    }
}

/// The row scaling s_i = max|A| / max_j |C_ij| of the Newton matrix.
pub(super) fn constraint_scaling(c: &Constraint, a_max: f64) -> Result<Vec<f64>> {
    let m = c.obstacle.len();
    let cs = c.matrix.symbolic();
    let mut row_max = vec![0.0f64; m];
    for j in 0..c.matrix.ncols() {
        for (i, v) in cs.row_idx_of_col(j).zip(c.matrix.val_of_col(j)) {
            row_max[i] = row_max[i].max(v.abs());
        }
    }
    let mut scale = Vec::with_capacity(m);
    for (i, &row_max) in row_max.iter().enumerate() {
        if row_max == 0.0 || !row_max.is_finite() {
            return Err(Error::numerical(
                STAGE,
                "constraint matrix",
                format!("row {i} of C is empty or not finite"),
            ));
        }
        scale.push(a_max / row_max);
    }
    Ok(scale)
}

/// The linear solves of the PDAS steps: each step's Newton system, with
/// the last factorisation while a switched solve pays ([`SwitchedSolve`]),
/// else factorised anew (the multiplier diagonal changed:
/// [`Changed::Declared`]).
pub(super) struct PdasSolves<'f> {
    factorizer: &'f mut dyn LinearSolver,
    /// The last factorisation and the set it was made for, while PDAS
    /// steps may be solved with it.
    kept: Option<(Box<dyn Factors>, Vec<bool>)>,
    c_rows: Option<SparseColMat<usize, f64>>,
    /// A switched step that took longer than the last factorised one ends
    /// switching for the run: where solves cost a large part of a
    /// factorisation (the membrane disk p1b-p0 at n = 256: 0.66 s switched
    /// against 0.52 s factorised), the bordered system's four do not pay.
    switching: bool,
    factorised_seconds: f64,
    refinement_steps: usize,
    /// Steps solved with the last factorisation.
    pub(super) switched_steps: usize,
}

impl<'f> PdasSolves<'f> {
    pub(super) fn new(
        factorizer: &'f mut dyn LinearSolver,
        c: &Constraint,
        options: &ActiveSetOptions,
    ) -> Result<Self> {
        Ok(PdasSolves {
            factorizer,
            kept: None,
            c_rows: match options.switched_steps {
                true => Some(constraint_rows(c)?),
                false => None,
            },
            switching: options.switched_steps,
            factorised_seconds: f64::INFINITY,
            refinement_steps: options.refinement_steps,
            switched_steps: 0,
        })
    }

    /// z of the step on `active` with right side `rhs`, and its relative
    /// residual ‖b − M z‖∞/‖b‖∞; sets the Newton matrix's diagonal to
    /// `active` when it factorises.
    pub(super) fn solve(
        &mut self,
        newton: &mut NewtonMatrix,
        active: &[bool],
        rhs: &[f64],
    ) -> Result<(Vec<f64>, f64)> {
        let t = Instant::now();
        let switched = match (&self.kept, &self.c_rows) {
            (Some((f, factorised)), Some(c_rows)) if self.switching => {
                SwitchedSolve::new(f.as_ref(), factorised, active, newton, c_rows)
                    .and_then(|switched| switched.solve(f.as_ref(), newton, rhs))
            }
            _ => None,
        };
        if let Some(solved) = switched {
            self.switched_steps += 1;
            self.switching = t.elapsed().as_secs_f64() < self.factorised_seconds;
            return Ok(solved);
        }
        // The Newton matrix is shared with the kept factorisation.
        drop(self.kept.take());
        newton.set_active(active);
        let (factorization, mut z, solve_residual) =
            self.factorizer
                .factor_and_solve_shared(&newton.matrix, rhs, Changed::Declared)?;
        // LU: refinement steps on top; LDLᵀ solves refine themselves.
        let steps = match factorization.refines_itself() {
            true => 0,
            false => self.refinement_steps,
        };
        // (No steps: the factorisation's own check measured the residual.)
        let linear_residual = match steps {
            0 => solve_residual,
            _ => refine(
                &newton.matrix,
                newton.kind,
                factorization.as_ref(),
                rhs,
                &mut z,
                steps,
                newton.threads,
            ),
        };
        self.kept = Some((factorization, active.to_vec()));
        self.factorised_seconds = t.elapsed().as_secs_f64();
        Ok((z, linear_residual))
    }
}

/// The rows of C, each as a column: (C's transpose, column-major).
pub(super) fn constraint_rows(c: &Constraint) -> Result<SparseColMat<usize, f64>> {
    c.matrix
        .as_ref()
        .transpose()
        .to_col_major()
        .map_err(|e| Error::numerical(STAGE, "constraint matrix", format!("its transpose: {e:?}")))
}

/// A PDAS step solved with the factorisation of the last factorised
/// Newton matrix M, whose active set differs from this step's in r
/// constraints. The step's matrix M' differs from M only in those
/// multipliers' diagonal entries (0 on the set, −d_off off it), so M' z = b
/// is the bordered system
///
///   [M  W] [z]   [b_M]
///   [Wᵀ 0] [ω] = [h  ],
///
/// one column per switched constraint: a constraint switched off pins its
/// multiplier (w = e_(n+i), h = 0; M's equation of that row is relaxed by
/// ω_i); one switched on adds its row of the Newton matrix, s_j C_j, as a
/// column (h = its right-hand side; M decouples its old row, whose right
/// side is set to 0), and ω_j is its multiplier. Through the Schur
/// complement G = Wᵀ M⁻¹ W (r × r): ω = G⁻¹ (Wᵀ M⁻¹ b_M − h), z = M⁻¹ (b_M −
/// W ω), two solves with M's factors. G comes from the columns' forward
/// sweeps over the paths of the elimination tree they reach
/// ([`Factors::inverse_gram`]), a fraction of a factorisation when r
/// is small (the fringe the last PDAS steps switch). Exact in exact
/// arithmetic; refined against M' like any solve.
pub(super) struct SwitchedSolve {
    /// Constraints switched on and off against the factorised set.
    pub(super) on: Vec<usize>,
    pub(super) off: Vec<usize>,
    /// W's columns: the off ones (e_(n+i)), then the on ones (s_j C_j).
    pub(super) columns: Vec<Vec<(usize, f64)>>,
    /// s_i C_i of the constraints switched off: their rows of M' read
    /// s_i C_i x − d_off μ_i = 0.
    pub(super) off_rows: Vec<Vec<(usize, f64)>>,
    pub(super) switched_off: f64,
    pub(super) n: usize,
    pub(super) g: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

/// A switched solve is refined once (kept unless its residual grew), and
/// again while its relative residual ‖b − M'z‖∞ / ‖b‖∞ is above
/// [`SWITCHED_ROUND_OFF`] and halves (at most this many steps):
/// the multipliers ω come out of G's solve, and a small residual alone
/// does not make them accurate (the shell at n = 128: unrefined 1.6e-15
/// left the KKT measure at 2.0e-10 and PDAS stagnated; refined once, 6e-16
/// and 1.7e-11). A solve that ends above [`SWITCHED_ACCEPTED`] is refused:
/// the step is factorised instead.
const SWITCHED_REFINEMENTS: usize = 4;
/// Solves with M's factors in a switched step: the bordered solve and
/// one refinement, two each.
const SWITCHED_SOLVES: usize = 4;
const SWITCHED_ACCEPTED: f64 = 1e-12;
/// The relative residual from which a switched solve's refinement stops
/// after its first step: at it, a second step never halved it (the shell
/// at n = 256, every switched step: unrefined 2.4e-15 … 2.6e-15, refined
/// once 6.1e-16, twice 4.9e-16 … 6.1e-16), and each step is two solves
/// and a product, 0.85 s there.
const SWITCHED_ROUND_OFF: f64 = 1e-15;

impl SwitchedSolve {
    /// None when nothing switched or the sweep of the columns would cost
    /// too much ([`Factors::inverse_gram`]).
    pub(super) fn new(
        f: &dyn Factors,
        factorised: &[bool],
        active: &[bool],
        newton: &NewtonMatrix,
        c_rows: &SparseColMat<usize, f64>,
    ) -> Option<Self> {
        let n = newton.n;
        let on: Vec<usize> = (0..active.len())
            .filter(|&i| active[i] && !factorised[i])
            .collect();
        let off: Vec<usize> = (0..active.len())
            .filter(|&i| !active[i] && factorised[i])
            .collect();
        let r = on.len() + off.len();
        if r == 0 {
            return None;
        }
        let row = |i: usize| -> Vec<(usize, f64)> {
            let s = newton.scale[i];
            let rows = c_rows.symbolic().row_idx_of_col(i);
            rows.zip(c_rows.val_of_col(i))
                .map(|(j, &v)| (j, s * v))
                .collect()
        };
        let mut columns: Vec<Vec<(usize, f64)>> = off.iter().map(|&i| vec![(n + i, 1.0)]).collect();
        columns.extend(on.iter().map(|&j| row(j)));
        let gram = f.inverse_gram(&columns, newton.matrix.nrows(), SWITCHED_SOLVES)?;
        Some(SwitchedSolve {
            off_rows: off.iter().map(|&i| row(i)).collect(),
            on,
            off,
            columns,
            switched_off: newton.switched_off,
            n,
            g: nalgebra::DMatrix::from_column_slice(r, r, &gram).lu(),
        })
    }

    /// One bordered solve (two with M's factors), not refined; None when
    /// G is singular.
    pub(super) fn raw(&self, f: &dyn Factors, b: &[f64]) -> Option<Vec<f64>> {
        let n = self.n;
        let n_off = self.off.len();
        let mut b_m = b.to_vec();
        let mut h = vec![0.0; self.columns.len()];
        for (q, &j) in self.on.iter().enumerate() {
            h[n_off + q] = std::mem::take(&mut b_m[n + j]);
        }
        let mut y = b_m.clone();
        f.solve_unrefined_in_place(&mut y);
        let schur_rhs = nalgebra::DVector::from_iterator(
            h.len(),
            self.columns
                .iter()
                .zip(&h)
                .map(|(column, h)| column.iter().map(|&(i, v)| v * y[i]).sum::<f64>() - h),
        );
        let omega = self.g.solve(&schur_rhs)?;
        for (column, w) in self.columns.iter().zip(omega.iter()) {
            for &(i, v) in column {
                b_m[i] -= v * w;
            }
        }
        f.solve_unrefined_in_place(&mut b_m);
        let mut z = b_m;
        for (&i, row) in self.off.iter().zip(&self.off_rows) {
            z[n + i] = row.iter().map(|&(j, v)| v * z[j]).sum::<f64>() / self.switched_off;
        }
        for (q, &j) in self.on.iter().enumerate() {
            z[n + j] = omega[n_off + q];
        }
        Some(z)
    }

    /// M' z from M's matrix: the switched multipliers never meet M's
    /// diagonal entries (0 or −d_off, the other of M''s: their difference
    /// would swamp the rest of the row), they are multiplied apart.
    pub(super) fn product(&self, newton: &NewtonMatrix, z: &[f64]) -> Vec<f64> {
        let n = self.n;
        let mut masked = z.to_vec();
        for &i in self.on.iter().chain(&self.off) {
            masked[n + i] = 0.0;
        }
        let mut y = crate::linalg::product(&newton.matrix, newton.kind, &masked, newton.threads);
        let n_off = self.off.len();
        for (q, &j) in self.on.iter().enumerate() {
            for &(k, v) in &self.columns[n_off + q] {
                y[k] += v * z[n + j];
            }
        }
        for (&i, row) in self.off.iter().zip(&self.off_rows) {
            for &(k, v) in row {
                y[k] += v * z[n + i];
            }
            y[n + i] -= self.switched_off * z[n + i];
        }
        y
    }

    /// z with M' z = b, refined against M', and its relative residual;
    /// None (the caller factorises) when it does not reach
    /// [`SWITCHED_ACCEPTED`] or is not finite.
    pub(super) fn solve(
        &self,
        f: &dyn Factors,
        newton: &NewtonMatrix,
        b: &[f64],
    ) -> Option<(Vec<f64>, f64)> {
        let b_norm = norm_inf(b).max(f64::MIN_POSITIVE);
        let residual = |z: &[f64]| -> (Vec<f64>, f64) {
            let r: Vec<f64> = b
                .iter()
                .zip(self.product(newton, z))
                .map(|(b, y)| b - y)
                .collect();
            let size = norm_inf(&r) / b_norm;
            (r, size)
        };
        let mut z = self.raw(f, b)?;
        let (mut r, mut size) = residual(&z);
        for step in 0..SWITCHED_REFINEMENTS {
            if step > 0 && size <= SWITCHED_ROUND_OFF {
                break;
            }
            let dz = self.raw(f, &r)?;
            let candidate: Vec<f64> = z.iter().zip(&dz).map(|(a, d)| a + d).collect();
            let (r_new, size_new) = residual(&candidate);
            let pays = match step {
                0 => size_new <= size,
                _ => size_new < 0.5 * size,
            };
            if !pays {
                break;
            }
            (z, r, size) = (candidate, r_new, size_new);
        }
        let finite = z.iter().all(|v| v.is_finite());
        (finite && size <= SWITCHED_ACCEPTED).then_some((z, size))
    }
}
