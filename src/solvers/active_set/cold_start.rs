//! The active set's cold starts (module docs of `active_set`): the depth
//! bisection's probes and the interior-point steps before PDAS.

use super::newton::NewtonMatrix;
use super::{count, dot, pdas_rule, IterateProducts, STAGE};
use crate::error::{Error, Result};
use crate::linalg::{mat_t_vec, mat_vec, norm_inf, Changed, LinearSolver};
use crate::solvers::measures::KktMeasures;
use crate::solvers::monitor::check_finite;
use crate::solvers::{ContactProblem, ReportBuilder};
use faer::sparse::SparseColMat;
use std::time::Instant;

/// Whether the interior point's predicted set has settled
/// ([`SETTLED_SET_CHANGE`]): `changes` of it changed in the last step, and
/// `affine_set` is the PDAS rule's set at that step's affine-scaling point.
pub(super) fn settled(predicted: &[bool], changes: usize, affine_set: &[bool]) -> bool {
    let allowed = SETTLED_SET_CHANGE * count(predicted) as f64;
    let off_affine = predicted
        .iter()
        .zip(affine_set)
        .filter(|(p, a)| p != a)
        .count();
    changes as f64 <= allowed || off_affine as f64 <= allowed
}

/// What the depth bisection proposes after a solve.
pub(super) enum Probe {
    /// The next probe.
    Next(Vec<bool>),
    /// The probing is over: plain PDAS continues from this set.
    Finish(Vec<bool>),
}

/// Bisection on nested candidate sets {depth > ℓ} (module docs).
pub(super) struct DepthBisection {
    pub(super) max_probes: usize,
    pub(super) probes: usize,
    /// Layer depth inside the free solution's penetration set; None before
    /// the first (free) solve.
    pub(super) depth: Option<Vec<f64>>,
    /// Bracket: the level of a too-large set, of a too-small one, and the
    /// level probed now.
    pub(super) too_large: f64,
    pub(super) too_small: f64,
    pub(super) level: f64,
    /// The plain PDAS proposal after the least violating solve so far,
    /// with its count of violations (negative λ + penetrations).
    pub(super) best: Option<(usize, Vec<bool>)>,
}

impl DepthBisection {
    pub(super) fn new(max_probes: usize) -> Self {
        DepthBisection {
            max_probes,
            probes: 0,
            depth: None,
            too_large: 0.0,
            too_small: 0.0,
            level: 0.0,
            best: None,
        }
    }

    /// The next set after a solve on `active` that gave (λ, ḡ); `plain` is
    /// the plain PDAS proposal.
    pub(super) fn propose(
        &mut self,
        c: &SparseColMat<usize, f64>,
        active: &[bool],
        lambda: &[f64],
        gaps: &[f64],
        plain: Vec<bool>,
    ) -> Probe {
        let m = active.len();
        let negative = (0..m).filter(|&i| active[i] && lambda[i] < 0.0).count();
        let penetrating = (0..m).filter(|&i| !active[i] && gaps[i] < 0.0).count();
        if self
            .best
            .as_ref()
            .is_none_or(|(v, _)| negative + penetrating < *v)
        {
            self.best = Some((negative + penetrating, plain));
        }
        match &self.depth {
            None => {
                let inside: Vec<bool> = gaps.iter().map(|&g| g < 0.0).collect();
                let depth = layer_depth(&constraint_neighbours(c), &inside);
                self.too_large = 0.0;
                self.too_small = depth.iter().cloned().fold(0.0, f64::max);
                self.depth = Some(depth);
            }
            Some(_) => {
                self.probes += 1;
                if negative > penetrating {
                    self.too_large = self.level;
                } else {
                    self.too_small = self.level;
                }
            }
        }
        let depth = self.depth.as_ref().expect("set above");
        let set_at = |l: f64| -> Vec<bool> { depth.iter().map(|&d| d > l).collect() };
        let level = 0.5 * (self.too_large + self.too_small);
        let next = set_at(level);
        if self.probes >= self.max_probes
            || next == set_at(self.too_large)
            || next == set_at(self.too_small)
        {
            let (_, set) = self.best.take().expect("one solve recorded");
            return Probe::Finish(set);
        }
        self.level = level;
        Probe::Next(next)
    }
}

