//! The numeric phase: a matrix's factors for the analysed pattern —
//! Cholesky, the signed-regularised LDLᵀ ([`RegularizedLdlt`], equilibrated,
//! refined against the unperturbed matrix) or LU, with the fallbacks
//! between them, the static condensation of interior groups, and the scale
//! of the entries ([`EntryScale`]) and equilibration they are judged and
//! scaled by. [`ReusableFactorization`] is the factoriser the linear-solver
//! seam's direct solver wraps.

use super::analysis::{
    ldlt_analysis, lu_analysis, AnalysedPattern, LdltAnalysis, OrderedMatrix, SymbolicAnalysis,
};
use super::condensed::{CondensationPlan, InteriorGroups, LocalFactors};
use super::kernels::{
    diagonal_entry, diagonal_position, first_non_finite, in_two_halves, lower_product, mat_vec_ref,
    norm_inf, two_threads, Storage, PARALLEL_ENTRIES,
};
use super::reuse::{
    FactorInputs, FixedScale, KeptElimination, KeptScale, SpareFactors, FACTORISATION_THREADS,
    GRAM_BUDGET, SOLVE_WORK_PER_ENTRY,
};
use super::solve::{
    check_solve, judge_solve, refine_to_round_off, solve_refined, test_rhs, SolveQuality,
    BACKWARD_ACCEPTED, COMPONENTWISE_ACCEPTED, CONDENSED_ACCEPTED, LDLT_ACCEPTED,
};
use super::tree_ldlt::{self, TreeSchedule};
use crate::error::{Error, Result};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::{LdltError, LdltRegularization};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::cholesky::{
    simplicial, supernodal, LdltRef, SymbolicCholesky, SymbolicCholeskyRaw,
};
use faer::sparse::linalg::solvers::{Llt, Lu, SymbolicLlt};
use faer::sparse::{FaerError, SparseColMat, SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};
use std::sync::Arc;

/// Lets the process keep the memory it frees for its next allocations
/// instead of returning it to the system (glibc's `mallopt`): every Newton
/// step allocates and frees factors of the same sizes (hundreds of MB), and
/// glibc serves blocks above its mmap threshold (≤ 32 MB) with fresh pages
/// that the kernel must fault in and zero each time (Uzawa: every
/// iteration's vectors of the problem's size); the shell's active set at
/// n = 128 spends 2.9 s of system time with it, 12.5 s without
/// (docs/work-precision.md). One arena for every thread: the second
/// threads would otherwise keep arenas of their own, never trimmed.
/// Returns whether the settings were accepted (other C libraries: nothing
/// is changed, false).
pub fn keep_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // Blocks up to 2 GB come from the heap; the heap's top is never
        // trimmed (−1 is the largest threshold).
        // SAFETY: mallopt only sets glibc's allocation parameters.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, i32::MAX) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, -1) == 1
                && libc::mallopt(libc::M_ARENA_MAX, 1) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

/// faer's parallelism: sequential (see [`two_threads`]).
pub(super) fn parallelism() -> Par {
    Par::Seq
}

/// What the matrix is known to be; picks the factorisation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatrixKind {
    /// Symmetric positive definite: Cholesky (LLᵀ).
    SymmetricPositiveDefinite,
    /// Symmetric and quasi-definite in structure: the unknowns
    /// [0, n_primal) are primal (positive pivots), the rest multipliers
    /// (negative pivots), as in [[K, Bᵀ], [B, 0]] with K positive definite
    /// on ker B. Signed-regularised LDLᵀ ([`RegularizedLdlt`]).
    SymmetricSaddle { n_primal: usize },
    /// Anything else: LU with partial pivoting.
    General,
}

/// How many solves a factorisation will serve: it picks the ordering of a
/// symmetric saddle matrix (the other kinds ignore it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Solves {
    /// One or a few (a Newton step, the floor): AMD, the least fill; some
    /// multipliers come before their neighbours, so each solve is refined
    /// once against the true matrix.
    Few,
    /// Many (Uzawa, FISTA, Lanczos): every multiplier right after its last
    /// primal neighbour in the AMD order, so no pivot is regularised and
    /// one triangular sweep per solve suffices. Measured on the shell at
    /// n = 64: factorisation 0.57 s instead of 0.47 s, solve 0.022 s instead
    /// of 0.032 s, peak RSS 418 MB instead of 367 MB.
    Many,
}

impl Solves {
    /// The ordering it picks for a symmetric saddle matrix, for messages.
    fn describe(self) -> &'static str {
        match self {
            Solves::Few => "AMD order",
            Solves::Many => "multipliers after their neighbours",
        }
    }
}

impl MatrixKind {
    /// What a matrix of this kind is, for error messages.
    pub fn describe(self) -> &'static str {
        match self {
            MatrixKind::SymmetricPositiveDefinite => "stiffness matrix",
            MatrixKind::SymmetricSaddle { .. } => "saddle-point matrix [[K_ρ, Bᵀ], [B, 0]]",
            MatrixKind::General => "system matrix",
        }
    }
}

pub enum Factorization {
    Cholesky(Llt<usize, f64>),
    Ldlt(Box<RegularizedLdlt>),
    Lu(Box<Lu<usize, f64>>),
    /// Interior groups eliminated, the Schur complement factorised
    /// ([`InteriorGroups`], `linalg/condensed.rs`).
    Condensed(Box<CondensedFactorization>),
}

/// A factorisation by static condensation: the local eliminations of the
/// interior groups and the factorisation of the Schur complement S.
pub struct CondensedFactorization {
    plan: Arc<CondensationPlan>,
    local: Arc<LocalFactors>,
    schur: Factorization,
    /// A and the scale of its entries, for the refinement of each solve:
    /// the local eliminations are not refined by S's factorisation
    /// (ρ = 1e12 shell: residual 5e-8 unrefined).
    matrix: RefinementMatrix,
    scale: EntryScale,
    /// The threads of its products and of the interior unknowns' recovery.
    threads: usize,
}

/// The matrix a condensed factorisation refines its solves against.
pub(super) enum RefinementMatrix {
    /// The caller's own matrix, shared ([`ReusableFactorization::factorize_and_solve_shared`]).
    Shared(Arc<SparseColMat<usize, f64>>, Storage),
    /// A symmetric matrix by its lower triangle ([`SymmetricLower`]).
    Symmetric(SymmetricLower),
    /// Any other: A's values on its pattern (shared with the
    /// [`ReusableFactorization`] that made the factorisation).
    General {
        pattern: Arc<SymbolicSparseColMat<usize>>,
        values: Vec<f64>,
    },
}

impl RefinementMatrix {
    /// A's values on the kept pattern (a general matrix's), else A's lower
    /// triangle (a symmetric one's: its pattern is only fingerprinted).
    fn of(a: &Shared<'_>, storage: Storage, pattern: &AnalysedPattern) -> Self {
        if let Shared::Owned(a) = a {
            return RefinementMatrix::Shared(a.clone(), storage);
        }
        match pattern {
            AnalysedPattern::Kept(pattern) => RefinementMatrix::General {
                pattern: pattern.clone(),
                values: (0..a.ncols())
                    .flat_map(|j| a.val_of_col(j))
                    .copied()
                    .collect(),
            },
            AnalysedPattern::Fingerprint { .. } => {
                RefinementMatrix::Symmetric(SymmetricLower::of(a))
            }
        }
    }

    /// a_ii.
    fn diagonal(&self, i: usize) -> f64 {
        match self {
            RefinementMatrix::Shared(a, _) => diagonal_entry(a.as_ref().as_ref(), i),
            RefinementMatrix::Symmetric(lower) => lower.diagonal(i),
            RefinementMatrix::General { pattern, values } => {
                diagonal_entry(SparseColMatRef::new((**pattern).as_ref(), values), i)
            }
        }
    }

    /// A x.
    fn product(&self, x: &[f64], threads: usize) -> Vec<f64> {
        match self {
            RefinementMatrix::Shared(a, storage) => {
                storage.product(a.as_ref().as_ref(), x, threads)
            }
            RefinementMatrix::Symmetric(lower) => lower.product(x, threads),
            RefinementMatrix::General { pattern, values } => {
                mat_vec_ref(SparseColMatRef::new((**pattern).as_ref(), values), x)
            }
        }
    }
}

/// A symmetric matrix by its lower triangle (CSC, 32-bit rows): y = A x
/// ([`lower_product`]) reads each off-diagonal entry once, for both of its
/// places. Half the memory of A, and of the traffic of the product that
/// refines every condensed solve (Uzawa: one per iteration). The upper
/// triangle is not read, as in the LDLᵀ (`Side::Lower`).
pub(super) struct SymmetricLower {
    col_ptr: Vec<usize>,
    rows: Vec<u32>,
    values: Vec<f64>,
}

impl SymmetricLower {
    fn of(a: &SparseColMat<usize, f64>) -> Self {
        let n = a.ncols();
        assert!(
            u32::try_from(n).is_ok(),
            "a matrix of order {n}: rows are 32-bit"
        );
        // Sized exactly: grown by doubling, the arrays and their copies
        // raised the peak by their own size again.
        let len = (0..n)
            .map(|j| a.symbolic().row_idx_of_col(j).filter(|&i| i >= j).count())
            .sum();
        let mut col_ptr = Vec::with_capacity(n + 1);
        let (mut rows, mut values) = (Vec::with_capacity(len), Vec::with_capacity(len));
        col_ptr.push(0);
        for j in 0..n {
            for (i, &v) in a.symbolic().row_idx_of_col(j).zip(a.val_of_col(j)) {
                if i >= j {
                    rows.push(i as u32);
                    values.push(v);
                }
            }
            col_ptr.push(rows.len());
        }
        SymmetricLower {
            col_ptr,
            rows,
            values,
        }
    }

    fn product(&self, x: &[f64], threads: usize) -> Vec<f64> {
        lower_product(&self.col_ptr, &self.rows, &self.values, x, threads)
    }

    /// a_jj (0 where not stored).
    fn diagonal(&self, j: usize) -> f64 {
        let column = self.col_ptr[j]..self.col_ptr[j + 1];
        diagonal_position(&self.rows[column.clone()], j).map_or(0.0, |p| self.values[column][p])
    }
}

impl CondensedFactorization {
    /// Solves A x = b (or Aᵀ x = b) in place: condense b, solve S,
    /// recover; then refined against A (not Aᵀ) to round-off.
    fn solve_in_place(&self, b: &mut [f64], transpose: bool) {
        if transpose {
            self.raw_solve(b, true);
        } else {
            self.solve_with_product(b);
        }
    }

    /// Solves A x = b, refined; returns A x from the refinement's last residual.
    fn solve_with_product(&self, b: &mut [f64]) -> Vec<f64> {
        solve_refined(
            b,
            |v| self.matrix.product(v, self.threads),
            |i| self.matrix.diagonal(i),
            &self.scale,
            |d| self.raw_solve(d, false),
        )
    }

    /// One solve, not refined against A. Nor is S's solve refined against
    /// S: the callers refine against A, whose residual S's own refinement
    /// would only anticipate. The transposed solve is the exception (no
    /// caller refines it), so S's solve is refined there.
    fn raw_solve(&self, b: &mut [f64], transpose: bool) {
        let mut x_r = self
            .plan
            .condense_rhs(&self.local, b, transpose, self.threads);
        if transpose {
            self.schur.solve_transpose_in_place(&mut x_r);
        } else {
            self.schur.solve_unrefined_in_place(&mut x_r);
        }
        self.plan
            .recover(&self.local, &x_r, b, transpose, self.threads);
    }

