//! The measures every solver reports (docs/formulation.md §4), and the per-iteration history.

use super::ContactProblem;
use crate::linalg::{mat_t_vec, mat_vec, over_halves};
use crate::solvers::DualNorm;
use faer::sparse::SparseColMat;
use std::ops::Range;

/// KKT measures of an iterate (x, λ). Absolute values, and the relative
/// ones that the tolerance applies to.
#[derive(Debug, Clone, Copy, Default)]
pub struct KktMeasures {
    /// max_i max(0, −ḡ_i).
    pub penetration: f64,
    /// min_i λ_i (≥ 0 by construction of the projected methods).
    pub dual_min: f64,
    /// max_i |λ_i ḡ_i|.
    pub complementarity: f64,
    /// ‖A x − F − Cᵀλ‖ over the primal rows, relative to max(‖F‖, ‖A x‖, ‖Cᵀλ‖).
    pub stationarity: f64,
    /// ‖(A x − F)‖ over the equality-multiplier rows (‖B U‖), absolute.
    pub tangency: f64,
    /// Number of multipliers with λ_i > 0.
    pub active: usize,
    /// The scale of gaps: max(‖ḡ(0)‖∞ = ‖g_i/w_i‖∞, ‖x_primal‖∞,
    /// max_i |λ_i| S̃_ii), the last the mean gap the contact force λ_i
    /// alone opens ([`jacobi_dual_diagonal`]): a body resting on a zero
    /// obstacle has g = 0 and x = 0, and without it the gaps' round-off
    /// would be measured against x's.
    pub gap_scale: f64,
    /// The largest relative measure: penetration/gap_scale,
    /// max(0, −dual_min)/‖λ‖∞, complementarity/(‖λ‖∞ gap_scale),
    /// stationarity, tangency/(‖F‖ + ‖x‖). This is what `tol` bounds.
    pub kkt: f64,
}

/// Computes the measures of (x, λ) for a problem. `cx` is C x when the
/// caller already has it (Uzawa does: it needs it for the step); A x is
/// computed on `threads`.
pub fn kkt_measures(
    problem: &ContactProblem,
    x: &[f64],
    lambda: &[f64],
    cx: Option<&[f64]>,
    threads: usize,
) -> KktMeasures {
    kkt_measures_with(
        problem,
        x,
        lambda,
        Products {
            cx,
            ..Products::default()
        },
        threads,
    )
}

/// Products of an iterate (x, λ) its solver has at hand, and the
/// problem's compliance S̃: the measures take them instead of computing
/// them again (the same functions, so the same numbers). None: computed
/// here.
#[derive(Debug, Clone, Copy, Default)]
pub struct Products<'a> {
    /// A x.
    pub ax: Option<&'a [f64]>,
    /// C x.
    pub cx: Option<&'a [f64]>,
    /// Cᵀ λ.
    pub ct_lambda: Option<&'a [f64]>,
    /// S̃_ii of [`jacobi_dual_diagonal`], the same for every iterate of a
    /// solve (and not computable while the active set holds A).
    pub compliance: Option<&'a [f64]>,
}

