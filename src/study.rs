//! Studies: a scene run over a grid of overrides, one table row per run,
//! with convergence rates fitted between successive mesh levels.
//!
//! A study file (TOML, in `pipelines/studies/`):
//!
//! ```toml
//! name = "membrane-thesis"
//! scene = "../scenes/obstacle-disk.toml"      # relative to the study file
//! set = ["solver.stop=thesis"]                # overrides for every run
//! [[sweep]]                                   # outer to inner loops
//! key = "element"
//! values = ["p1b-p0", "p2-p1"]
//! [[sweep]]
//! key = "mesh.h"                              # the innermost sweep is the mesh level
//! values = [0.8, 0.4, 0.2, 0.1]
//! ```

use crate::error::{Error, Result};
use crate::models::membrane::ExactErrors;
use crate::pipeline::{run_scene, RunSummary};
use crate::plot;
use crate::scene::Scene;
use serde::Deserialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Study {
    pub name: String,
    pub title: Option<String>,
    pub scene: String,
    #[serde(default)]
    pub set: Vec<String>,
    pub sweep: Vec<Sweep>,
    /// Draw errors against h (log–log), one figure per group of the outer sweeps.
    #[serde(default)]
    pub convergence_plot: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sweep {
    pub key: String,
    pub values: Vec<toml::Value>,
}

/// One run of a study: its overrides (beyond `set`) and what it reported.
pub struct StudyRow {
    pub labels: Vec<(String, String)>,
    pub summary: RunSummary,
}

impl Study {
    pub fn load(path: &Path) -> Result<Study> {
        let err = |field: &str, reason: String| Error::Scene {
            file: path.to_path_buf(),
            field: field.into(),
            reason,
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| err("(file)", format!("cannot read: {e}")))?;
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| err("(syntax)", e.to_string().replace('\n', " ")))?;
        let study: Study = serde_path_to_error::deserialize(toml::Value::Table(table))
            .map_err(|e| err(&e.path().to_string(), e.into_inner().to_string()))?;
        if study.sweep.iter().any(|s| s.values.is_empty()) {
            return Err(err(
                "sweep.values",
                "every sweep needs at least one value".into(),
            ));
        }
        Ok(study)
    }

    /// The override lists of all runs, outer sweeps first.
    pub fn runs(&self) -> Vec<Vec<(String, String)>> {
        let mut runs: Vec<Vec<(String, String)>> = vec![vec![]];
        for sweep in &self.sweep {
            runs = runs
                .into_iter()
                .flat_map(|prefix| {
                    sweep.values.iter().map(move |v| {
                        let mut r = prefix.clone();
                        r.push((sweep.key.clone(), v.to_string()));
                        r
                    })
                })
                .collect();
        }
        runs
    }
}

/// Runs every combination, writing results under `out_dir`.
pub fn run_study(study_path: &Path, out_dir: &Path, show_progress: bool) -> Result<Vec<StudyRow>> {
    let study = Study::load(study_path)?;
    let scene_path = study_path
        .parent()
        .unwrap_or(Path::new("."))
        .join(&study.scene);
    let mut rows = Vec::new();
    for (i, labels) in study.runs().into_iter().enumerate() {
        let mut overrides = study.set.clone();
        overrides.extend(labels.iter().map(|(k, v)| format!("{k}={v}")));
        let scene = Scene::load(&scene_path, &overrides)?;
        let out: PathBuf = out_dir.join(format!("{}-{:03}.h5", study.name, i));
        let summary = run_scene(&scene, &out, show_progress)?;
        if show_progress {
            eprintln!(
                "[{}] {} → {} iterations, kkt {:.2e}, {:.2}s",
                i,
                overrides.join(" "),
                summary.iterations,
                summary.measures.kkt,
                summary.wall_seconds
            );
        }
        rows.push(StudyRow { labels, summary });
    }
    Ok(rows)
}

/// Observed rate log(e_{k−1}/e_k)/log(h_{k−1}/h_k) between successive levels
/// of the innermost sweep (None at the first level of each group).
pub fn rates(rows: &[StudyRow], error: impl Fn(&RunSummary) -> Option<f64>) -> Vec<Option<f64>> {
    let mut out = vec![None; rows.len()];
    for i in 1..rows.len() {
        let (a, b) = (&rows[i - 1], &rows[i]);
        let same_group = a.labels.len() == b.labels.len()
            && a.labels[..a.labels.len().saturating_sub(1)]
                == b.labels[..b.labels.len().saturating_sub(1)];
        if !same_group {
            continue;
        }
        if let (Some(ea), Some(eb)) = (error(&a.summary), error(&b.summary)) {
            if ea > 0.0 && eb > 0.0 && a.summary.h != b.summary.h {
                out[i] = Some((ea / eb).ln() / (a.summary.h / b.summary.h).ln());
            }
        }
    }
    out
}

const COLUMNS: [&str; 20] = [
    "h",
    "#tri",
    "#dofs",
    "alpha",
    "iter",
    "stop",
    "‖Δλ‖",
    "penetration",
    "complementarity",
    "stationarity",
    "KKT",
    "L² err",
    "rate",
    "H¹ err",
    "rate",
    "a_h",
    "|a_h−a|",
    "λ L² err",
    "2/s_max",
    "time [s]",
];

fn opt(v: Option<f64>, precision: usize) -> String {
    v.map_or("–".into(), |x| format!("{x:.precision$e}"))
}

