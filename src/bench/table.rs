//! What a benchmark writes: the Markdown tables (times, memory per phase,
//! the targets), the CSV and the time–level plots.

use super::child::{num, Fields, RSS_PHASES};
use super::{BenchConfig, BenchRow};
use crate::error::Result;
use crate::output::OutputTransaction;
use crate::plot;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub(super) fn write(path: &Path, text: &str) -> Result<()> {
    crate::output::write_text_atomically(path, text)
}

/// Seconds with three significant digits.
fn secs(t: f64) -> String {
    if !t.is_finite() {
        "–".into()
    } else if t >= 100.0 {
        format!("{t:.0}")
    } else if t >= 0.01 {
        format!("{:.*}", (2.0 - t.log10().floor()).max(0.0) as usize, t)
    } else {
        format!("{t:.2e}")
    }
}

fn fmt_time(r: &BenchRow) -> String {
    match r.status.as_str() {
        "converged" => secs(r.seconds),
        "capped" | "killed" | "not run" => format!(">{}", secs(r.seconds)),
        _ => "failed".into(),
    }
}

/// Marks the iterations of a run that ended inside the interior-point start.
const INTERIOR_MARK: &str = "†";

/// The table: one row per (problem, level, method), the tolerances side by side.
pub fn bench_markdown(
    cfg: &BenchConfig,
    rows: &[BenchRow],
    floors: &[(String, String, usize, f64, f64)],
) -> String {
    let mut tols: Vec<f64> = cfg.tolerances.clone();
    tols.sort_by(|a, b| b.total_cmp(a));
    let mut md = format!(
        "## Benchmark `{}`: time to the relative KKT measure (cap {} s per run unless stated)\n\n",
        cfg.name, cfg.cap_seconds
    );
    md.push_str("Times: solver wall time (factorisations + iterations), seconds; `>t`: capped (lower bound); est.: extrapolated from the KKT rate of the capped run. Memory: peak RSS (VmHWM) of the child process of the run. ×floor: time / (one factorisation + one solve without contact).\n\n");
    let mut head = vec!["problem", "level", "dofs", "method"]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
    for t in &tols {
        head.push(format!("it ({t:.0e})"));
        head.push(format!("time ({t:.0e})"));
        head.push(format!("×floor ({t:.0e})"));
        head.push(format!("MB ({t:.0e})"));
    }
    head.push("est. time (loosest)".into());
    let _ = writeln!(md, "| {} |", head.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(head.len()));
    for (prob, level, dofs, floor, mem) in floors {
        let _ = writeln!(
            md,
            "| {prob} | {level} | {dofs} | **linear solve (floor)** | 1 | {} | 1 | {mem:.0} |{}",
            secs(*floor),
            " | | | |".repeat(tols.len() - 1) + " |"
        );
        let methods: Vec<String> = cfg.method.iter().map(|m| m.label.clone()).collect();
        for m in &methods {
            let cells: Vec<&BenchRow> = tols
                .iter()
                .filter_map(|t| {
                    rows.iter().find(|r| {
                        &r.problem == prob && &r.level == level && &r.method == m && r.tol == *t
                    })
                })
                .collect();
            if cells.is_empty() {
                continue;
            }
            let mut line = vec![prob.clone(), level.clone(), dofs.to_string(), m.clone()];
            for r in &cells {
                line.push(r.iterations.map_or("–".into(), |k| {
                    match (r.status == "converged", r.interior) {
                        (true, false) => k.to_string(),
                        (true, true) => format!("{k}{INTERIOR_MARK}"),
                        (false, _) => format!(">{k}"),
                    }
                }));
                line.push(fmt_time(r));
                let ratio = r.seconds / r.floor_seconds;
                line.push(if r.status == "converged" {
                    format!("{ratio:.1}")
                } else if ratio.is_finite() {
                    format!(">{ratio:.0}")
                } else {
                    "–".into()
                });
                line.push(if r.peak_rss_mb.is_finite() {
                    format!("{:.0}", r.peak_rss_mb)
                } else {
                    "–".into()
                });
            }
            line.push(
                cells
                    .first()
                    .and_then(|r| r.estimate_seconds)
                    .map_or("".into(), |e| format!("~{e:.3e}")),
            );
            let _ = writeln!(md, "| {} |", line.join(" | "));
        }
    }
    if rows.iter().any(|r| r.interior) {
        let _ = writeln!(
            md,
            "\n{INTERIOR_MARK}: the run (a re-run with `max_iter` at the step where the tightest run first met this tolerance) ended inside the active set's interior-point start: its iterate meets the tolerance by the KKT measure but is interior (λ > 0 on every constraint), not a complementary pair, whose finish takes the tighter run's PDAS steps (docs/work-precision.md)."
        );
    }
    md.push_str(&targets(cfg, rows));
    md
}

