//! `obstacle index BUILD_DIR`: the overview page of the main job's outputs
//! under `build/results` and `build/studies`: one line per run with its
//! status (converged, not converged, failed with the reason), every study
//! table rendered from its CSV file, every figure as a thumbnail; and a
//! report page beside every run, failed ones included.

use super::{
    has_extension, page_name, relative_link, render_report, report_path, run_outcome, Picture,
    RunStatus, DIGITS,
};
use crate::error::{Error, Result};
use crate::numbers::{count, meaningful, seconds};
use crate::output::marker::marker_path;
use crate::output::{numeric_attr, write_text_atomically, OutputTransaction, ResultFile};
use askama::Template;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Outputs of the main job with a fixed explanation (file stem → line).
const KNOWN: &[(&str, &str)] = &[
    (
        "membrane-thesis",
        "membrane, both pairs, h = 0.8 … 0.1, α = 0.9, 1.9, auto (thesis Tables 5.1–5.4)",
    ),
    (
        "membrane-convergence",
        "membrane errors and rates of converged solutions against the exact solution",
    ),
    (
        "naghdi-hypar",
        "the thesis shell (hyperbolic paraboloid) in contact with its obstacle",
    ),
    ("naghdi-hypar-free", "the thesis shell without obstacle"),
    ("naghdi-history", "shell Uzawa history (thesis Table 5.5)"),
    ("naghdi-rho", "shell ρ sweep (thesis Tables 5.6 and 5.8)"),
    ("naghdi-alpha", "shell α sweep (thesis Table 5.7)"),
    (
        "naghdi-refinement",
        "shell refinement n = 16 … 128, errors against the finest mesh (thesis Fig. 5.10)",
    ),
];

/// The folders of the main job that the index lists, below the build folder.
const INDEX_FOLDERS: &[&str] = &["results", "studies"];

/// One run's line.
struct RunLine {
    class: &'static str,
    word: &'static str,
    detail: String,
    /// The failure's reason, shown under the explanation.
    reason: String,
    name: String,
    page: String,
    file: Option<String>,
    what: String,
    iterations: String,
    kkt: String,
    time: String,
}

struct RunSection {
    title: String,
    anchor: String,
    runs: Vec<RunLine>,
}

struct TableCell {
    text: String,
    number: bool,
    link: Option<String>,
}

struct TableRow {
    class: &'static str,
    /// The run's status word, empty in a table without `converged` column.
    status: &'static str,
    cells: Vec<TableCell>,
}

/// A CSV file as an HTML table.
struct TableView {
    title: String,
    anchor: String,
    file_name: String,
    csv: String,
    markdown: Option<String>,
    /// Whether the rows have a status (the CSV has a `converged` column).
    with_status: bool,
    head: Vec<String>,
    rows: Vec<TableRow>,
}

#[derive(Template)]
#[template(path = "index.html")]
struct IndexPage {
    title: String,
    overall: String,
    overall_class: &'static str,
    /// The runs that failed: their report pages and what they are.
    failures: Vec<Picture>,
    sections: Vec<RunSection>,
    tables: Vec<TableView>,
    figures: Vec<Picture>,
}