/// Neighbouring constraints: rows of C that share a column (for P0 contact,
/// triangles sharing a vertex; for P1, vertices within two edges). Columns shared by more than 24 rows are
/// skipped (not a local neighbourhood).
pub(super) fn constraint_neighbours(c: &SparseColMat<usize, f64>) -> Vec<Vec<usize>> {
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); c.nrows()];
    for j in 0..c.ncols() {
        let rows: Vec<usize> = c.symbolic().row_idx_of_col(j).collect();
        if rows.len() > 24 {
            continue;
        }
        for &a in &rows {
            neighbours[a].extend(rows.iter().copied().filter(|&b| b != a));
        }
    }
    for list in neighbours.iter_mut() {
        list.sort_unstable();
        list.dedup();
    }
    neighbours
}

/// Graph distance in layers of each member of `inside` to the nearest
/// non-member (1 for the rim); 0 outside; 1 for all when every constraint
/// is inside.
pub(super) fn layer_depth(neighbours: &[Vec<usize>], inside: &[bool]) -> Vec<f64> {
    let m = inside.len();
    let mut depth = vec![usize::MAX; m];
    let mut queue = std::collections::VecDeque::new();
    for i in (0..m).filter(|&i| !inside[i]) {
        depth[i] = 0;
        queue.push_back(i);
    }
    while let Some(i) = queue.pop_front() {
        for &j in &neighbours[i] {
            if depth[j] == usize::MAX {
                depth[j] = depth[i] + 1;
                queue.push_back(j);
            }
        }
    }
    depth
        .into_iter()
        .map(|d| if d == usize::MAX { 1.0 } else { d as f64 })
        .collect()
}

/// The interior-point start (module docs): Mehrotra predictor–corrector
/// steps on the Newton matrix with every constraint on.
pub(super) struct InteriorPoint<'a> {
    pub(super) problem: &'a ContactProblem,
    /// c_i of the PDAS rule, for the predicted set.
    pub(super) c_rule: &'a [f64],
    pub(super) handover: f64,
    pub(super) max_steps: usize,
}

/// Where the interior-point start hands over to PDAS.
pub(super) struct Handover {
    pub(super) x: Vec<f64>,
    pub(super) lambda: Vec<f64>,
    /// The PDAS rule's set at (x, λ).
    pub(super) predicted: Vec<bool>,
    /// Newton solves done, the free one included (history rows 1..=steps).
    pub(super) steps: usize,
    pub(super) max_linear_residual: f64,
}

/// The fraction of the step to the boundary of (λ, t) > 0 taken. Measured
/// on the thesis shell (tol 1e-10, 1e-8 at n = 256), Newton solves at
/// n = 16, 32, 64, 128, 256: 0.99 gave 8, 13, 14, 16, 17; 0.95 gives 9,
/// 11, 13, 15, 16 (0.93 and 0.97 within one of these at n ≤ 128): the
/// iterates stay nearer the central path, fewer steps are blocked.
const STEP_TO_BOUNDARY: f64 = 0.95;
/// Near the solution (relative KKT measure below `LATE_BELOW`) the steps
/// go nearer the boundary, as the fraction → 1 of the convergence theory:
/// Newton solves at n = 16, 32, 64, 128, 256 are 8, 11, 13, 14, 16, against
/// 9, 11, 13, 15, 16 with the one fraction throughout (0.99 alike; from
/// KKT 1e-3 on alike).
const LATE_STEP_TO_BOUNDARY: f64 = 0.995;
const LATE_BELOW: f64 = 1e-4;
/// The handover waits for the predicted set to settle ([`settled`]): at
/// most this fraction of it changed in the last step, or differs from the
/// PDAS rule's set at the step's affine-scaling point. The KKT bound alone
/// handed over too early at n = 512 (a predicted set of 11,282 triangles
/// for a zone of 133,056: 7 PDAS steps, 18 solves). The last step's change
/// alone waits one interior-point step more where the set jumps to the
/// zone in one step (n = 128: 550 → 6884 for 6806) that the affine point
/// already predicted (30 of the 6884 differ). With the affine test, n =
/// 128 and 256 keep their 14 and 16 Newton solves with one factorisation
/// fewer (one more PDAS step, switched), n = 512 takes 15 against 16
/// (docs/work-precision.md, "Hand over when the affine-scaling point
/// agrees").
const SETTLED_SET_CHANGE: f64 = 0.05;
/// The centring offset of the start, relative to the largest penetration
/// (0.05 … 3 measured: the same Newton solves to ±1).
const START_OFFSET: f64 = 0.5;

