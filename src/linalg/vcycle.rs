//! The V-cycle for a symmetric positive definite matrix, given the
//! prolongations of a nested hierarchy: Galerkin coarse operators PᵀAP,
//! Gauss–Seidel or damped Jacobi smoothing, the coarsest level factorised
//! through the linear-solver seam (`linalg::factor_once`, Cholesky).
//!
//! The matrices are stored whole (both triangles) in compressed columns:
//! Gauss–Seidel reads row i of a symmetric A as its column i.

use super::kernels::{cut, each_in_halves, on_halves};
use super::pcg::{norm2, pcg, product, residual, CgReport};
use super::{factor_once, Factors, LinearOptions, MatrixKind, Solves, SystemPattern};
use crate::error::{Error, Result};
use faer::sparse::linalg::matmul::sparse_sparse_matmul;
use faer::sparse::{SparseColMat, SymbolicSparseColMat, SymbolicSparseColMatRef};
use faer::{Index, Par};
use std::ops::Range;

const STAGE: &str = "multigrid";

/// How each level smooths.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Smoother {
    /// Gauss–Seidel: forward sweeps before the coarse correction, backward
    /// sweeps after it, so the V-cycle is a symmetric operator (a CG
    /// preconditioner).
    GaussSeidel,
    /// Symmetric Gauss–Seidel: each smoothing step a forward and a backward
    /// sweep (twice the work of a [`Smoother::GaussSeidel`] step). The
    /// default: on the P1 Laplacian on the square (3–6 levels) its
    /// V(1,1)-cycle contracts the residual by 0.11–0.13 per cycle on
    /// average, Gauss–Seidel's V(1,1) (half the sweeps) by 0.23–0.26 and
    /// damped Jacobi's (ω = 4/5) by 0.36–0.42 (docs/solvers.md,
    /// "Multigrid").
    SymmetricGaussSeidel,
    /// x ← x + ω D⁻¹ (b − A x).
    Jacobi { omega: f64 },
}

/// The cycle's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MultigridOptions {
    /// Smoothing steps before (`pre`) and after (`post`) the coarse
    /// correction; a V(ν₁, ν₂)-cycle. Equal counts keep it symmetric.
    pub pre: usize,
    pub post: usize,
    pub smoother: Smoother,
    /// The order of the Gauss–Seidel sweeps on each level.
    pub order: SweepOrder,
    /// The coarsest level's direct solver.
    pub coarse: LinearOptions,
    /// With 2 or more, the levels of at least 2¹⁶ unknowns are smoothed,
    /// and their vectors worked on, in two halves on two threads (the same
    /// numbers on one: [`SweptLevel`]).
    pub threads: usize,
}

impl Default for MultigridOptions {
    /// V(1,1) with symmetric Gauss–Seidel in Cuthill–McKee order, the
    /// coarsest level on one thread.
    fn default() -> Self {
        MultigridOptions {
            pre: 1,
            post: 1,
            smoother: Smoother::SymmetricGaussSeidel,
            order: SweepOrder::CuthillMcKee,
            coarse: LinearOptions {
                threads: 1,
                ..LinearOptions::default()
            },
            threads: 1,
        }
    }
}

/// The order in which Gauss–Seidel visits a level's unknowns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepOrder {
    /// As numbered. On a refined mesh that is hierarchical: the coarse
    /// vertices first, then each level's midpoints.
    Numbered,
    /// Cuthill–McKee of the level's matrix graph (breadth first from a
    /// vertex of least degree, neighbours by increasing degree): fronts
    /// sweeping across the domain, as a lexicographic order does on a grid.
    /// The default: symmetric Gauss–Seidel's V(1,1) contracts by 0.11–0.13
    /// in this order, by 0.17–0.20 in the hierarchical one (the square, 3–6
    /// levels).
    CuthillMcKee,
}

