//! Sparse direct factorisations (faer), factorised once and reused by every
//! solve of an iteration. The symbolic analysis is kept so a matrix with the
//! same pattern can be refactorised numerically only.

use crate::error::{Error, Result};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::{LdltError, LdltRegularization};
use faer::linalg::solvers::Solve;
use faer::perm::PermRef;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, simplicial, supernodal, LdltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::solvers::{Llt, Lu, SymbolicLlt, SymbolicLu};
use faer::sparse::{
    FaerError, SparseColMat, SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef,
    Triplet,
};
use faer::{Conj, MatMut, Par, Side};
use std::sync::Arc;

mod condensed;
mod linear_solver;
mod tree_ldlt;
pub use linear_solver::{
    analyse, factor_once, Factors, LinearMethod, LinearOptions, LinearSolver, SolverCounts,
    SystemPattern,
};
use tree_ldlt::TreeSchedule;

/// Lets the process keep the memory it frees for its next allocations
/// instead of returning it to the system (glibc's `mallopt`): every Newton
/// step allocates and frees factors of the same sizes (hundreds of MB), and
/// glibc serves blocks above its mmap threshold (≤ 32 MB) with fresh pages
/// that the kernel must fault in and zero each time (Uzawa: every
/// iteration's vectors of the problem's size). Measured on the shell,
/// active set at n = 128, same binary without and with it (issue 13):
/// system time 12.5 → 2.9 s, solver 43.9 → 34.6 s, peak RSS 1663 → 1774 MB.
/// One arena for every thread: the factorisation's and solves' second
/// threads otherwise keep an arena of their own, never trimmed (the shell's
/// n = 256 active set: peak 3,928,728 → 3,892,684 kB, same time).
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

/// The threads of the supernodal LDLᵀ factorisations and of the large
/// kernels (products, equilibration, entry checks, pattern fingerprints):
/// 1 (or 0) faer's sequential factorisation; 2 or more two threads on the
/// elimination tree (`tree_ldlt`), whose one-column solves use the same
/// split. Passed to each kernel by its caller, from [`LinearOptions`]
/// (`solver.threads`). Cholesky and LU are sequential: faer's own threads
/// lost on this 2-core machine (docs/work-precision.md, "Two threads on
/// the elimination tree").
fn two_threads(threads: usize) -> bool {
    threads >= 2
}

/// faer's parallelism: sequential (see [`two_threads`]).
fn parallelism() -> Par {
    Par::Seq
}

pub use condensed::InteriorGroups;
use condensed::{CondensationPlan, LocalFactors};

/// How a matrix given to this module is stored. Every factorisation of a
/// symmetric kind reads the lower triangle only (`Side::Lower`), so a
/// symmetric matrix may be given by its lower triangle alone (no stored
/// entry above the diagonal); its products then imply the upper one. Half
/// the memory: the active set's Newton matrix is given so (issue 13).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Storage {
    Whole,
    LowerTriangle,
}

impl Storage {
    /// A matrix of a symmetric kind without an entry above the diagonal is
    /// its lower triangle; anything else is whole (a general matrix always).
    /// Read from each column's first row: rows are sorted within a column
    /// (faer's checked constructors and its triplet assembly sort them),
    /// so one look per column serves instead of a pass over every entry
    /// (each product with the problem's A asks).
    fn of(a: SparseColMatRef<'_, usize, f64>, kind: MatrixKind) -> Self {
        let symbolic = a.symbolic();
        let lower = kind != MatrixKind::General
            && (0..a.ncols()).all(|j| symbolic.row_idx_of_col(j).next().is_none_or(|i| i >= j));
        debug_assert!(
            !lower || (0..a.ncols()).all(|j| symbolic.row_idx_of_col(j).all(|i| i >= j)),
            "row indices sorted within each column"
        );
        match lower {
            true => Storage::LowerTriangle,
            false => Storage::Whole,
        }
    }

    /// y = A x (a large lower triangle on `threads`).
    fn product(self, a: SparseColMatRef<'_, usize, f64>, x: &[f64], threads: usize) -> Vec<f64> {
        let s = a.symbolic();
        match self {
            Storage::Whole => mat_vec_ref(a, x),
            Storage::LowerTriangle => lower_product(s.col_ptr(), s.row_idx(), a.val(), x, threads),
        }
    }

    /// |A| |x| (entries' absolute values).
    fn absolute_product(self, a: SparseColMatRef<'_, usize, f64>, x: &[f64]) -> Vec<f64> {
        let (s, values) = (a.symbolic(), a.val());
        let mut y = vec![0.0; a.nrows()];
        for (j, &xj) in x.iter().enumerate() {
            for k in s.col_ptr()[j]..s.col_ptr()[j + 1] {
                let (i, v) = (s.row_idx()[k], values[k].abs());
                y[i] += v * xj.abs();
                // The implied upper entry (j, i).
                if self == Storage::LowerTriangle && i > j {
                    y[j] += v * x[i].abs();
                }
            }
        }
        y
    }

    /// r = b − A x.
    fn residual(
        self,
        a: SparseColMatRef<'_, usize, f64>,
        x: &[f64],
        b: &[f64],
        threads: usize,
    ) -> Vec<f64> {
        difference(b, &self.product(a, x, threads))
    }

    /// The matrix with both triangles (the lower triangle and its mirror),
    /// for LU, which reads every entry.
    fn whole(self, a: &SparseColMat<usize, f64>) -> std::borrow::Cow<'_, SparseColMat<usize, f64>> {
        if self == Storage::Whole {
            return std::borrow::Cow::Borrowed(a);
        }
        let mut entries = Vec::with_capacity(2 * a.val().len());
        for j in 0..a.ncols() {
            for (i, &v) in a.symbolic().row_idx_of_col(j).zip(a.val_of_col(j)) {
                entries.push(Triplet::new(i, j, v));
                if i != j {
                    entries.push(Triplet::new(j, i, v));
                }
            }
        }
        let whole = SparseColMat::try_new_from_triplets(a.nrows(), a.ncols(), &entries)
            .expect("indices of a valid matrix");
        std::borrow::Cow::Owned(whole)
    }
}

/// A index stored in a column's row list (usize, or u32 where memory counts).
trait RowIndex: Copy {
    fn get(self) -> usize;
}

impl RowIndex for usize {
    fn get(self) -> usize {
        self
    }
}

impl RowIndex for u32 {
    fn get(self) -> usize {
        self as usize
    }
}

