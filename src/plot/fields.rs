//! Figures over the mesh: P1 and cell fields, the contact zone.

use super::*;

pub(super) struct FieldFigure<'a> {
    pub(super) frame: Frame,
    pub(super) mesh: &'a Mesh,
    pub(super) values: &'a [f64],
    pub(super) per_vertex: bool,
    pub(super) title: &'a str,
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) levels: Vec<f64>,
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
pub(super) enum Key {
    /// Text only.
    Heading,
    /// A filled square, indented by so many pixels.
    Swatch(RGBColor, i32),
    Dot(RGBColor),
    /// A line of that width.
    Line(RGBColor, u32),
}

pub(super) struct ContactFigure<'a> {
    pub(super) frame: Frame,
    pub(super) mesh: &'a Mesh,
    pub(super) active: &'a [bool],
    pub(super) per_vertex: bool,
    pub(super) title: &'a str,
    pub(super) radius: Option<f64>,
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
