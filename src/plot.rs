//! Figures as PNG or SVG files (chosen by the extension of the path): P1 and
//! piecewise-constant fields over the mesh, the contact zone, solver
//! histories, convergence plots and curves on linear axes (profiles).
//!
//! Crates, and why each is here:
//! - `plotters` draws the figures and writes PNG (`bitmap_backend`,
//!   `bitmap_encoder`) and SVG (`svg_backend`). Its default features are
//!   off: they load system fonts through font-kit and fail at run time on a
//!   machine without them. `ab_glyph` renders text with a font registered
//!   from memory instead; `line_series`/`point_series` are the curves,
//!   `colormaps` (which needs `full_palette`) gives Viridis.
//! - `dejavu` ships DejaVu Sans (free licence) as bytes compiled into the
//!   binary, so nothing is needed from the system when a figure is drawn.
//!   It is registered with `plotters::style::register_font` on first use.
//! - `tempfile` (already a dependency) gives the temporary file in the target
//!   directory that a figure is rendered into and then renamed over `path`,
//!   so a reader never sees a half-written figure.
//!
//! Every function validates its input before creating any file: a
//! non-finite field value, a field of the wrong length or a bad path is an
//! [`Error::Output`] naming `path`, and no file is left behind. Drawing
//! never panics into the caller (a panic inside plotters is caught and
//! reported as an error). Files are written with mode 0644.
//!
//! SVG files hold one element per drawn (sub-)triangle: fine for meshes of
//! a few ten thousand triangles; for finer meshes prefer PNG.

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::solvers::measures::History;
use plotters::coord::ranged1d::{AsRangedCoord, BoldPoints, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// The family name the embedded font is registered under.
const FONT: &str = "sans-serif";

type DrawResult<T = ()> = std::result::Result<T, Box<dyn std::error::Error>>;
/// A clipped segment: its ends, and whether each was cut.
type Clipped = ((f64, f64), (f64, f64), bool, bool);
/// A named curve with gaps (None) where a value cannot be shown.
type Curve = (String, Vec<Option<(f64, f64)>>);
/// A chart on two axes (linear f64 ones unless said).
type Chart2d<'a, DB, X = RangedCoordf64, Y = RangedCoordf64> =
    ChartContext<'a, DB, Cartesian2d<X, Y>>;

/// Colours of curves (matplotlib's "tab10").
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Layout of the mesh figures, in pixels.
const FIG_W: u32 = 960;
const TITLE_H: u32 = 48;
const MARGIN: u32 = 16;
const X_LABEL_AREA: u32 = 52;
const Y_LABEL_AREA: u32 = 76;
const MIN_PLOT_H: f64 = 280.0;
const MAX_PLOT_H: f64 = 820.0;
const MIN_PLOT_W: f64 = 320.0;
/// Width of the panel right of a field plot (colour bar) and of a contact plot (legend).
const COLOUR_BAR_PANEL: u32 = 150;
/// The contact figure draws all mesh edges (else only the boundary) and
/// dots at active vertices when triangles are at least this large.
const MIN_EDGE_PX: f64 = 4.0;
const MIN_DOT_SPACING_PX: f64 = 8.0;
const LEGEND_PANEL: u32 = 290;
/// At most this many sub-triangles are drawn for a P1 field.
/// SVG coordinates are whole pixels and every sub-triangle costs ~190 bytes,
/// so SVG gets fewer, larger ones.
const SUBTRIANGLE_BUDGET_PNG: usize = 600_000;
const SUBTRIANGLE_BUDGET_SVG: usize = 10_000;
/// Target edge length of a sub-triangle, in pixels.
const SUBTRIANGLE_PX_PNG: f64 = 5.0;
const SUBTRIANGLE_PX_SVG: f64 = 10.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Png,
    Svg,
}

/// A figure: its size and how to draw it on a backend.
trait Figure {
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, format: Format) -> DrawResult
    where
        DB::ErrorType: 'static;
}

// ---------------------------------------------------------------------------
// Public API
// ---------------------------------------------------------------------------

/// Colour map of a P1 field (one value per vertex), interpolated linearly
/// inside each triangle (drawn as sub-triangles), with ~10 isolines (thin
/// black, also marked on the colour bar), a colour bar with its min/max,
/// equal aspect ratio and axes x, y.
pub fn plot_vertex_field(path: &Path, mesh: &Mesh, values: &[f64], title: &str) -> Result<()> {
    let format = format_of(path)?;
    check_mesh(path, mesh)?;
    check_field(path, values, mesh.vertices.len(), "vertex", "vertices")?;
    let (lo, hi) = display_range(values);
    let fig = FieldFigure {
        frame: Frame::for_mesh(mesh, COLOUR_BAR_PANEL),
        mesh,
        values,
        per_vertex: true,
        title,
        lo,
        hi,
        // None for a constant field (whose colour range is widened).
        levels: if values.iter().all(|&v| v == values[0]) {
            Vec::new()
        } else {
            iso_levels(lo, hi, 10)
        },
    };
    render(path, format, &fig)
}

/// Piecewise-constant colour map of a cell field (one value per triangle),
/// with a colour bar and its min/max, equal aspect ratio and axes x, y.
pub fn plot_cell_field(path: &Path, mesh: &Mesh, values: &[f64], title: &str) -> Result<()> {
    let format = format_of(path)?;
    check_mesh(path, mesh)?;
    check_field(path, values, mesh.triangles.len(), "cell", "triangles")?;
    let (lo, hi) = display_range(values);
    let fig = FieldFigure {
        frame: Frame::for_mesh(mesh, COLOUR_BAR_PANEL),
        mesh,
        values,
        per_vertex: false,
        title,
        lo,
        hi,
        levels: Vec::new(),
    };
    render(path, format, &fig)
}

/// The contact zone: `active` has one flag per triangle (those triangles
/// are filled) or one per vertex (the triangles touching an active vertex
/// are filled lightly, those with three active vertices strongly, and the
/// active vertices are dotted unless the mesh is too fine for dots); when
/// the mesh has as many triangles as vertices, the flags are taken per
/// vertex. The mesh edges are drawn light grey (only the boundary if the
/// triangles are under 4 px) and, if given, the exact contact circle of `reference_radius`
/// (centred at the origin) in red. A legend panel counts what is shown.
pub fn plot_contact_zone(
    path: &Path,
    mesh: &Mesh,
    active: &[bool],
    title: &str,
    reference_radius: Option<f64>,
) -> Result<()> {
    let format = format_of(path)?;
    check_mesh(path, mesh)?;
    let per_vertex = if active.len() == mesh.vertices.len() {
        true
    } else if active.len() == mesh.triangles.len() {
        false
    } else {
        return Err(Error::output(
            path,
            format!(
                "contact flags: {} values, expected one per vertex ({}) or per triangle ({})",
                active.len(),
                mesh.vertices.len(),
                mesh.triangles.len()
            ),
        ));
    };
    if let Some(r) = reference_radius {
        if !r.is_finite() || r < 0.0 {
            return Err(Error::output(
                path,
                format!("reference contact radius {r} is not a finite number >= 0"),
            ));
        }
    }
    let fig = ContactFigure {
        frame: Frame::for_mesh(mesh, LEGEND_PANEL),
        mesh,
        active,
        per_vertex,
        title,
        radius: reference_radius,
    };
    render(path, format, &fig)
}