    /// Bᵀ A⁻¹ B = B_Iᵀ A_II⁻¹ B_I + B̃ᵀ S⁻¹ B̃ (B̃ = B_R − A_RI A_II⁻¹ B_I,
    /// the condensed columns) for sparse columns B of A (order n).
    fn gram(&self, columns: &[Vec<(usize, f64)>], n: usize, solves: usize) -> Option<Vec<f64>> {
        let Factorization::Ldlt(schur) = &self.schur else {
            return None;
        };
        let (remaining, interior): (Vec<_>, Vec<_>) = self
            .plan
            .condense_sparse(&self.local, columns, n)
            .into_iter()
            .map(|c| (c.remaining, c.interior))
            .unzip();
        let mut gram = schur.gram(&remaining, solves)?;
        let r = columns.len();
        for (q, interior_q) in interior.iter().enumerate() {
            for (p, column_p) in columns.iter().enumerate() {
                gram[p + q * r] += column_p
                    .iter()
                    .filter_map(|&(i, v)| {
                        let k = interior_q.binary_search_by_key(&i, |e| e.0).ok()?;
                        Some(v * interior_q[k].1)
                    })
                    .sum::<f64>();
            }
        }
        Some(gram)
    }

    /// The number of unknowns of the factorised Schur complement.
    pub fn n_schur(&self) -> usize {
        self.plan.n_schur()
    }
}

impl Factorization {
    /// Solves A x = b in place.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        self.solve_block_in_place(b, 1);
    }

    /// Solves A x = b in place (the same x as [`Factorization::solve_in_place`])
    /// and returns A x when the solve computed it for its refinement (LDLᵀ,
    /// condensed); None for Cholesky and LU, which do not refine.
    pub fn solve_with_product(&self, b: &mut [f64]) -> Option<Vec<f64>> {
        match self {
            Factorization::Ldlt(f) if !f.raw_solves_suffice => Some(f.solve_with_product(b)),
            Factorization::Condensed(f) => Some(f.solve_with_product(b)),
            _ => {
                self.solve_in_place(b);
                None
            }
        }
    }
}

/// Factorises `a` on one thread (symbolic analysis and numeric factorisation of
/// [`ReusableFactorization`], used once) and checks the factorisation on one
/// solve: a numerically singular matrix shows up as a non-finite or
/// inaccurate solution even when the factorisation itself "succeeds".
/// `what` names the matrix in error messages.
pub fn factorize_checked(
    a: &SparseColMat<usize, f64>,
    kind: MatrixKind,
    solves: Solves,
    what: &str,
) -> Result<Factorization> {
    factorize_checked_with(a, kind, solves, None, what)
}

/// [`factorize_checked`], condensing the `interior` groups first when given.
pub fn factorize_checked_with(
    a: &SparseColMat<usize, f64>,
    kind: MatrixKind,
    solves: Solves,
    interior: Option<&InteriorGroups>,
    what: &str,
) -> Result<Factorization> {
    let (f, _) = ReusableFactorization::analyze_with(a, kind, solves, interior, what, 1)?
        .factorize(a, what)?;
    Ok(f)
}

/// A factorisation whose symbolic analysis (fill-reducing ordering,
/// elimination structure) is computed once for a sparsity pattern and
/// reused by every numeric refactorisation of a matrix with that exact
/// pattern (explicit zeros included). Counts both, so callers can report
/// (and tests check) that only numeric refactorisations follow the first.
/// With interior groups ([`ReusableFactorization::analyze_with`]) the
/// factorised matrix is the Schur complement S, whose pattern is fixed by
/// the pattern of A: the counts are those of S.
pub struct ReusableFactorization {
    /// What each matrix is checked against: the analysed pattern.
    pattern: AnalysedPattern,
    /// The factoriser of A, or of S when condensed.
    direct: DirectFactorizer,
    condensation: Option<Arc<CondensationPlan>>,
    /// S of the last condensed matrix (shared with its factorisation), whose
    /// arrays the next one reuses once that factorisation is dropped: S's
    /// pattern exists once, not also in the plan and in a copy per matrix
    /// (the shell at n = 256: 118 MB of row indices).
    schur: Option<SharedMatrix>,
    /// The last matrix's eliminated groups (its local factors and the
    /// Schur terms where declared entries land), kept for the next one when
    /// the caller asked ([`ReusableFactorization::keep_eliminations`]).
    kept: Option<KeptElimination>,
    /// The value positions of A the caller declared to change between the
    /// matrices that reuse the kept eliminations.
    changing: Option<Vec<usize>>,
    /// A's kind and solves, for the fallback to A itself.
    kind: MatrixKind,
    solves: Solves,
    /// How A is stored (its pattern is the analysed one).
    storage: Storage,
}

/// A matrix shared with the factorisations that refine against it.
pub(super) type SharedMatrix = Arc<SparseColMat<usize, f64>>;

/// What changed in a matrix since the last one a [`ReusableFactorization`]
/// factorised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Changed {
    /// Any entry.
    Any,
    /// Only the entries declared to
    /// [`ReusableFactorization::keep_eliminations`] (each between remaining
    /// unknowns): the groups' eliminations are reused, and S is the last
    /// one with those entries updated (the first matrix after
    /// `keep_eliminations` is eliminated whole). The caller vouches for it
    /// (the active set's Newton steps change only their multiplier
    /// diagonal): neither the pattern nor the other entries are read again
    /// (declared entries on the diagonal: their scale is updated from
    /// them alone).
    Declared,
}

/// The symbolic analysis of one matrix pattern and its counts.
pub(super) struct DirectFactorizer {
    symbolic: SymbolicAnalysis,
    /// The kind of the matrices it is given (a symmetric one may be its
    /// lower triangle, [`Storage`]).
    kind: MatrixKind,
    /// How they are stored (their pattern is the analysed one).
    storage: Storage,
    symbolic_analyses: usize,
    numeric_factorizations: usize,
    /// Their work in whole numeric factorisations: each counts the
    /// fraction of a whole one's estimated work it did (less than 1 where
    /// an LDLᵀ kept supernodes of the last one).
    factorized_work: f64,
    /// Why each fallback was taken, in order (named by a failure of the
    /// factorisation it led to).
    fallbacks: Vec<String>,
    /// Whether LU is the last fallback; false for the Schur complement of a
    /// condensed factorisation, whose last fallback is A itself.
    lu_last: bool,
    /// The factor values of its last dropped LDLᵀ, for the next one.
    spare_factors: Arc<SpareFactors>,
    /// The scale and equilibration of the last matrix, for a next one that
    /// differs from it only in declared diagonal entries; the declared
    /// positions when [`KeptScale::of`] refused them (not asked again).
    kept_scale: Option<std::result::Result<KeptScale, Vec<usize>>>,
    /// The threads of its factorisations and kernels ([`two_threads`]).
    threads: usize,
}

impl ReusableFactorization {
    /// The symbolic analysis of the pattern of `a` (values are not read),
    /// for factorisations on one thread.
    pub fn analyze(
        a: &SparseColMat<usize, f64>,
        kind: MatrixKind,
        solves: Solves,
        what: &str,
    ) -> Result<Self> {
        Self::analyze_with(a, kind, solves, None, what, 1)
    }

    /// [`ReusableFactorization::analyze`] with the `interior` groups
    /// condensed (checked against `a`'s pattern: a group coupling with
    /// another group is an error naming it; no groups, or an empty list:
    /// A itself is factorised), for factorisations and kernels on
    /// `threads` ([`two_threads`]).
    pub fn analyze_with(
        a: &SparseColMat<usize, f64>,
        kind: MatrixKind,
        solves: Solves,
        interior: Option<&InteriorGroups>,
        what: &str,
        threads: usize,
    ) -> Result<Self> {
        if a.nrows() != a.ncols() {
            return Err(Error::numerical(
                what,
                "shape",
                format!("{}×{} is not square", a.nrows(), a.ncols()),
            ));
        }
        let (direct, condensation, schur) = match interior.filter(|g| !g.is_empty()) {
            None => (
                DirectFactorizer::analyze(a, kind, solves, what, threads)?,
                None,
                None,
            ),
            Some(groups) => {
                let (plan, schur) = CondensationPlan::new(a, groups, kind, what)?;
                let mut direct =
                    DirectFactorizer::analyze(&schur, plan.schur_kind, solves, what, threads)?;
                direct.lu_last = false;
                (direct, Some(Arc::new(plan)), Some(Arc::new(schur)))
            }
        };
        Ok(ReusableFactorization {
            pattern: AnalysedPattern::of(a, kind, threads),
            direct,
            condensation,
            schur,
            kept: None,
            changing: None,
            kind,
            solves,
            storage: Storage::of(a.as_ref(), kind),
        })
    }

    /// Keeps each condensed matrix's eliminated groups for next matrices
    /// that differ from it only in the entries at the value positions
    /// `changing` ([`Changed::Declared`]), each between remaining unknowns
    /// (else the next factorisation is an error naming it); None drops the
    /// kept ones. What is kept besides the local factors: one Schur term
    /// per declared entry (it was an array of S's size, 113 MB at the
    /// shell's n = 256).
    pub fn keep_eliminations(&mut self, changing: Option<&[usize]>) {
        self.changing = changing.map(<[usize]>::to_vec);
        self.kept = None;
    }

    /// Numeric factorisation of `a`, which must have the analysed pattern;
    /// checked on a test solve as [`factorize_checked`] does. Returns the
    /// factorisation and its test residual.
    pub fn factorize(
        &mut self,
        a: &SparseColMat<usize, f64>,
        what: &str,
    ) -> Result<(Factorization, f64)> {
        let (f, _, rel) = self.factorize_and_solve(a, &test_rhs(a.nrows()), what)?;
        Ok((f, rel))
    }

    /// Numeric factorisation of `a` and the solve of A x = b, checked on
    /// that solve instead of a test solve (one solve less per matrix).
    /// Returns the factorisation, x and ‖b − A x‖∞/‖b‖∞.
    pub fn factorize_and_solve(
        &mut self,
        a: &SparseColMat<usize, f64>,
        b: &[f64],
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        self.factorize_and_solve_matrix(Shared::Borrowed(a), b, Changed::Any, what)
    }

    /// [`ReusableFactorization::factorize_and_solve`] of a matrix the
    /// factorisation keeps a share of for its refinement instead of a copy
    /// (the active set's Newton matrix: 0.1 GB per step at the shell's
    /// n = 128); the caller changes its values only after dropping it,
    /// and says what `changed` since the last matrix factorised.
    pub fn factorize_and_solve_shared(
        &mut self,
        a: &Arc<SparseColMat<usize, f64>>,
        b: &[f64],
        changed: Changed,
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        self.factorize_and_solve_matrix(Shared::Owned(a.clone()), b, changed, what)
    }

    /// S and the local factors of `a`: the kept eliminations when only
    /// entries between remaining unknowns changed, else eliminated anew
    /// (and kept when asked; the old ones are dropped first). S is written
    /// into the last one's arrays when its factorisation is gone.
    fn condense(
        &mut self,
        plan: &CondensationPlan,
        a: &SparseColMat<usize, f64>,
        changed: Changed,
        what: &str,
    ) -> Result<(SharedMatrix, Arc<LocalFactors>)> {
        let last = self.schur.take().expect("a condensed factoriser keeps S");
        // The caller still holds the last factorisation: a copy.
        let mut s = Arc::try_unwrap(last).unwrap_or_else(|shared| (*shared).clone());
        let local = self.eliminate(plan, a, changed, s.val_mut(), what);
        let s = Arc::new(s);
        self.schur = Some(s.clone());
        Ok((s, local?))
    }

