//! The one failure monitor of the iterative methods: non-finite iterates,
//! divergence (growth of a step), cycles (windows in which neither the step
//! nor the KKT measure decreases), a stalled step and a stagnant KKT
//! measure. Each method feeds it per iteration the measures it watches and
//! keeps its own order of tests (its iterates do not depend on them); the
//! errors name the method (`stage`), the iteration and the measure.

use crate::error::{Error, Result};
use crate::linalg::first_non_finite;

/// An error naming the stage, the quantity and the iteration when `v` holds
/// a non-finite value (divergence, a singular solve).
pub(crate) fn check_finite(stage: &str, iteration: usize, what: &str, v: &[f64]) -> Result<()> {
    match first_non_finite(v) {
        None => Ok(()),
        Some(i) => Err(Error::numerical(
            stage,
            what,
            format!("non-finite value at index {i} in iteration {iteration}"),
        )),
    }
}

/// Steps at or below this fraction of the iterate's size are round-off: a
/// converged iteration stagnating at machine precision must not look like
/// growth, a cycle or a stall.
const ROUND_OFF: f64 = 1e-10;

pub(crate) struct Monitor {
    /// The method, as errors name it.
    stage: &'static str,
    /// The measure a divergence names (e.g. the dual step).
    measure: &'static str,
    /// Smallest step so far, per watched step (λ, ψ, ...).
    min_steps: Vec<f64>,
    /// Window of the cycle test; 0: off.
    cycle_window: usize,
    log_steps: Vec<f64>,
    log_kkt: Vec<f64>,
    /// Steps of the stall test.
    steps: Vec<f64>,
    /// Iterations without a 1% improvement of the best KKT measure that
    /// make a stagnation; 0: off.
    stagnation_window: usize,
    best: f64,
    best_at: usize,
}

impl Monitor {
    pub(crate) fn new(stage: &'static str, measure: &'static str) -> Self {
        Monitor {
            stage,
            measure,
            min_steps: Vec::new(),
            cycle_window: 0,
            log_steps: Vec::new(),
            log_kkt: Vec::new(),
            steps: Vec::new(),
            stagnation_window: 0,
            best: f64::INFINITY,
            best_at: 0,
        }
    }

    /// Turns on the cycle test ([`Monitor::cycles`]) with this window.
    pub(crate) fn with_cycle_window(mut self, window: usize) -> Self {
        self.cycle_window = window;
        self
    }

    /// Turns on the stagnation test ([`Monitor::stagnation`]) with this window.
    pub(crate) fn with_stagnation_window(mut self, window: usize) -> Self {
        self.stagnation_window = window;
        self
    }

    /// [`check_finite`] for this method.
    pub(crate) fn finite(&self, iteration: usize, what: &str, v: &[f64]) -> Result<()> {
        check_finite(self.stage, iteration, what, v)
    }

    /// A reason when watched step number `which` is not finite, or, from
    /// iteration 10 on, is 1e4× its smallest value so far (and above
    /// round-off of `scale`, the iterate's size). A diverging iterate grows
    /// while the relative KKT measure stays O(1), so the step tells.
    pub(crate) fn growth(
        &mut self,
        which: usize,
        k: usize,
        step: f64,
        scale: f64,
    ) -> Option<String> {
        if !step.is_finite() {
            return Some("the step is not finite".into());
        }
        if self.min_steps.len() <= which {
            self.min_steps.resize(which + 1, f64::INFINITY);
        }
        let min_step = &mut self.min_steps[which];
        *min_step = min_step.min(step);
        (k >= 10 && step > ROUND_OFF * scale && step > 1e4 * *min_step)
            .then(|| format!("the step grew from {:.3e} to {step:.3e}", *min_step))
    }

    /// A reason when the KKT measure is not finite.
    pub(crate) fn kkt_not_finite(kkt: f64) -> Option<String> {
        (!kkt.is_finite()).then(|| "the KKT measure is not finite".to_string())
    }

    /// The bounded cycle of a fixed-step projected iteration above its
    /// stability bound, when the projection onto λ ≥ 0 clips the growth:
    /// over two consecutive windows neither the mean log step nor the mean
    /// log KKT measure decreased. Any convergence, however slow, lowers both.
    pub(crate) fn cycles(&mut self, step: f64, scale: f64, kkt: f64) -> Option<String> {
        let window = self.cycle_window;
        if window == 0 {
            return None;
        }
        self.log_steps.push(step.max(f64::MIN_POSITIVE).ln());
        self.log_kkt.push(kkt.max(f64::MIN_POSITIVE).ln());
        let n = self.log_steps.len();
        if n < 2 * window || step <= ROUND_OFF * scale {
            return None;
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let change = |v: &[f64]| mean(&v[n - window..]) - mean(&v[n - 2 * window..n - window]);
        (change(&self.log_steps) > -1e-9 && change(&self.log_kkt) > -1e-9).then(|| {
            format!(
                "the iteration cycles without converging: over the last {} iterations neither the step ({step:.3e}) nor the KKT measure ({kkt:.3e}) decreased",
                2 * window
            )
        })
    }

    /// True every `window` iterations (from 3 windows on) when the largest
    /// step of the last window is not below the largest step of the window
    /// before it, and the step is above round-off of `scale`.
    pub(crate) fn stalled(&mut self, window: usize, k: usize, step: f64, scale: f64) -> bool {
        self.steps.push(step);
        let n = self.steps.len();
        if !k.is_multiple_of(window) || n < 3 * window || step <= ROUND_OFF * scale {
            return false;
        }
        let max = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(*x));
        max(&self.steps[n - window..]) >= max(&self.steps[n - 2 * window..n - window])
    }