/// Semilog-y curves of the named `columns` of `history` against its
/// "iteration" column (the row number if it has none), one colour each,
/// with a legend. Non-positive and non-finite values are skipped (the curve
/// is broken there). A column `history` lacks is an error.
pub fn plot_history(path: &Path, history: &History, columns: &[&str], title: &str) -> Result<()> {
    let format = format_of(path)?;
    let n = history
        .columns
        .iter()
        .map(|(_, c)| c.len())
        .min()
        .unwrap_or(0);
    let x: Vec<f64> = match history.column("iteration") {
        Some(it) => it[..n].to_vec(),
        None => (0..n).map(|i| i as f64).collect(),
    };
    let mut curves = Vec::with_capacity(columns.len());
    for &name in columns {
        let Some(col) = history.column(name) else {
            let known: Vec<&str> = history.columns.iter().map(|(n, _)| n.as_str()).collect();
            return Err(Error::output(
                path,
                format!(
                    "history has no column `{name}` (it has: {})",
                    known.join(", ")
                ),
            ));
        };
        let points: Vec<Option<(f64, f64)>> = x
            .iter()
            .zip(&col[..n])
            .map(|(&x, &y)| (x.is_finite() && y.is_finite() && y > 0.0).then_some((x, y)))
            .collect();
        curves.push((name.to_string(), points));
    }
    let fig = HistoryFigure {
        title,
        curves,
        x_is_integer: x.iter().all(|v| v.fract() == 0.0),
    };
    render(path, format, &fig)
}

/// Log–log curves (points and lines) of each `(name, points)` series with a
/// legend (each name followed by the least-squares slope of its points), plus
/// dashed reference lines of the given `reference_slopes`, labelled "h^p",
/// drawn from the largest x at half the lowest value of the series there
/// (so they start below the data).
/// Points with a non-positive or non-finite coordinate are skipped.
pub fn plot_convergence(
    path: &Path,
    series: &[(String, Vec<(f64, f64)>)],
    x_label: &str,
    y_label: &str,
    title: &str,
    reference_slopes: &[f64],
) -> Result<()> {
    let format = format_of(path)?;
    if let Some(p) = reference_slopes.iter().find(|p| !p.is_finite()) {
        return Err(Error::output(
            path,
            format!("reference slope {p} is not finite"),
        ));
    }
    let series = sorted_by_x(series, |x, y| {
        x.is_finite() && y.is_finite() && x > 0.0 && y > 0.0
    });
    let fig = ConvergenceFigure {
        labels: Labels {
            title,
            x: x_label,
            y: y_label,
        },
        series,
        slopes: reference_slopes,
    };
    render(path, format, &fig)
}

/// Curves on linear axes (points joined by lines), one colour each, with a legend:
/// e.g. profiles of the shell's constraint (u − ε/2 r)·e3 and of the obstacle Φ_h along a line.
///
/// Each series is sorted by x. A point with a non-finite x is skipped; one
/// with a finite x but a non-finite y breaks the curve there (as in
/// [`plot_history`]); a point that stands alone is drawn as a dot. Both
/// axes are linear: x spans the points, y has a little room above and below.
/// The legend goes to a corner of the plot where it hides no curve, else to
/// the upper right with the y range raised to make room for it. No series,
/// or none with a finite point, gives a figure with a note (not an error).
pub fn plot_lines(
    path: &Path,
    series: &[(String, Vec<(f64, f64)>)],
    x_label: &str,
    y_label: &str,
    title: &str,
) -> Result<()> {
    let format = format_of(path)?;
    let curves: Vec<Curve> = sorted_by_x(series, |x, _| x.is_finite())
        .into_iter()
        .map(|(name, pts)| {
            let pts = pts
                .into_iter()
                .map(|(x, y)| y.is_finite().then_some((x, y)));
            (name, pts.collect())
        })
        .collect();
    let fig = LinesFigure {
        labels: Labels {
            title,
            x: x_label,
            y: y_label,
        },
        curves,
    };
    render(path, format, &fig)
}

// ---------------------------------------------------------------------------
// Validation and writing
// ---------------------------------------------------------------------------

/// The points of each series that `keep` accepts, sorted by x (stably).
fn sorted_by_x(
    series: &[(String, Vec<(f64, f64)>)],
    keep: impl Fn(f64, f64) -> bool,
) -> Vec<(String, Vec<(f64, f64)>)> {
    series
        .iter()
        .map(|(name, pts)| {
            let mut pts: Vec<(f64, f64)> =
                pts.iter().copied().filter(|&(x, y)| keep(x, y)).collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            (name.clone(), pts)
        })
        .collect()
}

fn format_of(path: &Path) -> Result<Format> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .as_deref()
    {
        Some("png") => Ok(Format::Png),
        Some("svg") => Ok(Format::Svg),
        _ => Err(Error::output(
            path,
            "unsupported figure format: the file name must end in .png or .svg",
        )),
    }
}

fn check_mesh(path: &Path, mesh: &Mesh) -> Result<()> {
    if mesh.triangles.is_empty() {
        return Err(Error::output(path, "the mesh has no triangles"));
    }
    if let Some(i) = mesh
        .vertices
        .iter()
        .position(|p| !p[0].is_finite() || !p[1].is_finite())
    {
        return Err(Error::output(
            path,
            format!("mesh vertex {i} has a non-finite coordinate"),
        ));
    }
    let n = mesh.vertices.len();
    if let Some(t) = mesh
        .triangles
        .iter()
        .position(|t| t.iter().any(|&v| v >= n))
    {
        return Err(Error::output(
            path,
            format!("mesh triangle {t} refers to a vertex >= {n} (the number of vertices)"),
        ));
    }
    Ok(())
}

fn check_field(path: &Path, values: &[f64], expected: usize, kind: &str, what: &str) -> Result<()> {
    if values.len() != expected {
        return Err(Error::output(
            path,
            format!(
                "{kind} field: {} values for {expected} {what}",
                values.len()
            ),
        ));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(Error::output(
            path,
            format!(
                "{kind} field: value {} at index {i} is not finite",
                values[i]
            ),
        ));
    }
    Ok(())
}

/// Registers the embedded DejaVu Sans once per process.
fn ensure_font() -> std::result::Result<(), String> {
    static REGISTERED: std::sync::OnceLock<std::result::Result<(), String>> =
        std::sync::OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            let bad = |_| "the embedded DejaVu Sans font cannot be read".to_string();
            plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular())
                .map_err(bad)?;
            plotters::style::register_font(FONT, FontStyle::Bold, dejavu::sans::bold())
                .map_err(bad)?;
            Ok(())
        })
        .clone()
}

/// Renders `fig` into a temporary file next to `path`, then renames it over
/// `path` (mode 0644). Panics inside the drawing code become errors.
fn render<F: Figure>(path: &Path, format: Format, fig: &F) -> Result<()> {
    ensure_font().map_err(|e| Error::output(path, e))?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let suffix = match format {
        Format::Png => ".png",
        Format::Svg => ".svg",
    };
    let tmp = tempfile::Builder::new()
        .prefix(".plot-")
        .suffix(suffix)
        .tempfile_in(dir)
        .map_err(|e| {
            Error::output(
                path,
                format!("cannot create a temporary file in {}: {e}", dir.display()),
            )
        })?;
    let (w, h) = fig.size();
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| -> DrawResult {
        match format {
            Format::Png => {
                let root = BitMapBackend::new(tmp.path(), (w, h)).into_drawing_area();
                root.fill(&WHITE)?;
                fig.draw(&root, format)?;
                root.present()?;
            }
            Format::Svg => {
                let mut svg = String::new();
                {
                    let root = SVGBackend::with_string(&mut svg, (w, h)).into_drawing_area();
                    root.fill(&WHITE)?;
                    fig.draw(&root, format)?;
                    root.present()?;
                }
                let mut file = tmp.as_file();
                file.write_all(svg.as_bytes())?;
                file.flush()?;
            }
        }
        Ok(())
    }));
    match outcome {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return Err(Error::output(path, format!("cannot draw the figure: {e}"))),
        Err(panic) => {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            return Err(Error::output(
                path,
                format!("drawing the figure failed: {msg}"),
            ));
        }
    }
    crate::output::persist_readable(tmp, path)
}

// ---------------------------------------------------------------------------
// Numbers, colours, levels
// ---------------------------------------------------------------------------

/// `v` with `sig` significant digits, trailing zeros trimmed; scientific
/// notation outside [1e-3, 1e5).
fn fmt_sig(v: f64, sig: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v == 0.0 { "0".into() } else { format!("{v}") };
    }
    let e = v.abs().log10().floor() as i32;
    let trim = |s: String| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    if (-3..5).contains(&e) {
        let decimals = (sig as i32 - 1 - e).max(0) as usize;
        let s = trim(format!("{v:.decimals$}"));
        if s == "-0" {
            "0".into()
        } else {
            s
        }
    } else {
        let s = format!("{:.*e}", sig.saturating_sub(1), v);
        match s.split_once('e') {
            Some((m, ex)) => format!("{}e{ex}", trim(m.to_string())),
            None => s,
        }
    }
}