    /// S's values (see [`ReusableFactorization::condense`]) and the local
    /// factors.
    fn eliminate(
        &mut self,
        plan: &CondensationPlan,
        a: &SparseColMat<usize, f64>,
        changed: Changed,
        s_values: &mut [f64],
        what: &str,
    ) -> Result<Arc<LocalFactors>> {
        let values = a.val();
        if let (Changed::Declared, Some(kept)) = (changed, &self.kept) {
            // The same sum as S = terms + A_RR everywhere: bit for bit.
            for &(k, pos, term) in &kept.terms {
                s_values[pos] = term + values[k];
            }
            return Ok(kept.local.clone());
        }
        self.kept = None;
        let Some(changing) = &self.changing else {
            return Ok(Arc::new(plan.condense_into(a, s_values, what)?));
        };
        // The Schur terms first, then A_RR on top: the declared entries'
        // terms are read in between.
        s_values.fill(0.0);
        let local = Arc::new(plan.eliminate_into(a, s_values, what)?);
        let terms = changing
            .iter()
            .map(|&k| {
                let pos = plan.schur_position(k).ok_or_else(|| {
                    Error::numerical(
                        what,
                        "declared entry",
                        format!("value {k} of the matrix is not between remaining unknowns"),
                    )
                })?;
                Ok((k, pos, s_values[pos]))
            })
            .collect::<Result<Vec<_>>>()?;
        plan.add_remaining_entries(a, s_values);
        self.kept = Some(KeptElimination {
            terms,
            local: local.clone(),
            fixed_scale: None,
        });
        Ok(local)
    }

    fn factorize_and_solve_matrix(
        &mut self,
        matrix: Shared<'_>,
        b: &[f64],
        changed: Changed,
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        let a: &SparseColMat<usize, f64> = &matrix;
        // Declared changes since a kept elimination: the caller vouches
        // for the pattern and every other entry, so neither is read again
        // (a pass over A's rows and one over its values: 12 ms of a 0.34 s
        // Newton step at the shell's n = 128).
        let declared_scale = match (changed, &self.kept, &self.changing) {
            (Changed::Declared, Some(kept), Some(changing)) => {
                kept.fixed_scale.map(|f| f.with(a, changing, what))
            }
            _ => None,
        };
        let threads = self.direct.threads;
        if declared_scale.is_none() && !self.pattern.matches(a, threads) {
            return Err(Error::numerical(
                what,
                "sparsity pattern",
                "the matrix does not have the pattern of the symbolic analysis",
            ));
        }
        let Some(plan) = self.condensation.clone() else {
            let declared = match changed {
                Changed::Declared => self.changing.as_deref(),
                Changed::Any => None,
            };
            return self
                .direct
                .factorize_and_solve_declared(matrix.clone(), b, declared, what);
        };
        let read_whole = declared_scale.is_none();
        let scale = match declared_scale {
            Some(scale) => scale?,
            None => checked_scale(a, what, threads)?,
        };
        let norm = scale.norm;
        let storage = self.storage;
        let (s, local) = self.condense(&plan, a, changed, what)?;
        // A new kept elimination: the scale of what stays.
        if let (true, Some(kept), Some(changing)) = (read_whole, self.kept.as_mut(), &self.changing)
        {
            if kept.fixed_scale.is_none() {
                kept.fixed_scale = FixedScale::of(a, scale, changing);
            }
        }
        let b_s = plan.condense_rhs(&local, b, false, threads);
        // Declared changes of A change S only where they land.
        let declared: Option<Vec<usize>> = match (changed, &self.kept) {
            (Changed::Declared, Some(kept)) => Some(kept.terms.iter().map(|t| t.1).collect()),
            _ => None,
        };
        // S is shared with its factorisation (kept there for the refinement).
        let s = Shared::Owned(s);
        let Ok((mut schur, x_r, schur_relative)) =
            self.direct
                .factorize_and_solve_declared(s, &b_s, declared.as_deref(), what)
        else {
            // No LDLᵀ of S met its accuracy (S takes no LU: at the shell's
            // n = 256 it ran out of memory where the whole matrix's LDLᵀ
            // holds): A itself.
            drop((local, b_s));
            return self.factorize_whole(matrix, b, what);
        };
        // Only for many solves: the few-solves (AMD) order regularises pivots.
        if let (Factorization::Ldlt(ldlt), Solves::Many) = (&mut schur, self.solves) {
            ldlt.skip_refinement_if_exact();
        }
        let mut x = b.to_vec();
        plan.recover(&local, &x_r, &mut x, false, threads);
        let condensed = CondensedFactorization {
            plan: plan.clone(),
            local,
            schur,
            matrix: RefinementMatrix::of(&matrix, storage, &self.pattern),
            scale,
            threads,
        };
        let product = |v: &[f64]| condensed.matrix.product(v, threads);
        let diagonal = |i| condensed.matrix.diagonal(i);
        let refined_ax = refine_to_round_off(product, diagonal, &condensed.scale, &mut x, b, |d| {
            condensed.raw_solve(d, false)
        });
        // Judged on A itself, all of it as stored: the local eliminations
        // are not refined, and the refinement's copy reads a whole A's lower
        // triangle only (a whole A's round-off asymmetry moved the shell's
        // first residual at n = 128 from 2.6e-9 to 3.3e-9, too near the
        // acceptance bounds). A shared A is the refinement's own: its last
        // product is the judge's.
        let shared = matches!(condensed.matrix, RefinementMatrix::Shared(..));
        let judged_ax = shared.then_some(refined_ax);
        let f = Factorization::Condensed(Box::new(condensed));
        let checked = if norm_inf(b) == 0.0 {
            check_solve(a, storage, norm, &f, b, what, threads)
        } else {
            judge_solve(a, storage, norm, &x, b, judged_ax.as_deref(), what, threads)
                .map(|q| (x, q))
        };
        if let Ok((x, quality)) = checked {
            if quality.condensed_accepted(schur_relative) {
                return Ok((f, x, quality.relative));
            }
        }
        // S lost the accuracy A allows (cancellation in A_RR − A_RI A_II⁻¹
        // A_IR: the shell at ρ = 1e12, refined residual 5e-8 condensed, 3e-10
        // whole).
        drop(f);
        self.factorize_whole(matrix, b, what)
    }

    /// The fallback of a condensed factorisation: A itself from now on
    /// (with its own fallbacks, LU last).
    fn factorize_whole(
        &mut self,
        matrix: Shared<'_>,
        b: &[f64],
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        let analyses = self.direct.symbolic_analyses;
        self.condensation = None;
        self.schur = None;
        self.kept = None;
        let threads = self.direct.threads;
        self.direct = DirectFactorizer::analyze(&matrix, self.kind, self.solves, what, threads)?;
        self.direct.symbolic_analyses += analyses;
        self.direct.factorize_and_solve(matrix, b, what)
    }

    /// The factorisation in use: "Cholesky", "LDLᵀ" or "LU" (after a
    /// fallback, the one now used); of S when condensed.
    pub fn method(&self) -> &'static str {
        match &self.direct.symbolic {
            SymbolicAnalysis::Llt(_) => "Cholesky",
            SymbolicAnalysis::Ldlt { .. } => "LDLᵀ",
            SymbolicAnalysis::Lu(_) => "LU",
        }
    }

    /// Symbolic analyses done (1: the one of [`ReusableFactorization::analyze`]).
    pub fn symbolic_analyses(&self) -> usize {
        self.direct.symbolic_analyses
    }

    /// Numeric factorisations done with the one symbolic analysis.
    pub fn numeric_factorizations(&self) -> usize {
        self.direct.numeric_factorizations
    }

    /// The numeric factorisations' work in whole factorisations: below
    /// [`ReusableFactorization::numeric_factorizations`] where LDLᵀs kept
    /// the supernodes that their matrix's changes did not reach.
    pub fn factorized_work(&self) -> f64 {
        self.direct.factorized_work
    }

    /// The order of the factorised matrix: A's, or S's when condensed.
    pub fn factorized_order(&self) -> usize {
        self.condensation
            .as_ref()
            .map_or(self.pattern.nrows(), |plan| plan.n_schur())
    }
}

/// The scale of `a`'s entries ([`EntryScale`]), or an error naming its
/// first entry that is not finite.
pub(super) fn checked_scale(
    a: &SparseColMat<usize, f64>,
    what: &str,
    threads: usize,
) -> Result<EntryScale> {
    // Eight lanes of compare-and-select (they vectorise; f64::max's NaN
    // rule does not): NaN fails both comparisons, ∞ the second.
    const LANES: usize = 8;
    type Lanes = ([f64; LANES], [bool; LANES]);
    let part = |values: &[f64], (norm, finite): &mut Lanes| {
        let mut lanes = values.chunks_exact(LANES);
        for chunk in &mut lanes {
            for ((m, ok), v) in norm.iter_mut().zip(finite.iter_mut()).zip(chunk) {
                let v = v.abs();
                *m = if v > *m { v } else { *m };
                *ok &= v <= f64::MAX;
            }
        }
        for (v, ok) in lanes.remainder().iter().zip(finite.iter_mut()) {
            let v = v.abs();
            norm[0] = if v > norm[0] { v } else { norm[0] };
            *ok &= v <= f64::MAX;
        }
    };
    let (values, col_ptr) = (a.val(), a.symbolic().col_ptr());
    let row_idx = a.symbolic().row_idx();
    // Columns `columns`: the largest off-diagonal and diagonal entries and
    // whether all are finite (rows are sorted within a column).
    let of_columns = |columns: std::ops::Range<usize>| {
        let unseen: Lanes = ([0.0; LANES], [true; LANES]);
        let (mut off, mut diagonal) = (unseen, unseen);
        for j in columns {
            let (rows, col) = (
                &row_idx[col_ptr[j]..col_ptr[j + 1]],
                &values[col_ptr[j]..col_ptr[j + 1]],
            );
            match diagonal_position(rows, j) {
                Some(p) => {
                    part(&col[..p], &mut off);
                    part(&col[p..=p], &mut diagonal);
                    part(&col[p + 1..], &mut off);
                }
                None => part(col, &mut off),
            }
        }
        let finite = off.1.iter().chain(&diagonal.1).all(|&ok| ok);
        (norm_inf(&off.0), norm_inf(&diagonal.0), finite)
    };
    let (off_diagonal, diagonal, finite) =
        in_two_halves(a, threads, of_columns, |(o1, d1, f1), (o2, d2, f2)| {
            (o1.max(o2), d1.max(d2), f1 & f2)
        });
    match finite {
        true => Ok(EntryScale::of(off_diagonal, diagonal)),
        false => Err(non_finite_entry(
            what,
            first_non_finite(values).expect("a non-finite entry"),
        )),
    }
}

/// The error for a matrix whose value `k` is not finite.
pub(super) fn non_finite_entry(what: &str, k: usize) -> Error {
    Error::numerical(what, "matrix entries", format!("entry {k} is not finite"))
}

/// The size of a matrix's entries, for the round-off level of a residual
/// row by row ([`EntryScale::excess`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct EntryScale {
    /// ‖A‖ = max |a_ij| (at least the smallest positive number).
    pub(super) norm: f64,
    /// max |a_ij|, i ≠ j.
    pub(super) off_diagonal: f64,
}

