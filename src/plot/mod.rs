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

mod curves;
mod draw;
mod fields;
mod render;
mod scale;

use curves::*;
use draw::*;
use fields::*;
use render::*;
use scale::*;

pub use scale::loglog_slope;

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