/// One level's operator made ready to join a hierarchy ([`Multigrid::stacked`]):
/// stored in its sweep order, its diagonal checked positive. Building it
/// (the ordering and the renumbering) is most of a level's set-up and needs
/// no other level.
///
/// A level of at least 2¹⁶ unknowns is swept in two halves of its sweep
/// order, [0, m) and [m, n) with m = n/2 ([`Halves`]): a forward sweep
/// visits each half's rows not coupled to the other half, the two halves
/// at once (they share no entry), then the rows that couple across, in
/// order; a backward sweep is its reverse. That is Gauss–Seidel in one
/// order, whichever the number of threads: the same numbers on one.
pub struct SweptLevel(Level);

impl SweptLevel {
    /// Level `l`'s operator `a` (symmetric, stored whole), in the order of
    /// `order`; an error naming the level where a diagonal entry is not
    /// positive.
    pub fn new(l: usize, a: &SparseColMat<usize, f64>, order: SweepOrder) -> Result<Self> {
        let diagonal = positive_diagonal(l, a)?;
        check_entries_fit(l, a.compute_nnz())?;
        let order = sweep_order(order, a.symbolic());
        // Stored in sweep order: the sweeps then read x and A front by
        // front, not scattered over the hierarchy's numbering (twice as
        // fast a V-cycle at 1025²).
        let position = inverse(&order);
        let a = renumbered(a, &position, &position);
        Ok(SweptLevel::in_order(a, &diagonal, order))
    }

    /// Level `l`'s symmetric operator of `n` unknowns given by its lower
    /// triangle: `lower(visit)` calls `visit(i, j, a_ij)` once for each
    /// entry with i ≥ j. As [`SweptLevel::new`], without the operator ever
    /// held whole in its given numbering (at a fine level that copy would
    /// be the largest array of the set-up): its pattern alone gives the
    /// order, then the entries go straight to their places.
    pub fn from_lower(
        l: usize,
        n: usize,
        lower: impl Fn(&mut dyn FnMut(usize, usize, f64)),
        order: SweepOrder,
    ) -> Result<Self> {
        let mut degree = vec![0u32; n];
        let mut diagonal = vec![0.0; n];
        lower(&mut |i, j, v| {
            degree[j] += 1;
            match i == j {
                true => diagonal[j] = v,
                false => degree[i] += 1,
            }
        });
        check_positive(l, &diagonal)?;
        let mut start = vec![0usize; n + 1];
        for j in 0..n {
            start[j + 1] = start[j] + degree[j] as usize;
        }
        check_entries_fit(l, start[n])?;
        let order = match order {
            SweepOrder::Numbered => (0..n).collect(),
            SweepOrder::CuthillMcKee => {
                let mut rows = vec![0u32; start[n]];
                let mut next = start[..n].to_vec();
                lower(&mut |i, j, _| {
                    rows[next[j]] = i as u32;
                    next[j] += 1;
                    if i != j {
                        rows[next[i]] = j as u32;
                        next[i] += 1;
                    }
                });
                drop(next);
                (0..n).for_each(|j| rows[start[j]..start[j + 1]].sort_unstable());
                let col_ptr = start.iter().map(|&p| p as u32).collect();
                let pattern = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, rows);
                sweep_order(order, pattern.as_ref())
            }
        };
        // The columns in sweep order, then each column's entries.
        let position = inverse(&order);
        for (k, &j) in order.iter().enumerate() {
            start[k + 1] = start[k] + degree[j] as usize;
        }
        drop(degree);
        let mut rows = vec![0u32; start[n]];
        let mut values = vec![0.0; start[n]];
        let mut next = start[..n].to_vec();
        let mut place = |column: usize, row: usize, v: f64| {
            rows[next[column]] = row as u32;
            values[next[column]] = v;
            next[column] += 1;
        };
        lower(&mut |i, j, v| {
            let (pi, pj) = (position[i], position[j]);
            place(pj, pi, v);
            if i != j {
                place(pi, pj, v);
            }
        });
        drop(next);
        let mut column: Vec<(u32, f64)> = Vec::new();
        for c in 0..n {
            let range = start[c]..start[c + 1];
            column.clear();
            column.extend(
                rows[range.clone()]
                    .iter()
                    .copied()
                    .zip(&values[range.clone()])
                    .map(|(r, &v)| (r, v)),
            );
            column.sort_unstable_by_key(|e| e.0);
            for (k, (r, v)) in range.zip(&column) {
                (rows[k], values[k]) = (*r, *v);
            }
        }
        let start = start.into_iter().map(|p| p as u32).collect();
        let a = SparseColMat::new(
            SymbolicSparseColMat::new_checked(n, n, start, None, rows),
            values,
        );
        Ok(SweptLevel::in_order(a, &diagonal, order))
    }

    /// The level of `a` (in sweep order) with `diagonal` (in the given
    /// numbering) and `order`.
    fn in_order(a: SparseColMat<u32, f64>, diagonal: &[f64], order: Vec<usize>) -> Self {
        let diagonal = order.iter().map(|&i| diagonal[i]).collect();
        let halves = Halves::of(&a);
        SweptLevel(Level {
            a,
            diagonal,
            order,
            halves,
        })
    }
}