impl EntryScale {
    /// From the largest off-diagonal and diagonal |entries|.
    pub(super) fn of(off_diagonal: f64, diagonal: f64) -> Self {
        EntryScale {
            norm: off_diagonal.max(diagonal).max(f64::MIN_POSITIVE),
            off_diagonal,
        }
    }

    /// How far the residual r of A x = b is above round-off (`diagonal(i)`
    /// = a_ii): max_i |r_i| / 4ε (max(max_{j≠i}|a_ij| ‖x‖∞, |a_ii x_i|) +
    /// ‖b‖∞), ≤ 1 at round-off. The level of every row is at most the
    /// normwise 4ε (max|a_ij| ‖x‖∞ + ‖b‖∞), reached when the largest entries
    /// are off the diagonal or on the largest unknowns; a row with a huge
    /// diagonal entry on a small unknown (a constraint the active set
    /// switches off by its diagonal, an interior-point barrier) has its own,
    /// higher level: its round-off (ε |a_ii x_i|, as large as the rest of
    /// its row, whose sum it balances) is no longer taken for that of the
    /// other rows. With the normwise level alone the refinement stopped at
    /// the exact active set with the shell's stationarity 2.1e-10 at
    /// n = 128 (1.6e-11 with the switched rows' entries zero). A row within
    /// the common level 4ε (max_{i≠j}|a_ij| ‖x‖∞ + ‖b‖∞) is measured
    /// against it (its own is no lower): its diagonal is not read, and the
    /// value is exact only above 1.
    pub(super) fn excess(
        &self,
        r: &[f64],
        x: &[f64],
        b: &[f64],
        diagonal: impl Fn(usize) -> f64,
    ) -> f64 {
        let common = self.off_diagonal * norm_inf(x);
        let b_norm = norm_inf(b);
        let level = 4.0 * f64::EPSILON;
        let at_common = level * (common + b_norm);
        // The diagonal is read only where the common level is exceeded.
        r.iter()
            .zip(x)
            .enumerate()
            .fold(0.0f64, |m, (i, (ri, xi))| {
                let ri = ri.abs();
                m.max(match ri <= at_common {
                    true => ri / at_common,
                    false => ri / (level * (common.max((diagonal(i) * xi).abs()) + b_norm)),
                })
            })
    }
}

impl DirectFactorizer {
    fn analyze(
        a: &SparseColMat<usize, f64>,
        kind: MatrixKind,
        solves: Solves,
        what: &str,
        threads: usize,
    ) -> Result<Self> {
        let symbolic = match kind {
            MatrixKind::General => lu_analysis(a, what)?,
            MatrixKind::SymmetricSaddle { n_primal } => {
                ldlt_analysis(a, n_primal, solves, what, threads)?
            }
            MatrixKind::SymmetricPositiveDefinite => SymbolicAnalysis::Llt(
                SymbolicLlt::try_new(a.symbolic(), Side::Lower)
                    .map_err(|e| Error::numerical(what, "Cholesky (symbolic)", format!("{e:?}")))?,
            ),
        };
        Ok(DirectFactorizer {
            symbolic,
            kind,
            storage: Storage::of(a.as_ref(), kind),
            symbolic_analyses: 1,
            numeric_factorizations: 0,
            factorized_work: 0.0,
            fallbacks: Vec::new(),
            lu_last: true,
            spare_factors: Arc::default(),
            kept_scale: None,
            threads,
        })
    }

    /// Numeric factorisation of `a` (of the analysed pattern) and the
    /// checked solve of A x = b (see [`ReusableFactorization::factorize_and_solve`]).
    fn factorize_and_solve(
        &mut self,
        matrix: Shared<'_>,
        b: &[f64],
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        self.factorize_and_solve_declared(matrix, b, None, what)
    }

    /// [`DirectFactorizer::factorize_and_solve`] of a matrix that differs
    /// from the last one only at the value positions `declared`, all on
    /// the diagonal (the caller vouches for it; None: any change). Its
    /// scale and equilibration then come from those entries alone
    /// ([`KeptScale`]) instead of five passes over all of it.
    fn factorize_and_solve_declared(
        &mut self,
        matrix: Shared<'_>,
        b: &[f64],
        declared: Option<&[usize]>,
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        let a: &SparseColMat<usize, f64> = &matrix;
        let (scale, equilibration) = self.scale_of(a, declared, what)?;
        // The kept scale that gave `equilibration`, if one did.
        let kept = self
            .kept_scale
            .as_ref()
            .and_then(|k| k.as_ref().ok())
            .filter(|_| equilibration.is_some());
        let norm = scale.norm;
        let storage = self.storage;
        let f = match &self.symbolic {
            SymbolicAnalysis::Lu(symbolic) => Factorization::Lu(Box::new(
                Lu::try_new_with_symbolic(symbolic.clone(), storage.whole(a).as_ref().as_ref()).map_err(|e| {
                    let reason = match e {
                        faer::sparse::linalg::LuError::Generic(FaerError::OutOfMemory) => {
                            "out of memory".to_string()
                        }
                        e => format!("singular matrix ({e:?})"),
                    };
                    Error::numerical(what, "LU", self.after_fallbacks(reason))
                })?,
            )),
            SymbolicAnalysis::Ldlt {
                analysis, n_primal, ..
            } if *n_primal == a.nrows() => {
                // Every pivot positive (the SPD fallback): no pivot is
                // regularised, so the refined solve is backward stable; its
                // residual relative to ‖b‖ may still be ~ε·κ (thin shells:
                // κ ~ 1e12), so it is judged by the backward error
                // ‖Ax − b‖/(‖A‖‖x‖ + ‖b‖). A matrix that is not positive
                // definite after all goes on to LU, as below.
                let solved = RegularizedLdlt::new(analysis, matrix.to_arc(), storage, scale, equilibration, kept, &self.spare_factors, what, self.threads)
                    .ok()
                    .map(|l| Factorization::Ldlt(Box::new(l)))
                    .and_then(|f| {
                        let rhs = if norm_inf(b) == 0.0 { test_rhs(a.nrows()) } else { b.to_vec() };
                        let mut x = rhs.clone();
                        f.solve_in_place(&mut x);
                        let quality = SolveQuality::of(a, storage, norm, &x, &rhs, self.threads);
                        (quality.backward <= BACKWARD_ACCEPTED).then(|| {
                            let x = if norm_inf(b) == 0.0 { vec![0.0; b.len()] } else { x };
                            (f, x, quality.relative)
                        })
                    });
                if let Some(done) = solved {
                    self.count(&done.0);
                    return Ok(done);
                }
                let why = "LDLᵀ with positive pivots missed its backward error".to_string();
                let lu = self.lu_fallback(a, &why, what)?;
                return self.retry_with(lu, why, matrix.clone(), b, what);
            }
            SymbolicAnalysis::Ldlt {
                analysis,
                n_primal,
                order,
            } => {
                let (n_primal, order) = (*n_primal, *order);
                let ldlt =
                    RegularizedLdlt::new(
                        analysis,
                        matrix.to_arc(),
                        storage,
                        scale,
                        equilibration,
                        kept,
                        &self.spare_factors,
                        what,
                        self.threads,
                    );
                let solved = ldlt.map(|l| Factorization::Ldlt(Box::new(l))).and_then(|f| {
                    let (x, quality) = check_solve(a, storage, norm, &f, b, what, self.threads)?;
                    Ok((f, x, quality))
                });
                let why = match solved {
                    Ok((f, x, quality)) if quality.accepted(self.accepted()) => {
                        self.count(&f);
                        return Ok((f, x, quality.relative));
                    }
                    Ok((_, _, q)) => format!(
                        "LDLᵀ ({}): refined residual {:.1e} above {:.0e} (componentwise {:.1e} above {COMPONENTWISE_ACCEPTED:.0e})",
                        order.describe(),
                        q.relative,
                        self.accepted(),
                        q.componentwise.unwrap_or(f64::NAN)
                    ),
                    Err(e) => format!("LDLᵀ ({}): {e}", order.describe()),
                };
                // A zero pivot, or the refined solve misses its accuracy.
                // The AMD order regularises the pivots of multipliers that
                // come before their neighbours, and refinement cannot undo a
                // perturbation the conditioning amplifies (the shell at
                // ρ = 1e12; the condensed shell's first Newton matrix at
                // n = 256): the order that regularises no pivot next, then LU
                // (the signs are not the matrix's inertia).
                let next = match order {
                    Solves::Few => ldlt_analysis(a, n_primal, Solves::Many, what, self.threads)?,
                    Solves::Many => self.lu_fallback(a, &why, what)?,
                };
                return self.retry_with(next, why, matrix.clone(), b, what);
            }
            SymbolicAnalysis::Llt(symbolic) => Factorization::Cholesky(
                Llt::try_new_with_symbolic(symbolic.clone(), a.as_ref(), Side::Lower).map_err(
                    |e| {
                        Error::numerical(
                            what,
                            "Cholesky",
                            format!("the matrix is not positive definite ({e:?}): is the problem constrained enough (Dirichlet part, coercivity)?"),
                        )
                    },
                )?,
            ),
        };
        self.count(&f);
        match check_solve(a, storage, norm, &f, b, what, self.threads) {
            Ok((x, quality)) => Ok((f, x, quality.relative)),
            Err(e) if matches!(self.symbolic, SymbolicAnalysis::Llt(_)) => {
                // An SPD matrix too ill-conditioned for a plain Cholesky solve
                // (thin shells: membrane ~ Eε against bending ~ Eε³): the
                // equilibrated LDLᵀ with every pivot positive, refined against
                // the true matrix in every solve. Measured: the clamped plate
                // at ε = 0.008 (p2b-psri, 16×16), test residual 1.4e-6 plain,
                // round-off equilibrated and refined.
                let n = a.nrows();
                let why = format!("Cholesky: {e}");
                let ldlt = ldlt_analysis(a, n, Solves::Few, what, self.threads).map_err(|_| e)?;
                self.retry_with(ldlt, why, matrix.clone(), b, what)
            }
            Err(e) => Err(self.naming_fallbacks(e)),
        }
    }

    /// A fallback (`why`: what failed): a new symbolic analysis from now
    /// on, and the numeric factorisation and solve again with it.
    fn retry_with(
        &mut self,
        symbolic: SymbolicAnalysis,
        why: String,
        a: Shared<'_>,
        b: &[f64],
        what: &str,
    ) -> Result<(Factorization, Vec<f64>, f64)> {
        self.fallbacks.push(why);
        self.symbolic = symbolic;
        self.symbolic_analyses += 1;
        self.factorize_and_solve(a, b, what)
    }
}