/// `obstacle index`: writes `BUILD/index.html` (or `out`) and a report page
/// beside every run under `build/results` and `build/studies` (a result
/// file, or the failure marker of a run that failed); each folder's pages
/// in one output transaction, the index last. Returns the index's path.
pub fn index_command(build: &Path, out: Option<&Path>) -> Result<PathBuf> {
    let page = page_name(out.map_or_else(|| build.join("index.html"), Path::to_path_buf))?;
    let folder = page.parent().unwrap_or(Path::new(""));
    // Created first: the links are resolved against the page's folder.
    let outputs = OutputTransaction::new(folder, "index", &[])?;
    let mut sections = Vec::new();
    let mut tables = Vec::new();
    let mut figures = Vec::new();
    // Report pages by folder: one transaction each.
    let mut reports: BTreeMap<PathBuf, Vec<(PathBuf, String)>> = BTreeMap::new();
    let (mut n_runs, mut by_status) = (0usize, BTreeMap::<&str, usize>::new());
    let mut failures = Vec::new();
    for sub in INDEX_FOLDERS {
        let dir = build.join(sub);
        let mut files = Vec::new();
        list_files(&dir, &mut files)?;
        files.sort();
        // The tables first: their rows name each study run's overrides.
        let mut overrides: BTreeMap<PathBuf, String> = BTreeMap::new();
        for f in files.iter().filter(|f| has_extension(f, "csv")) {
            tables.push(table_view(f, folder, &mut overrides)?);
        }
        let mut runs = Vec::new();
        for run in run_paths(&files) {
            let (status, file) = run_outcome(&run);
            let report = report_path(&run);
            let html = render_report(
                &run,
                &status,
                file.as_ref(),
                report_folder(&report),
                Some(&page),
            )?;
            reports
                .entry(report_folder(&report).to_path_buf())
                .or_default()
                .push((report.clone(), html));
            n_runs += 1;
            *by_status.entry(status.word()).or_default() += 1;
            let line = run_line(&run, &status, file.as_ref(), &report, folder, &overrides);
            if matches!(
                status,
                RunStatus::Failed { .. } | RunStatus::Unreadable { .. }
            ) {
                failures.push(Picture {
                    src: line.page.clone(),
                    caption: format!("{} ({})", line.name, line.what),
                });
            }
            runs.push(line);
        }
        sections.push(RunSection {
            title: dir.display().to_string(),
            anchor: format!("runs-{sub}"),
            runs,
        });
        for f in &files {
            if has_extension(f, "png") || has_extension(f, "svg") {
                // One picture per figure: the PNG where both were written.
                if has_extension(f, "svg") && f.with_extension("png").is_file() {
                    continue;
                }
                figures.push(Picture {
                    src: relative_link(f, folder),
                    caption: explanation(f),
                });
            }
        }
    }
    // The thesis tables in the order of the main job, then the others.
    tables.sort_by_key(|t| {
        let owner = t.file_name.split('.').next().unwrap_or("").to_string();
        let known = KNOWN.iter().position(|(k, _)| *k == owner);
        (known.unwrap_or(KNOWN.len()), t.file_name.clone())
    });
    let failed = by_status.get("failed").copied().unwrap_or(0)
        + by_status.get("unreadable").copied().unwrap_or(0);
    let not_converged = by_status.get("not converged").copied().unwrap_or(0);
    let mut overall = count(n_runs as u64, "run", "runs");
    let parts: Vec<String> = [
        "converged",
        "stopped by the thesis rule",
        "not converged",
        "failed",
        "unreadable",
    ]
    .iter()
    .filter_map(|w| by_status.get(w).map(|n| format!("{n} {w}")))
    .collect();
    if !parts.is_empty() {
        overall = format!("{overall}: {}", parts.join(", "));
    }
    let overall_class = if failed > 0 {
        "failed"
    } else if not_converged > 0 {
        "not-converged"
    } else {
        "converged"
    };
    let index = IndexPage {
        title: "obstacle-fem: outputs of the main job".into(),
        overall,
        overall_class,
        failures,
        sections,
        tables,
        figures,
    }
    .render()
    .map_err(|e| Error::output(&page, format!("cannot render the index: {e}")))?;
    for (dir, pages) in reports {
        let transaction = OutputTransaction::new(&dir, "reports", &[])?;
        for (path, html) in pages {
            write_text_atomically(&transaction.stage(&path)?, &html)?;
        }
        transaction.commit()?;
    }
    write_text_atomically(&outputs.stage(&page)?, &index)?;
    outputs.commit()?;
    Ok(page)
}

