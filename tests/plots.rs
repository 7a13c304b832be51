//! Figures: every plot is written as PNG and SVG, atomically, and bad input
//! is an error that leaves no file.
//!
//! Set `OBSTACLE_PLOT_DIR=/some/dir` to keep the figures for a look.

mod common;

use common::square_mesh;

use obstacle_fem::plot::{
    plot_cell_field, plot_contact_zone, plot_convergence, plot_history, plot_lines,
    plot_vertex_field,
};
use obstacle_fem::solvers::measures::History;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A membrane-like field: a bump resting on a flat obstacle near the centre.
fn field(p: [f64; 2]) -> f64 {
    let [x, y] = p;
    let r2 = x * x + y * y;
    ((1.0 - x * x) * (1.0 - y * y) * (1.0 + 0.4 * x)).min(0.75 - 0.3 * r2)
}

struct Out {
    _tmp: tempfile::TempDir,
    dir: PathBuf,
}

fn out_dir() -> Out {
    let tmp = tempfile::tempdir().unwrap();
    let dir = match std::env::var_os("OBSTACLE_PLOT_DIR") {
        Some(d) => {
            std::fs::create_dir_all(&d).unwrap();
            PathBuf::from(d)
        }
        None => tmp.path().to_path_buf(),
    };
    Out { _tmp: tmp, dir }
}

/// Checks a written figure: exists, non-empty, PNG signature or SVG text
/// with the title, mode 0644.
fn check_figure(path: &Path, title: &str) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(!bytes.is_empty(), "{} is empty", path.display());
    match path.extension().and_then(|e| e.to_str()) {
        Some("png") => assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
            "{} is not a PNG",
            path.display()
        ),
        Some("svg") => {
            let text = String::from_utf8(bytes).expect("SVG is UTF-8");
            let start = text.trim_start();
            assert!(
                start.starts_with("<svg") || start.starts_with("<?xml"),
                "{} does not start like SVG",
                path.display()
            );
            assert!(
                text.trim_end().ends_with("</svg>"),
                "{} is cut",
                path.display()
            );
            assert!(
                text.contains(title),
                "{} lacks its title {title:?}",
                path.display()
            );
        }
        other => panic!("unexpected extension {other:?}"),
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o644, "{} has mode {mode:o}", path.display());
    }
}

/// No temporary files are left in `dir`.
fn assert_no_leftovers(dir: &Path) {
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".plot-"))
        .collect();
    assert!(left.is_empty(), "temporary files left: {left:?}");
}

/// A decoded PNG figure: its size and a count of each RGB colour.
struct Png {
    width: u32,
    height: u32,
    counts: HashMap<[u8; 3], usize>,
}

impl Png {
    fn read(path: &Path) -> Png {
        let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
        decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = decoder
            .read_info()
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut buf = vec![0; reader.output_buffer_size()];
        let frame = reader
            .next_frame(&mut buf)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let samples = frame.color_type.samples();
        assert!(samples >= 3, "{}: not an RGB image", path.display());
        let mut counts = HashMap::new();
        for px in buf[..frame.buffer_size()].chunks_exact(samples) {
            *counts.entry([px[0], px[1], px[2]]).or_insert(0) += 1;
        }
        Png {
            width: frame.width,
            height: frame.height,
            counts,
        }
    }

    fn count(&self, rgb: [u8; 3]) -> usize {
        self.counts.get(&rgb).copied().unwrap_or(0)
    }

    /// The fraction of pixels that are not white.
    fn ink(&self) -> f64 {
        let total = (self.width * self.height) as f64;
        1.0 - self.count([255, 255, 255]) as f64 / total
    }

    fn describe(&self, what: &str) -> String {
        format!(
            "{what}: {}×{}, {} colours, ink {:.3}",
            self.width,
            self.height,
            self.counts.len(),
            self.ink()
        )
    }
}

/// The first colours of the curve palette (matplotlib's tab10, src/plot/mod.rs).
const TAB10: [[u8; 3]; 4] = [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40]];

#[test]
fn vertex_field_png_and_svg() {
    let out = out_dir();
    let mesh = square_mesh(24);
    let values: Vec<f64> = mesh.vertices.iter().map(|&p| field(p)).collect();
    let title = "Displacement u_h (P1)";
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("vertex_field.{ext}"));
        plot_vertex_field(&path, &mesh, &values, title).unwrap();
        check_figure(&path, title);
    }
}