impl InteriorPoint<'_> {
    pub(super) fn run(
        &self,
        newton: &mut NewtonMatrix,
        factorizer: &mut dyn LinearSolver,
        report: &mut ReportBuilder,
    ) -> Result<Handover> {
        let problem = self.problem;
        let c = problem.constraint.as_ref().expect("a constrained problem");
        let (n, m) = (problem.n(), c.obstacle.len());
        // The free solve, and its factorisation for the multiplier scale κ.
        newton.set_active(&vec![false; m]);
        let mut rhs = vec![0.0; n + m];
        rhs[..n].copy_from_slice(&problem.rhs);
        let t = Instant::now();
        let (free, z, mut max_residual) =
            factorizer.factor_and_solve_shared(&newton.matrix, &rhs, Changed::Declared)?;
        report.factor_seconds += t.elapsed().as_secs_f64();
        check_finite(STAGE, 1, "free solve", &z)?;
        let mut x = z[..n].to_vec();
        let mut lambda = vec![0.0; m];
        let mut products = IterateProducts::of(newton, problem, &x, &lambda);
        let mut predicted = pdas_rule(c, self.c_rule, &products.cx, &lambda);
        self.record(
            report,
            (1, 0.0),
            products.measures(newton, problem, &x, &lambda),
            &predicted,
            &vec![false; m],
            max_residual,
        );
        if report.measures.kkt <= self.handover {
            return Ok(Handover {
                x,
                lambda,
                predicted,
                steps: 1,
                max_linear_residual: max_residual,
            });
        }
        let gap: Vec<f64> = (0..m).map(|i| products.cx[i] - c.obstacle[i]).collect();
        let penetration: Vec<f64> = gap.iter().map(|&g| (-g).max(0.0)).collect();
        let p_max = norm_inf(&penetration);
        if p_max == 0.0 {
            // Nothing penetrates: no multiplier scale to start from; PDAS
            // continues from the free solution's set.
            return Ok(Handover {
                x,
                lambda,
                predicted,
                steps: 1,
                max_linear_residual: max_residual,
            });
        }
        let mut y = vec![0.0; n + m];
        y[..n].copy_from_slice(&mat_t_vec(&c.matrix, &penetration));
        free.solve_in_place(&mut y);
        drop(free);
        let dual_p = dot(&penetration, &mat_vec(&c.matrix, &y[..n]));
        let kappa = dot(&penetration, &penetration) / dual_p;
        if !(kappa.is_finite() && kappa > 0.0) {
            return Err(Error::numerical(
                STAGE,
                "interior-point start",
                format!("the multiplier scale κ = pᵀp / pᵀ C A⁻¹ Cᵀ p is {kappa:.3e} (pᵀ C A⁻¹ Cᵀ p = {dual_p:.3e}): A is not positive on the penetration"),
            ));
        }
        let (eps_lambda, eps_gap) = (START_OFFSET * kappa * p_max, START_OFFSET * p_max);
        let mu0 = eps_lambda * eps_gap;
        lambda = gap
            .iter()
            .map(|&g| match g < 0.0 {
                true => -kappa * g + eps_lambda,
                false => mu0 / (g + eps_gap),
            })
            .collect();
        let mut slack: Vec<f64> = lambda.iter().map(|l| mu0 / l).collect();
        products.ct_lambda = mat_t_vec(&c.matrix, &lambda);
        let mut k = 1;
        while k <= self.max_steps {
            k += 1;
            // Residuals: r_d = F + Cᵀλ − A x, r_p = C x − g − t (t: slack).
            let IterateProducts { ax, cx, ct_lambda } = &products;
            let r_d: Vec<f64> = (0..n)
                .map(|j| problem.rhs[j] + ct_lambda[j] - ax[j])
                .collect();
            let r_p: Vec<f64> = (0..m).map(|i| cx[i] - c.obstacle[i] - slack[i]).collect();
            let mu = dot(&slack, &lambda) / m as f64;
            let delta: Vec<f64> = (0..m)
                .map(|i| newton.scale[i].powi(2) * slack[i] / lambda[i])
                .collect();
            newton.set_barrier(&delta);
            let s = &newton.scale;
            // Row n + i: s_i (C dx)_i − Δ_i dμ_i = s_i (r_c,i/λ_i − r_p,i),
            // dλ = −S dμ, dt = C dx + r_p; r_c the complementarity target.
            let rhs_of = |r_c: &dyn Fn(usize) -> f64, rhs: &mut [f64]| {
                rhs[..n].copy_from_slice(&r_d);
                for i in 0..m {
                    rhs[n + i] = s[i] * (r_c(i) / lambda[i] - r_p[i]);
                }
            };
            let direction = |z: &[f64]| -> (Vec<f64>, Vec<f64>) {
                let dl: Vec<f64> = (0..m).map(|i| -s[i] * z[n + i]).collect();
                let cdx = mat_vec(&c.matrix, &z[..n]);
                (dl, (0..m).map(|i| cdx[i] + r_p[i]).collect())
            };
            // Predictor (affine scaling): r_c = −λ∘t.
            rhs_of(&|i| -slack[i] * lambda[i], &mut rhs);
            let t = Instant::now();
            let (f, z, residual) =
                factorizer.factor_and_solve_shared(&newton.matrix, &rhs, Changed::Declared)?;
            report.factor_seconds += t.elapsed().as_secs_f64();
            max_residual = max_residual.max(residual);
            check_finite(STAGE, k, "interior-point predictor", &z)?;
            let (dl_aff, dt_aff) = direction(&z);
            // The PDAS rule's set at the affine-scaling point (x + dx_aff,
            // λ + dλ_aff), a second prediction for the settle test:
            // C(x + dx_aff) = C x + dt_aff − r_p.
            let affine_set = {
                let cx_aff: Vec<f64> = (0..m)
                    .map(|i| products.cx[i] + dt_aff[i] - r_p[i])
                    .collect();
                let lambda_aff: Vec<f64> = (0..m).map(|i| lambda[i] + dl_aff[i]).collect();
                pdas_rule(c, self.c_rule, &cx_aff, &lambda_aff)
            };
            let a_aff = step_to_boundary(&slack, &dt_aff).min(step_to_boundary(&lambda, &dl_aff));
            let mu_aff = (0..m)
                .map(|i| (slack[i] + a_aff * dt_aff[i]) * (lambda[i] + a_aff * dl_aff[i]))
                .sum::<f64>()
                / m as f64;
            let sigma = (mu_aff / mu).powi(3).min(1.0);
            // Corrector: r_c = σμ − λ∘t − dλ_aff∘dt_aff, the same factorisation.
            rhs_of(
                &|i| sigma * mu - slack[i] * lambda[i] - dl_aff[i] * dt_aff[i],
                &mut rhs,
            );
            let mut z = rhs.clone();
            f.solve_unrefined_in_place(&mut z);
            drop(f);
            check_finite(STAGE, k, "interior-point corrector", &z)?;
            let (dl, dt) = direction(&z);
            let fraction = match report.measures.kkt < LATE_BELOW {
                true => LATE_STEP_TO_BOUNDARY,
                false => STEP_TO_BOUNDARY,
            };
            let alpha = (fraction
                * step_to_boundary(&slack, &dt).min(step_to_boundary(&lambda, &dl)))
            .min(1.0);
            x.iter_mut().zip(&z[..n]).for_each(|(v, d)| *v += alpha * d);
            lambda
                .iter_mut()
                .zip(&dl)
                .for_each(|(v, d)| *v += alpha * d);
            slack.iter_mut().zip(&dt).for_each(|(v, d)| *v += alpha * d);
            products = IterateProducts::of(newton, problem, &x, &lambda);
            let next = pdas_rule(c, self.c_rule, &products.cx, &lambda);
            let before = std::mem::replace(&mut predicted, next);
            let changes = self.record(
                report,
                (k, alpha * norm_inf(&dl)),
                products.measures(newton, problem, &x, &lambda),
                &predicted,
                &before,
                residual,
            );
            if report.measures.kkt <= self.handover && settled(&predicted, changes, &affine_set) {
                break;
            }
        }
        Ok(Handover {
            x,
            lambda,
            predicted,
            steps: k,
            max_linear_residual: max_residual,
        })
    }

    /// History row k of an interior-point step (`step` = (k, its dual
    /// step)): `active` is the predicted set, `changes` against the
    /// previous step's, which it returns.
    pub(super) fn record(
        &self,
        report: &mut ReportBuilder,
        (k, dual_step): (usize, f64),
        measures: KktMeasures,
        predicted: &[bool],
        before: &[bool],
        linear_residual: f64,
    ) -> usize {
        let added = (0..predicted.len())
            .filter(|&i| predicted[i] && !before[i])
            .count();
        let removed = (0..predicted.len())
            .filter(|&i| !predicted[i] && before[i])
            .count();
        report.record(
            k,
            dual_step,
            measures,
            &[
                count(predicted) as f64,
                (added + removed) as f64,
                added as f64,
                removed as f64,
                linear_residual,
            ],
        );
        added + removed
    }
}

