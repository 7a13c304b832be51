//! HTML pages over finished outputs: `obstacle report RESULT.h5` (one run:
//! its status first, then its numbers grouped as problem, mesh, solver, KKT
//! measures, timing and memory, its plots as a gallery, the scene as run)
//! and `obstacle index BUILD_DIR` (the overview: every run's status, every
//! study table, every figure as a thumbnail, and a report page per run).
//!
//! Pages only read what the runs wrote. They are askama templates
//! (`templates/`): checked against their data when the crate compiles, and
//! every value is HTML-escaped unless a template says otherwise (none does).
//! Numbers go through [`crate::numbers`], one rule for meaningful digits.
//! Every link is relative, so a page moves with its folder.

mod index;

pub use index::index_command;

use crate::error::{Error, Result};
use crate::numbers::{count, meaningful, mebibytes, seconds};
use crate::output::blocks::result_mesh;
use crate::output::marker::newer_failure;
use crate::output::{read_result, write_text_atomically, AttrValue, OutputTransaction, ResultFile};
use crate::scene::PlotKind;
use askama::Template;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Significant digits of the numbers on the pages.
pub const DIGITS: usize = 4;

/// The default page of a result: `RESULT.html` beside it.
pub fn report_path(result: &Path) -> PathBuf {
    result.with_extension("html")
}

/// The plot files beside `result` (`RESULT.<kind>.<png|svg>` and the shell's
/// `RESULT.<kind>-profiles.<ext>`), in [`PlotKind::ALL`] order.
pub fn result_plots(result: &Path) -> Vec<PathBuf> {
    let mut plots = Vec::new();
    for kind in PlotKind::ALL {
        for suffix in ["", "-profiles"] {
            for ext in ["png", "svg"] {
                let path = result.with_extension(format!("{}{suffix}.{ext}", kind.name()));
                if path.is_file() {
                    plots.push(path);
                }
            }
        }
    }
    plots
}

/// What became of a run: the status line of its page and its index row.
#[derive(Debug, Clone, PartialEq)]
pub enum RunStatus {
    /// KKT measure within the tolerance (or one linear solve).
    Converged { detail: String },
    /// Stopped by the scene's own rule (`stop = "thesis"`: the thesis'
    /// criterion on the dual step was met), the KKT measure above the
    /// tolerance: the run did what the scene asked.
    StoppedByRule { detail: String },
    /// Stopped by `max_iter` (or another stop) above the tolerance.
    NotConverged { detail: String },
    /// Failed numerically: the error its failure marker holds.
    Failed { reason: String },
    /// A result file that cannot be read back.
    Unreadable { reason: String },
}

impl RunStatus {
    /// The CSS class of the status (and the status word, hyphenated).
    pub fn class(&self) -> &'static str {
        match self {
            RunStatus::Converged { .. } => "converged",
            RunStatus::StoppedByRule { .. } => "stopped",
            RunStatus::NotConverged { .. } => "not-converged",
            RunStatus::Failed { .. } => "failed",
            RunStatus::Unreadable { .. } => "unreadable",
        }
    }

    /// The status word: converged, stopped by the thesis rule, not
    /// converged, failed, unreadable.
    pub fn word(&self) -> &'static str {
        match self {
            RunStatus::Converged { .. } => "converged",
            RunStatus::StoppedByRule { .. } => "stopped by the thesis rule",
            RunStatus::NotConverged { .. } => "not converged",
            RunStatus::Failed { .. } => "failed",
            RunStatus::Unreadable { .. } => "unreadable",
        }
    }

    /// Why: the measures against the tolerance, or the error.
    pub fn detail(&self) -> &str {
        match self {
            RunStatus::Converged { detail }
            | RunStatus::StoppedByRule { detail }
            | RunStatus::NotConverged { detail } => detail,
            RunStatus::Failed { reason } | RunStatus::Unreadable { reason } => reason,
        }
    }

    /// The status of a result file read back, from its `/solver` attributes.
    pub fn of_result(file: &ResultFile) -> RunStatus {
        let attrs = &file.data.solver_attrs;
        let text = |name: &str| match find(attrs, name) {
            Some(AttrValue::Str(s)) => s.clone(),
            _ => String::new(),
        };
        let number = |name: &str| crate::output::numeric_attr(attrs, name);
        let converged = matches!(find(attrs, "converged"), Some(AttrValue::Bool(true)));
        let stop = text("stop_reason");
        let iterations = number("iterations").unwrap_or(0.0).max(0.0) as u64;
        let after = count(iterations, "iteration", "iterations");
        let kkt = number("kkt").map_or_else(|| "–".into(), |v| meaningful(v, 3));
        let tol = number("tol").map_or_else(|| "–".into(), |v| meaningful(v, 3));
        if converged && stop == "linear" {
            return RunStatus::Converged {
                detail: "one linear solve (no contact constraint)".into(),
            };
        }
        if converged {
            return RunStatus::Converged {
                detail: format!("KKT measure {kkt} ≤ tolerance {tol} after {after}"),
            };
        }
        if stop == "thesis" {
            return RunStatus::StoppedByRule {
                detail: format!(
                    "the thesis criterion ‖λᵏ − λᵏ⁻¹‖ < thesis_tol met after {after}; KKT measure {kkt} (tolerance {tol})"
                ),
            };
        }
        let why = match stop.as_str() {
            "max_iter" => format!("stopped at max_iter after {after}"),
            "" => format!("after {after}"),
            other => format!("stopped ({other}) after {after}"),
        };
        RunStatus::NotConverged {
            detail: format!("{why}; KKT measure {kkt} > tolerance {tol}"),
        }
    }
}

