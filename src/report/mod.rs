//! HTML pages over finished outputs: `obstacle report RESULT.h5` (one run:
//! scene as run, mesh, solver and KKT measures, key numbers, its plots) and
//! `obstacle index BUILD_DIR` (every table, figure and result of the main job,
//! one line of explanation each). Pages only read what the runs wrote; every
//! text is escaped and every link is relative, so a page moves with its folder.

use crate::error::{Error, Result};
use crate::output::blocks::result_mesh;
use crate::output::xdmf::xml_escape;
use crate::output::{read_result, write_text_atomically, AttrValue, OutputTransaction, ResultFile};
use crate::scene::PlotKind;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The page's style: one small sheet, no external resources.
const STYLE: &str = "body{font-family:sans-serif;max-width:70em;margin:1em auto;padding:0 1em}\
table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px;text-align:left}\
pre{background:#f4f4f4;padding:.5em;overflow-x:auto}img{max-width:100%;margin:.5em 0}\
figure{margin:1em 0}";

/// Root attributes shown first, as the run's key numbers (the others follow).
const KEY_ATTRS: &[&str] = &["model", "element", "simulated", "u3_min", "contact_force"];

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

/// `obstacle report`: reads `result`, writes its page (default
/// [`report_path`]) in one output transaction; returns the page's path.
pub fn report_command(result: &Path, out: Option<&Path>) -> Result<PathBuf> {
    let file = read_result(result)?;
    let page = page_name(out.map_or_else(|| report_path(result), Path::to_path_buf))?;
    let folder = page.parent().unwrap_or(Path::new(""));
    let label = page
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("report");
    let outputs = OutputTransaction::new(folder, label, &[result.to_path_buf()])?;
    let html = render_report(result, &file, &result_plots(result), folder)?;
    write_text_atomically(&outputs.stage(&page)?, &html)?;
    outputs.commit()?;
    Ok(page)
}

/// The page of one result file; `plots` are linked relative to `page_folder`.
pub fn render_report(
    result: &Path,
    file: &ResultFile,
    plots: &[PathBuf],
    page_folder: &Path,
) -> Result<String> {
    let d = &file.data;
    let name = result
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let mesh = result_mesh(file, result)?;
    let mut s = page_head(&format!("obstacle report: {name}"));

    s.push_str("<h2>Key numbers</h2>\n<table>\n");
    let mut root: Vec<&(String, AttrValue)> = d.root_attrs.iter().collect();
    root.sort_by_key(|(k, _)| {
        KEY_ATTRS
            .iter()
            .position(|a| a == k)
            .unwrap_or(KEY_ATTRS.len())
    });
    table_row(&mut s, "version", &file.version);
    for (k, v) in root {
        table_row(&mut s, k, &attr_text(v));
    }
    s.push_str("</table>\n<h2>Mesh</h2>\n<table>\n");
    table_row(&mut s, "vertices", &mesh.n_vertices().to_string());
    table_row(&mut s, "triangles", &mesh.n_triangles().to_string());
    table_row(&mut s, "edges", &mesh.n_edges().to_string());
    table_row(&mut s, "h (longest edge)", &format!("{:.6}", mesh.h_max()));
    s.push_str("</table>\n<h2>Solver and KKT measures</h2>\n<table>\n");
    for (k, v) in &d.solver_attrs {
        table_row(&mut s, k, &attr_text(v));
    }
    let iterations = d.history.first().map_or(0, |(_, v)| v.len());
    table_row(
        &mut s,
        "history",
        &format!("{} measures × {iterations} iterations", d.history.len()),
    );
    s.push_str("</table>\n<h2>Plots</h2>\n");
    if plots.is_empty() {
        s.push_str("<p>No plot beside the result file.</p>\n");
    }
    for p in plots {
        let src = relative_link(p, page_folder);
        let _ = writeln!(
            s,
            "<figure><img src=\"{0}\" alt=\"{0}\"><figcaption>{0}</figcaption></figure>",
            xml_escape(&src)
        );
    }
    let _ = write!(
        s,
        "<h2>Scene as run</h2>\n<pre>{}</pre>\n</body>\n</html>\n",
        xml_escape(&d.scene_text)
    );
    Ok(s)
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

/// An attribute as the page shows it: strings without quotes.
fn attr_text(v: &AttrValue) -> String {
    match v {
        AttrValue::Str(s) => s.clone(),
        other => other.to_string(),
    }
}

fn table_row(s: &mut String, key: &str, value: &str) {
    let _ = writeln!(
        s,
        "<tr><th>{}</th><td>{}</td></tr>",
        xml_escape(key),
        xml_escape(value)
    );
}

fn page_head(title: &str) -> String {
    let title = xml_escape(title);
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <title>{title}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1>{title}</h1>\n"
    )
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

/// `obstacle index`: the page linking every table (`.md`, `.csv`), figure
/// (`.png`, `.svg`) and result (`.h5`, with its report page when written)
/// under `build/results` and `build/studies`; returns the page's path.
pub fn index_command(build: &Path, out: Option<&Path>) -> Result<PathBuf> {
    let page = page_name(out.map_or_else(|| build.join("index.html"), Path::to_path_buf))?;
    let folder = page.parent().unwrap_or(Path::new(""));
    // Created first: the links are resolved against the page's folder.
    let outputs = OutputTransaction::new(folder, "index", &[])?;
    let mut s = page_head("obstacle-fem: outputs of the main job");
    for sub in INDEX_FOLDERS {
        let dir = build.join(sub);
        let mut files = Vec::new();
        list_files(&dir, &mut files)?;
        files.sort();
        let _ = writeln!(s, "<h2>{}</h2>", xml_escape(&dir.display().to_string()));
        if files.is_empty() {
            s.push_str("<p>Nothing written yet.</p>\n");
            continue;
        }
        s.push_str("<ul>\n");
        for f in files.iter().filter(|f| listed_kind(f).is_some()) {
            let link = xml_escape(&relative_link(f, folder));
            let text = xml_escape(&f.file_name().unwrap_or_default().to_string_lossy());
            let _ = write!(s, "<li><a href=\"{link}\">{text}</a>");
            let page = report_path(f);
            if has_extension(f, "h5") && page.is_file() {
                let _ = write!(
                    s,
                    " (<a href=\"{}\">report</a>)",
                    xml_escape(&relative_link(&page, folder))
                );
            }
            let _ = writeln!(s, ": {}</li>", xml_escape(&explanation(f)));
        }
        s.push_str("</ul>\n");
    }
    s.push_str("</body>\n</html>\n");
    write_text_atomically(&outputs.stage(&page)?, &s)?;
    outputs.commit()?;
    Ok(page)
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

fn has_extension(path: &Path, ext: &str) -> bool {
    path.extension().and_then(|e| e.to_str()) == Some(ext)
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