/// A linear-axis tick label: values tiny against the axis span are 0; at
/// least 4 significant digits, more where the span is small against the
/// value (so that the ticks of [1.00001, 1.00002] stay apart).
fn fmt_tick(v: f64, span: f64) -> String {
    if v.abs() <= 1e-9 * span {
        "0".into()
    } else {
        let extra = (v.abs() / span).log10().ceil();
        let sig = if extra.is_finite() {
            (extra.clamp(0.0, 15.0) as usize + 2).max(4)
        } else {
            4
        };
        fmt_sig(v, sig)
    }
}

fn superscript(n: i32) -> String {
    n.to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            '0' => '⁰',
            '1' => '¹',
            '2' => '²',
            '3' => '³',
            '4' => '⁴',
            '5' => '⁵',
            '6' => '⁶',
            '7' => '⁷',
            '8' => '⁸',
            _ => '⁹',
        })
        .collect()
}

/// A log-axis tick label: decades as 10ⁿ, other ticks as plain numbers.
fn fmt_log_tick(v: f64) -> String {
    if v <= 0.0 || !v.is_finite() {
        return String::new();
    }
    let l = v.log10();
    let k = l.round();
    if (l - k).abs() < 1e-6 {
        format!("10{}", superscript(k as i32))
    } else {
        fmt_sig(v, 2)
    }
}

/// Ticks of a log axis over [lo, hi]: labelled ("bold") ones — decades
/// (every few decades on long axes), plus 2 and 5 on axes shorter than two
/// decades, plus every digit on axes shorter than one — and grid-only
/// ("light") ones at every digit of every decade.
fn log_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let span = (hi / lo).log10();
    let (k0, k1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let every = (span / 10.0).ceil().max(1.0) as i32;
    let digits: &[f64] = if span < 1.0 {
        &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    } else if span < 2.0 {
        &[1.0, 2.0, 5.0]
    } else {
        &[1.0]
    };
    let inside = |v: &f64| *v >= lo * (1.0 - 1e-9) && *v <= hi * (1.0 + 1e-9);
    let mut bold = Vec::new();
    let mut light = Vec::new();
    for k in k0..=k1 {
        let p = 10f64.powi(k);
        if k.rem_euclid(every) == 0 {
            bold.extend(digits.iter().map(|d| d * p).filter(inside));
        }
        if span <= 12.0 {
            light.extend((1..10).map(|d| d as f64 * p).filter(inside));
        } else if inside(&p) {
            light.push(p);
        }
    }
    (bold, light)
}

/// Log-axis range around [min, max] (both > 0), padded by a little.
fn log_range(min: f64, max: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (min.log10(), max.log10());
    if hi - lo < 0.3 {
        let mid = 0.5 * (hi + lo);
        lo = mid - 0.15;
        hi = mid + 0.15;
    }
    let pad = 0.05 * (hi - lo) + 0.05;
    (10f64.powf(lo - pad), 10f64.powf(hi + pad))
}

/// Range of the colour map: [min, max] of the values, widened if constant.
fn display_range(values: &[f64]) -> (f64, f64) {
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if hi > lo {
        (lo, hi)
    } else {
        let d = if lo == 0.0 { 1.0 } else { 0.5 * lo.abs() };
        (lo - d, lo + d)
    }
}

fn colour(v: f64, lo: f64, hi: f64) -> RGBColor {
    let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
    ViridisRGB::get_color(t)
}

/// A "nice" step (1, 2, 2.5 or 5 times a power of ten) near `raw`.
fn nice_step(raw: f64) -> f64 {
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    let n = if m < 1.5 {
        1.0
    } else if m < 2.25 {
        2.0
    } else if m < 3.5 {
        2.5
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    };
    n * p
}

/// About `target` round levels strictly inside (lo, hi).
fn iso_levels(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    let span = hi - lo;
    if !span.is_finite() || span <= 0.0 {
        return Vec::new();
    }
    let step = nice_step(span / target as f64);
    let mut k = (lo / step).floor();
    let mut levels = Vec::new();
    while levels.len() < 4 * target {
        let c = k * step;
        k += 1.0;
        if c <= lo + 1e-9 * span {
            continue;
        }
        if c >= hi - 1e-9 * span {
            break;
        }
        levels.push(c);
    }
    levels
}

/// Isolines of the P1 field at `level` (marching triangles), chained into
/// polylines. A vertex counts as above when its value is > level, so every
/// crossed edge has a well-defined crossing point, computed the same way
/// from either triangle.
fn isolines(mesh: &Mesh, values: &[f64], level: f64) -> Vec<Vec<(f64, f64)>> {
    let mut segments: Vec<[[usize; 2]; 2]> = Vec::new();
    for t in &mesh.triangles {
        let above = t.map(|v| values[v] > level);
        let mut crossed = [[0usize; 2]; 2];
        let mut n = 0;
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            if above[i] != above[j] && n < 2 {
                let (a, b) = (t[i].min(t[j]), t[i].max(t[j]));
                crossed[n] = [a, b];
                n += 1;
            }
        }
        if n == 2 {
            segments.push(crossed);
        }
    }
    let point = |[a, b]: [usize; 2]| -> (f64, f64) {
        let s = (level - values[a]) / (values[b] - values[a]);
        let (pa, pb) = (mesh.vertices[a], mesh.vertices[b]);
        (pa[0] + s * (pb[0] - pa[0]), pa[1] + s * (pb[1] - pa[1]))
    };
    let mut by_edge: HashMap<[usize; 2], Vec<usize>> = HashMap::new();
    for (s, seg) in segments.iter().enumerate() {
        for e in seg {
            by_edge.entry(*e).or_default().push(s);
        }
    }
    let mut used = vec![false; segments.len()];
    let mut lines = Vec::new();
    for start in 0..segments.len() {
        if used[start] {
            continue;
        }
        used[start] = true;
        let mut chain = std::collections::VecDeque::from(segments[start].to_vec());
        for forward in [true, false] {
            loop {
                let end = if forward {
                    chain[chain.len() - 1]
                } else {
                    chain[0]
                };
                let next = by_edge
                    .get(&end)
                    .and_then(|ss| ss.iter().copied().find(|&s| !used[s]));
                let Some(s) = next else { break };
                used[s] = true;
                let other = if segments[s][0] == end {
                    segments[s][1]
                } else {
                    segments[s][0]
                };
                if forward {
                    chain.push_back(other);
                } else {
                    chain.push_front(other);
                }
            }
        }
        lines.push(chain.into_iter().map(point).collect());
    }
    lines
}

/// The part of segment p–q inside the rectangle [x0, x1] × [y0, y1]
/// (Liang–Barsky), with flags telling whether each end was cut.
fn clip_segment(
    p: (f64, f64),
    q: (f64, f64),
    (x0, x1, y0, y1): (f64, f64, f64, f64),
) -> Option<Clipped> {
    let (dx, dy) = (q.0 - p.0, q.1 - p.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (pk, qk) in [
        (-dx, p.0 - x0),
        (dx, x1 - p.0),
        (-dy, p.1 - y0),
        (dy, y1 - p.1),
    ] {
        if pk == 0.0 {
            if qk < 0.0 {
                return None;
            }
        } else {
            let r = qk / pk;
            if pk < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    let at = |t: f64| (p.0 + t * dx, p.1 + t * dy);
    Some((at(t0), at(t1), t0 > 0.0, t1 < 1.0))
}

/// All edges of the triangles, each once, with the number of triangles
/// sharing it (1 on the boundary).
fn mesh_edges(mesh: &Mesh) -> Vec<([usize; 2], usize)> {
    let mut edges: Vec<[usize; 2]> = mesh
        .triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| [a.min(b), a.max(b)])
        .collect();
    edges.sort_unstable();
    let mut counted: Vec<([usize; 2], usize)> = Vec::with_capacity(edges.len() / 2 + 1);
    for e in edges {
        match counted.last_mut() {
            Some((last, n)) if *last == e => *n += 1,
            _ => counted.push((e, 1)),
        }
    }
    counted
}

/// The typical edge length of the mesh's triangles in pixels of `chart`
/// (that of a right isosceles triangle of the mean area).
fn typical_edge_px<DB: DrawingBackend>(mesh: &Mesh, chart: &Chart2d<'_, DB>) -> f64 {
    let nt = mesh.triangles.len().max(1);
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| mesh.vertices[v]);
            0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])).abs()
        })
        .sum();
    let x = chart.x_range();
    let px_per_unit = chart.plotting_area().dim_in_pixel().0 as f64 / (x.end - x.start);
    (2.0 * area / nt as f64).sqrt() * px_per_unit
}