/// A run's status and, unless it failed, its result file: the failure
/// marker when it is newer than the result, else the result read back.
pub fn run_outcome(result: &Path) -> (RunStatus, Option<ResultFile>) {
    match newer_failure(result) {
        Ok(Some(reason)) => return (RunStatus::Failed { reason }, None),
        Ok(None) => {}
        Err(e) => {
            return (
                RunStatus::Unreadable {
                    reason: e.to_string(),
                },
                None,
            )
        }
    }
    match read_result(result) {
        Ok(file) => (RunStatus::of_result(&file), Some(file)),
        Err(e) => (
            RunStatus::Unreadable {
                reason: e.to_string(),
            },
            None,
        ),
    }
}

fn find<'a>(attrs: &'a [(String, AttrValue)], name: &str) -> Option<&'a AttrValue> {
    attrs.iter().find(|(k, _)| k == name).map(|(_, v)| v)
}

/// `obstacle report`: the page of `result` (default [`report_path`]) in
/// one output transaction; returns the page's path. A run whose failure
/// marker is newer than its result gets a page saying it failed and why.
pub fn report_command(result: &Path, out: Option<&Path>) -> Result<PathBuf> {
    let page = page_name(out.map_or_else(|| report_path(result), Path::to_path_buf))?;
    let (status, file) = run_outcome(result);
    let file = match (&status, file) {
        (RunStatus::Unreadable { .. }, _) => Some(read_result(result)?),
        (_, file) => file,
    };
    let folder = page.parent().unwrap_or(Path::new(""));
    let label = page
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("report");
    let outputs = OutputTransaction::new(folder, label, &[result.to_path_buf()])?;
    let html = render_report(result, &status, file.as_ref(), folder, None)?;
    write_text_atomically(&outputs.stage(&page)?, &html)?;
    outputs.commit()?;
    Ok(page)
}

/// One row of a report table: what, its `/solver` or root attribute name
/// (empty for a derived row), and the value as shown.
pub struct Row {
    pub label: String,
    pub key: String,
    pub value: String,
}

/// A titled table of a report.
pub struct Group {
    pub title: &'static str,
    pub rows: Vec<Row>,
}

/// A picture in a gallery: its link (relative to the page) and caption.
pub struct Picture {
    pub src: String,
    pub caption: String,
}

#[derive(Template)]
#[template(path = "report.html")]
struct ReportPage<'a> {
    title: String,
    status: &'a RunStatus,
    index_link: Option<String>,
    groups: Vec<Group>,
    figures: Vec<Picture>,
    scene_text: Option<&'a str>,
}

/// The page of the run that was to write `result`: its status, and when
/// `file` is given its numbers and the plots beside it (linked relative to
/// `page_folder`); `index` links back to the overview page.
pub fn render_report(
    result: &Path,
    status: &RunStatus,
    file: Option<&ResultFile>,
    page_folder: &Path,
    index: Option<&Path>,
) -> Result<String> {
    let name = result
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let (groups, figures) = match file {
        Some(file) => (
            report_groups(result, file)?,
            result_plots(result)
                .iter()
                .map(|p| Picture {
                    src: relative_link(p, page_folder),
                    caption: plot_caption(p),
                })
                .collect(),
        ),
        None => (Vec::new(), Vec::new()),
    };
    let page = ReportPage {
        title: format!("obstacle report: {name}"),
        status,
        index_link: index.map(|i| relative_link(i, page_folder)),
        groups,
        figures,
        scene_text: file.map(|f| f.data.scene_text.as_str()),
    };
    page.render()
        .map_err(|e| Error::output(result, format!("cannot render the report page: {e}")))
}