/// y = A x for a symmetric A given by its lower triangle (CSC): each entry
/// below the diagonal is read once, for both of its places; entries above
/// the diagonal (there are none in this storage) would be ignored. A large
/// matrix on two threads ([`in_column_halves`]): the columns from j on
/// reach rows ≥ j only, so the second half sums into y[split..] alone,
/// added to the first half's y at the end (one sum per entry more than
/// in order: y agrees with the one-thread product to round-off).
fn lower_product<R: RowIndex + Sync>(
    col_ptr: &[usize],
    rows: &[R],
    values: &[f64],
    x: &[f64],
    threads: usize,
) -> Vec<f64> {
    let n = x.len();
    // y[columns.start..] of the columns `columns`.
    let part = |columns: std::ops::Range<usize>| {
        let from = columns.start;
        let mut y = vec![0.0; n - from];
        for j in columns {
            let (range, xj) = (col_ptr[j]..col_ptr[j + 1], x[j]);
            let mut upper = 0.0;
            for (&i, &v) in rows[range.clone()].iter().zip(&values[range]) {
                let i = i.get();
                if i > j {
                    y[i - from] += v * xj;
                    upper += v * x[i];
                } else if i == j {
                    upper += v * xj;
                }
            }
            y[j - from] += upper;
        }
        y
    };
    in_column_halves(&col_ptr[..=n], threads, part, |mut first, second| {
        let from = n - second.len();
        first[from..]
            .iter_mut()
            .zip(&second)
            .for_each(|(a, b)| *a += b);
        first
    })
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
enum RefinementMatrix {
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
struct SymmetricLower {
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

/// How well a solution x of A x = b (b ≠ 0) satisfies it.
#[derive(Debug, Clone, Copy)]
struct SolveQuality {
    /// ‖Ax − b‖∞/‖b‖∞.
    relative: f64,
    /// ‖Ax − b‖∞/(‖A‖ ‖x‖∞ + ‖b‖∞), ‖A‖ the largest entry.
    backward: f64,
    /// Componentwise (Oettli–Prager): max_i |Ax − b|_i/(|A| |x| + |b|)_i,
    /// each row against its own scale; computed (one more pass over A)
    /// only when the relative residual is above every acceptance bound.
    componentwise: Option<f64>,
}

impl SolveQuality {
    const EXACT: SolveQuality = SolveQuality {
        relative: 0.0,
        backward: 0.0,
        componentwise: Some(0.0),
    };

    fn of(
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
    fn with_product(
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
    fn accepted(self, bound: f64) -> bool {
        self.relative <= bound
            || self
                .componentwise
                .is_some_and(|c| c <= COMPONENTWISE_ACCEPTED)
    }

    /// A condensed solve (judged on A; S's own solve had relative residual
    /// `schur_relative`) is kept within [`CONDENSED_ACCEPTED`], or when the
    /// condensation lost at most [`CONDENSATION_LOSS`] of S's accuracy: what
    /// remains is S's conditioning, which A shares.
    fn condensed_accepted(self, schur_relative: f64) -> bool {
        self.relative <= CONDENSED_ACCEPTED || self.relative <= CONDENSATION_LOSS * schur_relative
    }
}

/// Solves A x = b with `f` and checks it ([`judge_solve`]; b = 0: on a
/// fixed test right-hand side instead, x = 0). Returns x and how well it
/// solves.
fn check_solve(
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
fn judge_solve(
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

/// The symbolic LU analysis of `a`'s pattern.
fn lu_analysis(a: &SparseColMat<usize, f64>, what: &str) -> Result<SymbolicAnalysis> {
    SymbolicLu::try_new(a.symbolic())
        .map(SymbolicAnalysis::Lu)
        .map_err(|e| Error::numerical(what, "LU (symbolic)", format!("{e:?}")))
}

/// A fixed, dense, non-trivial right-hand side for test solves.
fn test_rhs(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| 1.0 + ((i * 7919) % 13) as f64 / 13.0)
        .collect()
}

/// r = b − A x.
pub fn residual(a: &SparseColMat<usize, f64>, x: &[f64], b: &[f64]) -> Vec<f64> {
    difference(b, &mat_vec(a, x))
}

/// b − a.
fn difference(b: &[f64], a: &[f64]) -> Vec<f64> {
    b.iter().zip(a).map(|(p, q)| p - q).collect()
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

/// Index of the first non-finite entry of `v`, if any.
pub fn first_non_finite(v: &[f64]) -> Option<usize> {
    // Blocks without an early exit (they vectorise), then the position.
    const BLOCK: usize = 256;
    let block = v
        .chunks(BLOCK)
        .position(|c| c.iter().fold(false, |bad, x| bad | !x.is_finite()))?;
    let start = block * BLOCK;
    v[start..]
        .iter()
        .position(|x| !x.is_finite())
        .map(|k| start + k)
}

/// The symbolic analysis of a factorisation, by kind.
enum SymbolicAnalysis {
    Lu(SymbolicLu<usize>),
    Ldlt {
        analysis: LdltAnalysis,
        n_primal: usize,
        /// The order it was analysed for ([`Solves`]).
        order: Solves,
    },
    Llt(SymbolicLlt<usize>),
}

/// What every numeric LDLᵀ of one pattern reads.
struct LdltAnalysis {
    symbolic: Arc<SymbolicCholesky<usize>>,
    /// The two threads' split of a supernodal analysis ([`two_threads`]).
    schedule: Option<Arc<TreeSchedule>>,
    /// Where the matrix's entries go in that order.
    ordered: OrderedPattern,
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
type SharedMatrix = Arc<SparseColMat<usize, f64>>;

/// The groups of the last matrix, eliminated. S differs from the last
/// one only where a declared entry of A lands: there it is the Schur term
/// plus that entry.
struct KeptElimination {
    /// (A value position, S value position, Schur term there) of each
    /// declared entry.
    terms: Vec<(usize, usize, f64)>,
    local: Arc<LocalFactors>,
    /// The entries that stay, when every declared entry is on the
    /// diagonal: the next matrices' scale from their declared entries alone.
    fixed_scale: Option<FixedScale>,
}

/// The scale of a matrix's entries but its declared ones, all on the
/// diagonal: the largest off-diagonal entry, the largest other diagonal one.
#[derive(Debug, Clone, Copy)]
struct FixedScale {
    off_diagonal: f64,
    diagonal: f64,
}

impl FixedScale {
    /// Of `a` (checked whole: `scale`), when every position in `declared`
    /// is a diagonal entry.
    fn of(a: &SparseColMat<usize, f64>, scale: EntryScale, declared: &[usize]) -> Option<Self> {
        let (col_ptr, row_idx) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        let mut declared_column = vec![false; a.ncols()];
        for &k in declared {
            let j = col_ptr.partition_point(|&p| p <= k) - 1;
            if row_idx[k] != j {
                return None;
            }
            declared_column[j] = true;
        }
        let diagonal = (0..a.ncols())
            .filter(|&j| !declared_column[j])
            .fold(0.0f64, |m, j| m.max(diagonal_entry(a.as_ref(), j).abs()));
        Some(FixedScale {
            off_diagonal: scale.off_diagonal,
            diagonal,
        })
    }

    /// The scale of `a`, which differs from the matrix it was made of only
    /// at the `declared` positions; an error naming one that is not finite.
    fn with(
        self,
        a: &SparseColMat<usize, f64>,
        declared: &[usize],
        what: &str,
    ) -> Result<EntryScale> {
        let values = a.val();
        let mut diagonal = self.diagonal;
        for &k in declared {
            if !values[k].is_finite() {
                return Err(non_finite_entry(what, k));
            }
            diagonal = diagonal.max(values[k].abs());
        }
        Ok(EntryScale::of(self.off_diagonal, diagonal))
    }
}

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
struct DirectFactorizer {
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

/// The factor values of a dropped LDLᵀ, reused by the next one of the same
/// size: faer zeroes them itself before it factorises, so fresh zeroed
/// memory was a second pass over the factor (1.2 GB per Newton step at the
/// shell's n = 256). With them, what they are the factor of, when the next
/// one may keep the supernodes its changes do not reach ([`FactorInputs`]).
#[derive(Default)]
struct SpareFactors(std::sync::Mutex<Option<(Vec<f64>, Option<FactorInputs>)>>);

impl SpareFactors {
    /// `len` values: the spare ones when they fit, else zeros; an error
    /// (not an abort) when the memory for them is not there, so the
    /// factoriser's fallbacks and its caller see it (the shell's n = 512:
    /// the fallback order's factor of 14.6 GB beside everything else).
    /// With the values, what spare ones are the factor of.
    fn take(&self, len: usize, what: &str) -> Result<(Vec<f64>, Option<FactorInputs>)> {
        let spare = self.0.lock().map(|mut s| s.take()).unwrap_or(None);
        if let Some(spare) = spare.filter(|(v, _)| v.len() == len) {
            return Ok(spare);
        }
        let values = zeroed(len).ok_or_else(|| {
            Error::numerical(
                what,
                "LDLᵀ",
                format!(
                    "out of memory: the factor needs {:.1} GB",
                    len as f64 * std::mem::size_of::<f64>() as f64 / 1e9
                ),
            )
        })?;
        Ok((values, None))
    }

    fn put(&self, values: Vec<f64>, inputs: Option<FactorInputs>) {
        if let Ok(mut spare) = self.0.lock() {
            *spare = Some((values, inputs));
        }
    }
}

/// `len` zeros, or None when the memory is not there. Zeroed by the
/// allocator (calloc): fresh pages come zero from the kernel and are first
/// touched where the factorisation writes them, on both of its threads,
/// instead of all at once here by one (the floor's first factorisation at
/// the shell's n = 256 faulted in its 1.2 GB factor in a zero fill).
fn zeroed(len: usize) -> Option<Vec<f64>> {
    let layout = std::alloc::Layout::array::<f64>(len).ok()?;
    if layout.size() == 0 {
        return Some(Vec::new());
    }
    // SAFETY: the layout is Vec<f64>'s for capacity `len`, of nonzero size;
    // a non-null pointer from the global allocator with it, all bytes 0
    // (0.0), is a valid Vec of `len` values.
    unsafe {
        let ptr = std::alloc::alloc_zeroed(layout).cast::<f64>();
        (!ptr.is_null()).then(|| Vec::from_raw_parts(ptr, len, len))
    }
}

/// What a factor computed by the two threads' factorisation is the factor
/// of, as far as the next matrix with the same kept scale may differ: its
/// declared diagonal entries and their rows' scale. Everything else (the
/// other entries and D, the analysis, the regularisation's size) the next
/// matrix must share for its factorisation to keep supernodes of this one.
#[derive(Debug)]
struct FactorInputs {
    /// The [`KeptScale`] the matrix was scaled by ([`KeptScale::generation`]).
    generation: u64,
    symbolic: Arc<SymbolicCholesky<usize>>,
    /// The regularisation's size (max |D A D|), bit for bit.
    norm: f64,
    /// Per declared position: its value and its row's d_i.
    declared: Vec<(f64, f64)>,
}

impl FactorInputs {
    fn of(
        kept: &KeptScale,
        a: &SparseColMat<usize, f64>,
        symbolic: &Arc<SymbolicCholesky<usize>>,
        norm: f64,
    ) -> Self {
        let values = a.val();
        FactorInputs {
            generation: kept.generation,
            symbolic: symbolic.clone(),
            norm,
            declared: kept
                .positions
                .iter()
                .zip(&kept.rows)
                .map(|(&k, &i)| (values[k], kept.d[i]))
                .collect(),
        }
    }

    /// The columns (in the analysis' order `inverse`) whose entries differ
    /// between the matrices of `self` and `last`, or None when more than
    /// declared entries may differ.
    fn changed_columns(
        &self,
        last: &FactorInputs,
        kept: &KeptScale,
        inverse: &[usize],
    ) -> Option<Vec<usize>> {
        let same = self.generation == last.generation
            && Arc::ptr_eq(&self.symbolic, &last.symbolic)
            && self.norm.to_bits() == last.norm.to_bits()
            && self.declared.len() == last.declared.len();
        if !same {
            return None;
        }
        let bits = |(v, d): (f64, f64)| (v.to_bits(), d.to_bits());
        let mut columns = Vec::new();
        for (r, (&now, &before)) in self.declared.iter().zip(&last.declared).enumerate() {
            if bits(now) == bits(before) {
                continue;
            }
            // Row i's entries of P A Pᵀ: its diagonal, and each (i, j) in
            // the column of whichever of the two comes first.
            let p = inverse[kept.rows[r]];
            columns.push(p);
            if now.1.to_bits() == before.1.to_bits() {
                continue;
            }
            let neighbours = &kept.neighbours[kept.neighbour_ptr[r]..kept.neighbour_ptr[r + 1]];
            columns.extend(neighbours.iter().map(|&j| inverse[j].min(p)));
        }
        Some(columns)
    }
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
fn checked_scale(a: &SparseColMat<usize, f64>, what: &str, threads: usize) -> Result<EntryScale> {
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
fn non_finite_entry(what: &str, k: usize) -> Error {
    Error::numerical(what, "matrix entries", format!("entry {k} is not finite"))
}

/// The size of a matrix's entries, for the round-off level of a residual
/// row by row ([`EntryScale::excess`]).
#[derive(Debug, Clone, Copy)]
struct EntryScale {
    /// ‖A‖ = max |a_ij| (at least the smallest positive number).
    norm: f64,
    /// max |a_ij|, i ≠ j.
    off_diagonal: f64,
}

impl EntryScale {
    /// From the largest off-diagonal and diagonal |entries|.
    fn of(off_diagonal: f64, diagonal: f64) -> Self {
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
    fn excess(&self, r: &[f64], x: &[f64], b: &[f64], diagonal: impl Fn(usize) -> f64) -> f64 {
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

/// a_jj of a matrix whose rows are sorted within each column (0 where not
/// stored).
fn diagonal_entry(a: SparseColMatRef<'_, usize, f64>, j: usize) -> f64 {
    diagonal_position(a.symbolic().row_idx_of_col_raw(j), j).map_or(0.0, |p| a.val_of_col(j)[p])
}

/// Where row j is in column j's sorted `rows`: first in a lower triangle's.
fn diagonal_position<R: RowIndex>(rows: &[R], j: usize) -> Option<usize> {
    match rows.first().map(|r| r.get()) == Some(j) {
        true => Some(0),
        false => rows.binary_search_by(|r| r.get().cmp(&j)).ok(),
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

/// The pattern a [`ReusableFactorization`] was analysed for, as its
/// refactorisations check it: kept whole when a condensed factorisation's
/// refinement reads A's values on it (a general matrix), else only its
/// fingerprint. The copy was the largest avoidable array of the shell's
/// active set at n = 256 (75M row indices of the Newton matrix, 0.6 GB).
enum AnalysedPattern {
    Kept(Arc<SymbolicSparseColMat<usize>>),
    /// Order and a 64-bit hash of the column lengths and row indices:
    /// a different pattern passes only on a hash collision (the check is
    /// against calling with the wrong matrix, not against an adversary).
    Fingerprint {
        nrows: usize,
        ncols: usize,
        hash: u64,
    },
}

impl AnalysedPattern {
    fn of(a: &SparseColMat<usize, f64>, kind: MatrixKind, threads: usize) -> Self {
        match kind {
            MatrixKind::General => AnalysedPattern::Kept(Arc::new(pattern_of(a))),
            _ => AnalysedPattern::Fingerprint {
                nrows: a.nrows(),
                ncols: a.ncols(),
                hash: pattern_hash(a, threads),
            },
        }
    }

    /// Whether `a` has the pattern (compared column by column when kept:
    /// no copy of `a`'s pattern, which is as large as A's values).
    fn matches(&self, a: &SparseColMat<usize, f64>, threads: usize) -> bool {
        match self {
            AnalysedPattern::Kept(pattern) => {
                a.nrows() == pattern.nrows()
                    && a.ncols() == pattern.ncols()
                    && (0..a.ncols()).all(|j| {
                        a.symbolic().row_idx_of_col_raw(j) == pattern.row_idx_of_col_raw(j)
                    })
            }
            &AnalysedPattern::Fingerprint { nrows, ncols, hash } => {
                a.nrows() == nrows && a.ncols() == ncols && pattern_hash(a, threads) == hash
            }
        }
    }

    fn nrows(&self) -> usize {
        match self {
            AnalysedPattern::Kept(pattern) => pattern.nrows(),
            AnalysedPattern::Fingerprint { nrows, .. } => *nrows,
        }
    }
}

/// A 64-bit hash of `a`'s pattern: every column's length and the first
/// half of the row indices (column by column), then the second half
/// ([`PatternHasher`]); the halves hash on two threads when factorisations
/// have two ([`two_threads`]) and the pattern is large: the hash is the
/// same either way.
fn pattern_hash(a: &SparseColMat<usize, f64>, threads: usize) -> u64 {
    let s = a.symbolic();
    let mut first = PatternHasher::default();
    for j in 0..a.ncols() {
        first.push(s.row_idx_of_col_raw(j).len());
    }
    let rows: std::borrow::Cow<'_, [usize]> = match s.col_nnz() {
        // Compressed: the row indices are one slice.
        None => std::borrow::Cow::Borrowed(&s.row_idx()[..s.col_ptr()[a.ncols()]]),
        Some(_) => (0..a.ncols())
            .flat_map(|j| s.row_idx_of_col_raw(j).iter().copied())
            .collect(),
    };
    let (head, tail) = rows.split_at(rows.len() / 2);
    let hash_tail = || {
        let mut h = PatternHasher::default();
        h.extend(tail);
        h.finish()
    };
    let tail_hash = match two_threads(threads) && rows.len() >= PARALLEL_ENTRIES {
        true => std::thread::scope(|scope| {
            let tail_hash = scope.spawn(hash_tail);
            first.extend(head);
            tail_hash.join().expect("the pattern hash's second thread")
        }),
        false => {
            first.extend(head);
            hash_tail()
        }
    };
    PatternHasher::step(first.finish(), tail_hash as usize)
}

/// FxHash's multiply-rotate step dealt round-robin to four independent
/// chains: one chain waits for a multiply per value (the shell's n = 128
/// Newton matrix: 37 ms of every Newton step with the entry check), four
/// run at memory speed. The hash depends on the sequence only, not on how
/// it is cut into `extend` calls.
#[derive(Default)]
struct PatternHasher {
    lanes: [u64; 4],
    pushed: usize,
}

impl PatternHasher {
    fn step(h: u64, x: usize) -> u64 {
        (h.rotate_left(5) ^ x as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95)
    }

    fn push(&mut self, x: usize) {
        let lane = self.pushed % 4;
        self.lanes[lane] = Self::step(self.lanes[lane], x);
        self.pushed += 1;
    }

    fn extend(&mut self, values: &[usize]) {
        let head = ((4 - self.pushed % 4) % 4).min(values.len());
        values[..head].iter().for_each(|&x| self.push(x));
        let mut blocks = values[head..].chunks_exact(4);
        for block in &mut blocks {
            for (lane, &x) in self.lanes.iter_mut().zip(block) {
                *lane = Self::step(*lane, x);
            }
        }
        self.pushed += 4 * ((values.len() - head) / 4);
        blocks.remainder().iter().for_each(|&x| self.push(x));
    }

    fn finish(&self) -> u64 {
        let mixed = self.lanes.iter().fold(0, |h, &l| Self::step(h, l as usize));
        Self::step(mixed, self.pushed)
    }
}

/// The pattern of `a` in compact form.
fn pattern_of(a: &SparseColMat<usize, f64>) -> SymbolicSparseColMat<usize> {
    let s = a.symbolic();
    let mut col_ptr = Vec::with_capacity(a.ncols() + 1);
    let mut row_idx = Vec::with_capacity(a.val().len());
    col_ptr.push(0);
    for j in 0..a.ncols() {
        row_idx.extend(s.row_idx_of_col(j));
        col_ptr.push(row_idx.len());
    }
    SymbolicSparseColMat::new_checked(a.nrows(), a.ncols(), col_ptr, None, row_idx)
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
struct Equilibration {
    d: Vec<f64>,
    norm: Option<f64>,
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

/// What a matrix's scale and equilibration keep for the matrices that
/// differ from it only in some diagonal entries (the active set's
/// multiplier diagonal in S), itself included: the rest of the matrix is
/// not read again. D on the other rows is Ruiz's, with the declared
/// entries left out (they would make it depend on the first matrix's: the
/// free solve's switched-off rows, ~max|A|/ε², hid the multipliers'
/// couplings from D; the whole Newton matrix at n = 256 then stopped at
/// KKT 3.0e-10 instead of reaching 1e-10); a declared row i takes
/// d_i = min(1/√|a_ii|, 1/max_{j≠i} |a_ij| d_j), which makes its row
/// (and column) of D A D of max-norm 1, as Ruiz's sweeps aim at. Valid when
/// no two declared rows share an entry (their d_j would move together).
/// Measured on the shell's Newton steps at n = 256: Ruiz's three sweeps
/// over S alone took 0.065 s of a 2.2 s step; with S's scale and the norm
/// of D S D, five passes over S, now none.
struct KeptScale {
    /// The declared value positions and their rows.
    positions: Vec<usize>,
    rows: Vec<usize>,
    /// The scale of the entries that stay.
    fixed: FixedScale,
    /// D, its declared rows updated by [`KeptScale::with`].
    d: Vec<f64>,
    /// Per row: max_{j≠i} |a_ij| d_j (read for the declared rows).
    off_diagonal: Vec<f64>,
    /// max |a_ij| d_i d_j over the entries in no declared row or column.
    fixed_norm: f64,
    /// The other rows with an entry in declared row `positions[r]`'s row
    /// or column: `neighbours[neighbour_ptr[r]..neighbour_ptr[r + 1]]`.
    neighbour_ptr: Vec<usize>,
    neighbours: Vec<usize>,
    /// Unique to this scale: factors of matrices scaled by it may share
    /// supernodes ([`FactorInputs`]).
    generation: u64,
}

/// The next [`KeptScale::generation`].
static KEPT_SCALES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl KeptScale {
    /// Of `a` (`scale` its [`checked_scale`]) for changes at the `declared`
    /// positions; None when one is not on the diagonal or two declared
    /// rows share an entry.
    fn of(
        a: &SparseColMat<usize, f64>,
        scale: EntryScale,
        declared: &[usize],
        threads: usize,
    ) -> Option<Self> {
        let fixed = FixedScale::of(a, scale, declared)?;
        let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
        let rows: Vec<usize> = declared.iter().map(|&k| row_idx[k]).collect();
        // Per row: its place in `declared`, or usize::MAX.
        let mut declared_as = vec![usize::MAX; a.nrows()];
        rows.iter()
            .enumerate()
            .for_each(|(r, &i)| declared_as[i] = r);
        let is_declared = |i: usize| declared_as[i] != usize::MAX;
        let d = ruiz_equilibration(a, threads, |i, j| i == j && is_declared(i));
        let mut off_diagonal = vec![0.0f64; a.nrows()];
        let mut fixed_norm = 0.0f64;
        let mut pairs = Vec::new();
        for j in 0..a.ncols() {
            for k in col_ptr[j]..col_ptr[j + 1] {
                let (i, v) = (row_idx[k], values[k].abs());
                match (i == j, is_declared(i), is_declared(j)) {
                    (true, false, _) => fixed_norm = fixed_norm.max(v * d[i] * d[i]),
                    (true, true, _) => {}
                    (false, true, true) => return None,
                    (false, true, false) => {
                        off_diagonal[i] = off_diagonal[i].max(v * d[j]);
                        pairs.push((declared_as[i], j));
                    }
                    (false, false, true) => {
                        off_diagonal[j] = off_diagonal[j].max(v * d[i]);
                        pairs.push((declared_as[j], i));
                    }
                    (false, false, false) => fixed_norm = fixed_norm.max(v * d[i] * d[j]),
                }
            }
        }
        pairs.sort_unstable();
        let mut neighbour_ptr = vec![0usize; rows.len() + 1];
        pairs.iter().for_each(|&(r, _)| neighbour_ptr[r + 1] += 1);
        for r in 0..rows.len() {
            neighbour_ptr[r + 1] += neighbour_ptr[r];
        }
        Some(KeptScale {
            positions: declared.to_vec(),
            rows,
            fixed,
            d,
            off_diagonal,
            fixed_norm,
            neighbour_ptr,
            neighbours: pairs.into_iter().map(|(_, j)| j).collect(),
            generation: KEPT_SCALES.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        })
    }

    /// The scale and equilibration of `a`, which differs from the matrix
    /// this was made of only at the declared positions; an error naming
    /// one that is not finite.
    fn with(
        &mut self,
        a: &SparseColMat<usize, f64>,
        what: &str,
    ) -> Result<(EntryScale, Equilibration)> {
        let scale = self.fixed.with(a, &self.positions, what)?;
        let values = a.val();
        let mut norm = self.fixed_norm;
        for (&k, &i) in self.positions.iter().zip(&self.rows) {
            let (v, off) = (values[k].abs(), self.off_diagonal[i]);
            let mut d = if off > 0.0 { off.recip() } else { 1.0 };
            if v > 0.0 {
                d = d.min(v.sqrt().recip());
            }
            self.d[i] = d;
            norm = norm.max(v * d * d).max(off * d);
        }
        let equilibration = Equilibration {
            d: self.d.clone(),
            norm: Some(norm),
        };
        Ok((scale, equilibration))
    }
}

/// A diagonal D > 0 with every row of D A D of max-norm about 1 (three
/// sweeps of Ruiz's symmetric scaling). Why: the regularisation δ is one
/// number, so the blocks of a saddle matrix (stiffness up to ~ρ, constraint
/// rows O(1)) must be of comparable size for δ to be small against all of
/// them (measured on the thesis shell without the ψ scaling: test residual
/// 6e-5 unequilibrated, 3e-11 equilibrated).
fn symmetric_equilibration(a: &SparseColMat<usize, f64>, threads: usize) -> Vec<f64> {
    ruiz_equilibration(a, threads, |_, _| false)
}

/// [`symmetric_equilibration`] with the entries (i, j) where `left_out`
/// holds read as 0.
fn ruiz_equilibration(
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

/// [`Factorization::inverse_gram`] sweeps columns while the sweep and the
/// caller's solves with the same factors are estimated below this
/// fraction of a whole factorisation (in its multiply–adds): a bordered
/// solve then beats a new factorisation.
const GRAM_BUDGET: f64 = 0.5;
/// The factorisation's work runs on two threads; the sweep's estimate is
/// already its time on two (`tree_ldlt::forward_gram`).
const FACTORISATION_THREADS: f64 = 2.0;
/// A one-column solve's cost per factor entry, in the factorisation's
/// multiply–adds: it reads the factor once (memory-bound). Measured on
/// this machine (AMD EPYC, AVX2): 15 for the shell at n = 64 (4 solves ≈
/// 0.04 s, a factorisation 0.15 s), 40 at n = 256 (0.35 s and 5.4 s); the
/// low end keeps the bordered step where it pays at every size, and
/// refuses it for the membrane disk p1b-p0, whose 4 solves cost about a
/// factorisation (n = 256: a switched step 0.66 s, a factorised 0.52 s).
const SOLVE_WORK_PER_ENTRY: f64 = 15.0;

/// Matrices (and factors) with at least this many entries are checked,
/// equilibrated and solved with on two threads when factorisations have
/// two ([`two_threads`]).
const PARALLEL_ENTRIES: usize = 1 << 20;

/// `work` over all of `a`'s columns: on two threads (each about half the
/// entries, the results combined) when factorisations have two and `a` is
/// large, else at once.
fn in_two_halves<R: Send>(
    a: &SparseColMat<usize, f64>,
    threads: usize,
    work: impl Fn(std::ops::Range<usize>) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    in_column_halves(a.symbolic().col_ptr(), threads, work, combine)
}

/// [`in_two_halves`] for the columns of a compressed pattern given by its
/// column pointers (`col_ptr[n]` = its number of entries).
fn in_column_halves<R: Send>(
    col_ptr: &[usize],
    threads: usize,
    work: impl Fn(std::ops::Range<usize>) -> R + Sync,
    combine: impl FnOnce(R, R) -> R,
) -> R {
    let n = col_ptr.len() - 1;
    let Some(split) = column_halves(col_ptr, threads) else {
        return work(0..n);
    };
    std::thread::scope(|scope| {
        let second = scope.spawn(|| work(split..n));
        let first = work(0..split);
        combine(first, second.join().expect("the second thread"))
    })
}

/// Where [`in_column_halves`] splits the columns of `col_ptr` (the
/// first column of the second half), or None when it works on one thread.
fn column_halves(col_ptr: &[usize], threads: usize) -> Option<usize> {
    let n = col_ptr.len() - 1;
    let nnz = col_ptr[n];
    (two_threads(threads) && nnz >= PARALLEL_ENTRIES)
        .then(|| col_ptr.partition_point(|&p| p < nnz / 2).min(n))
}

/// The LDLᵀ analysis in the ordering `solves` asks for, with its two
/// threads' schedule when supernodal and this thread factorises on two
/// ([`two_threads`]).
fn ldlt_analysis(
    a: &SparseColMat<usize, f64>,
    n_primal: usize,
    solves: Solves,
    what: &str,
    threads: usize,
) -> Result<SymbolicAnalysis> {
    let symbolic = analyze_symmetric(a, n_primal, solves, what)?;
    let schedule = match symbolic.raw() {
        SymbolicCholeskyRaw::Supernodal(raw) if two_threads(threads) => {
            TreeSchedule::new(raw).map(Arc::new)
        }
        _ => None,
    };
    let ordered = OrderedPattern::new(&symbolic, a, n_primal, schedule.is_some());
    Ok(SymbolicAnalysis::Ldlt {
        analysis: LdltAnalysis {
            symbolic: Arc::new(symbolic),
            schedule,
            ordered,
        },
        n_primal,
        order: solves,
    })
}

/// The symbolic LDLᵀ analysis in the ordering `solves` asks for.
fn analyze_symmetric(
    a: &SparseColMat<usize, f64>,
    n_primal: usize,
    solves: Solves,
    what: &str,
) -> Result<SymbolicCholesky<usize>> {
    let fail = |e: FaerError| Error::numerical(what, "LDLᵀ (symbolic)", format!("{e:?}"));
    match solves {
        Solves::Few => factorize_symbolic_cholesky(
            a.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        ),
        Solves::Many => {
            let (fwd, inv) = multipliers_after_neighbours(a, n_primal).map_err(fail)?;
            factorize_symbolic_cholesky(
                a.symbolic(),
                Side::Lower,
                SymmetricOrdering::Custom(PermRef::new_checked(&fwd, &inv, a.nrows())),
                Default::default(),
            )
        }
    }
    .map_err(fail)
}

/// The AMD order of the symmetric pattern with every multiplier (index ≥
/// n_primal) moved right after the last of its primal neighbours: its
/// pivot is then the nonzero local Schur complement −b K⁻¹ bᵀ instead of 0.
/// Returns (forward, inverse), `forward[new] = old`.
fn multipliers_after_neighbours(
    a: &SparseColMat<usize, f64>,
    n_primal: usize,
) -> std::result::Result<(Vec<usize>, Vec<usize>), FaerError> {
    let n = a.nrows();
    let (mut fwd, mut inv) = (vec![0usize; n], vec![0usize; n]);
    let mut buffer =
        MemBuffer::try_new(amd::order_maybe_unsorted_scratch::<usize>(n, a.val().len()))
            .map_err(|_| FaerError::OutOfMemory)?;
    amd::order_maybe_unsorted(
        &mut fwd,
        &mut inv,
        a.symbolic(),
        Default::default(),
        MemStack::new(&mut buffer),
    )?;
    // The AMD position of each multiplier's last primal neighbour, from
    // the entries of either triangle (the matrix may be its lower one).
    let mut last: Vec<Option<usize>> = vec![None; n];
    for j in 0..n {
        for i in a.symbolic().row_idx_of_col(j) {
            let (multiplier, primal) = match (i < n_primal, j < n_primal) {
                (true, false) => (j, i),
                (false, true) => (i, j),
                _ => continue,
            };
            last[multiplier] = last[multiplier].max(Some(inv[primal]));
        }
    }
    // Sort key: (position of the last primal neighbour, after the primal
    // unknown at that position, own AMD position).
    let mut order: Vec<(usize, bool, usize, usize)> = (0..n)
        .map(|j| match j < n_primal {
            true => (inv[j], false, inv[j], j),
            false => (last[j].unwrap_or(inv[j]), true, inv[j], j),
        })
        .collect();
    order.sort_unstable();
    for (new, &(_, _, _, old)) in order.iter().enumerate() {
        fwd[new] = old;
        inv[old] = new;
    }
    Ok((fwd, inv))
}

/// Relative size of the regularised pivots: δ = √ε · max|DAD| (D the
/// equilibration). A pivot of the wrong sign or below ε·max|DAD| in size (a multiplier eliminated before
/// its primal neighbours) is replaced by ±δ, so the factors are those of
/// A + E with ‖E‖ ≤ δ; refinement against A removes the perturbation, each
/// step gaining about −log₁₀(√ε) ≈ 8 digits.
const REGULARIZATION: f64 = 1.5e-8;
/// Test residual (‖Ax − b‖∞/‖b‖∞ after refinement) up to which the LDLᵀ of a
/// matrix factorised whole is used, else the next fallback. Measured on
/// the shell matrices (ρ = 0 … 1e12, thin, plate, with and without the ψ
/// scaling, 16×16): LDLᵀ and LU both leave 1e-12 … 7e-10; the AMD order at
/// ρ = 1e12, whose regularised pivots the refinement cannot undo, 5.1e-7
/// (LU 4.2e-9; `ldlt_matches_lu_on_the_shell`). The condensed shell's first
/// Newton matrix at n = 256 leaves 1.4e-8 (S, AMD order), 1.6e-8 (S, the
/// other order) and 5.9e-9 (the whole matrix). 3e-8 here let Young's
/// modulus 1e-14 (`parsers_prop`) stop on a whole-matrix LDLᵀ at 1.3e-8 where
/// LU reaches the tolerance.
const LDLT_ACCEPTED: f64 = 1e-8;
/// The bound of a condensed factorisation (S's LDLᵀ, and the condensed solve
/// judged on A), whose fallback is the whole matrix: n = 256's 1.4e-8 (S) and
/// 1.5e-8 (on A) are kept (falling back cost 10.1 GB against 7.0 GB), the
/// condensed shell at ρ = 1e12 (5.0e-8, whole 3e-10: cancellation in S) goes
/// on to the whole matrix.
const CONDENSED_ACCEPTED: f64 = 3e-8;
/// How many times S's own relative residual a condensed solve (judged on A)
/// may have and still be kept above [`CONDENSED_ACCEPTED`]. Cancellation
/// in S shows as a large ratio: the shell at ρ = 1e12 (n = 16) has 2.4e-9
/// on S and 5.7e-8 on A (24×; the whole matrix then reaches 3e-10). Growing
/// conditioning does not: the first Newton solve at n = 64, 128, 512 has
/// 4.0e-10 / 5.1e-10, 2.8e-9 / 2.7e-9, 6.9e-8 / 8.1e-8 (≤ 1.3×); at n = 512
/// the bound alone sent it to the whole matrix, which does not fit.
const CONDENSATION_LOSS: f64 = 4.0;
/// Backward error ‖Ax − b‖∞/(‖A‖ ‖x‖∞ + ‖b‖∞) up to which the SPD fallback
/// (equilibrated, refined LDLᵀ of a matrix plain Cholesky could not solve
/// to 1e-6) is accepted.
const BACKWARD_ACCEPTED: f64 = 1e-12;
/// Componentwise backward error (Oettli–Prager, [`SolveQuality`]) up to
/// which a refined solve is kept whatever its relative residual: x then
/// solves a matrix and right-hand side perturbed by < 4e-13 in every entry,
/// as well as any backward-stable solve does. Why not the relative residual
/// alone: it grows with the conditioning even at round-off. The shell's
/// first Newton solve (b the load alone, small against A x's terms) has
/// relative residual 4.0e-10 at n = 64 and 1.4e-8 at n = 256, near
/// [`CONDENSED_ACCEPTED`]; at n = 512 it crossed it and the fallback order's
/// factor (14.6 GB) did not fit. Measured on the shell at n = 16
/// (`ldlt_matches_lu_on_the_shell`): accurate solves 2.5e-16 … 4.2e-14, the
/// AMD order at ρ = 1e12, whose regularised pivots the refinement cannot
/// undo, 1.6e-12 (and relative residual 6.5e-7 against LU's 3.9e-9).
/// Tenth session, n = 512: the first Newton solve's S (AMD order) left
/// relative residual 7.0e-8, normwise backward error 2.1e-16 and
/// componentwise 1.48e-13 (a round-off change in the products tipped it
/// over 1e-13, and the fallback order's factor did not fit): 4e-13 keeps
/// it, ~4× below the regularised case.
const COMPONENTWISE_ACCEPTED: f64 = 4e-13;
/// Refinement steps at most; they stop earlier at round-off level.
const MAX_REFINEMENT: usize = 6;

/// A matrix given to a factorisation: borrowed from the caller, or owned
/// (S of a condensed factorisation) and then shared with the LDLᵀ that
/// keeps it instead of copying it.
#[derive(Clone)]
enum Shared<'a> {
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

/// The pattern of P A Pᵀ as the numeric factorisation of a symbolic
/// analysis reads it (in its order P, on its side: supernodal lower,
/// simplicial upper; from A's lower triangle), and the signs in that order.
/// Computed once per analysis: each factorisation then only scatters
/// A's values (a counting sort of S's pattern per Newton step took 4.8 s
/// of the shell's n = 256 active set, 17 steps).
struct OrderedPattern {
    /// P A Pᵀ's pattern, rows unsorted within a column: in each column the
    /// entries in the order A's columns give them.
    pattern: SymbolicSparseColMat<usize>,
    /// The inverse order: `inverse[old] = new`.
    inverse: Vec<usize>,
    /// Whether P A Pᵀ is read by its upper triangle (simplicial).
    upper: bool,
    /// Per entry of P A Pᵀ, the position of its value in A: kept for the
    /// two threads' factorisation, which reads A's values through it
    /// ([`OrderedPattern::entries`]) instead of a scaled copy.
    source: Option<Vec<u32>>,
    /// The signs of the regularisation in the order P.
    signs: Vec<i8>,
}

impl OrderedPattern {
    /// The pattern of `a` (n_primal positive signs, then negative) in the
    /// order of `symbolic`, with the positions of A's values when `sources`
    /// (and they fit 32 bits).
    fn new(
        symbolic: &SymbolicCholesky<usize>,
        a: &SparseColMat<usize, f64>,
        n_primal: usize,
        sources: bool,
    ) -> Self {
        let n = a.nrows();
        let (forward, inverse): (Vec<usize>, Vec<usize>) = match symbolic.perm() {
            Some(perm) => (perm.arrays().0.to_vec(), perm.arrays().1.to_vec()),
            None => ((0..n).collect(), (0..n).collect()),
        };
        let upper = matches!(symbolic.raw(), SymbolicCholeskyRaw::Simplicial(_));
        let mut ordered = OrderedPattern {
            pattern: SymbolicSparseColMat::new_checked(n, n, vec![0; n + 1], None, Vec::new()),
            inverse,
            upper,
            source: None,
            signs: forward
                .iter()
                .map(|&i| if i < n_primal { 1 } else { -1 })
                .collect(),
        };
        let mut counts = vec![0usize; n + 1];
        ordered.for_each_entry(a, |_, (_, c)| counts[c + 1] += 1);
        for c in 0..n {
            counts[c + 1] += counts[c];
        }
        let mut next = counts[..n].to_vec();
        let mut row_idx = vec![0; counts[n]];
        let sources = sources && a.val().len() <= u32::MAX as usize;
        let mut source = vec![0u32; if sources { counts[n] } else { 0 }];
        ordered.for_each_entry(a, |k, (r, c)| {
            row_idx[next[c]] = r;
            if sources {
                source[next[c]] = k as u32;
            }
            next[c] += 1;
        });
        ordered.pattern = SymbolicSparseColMat::new_unsorted_checked(n, n, counts, None, row_idx);
        ordered.source = sources.then_some(source);
        ordered
    }

    /// `visit(k, (row, column))` for every entry k of A's lower triangle,
    /// (row, column) its place in P A Pᵀ on the side read; A's columns in
    /// order.
    fn for_each_entry(
        &self,
        a: &SparseColMat<usize, f64>,
        mut visit: impl FnMut(usize, (usize, usize)),
    ) {
        let (col_ptr, row_idx) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        for j in 0..a.ncols() {
            let pj = self.inverse[j];
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                if i < j {
                    continue;
                }
                let pi = self.inverse[i];
                let place = match self.upper {
                    false => (pi.max(pj), pi.min(pj)),
                    true => (pi.min(pj), pi.max(pj)),
                };
                visit(k, place);
            }
        }
    }

    /// P (D A D) Pᵀ read through the positions of A's values (None
    /// without them): its entries are v (d_i d_j) as in
    /// [`OrderedPattern::equilibrated`], made where they are read; `norm`:
    /// the largest |v (d_i d_j)| when known.
    fn entries<'a>(
        &'a self,
        a: &'a SparseColMat<usize, f64>,
        scale: &[f64],
        norm: Option<f64>,
        threads: usize,
    ) -> Option<OrderedEntries<'a>> {
        let source = self.source.as_deref()?;
        Some(OrderedEntries {
            pattern: self.pattern.as_ref(),
            source,
            values: a.val(),
            norm: norm.unwrap_or_else(|| equilibrated_norm(a, scale, threads)),
            scale: self.in_order(scale),
        })
    }

    /// `scale` in the order P.
    fn in_order(&self, scale: &[f64]) -> Vec<f64> {
        let mut ordered = vec![0.0; scale.len()];
        for (&new, &d) in self.inverse.iter().zip(scale) {
            ordered[new] = d;
        }
        ordered
    }

    /// P (D A D) Pᵀ's values, A of this pattern, D = diag(`scale`): each
    /// entry v (d_i d_j), as faer's permutation and a scaling gave them.
    fn equilibrated(&self, a: &SparseColMat<usize, f64>, scale: &[f64]) -> OrderedMatrix<'_> {
        let (values, scale) = (a.val(), self.in_order(scale));
        let mut next = self.pattern.col_ptr()[..a.ncols()].to_vec();
        let mut ordered = vec![0.0; self.pattern.row_idx().len()];
        let mut norm = 0.0f64;
        // A's columns in order, as the pattern was made.
        self.for_each_entry(a, |k, (r, c)| {
            let v = values[k] * (scale[r] * scale[c]);
            ordered[next[c]] = v;
            next[c] += 1;
            norm = norm.max(v.abs());
        });
        OrderedMatrix {
            pattern: self,
            values: ordered,
            norm,
        }
    }
}

/// faer's numeric LDLᵀ of `scaled` (sequential; supernodal or
/// simplicial as analysed) into `values`.
fn factorize_in_faer(
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

/// P (D A D) Pᵀ's values as a numeric factorisation reads them, on their
/// [`OrderedPattern`].
struct OrderedMatrix<'p> {
    pattern: &'p OrderedPattern,
    values: Vec<f64>,
    /// max |v| of the values.
    norm: f64,
}

impl OrderedMatrix<'_> {
    fn as_ref(&self) -> SparseColMatRef<'_, usize, f64> {
        SparseColMatRef::new(self.pattern.pattern.as_ref(), &self.values)
    }
}

/// P (D A D) Pᵀ without a copy ([`OrderedPattern::entries`]): entry t
/// (row i, column j of the pattern) is `values[source[t]] scale[i]
/// scale[j]`.
struct OrderedEntries<'a> {
    pattern: SymbolicSparseColMatRef<'a, usize>,
    source: &'a [u32],
    values: &'a [f64],
    /// D in the order P.
    scale: Vec<f64>,
    /// max |v| of the entries.
    norm: f64,
}

/// max |v (d_i d_j)| over A's lower triangle, D = diag(`scale`): the
/// largest entry of D A D, on two threads as the equilibration.
fn equilibrated_norm(a: &SparseColMat<usize, f64>, scale: &[f64], threads: usize) -> f64 {
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let largest = |columns: std::ops::Range<usize>| {
        let mut norm = 0.0f64;
        for j in columns {
            let dj = scale[j];
            for k in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[k];
                if i >= j {
                    norm = norm.max((values[k] * (scale[i] * dj)).abs());
                }
            }
        }
        norm
    };
    in_two_halves(a, threads, largest, f64::max)
}

/// Solves A x = b in place with `raw_solve` (an approximate inverse), then
/// refines against `product` (A x) to round-off ([`refine_to_round_off`]);
/// returns A x of the final x.
fn solve_refined(
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
fn refine_to_round_off(
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

/// y = A x.
pub fn mat_vec(a: &SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    mat_vec_ref(a.as_ref(), x)
}

/// y = A x for a matrix of `kind` as this module reads it: a symmetric one
/// given by its lower triangle implies the upper one (`Storage`), a large
/// one multiplied on `threads` ([`two_threads`]).
pub fn product(
    a: &SparseColMat<usize, f64>,
    kind: MatrixKind,
    x: &[f64],
    threads: usize,
) -> Vec<f64> {
    Storage::of(a.as_ref(), kind).product(a.as_ref(), x, threads)
}

/// The lower triangle of `a` (its entries on and below the diagonal), made
/// in `a`'s own arrays: a symmetric matrix's storage that every
/// factorisation and [`product`] reads, at half the memory (the shell's A
/// at n = 256: 1.07 GB whole, 0.53 GB lower).
pub fn into_lower_triangle(a: SparseColMat<usize, f64>) -> SparseColMat<usize, f64> {
    let n = a.nrows();
    retain_entries(a, n, n, |i, j| i >= j)
}

/// The `nrows` × `ncols` matrix of the entries (i, j) of `a` with j <
/// `ncols` and `keep(i, j)` (each kept i < `nrows`), made in `a`'s own
/// arrays (entries only move towards the front; the arrays shrink to
/// fit): no second copy of `a` at any time.
pub fn retain_entries(
    a: SparseColMat<usize, f64>,
    nrows: usize,
    ncols: usize,
    keep: impl Fn(usize, usize) -> bool,
) -> SparseColMat<usize, f64> {
    let (symbolic, mut values) = a.into_parts();
    let (_, _, mut col_ptr, col_nnz, mut row_idx) = symbolic.into_parts();
    let mut kept = 0;
    for j in 0..ncols {
        let range = match &col_nnz {
            Some(nnz) => col_ptr[j]..col_ptr[j] + nnz[j],
            None => col_ptr[j]..col_ptr[j + 1],
        };
        col_ptr[j] = kept;
        for k in range {
            if keep(row_idx[k], j) {
                debug_assert!(row_idx[k] < nrows, "a kept row inside the result");
                (row_idx[kept], values[kept]) = (row_idx[k], values[k]);
                kept += 1;
            }
        }
    }
    col_ptr.truncate(ncols + 1);
    col_ptr[ncols] = kept;
    col_ptr.shrink_to_fit();
    row_idx.truncate(kept);
    values.truncate(kept);
    row_idx.shrink_to_fit();
    values.shrink_to_fit();
    let symbolic = SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, None, row_idx);
    SparseColMat::new(symbolic, values)
}

/// y = A x for a borrowed matrix.
fn mat_vec_ref(a: SparseColMatRef<'_, usize, f64>, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; a.nrows()];
    let (cp, ri, val) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    for j in 0..a.ncols() {
        let xj = x[j];
        if xj != 0.0 {
            for k in cp[j]..cp[j + 1] {
                y[ri[k]] += val[k] * xj;
            }
        }
    }
    y
}

/// y = Aᵀ x.
pub fn mat_t_vec(a: &SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    let (cp, ri, val) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    (0..a.ncols())
        .map(|j| (cp[j]..cp[j + 1]).map(|k| val[k] * x[ri[k]]).sum())
        .collect()
}

/// max |x_i|.
pub fn norm_inf(x: &[f64]) -> f64 {
    x.iter().fold(0.0, |m, v| m.max(v.abs()))
}

/// (Σ x_i²)^(1/2).
pub fn norm2(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

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