#[test]
fn constant_and_wide_fields_are_fine() {
    let out = out_dir();
    let mesh = square_mesh(3);
    let zeros = vec![0.0; mesh.n_vertices()];
    let path = out.dir.join("constant.png");
    plot_vertex_field(&path, &mesh, &zeros, "constant").unwrap();
    check_figure(&path, "constant");
    let tiny: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|p| 1e-9 * (p[0] + 2.0 * p[1]))
        .collect();
    let path = out.dir.join("tiny.svg");
    plot_vertex_field(&path, &mesh, &tiny, "tiny values").unwrap();
    check_figure(&path, "tiny values");
}

/// Width and height of a PNG, from its IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    (be(16), be(20))
}

#[test]
fn long_domains_keep_their_aspect_ratio() {
    let out = out_dir();
    for (name, sx, sy) in [("wide", 4.0, 1.0), ("tall", 1.0, 3.0)] {
        let mut mesh = square_mesh(16);
        for p in &mut mesh.vertices {
            p[0] *= sx;
            p[1] *= sy;
        }
        let values: Vec<f64> = mesh
            .vertices
            .iter()
            .map(|p| field([p[0] / sx, p[1] / sy]))
            .collect();
        let path = out.dir.join(format!("{name}.png"));
        plot_vertex_field(&path, &mesh, &values, name).unwrap();
        check_figure(&path, name);
        let (w, h) = png_size(&path);
        assert!(
            (sx > sy) == (w > h),
            "{name}: a {sx}×{sy} domain drawn {w}×{h} px"
        );
    }
}

#[test]
fn cell_field_png_and_svg() {
    let out = out_dir();
    let mesh = square_mesh(12);
    let values: Vec<f64> = mesh
        .triangles
        .iter()
        .map(|t| {
            let c = t.map(|v| mesh.vertices[v]);
            field([
                (c[0][0] + c[1][0] + c[2][0]) / 3.0,
                (c[0][1] + c[1][1] + c[2][1]) / 3.0,
            ])
        })
        .collect();
    let title = "Multiplier per triangle";
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("cell_field.{ext}"));
        plot_cell_field(&path, &mesh, &values, title).unwrap();
        check_figure(&path, title);
    }
}

#[test]
fn contact_zone_per_vertex_and_per_triangle() {
    let out = out_dir();
    let mesh = square_mesh(20);
    let radius = 0.55;
    let per_vertex: Vec<bool> = mesh
        .vertices
        .iter()
        .map(|p| p[0].hypot(p[1]) < radius)
        .collect();
    let per_triangle: Vec<bool> = mesh
        .triangles
        .iter()
        .map(|t| t.iter().all(|&v| per_vertex[v]))
        .collect();
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("contact_vertices.{ext}"));
        plot_contact_zone(
            &path,
            &mesh,
            &per_vertex,
            "Contact set (vertices)",
            Some(radius),
        )
        .unwrap();
        check_figure(&path, "Contact set (vertices)");
        let path = out.dir.join(format!("contact_triangles.{ext}"));
        plot_contact_zone(&path, &mesh, &per_triangle, "Contact set (triangles)", None).unwrap();
        check_figure(&path, "Contact set (triangles)");
    }
    // A circle larger than the domain is clipped, not drawn outside.
    let path = out.dir.join("contact_big_circle.png");
    plot_contact_zone(&path, &mesh, &per_vertex, "big circle", Some(1.2)).unwrap();
    check_figure(&path, "big circle");
}

#[test]
fn history_semilog() {
    let out = out_dir();
    let mut h = History::with_columns(&["iteration", "kkt", "dual_step", "penetration"]);
    for k in 0..120 {
        let kf = k as f64;
        let pen = if k % 17 == 5 {
            0.0
        } else {
            1e-2 * 0.9f64.powf(kf)
        };
        h.push(&[kf, 0.93f64.powf(kf), 3.0 * 0.9f64.powf(kf), pen]);
    }
    let title = "Uzawa history";
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("history.{ext}"));
        plot_history(&path, &h, &["kkt", "dual_step", "penetration"], title).unwrap();
        check_figure(&path, title);
    }
    // A missing column is an error naming it, and leaves no file.
    let path = out.dir.join("history_missing.png");
    let err = plot_history(&path, &h, &["nope"], title).unwrap_err();
    assert!(err.to_string().contains("nope"), "{err}");
    assert!(!path.exists());
    // An empty history still gives a figure.
    let path = out.dir.join("history_empty.png");
    plot_history(
        &path,
        &History::with_columns(&["iteration", "kkt"]),
        &["kkt"],
        "empty",
    )
    .unwrap();
    check_figure(&path, "empty");
}