/// The caption of a plot beside a result: its kind (`RESULT.u.png` → `u`).
fn plot_caption(plot: &Path) -> String {
    let name = plot.file_name().unwrap_or_default().to_string_lossy();
    let inner = name.split_once('.').map_or("", |(_, rest)| rest);
    let kind = inner.rsplit_once('.').map_or(inner, |(k, _)| k);
    match kind {
        "u" => "u (displacement)".into(),
        "lambda" => "λ (contact multiplier)".into(),
        "contact" => "contact zone".into(),
        "history" => "solver history".into(),
        other => other.into(),
    }
}

/// Where a `/solver` attribute goes on the page.
fn solver_group(name: &str) -> usize {
    match name {
        "converged" | "kkt" | "penetration" | "dual_min" | "complementarity" | "stationarity"
        | "tangency" | "active" | "dual_step" => KKT,
        n if n.ends_with("seconds") || n.starts_with("seconds_at_end_of_") => TIMING,
        n if n.starts_with("peak_rss_mb_") => MEMORY,
        _ => SOLVER,
    }
}

const PROBLEM: usize = 0;
const MESH: usize = 1;
const SOLVER: usize = 2;
const KKT: usize = 3;
const TIMING: usize = 4;
const MEMORY: usize = 5;
const GROUP_TITLES: [&str; 6] = [
    "Problem",
    "Mesh",
    "Solver",
    "KKT measures",
    "Timing",
    "Memory",
];

/// What a known attribute is, for the row's label.
fn label_of(name: &str) -> String {
    let known = match name {
        "model" => "model",
        "element" => "element pair",
        "simulated" => "what is simulated",
        "scene" => "scene",
        "u3_min" => "min u₃",
        "contact_force" => "contact force ∫λ",
        "contact_area" => "contact area",
        "contact_radius" => "contact radius a_h",
        "exact_contact_radius" => "exact contact radius a",
        "gap_origin" => "gap at the origin",
        "strain_energy" => "strain energy",
        "external_work" => "external work",
        "error_l2" => "L² error of u",
        "error_h1" => "H¹ error of u",
        "error_l2_lambda" => "L² error of λ",
        "phi_positive_vertices" => "vertices with Φ_h > 0",
        "tangency_scale" => "tangency scale σ",
        "algorithm" => "algorithm",
        "method" => "method",
        "iterations" => "iterations",
        "stop_reason" => "stopped by",
        "stop" => "stop rule",
        "tol" => "KKT tolerance",
        "thesis_tol" => "thesis tolerance ‖Δλ‖",
        "max_iter" => "max iterations",
        "threads" => "threads",
        "dual_norm" => "norm of ‖Δλ‖",
        "step_form" => "step form",
        "cold_start" => "cold start",
        "alpha" => "dual step α",
        "s_max_estimate" => "s_max (Lanczos)",
        "s_min_ritz" => "s_min (Ritz value)",
        "stability_bound" => "stability bound 2/s_max",
        "converged" => "converged (KKT ≤ tolerance)",
        "kkt" => "relative KKT measure",
        "penetration" => "penetration max(0, −min ḡ)",
        "dual_min" => "min λ",
        "complementarity" => "complementarity max |λᵢḡᵢ|",
        "stationarity" => "stationarity ‖Ku − F − Cᵀλ‖/‖F‖",
        "tangency" => "tangency ‖BU‖",
        "active" => "active constraints",
        "dual_step" => "last step ‖λᵏ − λᵏ⁻¹‖",
        "wall_seconds" => "solver wall time",
        "factor_seconds" => "factorisation",
        "run_seconds" => "whole run",
        _ => "",
    };
    if !known.is_empty() {
        known.into()
    } else if let Some(phase) = name.strip_prefix("seconds_at_end_of_") {
        format!("end of {phase} (since the start)")
    } else if let Some(phase) = name.strip_prefix("peak_rss_mb_") {
        format!("peak resident memory at the end of {phase}")
    } else {
        name.replace('_', " ")
    }
}