fn pt(p: [f64; 2]) -> (f64, f64) {
    (p[0], p[1])
}

// ---------------------------------------------------------------------------
// Shared drawing pieces
// ---------------------------------------------------------------------------

fn text_style(size: f64, pos: Pos) -> TextStyle<'static> {
    TextStyle::from((FONT, size).into_font()).pos(pos)
}

/// The title, centred in `area`, shrunk to fit its width.
fn draw_title<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, title: &str) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let (w, h) = area.dim_in_pixel();
    let mut size = 24.0;
    let pos = Pos::new(HPos::Center, VPos::Center);
    loop {
        let style = TextStyle::from((FONT, size, FontStyle::Bold).into_font()).pos(pos);
        let (tw, _) = area.estimate_text_size(title, &style)?;
        if tw + 20 <= w || size <= 11.0 {
            area.draw(&Text::new(
                title.to_string(),
                ((w / 2) as i32, (h / 2 + 2) as i32),
                style,
            ))?;
            return Ok(());
        }
        size -= 1.0;
    }
}

/// Pixel layout of a mesh figure: a title row, the mesh plot (equal
/// aspect ratio) and a side panel of `side` pixels on the right.
struct Frame {
    /// Bounding box of the mesh, padded: x range, y range.
    x: (f64, f64),
    y: (f64, f64),
    width: u32,
    height: u32,
    side: u32,
}

impl Frame {
    fn for_mesh(mesh: &Mesh, side: u32) -> Frame {
        let (mut x0, mut x1, mut y0, mut y1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for t in &mesh.triangles {
            for &v in t {
                let [x, y] = mesh.vertices[v];
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
        let (mut dx, mut dy) = (x1 - x0, y1 - y0);
        let usable = |d: f64| d.is_finite() && d > 0.0;
        if !usable(dx) && !usable(dy) {
            dx = 1.0;
            dy = 1.0;
        } else if !usable(dx) {
            dx = dy;
        } else if !usable(dy) {
            dy = dx;
        }
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let pad = 0.03 * dx.max(dy);
        let (dx, dy) = (dx + 2.0 * pad, dy + 2.0 * pad);
        let main_w = FIG_W - side;
        let mut pw = (main_w - 2 * MARGIN - Y_LABEL_AREA) as f64;
        let mut ph = pw * dy / dx;
        if ph > MAX_PLOT_H {
            ph = MAX_PLOT_H;
            pw = (ph * dx / dy).max(MIN_PLOT_W);
        }
        let ph = ph.max(MIN_PLOT_H);
        Frame {
            x: (cx - 0.5 * dx, cx + 0.5 * dx),
            y: (cy - 0.5 * dy, cy + 0.5 * dy),
            width: pw.round() as u32 + 2 * MARGIN + Y_LABEL_AREA + side,
            height: TITLE_H + ph.round() as u32 + 2 * MARGIN + X_LABEL_AREA,
            side,
        }
    }

    /// Splits the figure into the title row (drawn), the main area and the
    /// side panel.
    fn split<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        title: &str,
    ) -> DrawResult<(DrawingArea<DB, Shift>, DrawingArea<DB, Shift>)>
    where
        DB::ErrorType: 'static,
    {
        let (title_area, rest) = root.split_vertically(TITLE_H);
        draw_title(&title_area, title)?;
        let (w, _) = rest.dim_in_pixel();
        Ok(rest.split_horizontally(w.saturating_sub(self.side)))
    }

    /// The mesh chart on `main` with equal scales on both axes (the data
    /// ranges are widened to the pixel aspect ratio), axes drawn.
    fn chart<'a, DB: DrawingBackend>(
        &self,
        main: &'a DrawingArea<DB, Shift>,
    ) -> DrawResult<Chart2d<'a, DB>>
    where
        DB::ErrorType: 'static,
    {
        let builder = |area| {
            let mut b = ChartBuilder::on(area);
            b.margin(MARGIN)
                .x_label_area_size(X_LABEL_AREA)
                .y_label_area_size(Y_LABEL_AREA);
            b
        };
        let (pw, ph) = builder(main)
            .build_cartesian_2d(0.0..1.0, 0.0..1.0)?
            .plotting_area()
            .dim_in_pixel();
        let (pw, ph) = (pw.max(1) as f64, ph.max(1) as f64);
        let (dx, dy) = (self.x.1 - self.x.0, self.y.1 - self.y.0);
        let scale = (pw / dx).min(ph / dy);
        let (hx, hy) = (0.5 * pw / scale, 0.5 * ph / scale);
        let (cx, cy) = (0.5 * (self.x.0 + self.x.1), 0.5 * (self.y.0 + self.y.1));
        let mut chart = builder(main).build_cartesian_2d(cx - hx..cx + hx, cy - hy..cy + hy)?;
        let (sx, sy) = (2.0 * hx, 2.0 * hy);
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("x")
            .y_desc("y")
            .x_labels(8)
            .y_labels(8)
            .label_style((FONT, 17))
            .axis_desc_style((FONT, 20))
            .x_label_formatter(&|v| fmt_tick(*v, sx))
            .y_label_formatter(&|v| fmt_tick(*v, sy))
            .draw()?;
        Ok(chart)
    }
}

/// A vertical colour bar in the side panel, aligned with the plot (whose
/// vertical pixel extent in the panel is `top..bottom`), with tick labels,
/// its min and max, and the isoline levels marked.
fn draw_colour_bar<DB: DrawingBackend>(
    panel: &DrawingArea<DB, Shift>,
    top: i32,
    bottom: i32,
    (lo, hi): (f64, f64),
    (vmin, vmax): (f64, f64),
    levels: &[f64],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    const LEFT: i32 = 14;
    const BAR_W: i32 = 26;
    const TICKS_W: i32 = 80;
    let (w, h) = panel.dim_in_pixel();
    let (w, h) = (w as i32, h as i32);
    let bar_top = top + 34;
    let bar_bottom = (bottom - 34).max(bar_top + 40);
    let area = panel.margin(
        bar_top,
        (h - bar_bottom).max(0),
        LEFT,
        (w - LEFT - BAR_W - TICKS_W).max(0),
    );
    let mut chart = ChartBuilder::on(&area)
        .right_y_label_area_size(TICKS_W)
        .build_cartesian_2d(0.0..1.0, lo..hi)?;
    const STRIPS: usize = 256;
    chart.draw_series((0..STRIPS).map(|k| {
        let a = lo + (hi - lo) * k as f64 / STRIPS as f64;
        let b = lo + (hi - lo) * (k + 1) as f64 / STRIPS as f64;
        let c = ViridisRGB::get_color((k as f64 + 0.5) / STRIPS as f64);
        Rectangle::new([(0.0, a), (1.0, b)], c.filled())
    }))?;
    chart.draw_series(
        levels
            .iter()
            .map(|&l| PathElement::new(vec![(0.0, l), (1.0, l)], BLACK.stroke_width(1))),
    )?;
    chart.draw_series(std::iter::once(Rectangle::new(
        [(0.0, lo), (1.0, hi)],
        BLACK.stroke_width(1),
    )))?;
    let span = hi - lo;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .set_all_tick_mark_size(6)
        .y_labels(7)
        .label_style((FONT, 16))
        .y_label_formatter(&|v| fmt_tick(*v, span))
        .draw()?;
    let small = |pos| text_style(16.0, pos);
    panel.draw(&Text::new(
        format!("max {}", fmt_sig(vmax, 4)),
        (LEFT, bar_top - 10),
        small(Pos::new(HPos::Left, VPos::Bottom)),
    ))?;
    panel.draw(&Text::new(
        format!("min {}", fmt_sig(vmin, 4)),
        (LEFT, bar_bottom + 10),
        small(Pos::new(HPos::Left, VPos::Top)),
    ))?;
    Ok(())
}

/// Draws a polyline as runs along which x does not decrease: plotters'
/// bitmap backend drops the end pixels of a horizontal 1-pixel segment drawn
/// from right to left, which leaves gaps in curves.
fn draw_polyline<DB: DrawingBackend>(
    area: &DrawingArea<DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    points: &[(f64, f64)],
    style: ShapeStyle,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let flush = |run: &mut Vec<(f64, f64)>, forward: bool| -> DrawResult {
        if run.len() >= 2 {
            if !forward {
                run.reverse();
            }
            area.draw(&PathElement::new(std::mem::take(run), style))?;
        }
        run.clear();
        Ok(())
    };
    let mut run: Vec<(f64, f64)> = Vec::new();
    let mut forward = true;
    for &p in points {
        if let Some(&last) = run.last() {
            let step_forward = p.0 >= last.0;
            if run.len() == 1 {
                forward = step_forward;
            } else if step_forward != forward {
                flush(&mut run, forward)?;
                run.push(last);
                forward = step_forward;
            }
        }
        run.push(p);
    }
    flush(&mut run, forward)
}

/// A filled triangle, outlined in its own colour so that neighbours leave
/// no hairline gaps between them.
fn fill_triangle<DB: DrawingBackend>(
    area: &DrawingArea<DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    p: [(f64, f64); 3],
    c: RGBColor,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    area.draw(&Polygon::new(p.to_vec(), c.filled()))?;
    area.draw(&PathElement::new(
        vec![p[0], p[1], p[2], p[0]],
        c.stroke_width(1),
    ))?;
    Ok(())
}

// ---------------------------------------------------------------------------
// Figures
// ---------------------------------------------------------------------------

struct FieldFigure<'a> {
    frame: Frame,
    mesh: &'a Mesh,
    values: &'a [f64],
    per_vertex: bool,
    title: &'a str,
    lo: f64,
    hi: f64,
    levels: Vec<f64>,
}