#[test]
fn convergence_loglog() {
    let out = out_dir();
    let hs: [f64; 5] = [0.25, 0.125, 0.0625, 0.03125, 0.015625];
    let series = vec![
        (
            "L2 error".to_string(),
            hs.iter().map(|&h| (h, 0.8 * h * h * (1.0 + h))).collect(),
        ),
        (
            "H1 error".to_string(),
            hs.iter().map(|&h| (h, 1.5 * h)).collect(),
        ),
        (
            "contact radius error".to_string(),
            hs.iter()
                .map(|&h| (h, 0.3 * h.powf(1.5)))
                .chain([(0.01, 0.0)])
                .collect(),
        ),
    ];
    let title = "Convergence under refinement";
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("convergence.{ext}"));
        plot_convergence(&path, &series, "h", "error", title, &[1.0, 2.0]).unwrap();
        check_figure(&path, title);
        let text = std::fs::read(&path).unwrap();
        if ext == "svg" {
            let text = String::from_utf8(text).unwrap();
            assert!(text.contains("h¹") && text.contains("h²"));
        }
    }
    let path = out.dir.join("convergence_empty.svg");
    plot_convergence(&path, &[], "h", "error", "nothing", &[1.0]).unwrap();
    check_figure(&path, "nothing");
}

/// Profiles along y = 0 as a pipeline writes them: the shell's constraint
/// resting on an obstacle bump, points in vertex order (not sorted by x).
fn profiles() -> Vec<(String, Vec<(f64, f64)>)> {
    let xs: Vec<f64> = (0..41)
        .map(|i| -1.0 + 0.05 * ((i * 17) % 41) as f64)
        .collect();
    let phi = |x: f64| 0.2 - 0.5 * x * x;
    let w = |x: f64| phi(x).max(0.1 * (1.0 - x * x));
    vec![
        (
            "(u − ε/2 r)·e3 on y = 0".to_string(),
            xs.iter().map(|&x| (x, w(x))).collect(),
        ),
        (
            "Φ_h on y = 0".to_string(),
            xs.iter().map(|&x| (x, phi(x))).collect(),
        ),
    ]
}

#[test]
fn lines_png_and_svg() {
    let out = out_dir();
    let mut series = profiles();
    // A gap (non-finite y), a point without a place (non-finite x), and a
    // series of one point.
    series[0].1.push((0.33, f64::NAN));
    series[1].1.push((f64::INFINITY, 0.0));
    series.push(("probe".to_string(), vec![(0.5, 0.0)]));
    let title = "Constraint and obstacle: profiles";
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("lines.{ext}"));
        plot_lines(&path, &series, "x", "z", title).unwrap();
        check_figure(&path, title);
        if ext == "svg" {
            let text = std::fs::read_to_string(&path).unwrap();
            for name in ["Φ_h on y = 0", "probe", "z"] {
                assert!(text.contains(name), "the SVG lacks {name:?}");
            }
        }
    }
}

/// Curves through every corner of the plot: the legend needs room above them.
#[test]
fn lines_with_a_crowded_plot() {
    let out = out_dir();
    let wave = |phase: f64| -> Vec<(f64, f64)> {
        (0..=200)
            .map(|i| {
                let x = -1.0 + 0.01 * i as f64;
                (x, (6.0 * x + phase).sin())
            })
            .collect()
    };
    let series: Vec<(String, Vec<(f64, f64)>)> = (0..4)
        .map(|k| {
            let name = format!("(u − ε/2 r)·e3 on a long line name {k}");
            (name, wave(0.8 * k as f64))
        })
        .collect();
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("lines_crowded.{ext}"));
        plot_lines(&path, &series, "x or y", "z", "crowded").unwrap();
        check_figure(&path, "crowded");
    }
    // The PNG: the curve figure's size, each of the four curves drawn in its
    // own colour (a long curve: many pixels), and ink in a sane range.
    let png = Png::read(&out.dir.join("lines_crowded.png"));
    println!("{}", png.describe("crowded"));
    assert_eq!((png.width, png.height), (960, 600));
    for (k, c) in TAB10.iter().enumerate() {
        assert!(
            png.count(*c) >= 300,
            "curve {k} (colour {c:?}) has {} pixels",
            png.count(*c)
        );
    }
    assert!(png.counts.len() >= 8, "{}", png.describe("crowded"));
    assert!(
        (0.02..0.5).contains(&png.ink()),
        "{}",
        png.describe("crowded")
    );
    // The SVG: every series is in the legend, once (the title, axes and
    // legend only: curves are paths).
    let svg = std::fs::read_to_string(out.dir.join("lines_crowded.svg")).unwrap();
    for (name, _) in &series {
        assert_eq!(
            svg.matches(name.as_str()).count(),
            1,
            "legend entry {name:?}"
        );
    }
    let len = svg.len();
    println!("crowded SVG: {len} bytes");
    assert!((5_000..2_000_000).contains(&len), "SVG of {len} bytes");
}