/// An attribute's value as the page shows it: meaningful digits, seconds
/// and memory with their units, yes/no, strings as they are.
fn value_of(name: &str, v: &AttrValue) -> String {
    match v {
        AttrValue::F64(x) if name.ends_with("seconds") || name.starts_with("seconds_") => {
            seconds(*x)
        }
        AttrValue::F64(x) if name.starts_with("peak_rss_mb_") => mebibytes(*x),
        AttrValue::F64(x) => meaningful(*x, DIGITS),
        AttrValue::I64(x) => x.to_string(),
        AttrValue::Bool(true) => "yes".into(),
        AttrValue::Bool(false) => "no".into(),
        AttrValue::Str(s) => s.clone(),
    }
}

fn attr_row(name: &str, v: &AttrValue) -> Row {
    Row {
        label: label_of(name),
        key: name.into(),
        value: value_of(name, v),
    }
}

/// The report's tables: root attributes (problem), the mesh, the `/solver`
/// attributes split into solver, KKT measures, timing and memory, and the
/// history's size; empty groups left out.
fn report_groups(result: &Path, file: &ResultFile) -> Result<Vec<Group>> {
    let d = &file.data;
    let mesh = result_mesh(file, result)?;
    let mut rows: [Vec<Row>; 6] = Default::default();
    for (k, v) in &d.root_attrs {
        rows[PROBLEM].push(attr_row(k, v));
    }
    rows[PROBLEM].push(Row {
        label: "program version".into(),
        key: "version".into(),
        value: file.version.clone(),
    });
    let derived = |label: &str, value: String| Row {
        label: label.into(),
        key: String::new(),
        value,
    };
    rows[MESH].push(derived("vertices", mesh.n_vertices().to_string()));
    rows[MESH].push(derived("triangles", mesh.n_triangles().to_string()));
    rows[MESH].push(derived("edges", mesh.n_edges().to_string()));
    rows[MESH].push(derived(
        "h (longest edge)",
        meaningful(mesh.h_max(), DIGITS),
    ));
    for (k, v) in &d.solver_attrs {
        rows[solver_group(k)].push(attr_row(k, v));
    }
    let iterations = d.history.first().map_or(0, |(_, v)| v.len()) as u64;
    if !d.history.is_empty() {
        let mut text = format!(
            "{} × {} in /solver/history",
            count(d.history.len() as u64, "measure", "measures"),
            count(iterations, "iteration", "iterations")
        );
        let names: Vec<&str> = d.history.iter().map(|(n, _)| n.as_str()).collect();
        let _ = write!(text, " ({})", names.join(", "));
        rows[SOLVER].push(derived("history", text));
    }
    Ok(GROUP_TITLES
        .into_iter()
        .zip(rows)
        .filter(|(_, rows)| !rows.is_empty())
        .map(|(title, rows)| Group { title, rows })
        .collect())
}

/// A page's path, refused unless it ends in `.html`.
fn page_name(page: PathBuf) -> Result<PathBuf> {
    if has_extension(&page, "html") {
        Ok(page)
    } else {
        Err(Error::output(
            &page,
            "the page's file name must end in .html",
        ))
    }
}

/// A link from a page in `folder` to `path`: relative to the page (with
/// `..` where `path` is not below it), so the page moves with its folder,
/// and each segment percent-encoded (RFC 3986 unreserved characters kept),
/// so a name with `#`, `?`, `%` or a space is a file name, not a fragment,
/// query or escape. Both paths are resolved first: `folder` as given may be
/// relative to another folder than `path`.
fn relative_link(path: &Path, folder: &Path) -> String {
    let resolve = |p: &Path| {
        let p = if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        };
        p.canonicalize()
            .or_else(|_| std::path::absolute(p))
            .unwrap_or_else(|_| p.to_path_buf())
    };
    let (to, from) = (resolve(path), resolve(folder));
    let common = to
        .components()
        .zip(from.components())
        .take_while(|(a, b)| a == b)
        .count();
    let ups = from.components().count() - common;
    let mut segments: Vec<String> = vec!["..".into(); ups];
    segments.extend(
        to.components()
            .skip(common)
            .map(|c| percent_encode(c.as_os_str().as_encoded_bytes())),
    );
    segments.join("/")
}

/// A path segment's bytes with everything but `A-Z a-z 0-9 - . _ ~` as `%XX`.
fn percent_encode(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(bytes.len());
    for &b in bytes {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            s.push(b as char);
        } else {
            let _ = write!(s, "%{b:02X}");
        }
    }
    s
}

fn has_extension(path: &Path, ext: &str) -> bool {
    path.extension().and_then(|e| e.to_str()) == Some(ext)
}