/// The largest α ≤ 1 with v + α dv ≥ 0 (v > 0).
pub(super) fn step_to_boundary(v: &[f64], dv: &[f64]) -> f64 {
    v.iter()
        .zip(dv)
        .filter(|(_, &d)| d < 0.0)
        .fold(1.0f64, |a, (&vi, &d)| a.min(-vi / d))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A set of `size` triangles in contact among 1000, from index `from`.
    fn set(from: usize, size: usize) -> Vec<bool> {
        (0..1000)
            .map(|i| (from..from + size).contains(&i))
            .collect()
    }

    /// The settle test hands over once either prediction agrees: a set
    /// that jumped to the zone in one step (n = 128: 550 → 6884) and that
    /// the affine-scaling point predicts too (30 of 6884 off); not one
    /// that the affine point contradicts (n = 512: 11,282 with 116,762
    /// off), nor a set that is still moving.
    #[test]
    fn the_set_settles_when_either_prediction_agrees() {
        let jumped = set(0, 400);
        // 370 changed in the last step (92 %), 10 differ from the affine
        // point's set (2.5 %): settled.
        assert!(settled(&jumped, 370, &set(5, 400)));
        // The same jump, and the affine point predicts 900 triangles.
        assert!(!settled(&jumped, 370, &set(0, 900)));
        // 20 changed (5 %): settled whatever the affine point says.
        assert!(settled(&jumped, 20, &set(0, 900)));
        assert!(!settled(&jumped, 21, &set(0, 900)));
        // Exactly at the bound on the affine side: 20 differ.
        assert!(settled(&jumped, 370, &set(0, 420)));
        assert!(!settled(&jumped, 370, &set(0, 421)));
        // An empty set that did not change is settled, as before.
        assert!(settled(&set(0, 0), 0, &set(0, 5)));
    }
}