fn report_folder(report: &Path) -> &Path {
    match report.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The runs among `files`: every result file, and every failure marker
/// whose run left no result file (as the result file it was to write).
fn run_paths(files: &[PathBuf]) -> Vec<PathBuf> {
    let mut runs: Vec<PathBuf> = files
        .iter()
        .filter(|f| has_extension(f, "h5"))
        .cloned()
        .collect();
    for f in files.iter().filter(|f| has_extension(f, "failed")) {
        let result = f.with_extension("h5");
        if marker_path(&result) == *f && !runs.contains(&result) {
            runs.push(result);
        }
    }
    runs.sort();
    runs
}

/// The index line of the run that was to write `run`.
fn run_line(
    run: &Path,
    status: &RunStatus,
    file: Option<&ResultFile>,
    report: &Path,
    folder: &Path,
    overrides: &BTreeMap<PathBuf, String>,
) -> RunLine {
    let solver = |name: &str| file.and_then(|f| numeric_attr(&f.data.solver_attrs, name));
    let dash = || "–".to_string();
    let reason = match status {
        RunStatus::Failed { reason } | RunStatus::Unreadable { reason } => reason.clone(),
        _ => String::new(),
    };
    RunLine {
        class: status.class(),
        word: status.word(),
        detail: status.detail().to_string(),
        reason,
        name: run
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned(),
        page: relative_link(report, folder),
        file: run.is_file().then(|| relative_link(run, folder)),
        what: match overrides.get(run) {
            Some(o) => format!("{}: {o}", owner_line(run)),
            None => explanation(run),
        },
        iterations: solver("iterations").map_or_else(dash, |v| format!("{v}")),
        kkt: solver("kkt").map_or_else(dash, |v| meaningful(v, 3)),
        time: solver("wall_seconds").map_or_else(dash, seconds),
    }
}

/// A study's CSV file as a table: headings as the Markdown table names
/// them, numbers with meaningful digits (integers exact), `converged` as
/// yes/no, `result_file` as a link to the run's report page; a failed or
/// not converged run's row marked.
fn table_view(
    csv: &Path,
    folder: &Path,
    overrides: &mut BTreeMap<PathBuf, String>,
) -> Result<TableView> {
    let text = std::fs::read_to_string(csv)
        .map_err(|e| Error::output(csv, format!("cannot read the table: {e}")))?;
    let mut lines = text.lines().filter(|l| !l.is_empty());
    let names: Vec<&str> = lines
        .next()
        .map_or_else(Vec::new, |h| h.split(',').collect());
    let column = |name: &str| names.iter().position(|n| *n == name);
    let (stop, converged, result) = (column("stop"), column("converged"), column("result_file"));
    let rows = lines
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            let at = |i: Option<usize>| i.and_then(|i| cells.get(i).copied()).unwrap_or("");
            if let Some(run) = Some(at(result)).filter(|r| !r.is_empty()) {
                let labels: Vec<String> = names
                    .iter()
                    .zip(&cells)
                    .filter(|(n, _)| is_sweep_key(n))
                    .map(|(n, v)| format!("{n} = {}", unquoted(v)))
                    .collect();
                let name = Path::new(run).file_name().unwrap_or_default();
                overrides.insert(csv.with_file_name(name), labels.join(", "));
            }
            let (class, status) = if at(stop) == "failed" {
                ("failed", "failed")
            } else if at(converged) == "false" && at(stop) == "thesis" {
                ("stopped", "stopped by the thesis rule")
            } else if at(converged) == "false" {
                ("not-converged", "not converged")
            } else if at(converged) == "true" {
                ("converged", "converged")
            } else {
                ("", "")
            };
            let cells = cells
                .iter()
                .enumerate()
                .map(|(i, c)| table_cell(names.get(i).copied().unwrap_or(""), c, csv, folder))
                .collect();
            TableRow {
                class,
                status,
                cells,
            }
        })
        .collect();
    let stem = csv.file_stem().unwrap_or_default().to_string_lossy();
    // `STUDY.history.csv` and `STUDY.reference.csv` are parts of STUDY.
    let (owner, part) = stem.split_once('.').unwrap_or((&stem, ""));
    let markdown = csv.with_file_name(format!("{owner}.md"));
    let title = describe(csv, owner).unwrap_or_else(|| owner.to_string());
    let title = match part {
        "" => title,
        "history" => format!("{title}: the history at given iterations"),
        "reference" => format!("{title}: relative L² errors against the finest mesh, fitted rates"),
        other => format!("{title}: {other}"),
    };
    Ok(TableView {
        title,
        anchor: format!("table-{}", stem.replace('.', "-")),
        file_name: csv
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned(),
        csv: relative_link(csv, folder),
        markdown: markdown.is_file().then(|| relative_link(&markdown, folder)),
        with_status: converged.is_some(),
        head: names
            .iter()
            .map(|n| crate::study::column_heading(n))
            .collect(),
        rows,
    })
}

/// A sweep value without the quotes of its TOML string (`"p1b-p0"`).
fn unquoted(value: &str) -> &str {
    value
        .strip_prefix('"')
        .and_then(|v| v.strip_suffix('"'))
        .unwrap_or(value)
}

/// Whether a CSV column is a study's sweep key (a scene key: `element`,
/// `model`, or a dotted key such as `mesh.h`), not one of its measured
/// columns (plain names: `iterations`, `kkt`, `u3_min`, ...).
fn is_sweep_key(column: &str) -> bool {
    column.contains('.') || matches!(column, "element" | "model")
}

/// The line of the study (or known output) a run belongs to: the part of
/// [`explanation`] after "result NNN of: ".
fn owner_line(run: &Path) -> String {
    let line = explanation(run);
    match line.split_once(" of: ") {
        Some((_, owner)) => owner.to_string(),
        None => line,
    }
}