impl FieldFigure<'_> {
    /// Sub-triangles per triangle edge: about `SUBTRIANGLE_PX_*` pixels
    /// each, within the budget.
    fn subdivisions(&self, format: Format, edge_px: f64) -> usize {
        let nt = self.mesh.triangles.len();
        let (budget, target_px) = match format {
            Format::Png => (SUBTRIANGLE_BUDGET_PNG, SUBTRIANGLE_PX_PNG),
            Format::Svg => (SUBTRIANGLE_BUDGET_SVG, SUBTRIANGLE_PX_SVG),
        };
        let mut n = ((edge_px / target_px).ceil() as usize).clamp(1, 16);
        while n > 1 && n * n * nt > budget {
            n -= 1;
        }
        n
    }
}

impl Figure for FieldFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (self.frame.width, self.frame.height)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, format: Format) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        let (main, side) = self.frame.split(root, self.title)?;
        let chart = self.frame.chart(&main)?;
        let area = chart.plotting_area();
        let (lo, hi) = (self.lo, self.hi);
        let mesh = self.mesh;
        if self.per_vertex {
            let n = self.subdivisions(format, typical_edge_px(mesh, &chart));
            let nf = n as f64;
            for t in &mesh.triangles {
                let p = t.map(|v| mesh.vertices[v]);
                let v = t.map(|v| self.values[v]);
                let lattice = |i: usize, j: usize| {
                    let (a, b) = (i as f64 / nf, j as f64 / nf);
                    let w = 1.0 - a - b;
                    (
                        (
                            w * p[0][0] + a * p[1][0] + b * p[2][0],
                            w * p[0][1] + a * p[1][1] + b * p[2][1],
                        ),
                        w * v[0] + a * v[1] + b * v[2],
                    )
                };
                for j in 0..n {
                    for i in 0..n - j {
                        let mut subs = vec![[(i, j), (i + 1, j), (i, j + 1)]];
                        if i + j + 2 <= n {
                            subs.push([(i + 1, j), (i + 1, j + 1), (i, j + 1)]);
                        }
                        for s in subs {
                            let c = s.map(|(i, j)| lattice(i, j));
                            let mean = (c[0].1 + c[1].1 + c[2].1) / 3.0;
                            fill_triangle(area, c.map(|c| c.0), colour(mean, lo, hi))?;
                        }
                    }
                }
            }
            for &level in &self.levels {
                for line in isolines(mesh, self.values, level) {
                    draw_polyline(area, &line, BLACK.stroke_width(1))?;
                }
            }
        } else {
            for (t, &v) in mesh.triangles.iter().zip(self.values) {
                fill_triangle(area, t.map(|v| pt(mesh.vertices[v])), colour(v, lo, hi))?;
            }
        }
        let vmin = self.values.iter().copied().fold(f64::INFINITY, f64::min);
        let vmax = self
            .values
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let (_, ph) = area.dim_in_pixel();
        draw_colour_bar(
            &side,
            MARGIN as i32,
            (MARGIN + ph) as i32,
            (lo, hi),
            (vmin, vmax),
            &self.levels,
        )
    }
}

/// The symbol of a legend line of the contact figure.
enum Key {
    /// Text only.
    Heading,
    /// A filled square, indented by so many pixels.
    Swatch(RGBColor, i32),
    Dot(RGBColor),
    /// A line of that width.
    Line(RGBColor, u32),
}

struct ContactFigure<'a> {
    frame: Frame,
    mesh: &'a Mesh,
    active: &'a [bool],
    per_vertex: bool,
    title: &'a str,
    radius: Option<f64>,
}

