//! Progress of long iterations: on a terminal a live line (iteration, KKT
//! measure, ETA from the measured rate of decrease of the KKT measure); when
//! stderr is a log (not a terminal, or under CI) one plain line every
//! [`LOG_INTERVAL`], so a long run shows it is alive without flooding the
//! log. `--quiet` silences both.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// Whether progress should be drawn at all.
pub fn progress_wanted() -> bool {
    std::io::stderr().is_terminal() && std::env::var_os("CI").is_none()
}

/// The interval between two progress lines in a log.
pub const LOG_INTERVAL: Duration = Duration::from_secs(10);

pub struct IterationProgress {
    bar: Option<ProgressBar>,
    /// The iteration's name, for log lines; `None` when nothing is shown.
    log_name: Option<String>,
    last_log: Instant,
    tol: f64,
    start: Instant,
    last_draw: Instant,
    /// (iteration, kkt) samples to extrapolate the convergence rate.
    window: Vec<(usize, f64)>,
}

impl IterationProgress {
    pub fn new(name: &str, max_iter: usize, tol: f64, show: bool) -> Self {
        let bar = (show && progress_wanted()).then(|| {
            let b = ProgressBar::with_draw_target(
                Some(max_iter as u64),
                ProgressDrawTarget::stderr_with_hz(10),
            );
            b.set_style(
                ProgressStyle::with_template(&format!(
                    "{name} {{elapsed_precise}} it {{pos}}/{{len}} {{msg}}"
                ))
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            b
        });
        let now = Instant::now();
        IterationProgress {
            log_name: (show && bar.is_none()).then(|| name.to_string()),
            last_log: now,
            bar,
            tol,
            start: now,
            last_draw: now,
            window: Vec::new(),
        }
    }

    pub fn update(&mut self, iteration: usize, kkt: f64, dual_step: f64) {
        if let Some(name) = &self.log_name {
            if self.last_log.elapsed() >= LOG_INTERVAL {
                self.last_log = Instant::now();
                eprintln!(
                    "{name}: iteration {iteration}, kkt {kkt:.2e} (tol {:.0e}), Δλ {dual_step:.2e}, {:.0} s elapsed",
                    self.tol,
                    self.start.elapsed().as_secs_f64()
                );
            }
            return;
        }
        let Some(bar) = &self.bar else { return };
        if self.last_draw.elapsed() < Duration::from_millis(100) {
            return;
        }
        self.last_draw = Instant::now();
        self.window.push((iteration, kkt));
        if self.window.len() > 20 {
            self.window.remove(0);
        }
        let eta = self.eta(iteration, kkt);
        bar.set_position(iteration as u64);
        bar.set_message(format!(
            "kkt {kkt:.2e} (tol {:.0e})  Δλ {dual_step:.2e}  ETA {eta}",
            self.tol
        ));
    }

    /// Remaining time from the observed geometric rate of the KKT measure.
    fn eta(&self, iteration: usize, kkt: f64) -> String {
        let (&(k0, r0), per_iter) = match self.window.first() {
            Some(first) if first.0 < iteration => {
                (first, self.start.elapsed().as_secs_f64() / iteration as f64)
            }
            _ => return "?".into(),
        };
        let rate = (kkt / r0).powf(1.0 / (iteration - k0) as f64);
        if rate.is_nan() || rate >= 1.0 || kkt <= self.tol {
            return "?".into();
        }
        let remaining = (self.tol / kkt).ln() / rate.ln();
        format!("{:.0}s", remaining * per_iter)
    }

    pub fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

/// An iteration that ends early (an error) clears its bar too.
impl Drop for IterationProgress {
    fn drop(&mut self) {
        self.finish();
    }
}
