//! Drawing pieces shared by the mesh figures: title, frame, colour bar,
//! polylines, filled triangles.

use super::*;

pub(super) fn text_style(size: f64, pos: Pos) -> TextStyle<'static> {
    TextStyle::from((FONT, size).into_font()).pos(pos)
}

/// The title, centred in `area`, shrunk to fit its width.
pub(super) fn draw_title<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
) -> DrawResult
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
pub(super) struct Frame {
    /// Bounding box of the mesh, padded: x range, y range.
    pub(super) x: (f64, f64),
    pub(super) y: (f64, f64),
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) side: u32,
}

impl Frame {
    pub(super) fn for_mesh(mesh: &Mesh, side: u32) -> Frame {
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
    pub(super) fn split<DB: DrawingBackend>(
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
    pub(super) fn chart<'a, DB: DrawingBackend>(
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
pub(super) fn draw_colour_bar<DB: DrawingBackend>(
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
    // The max/min lines sit HEADER_GAP pixels off the bar's ends: more than
    // half a tick label's height (16 px font), so the label of the end tick
    // never touches them.
    const HEADER_GAP: i32 = 18;
    let bar_top = top + 44;
    let bar_bottom = (bottom - 44).max(bar_top + 40);
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
        (LEFT, bar_top - HEADER_GAP),
        small(Pos::new(HPos::Left, VPos::Bottom)),
    ))?;
    panel.draw(&Text::new(
        format!("min {}", fmt_sig(vmin, 4)),
        (LEFT, bar_bottom + HEADER_GAP),
        small(Pos::new(HPos::Left, VPos::Top)),
    ))?;
    Ok(())
}

/// Draws a polyline as runs along which x does not decrease: plotters'
/// bitmap backend drops the end pixels of a horizontal 1-pixel segment drawn
/// from right to left, which leaves gaps in curves.
pub(super) fn draw_polyline<DB: DrawingBackend>(
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
pub(super) fn fill_triangle<DB: DrawingBackend>(
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