#[test]
fn lines_without_data_and_with_odd_ranges() {
    let out = out_dir();
    let nothing: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    let all_bad = vec![
        ("nan".to_string(), vec![(f64::NAN, 1.0), (0.0, f64::NAN)]),
        ("empty".to_string(), Vec::new()),
    ];
    let odd = [
        ("constant", vec![(0.0, 2.5), (1.0, 2.5), (2.0, 2.5)]),
        ("one point", vec![(3.0, -1.0)]),
        ("one x", vec![(1.0, 0.0), (1.0, 1.0)]),
        (
            "narrow",
            vec![(0.0, 1.00001), (1.0, 1.00002), (2.0, 1.000015)],
        ),
        ("tiny", vec![(0.0, 1e-12), (1e-9, -1e-12)]),
        ("huge", vec![(-f64::MAX, f64::MAX), (f64::MAX, -f64::MAX)]),
    ];
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("lines_none.{ext}"));
        plot_lines(&path, &nothing, "x", "z", "no series").unwrap();
        check_figure(&path, "no series");
        let path = out.dir.join(format!("lines_all_bad.{ext}"));
        plot_lines(&path, &all_bad, "x", "z", "no finite point").unwrap();
        check_figure(&path, "no finite point");
        for (name, pts) in &odd {
            let path = out
                .dir
                .join(format!("lines_{}.{ext}", name.replace(' ', "_")));
            plot_lines(&path, &[(name.to_string(), pts.clone())], "x", "z", name).unwrap();
            check_figure(&path, name);
        }
    }
}

#[test]
fn bad_input_is_an_error_and_writes_nothing() {
    // Its own directory, whatever OBSTACLE_PLOT_DIR says: other tests may
    // be writing temporary files into that one.
    let tmp = tempfile::tempdir().unwrap();
    let out = Out {
        dir: tmp.path().to_path_buf(),
        _tmp: tmp,
    };
    let mesh = square_mesh(4);
    let mut values: Vec<f64> = mesh.vertices.iter().map(|&p| field(p)).collect();
    values[7] = f64::NAN;
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("nan_vertex.{ext}"));
        let err = plot_vertex_field(&path, &mesh, &values, "nan").unwrap_err();
        assert!(err.to_string().contains("not finite"), "{err}");
        assert!(!path.exists());
    }
    let mut cells = vec![1.0; mesh.n_triangles()];
    cells[3] = f64::INFINITY;
    let path = out.dir.join("nan_cell.png");
    assert!(plot_cell_field(&path, &mesh, &cells, "inf").is_err());
    assert!(!path.exists());
    // Wrong lengths.
    let path = out.dir.join("short.png");
    assert!(plot_vertex_field(&path, &mesh, &[1.0, 2.0], "short").is_err());
    assert!(plot_cell_field(&path, &mesh, &[1.0], "short").is_err());
    assert!(plot_contact_zone(&path, &mesh, &[true], "short", None).is_err());
    assert!(!path.exists());
    // Bad radius, bad slope, bad extension, missing directory.
    let flags = vec![false; mesh.n_vertices()];
    assert!(plot_contact_zone(&path, &mesh, &flags, "r", Some(f64::NAN)).is_err());
    assert!(plot_convergence(&path, &[], "h", "e", "t", &[f64::NAN]).is_err());
    assert!(!path.exists());
    let ok: Vec<f64> = mesh.vertices.iter().map(|&p| field(p)).collect();
    let err = plot_vertex_field(&out.dir.join("field.pdf"), &mesh, &ok, "pdf").unwrap_err();
    assert!(err.to_string().contains(".png or .svg"), "{err}");
    let missing = out.dir.join("no/such/dir/field.png");
    assert!(plot_vertex_field(&missing, &mesh, &ok, "missing").is_err());
    for name in ["lines.pdf", "lines", "lines.png.tmp"] {
        let bad = out.dir.join(name);
        let err = plot_lines(&bad, &profiles(), "x", "z", "bad").unwrap_err();
        assert!(err.to_string().contains(".png or .svg"), "{err}");
        assert!(!bad.exists());
    }
    assert!(plot_lines(&missing.with_extension("svg"), &profiles(), "x", "z", "t").is_err());
    // A broken mesh (built by hand, not validated) is an error too.
    let mut broken = mesh.clone();
    broken.triangles[0][1] = 10_000;
    assert!(plot_vertex_field(&path, &broken, &ok, "broken").is_err());
    assert!(!path.exists());
    assert_no_leftovers(&out.dir);
}