impl DirectFactorizer {
    /// The scale of `a`'s entries ([`checked_scale`]) and its symmetric
    /// equilibration (for an LDLᵀ): from the kept ones when `a`
    /// differs from the last matrix only at the `declared` diagonal
    /// positions, else from all of `a` (kept for the next matrix when
    /// positions are declared).
    fn scale_of(
        &mut self,
        a: &SparseColMat<usize, f64>,
        declared: Option<&[usize]>,
        what: &str,
    ) -> Result<(EntryScale, Option<Equilibration>)> {
        // Only an LDLᵀ equilibrates.
        let ldlt = matches!(self.symbolic, SymbolicAnalysis::Ldlt { .. });
        let Some(declared) = declared.filter(|_| ldlt) else {
            self.kept_scale = None;
            return Ok((checked_scale(a, what, self.threads)?, None));
        };
        match self.kept_scale.as_mut() {
            Some(Ok(kept)) if kept.positions == declared => {
                return kept.with(a, what).map(|(s, e)| (s, Some(e)));
            }
            Some(Err(refused)) if refused.as_slice() == declared => {
                return Ok((checked_scale(a, what, self.threads)?, None));
            }
            _ => {}
        }
        let scale = checked_scale(a, what, self.threads)?;
        let Some(mut kept) = KeptScale::of(a, scale, declared, self.threads) else {
            self.kept_scale = Some(Err(declared.to_vec()));
            return Ok((scale, None));
        };
        let scaled = kept.with(a, what);
        self.kept_scale = Some(Ok(kept));
        scaled.map(|(s, e)| (s, Some(e)))
    }

    /// One more numeric factorisation, `f`.
    fn count(&mut self, f: &Factorization) {
        self.numeric_factorizations += 1;
        self.factorized_work += match f {
            Factorization::Ldlt(ldlt) => ldlt.factorized,
            _ => 1.0,
        };
    }

    /// `reason`, preceded by the failures that led here.
    fn after_fallbacks(&self, reason: String) -> String {
        match self.fallbacks.is_empty() {
            true => reason,
            false => format!("{reason} (a fallback after: {})", self.fallbacks.join("; ")),
        }
    }

    /// The relative residual up to which an LDLᵀ is kept: of a Schur
    /// complement (whose fallback is the whole matrix) the condensed bound.
    fn accepted(&self) -> f64 {
        match self.lu_last {
            true => LDLT_ACCEPTED,
            false => CONDENSED_ACCEPTED,
        }
    }

    /// LU's analysis as the next fallback after `why`, or an error when LU
    /// is not this factoriser's fallback.
    fn lu_fallback(
        &self,
        a: &SparseColMat<usize, f64>,
        why: &str,
        what: &str,
    ) -> Result<SymbolicAnalysis> {
        if !self.lu_last {
            return Err(Error::numerical(
                what,
                "factorisation",
                self.after_fallbacks(why.to_string()),
            ));
        }
        lu_analysis(&Storage::of(a.as_ref(), self.kind).whole(a), what)
    }

    /// `e` with the failures that led here in its reason.
    fn naming_fallbacks(&self, e: Error) -> Error {
        match e {
            Error::Numerical {
                stage,
                measure,
                reason,
            } => Error::Numerical {
                stage,
                measure,
                reason: self.after_fallbacks(reason),
            },
            e => e,
        }
    }
}

impl Factorization {
    /// Solves A X = B in place for the k columns of B (column-major).
    pub fn solve_block_in_place(&self, b: &mut [f64], k: usize) {
        let n = b.len() / k.max(1);
        parallelism();
        match self {
            Factorization::Cholesky(f) => {
                f.solve_in_place(MatMut::from_column_major_slice_mut(b, n, k))
            }
            Factorization::Ldlt(f) => f.solve_block_in_place(b, k),
            Factorization::Lu(f) => f.solve_in_place(MatMut::from_column_major_slice_mut(b, n, k)),
            Factorization::Condensed(f) => b
                .chunks_exact_mut(n)
                .for_each(|col| f.solve_in_place(col, false)),
        }
    }

    /// Bᵀ A⁻¹ B (r × r, column-major) for r sparse columns B of A (order
    /// n; `columns[c]` holds (row, value)), through the factors as they
    /// are, without refinement: the forward sweeps of the columns alone,
    /// over the paths of the elimination tree they reach. For a caller
    /// that then solves `solves` times with these factors instead of
    /// factorising anew: None where the sweep is not available (LU,
    /// Cholesky, one thread) or the sweep and the solves are estimated to
    /// cost more than [`GRAM_BUDGET`] of a factorisation.
    pub fn inverse_gram(
        &self,
        columns: &[Vec<(usize, f64)>],
        n: usize,
        solves: usize,
    ) -> Option<Vec<f64>> {
        match self {
            Factorization::Ldlt(f) => f.gram(columns, solves),
            Factorization::Condensed(f) => f.gram(columns, n, solves),
            _ => None,
        }
    }

    /// Solves A x = b in place with the factors as they are, without
    /// refinement: one sweep through the factors and no product with A.
    /// An LDLᵀ's regularised pivots leave a relative residual ~1e-8, which
    /// is enough for a direction (an interior-point corrector) or for a
    /// caller that refines against a larger matrix (S inside a condensed
    /// solve). Cholesky and LU solves are not refined anyway.
    pub fn solve_unrefined_in_place(&self, b: &mut [f64]) {
        match self {
            Factorization::Ldlt(f) => f.raw_solve(b, 1),
            Factorization::Condensed(f) => f.raw_solve(b, false),
            _ => self.solve_in_place(b),
        }
    }

    /// Solves Aᵀ X = B in place for the k columns of B (column-major).
    pub fn solve_transpose_block_in_place(&self, b: &mut [f64], k: usize) {
        let n = b.len() / k.max(1);
        match self {
            // Symmetric factorisations: Aᵀ = A.
            Factorization::Cholesky(_) | Factorization::Ldlt(_) => self.solve_block_in_place(b, k),
            Factorization::Lu(f) => {
                f.solve_transpose_in_place(MatMut::from_column_major_slice_mut(b, n, k))
            }
            Factorization::Condensed(f) => b
                .chunks_exact_mut(n)
                .for_each(|col| f.solve_in_place(col, true)),
        }
    }

    /// Solves Aᵀ x = b in place.
    pub fn solve_transpose_in_place(&self, b: &mut [f64]) {
        self.solve_transpose_block_in_place(b, 1);
    }
}

/// A symmetric equilibration D (the factors are those of D A D) and the
/// largest |entry| of D A D when known.
pub(super) struct Equilibration {
    pub(super) d: Vec<f64>,
    pub(super) norm: Option<f64>,
}

impl Equilibration {
    /// Of all of `a` ([`symmetric_equilibration`]).
    fn of(a: &SparseColMat<usize, f64>, threads: usize) -> Self {
        Equilibration {
            d: symmetric_equilibration(a, threads),
            norm: None,
        }
    }
}

/// A diagonal D > 0 with every row of D A D of max-norm about 1 (three
/// sweeps of Ruiz's symmetric scaling). Why: the regularisation δ is one
/// number, so the blocks of a saddle matrix (stiffness up to ~ρ, constraint
/// rows O(1)) must be of comparable size for δ to be small against all of
/// them (measured on the thesis shell without the ψ scaling: test residual
/// 6e-5 unequilibrated, 3e-11 equilibrated).
pub(super) fn symmetric_equilibration(a: &SparseColMat<usize, f64>, threads: usize) -> Vec<f64> {
    ruiz_equilibration(a, threads, |_, _| false)
}

/// [`symmetric_equilibration`] with the entries (i, j) where `left_out`
/// holds read as 0.
pub(super) fn ruiz_equilibration(
    a: &SparseColMat<usize, f64>,
    threads: usize,
    left_out: impl Fn(usize, usize) -> bool + Sync,
) -> Vec<f64> {
    let n = a.nrows();
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    // The row maxima of |D A D| over columns `range`.
    let row_maxima = |d: &[f64], range: std::ops::Range<usize>| {
        let mut row_max = vec![0.0f64; n];
        for j in range {
            // Column j's own maximum in a register: one scattered update
            // per entry instead of two (max is exact: the same d).
            let (dj, mut col_max) = (d[j], 0.0f64);
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                if left_out(i, j) {
                    continue;
                }
                let v = (values[k] * d[i] * dj).abs();
                row_max[i] = row_max[i].max(v);
                col_max = col_max.max(v);
            }
            row_max[j] = row_max[j].max(col_max);
        }
        row_max
    };
    // The maximum of the two halves' maxima is exact: the same scaling.
    let mut d = vec![1.0; n];
    for _ in 0..3 {
        let row_max = in_two_halves(
            a,
            threads,
            |columns| row_maxima(&d, columns),
            |mut first, second| {
                first
                    .iter_mut()
                    .zip(&second)
                    .for_each(|(a, b)| *a = a.max(*b));
                first
            },
        );
        for (di, m) in d.iter_mut().zip(&row_max) {
            if *m > 0.0 && m.is_finite() {
                *di /= m.sqrt();
            }
        }
    }
    d
}

/// Relative size of the regularised pivots: δ = √ε · max|DAD| (D the
/// equilibration). A pivot of the wrong sign or below ε·max|DAD| in size (a multiplier eliminated before
/// its primal neighbours) is replaced by ±δ, so the factors are those of
/// A + E with ‖E‖ ≤ δ; refinement against A removes the perturbation, each
/// step gaining about −log₁₀(√ε) ≈ 8 digits.
pub(super) const REGULARIZATION: f64 = 1.5e-8;
/// A matrix given to a factorisation: borrowed from the caller, or owned
/// (S of a condensed factorisation) and then shared with the LDLᵀ that
/// keeps it instead of copying it.
#[derive(Clone)]
pub(super) enum Shared<'a> {
    Borrowed(&'a SparseColMat<usize, f64>),
    Owned(Arc<SparseColMat<usize, f64>>),
}

impl Shared<'_> {
    /// The matrix to keep: a copy when borrowed.
    fn to_arc(&self) -> Arc<SparseColMat<usize, f64>> {
        match self {
            Shared::Borrowed(a) => Arc::new((*a).clone()),
            Shared::Owned(a) => Arc::clone(a),
        }
    }
}

impl std::ops::Deref for Shared<'_> {
    type Target = SparseColMat<usize, f64>;
    fn deref(&self) -> &Self::Target {
        match self {
            Shared::Borrowed(a) => a,
            Shared::Owned(a) => a,
        }
    }
}

/// LDLᵀ with signed dynamic regularisation (+ on primal pivots, − on
/// multiplier pivots) for symmetric saddle-point matrices, followed by
/// iterative refinement against the unperturbed matrix in every solve.
///
/// Why not LU: the saddle matrices are symmetric, so a symmetric ordering
/// (AMD) and half the factor suffice; on the shell matrices this is several
/// times faster and half the memory of faer's LU (whose column ordering does
/// not see the symmetry). Plain LDLᵀ without pivoting meets zero pivots on
/// the multiplier block; the signed regularisation makes it a quasi-definite
/// factorisation of a δ-perturbed matrix, stable in any order.
pub struct RegularizedLdlt {
    symbolic: Arc<SymbolicCholesky<usize>>,
    values: Vec<f64>,
    /// The two threads' split of the tree when factorised on two: its
    /// one-column solves run on two as well ([`tree_ldlt::solve_in_place`]).
    schedule: Option<Arc<TreeSchedule>>,
    /// Symmetric equilibration D: the factors are those of D A D.
    scale: Vec<f64>,
    /// The matrix itself, for the refinement (shared with the caller's
    /// copy when there is one: a condensed factorisation's S exists once),
    /// whole or its lower triangle.
    matrix: Arc<SparseColMat<usize, f64>>,
    storage: Storage,
    /// The scale of its entries, for the refinement's round-off level.
    entry_scale: EntryScale,
    /// Solves skip the refinement against this matrix: set only inside a
    /// condensed factorisation (which refines against A anyway) when a test
    /// solve met round-off without a step (no pivot regularised).
    raw_solves_suffice: bool,
    /// Where the factor values go when it is dropped, and what they are
    /// the factor of (when the next factorisation may keep part of them).
    spare_factors: Arc<SpareFactors>,
    inputs: Option<FactorInputs>,
    /// The fraction of a whole factorisation's estimated work this one did
    /// (below 1 where it kept supernodes of the last one).
    factorized: f64,
    /// The threads of its refinement's products ([`two_threads`]).
    threads: usize,
}