    /// An error when the best KKT measure has not improved by 1% over the
    /// stagnation window: the tolerance is below what the solves resolve.
    pub(crate) fn stagnation(&mut self, k: usize, kkt: f64, tol: f64) -> Result<()> {
        if self.stagnation_window == 0 {
            return Ok(());
        }
        if kkt < 0.99 * self.best {
            (self.best, self.best_at) = (kkt, k);
        }
        if k - self.best_at <= self.stagnation_window {
            return Ok(());
        }
        Err(Error::numerical(
            self.stage,
            "KKT measure",
            format!(
                "stagnation at iteration {k}: the best KKT measure {:.3e} (iteration {}) did not improve by 1% over {} iterations (tol {tol:.1e}): the tolerance is below what the solves resolve",
                self.best, self.best_at, self.stagnation_window
            ),
        ))
    }

    /// The divergence error: the iteration, the reason found above, the
    /// KKT measure, and the method's `remedy` (which step is too large).
    pub(crate) fn diverged(&self, k: usize, reason: &str, kkt: f64, remedy: &str) -> Error {
        Error::numerical(
            self.stage,
            self.measure,
            format!("diverged at iteration {k}: {reason} (KKT measure {kkt:.3e}); {remedy}"),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn growth_needs_ten_iterations_and_a_step_above_round_off() {
        let mut m = Monitor::new("test", "step");
        for k in 1..=9 {
            assert_eq!(m.growth(0, k, 10f64.powi(k as i32), 1.0), None, "k = {k}");
        }
        // 1e4 × the smallest step (1e1) and well above round-off of scale 1e6.
        let reason = m.growth(0, 10, 1.5e5, 1e6).expect("growth");
        assert_eq!(reason, "the step grew from 1.000e1 to 1.500e5");
        // Round-off of the iterate's scale: no growth.
        assert_eq!(m.growth(0, 11, 1.5e5, 1e16), None);
        // Each watched step has its own minimum.
        assert_eq!(m.growth(1, 12, 1.5e5, 1.0), None);
        assert_eq!(
            m.growth(1, 13, f64::INFINITY, 1.0).as_deref(),
            Some("the step is not finite")
        );
    }

    #[test]
    fn a_cycle_is_two_windows_without_decrease_and_slow_convergence_is_not() {
        let mut cycling = Monitor::new("test", "step").with_cycle_window(5);
        let reasons: Vec<Option<String>> = (0..10).map(|_| cycling.cycles(1.0, 1.0, 0.5)).collect();
        assert!(reasons[..9].iter().all(Option::is_none));
        assert_eq!(
            reasons[9].as_deref(),
            Some("the iteration cycles without converging: over the last 10 iterations neither the step (1.000e0) nor the KKT measure (5.000e-1) decreased")
        );
        // A step falling by 0.1% per iteration is convergence.
        let mut slow = Monitor::new("test", "step").with_cycle_window(5);
        assert!((0..40).all(|k| {
            let v = 0.999f64.powi(k);
            slow.cycles(v, 1.0, v).is_none()
        }));
        // Off without a window.
        let mut off = Monitor::new("test", "step");
        assert!((0..40).all(|_| off.cycles(1.0, 1.0, 1.0).is_none()));
    }

    #[test]
    fn a_stall_is_judged_once_per_window_from_three_windows_on() {
        let mut m = Monitor::new("test", "step");
        let stalled: Vec<usize> = (1..=12).filter(|&k| m.stalled(3, k, 1.0, 1.0)).collect();
        assert_eq!(stalled, vec![9, 12]);
        let mut falling = Monitor::new("test", "step");
        assert!((1..=12).all(|k| !falling.stalled(3, k, 0.5f64.powi(k as i32), 1.0)));
    }

    #[test]
    fn stagnation_names_the_method_the_iteration_and_the_best_measure() {
        let mut m = Monitor::new("FISTA", "step").with_stagnation_window(3);
        for (k, kkt) in [(1, 1.0), (2, 0.5), (3, 0.499), (4, 0.498), (5, 0.497)] {
            assert!(m.stagnation(k, kkt, 1e-8).is_ok(), "k = {k}");
        }
        let err = m.stagnation(6, 0.496, 1e-8).unwrap_err().to_string();
        assert_eq!(
            err,
            "FISTA: KKT measure: stagnation at iteration 6: the best KKT measure 5.000e-1 (iteration 2) did not improve by 1% over 3 iterations (tol 1.0e-8): the tolerance is below what the solves resolve"
        );
    }

    #[test]
    fn divergence_and_non_finite_errors_name_method_measure_and_iteration() {
        let m = Monitor::new("Uzawa", "dual step ‖λ^k − λ^{k−1}‖");
        assert_eq!(
            m.diverged(12, "the step grew", 2.0, "α = 3 is too large").to_string(),
            "Uzawa: dual step ‖λ^k − λ^{k−1}‖: diverged at iteration 12: the step grew (KKT measure 2.000e0); α = 3 is too large"
        );
        assert_eq!(
            m.finite(4, "multiplier λ", &[0.0, f64::NAN])
                .unwrap_err()
                .to_string(),
            "Uzawa: multiplier λ: non-finite value at index 1 in iteration 4"
        );
        assert!(m.finite(4, "multiplier λ", &[0.0, 1.0]).is_ok());
    }
}