/// Peak RSS of one child at the end of each phase (MB, `RSS_PHASES` order;
/// NaN for a phase the child does not have).
pub struct PhaseRss {
    pub problem: String,
    pub level: String,
    pub method: String,
    pub mb: [f64; RSS_PHASES.len()],
}

impl PhaseRss {
    pub(super) fn new(problem: &str, level: &str, method: &str, f: &Fields) -> Self {
        PhaseRss {
            problem: problem.into(),
            level: level.into(),
            method: method.into(),
            mb: RSS_PHASES.map(|phase| num(f, &format!("rss_kb_{phase}")) / 1024.0),
        }
    }
}

/// The memory table: peak RSS so far at the end of each phase, per child.
pub fn phase_rss_markdown(rows: &[PhaseRss], tightest: f64) -> String {
    let mut md = format!(
        "\n### Peak RSS per phase (MB; VmHWM at the end of each phase, so each column includes the ones before; contact runs at tol {tightest:.0e}, nested levels inside `solve`)\n\n| problem | level | run | {} |\n|---|---|---|{}\n",
        RSS_PHASES.join(" | "),
        "---|".repeat(RSS_PHASES.len())
    );
    for r in rows {
        let cells: Vec<String> =
            r.mb.iter()
                .map(|v| {
                    if v.is_finite() {
                        format!("{v:.0}")
                    } else {
                        "–".into()
                    }
                })
                .collect();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} |",
            r.problem,
            r.level,
            r.method,
            cells.join(" | ")
        );
    }
    md
}

/// The targets, checked on the rows.
pub fn targets(cfg: &BenchConfig, rows: &[BenchRow]) -> String {
    let mut md = String::from("\n### Targets\n\n");
    let tightest = cfg.tolerances.iter().copied().fold(f64::INFINITY, f64::min);
    let as_rows: Vec<&BenchRow> = rows
        .iter()
        .filter(|r| r.method == "active-set" && r.tol == tightest)
        .collect();
    if !as_rows.is_empty() {
        let _ = writeln!(
            md,
            "1. active-set to {tightest:.0e} within 10× the linear solve at every size:"
        );
        let mut all = true;
        for r in &as_rows {
            let ratio = r.seconds / r.floor_seconds;
            let ok = r.status == "converged" && ratio <= 10.0;
            all &= ok;
            let _ = writeln!(
                md,
                "   - {} {}: {}{:.1}× ({} iterations, {} s vs floor {} s, {} of it in factorisations) — {}",
                r.problem,
                r.level,
                if r.status == "converged" { "" } else { ">" },
                ratio,
                r.iterations.map_or("?".into(), |k| k.to_string()),
                secs(r.seconds),
                secs(r.floor_seconds),
                if r.factor_seconds.is_finite() {
                    format!("{:.0}%", 100.0 * r.factor_seconds / r.seconds)
                } else {
                    "–".into()
                },
                if ok { "met" } else { "NOT met" }
            );
        }
        let _ = writeln!(md, "   - overall: {}", if all { "met" } else { "NOT met" });
    }
    let loose = 1e-6;
    {
        let prob = "shell";
        let find = |m: &str| {
            rows.iter()
                .find(|r| r.problem == prob && r.level == "64" && r.method == m && r.tol == loose)
        };
        if let (Some(a), Some(u)) = (find("active-set"), find("uzawa")) {
            let ratio = u.seconds / a.seconds;
            let est = u.estimate_seconds.map(|e| e / a.seconds);
            let _ = writeln!(
                md,
                "2. active-set ≥ 1000× faster than thesis Uzawa (α = 0.01) to 1e-6 at {prob} n = 64: Uzawa {} s, active-set {} s: ratio {}{ratio:.1}{}{} — {}",
                fmt_time(u),
                fmt_time(a),
                if u.status == "converged" { "" } else { "> " },
                if a.status == "converged" { "" } else { " (active-set capped too)" },
                est.map_or(String::new(), |e| format!(" (estimated from the KKT rate: ~{e:.0})")),
                if u.status == "converged" && a.status == "converged" {
                    if ratio >= 1000.0 { "met" } else { "NOT met" }
                } else if ratio >= 1000.0 {
                    "met (lower bound)"
                } else if est.is_some_and(|e| e >= 1000.0) {
                    "met by the estimate only (the lower bound is below 1000)"
                } else {
                    "not shown"
                }
            );
        }
    }
    md
}

