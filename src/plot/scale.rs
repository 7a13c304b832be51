//! Numbers, colours, levels: tick and number formats, log ranges, the colour
//! map, isolines, clipping, and the log–log slope of a convergence curve.

use super::*;
use crate::mesh::signed_area;

/// `v` with at most `sig` significant digits: the pages' rule
/// ([`crate::numbers::meaningful`]), so a figure and its report page print
/// a number alike.
pub(super) fn fmt_sig(v: f64, sig: usize) -> String {
    crate::numbers::meaningful(v, sig)
}

/// A linear-axis tick label: values tiny against the axis span are 0; at
/// least 4 significant digits, more where the span is small against the
/// value (so that the ticks of [1.00001, 1.00002] stay apart).
pub(super) fn fmt_tick(v: f64, span: f64) -> String {
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

/// A log-axis tick label in one form for the whole axis over [lo, hi]:
/// plain numbers (`0.05, 0.1, 0.2`) when the axis stays within [1e-3, 1e5),
/// else `m×10ⁿ` for every tick (`5×10⁻², 10⁻¹, 2×10⁻¹`), never a mix.
pub(super) fn fmt_log_tick(v: f64, (lo, hi): (f64, f64)) -> String {
    if v <= 0.0 || !v.is_finite() {
        return String::new();
    }
    if lo >= 1e-3 && hi < 1e5 {
        crate::numbers::meaningful(v, 2)
    } else {
        crate::numbers::scientific(v, 2)
    }
}

/// Ticks of a log axis over [lo, hi]: labelled ("bold") ones — decades
/// (every few decades on long axes), plus 2 and 5 on axes shorter than two
/// decades, plus every digit on axes shorter than one — and grid-only
/// ("light") ones at every digit of every decade.
pub(super) fn log_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
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
pub(super) fn log_range(min: f64, max: f64) -> (f64, f64) {
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
pub(super) fn display_range(values: &[f64]) -> (f64, f64) {
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if hi > lo {
        (lo, hi)
    } else {
        let d = if lo == 0.0 { 1.0 } else { 0.5 * lo.abs() };
        (lo - d, lo + d)
    }
}

pub(super) fn colour(v: f64, lo: f64, hi: f64) -> RGBColor {
    let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
    ViridisRGB::get_color(t)
}

/// A "nice" step (1, 2, 2.5 or 5 times a power of ten) near `raw`.
pub(super) fn nice_step(raw: f64) -> f64 {
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
pub(super) fn iso_levels(lo: f64, hi: f64, target: usize) -> Vec<f64> {
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
pub(super) fn isolines(mesh: &Mesh, values: &[f64], level: f64) -> Vec<Vec<(f64, f64)>> {
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
pub(super) fn clip_segment(
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
pub(super) fn mesh_edges(mesh: &Mesh) -> Vec<([usize; 2], usize)> {
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
pub(super) fn typical_edge_px<DB: DrawingBackend>(mesh: &Mesh, chart: &Chart2d<'_, DB>) -> f64 {
    let nt = mesh.triangles.len().max(1);
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| mesh.vertices[v]);
            signed_area(a, b, c).abs()
        })
        .sum();
    let x = chart.x_range();
    let px_per_unit = chart.plotting_area().dim_in_pixel().0 as f64 / (x.end - x.start);
    (2.0 * area / nt as f64).sqrt() * px_per_unit
}

pub(super) fn pt(p: [f64; 2]) -> (f64, f64) {
    (p[0], p[1])
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn number_formats() {
        assert_eq!(fmt_sig(0.30000000000000004, 4), "0.3");
        assert_eq!(fmt_sig(1234.6, 4), "1235");
        assert_eq!(fmt_sig(1.5e-7, 4), "1.5×10⁻⁷");
        assert_eq!(fmt_tick(1e-17, 1.0), "0");
        assert_eq!(fmt_tick(0.25, 1.0), "0.25");
        assert_eq!(fmt_tick(1.000012, 1e-5), "1.000012");
        assert_eq!(fmt_tick(250.25, 2.0), "250.25");
        // One form per axis: plain within [1e-3, 1e5), else m×10ⁿ.
        let (short, long) = ((0.04, 0.6), (1e-4, 2.0));
        let ticks = |axis| [0.05, 0.1, 0.2].map(|v| fmt_log_tick(v, axis));
        assert_eq!(ticks(short), ["0.05", "0.1", "0.2"]);
        assert_eq!(ticks(long), ["5×10⁻²", "10⁻¹", "2×10⁻¹"]);
        assert_eq!(fmt_log_tick(1.0, long), "10⁰");
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
