//! The figure trait, input validation, and rendering to a temporary file
//! renamed over the target path.

use super::*;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Format {
    Png,
    Svg,
}

/// A figure: its size and how to draw it on a backend.
pub(super) trait Figure {
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, format: Format) -> DrawResult
    where
        DB::ErrorType: 'static;
}

/// The points of each series that `keep` accepts, sorted by x (stably).
pub(super) fn sorted_by_x(
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

pub(super) fn format_of(path: &Path) -> Result<Format> {
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

pub(super) fn check_mesh(path: &Path, mesh: &Mesh) -> Result<()> {
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

pub(super) fn check_field(
    path: &Path,
    values: &[f64],
    expected: usize,
    kind: &str,
    what: &str,
) -> Result<()> {
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
pub(super) fn ensure_font() -> std::result::Result<(), String> {
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
pub(super) fn render<F: Figure>(path: &Path, format: Format, fig: &F) -> Result<()> {
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