/// An error naming level l when its `nnz` entries do not fit the 32-bit
/// indices of a level.
fn check_entries_fit(l: usize, nnz: usize) -> Result<()> {
    match u32::try_from(nnz) {
        Ok(_) => Ok(()),
        Err(_) => Err(Error::numerical(
            STAGE,
            "size",
            format!("level {l}: {nnz} entries, above the 32-bit indices of a level"),
        )),
    }
}

/// The order `order` of the unknowns of a symmetric pattern (stored whole).
fn sweep_order<I: Index>(order: SweepOrder, pattern: SymbolicSparseColMatRef<'_, I>) -> Vec<usize> {
    match order {
        SweepOrder::Numbered => (0..pattern.nrows()).collect(),
        SweepOrder::CuthillMcKee => cuthill_mckee(pattern),
    }
}

/// A level's two halves of rows, [0, m) and [m, n) in sweep order, for its
/// Gauss–Seidel sweeps ([`SweptLevel`]); m = n below 2¹⁶ unknowns.
struct Halves {
    m: usize,
    /// The rows coupled to the other half, ascending.
    across: Vec<usize>,
    /// Each half's other rows, as ascending runs.
    runs: [Vec<Range<usize>>; 2],
}

impl Halves {
    fn of(a: &SparseColMat<u32, f64>) -> Self {
        let n = a.nrows();
        let m = cut(n);
        let (col_ptr, rows) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        let across: Vec<usize> = (0..n)
            .filter(|&i| {
                let side = i >= m;
                rows[col_ptr[i] as usize..col_ptr[i + 1] as usize]
                    .iter()
                    .any(|&j| (j as usize >= m) != side)
            })
            .collect();
        let runs_between = |half: Range<usize>| {
            let mut runs = Vec::new();
            let mut start = half.start;
            for &i in across.iter().filter(|&&i| half.contains(&i)) {
                if i > start {
                    runs.push(start..i);
                }
                start = i + 1;
            }
            if half.end > start {
                runs.push(start..half.end);
            }
            runs
        };
        let runs = [runs_between(0..m), runs_between(m..n)];
        Halves { m, across, runs }
    }
}

/// One level's operator and its diagonal, numbered in the level's sweep
/// order (Gauss–Seidel visits 0, 1, …, n − 1: the sweep reads x and the
/// matrix in storage order), and `order[k]`, the level's own number of
/// unknown k.
struct Level {
    /// 32-bit indices: a sweep reads 12 bytes per entry, not 16 (the
    /// sweeps and products are bound by memory traffic).
    a: SparseColMat<u32, f64>,
    diagonal: Vec<f64>,
    order: Vec<usize>,
    halves: Halves,
}

/// A multigrid hierarchy of one SPD matrix, set up once, cycled many times.
///
/// # Invariants
/// - `levels[0]` is the coarsest, `levels[last]` the given matrix;
///   `prolongations[l]` maps level l to level l + 1, and its transpose
///   restricts (checked by [`Multigrid::new`]: sizes)
/// - every level, and the prolongations between them, are numbered in the
///   level's sweep order (`Level::order`); only [`Multigrid::cycle`]
///   translates, at the finest level
/// - every level's matrix is symmetric, stored whole, with a positive
///   diagonal (diagonal checked; symmetry not, it is the caller's: a
///   Galerkin product of a symmetric matrix is)
pub struct Multigrid {
    levels: Vec<Level>,
    /// In the levels' sweep numbering.
    prolongations: Vec<SparseColMat<usize, f64>>,
    coarsest: Option<Box<dyn Factors>>,
    options: MultigridOptions,
}

