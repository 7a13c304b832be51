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
//!
//! Optional: `with = { KEY = [...] }` in a sweep (keys set together with its
//! key), `[reference]` (errors against the finest run), `[work_precision]`
//! (errors of root attributes against given values, plotted against time).

use crate::error::{Error, Result};
use crate::models::ExactErrors;
use crate::output::marker::FailureMarker;
use crate::output::{read_result, OutputTransaction};
use crate::pipeline::RunSummary;
use crate::plot;
use crate::run::run_scene;
use crate::scene::{read_toml_file, Scene};
use crate::transfer::relative_errors;
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
    /// Table columns (default [`DEFAULT_COLUMNS`]); see `column_value`.
    pub columns: Option<Vec<String>>,
    /// Per run, a table of history values at given iterations (thesis Table 5.5).
    pub history: Option<HistoryTableSpec>,
    /// Errors of each run against the last (finest) run of its group (thesis Fig. 5.10).
    pub reference: Option<ReferenceSpec>,
    /// Relative errors of root attributes against given reference values,
    /// plotted against wall time, one curve per group of the outer sweeps.
    pub work_precision: Option<WorkPrecisionSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkPrecisionSpec {
    /// Root attribute → its reference value, e.g. { u3_min = -1.217 }.
    pub reference: std::collections::BTreeMap<String, f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistoryTableSpec {
    pub iterations: Vec<usize>,
    pub columns: Vec<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSpec {
    /// Coefficient vectors (`/dofs/<name>`) compared, e.g. ["u", "r", "psi", "lambda"].
    pub fields: Vec<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sweep {
    pub key: String,
    pub values: Vec<toml::Value>,
    /// Keys set together with `key`, one value per value of `key` (e.g. the
    /// load scaled with the thickness): `with = { "load.f" = [...] }`.
    #[serde(default)]
    pub with: std::collections::BTreeMap<String, Vec<toml::Value>>,
}

/// One run of a study: its overrides (beyond `set`) and what it reported.
pub struct StudyRow {
    pub labels: Vec<(String, String)>,
    pub summary: RunSummary,
    /// A run that failed numerically (divergence, singular matrix, ...) is a
    /// result of the study, not the end of it: its message is kept here and
    /// its row shows "failed".
    pub failure: Option<String>,
}

impl Study {
    pub fn load(path: &Path) -> Result<Study> {
        let err = |field: &str, reason: String| Error::Scene {
            file: path.to_path_buf(),
            field: field.into(),
            reason,
        };
        let study: Study = read_toml_file(path)?;
        crate::names::check_name(&study.name).map_err(|reason| err("name", reason))?;
        if let Some(w) = &study.work_precision {
            for name in w.reference.keys() {
                // Each names a plot file.
                crate::names::check_name(name).map_err(|reason| {
                    err("work_precision.reference", format!("`{name}` {reason}"))
                })?;
            }
        }
        let mut swept: Vec<&str> = Vec::new();
        for key in study
            .sweep
            .iter()
            .flat_map(|s| std::iter::once(&s.key).chain(s.with.keys()))
        {
            if swept.contains(&key.as_str()) {
                return Err(err(
                    "sweep.key",
                    format!("`{key}` is swept twice: each key may be set by one sweep only"),
                ));
            }
            swept.push(key);
        }
        if study.sweep.iter().any(|s| s.values.is_empty()) {
            return Err(err(
                "sweep.values",
                "every sweep needs at least one value".into(),
            ));
        }
        for s in &study.sweep {
            if let Some((k, v)) = s.with.iter().find(|(_, v)| v.len() != s.values.len()) {
                return Err(err(
                    "sweep.with",
                    format!(
                        "`{k}` has {} values, `{}` has {}: `with` pairs one value with each",
                        v.len(),
                        s.key,
                        s.values.len()
                    ),
                ));
            }
        }
        Ok(study)
    }

    /// The study's scene file (`scene` is relative to the study file).
    pub fn scene_path(&self, study_path: &Path) -> PathBuf {
        study_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(&self.scene)
    }

    /// The scene overrides of a run: the study's `set`, then the run's labels.
    fn overrides(&self, labels: &[(String, String)]) -> Vec<String> {
        let mut overrides = self.set.clone();
        overrides.extend(labels.iter().map(|(k, v)| format!("{k}={v}")));
        overrides
    }

    /// Where run `i` writes its result: `<out_dir>/<study>-<i>.h5`.
    pub fn result_path(&self, out_dir: &Path, i: usize) -> PathBuf {
        out_dir.join(format!("{}-{:03}.h5", self.name, i))
    }

    /// The scene of each of `runs` (this study's, at `study_path`), every
    /// one loaded and checked: the first bad override is the error.
    pub fn run_scenes(
        &self,
        study_path: &Path,
        runs: &[Vec<(String, String)>],
    ) -> Result<Vec<Scene>> {
        let scene_path = self.scene_path(study_path);
        runs.iter()
            .map(|labels| Scene::load(&scene_path, &self.overrides(labels)))
            .collect()
    }

    /// The override lists of all runs, outer sweeps first.
    pub fn runs(&self) -> Vec<Vec<(String, String)>> {
        let mut runs: Vec<Vec<(String, String)>> = vec![vec![]];
        for sweep in &self.sweep {
            runs = runs
                .into_iter()
                .flat_map(|prefix| {
                    sweep.values.iter().enumerate().map(move |(i, v)| {
                        let mut r = prefix.clone();
                        r.push((sweep.key.clone(), v.to_string()));
                        for (k, w) in &sweep.with {
                            r.push((k.clone(), w[i].to_string()));
                        }
                        r
                    })
                })
                .collect();
        }
        runs
    }
}

/// Runs every combination, writing results under `out_dir`, `jobs` runs at
/// a time (at least one). The rows keep the grid's order whatever order the
/// runs finish in; the first error (in grid order) stops the runs not yet
/// started and is returned. Progress bars only show when `jobs` is 1.
pub fn run_study(
    study_path: &Path,
    out_dir: &Path,
    show_progress: bool,
    jobs: usize,
) -> Result<Vec<StudyRow>> {
    let study = Study::load(study_path)?;
    let runs = study.runs();
    // Every run's scene before any run: a bad override in the last run must
    // not come after the first runs replaced earlier results.
    let scenes = study.run_scenes(study_path, &runs)?;
    let run = |i: usize| {
        run_one(
            &study,
            &scenes[i],
            out_dir,
            i,
            &runs[i],
            show_progress,
            jobs,
        )
    };
    if jobs <= 1 {
        return (0..runs.len()).map(run).collect();
    }
    // A shared queue of run indices; each worker takes the next until the
    // queue is empty or a run has failed.
    let next = std::sync::atomic::AtomicUsize::new(0);
    let failed = std::sync::atomic::AtomicBool::new(false);
    let results: std::sync::Mutex<Vec<Option<Result<StudyRow>>>> =
        std::sync::Mutex::new((0..runs.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..jobs.min(runs.len()) {
            scope.spawn(|| {
                use std::sync::atomic::Ordering::SeqCst;
                while !failed.load(SeqCst) {
                    let i = next.fetch_add(1, SeqCst);
                    if i >= runs.len() {
                        break;
                    }
                    let result = run(i);
                    if result.is_err() {
                        failed.store(true, SeqCst);
                    }
                    // A worker that panicked poisons the lock; its panic ends the scope anyway.
                    results.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(result);
                }
            });
        }
    });
    let results = results.into_inner().unwrap_or_else(|e| e.into_inner());
    // Runs not started after a failure are `None`; the first `Err` is returned.
    results.into_iter().flatten().collect()
}

/// Run `i` of the study (overrides `labels` beyond `set`), into
/// `<out_dir>/<study>-<i>.h5`. A numerical failure becomes a row.
fn run_one(
    study: &Study,
    scene: &Scene,
    out_dir: &Path,
    i: usize,
    labels: &[(String, String)],
    show_progress: bool,
    jobs: usize,
) -> Result<StudyRow> {
    let overrides = study.overrides(labels);
    let out = study.result_path(out_dir, i);
    // The run's failure marker (`RUN.failed`) tells the pages (`obstacle
    // index`) a run that failed from one whose result is older: written on
    // a numerical failure, removed after a success.
    let marker = FailureMarker::new(&failure_marker_path(&out), &out, &scene.input_files())?;
    let (summary, failure) = match run_scene(scene, &out, show_progress && jobs <= 1) {
        Ok(summary) => {
            marker.remove_stale()?;
            (summary, None)
        }
        Err(e @ Error::Numerical { .. }) => {
            eprintln!("[{i}] {}: failed: {e}", overrides.join(" "));
            marker.write(&e.to_string())?;
            (failed_summary(scene, &out), Some(e.to_string()))
        }
        Err(e) => return Err(e),
    };
    if show_progress && failure.is_none() {
        eprintln!(
            "[{}] {} → {} iterations, kkt {:.2e}, {:.2}s",
            i,
            overrides.join(" "),
            summary.iterations,
            summary.measures.kkt,
            summary.wall_seconds
        );
    }
    Ok(StudyRow {
        labels: labels.to_vec(),
        summary,
        failure,
    })
}

/// The summary of a run that failed numerically: its scene, "failed", and
/// the result file it was to write (the CSV links the run's report page).
fn failed_summary(scene: &Scene, out: &Path) -> RunSummary {
    RunSummary {
        result_file: out.to_path_buf(),
        scene: scene.name.clone(),
        model: scene.model.name().into(),
        element: scene.element.name().into(),
        stop_reason: "failed".into(),
        ..Default::default()
    }
}

/// The failure marker of a result file: `FILE.failed` beside `FILE.h5`,
/// holding the error of a run that failed numerically (`solve --failure-marker`).
pub fn failure_marker_path(result: &Path) -> PathBuf {
    crate::output::marker::marker_path(result)
}

/// The rows of a study whose runs were solved elsewhere (`--from-results`,
/// the last rule of a workflow): each run's summary read back from its
/// result file, or its failure from its marker when that is newer (a failed
/// rerun keeps the older result file). Nothing is solved; a run with
/// neither file is an error naming the result file.
pub fn rows_from_results(study_path: &Path, out_dir: &Path) -> Result<Vec<StudyRow>> {
    let study = Study::load(study_path)?;
    let runs = study.runs();
    let scenes = study.run_scenes(study_path, &runs)?;
    runs.into_iter()
        .zip(scenes)
        .enumerate()
        .map(|(i, (labels, scene))| {
            let out = study.result_path(out_dir, i);
            let marker = failure_marker_path(&out);
            let (summary, failure) = match crate::output::marker::newer_failure(&out)? {
                Some(text) => (failed_summary(&scene, &out), Some(text)),
                None if out.is_file() => (RunSummary::from_result(&out, &scene)?, None),
                None => {
                    return Err(Error::output(
                        &out,
                        format!(
                            "run {i} of the study ({}) has no result file and no failure marker {}: run the workflow first",
                            study.overrides(&labels).join(" "),
                            marker.display()
                        ),
                    ))
                }
            };
            Ok(StudyRow {
                labels,
                summary,
                failure,
            })
        })
        .collect()
}

/// Observed rate log(e_{k−1}/e_k)/log(h_{k−1}/h_k) between successive levels
/// of the innermost sweep (None at the first level of each group).
pub fn rates(rows: &[StudyRow], error: impl Fn(&RunSummary) -> Option<f64>) -> Vec<Option<f64>> {
    let mut out = vec![None; rows.len()];
    for i in 1..rows.len() {
        let (a, b) = (&rows[i - 1], &rows[i]);
        let same_group = a.labels.len() == b.labels.len() && outer_labels(a) == outer_labels(b);
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

/// The columns of a study table when the study names none (the membrane's
/// thesis tables). Names: see `column_value`.
pub const DEFAULT_COLUMNS: [&str; 20] = [
    "h",
    "triangles",
    "dofs",
    "alpha",
    "iterations",
    "stop",
    "dual_step",
    "penetration",
    "complementarity",
    "stationarity",
    "kkt",
    "error_l2",
    "rate_l2",
    "error_h1",
    "rate_h1",
    "contact_radius",
    "contact_radius_error",
    "error_l2_lambda",
    "stability_bound",
    "time",
];

/// One table cell: a number with its display precision, or text.
enum Cell {
    Number(f64, Display),
    Text(String),
    Missing,
}

#[derive(Clone, Copy)]
enum Display {
    /// Scientific with this many digits.
    Sci(usize),
    /// Fixed with this many decimals.
    Fixed(usize),
    Integer,
}

/// The heading of a column in the study's tables (Markdown, and the HTML
/// the index renders from the CSV); other names as they are.
pub fn column_heading(name: &str) -> String {
    let h = match name {
        "h" => "h",
        "triangles" => "#tri",
        "dofs" => "#dofs",
        "alpha" => "alpha",
        "iterations" => "iter",
        "stop" => "stop",
        "dual_step" => "‖Δλ‖",
        "penetration" => "penetration",
        "complementarity" => "complementarity",
        "stationarity" => "stationarity",
        "tangency" => "‖BU‖",
        "kkt" => "KKT",
        "error_l2" => "L² err",
        "rate_l2" | "rate_h1" => "rate",
        "error_h1" => "H¹ err",
        "contact_radius" => "a_h",
        "contact_radius_error" => "|a_h−a|",
        "error_l2_lambda" => "λ L² err",
        "stability_bound" => "2/s_max",
        "time" => "time [s]",
        "time_per_iteration" => "time/iter [ms]",
        other => other,
    };
    h.to_string()
}

/// The value of column `name` for row `i`. Besides the names of
/// [`DEFAULT_COLUMNS`]: "tangency", "time_per_iteration", and any numeric
/// root attribute of the result file by its name (e.g. "u3_min",
/// "gap_origin", "contact_area" for the shell).
fn column_value(
    name: &str,
    rows: &[StudyRow],
    i: usize,
    l2_rates: &[Option<f64>],
    h1_rates: &[Option<f64>],
) -> Cell {
    use Display::*;
    let s = &rows[i].summary;
    let m = &s.measures;
    let e = s.errors;
    let num = |v: Option<f64>, d: Display| v.map_or(Cell::Missing, |x| Cell::Number(x, d));
    if rows[i].failure.is_some() {
        return if name == "stop" {
            Cell::Text("failed".into())
        } else {
            Cell::Missing
        };
    }
    match name {
        "h" => Cell::Number(s.h, Fixed(4)),
        "triangles" => Cell::Number(s.n_triangles as f64, Integer),
        "dofs" => Cell::Number(s.n_dofs as f64, Integer),
        "alpha" => num(s.alpha, Fixed(4)),
        "iterations" => Cell::Number(s.iterations as f64, Integer),
        "stop" => Cell::Text(s.stop_reason.clone()),
        "dual_step" => Cell::Number(s.last_dual_step, Sci(3)),
        "penetration" => Cell::Number(m.penetration, Sci(2)),
        "complementarity" => Cell::Number(m.complementarity, Sci(2)),
        "stationarity" => Cell::Number(m.stationarity, Sci(2)),
        "tangency" => Cell::Number(m.tangency, Sci(2)),
        "kkt" => Cell::Number(m.kkt, Sci(2)),
        "error_l2" => num(e.map(|e| e.l2), Sci(3)),
        "rate_l2" => num(l2_rates[i], Fixed(2)),
        "error_h1" => num(e.map(|e| e.h1), Sci(3)),
        "rate_h1" => num(h1_rates[i], Fixed(2)),
        "contact_radius" => num(e.map(|e| e.contact_radius), Fixed(4)),
        "contact_radius_error" => num(
            e.map(|e| (e.contact_radius - e.exact_contact_radius).abs()),
            Sci(2),
        ),
        "error_l2_lambda" => num(e.map(|e| e.lambda_l2), Sci(2)),
        "stability_bound" => num(s.spectrum.map(|sp| 2.0 / sp.s_max), Fixed(3)),
        "time" => Cell::Number(s.wall_seconds, Fixed(3)),
        "time_per_iteration" => {
            Cell::Number(1e3 * s.solve_seconds / s.iterations.max(1) as f64, Sci(3))
        }
        attr => num(s.attr(attr), Sci(4)),
    }
}

/// The column names of a study (its `columns`, or the defaults).
fn columns_of(study: &Study) -> Vec<String> {
    study
        .columns
        .clone()
        .unwrap_or_else(|| DEFAULT_COLUMNS.iter().map(|c| c.to_string()).collect())
}

/// The study as a Markdown table (one table per value of the outer sweeps).
pub fn markdown_table(study: &Study, rows: &[StudyRow]) -> String {
    let title = study.title.clone().unwrap_or_else(|| study.name.clone());
    let columns = columns_of(study);
    let l2_rates = rates(rows, |s| s.errors.map(|e| e.l2));
    let h1_rates = rates(rows, |s| s.errors.map(|e| e.h1));
    // The innermost sweep's value leads each row (the outer ones head the tables).
    let inner_key = study.sweep.last().map(|s| s.key.clone());
    let headings: Vec<String> = inner_key
        .iter()
        .cloned()
        .chain(columns.iter().map(|c| column_heading(c)))
        .collect();
    let mut md = format!("## {title}\n");
    let mut group: Option<Vec<(String, String)>> = None;
    for (i, row) in rows.iter().enumerate() {
        let outer = outer_labels(row);
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
            let _ = writeln!(md, "| {} |", headings.join(" | "));
            let _ = writeln!(md, "|{}", "---|".repeat(headings.len()));
            group = Some(outer);
        }
        let inner_value = row.labels.last().map(|(_, v)| v.clone());
        let cells: Vec<String> =
            inner_value
                .into_iter()
                .chain(columns.iter().map(|c| {
                    match column_value(c, rows, i, &l2_rates, &h1_rates) {
                        Cell::Number(x, Display::Sci(p)) => format!("{x:.p$e}"),
                        Cell::Number(x, Display::Fixed(p)) => format!("{x:.p$}"),
                        Cell::Number(x, Display::Integer) => format!("{x:.0}"),
                        Cell::Text(t) => t,
                        Cell::Missing => "–".into(),
                    }
                }))
                .collect();
        let _ = writeln!(md, "| {} |", cells.join(" | "));
    }
    let failures: Vec<String> = rows
        .iter()
        .filter_map(|r| {
            let labels: Vec<String> = r.labels.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            r.failure
                .as_ref()
                .map(|f| format!("- {}: {f}", labels.join(", ")))
        })
        .collect();
    if !failures.is_empty() {
        let _ = writeln!(md, "\nFailed runs:\n\n{}", failures.join("\n"));
    }
    md
}

/// The study as CSV (one line per run: labels, the table's columns at full
/// precision, converged, result file).
pub fn csv_table(study: &Study, rows: &[StudyRow]) -> String {
    let columns = columns_of(study);
    let l2_rates = rates(rows, |s| s.errors.map(|e| e.l2));
    let h1_rates = rates(rows, |s| s.errors.map(|e| e.h1));
    let mut csv = String::new();
    if let Some(first) = rows.first() {
        let labels: Vec<&str> = first.labels.iter().map(|(k, _)| k.as_str()).collect();
        let mut head: Vec<String> = labels.iter().map(|l| l.to_string()).collect();
        head.extend(columns.iter().cloned());
        head.extend(["converged".to_string(), "result_file".to_string()]);
        let _ = writeln!(csv, "{}", head.join(","));
    }
    for (i, row) in rows.iter().enumerate() {
        let mut line: Vec<String> = row
            .labels
            .iter()
            .map(|(_, v)| v.replace(',', ";"))
            .collect();
        line.extend(
            columns
                .iter()
                .map(|c| match column_value(c, rows, i, &l2_rates, &h1_rates) {
                    Cell::Number(x, _) => format!("{x:e}"),
                    Cell::Text(t) => t.replace(',', ";"),
                    Cell::Missing => String::new(),
                }),
        );
        line.push(row.summary.converged.to_string());
        line.push(row.summary.result_file.display().to_string());
        let _ = writeln!(csv, "{}", line.join(","));
    }
    csv
}

/// The labels of a row's outer sweeps (all but the innermost).
fn outer_labels(row: &StudyRow) -> Vec<(String, String)> {
    row.labels[..row.labels.len().saturating_sub(1)].to_vec()
}

/// The runs grouped by the values of the outer sweeps: consecutive ranges
/// over which only the innermost sweep (the mesh level) varies.
fn groups(rows: &[StudyRow]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = 0;
    while start < rows.len() {
        let group = outer_labels(&rows[start]);
        let len = rows[start..]
            .iter()
            .take_while(|r| outer_labels(r) == group)
            .count();
        out.push(start..start + len);
        start += len;
    }
    out
}

/// Per run, the history values at the study's iterations (thesis Table 5.5):
/// one Markdown table per run, a row per history column.
pub fn history_tables(spec: &HistoryTableSpec, rows: &[StudyRow]) -> String {
    let mut md = String::new();
    for row in rows.iter().filter(|r| r.failure.is_none()) {
        let h = &row.summary.history;
        let labels: Vec<String> = row
            .labels
            .iter()
            .map(|(k, v)| format!("{k} = {v}"))
            .collect();
        let _ = writeln!(
            md,
            "\n### History: {}\n",
            if labels.is_empty() {
                row.summary.scene.clone()
            } else {
                labels.join(", ")
            }
        );
        let its: Vec<String> = spec.iterations.iter().map(|k| k.to_string()).collect();
        let _ = writeln!(md, "| iteration | {} |", its.join(" | "));
        let _ = writeln!(md, "|---|{}", "---|".repeat(its.len()));
        for name in &spec.columns {
            let cells: Vec<String> = spec
                .iterations
                .iter()
                .map(|&k| {
                    h.column(name)
                        .and_then(|c| c.get(k.wrapping_sub(1)))
                        .map_or("–".into(), |v| format!("{v:.6e}"))
                })
                .collect();
            let _ = writeln!(md, "| {} | {} |", column_heading(name), cells.join(" | "));
        }
    }
    md
}

/// The history values of [`history_tables`] as CSV: per run that did not
/// fail, one line per iteration (the run's labels, the iteration, the
/// columns at full precision; empty past the run's last iteration).
pub fn history_csv(spec: &HistoryTableSpec, rows: &[StudyRow]) -> String {
    let mut csv = String::new();
    let Some(first) = rows.first() else {
        return csv;
    };
    let mut head: Vec<String> = first.labels.iter().map(|(k, _)| k.clone()).collect();
    head.push("iteration".into());
    head.extend(spec.columns.iter().cloned());
    let _ = writeln!(csv, "{}", head.join(","));
    for row in rows.iter().filter(|r| r.failure.is_none()) {
        for &k in &spec.iterations {
            let mut line: Vec<String> = row
                .labels
                .iter()
                .map(|(_, v)| v.replace(',', ";"))
                .collect();
            line.push(k.to_string());
            line.extend(spec.columns.iter().map(|name| {
                row.summary
                    .history
                    .column(name)
                    .and_then(|c| c.get(k.wrapping_sub(1)))
                    .map_or(String::new(), |v| format!("{v:e}"))
            }));
            let _ = writeln!(csv, "{}", line.join(","));
        }
    }
    csv
}

/// What [`reference_study`] writes: its Markdown tables, the same numbers as
/// CSV (`STUDY.reference.csv`), and its plots.
pub struct ReferenceTables {
    pub md: String,
    pub csv: String,
    pub files: Vec<PathBuf>,
}

/// Relative L² errors of each component against the last run of each group
/// of the outer sweeps (the finest mesh), their least-squares rates in h,
/// as a Markdown table and a CSV, and one log–log plot per group.
pub fn reference_study(
    study: &Study,
    spec: &ReferenceSpec,
    rows: &[StudyRow],
    outputs: &OutputTransaction,
) -> Result<ReferenceTables> {
    let mut md = String::new();
    let mut csv = String::new();
    let mut files = Vec::new();
    for range in groups(rows) {
        let (start, end) = (range.start, range.end);
        let group = outer_labels(&rows[start]);
        if rows[end - 1].failure.is_some() {
            let _ = writeln!(
                md,
                "\nThe finest run of a group failed: no reference errors."
            );
            continue;
        }
        let reference = &rows[end - 1].summary;
        let ref_file = read_result(&reference.result_file)?;
        let mut levels: Vec<(f64, Vec<(String, f64)>)> = Vec::new();
        for row in rows[start..end - 1].iter().filter(|r| r.failure.is_none()) {
            let s = &row.summary;
            let file = read_result(&s.result_file)?;
            let errors = relative_errors(
                (&file, &s.result_file),
                (&ref_file, &reference.result_file),
                &spec.fields,
            )?;
            levels.push((s.h, errors));
        }
        let Some((_, first)) = levels.first() else {
            continue;
        };
        let names: Vec<String> = first.iter().map(|(n, _)| n.clone()).collect();
        let label: Vec<String> = group.iter().map(|(k, v)| format!("{k} = {v}")).collect();
        let _ = writeln!(
            md,
            "\n### Relative L² errors against the finest mesh (h = {:.4}){}\n",
            reference.h,
            if label.is_empty() {
                String::new()
            } else {
                format!(", {}", label.join(", "))
            }
        );
        let _ = writeln!(md, "| h | {} |", names.join(" | "));
        let _ = writeln!(md, "|---|{}", "---|".repeat(names.len()));
        for (h, errors) in &levels {
            let cells: Vec<String> = errors.iter().map(|(_, e)| format!("{e:.3e}")).collect();
            let _ = writeln!(md, "| {h:.4} | {} |", cells.join(" | "));
        }
        let series: Vec<(String, Vec<(f64, f64)>)> = names
            .iter()
            .enumerate()
            .map(|(c, n)| {
                (
                    n.clone(),
                    levels.iter().map(|(h, e)| (*h, e[c].1)).collect(),
                )
            })
            .collect();
        let slopes: Vec<String> = series
            .iter()
            .map(|(_, pts)| plot::loglog_slope(pts).map_or("–".into(), |k| format!("{k:.2}")))
            .collect();
        let _ = writeln!(md, "| fitted rate κ | {} |", slopes.join(" | "));
        // The CSV: the group's labels, h (or "fitted rate"), one column per field.
        if csv.is_empty() {
            let mut head: Vec<String> = group.iter().map(|(k, _)| k.clone()).collect();
            head.push("h".into());
            head.extend(names.iter().map(|n| format!("error_{n}")));
            let _ = writeln!(csv, "{}", head.join(","));
        }
        let values: Vec<String> = group.iter().map(|(_, v)| v.replace(',', ";")).collect();
        for (h, errors) in &levels {
            let mut line = values.clone();
            line.push(format!("{h:e}"));
            line.extend(errors.iter().map(|(_, e)| format!("{e:e}")));
            let _ = writeln!(csv, "{}", line.join(","));
        }
        let mut line = values.clone();
        line.push("fitted rate κ".into());
        line.extend(
            series.iter().map(|(_, pts)| {
                plot::loglog_slope(pts).map_or(String::new(), |k| format!("{k:e}"))
            }),
        );
        let _ = writeln!(csv, "{}", line.join(","));
        let path = outputs
            .folder()
            .join(format!("{}-reference-{}.png", study.name, files.len()));
        plot::plot_convergence(
            &outputs.stage(&path)?,
            &series,
            "h",
            "relative L² error",
            &reference_title(study, &rows[end - 1], &label),
            &[0.5, 1.0, 2.0],
        )?;
        files.push(path);
    }
    Ok(ReferenceTables { md, csv, files })
}

/// The title of a reference plot: what is measured against which run, e.g.
/// "naghdi-refinement: relative L² errors against the finest mesh (mesh.n =
/// 128, h = 1.105)", with the group's labels where the study has outer sweeps.
fn reference_title(study: &Study, finest: &StudyRow, group: &[String]) -> String {
    let mut finest_is: Vec<String> = finest
        .labels
        .last()
        .map(|(k, v)| format!("{k} = {v}"))
        .into_iter()
        .collect();
    finest_is.push(format!(
        "h = {}",
        crate::numbers::meaningful(finest.summary.h, 4)
    ));
    let mut title = format!(
        "{}: relative L² errors against the finest mesh ({})",
        study.name,
        finest_is.join(", ")
    );
    if !group.is_empty() {
        title = format!("{title}, {}", group.join(", "));
    }
    title
}

/// Work–precision figures (`<out_dir>/<study>-work-precision-<attribute>.png`):
/// for each attribute of `spec.reference`, |value − reference| / |reference|
/// against the run's wall time, one curve per group of the outer sweeps
/// (e.g. per element), log–log. Returns the files and a Markdown table.
pub fn write_work_precision(
    study: &Study,
    spec: &WorkPrecisionSpec,
    rows: &[StudyRow],
    outputs: &OutputTransaction,
) -> Result<(String, Vec<PathBuf>)> {
    let mut files = Vec::new();
    let mut md =
        String::from("\n### Relative errors against the reference values, and wall time\n\n");
    let names: Vec<&String> = spec.reference.keys().collect();
    let _ = writeln!(
        md,
        "| run | time [s] | {} |\n|---|---|{}",
        names
            .iter()
            .map(|n| n.as_str())
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(names.len())
    );
    let error = |r: &StudyRow, name: &str, reference: f64| {
        r.summary
            .attr(name)
            .filter(|_| r.failure.is_none())
            .map(|v| (v - reference).abs() / reference.abs())
    };
    for r in rows {
        let label: Vec<String> = r.labels.iter().map(|(k, v)| format!("{k} = {v}")).collect();
        let cells: Vec<String> = spec
            .reference
            .iter()
            .map(|(n, &v)| error(r, n, v).map_or("–".into(), |e| format!("{e:.2e}")))
            .collect();
        let _ = writeln!(
            md,
            "| {} | {:.3} | {} |",
            label.join(", "),
            r.summary.wall_seconds,
            cells.join(" | ")
        );
    }
    for (name, &reference) in &spec.reference {
        let series: Vec<(String, Vec<(f64, f64)>)> = groups(rows)
            .into_iter()
            .map(|range| {
                let label: Vec<String> = outer_labels(&rows[range.start])
                    .iter()
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect();
                let pts = rows[range]
                    .iter()
                    .filter_map(|r| error(r, name, reference).map(|e| (r.summary.wall_seconds, e)))
                    .collect();
                (label.join(", "), pts)
            })
            .collect();
        let path = outputs
            .folder()
            .join(format!("{}-work-precision-{name}.png", study.name));
        plot::plot_convergence(
            &outputs.stage(&path)?,
            &series,
            "wall time [s]",
            &format!("relative error of {name}"),
            &format!("{}: {name} against time", study.name),
            &[],
        )?;
        files.push(path);
    }
    Ok((md, files))
}

/// Log–log plots of the exact-solution errors against h, one per group of the
/// outer sweeps (`<out_dir>/<study>-convergence-<k>.png`). Returns the files.
pub fn write_convergence_plots(
    study: &Study,
    rows: &[StudyRow],
    outputs: &OutputTransaction,
) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for range in groups(rows) {
        let (start, end) = (range.start, range.end);
        let group = outer_labels(&rows[start]);
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
            let path =
                outputs
                    .folder()
                    .join(format!("{}-convergence-{}.png", study.name, files.len()));
            let title = if label.is_empty() {
                format!("{}: errors against the exact solution", study.name)
            } else {
                format!(
                    "{}: errors against the exact solution, {}",
                    study.name,
                    label.join(", ")
                )
            };
            plot::plot_convergence(
                &outputs.stage(&path)?,
                &series,
                "h",
                "error",
                &title,
                &[1.0, 2.0],
            )?;
            files.push(path);
        }
    }
    Ok(files)
}

/// Snakemake expands wildcards (`{name}`) in a rule's string params, and
/// `{{` does not escape them there: an out dir, scene path or override
/// holding a brace would be a WildcardError. A param given as a function is
/// taken as it is.
const PARAM: &str = "lambda wildcards: ";

/// Memory (MB) of a run's Slurm job besides what the memory guard
/// estimates for its mesh: the `obstacle` process without its matrices
/// (peak RSS 54 MB on the disk at n = 4 and at n = 16, plots included) and
/// the Snakemake job step that starts it inside the job (a Python process:
/// Snakemake running a six-run study on one machine peaks at 97 MB), with
/// room to spare: a job above its request is killed.
const JOB_BASE_MB: f64 = 512.0;

/// The memory (MB) a run's job asks for when its mesh is known only after
/// meshing (`mesh.h`, `mesh.file`) and the scene sets no `mesh.memory_limit_gb`.
const UNKNOWN_MESH_MB: f64 = 4000.0;

/// The minutes each run's job may take (Slurm `--time`): the profile's
/// default, one value for the whole study, edited there.
const RUNTIME_MINUTES: u32 = 60;

/// What a run's job asks its scheduler for (Snakemake's `threads` and
/// `resources`, Slurm's `--cpus-per-task` and `--mem`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunResources {
    /// `solver.threads`.
    pub threads: i64,
    /// The memory guard's estimate for the run's mesh
    /// ([`crate::guards::estimate_before_meshing`], `mesh.n`) plus
    /// [`JOB_BASE_MB`]; for a mesh known only after meshing,
    /// `mesh.memory_limit_gb` (what the run may use) or [`UNKNOWN_MESH_MB`],
    /// plus [`JOB_BASE_MB`].
    pub mem_mb: u64,
}

impl RunResources {
    pub fn of(scene: &Scene) -> RunResources {
        let mesh_mb = match (
            crate::guards::estimate_before_meshing(scene),
            scene.mesh.memory_limit_gb,
        ) {
            (Some(e), _) => e.bytes / 1e6,
            (None, Some(gb)) => gb * 1e3,
            (None, None) => UNKNOWN_MESH_MB,
        };
        RunResources {
            threads: scene.solver.threads,
            mem_mb: (mesh_mb + JOB_BASE_MB).ceil() as u64,
        }
    }
}

/// Writes `<out_dir>/Snakefile`: the study as a Snakemake workflow. One rule
/// per run runs `obstacle solve` on the run's scene with the study's
/// overrides into the result file the in-process study writes
/// ([`Study::result_path`]); a numerical failure leaves its marker
/// ([`failure_marker_path`]) instead of failing the workflow. Each run's
/// rule asks for its [`RunResources`]. The last rule builds the tables and
/// plots from the files (`--from-results`), where Snakemake runs (a local
/// rule). Paths are absolute; the binary is `obstacle` (this one) unless
/// Snakemake's `--config obstacle=PATH` names another. Every run's scene is
/// loaded first, so a bad override is refused here, not on the cluster.
/// Also writes the Slurm profile `<out_dir>/slurm/config.yaml`
/// ([`slurm_profile`]). Returns both paths.
pub fn write_snakefile(
    study_path: &Path,
    out_dir: &Path,
    obstacle: &Path,
) -> Result<(PathBuf, PathBuf)> {
    let study = Study::load(study_path)?;
    if study.name.contains(['{', '}']) {
        return Err(Error::Scene {
            file: study_path.to_path_buf(),
            field: "name".into(),
            reason: "`{` and `}` are Snakemake wildcards: a study run as a workflow cannot have them in its name".into(),
        });
    }
    let scene_path = study.scene_path(study_path);
    let runs = study.runs();
    let scenes = study.run_scenes(study_path, &runs)?;
    let inputs = [study_path.to_path_buf(), scene_path.clone()];
    let outputs = OutputTransaction::new(out_dir, "Snakefile", &inputs)?;
    let profile_outputs = OutputTransaction::new(&out_dir.join("slurm"), "config", &inputs)?;
    let absolute = |p: &Path| {
        p.canonicalize()
            .map_err(|e| Error::output(p, format!("cannot resolve the path: {e}")))
    };
    let (study_abs, scene_abs, dir_abs) = (
        absolute(study_path)?,
        absolute(&scene_path)?,
        absolute(out_dir)?,
    );
    let path_str = |p: &Path| py_str(&p.to_string_lossy());
    let logs: Vec<String> = (0..runs.len())
        .map(|i| py_str(&format!("{}-{i:03}.log", study.name)))
        .collect();
    let tables = [
        py_str(&format!("{}.md", study.name)),
        py_str(&format!("{}.csv", study.name)),
    ];
    let mut s = String::from(crate::output::transaction::WORKFLOW_HEADER);
    let _ = writeln!(
        s,
        "# The study {name} as a Snakemake workflow, written by\n\
         # `obstacle study {study} --out-dir {dir} --workflow snakemake`: one rule per run\n\
         # (`obstacle solve`; a run that fails numerically leaves RUN.failed), then the\n\
         # tables and plots (`obstacle study --from-results`). Run `snakemake -j N` here,\n\
         # or on Slurm `snakemake --profile slurm` (slurm/config.yaml; docs/command-line.md).\n\
         # Another binary: --config obstacle=PATH.\n\
         \n\
         OBSTACLE = config.get(\"obstacle\", {exe})\n\
         STUDY = {study_py}\n\
         SCENE = {scene_py}\n\
         # A relative mesh.file/mesh.geo override is relative to the scene's folder, as in a study.\n\
         SCENE_DIR = {scene_dir_py}\n\
         OUT_DIR = {dir_py}\n\
         \n\
         workdir: OUT_DIR\n\
         \n\
         # The tables are built where Snakemake runs, not as a cluster job.\n\
         localrules: all, table\n\
         \n\
         rule all:\n    input: {tables}\n\
         \n\
         rule table:\n    input: {logs}\n    output: {tables}\n    shell:\n        \
         \"{{OBSTACLE:q}} study {{STUDY:q}} --out-dir {{OUT_DIR:q}} --from-results --quiet\"",
        name = study.name,
        // In a comment line: a newline in a path must not end it.
        study = study_abs.display().to_string().escape_debug(),
        dir = dir_abs.display().to_string().escape_debug(),
        exe = path_str(obstacle),
        study_py = path_str(&study_abs),
        scene_py = path_str(&scene_abs),
        scene_dir_py = path_str(scene_abs.parent().unwrap_or(Path::new("/"))),
        dir_py = path_str(&dir_abs),
        tables = tables.join(", "),
        logs = logs.join(", "),
    );
    for (i, (labels, scene)) in runs.iter().zip(&scenes).enumerate() {
        let out = study.result_path(&dir_abs, i);
        let sets: Vec<String> = study
            .overrides(labels)
            .iter()
            .flat_map(|o| ["--set", o.as_str()].map(py_str))
            .collect();
        let resources = RunResources::of(scene);
        let _ = writeln!(
            s,
            "\nrule run_{i:03}:\n    output: {log}\n    threads: {threads}\n    resources:\n        \
             mem_mb={mem_mb},\n    params:\n        \
             out={PARAM}{out},\n        failed={PARAM}{failed},\n        sets={PARAM}[{sets}],\n    shell:\n        \
             \"(cd {{SCENE_DIR:q}} && {{OBSTACLE:q}} solve {{SCENE:q}} --quiet --out {{params.out:q}} \
             --failure-marker {{params.failed:q}} {{params.sets:q}}) > {{output:q}}\"",
            log = logs[i],
            threads = resources.threads,
            mem_mb = resources.mem_mb,
            out = path_str(&out),
            failed = path_str(&failure_marker_path(&out)),
            sets = sets.join(", "),
        );
    }
    let path = out_dir.join("Snakefile");
    crate::output::write_text_atomically(&outputs.stage(&path)?, &s)?;
    let profile = out_dir.join("slurm").join("config.yaml");
    crate::output::write_text_atomically(
        &profile_outputs.stage(&profile)?,
        &slurm_profile(&study.name),
    )?;
    profile_outputs.commit()?;
    outputs.commit()?;
    Ok((path, profile))
}

/// The Snakemake profile that runs a study's workflow on Slurm (Snakemake's
/// executor plugin `snakemake-executor-plugin-slurm`): one job per run with
/// the resources of its rule and [`RUNTIME_MINUTES`], per-job logs kept in
/// `slurm-logs/`, job states read with `squeue` (which sees jobs finished
/// within the cluster's `MinJobAge`; the plugin turns to `sacct` when that is
/// shorter than three of its status intervals), and the cluster's default
/// partition and account unless set in `default-resources`.
pub fn slurm_profile(study_name: &str) -> String {
    format!(
        "{header}\
         # Snakemake on Slurm for the study {name}: `snakemake --profile slurm` in the\n\
         # study's out dir. Each run is one job asking for its rule's threads\n\
         # (solver.threads) and mem_mb (the run's memory estimate), and the runtime below.\n\
         executor: slurm\n\
         jobs: 100                                  # jobs queued at a time\n\
         latency-wait: 60                           # shared file systems are slow to show new files\n\
         keep-going: true                           # a job the scheduler ends stops no other run\n\
         default-resources:\n  \
           runtime: {RUNTIME_MINUTES}                              # minutes per run (Slurm --time)\n  \
           # slurm_partition: \"PARTITION\"          # a cluster without a default partition\n  \
           # slurm_account: \"ACCOUNT\"              # a cluster that charges an account\n\
         slurm-logdir: slurm-logs                   # one log per job: slurm-logs/rule_run_NNN/JOBID.log\n\
         slurm-keep-successful-logs: true\n\
         slurm-status-command: squeue\n\
         slurm-init-seconds-before-status-checks: 5\n",
        header = crate::output::transaction::WORKFLOW_HEADER,
        name = study_name.escape_debug(),
    )
}

/// `text` as a Python string literal.
fn py_str(text: &str) -> String {
    let mut s = String::from("\"");
    for c in text.chars() {
        match c {
            '\\' => s.push_str("\\\\"),
            '"' => s.push_str("\\\""),
            c if c.is_control() => {
                let _ = write!(s, "\\U{:08x}", c as u32);
            }
            c => s.push(c),
        }
    }
    s.push('"');
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disk(sets: &[&str]) -> Scene {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/scenes/obstacle-disk.toml");
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        Scene::load(&path, &sets).unwrap()
    }

    /// A run's job asks for `solver.threads` CPUs and the memory guard's
    /// estimate plus the job's base; for a mesh known only after meshing,
    /// `mesh.memory_limit_gb` or the default, plus the base.
    #[test]
    fn a_run_asks_for_its_threads_and_its_memory_estimate() {
        // The disk at n = 16: 2.9 · 256 triangles, 2.5 unknowns each, 3 KB each.
        let scene = disk(&["mesh.n=16", "solver.threads=3"]);
        let bytes = 2.9 * 256.0 * 2.5 * 3.0e3;
        assert_eq!(
            RunResources::of(&scene),
            RunResources {
                threads: 3,
                mem_mb: (bytes / 1e6 + JOB_BASE_MB).ceil() as u64
            }
        );
        let by_h = disk(&["mesh.h=0.1"]);
        assert_eq!(by_h.mesh.n, None);
        assert_eq!(RunResources::of(&by_h).mem_mb, 4512);
        let limited = disk(&["mesh.h=0.1", "mesh.memory_limit_gb=2.5"]);
        assert_eq!(RunResources::of(&limited).mem_mb, 3012);
    }
}