impl Figure for ContactFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (self.frame.width, self.frame.height)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, _format: Format) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        let strong = RGBColor(49, 130, 189);
        let light = RGBColor(189, 215, 238);
        let dot = RGBColor(8, 48, 107);
        let grey = RGBColor(185, 185, 185);
        let red = RGBColor(215, 25, 28);
        let (main, side) = self.frame.split(root, self.title)?;
        let chart = self.frame.chart(&main)?;
        let area = chart.plotting_area();
        let mesh = self.mesh;
        let tri = |t: &[usize; 3]| t.map(|v| pt(mesh.vertices[v]));
        let mut legend: Vec<(Key, String)> = Vec::new();
        if self.per_vertex {
            let (mut touching, mut full) = (0, 0);
            for t in &mesh.triangles {
                let k = t.iter().filter(|&&v| self.active[v]).count();
                if k == 3 {
                    full += 1;
                    fill_triangle(area, tri(t), strong)?;
                } else if k > 0 {
                    touching += 1;
                    fill_triangle(area, tri(t), light)?;
                }
            }
            legend.push((Key::Heading, "triangles with".into()));
            legend.push((
                Key::Swatch(strong, 16),
                format!("3 active vertices ({full})"),
            ));
            legend.push((
                Key::Swatch(light, 16),
                format!("1–2 active vertices ({touching})"),
            ));
        } else {
            let mut count = 0;
            for (t, _) in mesh.triangles.iter().zip(self.active).filter(|(_, &a)| a) {
                count += 1;
                fill_triangle(area, tri(t), strong)?;
            }
            legend.push((
                Key::Swatch(strong, 0),
                format!("contact triangles ({count})"),
            ));
        }
        // Edges and dots only where they stay apart; else the outline.
        let edge_px = typical_edge_px(mesh, &chart);
        let all_edges = edge_px >= MIN_EDGE_PX;
        for ([a, b], n) in mesh_edges(mesh) {
            if all_edges || n == 1 {
                let edge = [pt(mesh.vertices[a]), pt(mesh.vertices[b])];
                draw_polyline(area, &edge, grey.stroke_width(1))?;
            }
        }
        let edges_label = if all_edges {
            "mesh edges"
        } else {
            "mesh boundary"
        };
        legend.push((Key::Line(grey, 1), edges_label.into()));
        if self.per_vertex && edge_px >= MIN_DOT_SPACING_PX {
            let n_active = self.active.iter().filter(|&&a| a).count();
            for (p, _) in mesh.vertices.iter().zip(self.active).filter(|(_, &a)| a) {
                area.draw(&Circle::new(pt(*p), 2, dot.filled()))?;
            }
            legend.insert(
                legend.len() - 1,
                (Key::Dot(dot), format!("active vertices ({n_active})")),
            );
        }
        if let Some(r) = self.radius.filter(|&r| r > 0.0) {
            let (xr, yr) = (chart.x_range(), chart.y_range());
            let rect = (xr.start, xr.end, yr.start, yr.end);
            const N: usize = 720;
            let on_circle = |k: usize| {
                let a = std::f64::consts::TAU * k as f64 / N as f64;
                (r * a.cos(), r * a.sin())
            };
            let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
            let mut open = false;
            for k in 0..N {
                match clip_segment(on_circle(k), on_circle(k + 1), rect) {
                    Some((p, q, cut_start, cut_end)) => {
                        if !open || cut_start {
                            runs.push(vec![p]);
                        }
                        if let Some(run) = runs.last_mut() {
                            run.push(q);
                        }
                        open = !cut_end;
                    }
                    None => open = false,
                }
            }
            for run in runs {
                draw_polyline(area, &run, red.stroke_width(2))?;
            }
            legend.push((
                Key::Line(red, 2),
                format!("exact contact circle, r = {}", fmt_sig(r, 4)),
            ));
        }
        // Legend panel, aligned with the top of the plot.
        let style = text_style(17.0, Pos::new(HPos::Left, VPos::Center));
        let mut y = MARGIN as i32 + 14;
        for (key, label) in legend {
            let (x0, x1) = (12, 36);
            let indent = match key {
                Key::Heading => 0,
                Key::Swatch(c, indent) => {
                    side.draw(&Rectangle::new(
                        [(x0 + indent, y - 7), (x1 + indent, y + 7)],
                        c.filled(),
                    ))?;
                    indent
                }
                Key::Dot(c) => {
                    side.draw(&Circle::new(((x0 + x1) / 2, y), 3, c.filled()))?;
                    0
                }
                Key::Line(c, w) => {
                    side.draw(&PathElement::new(vec![(x0, y), (x1, y)], c.stroke_width(w)))?;
                    0
                }
            };
            let x = if matches!(key, Key::Heading) {
                x0
            } else {
                x1 + 8 + indent
            };
            side.draw(&Text::new(label, (x, y), style.clone()))?;
            y += 28;
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------
// Curve figures (history, convergence, lines): shared pieces
// ---------------------------------------------------------------------------

/// Size of the history and line figures, in pixels.
const CURVE_FIG: (u32, u32) = (960, 600);
/// Right margin of a curve chart (room for the last x tick label).
const CURVE_MARGIN_RIGHT: u32 = 28;
/// Font size of the tick labels of a curve chart, and how many labelled
/// ticks its y axis has at most (plotters' default).
const TICK_FONT: f64 = 17.0;
const Y_TICKS: usize = 11;
/// Font size of the legend's labels and a legend's layout in plotters:
/// the key area left of the labels, the margin inside the box and the gap
/// between the box and the plot's edge.
const LEGEND_FONT: f64 = 17.0;
const LEGEND_KEY: u32 = 30;
const LEGEND_MARGIN: u32 = 12;
const LEGEND_GAP: u32 = 5;

/// Title and axis descriptions of a curve figure.
struct Labels<'a> {
    title: &'a str,
    x: &'a str,
    y: &'a str,
}

/// Tick label formatters of the x and y axes.
type TickFormats<'f> = (&'f dyn Fn(&f64) -> String, &'f dyn Fn(&f64) -> String);

/// The title row and, below it, a chart over `x` × `y` with the margins,
/// light grid, axis descriptions and tick labels the curve figures share.
fn curve_chart<'c, DB, X, Y>(
    root: &DrawingArea<DB, Shift>,
    labels: &Labels<'_>,
    x: X,
    y: Y,
    (x_format, y_format): TickFormats<'_>,
) -> DrawResult<Chart2d<'c, DB, X::CoordDescType, Y::CoordDescType>>
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let y = Y::CoordDescType::from(y);
    let y_area = y_label_area(root, &y, y_format)?;
    let (title_area, main) = root.split_vertically(TITLE_H);
    draw_title(&title_area, labels.title)?;
    let mut chart = ChartBuilder::on(&main)
        .margin(MARGIN)
        .margin_right(CURVE_MARGIN_RIGHT)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(y_area)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .y_labels(Y_TICKS)
        .x_desc(labels.x)
        .y_desc(labels.y)
        .label_style((FONT, TICK_FONT))
        .axis_desc_style((FONT, 20))
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(BLACK.mix(0.04))
        .x_label_formatter(x_format)
        .y_label_formatter(y_format)
        .draw()?;
    Ok(chart)
}

/// Width in pixels of the label area left of a curve chart's y axis `y`:
/// [`Y_LABEL_AREA`], or more if the tick labels need it.
fn y_label_area<DB, Y>(
    root: &DrawingArea<DB, Shift>,
    y: &Y,
    y_format: &dyn Fn(&f64) -> String,
) -> DrawResult<u32>
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
    Y: Ranged<ValueType = f64>,
{
    let style = TextStyle::from((FONT, TICK_FONT).into_font());
    let mut widest = 0;
    for v in y.key_points(BoldPoints(Y_TICKS)) {
        widest = widest.max(root.estimate_text_size(&y_format(&v), &style)?.0);
    }
    // Room for the tick marks and the axis description beside the labels.
    Ok(Y_LABEL_AREA.max(widest + 40))
}

/// Width and height in pixels of the plot that [`curve_chart`] lays out on
/// `root` with a y label area of `y_area` pixels.
fn curve_plot_px<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, y_area: u32) -> (f64, f64) {
    let (w, h) = root.dim_in_pixel();
    let w = w.saturating_sub(MARGIN + CURVE_MARGIN_RIGHT + y_area);
    let h = h.saturating_sub(TITLE_H + 2 * MARGIN + X_LABEL_AREA);
    (w.max(1) as f64, h.max(1) as f64)
}

/// The legend label of a curve: its name, followed by `no_point` if it has
/// no point at all.
fn curve_label(name: &str, points: &[Option<(f64, f64)>], no_point: &str) -> String {
    if points.iter().all(Option::is_none) {
        format!("{name} ({no_point})")
    } else {
        name.to_string()
    }
}

/// Width and height in pixels of the legend [`finish_chart`] draws for
/// `curves` (labelled as [`draw_curves`] does), with its gap to the plot's edge.
fn legend_px<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    curves: &[Curve],
    no_point: &str,
) -> DrawResult<(f64, f64)>
where
    DB::ErrorType: 'static,
{
    let style = TextStyle::from((FONT, LEGEND_FONT).into_font());
    let mut text_w = 0;
    for (name, pts) in curves {
        text_w = text_w.max(
            root.estimate_text_size(&curve_label(name, pts, no_point), &style)?
                .0,
        );
    }
    let lines = curves.len().max(1) as f64;
    let text_h = LEGEND_FONT * (1.25 * (lines - 1.0) + 1.2);
    let frame = (2 * LEGEND_MARGIN + LEGEND_GAP) as f64;
    Ok(((text_w + LEGEND_KEY) as f64 + frame, text_h + frame))
}

/// The runs of a curve between its gaps.
fn curve_runs(points: &[Option<(f64, f64)>]) -> impl Iterator<Item = Vec<(f64, f64)>> + '_ {
    points
        .split(|p| p.is_none())
        .filter(|r| !r.is_empty())
        .map(|r| r.iter().flatten().copied().collect())
}

