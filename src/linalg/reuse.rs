//! The performance paths of the numeric phase, for matrices that differ
//! from the last one only in declared entries (`Changed::Declared`, the
//! active set's multiplier diagonal): what a factoriser keeps between them
//! (the eliminated groups, the scale and equilibration, a dropped LDLᵀ's
//! factor values and what they are the factor of), and the budget of the
//! bordered solves through [`super::Factorization::inverse_gram`]. The
//! factorisations give bit for bit what they give without them.

use super::condensed::LocalFactors;
use super::kernels::diagonal_entry;
use super::{non_finite_entry, ruiz_equilibration, EntryScale, Equilibration};
use crate::error::{Error, Result};
use faer::sparse::linalg::cholesky::SymbolicCholesky;
use faer::sparse::SparseColMat;
use std::sync::Arc;
/// The groups of the last matrix, eliminated. S differs from the last
/// one only where a declared entry of A lands: there it is the Schur term
/// plus that entry.
pub(super) struct KeptElimination {
    /// (A value position, S value position, Schur term there) of each
    /// declared entry.
    pub(super) terms: Vec<(usize, usize, f64)>,
    pub(super) local: Arc<LocalFactors>,
    /// The entries that stay, when every declared entry is on the
    /// diagonal: the next matrices' scale from their declared entries alone.
    pub(super) fixed_scale: Option<FixedScale>,
}

/// The scale of a matrix's entries but its declared ones, all on the
/// diagonal: the largest off-diagonal entry, the largest other diagonal one.
#[derive(Debug, Clone, Copy)]
pub(super) struct FixedScale {
    pub(super) off_diagonal: f64,
    pub(super) diagonal: f64,
}

impl FixedScale {
    /// Of `a` (checked whole: `scale`), when every position in `declared`
    /// is a diagonal entry.
    pub(super) fn of(
        a: &SparseColMat<usize, f64>,
        scale: EntryScale,
        declared: &[usize],
    ) -> Option<Self> {
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
    pub(super) fn with(
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

/// The factor values of a dropped LDLᵀ, reused by the next one of the same
/// size: faer zeroes them itself before it factorises, so fresh zeroed
/// memory was a second pass over the factor (1.2 GB per Newton step at the
/// shell's n = 256). With them, what they are the factor of, when the next
/// one may keep the supernodes its changes do not reach ([`FactorInputs`]).
#[derive(Default)]
pub(super) struct SpareFactors(std::sync::Mutex<Option<(Vec<f64>, Option<FactorInputs>)>>);

impl SpareFactors {
    /// `len` values: the spare ones when they fit, else zeros; an error
    /// (not an abort) when the memory for them is not there, so the
    /// factoriser's fallbacks and its caller see it (the shell's n = 512:
    /// the fallback order's factor of 14.6 GB beside everything else).
    /// With the values, what spare ones are the factor of.
    pub(super) fn take(&self, len: usize, what: &str) -> Result<(Vec<f64>, Option<FactorInputs>)> {
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

    pub(super) fn put(&self, values: Vec<f64>, inputs: Option<FactorInputs>) {
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
pub(super) fn zeroed(len: usize) -> Option<Vec<f64>> {
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
pub(super) struct FactorInputs {
    /// The [`KeptScale`] the matrix was scaled by ([`KeptScale::generation`]).
    pub(super) generation: u64,
    pub(super) symbolic: Arc<SymbolicCholesky<usize>>,
    /// The regularisation's size (max |D A D|), bit for bit.
    pub(super) norm: f64,
    /// Per declared position: its value and its row's d_i.
    pub(super) declared: Vec<(f64, f64)>,
}

impl FactorInputs {
    pub(super) fn of(
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
    pub(super) fn changed_columns(
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
/// over S alone take 0.065 s of a 2.2 s step; with S's scale and the norm
/// of D S D they are five passes over S, which keeping the scale saves.
pub(super) struct KeptScale {
    /// The declared value positions and their rows.
    pub(super) positions: Vec<usize>,
    pub(super) rows: Vec<usize>,
    /// The scale of the entries that stay.
    pub(super) fixed: FixedScale,
    /// D, its declared rows updated by [`KeptScale::with`].
    pub(super) d: Vec<f64>,
    /// Per row: max_{j≠i} |a_ij| d_j (read for the declared rows).
    pub(super) off_diagonal: Vec<f64>,
    /// max |a_ij| d_i d_j over the entries in no declared row or column.
    pub(super) fixed_norm: f64,
    /// The other rows with an entry in declared row `positions[r]`'s row
    /// or column: `neighbours[neighbour_ptr[r]..neighbour_ptr[r + 1]]`.
    pub(super) neighbour_ptr: Vec<usize>,
    pub(super) neighbours: Vec<usize>,
    /// Unique to this scale: factors of matrices scaled by it may share
    /// supernodes ([`FactorInputs`]).
    pub(super) generation: u64,
}

/// The next [`KeptScale::generation`].
pub(super) static KEPT_SCALES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl KeptScale {
    /// Of `a` (`scale` its [`checked_scale`]) for changes at the `declared`
    /// positions; None when one is not on the diagonal or two declared
    /// rows share an entry.
    pub(super) fn of(
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
    pub(super) fn with(
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

/// [`Factorization::inverse_gram`] sweeps columns while the sweep and the
/// caller's solves with the same factors are estimated below this
/// fraction of a whole factorisation (in its multiply–adds): a bordered
/// solve then beats a new factorisation.
pub(super) const GRAM_BUDGET: f64 = 0.5;

/// The factorisation's work runs on two threads; the sweep's estimate is
/// already its time on two (`tree_ldlt::forward_gram`).
pub(super) const FACTORISATION_THREADS: f64 = 2.0;

/// A one-column solve's cost per factor entry, in the factorisation's
/// multiply–adds: it reads the factor once (memory-bound). 15 to 40 on
/// the shells (n = 64 … 256); the low end keeps the bordered step where it
/// pays and refuses it where a few solves cost about a factorisation (the
/// membrane disk p1b-p0).
pub(super) const SOLVE_WORK_PER_ENTRY: f64 = 15.0;