/// What [`Multigrid::solve`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleReport {
    pub cycles: usize,
    /// ‖b − A x‖₂ / ‖b‖₂ before the first cycle and after each.
    pub residuals: Vec<f64>,
    pub converged: bool,
}

impl CycleReport {
    /// The mean contraction per cycle, (r_k / r_0)^(1/k).
    pub fn mean_contraction(&self) -> f64 {
        match self.residuals.as_slice() {
            [first, .., last] if *first > 0.0 => (last / first).powf(1.0 / self.cycles as f64),
            _ => 0.0,
        }
    }
    /// The largest residual ratio of one cycle.
    pub fn max_contraction(&self) -> f64 {
        self.residuals
            .windows(2)
            .filter(|w| w[0] > 0.0)
            .map(|w| w[1] / w[0])
            .fold(0.0, f64::max)
    }
}

impl Multigrid {
    /// The hierarchy of `a` (the finest level) with the Galerkin operators
    /// of `prolongations` (coarsest first: `prolongations[l]` maps level l
    /// to l + 1, the last one into `a`'s unknowns), and the coarsest
    /// operator factorised. Every level is held in its sweep order, `a`'s
    /// too: the caller keeps `a` as given if it needs it.
    pub fn new(
        a: &SparseColMat<usize, f64>,
        prolongations: &[SparseColMat<usize, f64>],
        options: MultigridOptions,
    ) -> Result<Self> {
        if a.nrows() != a.ncols() {
            return Err(Error::numerical(
                STAGE,
                "matrix",
                format!("not square: {} × {}", a.nrows(), a.ncols()),
            ));
        }
        // The coarser operators, finest first (the Galerkin products of the
        // given numbering; each level is then stored in its sweep order).
        let mut operators: Vec<SparseColMat<usize, f64>> = Vec::new();
        for (l, p) in prolongations.iter().enumerate().rev() {
            let fine = operators.last().unwrap_or(a);
            if p.nrows() != fine.nrows() {
                return Err(Error::numerical(
                    STAGE,
                    "prolongation",
                    format!(
                        "prolongation {l} has {} rows, its fine level {} unknowns",
                        p.nrows(),
                        fine.nrows()
                    ),
                ));
            }
            let r = p
                .as_ref()
                .transpose()
                .to_col_major()
                .map_err(|e| Error::numerical(STAGE, "restriction", format!("{e:?}")))?;
            let ap = sparse_sparse_matmul(fine.as_ref(), p.as_ref(), 1.0, Par::Seq)
                .map_err(|e| Error::numerical(STAGE, "A P", format!("{e:?}")))?;
            let coarse = sparse_sparse_matmul(r.as_ref(), ap.as_ref(), 1.0, Par::Seq)
                .map_err(|e| Error::numerical(STAGE, "Pᵀ A P", format!("{e:?}")))?;
            operators.push(coarse);
        }
        operators.reverse();
        let mut levels = operators
            .iter()
            .chain([a])
            .enumerate()
            .map(|(l, a)| SweptLevel::new(l, a, options.order));
        let coarsest = levels.next().expect("the given level")?;
        let mut mg = Multigrid::on_coarsest(coarsest, options)?;
        for (level, p) in levels.zip(prolongations) {
            mg = mg.stacked(level?, p)?;
        }
        Ok(mg)
    }

    /// The hierarchy of one level, its operator factorised.
    pub fn on_coarsest(level: SweptLevel, options: MultigridOptions) -> Result<Self> {
        let coarsest = factor_coarsest(&level.0.a, &options)?;
        Ok(Multigrid {
            levels: vec![level.0],
            prolongations: Vec::new(),
            coarsest,
            options,
        })
    }

