//! Curve figures on linear or log axes: solver history, convergence, lines.
//! First the shared pieces (chart, legend, ranges), then the figures.

use super::*;

// ---------------------------------------------------------------------------
// Curve figures (history, convergence, lines): shared pieces
// ---------------------------------------------------------------------------

/// Size of the history and line figures, in pixels.
pub(super) const CURVE_FIG: (u32, u32) = (960, 600);
/// Right margin of a curve chart (room for the last x tick label).
pub(super) const CURVE_MARGIN_RIGHT: u32 = 28;
/// Font size of the tick labels of a curve chart, and how many labelled
/// ticks its y axis has at most (plotters' default).
pub(super) const TICK_FONT: f64 = 17.0;
pub(super) const Y_TICKS: usize = 11;
/// Font size of the legend's labels and a legend's layout in plotters:
/// the key area left of the labels, the margin inside the box and the gap
/// between the box and the plot's edge.
pub(super) const LEGEND_FONT: f64 = 17.0;
pub(super) const LEGEND_KEY: u32 = 30;
pub(super) const LEGEND_MARGIN: u32 = 12;
pub(super) const LEGEND_GAP: u32 = 5;

/// Title and axis descriptions of a curve figure.
pub(super) struct Labels<'a> {
    pub(super) title: &'a str,
    pub(super) x: &'a str,
    pub(super) y: &'a str,
}

/// Tick label formatters of the x and y axes.
pub(super) type TickFormats<'f> = (&'f dyn Fn(&f64) -> String, &'f dyn Fn(&f64) -> String);

/// The title row and, below it, a chart over `x` × `y` with the margins,
/// light grid, axis descriptions and tick labels the curve figures share.
pub(super) fn curve_chart<'c, DB, X, Y>(
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
pub(super) fn y_label_area<DB, Y>(
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
pub(super) fn curve_plot_px<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    y_area: u32,
) -> (f64, f64) {
    let (w, h) = root.dim_in_pixel();
    let w = w.saturating_sub(MARGIN + CURVE_MARGIN_RIGHT + y_area);
    let h = h.saturating_sub(TITLE_H + 2 * MARGIN + X_LABEL_AREA);
    (w.max(1) as f64, h.max(1) as f64)
}

/// The legend label of a curve: its name, followed by `no_point` if it has
/// no point at all.
pub(super) fn curve_label(name: &str, points: &[Option<(f64, f64)>], no_point: &str) -> String {
    if points.iter().all(Option::is_none) {
        format!("{name} ({no_point})")
    } else {
        name.to_string()
    }
}

/// Width and height in pixels of the legend [`finish_chart`] draws for
/// `curves` (labelled as [`draw_curves`] does), with its gap to the plot's edge.
pub(super) fn legend_px<DB: DrawingBackend>(
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
pub(super) fn curve_runs(
    points: &[Option<(f64, f64)>],
) -> impl Iterator<Item = Vec<(f64, f64)>> + '_ {
    points
        .split(|p| p.is_none())
        .filter(|r| !r.is_empty())
        .map(|r| r.iter().flatten().copied().collect())
}

/// Each curve in its palette colour, broken at its gaps, with the points
/// that stand alone as dots, and its [`curve_label`] in the legend.
pub(super) fn draw_curves<DB, CT>(
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
pub(super) fn bounding_box(points: impl Iterator<Item = (f64, f64)>) -> (f64, f64, f64, f64) {
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
pub(super) fn curves_box(
    curves: &[Curve],
    fallback: (f64, f64, f64, f64),
) -> (bool, (f64, f64, f64, f64)) {
    let bounds = bounding_box(curves.iter().flat_map(|(_, p)| p.iter().flatten()).copied());
    let empty = bounds.0 > bounds.1;
    (empty, if empty { fallback } else { bounds })
}

/// Linear-axis range around [min, max] (finite), widened if a point, padded
/// by `pad` times its length on both sides; always finite.
pub(super) fn linear_range(min: f64, max: f64, pad: f64) -> (f64, f64) {
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
pub(super) fn quiet_corner(
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
        // A point off the plot (a reference line's clipped part) hides nothing.
        if !(0.0..=1.0).contains(&u) || !(0.0..=1.0).contains(&v) {
            return;
        }
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
pub(super) fn finish_chart<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
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

pub(super) struct HistoryFigure<'a> {
    pub(super) title: &'a str,
    pub(super) curves: Vec<Curve>,
    pub(super) x_is_integer: bool,
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
        let mut y_range = log_range(y0, y1);
        let legend = place_log_legend(
            root,
            (&self.curves, self.curves.len()),
            "no positive value",
            ((x0, x1), false),
            &mut y_range,
        )?;
        let (ylo, yhi) = y_range;
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
            (&x_format, &|v| fmt_log_tick(*v, (ylo, yhi))),
        )?;
        draw_curves(&mut chart, &self.curves, "no positive value")?;
        finish_chart(
            &mut chart,
            root,
            legend,
            empty.then_some("no positive value to plot"),
        )
    }
}

pub(super) struct ConvergenceFigure<'a> {
    pub(super) labels: Labels<'a>,
    pub(super) series: Vec<(String, Vec<(f64, f64)>)>,
    pub(super) slopes: &'a [f64],
}