/// Each curve in its palette colour, broken at its gaps, with the points
/// that stand alone as dots, and its [`curve_label`] in the legend.
fn draw_curves<DB, CT>(
    chart: &mut ChartContext<'_, DB, CT>,
    curves: &[Curve],
    no_point: &str,
) -> DrawResult
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
    CT: CoordTranslate<From = (f64, f64)>,
{
    for (k, (name, pts)) in curves.iter().enumerate() {
        let c = PALETTE[k % PALETTE.len()];
        let style = c.stroke_width(2);
        let runs: Vec<Vec<(f64, f64)>> = curve_runs(pts).collect();
        let isolated: Vec<(f64, f64)> =
            runs.iter().filter(|r| r.len() == 1).map(|r| r[0]).collect();
        let label = curve_label(name, pts, no_point);
        chart
            .draw_series(runs.into_iter().map(|r| PathElement::new(r, style)))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], style));
        chart.draw_series(isolated.into_iter().map(|p| Circle::new(p, 3, c.filled())))?;
    }
    Ok(())
}

/// (x_min, x_max, y_min, y_max) of points; x_min > x_max when there are none.
fn bounding_box(points: impl Iterator<Item = (f64, f64)>) -> (f64, f64, f64, f64) {
    points.fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(x0, x1, y0, y1), (x, y)| (x0.min(x), x1.max(x), y0.min(y), y1.max(y)),
    )
}

/// Whether the curves have no point, and the [`bounding_box`] of their
/// points (`fallback` if they have none).
fn curves_box(curves: &[Curve], fallback: (f64, f64, f64, f64)) -> (bool, (f64, f64, f64, f64)) {
    let bounds = bounding_box(curves.iter().flat_map(|(_, p)| p.iter().flatten()).copied());
    let empty = bounds.0 > bounds.1;
    (empty, if empty { fallback } else { bounds })
}

/// Linear-axis range around [min, max] (finite), widened if a point, padded
/// by `pad` times its length on both sides; always finite.
fn linear_range(min: f64, max: f64, pad: f64) -> (f64, f64) {
    let (lo, hi) = display_range(&[min, max]);
    // Halved first so that no difference overflows near ±f64::MAX.
    let half = 0.5 * hi - 0.5 * lo;
    let mid = 0.5 * lo + 0.5 * hi;
    let half = (half * (1.0 + 2.0 * pad)).min(f64::MAX / 2.0);
    ((mid - half).max(f64::MIN), (mid + half).min(f64::MAX))
}

/// The corner of the plot over `x` × `y` where a legend covering the
/// fraction `(fx, fy)` of its width and height hides the fewest points of the
/// curves (sampled along their segments), the upper right on a tie; and how
/// many it hides there.
fn quiet_corner(
    curves: &[Curve],
    x: (f64, f64),
    y: (f64, f64),
    (fx, fy): (f64, f64),
) -> (SeriesLabelPosition, usize) {
    const SAMPLES: usize = 8;
    let unit = |v: f64, (lo, hi): (f64, f64)| (v - lo) / (hi - lo);
    let mut hidden = [0usize; 4];
    let mut count = |(px, py): (f64, f64)| {
        let (u, v) = (unit(px, x), unit(py, y));
        let (right, left, top, bottom) = (u >= 1.0 - fx, u <= fx, v >= 1.0 - fy, v <= fy);
        for (k, inside) in [right && top, left && top, right && bottom, left && bottom]
            .into_iter()
            .enumerate()
        {
            hidden[k] += usize::from(inside);
        }
    };
    for (_, pts) in curves {
        for run in curve_runs(pts) {
            count(run[0]);
            for w in run.windows(2) {
                let (a, b) = (w[0], w[1]);
                for s in 1..=SAMPLES {
                    let t = s as f64 / SAMPLES as f64;
                    count((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
                }
            }
        }
    }
    let corners = [
        SeriesLabelPosition::UpperRight,
        SeriesLabelPosition::UpperLeft,
        SeriesLabelPosition::LowerRight,
        SeriesLabelPosition::LowerLeft,
    ];
    let best = (0..4).min_by_key(|&k| hidden[k]).unwrap_or(0);
    (corners[best].clone(), hidden[best])
}

/// The legend (where given) and, on an empty chart, a note in its middle.
fn finish_chart<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    root: &DrawingArea<DB, Shift>,
    legend: Option<SeriesLabelPosition>,
    empty_note: Option<&str>,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    if let Some(position) = legend {
        chart
            .configure_series_labels()
            .position(position)
            .margin(LEGEND_MARGIN)
            .legend_area_size(LEGEND_KEY)
            .label_font((FONT, LEGEND_FONT))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()?;
    }
    if let Some(note) = empty_note {
        let (w, h) = chart.plotting_area().dim_in_pixel();
        let (bx, by) = chart.plotting_area().get_base_pixel();
        root.draw(&Text::new(
            note,
            (bx + w as i32 / 2, by + h as i32 / 2),
            text_style(18.0, Pos::new(HPos::Center, VPos::Center)),
        ))?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Curve figures
// ---------------------------------------------------------------------------

struct HistoryFigure<'a> {
    title: &'a str,
    curves: Vec<Curve>,
    x_is_integer: bool,
}

impl Figure for HistoryFigure<'_> {
    fn size(&self) -> (u32, u32) {
        CURVE_FIG
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, _format: Format) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        let (empty, (mut x0, mut x1, y0, y1)) = curves_box(&self.curves, (0.0, 1.0, 1e-3, 1.0));
        if x1 <= x0 {
            x0 -= 1.0;
            x1 += 1.0;
        }
        let (ylo, yhi) = log_range(y0, y1);
        let (y_bold, y_light) = log_ticks(ylo, yhi);
        let span = x1 - x0;
        let integer = self.x_is_integer;
        let labels = Labels {
            title: self.title,
            x: "iteration",
            y: "value (log scale)",
        };
        let x_format = |v: &f64| {
            if integer && v.fract() != 0.0 {
                String::new()
            } else {
                fmt_tick(*v, span)
            }
        };
        let mut chart = curve_chart(
            root,
            &labels,
            x0..x1,
            (ylo..yhi)
                .log_scale()
                .with_key_points(y_bold)
                .with_light_points(y_light),
            (&x_format, &|v| fmt_log_tick(*v)),
        )?;
        draw_curves(&mut chart, &self.curves, "no positive value")?;
        finish_chart(
            &mut chart,
            root,
            (!self.curves.is_empty()).then_some(SeriesLabelPosition::UpperRight),
            empty.then_some("no positive value to plot"),
        )
    }
}

struct ConvergenceFigure<'a> {
    labels: Labels<'a>,
    series: Vec<(String, Vec<(f64, f64)>)>,
    slopes: &'a [f64],
}

/// Least-squares slope of log y against log x over the points with positive
/// finite coordinates (None for fewer than two distinct x): the fitted rate of
/// a convergence curve.
pub fn loglog_slope(pts: &[(f64, f64)]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = pts
        .iter()
        .copied()
        .filter(|&(x, y)| x.is_finite() && y.is_finite() && x > 0.0 && y > 0.0)
        .collect();
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let (mx, my) = pts.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
        (a + x.ln() / n, b + y.ln() / n)
    });
    let (sxy, sxx) = pts.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
        let dx = x.ln() - mx;
        (a + dx * (y.ln() - my), b + dx * dx)
    });
    (sxx > 1e-300).then(|| sxy / sxx)
}

fn slope_label(p: f64) -> String {
    if p.fract() == 0.0 {
        format!("h^{}", p as i64)
    } else {
        format!("h^{}", fmt_sig(p, 3))
    }
}