#[test]
fn overwrites_an_existing_figure() {
    let out = out_dir();
    let mesh = square_mesh(2);
    let values: Vec<f64> = mesh.vertices.iter().map(|&p| field(p)).collect();
    let path = out.dir.join("again.png");
    std::fs::write(&path, b"old").unwrap();
    plot_vertex_field(&path, &mesh, &values, "again").unwrap();
    check_figure(&path, "again");
}

/// A fine mesh (45 000 triangles): sub-triangles within budget, and the
/// contact figure draws the outline instead of a grey mass of edges.
#[test]
fn fine_mesh() {
    let out = out_dir();
    let mesh = square_mesh(150);
    let values: Vec<f64> = mesh.vertices.iter().map(|&p| field(p)).collect();
    let flags: Vec<bool> = mesh
        .vertices
        .iter()
        .map(|p| p[0].hypot(p[1]) < 0.5)
        .collect();
    let path = out.dir.join("fine_field.png");
    plot_vertex_field(&path, &mesh, &values, "fine field").unwrap();
    check_figure(&path, "fine field");
    for ext in ["png", "svg"] {
        let path = out.dir.join(format!("fine_contact.{ext}"));
        plot_contact_zone(&path, &mesh, &flags, "fine contact", Some(0.5)).unwrap();
        check_figure(&path, "fine contact");
    }
    // The field: a smooth colour map over 45 000 triangles has many colours
    // and fills most of the plot.
    let field_png = Png::read(&out.dir.join("fine_field.png"));
    println!("{}", field_png.describe("fine field"));
    assert_eq!((field_png.width, field_png.height), FINE_PNG_SIZE);
    assert!(
        field_png.counts.len() >= 200,
        "{}",
        field_png.describe("fine field")
    );
    assert!(
        field_png.ink() > 0.3,
        "{}",
        field_png.describe("fine field")
    );
    // The contact zone: the active disk (r < 0.5 in the square of side 2)
    // filled in the strong colour, a fixed share of the figure (measured:
    // 53 640 px, 8.0 %); the rest (outline, axes, text, legend) is thin ink,
    // not a grey mass of 45 000 triangle edges (measured: 2.0 %).
    let contact = Png::read(&out.dir.join("fine_contact.png"));
    println!("{}", contact.describe("fine contact"));
    assert_eq!((contact.width, contact.height), FINE_CONTACT_PNG_SIZE);
    let total = (contact.width * contact.height) as f64;
    let strong = contact.count([49, 130, 189]) as f64 / total;
    let other = contact.ink() - strong;
    println!("fine contact: strong {strong:.4}, other ink {other:.4}");
    assert!(
        (0.07..0.09).contains(&strong),
        "active zone share {strong:.4}"
    );
    assert!(other < 0.04, "ink besides the active zone {other:.4}");
    let svg_len = std::fs::metadata(out.dir.join("fine_contact.svg"))
        .unwrap()
        .len();
    println!("fine contact SVG: {svg_len} bytes");
    assert!(
        svg_len < FINE_SVG_MAX,
        "fine contact SVG of {svg_len} bytes"
    );
}

/// The sizes of the field and contact figures of a square domain (measured;
/// the field's colour bar panel is wider than the contact legend's).
const FINE_PNG_SIZE: (u32, u32) = (960, 834);
const FINE_CONTACT_PNG_SIZE: (u32, u32) = (960, 694);
/// The contact SVG of the fine mesh (measured: 1.74 MB, the active
/// triangles and the outline); every triangle edge besides would add megabytes.
const FINE_SVG_MAX: u64 = 2_500_000;