pub fn bench_csv(rows: &[BenchRow]) -> String {
    let mut csv = String::from("problem,level,n_dofs,method,tol,status,iterations,seconds,factor_seconds,total_seconds,peak_rss_mb,kkt,floor_seconds,ratio_to_floor,estimate_seconds,note\n");
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},{},{:e},{},{},{:e},{:e},{:e},{:.1},{:e},{:e},{:e},{},{}",
            r.problem,
            r.level,
            r.n_dofs,
            r.method,
            r.tol,
            r.status,
            r.iterations.map_or(String::new(), |k| k.to_string()),
            r.seconds,
            r.factor_seconds,
            r.total_seconds,
            r.peak_rss_mb,
            r.kkt,
            r.floor_seconds,
            r.seconds / r.floor_seconds,
            r.estimate_seconds
                .map_or(String::new(), |e| format!("{e:e}")),
            match r.interior {
                true => format!("interior iterate {}", r.note)
                    .trim_end()
                    .replace(',', ";"),
                false => r.note.replace(',', ";"),
            }
        );
    }
    csv
}

/// Time against the level, log–log, one figure per (problem, tolerance): a
/// curve per method (converged runs only) and the floor.
pub(super) fn bench_plots(
    cfg: &BenchConfig,
    rows: &[BenchRow],
    floors: &[(String, String, usize, f64, f64)],
    outputs: &OutputTransaction,
) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let problems: Vec<String> = cfg.problem.iter().map(|p| p.label.clone()).collect();
    for prob in &problems {
        for &tol in &cfg.tolerances {
            let mut series: Vec<(String, Vec<(f64, f64)>)> = cfg
                .method
                .iter()
                .map(|m| {
                    let pts = rows
                        .iter()
                        .filter(|r| {
                            &r.problem == prob
                                && r.method == m.label
                                && r.tol == tol
                                && r.status == "converged"
                        })
                        .filter_map(|r| r.level.parse::<f64>().ok().map(|n| (n, r.seconds)))
                        .collect();
                    (m.label.clone(), pts)
                })
                .filter(|(_, p): &(String, Vec<(f64, f64)>)| !p.is_empty())
                .collect();
            series.push((
                "linear solve (floor)".into(),
                floors
                    .iter()
                    .filter(|f| &f.0 == prob)
                    .filter_map(|f| f.1.parse::<f64>().ok().map(|n| (n, f.3)))
                    .collect(),
            ));
            let path = outputs
                .folder()
                .join(format!("{}-{prob}-{tol:.0e}.png", cfg.name));
            plot::plot_convergence(
                &outputs.stage(&path)?,
                &series,
                "n (mesh level)",
                "solver wall time [s]",
                &format!("{prob}: time to KKT ≤ {tol:.0e} (converged runs)"),
                &[],
            )?;
            files.push(path);
        }
    }
    Ok(files)
}