impl Figure for ConvergenceFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (900, 680)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, _format: Format) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        let (mut x0, mut x1, mut y0, mut y1) =
            bounding_box(self.series.iter().flat_map(|(_, p)| p).copied());
        let empty = x0 > x1;
        if empty {
            (x0, x1, y0, y1) = (0.1, 1.0, 0.1, 1.0);
        }
        // The reference lines start at the largest x, at half the lowest of
        // the series' values at their largest x: below the data there.
        let anchor = self
            .series
            .iter()
            .filter_map(|(_, p)| p.last())
            .map(|&(_, y)| 0.5 * y)
            .reduce(f64::min)
            .map(|ya| (x1, ya));
        if let Some((_, ya)) = anchor.filter(|_| !self.slopes.is_empty()) {
            y0 = y0.min(ya);
        }
        let (xlo, xhi) = log_range(x0, x1);
        let (ylo, yhi) = log_range(y0, y1);
        let (x_bold, x_light) = log_ticks(xlo, xhi);
        let (y_bold, y_light) = log_ticks(ylo, yhi);
        let mut chart = curve_chart(
            root,
            &self.labels,
            (xlo..xhi)
                .log_scale()
                .with_key_points(x_bold)
                .with_light_points(x_light),
            (ylo..yhi)
                .log_scale()
                .with_key_points(y_bold)
                .with_light_points(y_light),
            (&|v| fmt_log_tick(*v), &|v| fmt_log_tick(*v)),
        )?;
        if let Some((xa, ya)) = anchor {
            let grey = RGBColor(90, 90, 90);
            let rect = (xlo.log10(), xhi.log10(), ylo.log10(), yhi.log10());
            // Over the x range of the data (the whole axis if that is a point).
            let (la, lb) = if x1 > x0 {
                (x0.log10(), x1.log10())
            } else {
                (rect.0, rect.1)
            };
            for &p in self.slopes {
                // In log coordinates the line is straight: clip it there.
                let at = |lx: f64| (lx, ya.log10() + p * (lx - xa.log10()));
                let Some((a, b, _, _)) = clip_segment(at(la), at(lb), rect) else {
                    continue;
                };
                let exp = |(lx, ly): (f64, f64)| (10f64.powf(lx), 10f64.powf(ly));
                let (a, b) = (exp(a), exp(b));
                chart.draw_series(DashedLineSeries::new(
                    vec![a, b],
                    9,
                    6,
                    grey.stroke_width(2),
                ))?;
                // Label at the left end, inside the plot.
                let at_bottom = (a.1.log10() - rect.2).abs() < 1e-9;
                let (offset, pos) = if at_bottom {
                    ((-6, -4), Pos::new(HPos::Right, VPos::Bottom))
                } else {
                    ((8, 6), Pos::new(HPos::Left, VPos::Top))
                };
                let style = text_style(18.0, pos).color(&grey);
                chart.draw_series(std::iter::once(
                    EmptyElement::at(a) + Text::new(slope_label(p), offset, style),
                ))?;
            }
        }
        for (k, (name, pts)) in self.series.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let label = match loglog_slope(pts) {
                Some(s) => format!("{name} (slope {s:.2})"),
                None if pts.is_empty() => format!("{name} (no positive point)"),
                None => name.clone(),
            };
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
                .label(label)
                .legend(move |(x, y)| {
                    EmptyElement::at((x, y))
                        + PathElement::new(vec![(0, 0), (24, 0)], c.stroke_width(2))
                        + Circle::new((12, 0), 4, c.filled())
                });
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 5, c.filled())))?;
        }
        finish_chart(
            &mut chart,
            root,
            (!self.series.is_empty()).then_some(SeriesLabelPosition::UpperLeft),
            empty.then_some("no positive point to plot"),
        )
    }
}

/// What the legend of a line figure says of a curve without a point.
const NO_FINITE_POINT: &str = "no finite point";

struct LinesFigure<'a> {
    labels: Labels<'a>,
    curves: Vec<Curve>,
}

/// The length of the axis range `(lo, hi)`, at most `f64::MAX`.
fn span((lo, hi): (f64, f64)) -> f64 {
    (hi - lo).min(f64::MAX)
}

impl LinesFigure<'_> {
    /// Where the legend goes: a corner of the plot over `x` × `y` where it
    /// hides no curve point, else the upper right with the top of `y` raised
    /// so that the curves stay below it. None without curves.
    fn place_legend<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        x: (f64, f64),
        y: &mut (f64, f64),
    ) -> DrawResult<Option<SeriesLabelPosition>>
    where
        DB::ErrorType: 'static,
    {
        if self.curves.is_empty() {
            return Ok(None);
        }
        let y_span = span(*y);
        let y_format = |v: &f64| fmt_tick(*v, y_span);
        let y_area = y_label_area(root, &RangedCoordf64::from(y.0..y.1), &y_format)?;
        let (pw, ph) = curve_plot_px(root, y_area);
        let (lw, lh) = legend_px(root, &self.curves, NO_FINITE_POINT)?;
        let (fx, fy) = ((lw / pw).min(1.0), (lh / ph).min(0.6));
        let (corner, hidden) = quiet_corner(&self.curves, x, *y, (fx, fy));
        if hidden == 0 {
            return Ok(Some(corner));
        }
        // The old top at 1 − fy of the new height.
        y.1 = ((y.1 - fy * y.0) / (1.0 - fy)).min(f64::MAX);
        Ok(Some(SeriesLabelPosition::UpperRight))
    }
}

impl Figure for LinesFigure<'_> {
    fn size(&self) -> (u32, u32) {
        CURVE_FIG
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, _format: Format) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        let (empty, (x0, x1, y0, y1)) = curves_box(&self.curves, (0.0, 1.0, 0.0, 1.0));
        // The curves span the whole width, with a little room above and
        // below (and more above if the legend needs it).
        let x = linear_range(x0, x1, 0.0);
        let mut y = linear_range(y0, y1, 0.05);
        let legend = self.place_legend(root, x, &mut y)?;
        let (x_span, y_span) = (span(x), span(y));
        let mut chart = curve_chart(
            root,
            &self.labels,
            x.0..x.1,
            y.0..y.1,
            (&|v| fmt_tick(*v, x_span), &|v| fmt_tick(*v, y_span)),
        )?;
        draw_curves(&mut chart, &self.curves, NO_FINITE_POINT)?;
        finish_chart(
            &mut chart,
            root,
            legend,
            empty.then_some("no finite point to plot"),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn number_formats() {
        assert_eq!(fmt_sig(0.30000000000000004, 4), "0.3");
        assert_eq!(fmt_sig(1234.6, 4), "1235");
        assert_eq!(fmt_sig(1.5e-7, 4), "1.5e-7");
        assert_eq!(fmt_tick(1e-17, 1.0), "0");
        assert_eq!(fmt_tick(0.25, 1.0), "0.25");
        assert_eq!(fmt_tick(1.000012, 1e-5), "1.000012");
        assert_eq!(fmt_tick(250.25, 2.0), "250.25");
        assert_eq!(fmt_log_tick(1e-3), "10⁻³");
        assert_eq!(fmt_log_tick(1.0), "10⁰");
        assert_eq!(fmt_log_tick(2e-3), "0.002");
    }

    #[test]
    fn levels_are_inside_and_round() {
        let l = iso_levels(0.0, 1.0, 10);
        assert!(l.len() >= 5 && l.len() <= 20);
        assert!(l.iter().all(|&c| c > 0.0 && c < 1.0));
        assert!(iso_levels(1.0, 1.0, 10).is_empty());
    }

    #[test]
    fn clipping() {
        let r = (0.0, 1.0, 0.0, 1.0);
        let (a, b, ca, cb) = clip_segment((-1.0, 0.5), (2.0, 0.5), r).unwrap();
        assert_eq!((a, b, ca, cb), ((0.0, 0.5), (1.0, 0.5), true, true));
        assert!(clip_segment((-1.0, 2.0), (2.0, 2.0), r).is_none());
    }

    #[test]
    fn slope_fit() {
        let pts: Vec<(f64, f64)> = [0.1, 0.05, 0.025]
            .iter()
            .map(|&h| (h, 3.0 * h * h))
            .collect();
        assert!((loglog_slope(&pts).unwrap() - 2.0).abs() < 1e-12);
    }
}