    /// This hierarchy with `finest` on top, `p` the prolongation from the
    /// present finest level to it (both levels in their given numbering).
    /// The coarser operators stay as they are: [`Multigrid::new`] makes
    /// them the Galerkin products; a caller stacking its own levels answers
    /// for them being those or near (for nested P1 spaces the Galerkin
    /// product of the finer stiffness is the coarser mesh's own).
    pub fn stacked(mut self, finest: SweptLevel, p: &SparseColMat<usize, f64>) -> Result<Self> {
        let (fine, coarse) = (&finest.0.order, self.finest_order());
        if p.nrows() != fine.len() || p.ncols() != coarse.len() {
            return Err(Error::numerical(
                STAGE,
                "prolongation",
                format!(
                    "prolongation {} is {} × {}, its levels have {} and {} unknowns",
                    self.levels.len() - 1,
                    p.nrows(),
                    p.ncols(),
                    coarse.len(),
                    fine.len()
                ),
            ));
        }
        self.prolongations
            .push(renumbered(p, &inverse(fine), &inverse(coarse)));
        self.levels.push(finest.0);
        Ok(self)
    }

    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    /// Unknowns per level, coarsest first.
    pub fn sizes(&self) -> Vec<usize> {
        self.levels.iter().map(|l| l.a.nrows()).collect()
    }

    /// The operator of level l (0: the coarsest; the last: the given one),
    /// in the level's own numbering.
    pub fn operator(&self, l: usize) -> SparseColMat<usize, f64> {
        let order = &self.levels[l].order;
        renumbered(&self.levels[l].a, order, order)
    }