/// [`kkt_measures`] with the products the caller has (those it has not
/// computed on `threads`).
pub fn kkt_measures_with(
    problem: &ContactProblem,
    x: &[f64],
    lambda: &[f64],
    products: Products,
    threads: usize,
) -> KktMeasures {
    let n_primal = problem.n_primal;
    let computed_ax;
    let ax = match products.ax {
        Some(ax) => ax,
        None => {
            computed_ax = problem.product(x, threads);
            &computed_ax
        }
    };
    let mut computed_ct = None;
    let mut computed_cx = None;
    let mut computed_compliance = None;
    let mut row_measures = RowMeasures::default();
    if let Some(c) = &problem.constraint {
        if products.ct_lambda.is_none() {
            computed_ct = Some(mat_t_vec(&c.matrix, lambda));
        }
        let cx: &[f64] = match products.cx {
            Some(cx) => cx,
            None => computed_cx.insert(mat_vec(&c.matrix, x)),
        };
        let compliance: &[f64] = match products.compliance {
            Some(v) => v,
            None => computed_compliance.insert(jacobi_dual_diagonal(problem)),
        };
        // Maxima, minima and counts: the same in any order.
        let rows = |rows: Range<usize>| {
            let mut r = RowMeasures {
                dual_min: f64::INFINITY,
                ..RowMeasures::default()
            };
            for i in rows {
                let (g, w, l) = (c.obstacle[i], c.weights[i], lambda[i]);
                r.obstacle_scale = r.obstacle_scale.max((g / w).abs());
                r.contact_gap = r.contact_gap.max((l * compliance[i]).abs());
                r.lambda_max = r.lambda_max.max(l.abs());
                let gap = c.mean_gap(cx, i);
                r.penetration = r.penetration.max(-gap);
                r.complementarity = r.complementarity.max((l * gap).abs());
                r.dual_min = r.dual_min.min(l);
                r.active += usize::from(l > 0.0);
            }
            r
        };
        row_measures = over_halves(threads, lambda.len(), rows, RowMeasures::and);
    }
    let ct_lambda = products.ct_lambda.or(computed_ct.as_deref());
    // (Cᵀλ)_i, 0 past its rows or without a constraint.
    let ct_at = |i: usize| match ct_lambda {
        Some(ct) if i < ct.len() => ct[i],
        _ => 0.0,
    };
    // The primal rows in one pass, each sum in row order: ‖A x‖², ‖F‖²,
    // ‖Cᵀλ‖², ‖x‖², max |x_i|, and the residual A x − F − Cᵀλ (not stored),
    // whose norm is stationarity.
    let primal = |rows: Range<usize>| {
        let mut p = PrimalMeasures::default();
        for i in rows {
            let (a, f, ct, xi) = (ax[i], problem.rhs[i], ct_at(i), x[i]);
            p.ax2 += a * a;
            p.rhs2 += f * f;
            p.ct2 += ct * ct;
            p.x2 += xi * xi;
            p.x_max = p.x_max.max(xi.abs());
            let r = a - f - ct;
            p.residual2 += r * r;
        }
        p
    };
    let p = over_halves(threads, n_primal, primal, PrimalMeasures::and);
    // The scale of stationarity: the largest of its three terms ‖F‖, ‖A x‖,
    // ‖Cᵀλ‖ (primal rows), so a zero load (the obstacle alone pushes) is
    // not divided by ‖F‖ = 0; equal to ‖F‖ whenever the load dominates.
    let force_scale = p.ax2.sqrt().max(p.rhs2.sqrt()).max(p.ct2.sqrt());
    let mut m = KktMeasures::default();
    let x_scale = p.x_max;
    let f_norm = p.rhs2.sqrt().max(f64::MIN_POSITIVE);
    if problem.constraint.is_some() {
        let r = row_measures;
        m.gap_scale = r
            .obstacle_scale
            .max(x_scale)
            .max(r.contact_gap)
            .max(f64::MIN_POSITIVE);
        let lambda_scale = r.lambda_max.max(f64::MIN_POSITIVE);
        (m.penetration, m.complementarity, m.active) = (r.penetration, r.complementarity, r.active);
        m.dual_min = match lambda.is_empty() {
            true => 0.0,
            false => r.dual_min,
        };
        m.kkt = (m.penetration / m.gap_scale)
            .max((-m.dual_min).max(0.0) / lambda_scale)
            .max(m.complementarity / (lambda_scale * m.gap_scale));
    } else {
        m.gap_scale = x_scale;
    }
    // The equality rows' residual: tangency.
    let tail = n_primal..ax.len().min(problem.rhs.len());
    m.tangency = tail
        .map(|i| (ax[i] - problem.rhs[i] - ct_at(i)).powi(2))
        .sum::<f64>()
        .sqrt();
    m.stationarity = p.residual2.sqrt() / force_scale.max(f64::MIN_POSITIVE);
    let x_norm = (p.x2 + x[n_primal..].iter().map(|v| v * v).sum::<f64>()).sqrt();
    let tangency_rel = m.tangency / (f_norm + x_norm);
    m.kkt = m.kkt.max(m.stationarity).max(tangency_rel);
    m
}

/// The primal rows' part of the measures ([`kkt_measures_with`]) over a
/// range of rows.
#[derive(Default, Clone, Copy)]
struct PrimalMeasures {
    ax2: f64,
    rhs2: f64,
    ct2: f64,
    x2: f64,
    x_max: f64,
    residual2: f64,
}

impl PrimalMeasures {
    /// Two consecutive ranges' parts as one.
    fn and(self, o: Self) -> Self {
        PrimalMeasures {
            ax2: self.ax2 + o.ax2,
            rhs2: self.rhs2 + o.rhs2,
            ct2: self.ct2 + o.ct2,
            x2: self.x2 + o.x2,
            x_max: self.x_max.max(o.x_max),
            residual2: self.residual2 + o.residual2,
        }
    }
}