impl Drop for RegularizedLdlt {
    fn drop(&mut self) {
        self.spare_factors
            .put(std::mem::take(&mut self.values), self.inputs.take());
    }
}

impl RegularizedLdlt {
    /// The two threads' split of the analysis is used when `threads` is
    /// two or more ([`two_threads`]); `entry_scale` is
    /// the scale of the matrix's entries ([`checked_scale`]). With `kept`
    /// (the matrix scaled by it: `equilibration` is its), the supernodes
    /// that the changes since the spare factor's matrix do not reach are
    /// kept from it instead of factorised again.
    #[allow(clippy::too_many_arguments)]
    fn new(
        analysis: &LdltAnalysis,
        matrix: Arc<SparseColMat<usize, f64>>,
        storage: Storage,
        entry_scale: EntryScale,
        equilibration: Option<Equilibration>,
        kept: Option<&KeptScale>,
        spare_factors: &Arc<SpareFactors>,
        what: &str,
        threads: usize,
    ) -> Result<Self> {
        let LdltAnalysis {
            symbolic,
            schedule,
            ordered,
        } = analysis;
        let symbolic = symbolic.clone();
        let a = &*matrix;
        let Equilibration { d: scale, norm } =
            equilibration.unwrap_or_else(|| Equilibration::of(a, threads));
        let (mut values, last) = spare_factors.take(symbolic.len_val(), what)?;
        let regularization = |norm: f64| {
            let norm = norm.max(f64::MIN_POSITIVE);
            LdltRegularization {
                dynamic_regularization_signs: Some(ordered.signs.as_slice()),
                dynamic_regularization_delta: REGULARIZATION * norm,
                dynamic_regularization_epsilon: f64::EPSILON * norm,
            }
        };
        // Two threads read A's values in place (the positions of its
        // values exist with the schedule, when they fit 32 bits); faer
        // reads a scaled copy in its order.
        let tree = schedule.as_ref().filter(|_| two_threads(threads));
        let entries = tree.and_then(|_| ordered.entries(a, &scale, norm, threads));
        let (mut inputs, mut factorized) = (None, 1.0);
        let done = match (symbolic.raw(), tree, entries) {
            (SymbolicCholeskyRaw::Supernodal(raw), Some(tree), Some(entries)) => {
                // Only the supernodes the changes since the spare factor's
                // matrix reach, when it was factorised here with the same
                // kept scale.
                inputs = kept.map(|k| FactorInputs::of(k, a, &symbolic, entries.norm));
                let only = match (kept, &inputs, &last) {
                    (Some(kept), Some(now), Some(last)) => now
                        .changed_columns(last, kept, &ordered.inverse)
                        .map(|columns| tree.changed_supernodes(columns.into_iter())),
                    _ => None,
                };
                if let Some((_, fraction)) = &only {
                    factorized = *fraction;
                }
                tree_ldlt::factorize(
                    &mut values,
                    &entries,
                    &regularization(entries.norm),
                    raw,
                    tree,
                    only.as_ref().map(|(flags, _)| flags.as_slice()),
                )
                .map(|_| ())
            }
            (raw, ..) => {
                let scaled = ordered.equilibrated(a, &scale);
                factorize_in_faer(&mut values, &scaled, regularization(scaled.norm), raw)
            }
        };
        let schedule = tree.cloned();
        done.map_err(|e| Error::numerical(what, "LDLᵀ", format!("zero pivot ({e:?})")))?;
        Ok(RegularizedLdlt {
            symbolic,
            values,
            schedule,
            scale,
            entry_scale,
            storage,
            matrix,
            raw_solves_suffice: false,
            spare_factors: spare_factors.clone(),
            inputs,
            factorized,
            threads,
        })
    }

    /// a_ii of the matrix.
    fn diagonal(&self, i: usize) -> f64 {
        diagonal_entry(self.matrix.as_ref().as_ref(), i)
    }

    /// Lets solves skip the refinement against this matrix when one raw
    /// test solve is at round-off already (the many-solves order
    /// regularises no pivot): for S inside a condensed factorisation, whose
    /// solves are refined against A, this saves a product with S per solve.
    fn skip_refinement_if_exact(&mut self) {
        let rhs = test_rhs(self.matrix.nrows());
        let mut x = rhs.clone();
        self.raw_solve(&mut x, 1);
        let r = self
            .storage
            .residual(self.matrix.as_ref().as_ref(), &x, &rhs, self.threads);
        self.raw_solves_suffice =
            self.entry_scale.excess(&r, &x, &rhs, |i| self.diagonal(i)) <= 1.0;
    }

    /// One solve with the (perturbed, equilibrated) factors, k columns:
    /// x = D (D A D)⁻¹ D b.
    fn raw_solve(&self, b: &mut [f64], k: usize) {
        let n = self.matrix.nrows();
        let par = parallelism();
        let scale_all = |b: &mut [f64]| {
            for col in b.chunks_exact_mut(n) {
                col.iter_mut().zip(&self.scale).for_each(|(v, d)| *v *= d);
            }
        };
        scale_all(b);
        // Two threads pay from a factor of about a million entries on (the
        // shell at n = 16: Uzawa's iteration 0.33 → 0.49 ms with them).
        let two = k == 1 && self.values.len() >= PARALLEL_ENTRIES;
        match (&self.schedule, self.symbolic.raw(), self.symbolic.perm()) {
            (Some(schedule), SymbolicCholeskyRaw::Supernodal(raw), Some(perm)) if two => {
                // faer's solve permutes the same way around its own.
                let (forward, inverse) = perm.arrays();
                let mut x: Vec<f64> = forward.iter().map(|&i| b[i]).collect();
                tree_ldlt::solve_in_place(raw, &self.values, schedule, &mut x);
                for (v, &i) in b.iter_mut().zip(inverse) {
                    *v = x[i];
                }
            }
            _ => {
                let mut buffer =
                    MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(k, par));
                LdltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
                    Conj::No,
                    MatMut::from_column_major_slice_mut(b, n, k),
                    par,
                    MemStack::new(&mut buffer),
                );
            }
        }
        scale_all(b);
    }

    /// Bᵀ A⁻¹ B through the factors as they are (the perturbed,
    /// equilibrated ones) for sparse columns B: forward sweeps over the
    /// paths the columns reach. None without the two threads' supernodal
    /// split, or when the sweep and `solves` solves would not stay within
    /// [`GRAM_BUDGET`] of a factorisation.
    fn gram(&self, columns: &[Vec<(usize, f64)>], solves: usize) -> Option<Vec<f64>> {
        let (Some(schedule), SymbolicCholeskyRaw::Supernodal(raw), Some(perm)) =
            (&self.schedule, self.symbolic.raw(), self.symbolic.perm())
        else {
            return None;
        };
        // x = D (D A D)⁻¹ D b (as in a solve): the factor's columns are
        // D b in its order.
        let (_, inverse) = perm.arrays();
        let ordered: Vec<Vec<(usize, f64)>> = columns
            .iter()
            .map(|c| {
                c.iter()
                    .map(|&(i, v)| (inverse[i], v * self.scale[i]))
                    .collect()
            })
            .collect();
        let solve_work = solves as f64 * SOLVE_WORK_PER_ENTRY * self.values.len() as f64;
        let max_work = (GRAM_BUDGET * schedule.whole_work() - solve_work) / FACTORISATION_THREADS;
        tree_ldlt::forward_gram(raw, &self.values, schedule, &ordered, max_work)
    }

    /// Solves A X = B for k columns: factor solve, then refinement
    /// against A ([`refine_to_round_off`]).
    fn solve_block_in_place(&self, b: &mut [f64], k: usize) {
        let n = self.matrix.nrows();
        if self.raw_solves_suffice {
            return self.raw_solve(b, k);
        }
        let rhs = b.to_vec();
        self.raw_solve(b, k);
        for c in 0..k {
            let (x, bc) = (&mut b[c * n..(c + 1) * n], &rhs[c * n..(c + 1) * n]);
            refine_to_round_off(
                |v| {
                    self.storage
                        .product(self.matrix.as_ref().as_ref(), v, self.threads)
                },
                |i| self.diagonal(i),
                &self.entry_scale,
                x,
                bc,
                |d| self.raw_solve(d, 1),
            );
        }
    }

    /// Solves A x = b (one column) as [`RegularizedLdlt::solve_block_in_place`];
    /// returns A x from the refinement's last residual.
    fn solve_with_product(&self, b: &mut [f64]) -> Vec<f64> {
        solve_refined(
            b,
            |v| {
                self.storage
                    .product(self.matrix.as_ref().as_ref(), v, self.threads)
            },
            |i| self.diagonal(i),
            &self.entry_scale,
            |d| self.raw_solve(d, 1),
        )
    }
}

/// faer's numeric LDLᵀ of `scaled` (sequential; supernodal or
/// simplicial as analysed) into `values`.
pub(super) fn factorize_in_faer(
    values: &mut [f64],
    scaled: &OrderedMatrix<'_>,
    regularization: LdltRegularization<'_, f64>,
    symbolic: &SymbolicCholeskyRaw<usize>,
) -> std::result::Result<(), LdltError> {
    let (n, par) = (scaled.pattern.pattern.nrows(), parallelism());
    let mut buffer = MemBuffer::new(match symbolic {
        SymbolicCholeskyRaw::Simplicial(_) => {
            simplicial::factorize_simplicial_numeric_ldlt_scratch::<usize, f64>(n)
        }
        SymbolicCholeskyRaw::Supernodal(raw) => {
            supernodal::factorize_supernodal_numeric_ldlt_scratch::<usize, f64>(
                raw,
                par,
                Default::default(),
            )
        }
    });
    let stack = MemStack::new(&mut buffer);
    match symbolic {
        SymbolicCholeskyRaw::Simplicial(raw) => simplicial::factorize_simplicial_numeric_ldlt(
            values,
            scaled.as_ref(),
            regularization,
            raw,
            stack,
        )
        .map(|_| ()),
        SymbolicCholeskyRaw::Supernodal(raw) => supernodal::factorize_supernodal_numeric_ldlt(
            values,
            scaled.as_ref(),
            regularization,
            raw,
            par,
            stack,
            Default::default(),
        )
        .map(|_| ()),
    }
}

#[cfg(test)]
mod tests {
    use super::super::analysis::{equilibrated_norm, pattern_hash, PatternHasher};
    use super::super::kernels::{
        difference, into_lower_triangle, mat_vec, product, retain_entries,
    };
    use super::*;
    use faer::sparse::Triplet;