pub(super) fn slope_label(p: f64) -> String {
    if p.fract() == 0.0 && p.abs() < 100.0 {
        format!("h{}", crate::numbers::superscript(p as i32))
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
        let labels: Vec<String> = self
            .series
            .iter()
            .map(|(name, pts)| match loglog_slope(pts) {
                Some(s) => format!("{name} (slope {s:.2})"),
                None if pts.is_empty() => format!("{name} (no positive point)"),
                None => name.clone(),
            })
            .collect();
        // The legend in a corner where it hides no point of the curves or
        // of the reference lines, else above them.
        let mut measured: Vec<Curve> = self
            .series
            .iter()
            .zip(&labels)
            .map(|((name, pts), label)| {
                let name = if pts.is_empty() { name } else { label };
                (name.clone(), pts.iter().copied().map(Some).collect())
            })
            .collect();
        let in_legend = measured.len();
        if let Some((xa, ya)) = anchor.filter(|_| x1 > x0) {
            for &p in self.slopes {
                let at = |x: f64| Some((x, ya * (x / xa).powf(p)));
                measured.push((String::new(), vec![at(x0), at(x1)]));
            }
        }
        let mut y_range = log_range(y0, y1);
        let legend = place_log_legend(
            root,
            (&measured, in_legend),
            "no positive point",
            ((xlo, xhi), true),
            &mut y_range,
        )?;
        let (ylo, yhi) = y_range;
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
            (&|v| fmt_log_tick(*v, (xlo, xhi)), &|v| {
                fmt_log_tick(*v, (ylo, yhi))
            }),
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
        for (k, ((_, pts), label)) in self.series.iter().zip(labels).enumerate() {
            let c = PALETTE[k % PALETTE.len()];
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
            legend,
            empty.then_some("no positive point to plot"),
        )
    }
}

/// What the legend of a line figure says of a curve without a point.
pub(super) const NO_FINITE_POINT: &str = "no finite point";

pub(super) struct LinesFigure<'a> {
    pub(super) labels: Labels<'a>,
    pub(super) curves: Vec<Curve>,
}

/// The length of the axis range `(lo, hi)`, at most `f64::MAX`.
pub(super) fn span((lo, hi): (f64, f64)) -> f64 {
    (hi - lo).min(f64::MAX)
}

impl LinesFigure<'_> {
    /// Where the legend goes ([`place_legend`]), with the y label area the
    /// chart will have. None without curves.
    fn place_legend<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        x: (f64, f64),
        y: &mut (f64, f64),
    ) -> DrawResult<Option<SeriesLabelPosition>>
    where
        DB::ErrorType: 'static,
    {
        let y_span = span(*y);
        let y_format = |v: &f64| fmt_tick(*v, y_span);
        let y_area = y_label_area(root, &RangedCoordf64::from(y.0..y.1), &y_format)?;
        place_legend(
            root,
            (&self.curves, self.curves.len()),
            NO_FINITE_POINT,
            x,
            y,
            y_area,
        )
    }
}

/// Where the legend of the first `in_legend` of `curves` goes on a plot over
/// `x` × `y` (in the plot's linear coordinates: log10 of a log axis) with a
/// y label area of `y_area` pixels: a corner where it hides no point of any
/// of `curves`, else the upper right with the top of `y` raised so that the
/// curves stay below it. None without curves in the legend.
pub(super) fn place_legend<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    (curves, in_legend): (&[Curve], usize),
    no_point: &str,
    x: (f64, f64),
    y: &mut (f64, f64),
    y_area: u32,
) -> DrawResult<Option<SeriesLabelPosition>>
where
    DB::ErrorType: 'static,
{
    if in_legend == 0 {
        return Ok(None);
    }
    let (pw, ph) = curve_plot_px(root, y_area);
    let (lw, lh) = legend_px(root, &curves[..in_legend], no_point)?;
    let (fx, fy) = ((lw / pw).min(1.0), (lh / ph).min(0.6));
    let (corner, hidden) = quiet_corner(curves, x, *y, (fx, fy));
    if hidden == 0 {
        return Ok(Some(corner));
    }
    // The old top at 1 − fy of the new height.
    y.1 = ((y.1 - fy * y.0) / (1.0 - fy)).min(f64::MAX);
    Ok(Some(SeriesLabelPosition::UpperRight))
}

/// [`place_legend`] on log–log or lin–log axes: the curves and ranges
/// in log10 where `log_x` (the y axis is always log), the raised top back
/// in the data's units.
pub(super) fn place_log_legend<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    (curves, in_legend): (&[Curve], usize),
    no_point: &str,
    (x, log_x): ((f64, f64), bool),
    y: &mut (f64, f64),
) -> DrawResult<Option<SeriesLabelPosition>>
where
    DB::ErrorType: 'static,
{
    let lx = |v: f64| if log_x { v.log10() } else { v };
    let in_log: Vec<Curve> = curves
        .iter()
        .map(|(name, pts)| {
            let pts = pts
                .iter()
                .map(|p| p.filter(|&(a, b)| (a > 0.0 || !log_x) && b > 0.0))
                .map(|p| p.map(|(a, b)| (lx(a), b.log10())))
                .collect();
            (name.clone(), pts)
        })
        .collect();
    let mut ly = (y.0.log10(), y.1.log10());
    // The tick labels of a log axis are short (`10⁻³`, `0.05`).
    let corner = place_legend(
        root,
        (&in_log, in_legend),
        no_point,
        (lx(x.0), lx(x.1)),
        &mut ly,
        Y_LABEL_AREA + 24,
    )?;
    y.1 = 10f64.powf(ly.1);
    Ok(corner)
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