    /// y = A x with the finest level's operator as stored (the terms of
    /// [`Multigrid::add_to_level`] included), x and y in the given
    /// matrix's numbering.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        let x_swept = self.to_swept(x);
        let mut y_swept = vec![0.0; x.len()];
        product(
            &self.levels[self.levels.len() - 1].a,
            &x_swept,
            &mut y_swept,
            self.options.threads,
        );
        let mut y = vec![0.0; x.len()];
        self.from_swept(&y_swept, &mut y);
        y
    }

    /// v (the given matrix's numbering) in the finest level's sweep order.
    pub fn to_swept(&self, v: &[f64]) -> Vec<f64> {
        self.finest_order().iter().map(|&i| v[i]).collect()
    }

    /// The inverse of [`Multigrid::to_swept`]: `out` in the given numbering.
    pub fn from_swept(&self, v_swept: &[f64], out: &mut [f64]) {
        for (&i, &v) in self.finest_order().iter().zip(v_swept) {
            out[i] = v;
        }
    }

    /// The finest level's sweep order: `order[k]` is the given matrix's
    /// unknown at sweep position k (the numbering of [`Multigrid::add_to_level`],
    /// [`Multigrid::pcg_swept`] and [`Multigrid::prolongation_swept`]).
    pub fn finest_order(&self) -> &[usize] {
        &self.levels[self.levels.len() - 1].order
    }

    /// Prolongation l (level l to l + 1), rows and columns in the levels'
    /// sweep numbering.
    pub fn prolongation_swept(&self, l: usize) -> &SparseColMat<usize, f64> {
        &self.prolongations[l]
    }

    /// Adds v to entry (i, j) of level l's operator, both in the level's
    /// sweep numbering (its diagonal kept in step): the entry's position
    /// among the level's stored entries, or None where (i, j) lies outside
    /// its pattern. Call [`Multigrid::operators_changed`] before the next
    /// cycle.
    pub fn add_to_level(&mut self, l: usize, i: usize, j: usize, v: f64) -> Option<usize> {
        let level = &mut self.levels[l];
        let a = &mut level.a;
        let range = a.symbolic().col_range(j);
        let k = range.start
            + a.symbolic().row_idx()[range]
                .binary_search(&(i as u32))
                .ok()?;
        a.val_mut()[k] += v;
        if i == j {
            level.diagonal[i] += v;
        }
        Some(k)
    }

    /// Level l's stored entries: (row, column) of each position, in the
    /// level's sweep numbering, as `f(position, row, column)`.
    pub fn for_each_entry(&self, l: usize, mut f: impl FnMut(usize, usize, usize)) {
        let a = &self.levels[l].a;
        let (col_ptr, rows) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        for j in 0..a.ncols() {
            for k in col_ptr[j] as usize..col_ptr[j + 1] as usize {
                f(k, rows[k] as usize, j);
            }
        }
    }

    /// The number of stored entries of level l's operator.
    pub fn level_entries(&self, l: usize) -> usize {
        self.levels[l].a.val().len()
    }

    /// After [`Multigrid::add_to_level`]: every level's diagonal checked
    /// positive and the coarsest level factorised anew.
    pub fn operators_changed(&mut self) -> Result<()> {
        for (l, level) in self.levels.iter().enumerate() {
            check_positive(l, &level.diagonal)?;
        }
        self.coarsest = factor_coarsest(&self.levels[0].a, &self.options)?;
        Ok(())
    }

    /// Conjugate gradients on the finest level's operator as stored (the
    /// terms of [`Multigrid::add_to_level`] included), preconditioned by one
    /// V-cycle; b and x in the finest level's sweep numbering.
    pub fn pcg_swept(&self, b: &[f64], x: &mut [f64], rtol: f64, max_iter: usize) -> CgReport {
        let finest = self.levels.len() - 1;
        pcg(
            &self.levels[finest].a,
            b,
            x,
            |r, z| {
                z.fill(0.0);
                self.cycle_at(finest, r, z);
            },
            rtol,
            max_iter,
            self.options.threads,
        )
    }

    /// One V-cycle on A x = b from the given x.
    pub fn cycle(&self, b: &[f64], x: &mut [f64]) {
        let (b_swept, mut x_swept) = (self.to_swept(b), self.to_swept(x));
        self.cycle_at(self.levels.len() - 1, &b_swept, &mut x_swept);
        self.from_swept(&x_swept, x);
    }

    /// z = one V-cycle on A z = r from z = 0: the preconditioner.
    pub fn precondition(&self, r: &[f64], z: &mut [f64]) {
        z.fill(0.0);
        self.cycle(r, z);
    }

    /// V-cycles from x until ‖b − A x‖₂ ≤ `rtol` ‖b‖₂ or `max_cycles`.
    pub fn solve(&self, b: &[f64], x: &mut [f64], rtol: f64, max_cycles: usize) -> CycleReport {
        let finest = self.levels.len() - 1;
        let a = &self.levels[finest].a;
        let (b_swept, mut x_swept) = (self.to_swept(b), self.to_swept(x));
        let norm_b = norm2(b);
        let mut r = vec![0.0; b.len()];
        let mut relative = |x: &[f64]| {
            residual(a, &b_swept, x, &mut r, self.options.threads);
            match norm_b {
                0.0 => norm2(&r),
                _ => norm2(&r) / norm_b,
            }
        };
        let mut residuals = vec![relative(&x_swept)];
        let mut cycles = 0;
        while residuals[cycles] > rtol && cycles < max_cycles {
            self.cycle_at(finest, &b_swept, &mut x_swept);
            cycles += 1;
            residuals.push(relative(&x_swept));
        }
        self.from_swept(&x_swept, x);
        CycleReport {
            converged: residuals[cycles] <= rtol,
            cycles,
            residuals,
        }
    }

    fn cycle_at(&self, l: usize, b: &[f64], x: &mut [f64]) {
        if l == 0 {
            if let Some(f) = &self.coarsest {
                x.copy_from_slice(b);
                f.solve_in_place(x);
            }
            return;
        }
        let level = &self.levels[l];
        let options = &self.options;
        let threads = options.threads;
        for _ in 0..options.pre {
            smooth(level, options.smoother, Sweep::Forward, b, x, threads);
        }
        let mut r = vec![0.0; b.len()];
        residual(&level.a, b, x, &mut r, threads);
        let coarse_b = gather(&self.prolongations[l - 1], &r, threads);
        let mut coarse_x = vec![0.0; coarse_b.len()];
        self.cycle_at(l - 1, &coarse_b, &mut coarse_x);
        scatter_add(&self.prolongations[l - 1], &coarse_x, x);
        for _ in 0..options.post {
            smooth(level, options.smoother, Sweep::Backward, b, x, threads);
        }
    }
}