    /// A factor that cannot be allocated is an error naming the matrix and
    /// the size, not an abort; spare values of the right length are reused.
    #[test]
    fn a_factor_that_does_not_fit_is_an_error() {
        let spare = SpareFactors::default();
        let e = spare
            .take(usize::MAX / 16, "the test matrix")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the test matrix") && e.contains("out of memory") && e.contains("GB"),
            "{e}"
        );
        spare.put(vec![1.0; 8], None);
        assert_eq!(spare.take(8, "test").unwrap().0, vec![1.0; 8]);
        assert_eq!(spare.take(8, "test").unwrap().0, vec![0.0; 8]);
    }

    /// `retain_entries` keeps the entries asked for, in place, from a
    /// compressed matrix and from one whose columns have unused room
    /// (`col_nnz`), and cuts rows and columns off: the leading 2 × 2 block
    /// of a 3 × 3 matrix, and its lower triangle.
    #[test]
    fn retained_entries_are_the_ones_asked_for() {
        // Column j holds rows 0..3 with value 10 i + j; with room: each
        // column gets two unused slots after its entries.
        let dense = |i: usize, j: usize| (10 * i + j) as f64;
        let compressed = {
            let t: Vec<_> = (0..3)
                .flat_map(|j| (0..3).map(move |i| Triplet::new(i, j, dense(i, j))))
                .collect();
            SparseColMat::try_new_from_triplets(3, 3, &t).unwrap()
        };
        let with_room = {
            let (mut rows, mut values) = (Vec::new(), Vec::new());
            for j in 0..3 {
                for i in 0..3 {
                    rows.push(i);
                    values.push(dense(i, j));
                }
                rows.extend([0, 0]);
                values.extend([f64::NAN, f64::NAN]);
            }
            let symbolic = SymbolicSparseColMat::new_checked(
                3,
                3,
                vec![0, 5, 10, 15],
                Some(vec![3, 3, 3]),
                rows,
            );
            SparseColMat::new(symbolic, values)
        };
        for a in [compressed, with_room] {
            let block = retain_entries(a.clone(), 2, 2, |i, _| i < 2);
            assert_eq!((block.nrows(), block.ncols()), (2, 2));
            assert_eq!(block.symbolic().col_ptr(), &[0, 2, 4]);
            assert_eq!(block.symbolic().row_idx(), &[0, 1, 0, 1]);
            assert_eq!(block.val(), &[0.0, 10.0, 1.0, 11.0]);
            let lower = into_lower_triangle(a);
            assert_eq!(lower.symbolic().col_ptr(), &[0, 3, 5, 6]);
            assert_eq!(lower.symbolic().row_idx(), &[0, 1, 2, 1, 2, 2]);
            assert_eq!(lower.val(), &[0.0, 10.0, 20.0, 11.0, 21.0, 22.0]);
        }
    }

    /// A symmetric matrix given by its lower triangle multiplies as the
    /// whole matrix does, with one thread or two (the second half's sums
    /// added at the end): to round-off, in both halves of the split.
    #[test]
    fn a_lower_triangle_multiplies_on_two_threads() {
        let (n, band) = (200_000, 6);
        let value = |i: usize, j: usize| 1.0 + ((i * 31 + j * 17) % 97) as f64 / 97.0;
        let mut lower = Vec::new();
        let mut whole = Vec::new();
        for j in 0..n {
            for i in j..(j + band).min(n) {
                let v = if i == j {
                    2.0 * band as f64
                } else {
                    -value(i, j)
                };
                lower.push(Triplet::new(i, j, v));
                whole.push(Triplet::new(i, j, v));
                if i != j {
                    whole.push(Triplet::new(j, i, v));
                }
            }
        }
        let lower = SparseColMat::try_new_from_triplets(n, n, &lower).unwrap();
        let whole = SparseColMat::try_new_from_triplets(n, n, &whole).unwrap();
        assert!(lower.val().len() >= PARALLEL_ENTRIES);
        let kind = MatrixKind::SymmetricPositiveDefinite;
        assert_eq!(Storage::of(lower.as_ref(), kind), Storage::LowerTriangle);
        let x: Vec<f64> = (0..n).map(|i| ((i * 7919) % 113) as f64 - 56.0).collect();
        let expected = mat_vec(&whole, &x);
        let scale = norm_inf(&expected);
        for threads in [1, 2] {
            let y = product(&lower, kind, &x, threads);
            let worst = norm_inf(&difference(&expected, &y));
            assert!(
                worst <= 1e-14 * scale,
                "{threads} threads: differs by {worst:e} (scale {scale:e})"
            );
        }
    }

    /// The interior unknowns recovered after a condensed solve are the
    /// same numbers with one thread or two (each group's sums unchanged).
    #[test]
    fn interior_unknowns_recover_alike_on_two_threads() {
        // Groups of 2 interior unknowns, each coupled to 8 consecutive
        // remaining ones (overlapping by 4): Σ p q ≥ 2²⁰ coupling entries.
        let groups = (PARALLEL_ENTRIES / 16) + 7;
        let n_r = 4 * groups + 4;
        let n = n_r + 2 * groups;
        // Group g: unknowns u, w; A_II = [[a_uu(g), 1], [1, 3]]; row u
        // (w) couples to remaining unknown 4g + k by coupling_u (_w).
        let a_uu = |g: usize| 4.0 + (g % 3) as f64;
        let coupling_u = |g: usize, k: usize| 0.1 * ((g + k) % 5 + 1) as f64;
        let coupling_w = |g: usize, k: usize| -0.05 * ((g * k) % 7 + 1) as f64;
        let mut lower = Vec::new();
        for r in 0..n_r {
            lower.push(Triplet::new(r, r, 40.0));
        }
        for g in 0..groups {
            let (u, w) = (n_r + 2 * g, n_r + 2 * g + 1);
            lower.push(Triplet::new(u, u, a_uu(g)));
            lower.push(Triplet::new(w, u, 1.0));
            lower.push(Triplet::new(w, w, 3.0));
            for k in 0..8 {
                let r = 4 * g + k;
                lower.push(Triplet::new(u, r, coupling_u(g, k)));
                lower.push(Triplet::new(w, r, coupling_w(g, k)));
            }
        }
        let a = SparseColMat::try_new_from_triplets(n, n, &lower).unwrap();
        let interior =
            InteriorGroups::from_groups((0..groups).map(|g| vec![n_r + 2 * g, n_r + 2 * g + 1]));
        let kind = MatrixKind::SymmetricPositiveDefinite;
        let (plan, s) = CondensationPlan::new(&a, &interior, kind, "test").unwrap();
        let mut s_values = s.val().to_vec();
        let local = plan.condense_into(&a, &mut s_values, "test").unwrap();
        let b: Vec<f64> = (0..n).map(|i| ((i * 7919) % 101) as f64 - 50.0).collect();
        let x_r: Vec<f64> = (0..n_r)
            .map(|i| ((i * 104_729) % 89) as f64 / 89.0)
            .collect();
        let recovered = |threads: usize| {
            let mut x = b.clone();
            plan.recover(&local, &x_r, &mut x, false, threads);
            x
        };
        let (one, two) = (recovered(1), recovered(2));
        assert_eq!(&one[..n_r], &x_r[..]);
        let differing = one.iter().zip(&two).filter(|(p, q)| p != q).count();
        assert_eq!(differing, 0, "{differing} of {n} unknowns differ");
        // x_I = A_II⁻¹ (b_I − A_IR x_R), checked on the last group.
        let g = groups - 1;
        let (u, w) = (n_r + 2 * g, n_r + 2 * g + 1);
        let (a_uu, a_ww) = (a_uu(g), 3.0);
        let rhs = |row: usize, coupling: &dyn Fn(usize, usize) -> f64| {
            b[row] - (0..8).map(|k| coupling(g, k) * x_r[4 * g + k]).sum::<f64>()
        };
        let (r_u, r_w) = (rhs(u, &coupling_u), rhs(w, &coupling_w));
        let det = a_uu * a_ww - 1.0;
        let (x_u, x_w) = ((a_ww * r_u - r_w) / det, (a_uu * r_w - r_u) / det);
        assert!(
            (one[u] - x_u).abs() <= 1e-12 * x_u.abs().max(1.0),
            "{} vs {x_u}",
            one[u]
        );
        assert!(
            (one[w] - x_w).abs() <= 1e-12 * x_w.abs().max(1.0),
            "{} vs {x_w}",
            one[w]
        );
    }

    /// The largest |entry| wherever it lies (either half of the two
    /// threads' split, the lanes' remainder), with one thread or two; a
    /// NaN or ±∞ is an error naming its entry.
    #[test]
    fn checked_scale_finds_the_largest_entries_and_names_a_non_finite_one() {
        // Lower bidiagonal: column j holds the diagonal (value k = 2j) and,
        // but for the last, the entry below it (k = 2j + 1).
        let n = PARALLEL_ENTRIES / 2 + 13;
        let bidiagonal = |values: Vec<f64>| {
            let col_ptr: Vec<usize> = (0..=n).map(|j| (2 * j).min(2 * n - 1)).collect();
            let row_idx: Vec<usize> = (0..2 * n - 1).map(|k| k / 2 + k % 2).collect();
            let pattern = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
            SparseColMat::new(pattern, values)
        };
        for threads in [1, 2] {
            {
                // (value position, value): an off-diagonal entry, then diagonal ones.
                for (k, v) in [(2 * (n / 2) + 1, -9.0), (0, 7.5), (2 * (n - 1), -1e40)] {
                    let mut values = vec![1.0; 2 * n - 1];
                    values[k] = v;
                    let scale = checked_scale(&bidiagonal(values), "test", threads).unwrap();
                    let what = format!("entry {k} ({threads} threads)");
                    assert_eq!(scale.norm, v.abs(), "{what}");
                    let off_diagonal = if k % 2 == 1 { v.abs() } else { 1.0 };
                    assert_eq!(scale.off_diagonal, off_diagonal, "{what}");
                }
                for k in [2 * n - 3, 2 * n - 2] {
                    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                        let mut values = vec![1.0; 2 * n - 1];
                        values[k] = bad;
                        let e = checked_scale(&bidiagonal(values), "test", threads).unwrap_err();
                        let expected = format!("entry {k} is not finite");
                        assert!(e.to_string().contains(&expected), "{bad}: {e}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_huge_diagonal_on_a_tiny_unknown_does_not_stop_the_refinement() {
        // [4 1 1; 1 3 0; 1 0 −d]: the last unknown (a constraint the active
        // set switches off by its diagonal d) is x₀/d. The approximate
        // inverse is the exact one of the first block scaled by 1.001, so
        // refinement gains three digits per step; at the normwise level
        // 4ε d ‖x‖∞ it would stop before the first.
        let d = 1e40;
        let a = |x: &[f64]| vec![4.0 * x[0] + x[1] + x[2], x[0] + 3.0 * x[1], x[0] - d * x[2]];
        let scale = EntryScale {
            norm: d,
            off_diagonal: 1.0,
        };
        let diagonal = |i: usize| [4.0, 3.0, -d][i];
        let inexact_solve = |r: &mut [f64]| {
            let (p, q) = (r[0] / 1.001, r[1] / 1.001);
            (r[0], r[1]) = ((3.0 * p - q) / 11.0, (4.0 * q - p) / 11.0);
            r[2] = (r[0] - r[2]) / d;
        };
        let b = [1.0, 2.0, 0.0];
        let mut x = b.to_vec();
        inexact_solve(&mut x);
        let ax = refine_to_round_off(a, diagonal, &scale, &mut x, &b, inexact_solve);
        // Its first residual, ~1e-3 (x to three digits), was below
        // 4ε d ‖x‖∞ ≈ 5e15.
        let exact = [1.0 / 11.0, 7.0 / 11.0];
        for i in 0..2 {
            let (error, residual) = ((x[i] - exact[i]).abs(), (b[i] - ax[i]).abs());
            assert!(error <= 1e-14, "x_{i}: error {error:.1e}");
            assert!(residual <= 4e-15, "row {i}: residual {residual:.1e}");
        }
    }

    /// A 4×4 symmetric matrix: (whole, its lower triangle).
    fn symmetric() -> (SparseColMat<usize, f64>, SparseColMat<usize, f64>) {
        let lower = [
            (0, 0, 4.0),
            (1, 0, -1.0),
            (3, 0, 0.5),
            (1, 1, 3.0),
            (2, 1, 2.0),
            (2, 2, -5.0),
            (3, 2, 1.5),
            (3, 3, 2.0),
        ];
        let triplets = |mirrored: bool| -> Vec<Triplet<usize, usize, f64>> {
            lower
                .iter()
                .flat_map(|&(i, j, v)| {
                    let mirror = (mirrored && i != j).then(|| Triplet::new(j, i, v));
                    std::iter::once(Triplet::new(i, j, v)).chain(mirror)
                })
                .collect()
        };
        let matrix = |t: Vec<_>| SparseColMat::try_new_from_triplets(4, 4, &t).unwrap();
        (matrix(triplets(true)), matrix(triplets(false)))
    }

    /// The lower triangle of [`symmetric`], its column pointers, the
    /// value positions of its diagonal entries in columns 1 and 3 (first
    /// in each column) and its entry scale.
    fn with_declared_diagonal() -> (SparseColMat<usize, f64>, Vec<usize>, [usize; 2], EntryScale) {
        let (_, lower) = symmetric();
        let col_ptr = lower.symbolic().col_ptr().to_vec();
        let declared = [col_ptr[1], col_ptr[3]];
        let first = checked_scale(&lower, "test", 1).unwrap();
        (lower, col_ptr, declared, first)
    }

    /// `lower` with the values at `positions` set to `values`.
    fn with_values(
        lower: &SparseColMat<usize, f64>,
        positions: &[usize],
        values: &[f64],
    ) -> SparseColMat<usize, f64> {
        let mut all = lower.val().to_vec();
        positions.iter().zip(values).for_each(|(&k, &v)| all[k] = v);
        SparseColMat::new(lower.symbolic().to_owned().unwrap(), all)
    }

    #[test]
    fn declared_diagonal_entries_rescale_a_matrix_without_a_pass_over_it() {
        let (lower, col_ptr, declared, first) = with_declared_diagonal();
        let fixed = FixedScale::of(&lower, first, &declared).expect("declared on the diagonal");
        for (v1, v3) in [(3.0, 2.0), (-1e40, 0.5), (0.0, -7.0)] {
            let next = with_values(&lower, &declared, &[v1, v3]);
            let scale = fixed.with(&next, &declared, "test").unwrap();
            let whole = checked_scale(&next, "test", 1).unwrap();
            assert_eq!(
                (scale.norm, scale.off_diagonal),
                (whole.norm, whole.off_diagonal)
            );
        }
        let next = with_values(&lower, &declared[1..], &[f64::NAN]);
        let e = fixed.with(&next, &declared, "test").unwrap_err();
        assert!(e
            .to_string()
            .contains(&format!("entry {} is not finite", declared[1])));
        // An off-diagonal entry declared: no fixed scale.
        assert!(FixedScale::of(&lower, first, &[col_ptr[0] + 1]).is_none());
    }

    #[test]
    fn declared_diagonal_entries_reequilibrate_their_rows_only() {
        let (lower, col_ptr, declared, first) = with_declared_diagonal();
        let mut kept = KeptScale::of(&lower, first, &declared, 1).expect("rows 1 and 3 apart");
        // The other rows: Ruiz's with the declared entries read as 0.
        let d0 = symmetric_equilibration(&with_values(&lower, &declared, &[0.0, 0.0]), 1);
        // |(D A D)_ij| of a lower triangle, each entry in its row and column.
        let row_maxima = |a: &SparseColMat<usize, f64>, d: &[f64]| {
            let mut m = vec![0.0f64; 4];
            for j in 0..4 {
                let col = a.val_of_col(j);
                for (i, v) in a.symbolic().row_idx_of_col(j).zip(col) {
                    let e = (v * d[i] * d[j]).abs();
                    (m[i], m[j]) = (m[i].max(e), m[j].max(e));
                }
            }
            m
        };
        for (v1, v3) in [(3.0, 2.0), (-1e40, 0.5), (0.0, -7.0), (1e-30, 0.0)] {
            let next = with_values(&lower, &declared, &[v1, v3]);
            let (scale, equilibration) = kept.with(&next, "test").unwrap();
            let whole = checked_scale(&next, "test", 1).unwrap();
            assert_eq!(
                (scale.norm, scale.off_diagonal),
                (whole.norm, whole.off_diagonal)
            );
            let d = &equilibration.d;
            // The other rows keep their d; the declared ones have max-norm 1.
            assert_eq!((d[0], d[2]), (d0[0], d0[2]));
            let m = row_maxima(&next, d);
            for i in [1, 3] {
                assert!(
                    (m[i] - 1.0).abs() <= 1e-15,
                    "({v1}, {v3}): row {i} max {}",
                    m[i]
                );
            }
            assert_eq!(equilibration.norm, Some(equilibrated_norm(&next, d, 1)));
        }
        // Two declared rows sharing an entry (2, 1), or an entry off the
        // diagonal: nothing kept.
        assert!(KeptScale::of(&lower, first, &[col_ptr[1], col_ptr[2]], 1).is_none());
        assert!(KeptScale::of(&lower, first, &[col_ptr[0] + 1], 1).is_none());
    }

    #[test]
    fn the_diagonal_is_read_from_a_whole_matrix_a_lower_triangle_and_its_copy() {
        let (whole, lower) = symmetric();
        let copy = RefinementMatrix::Symmetric(SymmetricLower::of(&lower));
        for (j, expected) in [4.0, 3.0, -5.0, 2.0].into_iter().enumerate() {
            assert_eq!(diagonal_entry(whole.as_ref(), j), expected);
            assert_eq!(diagonal_entry(lower.as_ref(), j), expected);
            assert_eq!(copy.diagonal(j), expected);
        }
        // A diagonal entry not stored is 0.
        let pattern = SymbolicSparseColMat::new_checked(2, 2, vec![0, 1, 1], None, vec![1]);
        let below = SparseColMat::new(pattern, vec![7.0]);
        assert_eq!(diagonal_entry(below.as_ref(), 0), 0.0);
        assert_eq!(diagonal_entry(below.as_ref(), 1), 0.0);
    }

    #[test]
    fn a_lower_triangle_multiplies_and_expands_as_the_whole_matrix() {
        let (whole, lower) = symmetric();
        let kind = MatrixKind::SymmetricSaddle { n_primal: 2 };
        assert_eq!(Storage::of(whole.as_ref(), kind), Storage::Whole);
        assert_eq!(Storage::of(lower.as_ref(), kind), Storage::LowerTriangle);
        // A general matrix is never read as a triangle.
        assert_eq!(
            Storage::of(lower.as_ref(), MatrixKind::General),
            Storage::Whole
        );
        let x = [1.0, -2.0, 0.5, 3.0];
        let storage = Storage::LowerTriangle;
        assert_eq!(storage.product(lower.as_ref(), &x, 1), mat_vec(&whole, &x));
        let abs_x: Vec<f64> = x.iter().map(|v| v.abs()).collect();
        let abs_whole = SparseColMat::new(
            whole.symbolic().to_owned().unwrap(),
            whole.val().iter().map(|v| v.abs()).collect(),
        );
        assert_eq!(
            storage.absolute_product(lower.as_ref(), &x),
            mat_vec(&abs_whole, &abs_x)
        );
        let expanded = storage.whole(&lower);
        assert_eq!(expanded.symbolic().col_ptr(), whole.symbolic().col_ptr());
        assert_eq!(expanded.symbolic().row_idx(), whole.symbolic().row_idx());
        assert_eq!(expanded.val(), whole.val());
    }

    #[test]
    fn the_first_non_finite_entry_is_found_in_any_block() {
        let mut v = vec![1.0; 1000];
        assert_eq!(first_non_finite(&v), None);
        for (k, bad) in [
            (0, f64::NAN),
            (255, f64::INFINITY),
            (256, f64::NAN),
            (999, -f64::INFINITY),
        ] {
            let old = std::mem::replace(&mut v[k], bad);
            assert_eq!(first_non_finite(&v), Some(k));
            v[k] = old;
        }
        v[700] = f64::NAN;
        v[300] = f64::NAN;
        assert_eq!(first_non_finite(&v), Some(300));
    }

    #[test]
    fn the_pattern_hash_depends_on_the_pattern_only() {
        // The same sequence cut differently hashes the same.
        let values: Vec<usize> = (0..23).map(|k| (k * 7919) % 31).collect();
        let mut whole = PatternHasher::default();
        whole.extend(&values);
        for cut in [(1, 2), (3, 9), (5, 5), (0, 22)] {
            let mut parts = PatternHasher::default();
            parts.extend(&values[..cut.0]);
            values[cut.0..cut.1].iter().for_each(|&x| parts.push(x));
            parts.extend(&values[cut.1..]);
            assert_eq!(parts.finish(), whole.finish(), "cut {cut:?}");
        }
        // A compressed matrix and an uncompressed one of the same pattern
        // (other values, slack in the index storage) match; another
        // pattern does not.
        let (full, lower) = symmetric();
        let s = full.symbolic();
        let (mut col_ptr, mut col_nnz, mut row_idx) = (vec![0], Vec::new(), Vec::new());
        for j in 0..4 {
            row_idx.extend(s.row_idx_of_col_raw(j));
            row_idx.push(0);
            col_nnz.push(s.row_idx_of_col_raw(j).len());
            col_ptr.push(row_idx.len());
        }
        let loose = SymbolicSparseColMat::new_checked(4, 4, col_ptr, Some(col_nnz), row_idx);
        let loose = SparseColMat::new(loose, vec![2.0; 4 + full.val().len()]);
        assert_eq!(pattern_hash(&loose, 1), pattern_hash(&full, 1));
        assert_ne!(pattern_hash(&lower, 1), pattern_hash(&full, 1));
    }

    /// The acceptance rules on the measured cases they were set by
    /// (relative, componentwise, and for a condensed solve S's relative).
    #[test]
    fn acceptance_keeps_conditioning_and_refuses_lost_accuracy() {
        let quality = |relative, componentwise| SolveQuality {
            relative,
            backward: 0.0,
            componentwise: Some(componentwise),
        };
        // Shell n = 512, first Newton solve: S's LDLᵀ above its bound but
        // at round-off row by row; the condensed solve within 1.2× of S's.
        assert!(quality(6.933e-8, 6.862e-14).accepted(CONDENSED_ACCEPTED));
        assert!(quality(8.136e-8, 1.435e-12).condensed_accepted(6.933e-8));
        // ρ = 1e12 (n = 16): the AMD order's regularised pivots, and
        // cancellation in S (24× S's residual), still fall back.
        assert!(!quality(6.45e-7, 1.583e-12).accepted(LDLT_ACCEPTED));
        assert!(!quality(4.353e-7, 1.428e-12).accepted(CONDENSED_ACCEPTED));
        assert!(!quality(5.73e-8, 2.137e-13).condensed_accepted(2.429e-9));
        // Within the bounds: kept whatever the other measures.
        assert!(quality(1e-9, 1.0).accepted(LDLT_ACCEPTED));
        assert!(quality(2e-8, 1.0).condensed_accepted(1e-12));
    }
}