/// One CSV value as a table cell.
fn table_cell(column: &str, value: &str, csv: &Path, folder: &Path) -> TableCell {
    let text = |t: String| TableCell {
        text: t,
        number: false,
        link: None,
    };
    match column {
        "converged" => text(
            match value {
                "true" => "yes",
                "false" => "no",
                other => other,
            }
            .into(),
        ),
        // The run's report page, beside the CSV (the CSV names the file as
        // the study was given its output folder).
        "result_file" if !value.is_empty() => {
            let name = Path::new(value).file_name().unwrap_or_default();
            let run = csv.with_file_name(name);
            TableCell {
                text: run
                    .file_stem()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                number: false,
                link: Some(relative_link(&report_path(&run), folder)),
            }
        }
        _ => match value.parse::<f64>() {
            Ok(v) if !value.is_empty() => TableCell {
                // Integers (counts, integral sweep values) exact; `-0` as 0.
                text: if v.fract() == 0.0 && v.abs() < 1e15 {
                    format!("{}", v as i64)
                } else {
                    meaningful(v, DIGITS)
                },
                number: true,
                link: None,
            },
            _ => text(if value.is_empty() {
                "–".into()
            } else {
                unquoted(value).into()
            }),
        },
    }
}

/// Every non-hidden file below `dir` (none when it does not exist).
fn list_files(dir: &Path, files: &mut Vec<PathBuf>) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries {
        let entry = entry.map_err(|e| Error::output(dir, format!("cannot list: {e}")))?;
        let path = entry.path();
        // Hidden entries are staging folders of runs under way.
        if entry.file_name().to_string_lossy().starts_with('.') {
            continue;
        }
        // The entry itself, not what a symlink points to (a link to a folder
        // could loop); of the rest only regular files (or links to them):
        // a FIFO or a device would block or stream when read.
        let kind = entry
            .file_type()
            .map_err(|e| Error::output(&path, format!("cannot inspect: {e}")))?;
        if kind.is_dir() {
            list_files(&path, files)?;
        } else if path.is_file() {
            files.push(path);
        }
    }
    Ok(())
}

/// What the index calls a file it lists: table, figure or result.
fn listed_kind(path: &Path) -> Option<&'static str> {
    match path.extension().and_then(|e| e.to_str())? {
        "md" | "csv" => Some("table"),
        "png" | "svg" => Some("figure"),
        "h5" => Some("result"),
        _ => None,
    }
}

/// One line about a listed file: the known name's line, else the study's
/// title (the first line of `<stem>.md` beside it), else that of the study
/// whose run or plot it is, else the file kind; a figure of a result says
/// which plot of which result it is.
fn explanation(path: &Path) -> String {
    let kind = listed_kind(path).unwrap_or("file");
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    // The stem up to the first dot: `RESULT.u.png` belongs to `RESULT`.
    let (stem, rest) = name.split_once('.').unwrap_or((&name, ""));
    let plot = rest
        .rsplit_once('.')
        .map(|(p, _)| p)
        .filter(|p| !p.is_empty());
    if let Some(d) = describe(path, stem) {
        return match (kind, plot) {
            ("figure", Some(p)) => format!("figure {p}: {d}"),
            _ => format!("{kind}: {d}"),
        };
    }
    // A study's run or plot: `STUDY-000.h5`, `STUDY-convergence-0.png`.
    let owner = stem
        .match_indices('-')
        .rev()
        .find_map(|(i, _)| describe(path, &stem[..i]).map(|d| (&stem[i + 1..], d)));
    match (kind, plot, owner) {
        ("figure", Some(p), Some((run, d))) => format!("figure {p} of run {run}: {d}"),
        (kind, _, Some((part, d))) => format!("{kind} {part} of: {d}"),
        ("figure", Some(p), None) => format!("figure {p} of {stem}"),
        (kind, _, None) => kind.to_string(),
    }
}

/// The line of a known name, else the title of `<name>.md` beside `path`.
fn describe(path: &Path, name: &str) -> Option<String> {
    KNOWN
        .iter()
        .find(|(k, _)| *k == name)
        .map(|(_, line)| line.to_string())
        .or_else(|| study_title(&path.with_file_name(format!("{name}.md"))))
}

/// The title of a study's Markdown table (its first line, `## TITLE`).
fn study_title(md: &Path) -> Option<String> {
    // Only a regular file (or a link to one) is read: a FIFO would block.
    if !md.is_file() {
        return None;
    }
    let text = std::fs::read_to_string(md).ok()?;
    let title = text.lines().next()?.trim_start_matches('#').trim();
    (!title.is_empty()).then(|| title.to_string())
}