/// The constraint rows' part of the measures over a range of rows.
#[derive(Default, Clone, Copy)]
struct RowMeasures {
    obstacle_scale: f64,
    contact_gap: f64,
    lambda_max: f64,
    penetration: f64,
    complementarity: f64,
    dual_min: f64,
    active: usize,
}

impl RowMeasures {
    fn and(self, o: Self) -> Self {
        RowMeasures {
            obstacle_scale: self.obstacle_scale.max(o.obstacle_scale),
            contact_gap: self.contact_gap.max(o.contact_gap),
            lambda_max: self.lambda_max.max(o.lambda_max),
            penetration: self.penetration.max(o.penetration),
            complementarity: self.complementarity.max(o.complementarity),
            dual_min: self.dual_min.min(o.dual_min),
            active: self.active + o.active,
        }
    }
}

/// S̃_ii = (1/w_i) Σ_j C_ij² / |A_jj|: the diagonal of the mean-form dual
/// operator W⁻¹ C A⁻¹ Cᵀ with A replaced by its diagonal (0 where C's row
/// meets no nonzero diagonal entry), the mean gap a unit multiplier λ_i
/// opens on its own: the gap scale of the measures and the active set's
/// rule c_i = 1/S̃_ii.
pub fn jacobi_dual_diagonal(problem: &ContactProblem) -> Vec<f64> {
    match problem.constraint.as_ref() {
        Some(c) => jacobi_dual_diagonal_of(&problem.matrix, &c.matrix, &c.weights),
        None => Vec::new(),
    }
}

/// [`jacobi_dual_diagonal`] of A, C and the weights given apart.
pub fn jacobi_dual_diagonal_of(
    a: &SparseColMat<usize, f64>,
    c: &SparseColMat<usize, f64>,
    weights: &[f64],
) -> Vec<f64> {
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
    let mut s = vec![0.0; c.nrows()];
    for j in 0..c.ncols() {
        if diag[j] == 0.0 {
            continue;
        }
        for (i, v) in c.symbolic().row_idx_of_col(j).zip(c.val_of_col(j)) {
            s[i] += v * v / diag[j];
        }
    }
    s.iter_mut().zip(weights).for_each(|(si, w)| *si /= w);
    s
}

/// ‖λ^{k+1} − λ^k‖ in the chosen norm (L²: Σ w_i Δλ_i², the L²(Ω) norm of the
/// multiplier function through its Riesz weights).
pub fn dual_step_norm(new: &[f64], old: &[f64], weights: &[f64], norm: DualNorm) -> f64 {
    match norm {
        DualNorm::Inf => new
            .iter()
            .zip(old)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs())),
        DualNorm::L2 => new
            .iter()
            .zip(old)
            .zip(weights)
            .map(|((a, b), w)| w * (a - b) * (a - b))
            .sum::<f64>()
            .sqrt(),
    }
}

/// Per-iteration measures, as named columns (written to `/solver/history`).
#[derive(Debug, Clone, Default)]
pub struct History {
    pub columns: Vec<(String, Vec<f64>)>,
}

/// The columns every solver's history starts with ([`History::for_solver`]).
pub const KKT_COLUMNS: [&str; 8] = [
    "iteration",
    "dual_step",
    "penetration",
    "dual_min",
    "complementarity",
    "stationarity",
    "tangency",
    "kkt",
];

impl History {
    /// A history with the [`KKT_COLUMNS`] followed by the solver's own.
    pub fn for_solver(extra: &[&str]) -> Self {
        let names: Vec<&str> = KKT_COLUMNS.iter().chain(extra).copied().collect();
        History::with_columns(&names)
    }

    /// Appends one row of a [`History::for_solver`] history: iteration k,
    /// the dual step, the measures, then the solver's own values.
    pub fn push_iteration(&mut self, k: usize, dual_step: f64, m: &KktMeasures, extra: &[f64]) {
        let mut row = vec![
            k as f64,
            dual_step,
            m.penetration,
            m.dual_min,
            m.complementarity,
            m.stationarity,
            m.tangency,
            m.kkt,
        ];
        row.extend_from_slice(extra);
        self.push(&row);
    }

    pub fn with_columns(names: &[&str]) -> Self {
        History {
            columns: names.iter().map(|n| (n.to_string(), Vec::new())).collect(),
        }
    }

    /// Appends one row; `values` in column order.
    pub fn push(&mut self, values: &[f64]) {
        debug_assert_eq!(values.len(), self.columns.len());
        for ((_, col), v) in self.columns.iter_mut().zip(values) {
            col.push(*v);
        }
    }

    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, |(_, c)| c.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.columns
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, c)| c.as_slice())
    }
}