/// The study as a Markdown table (one table per value of the outer sweeps).
pub fn markdown_table(title: &str, rows: &[StudyRow]) -> String {
    let l2_rates = rates(rows, |s| s.errors.map(|e| e.l2));
    let h1_rates = rates(rows, |s| s.errors.map(|e| e.h1));
    let mut md = format!("## {title}\n");
    let mut group: Option<Vec<(String, String)>> = None;
    for (i, row) in rows.iter().enumerate() {
        let outer: Vec<_> = row.labels[..row.labels.len().saturating_sub(1)].to_vec();
        if group.as_ref() != Some(&outer) {
            let heading: Vec<String> = outer.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            let _ = writeln!(
                md,
                "\n### {}\n",
                if heading.is_empty() {
                    "all runs".into()
                } else {
                    heading.join(", ")
                }
            );
            let _ = writeln!(md, "| {} |", COLUMNS.join(" | "));
            let _ = writeln!(md, "|{}", "---|".repeat(COLUMNS.len()));
            group = Some(outer);
        }
        let s = &row.summary;
        let m = &s.measures;
        let e = s.errors;
        let cells = [
            format!("{:.4}", s.h),
            s.n_triangles.to_string(),
            s.n_dofs.to_string(),
            s.alpha.map_or("–".into(), |a| format!("{a:.4}")),
            s.iterations.to_string(),
            s.stop_reason.clone(),
            format!("{:.3e}", s.last_dual_step),
            format!("{:.2e}", m.penetration),
            format!("{:.2e}", m.complementarity),
            format!("{:.2e}", m.stationarity),
            format!("{:.2e}", m.kkt),
            opt(e.map(|e| e.l2), 3),
            l2_rates[i].map_or("–".into(), |r| format!("{r:.2}")),
            opt(e.map(|e| e.h1), 3),
            h1_rates[i].map_or("–".into(), |r| format!("{r:.2}")),
            e.map_or("–".into(), |e| format!("{:.4}", e.contact_radius)),
            opt(
                e.map(|e| (e.contact_radius - e.exact_contact_radius).abs()),
                2,
            ),
            opt(e.map(|e| e.lambda_l2), 2),
            s.spectrum
                .map_or("–".into(), |sp| format!("{:.3}", 2.0 / sp.s_max)),
            format!("{:.3}", s.wall_seconds),
        ];
        let _ = writeln!(md, "| {} |", cells.join(" | "));
    }
    md
}

/// The study as CSV (one line per run, labels first).
pub fn csv_table(rows: &[StudyRow]) -> String {
    let mut csv = String::new();
    if let Some(first) = rows.first() {
        let labels: Vec<&str> = first.labels.iter().map(|(k, _)| k.as_str()).collect();
        let _ = writeln!(
            csv,
            "{},h,n_triangles,n_dofs,alpha,iterations,converged,stop_reason,dual_step,penetration,complementarity,stationarity,kkt,error_l2,error_h1,contact_radius,exact_contact_radius,error_l2_lambda,s_max,wall_seconds,result_file",
            labels.join(",")
        );
    }
    for row in rows {
        let s = &row.summary;
        let m = &s.measures;
        let e = s.errors;
        let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:e}"));
        let labels: Vec<String> = row
            .labels
            .iter()
            .map(|(_, v)| v.replace(',', ";"))
            .collect();
        let _ = writeln!(
            csv,
            "{},{:e},{},{},{},{},{},{},{:e},{:e},{:e},{:e},{:e},{},{},{},{},{},{},{:e},{}",
            labels.join(","),
            s.h,
            s.n_triangles,
            s.n_dofs,
            f(s.alpha),
            s.iterations,
            s.converged,
            s.stop_reason,
            s.last_dual_step,
            m.penetration,
            m.complementarity,
            m.stationarity,
            m.kkt,
            f(e.map(|e| e.l2)),
            f(e.map(|e| e.h1)),
            f(e.map(|e| e.contact_radius)),
            f(e.map(|e| e.exact_contact_radius)),
            f(e.map(|e| e.lambda_l2)),
            f(s.spectrum.map(|sp| sp.s_max)),
            s.wall_seconds,
            s.result_file.display()
        );
    }
    csv
}

/// Log–log plots of the exact-solution errors against h, one per group of the
/// outer sweeps (`<out_dir>/<study>-convergence-<k>.png`). Returns the files.
pub fn write_convergence_plots(
    study: &Study,
    rows: &[StudyRow],
    out_dir: &Path,
) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let mut start = 0;
    while start < rows.len() {
        let outer = |r: &StudyRow| r.labels[..r.labels.len().saturating_sub(1)].to_vec();
        let group = outer(&rows[start]);
        let end = start
            + rows[start..]
                .iter()
                .take_while(|r| outer(r) == group)
                .count();
        let points = |f: &dyn Fn(&ExactErrors) -> f64| -> Vec<(f64, f64)> {
            rows[start..end]
                .iter()
                .filter_map(|r| r.summary.errors.as_ref().map(|e| (r.summary.h, f(e))))
                .collect()
        };
        let series = vec![
            ("L² error of u".to_string(), points(&|e| e.l2)),
            ("H¹ error of u".to_string(), points(&|e| e.h1)),
            (
                "|a_h − a| contact radius".to_string(),
                points(&|e| (e.contact_radius - e.exact_contact_radius).abs()),
            ),
            ("L² error of λ".to_string(), points(&|e| e.lambda_l2)),
        ];
        if series[0].1.len() >= 2 {
            let label: Vec<String> = group.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            let path = out_dir.join(format!("{}-convergence-{}.png", study.name, files.len()));
            plot::plot_convergence(
                &path,
                &series,
                "h",
                "error",
                &format!("{} {}", study.name, label.join(", ")),
                &[1.0, 2.0],
            )?;
            files.push(path);
        }
        start = end;
    }
    Ok(files)
}