#[derive(Clone, Copy)]
enum Sweep {
    Forward,
    Backward,
}

fn smooth(
    level: &Level,
    smoother: Smoother,
    sweep: Sweep,
    b: &[f64],
    x: &mut [f64],
    threads: usize,
) {
    let a = &level.a;
    let (col_ptr, rows, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let d = &level.diagonal;
    match smoother {
        Smoother::GaussSeidel => {
            // Row i's update in the part of x that starts at `offset`: a
            // half's rows read their own half only (`Halves`).
            let update = |i: usize, offset: usize, x: &mut [f64]| {
                let mut s = b[i];
                for k in col_ptr[i] as usize..col_ptr[i + 1] as usize {
                    s -= values[k] * x[rows[k] as usize - offset];
                }
                // The loop subtracted a_ii x_i too.
                x[i - offset] += s / d[i];
            };
            let halves = &level.halves;
            let within_halves = |x: &mut [f64]| {
                let sweep_half = |offset: usize, part: &mut [f64]| {
                    // m > 0 whenever there are rows: offset 0 is the first half.
                    let runs = &halves.runs[usize::from(offset > 0)];
                    match sweep {
                        Sweep::Forward => runs
                            .iter()
                            .for_each(|run| run.clone().for_each(|i| update(i, offset, part))),
                        Sweep::Backward => runs.iter().rev().for_each(|run| {
                            run.clone().rev().for_each(|i| update(i, offset, part))
                        }),
                    }
                };
                on_halves(threads, x, halves.m, sweep_half, |_, _| ());
            };
            match sweep {
                Sweep::Forward => {
                    within_halves(x);
                    halves.across.iter().for_each(|&i| update(i, 0, x));
                }
                Sweep::Backward => {
                    halves.across.iter().rev().for_each(|&i| update(i, 0, x));
                    within_halves(x);
                }
            }
        }
        Smoother::SymmetricGaussSeidel => {
            smooth(level, Smoother::GaussSeidel, Sweep::Forward, b, x, threads);
            smooth(level, Smoother::GaussSeidel, Sweep::Backward, b, x, threads);
        }
        Smoother::Jacobi { omega } => {
            let mut r = vec![0.0; b.len()];
            residual(a, b, x, &mut r, threads);
            for i in 0..b.len() {
                x[i] += omega * r[i] / d[i];
            }
        }
    }
}

/// A Cuthill–McKee order of a's graph, every connected component from a
/// vertex of least degree.
fn cuthill_mckee<I: Index>(a: SymbolicSparseColMatRef<'_, I>) -> Vec<usize> {
    let n = a.nrows();
    let degree = |j: usize| a.row_idx_of_col(j).len();
    let mut by_degree: Vec<usize> = (0..n).collect();
    by_degree.sort_by_key(|&j| degree(j));
    let mut seen = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut neighbours = Vec::new();
    for &start in &by_degree {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut head = order.len();
        order.push(start);
        while head < order.len() {
            let j = order[head];
            head += 1;
            neighbours.clear();
            neighbours.extend(a.row_idx_of_col(j).filter(|&i| !seen[i]));
            neighbours.sort_by_key(|&i| degree(i));
            for &i in &neighbours {
                seen[i] = true;
                order.push(i);
            }
        }
    }
    order
}

/// `order`'s inverse: the position of each unknown in the order.
fn inverse(order: &[usize]) -> Vec<usize> {
    let mut position = vec![0; order.len()];
    for (k, &i) in order.iter().enumerate() {
        position[i] = k;
    }
    position
}

/// `m` with entry (i, j) moved to (rows[i], cols[j]): each column moved
/// whole, its rows renumbered and sorted; indices of either width (the
/// caller sees that they fit).
fn renumbered<I: Index, J: Index>(
    m: &SparseColMat<I, f64>,
    rows: &[usize],
    cols: &[usize],
) -> SparseColMat<J, f64> {
    let (col_ptr, row_idx, values) = (m.symbolic().col_ptr(), m.symbolic().row_idx(), m.val());
    let mut start = vec![0usize; m.ncols() + 1];
    for j in 0..m.ncols() {
        start[cols[j] + 1] = col_ptr[j + 1].zx() - col_ptr[j].zx();
    }
    for c in 0..m.ncols() {
        start[c + 1] += start[c];
    }
    let mut new_rows = vec![J::truncate(0); values.len()];
    let mut new_values = vec![0.0; values.len()];
    let mut column: Vec<(usize, f64)> = Vec::new();
    for j in 0..m.ncols() {
        column.clear();
        column.extend(
            (col_ptr[j].zx()..col_ptr[j + 1].zx()).map(|k| (rows[row_idx[k].zx()], values[k])),
        );
        column.sort_unstable_by_key(|e| e.0);
        let at = start[cols[j]];
        for (o, &(r, v)) in column.iter().enumerate() {
            new_rows[at + o] = J::truncate(r);
            new_values[at + o] = v;
        }
    }
    let start = start.into_iter().map(J::truncate).collect();
    let symbolic = SymbolicSparseColMat::new_checked(m.nrows(), m.ncols(), start, None, new_rows);
    SparseColMat::new(symbolic, new_values)
}

/// The diagonal of level l's operator, or an error naming its first entry
/// that is not positive.
fn positive_diagonal<I: Index>(l: usize, a: &SparseColMat<I, f64>) -> Result<Vec<f64>> {
    let diagonal = diagonal(a);
    check_positive(l, &diagonal)?;
    Ok(diagonal)
}

/// An error naming level l's first diagonal entry that is not positive.
fn check_positive(l: usize, diagonal: &[f64]) -> Result<()> {
    match diagonal.iter().position(|&d| d.is_nan() || d <= 0.0) {
        Some(i) => Err(Error::numerical(
            STAGE,
            "diagonal",
            format!("level {l}: A[{i}, {i}] = {} is not positive", diagonal[i]),
        )),
        None => Ok(()),
    }
}

/// The coarsest level's factors through the seam (None for an empty level).
fn factor_coarsest(
    a: &SparseColMat<u32, f64>,
    options: &MultigridOptions,
) -> Result<Option<Box<dyn Factors>>> {
    if a.nrows() == 0 {
        return Ok(None);
    }
    // The seam factorises usize-indexed matrices; the coarsest level is small.
    let identity: Vec<usize> = (0..a.nrows()).collect();
    let a: SparseColMat<usize, f64> = renumbered(a, &identity, &identity);
    let a = &a;
    let pattern = SystemPattern {
        matrix: a,
        kind: MatrixKind::SymmetricPositiveDefinite,
        solves: Solves::Many,
        interior: None,
        what: "multigrid coarsest level",
    };
    Ok(Some(factor_once(pattern, &options.coarse)?))
}

/// The diagonal of a, 0 where it has no diagonal entry.
fn diagonal<I: Index>(a: &SparseColMat<I, f64>) -> Vec<f64> {
    (0..a.ncols())
        .map(|j| {
            a.symbolic()
                .row_idx_of_col(j)
                .zip(a.val_of_col(j))
                .find(|(i, _)| *i == j)
                .map_or(0.0, |(_, v)| *v)
        })
        .collect()
}

/// Mᵀ v (M in compressed columns: one column of M per entry of the
/// result), in halves on `threads`.
fn gather(m: &SparseColMat<usize, f64>, v: &[f64], threads: usize) -> Vec<f64> {
    let (col_ptr, rows, values) = (m.symbolic().col_ptr(), m.symbolic().row_idx(), m.val());
    let mut out = vec![0.0; m.ncols()];
    each_in_halves(threads, &mut out, |j| {
        (col_ptr[j]..col_ptr[j + 1])
            .map(|k| values[k] * v[rows[k]])
            .sum()
    });
    out
}

/// y += M x (M in compressed columns).
fn scatter_add(m: &SparseColMat<usize, f64>, x: &[f64], y: &mut [f64]) {
    let (col_ptr, rows, values) = (m.symbolic().col_ptr(), m.symbolic().row_idx(), m.val());
    for j in 0..m.ncols() {
        let xj = x[j];
        for k in col_ptr[j]..col_ptr[j + 1] {
            y[rows[k]] += values[k] * xj;
        }
    }
}
