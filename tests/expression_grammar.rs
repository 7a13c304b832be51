//! The expression grammar (docs/expressions.md) from the outside: random
//! expression trees, printed and parsed, evaluate to the tree's own value;
//! FreeFEM reads the FreeFEM text of each expression to the same numbers;
//! derivatives agree with central differences; every text is read, never
//! aborted on.

mod common;

use common::run_freefem;
use obstacle_fem::expression::{Expression, Variable};
use proptest::prelude::*;
use std::fmt::Write as _;

/// A random expression tree with its own evaluation and printing: the
/// parser's precedence and associativity are checked against it, not
/// against themselves.
#[derive(Debug, Clone)]
enum T {
    Num(f64),
    X,
    Y,
    R,
    Neg(Box<T>),
    /// + - * / ^ < <= > >=
    Bin(&'static str, Box<T>, Box<T>),
    Call1(&'static str, Box<T>),
    /// min max atan2
    Call2(&'static str, Box<T>, Box<T>),
    If(Box<T>, Box<T>, Box<T>),
}

impl T {
    fn eval(&self, x: f64, y: f64) -> f64 {
        let e = |t: &T| t.eval(x, y);
        let compare = |a: f64, b: f64, holds: bool| {
            if a.is_nan() || b.is_nan() {
                f64::NAN
            } else {
                f64::from(holds)
            }
        };
        match self {
            T::Num(v) => *v,
            T::X => x,
            T::Y => y,
            T::R => x.hypot(y),
            T::Neg(a) => -e(a),
            T::Bin(op, a, b) => {
                let (a, b) = (e(a), e(b));
                match *op {
                    "+" => a + b,
                    "-" => a - b,
                    "*" => a * b,
                    "/" => a / b,
                    "^" => a.powf(b),
                    "<" => compare(a, b, a < b),
                    "<=" => compare(a, b, a <= b),
                    ">" => compare(a, b, a > b),
                    _ => compare(a, b, a >= b),
                }
            }
            T::Call1(f, a) => {
                let a = e(a);
                match *f {
                    "sqrt" => a.sqrt(),
                    "exp" => a.exp(),
                    "ln" => a.ln(),
                    "sin" => a.sin(),
                    "cos" => a.cos(),
                    "atan" => a.atan(),
                    "tanh" => a.tanh(),
                    _ => a.abs(),
                }
            }
            T::Call2(f, a, b) => {
                let (a, b) = (e(a), e(b));
                match *f {
                    "min" => a.min(b),
                    "max" => a.max(b),
                    _ => a.atan2(b),
                }
            }
            T::If(c, a, b) => {
                let c = e(c);
                if c.is_nan() {
                    f64::NAN
                } else if c != 0.0 {
                    e(a)
                } else {
                    e(b)
                }
            }
        }
    }

    /// Fully parenthesised, with `spaces` between tokens.
    fn print(&self, spaces: &str) -> String {
        let p = |t: &T| t.print(spaces);
        match self {
            T::Num(v) => format!("{v:?}"),
            T::X => "x".into(),
            T::Y => "y".into(),
            T::R => "r".into(),
            T::Neg(a) => format!("(-{spaces}{})", p(a)),
            T::Bin(op, a, b) => format!("({}{spaces}{op}{spaces}{})", p(a), p(b)),
            T::Call1(f, a) => format!("{f}({spaces}{})", p(a)),
            T::Call2(f, a, b) => format!("{f}({},{spaces}{})", p(a), p(b)),
            T::If(c, a, b) => format!("if({}, {}, {})", p(c), p(a), p(b)),
        }
    }
}

fn tree() -> impl Strategy<Value = T> {
    let leaf = prop_oneof![
        (0u32..40).prop_map(|k| T::Num(f64::from(k) * 0.25)),
        prop_oneof![Just(1e-3), Just(2.5e2), Just(0.1)].prop_map(T::Num),
        Just(T::X),
        Just(T::Y),
        Just(T::R),
    ];
    leaf.prop_recursive(6, 48, 3, |inner| {
        let op = prop_oneof![
            Just("+"),
            Just("-"),
            Just("*"),
            Just("/"),
            Just("^"),
            Just("<"),
            Just("<="),
            Just(">"),
            Just(">=")
        ];
        let f1 = prop_oneof![
            Just("sqrt"),
            Just("exp"),
            Just("ln"),
            Just("sin"),
            Just("cos"),
            Just("atan"),
            Just("tanh"),
            Just("abs")
        ];
        let f2 = prop_oneof![Just("min"), Just("max"), Just("atan2")];
        prop_oneof![
            inner.clone().prop_map(|a| T::Neg(Box::new(a))),
            (op, inner.clone(), inner.clone()).prop_map(|(o, a, b)| T::Bin(
                o,
                Box::new(a),
                Box::new(b)
            )),
            (f1, inner.clone()).prop_map(|(f, a)| T::Call1(f, Box::new(a))),
            (f2, inner.clone(), inner.clone()).prop_map(|(f, a, b)| T::Call2(
                f,
                Box::new(a),
                Box::new(b)
            )),
            (inner.clone(), inner.clone(), inner).prop_map(|(c, a, b)| T::If(
                Box::new(c),
                Box::new(a),
                Box::new(b)
            )),
        ]
    })
}

const POINTS: [[f64; 2]; 4] = [[0.3, -0.7], [1.25, 0.5], [-0.4, 0.0], [2.0, 1.5]];

/// Equal as numbers: the same bits, or both NaN.
fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()) || a == b
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    /// A tree printed with full parentheses (any blanks) parses to its value;
    /// the parsed expression printed with minimal parentheses parses back to
    /// the same value again.
    #[test]
    fn printed_trees_parse_to_their_value(t in tree(), blank in prop_oneof![Just(""), Just(" "), Just("\t ")]) {
        let text = t.print(blank);
        let parsed = Expression::parse(&text).map_err(|e| TestCaseError::fail(format!("{text}: {e}")))?;
        let reprinted = parsed.to_string();
        let again = Expression::parse(&reprinted).map_err(|e| TestCaseError::fail(format!("{reprinted}: {e}")))?;
        for [x, y] in POINTS {
            let want = t.eval(x, y);
            let got = parsed.eval([x, y]);
            // Constant folding and evaluation are the same arithmetic: equal bits.
            prop_assert!(same(got, want), "{text} at ({x}, {y}): {got} vs {want}");
            let got = again.eval([x, y]);
            prop_assert!(same(got, want), "{reprinted} (from {text}) at ({x}, {y}): {got} vs {want}");
        }
    }

    /// Any text is parsed or refused with a message, never a panic.
    #[test]
    fn any_text_is_read_or_refused(text in "[-+*/^()<>=,. 0-9a-z]{0,40}") {
        if let Err(m) = Expression::parse(&text) {
            prop_assert!(m.contains("at character"), "{text}: {m}");
        }
    }
}

/// The conventions the grammar states, on the texts of the issue that asked
/// for them: `^` right-associative and tighter than a sign, blanks separate.
#[test]
fn conventions() {
    let value = |t: &str| Expression::parse(t).unwrap().eval([0.5, 2.0]);
    assert_eq!(value("2^3^2"), 512.0);
    assert_eq!(value("-x^2"), -0.25);
    assert_eq!(value("2^-1"), 0.5);
    assert_eq!(value("max(0.1, min(0.15 + 0.1*r^2, 0.2))"), 0.2);
    assert_eq!(value("min(x, min(y, 1))"), 0.5);
    assert_eq!(
        value("atan2(y, atan2(x, 1))"),
        2f64.atan2(0.5f64.atan2(1.0))
    );
    for text in ["1 2", "x + 1 0", "2 .5", "x y"] {
        let m = Expression::parse(text).unwrap_err();
        assert!(m.contains("operator"), "{text}: {m}");
    }
}

/// FreeFEM evaluates the FreeFEM text of each expression to the value here
/// (both sides of every twin read the same strings the same way).
#[test]
fn freefem_reads_the_same_expressions() {
    let texts = [
        "2^3^2*x",
        "-x^2 + y",
        "1/2*x + 3/4",
        "x^y^2",
        "(x^y)^2",
        "2^-x",
        "-(x - y) * -y",
        "if(x < 0, 2^3^2/8, -8) + x",
        "(x > 0.2)*3 + (y <= 0.5) - (x >= y)",
        "max(0.1, min(0.15 + 0.1*r^2, 0.2))",
        "min(x, min(y, 1)) + atan2(y, atan2(x, 1))",
        "sqrt(r) + exp(-x*y) + ln(1 + r) + abs(x - y)",
        "sin(x)*cos(y) + tan(x/3) + asin(x/3) + acos(y/3) + atan(x*y)",
        "sinh(x) + cosh(y) + tanh(x - y)",
        "if(r < 1, if(x < 0, 1, 2), 3*pi)",
        "x - y - 1 - 2*x/3/2",
        "1e-3*x + 2.5E2*y + .5",
    ];
    let points = [[0.3, 0.4], [0.9, -0.6], [-0.5, 0.25], [1.5, 0.75]];
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("values.txt");
    let mut script = String::new();
    for (k, text) in texts.iter().enumerate() {
        let e = Expression::parse(text).unwrap();
        writeln!(
            script,
            "func real f{k}(real x, real y) {{ return {}; }}",
            e.freefem()
        )
        .unwrap();
    }
    writeln!(
        script,
        "ofstream out(\"{}\");\nout.precision(17);",
        out.display()
    )
    .unwrap();
    for k in 0..texts.len() {
        for [x, y] in points {
            writeln!(script, "out << f{k}({x:e}, {y:e}) << \"\\n\";").unwrap();
        }
    }
    let path = dir.path().join("expressions.edp");
    std::fs::write(&path, script).unwrap();
    let (o, _) = run_freefem(path.to_str().unwrap(), &[]);
    common::check_success("FreeFEM expressions", &o);
    let values = common::read_numbers(&out);
    assert_eq!(values.len(), texts.len() * points.len());
    for (k, text) in texts.iter().enumerate() {
        let e = Expression::parse(text).unwrap();
        for (i, p) in points.iter().enumerate() {
            let (ours, theirs) = (e.eval(*p), values[k * points.len() + i]);
            assert!(
                (ours - theirs).abs() <= 1e-13 * (1.0 + ours.abs())
                    || (ours.is_nan() && theirs.is_nan()),
                "{text} at {p:?}: {ours} here, {theirs} in FreeFEM ({})",
                e.freefem()
            );
        }
    }
}

/// The derivatives a chart needs: exact, against central differences of
/// step 1e-5 (error O(h²)).
#[test]
fn derivatives_match_central_differences() {
    let texts = [
        "10*cos(y)*cos(x)",
        "10*cos(y)*sin(x)",
        "10*sin(y)",
        "(x^2 - y^2)/5000 + 1.4",
        "0.2 + if(x > 0, x^2/1.69, 0)",
    ];
    for text in texts {
        let e = Expression::parse(text).unwrap();
        for var in [Variable::X, Variable::Y] {
            let d = e.derivative(var).unwrap();
            for p in [[0.3, 0.4], [0.9, -0.6], [-0.5, 0.25]] {
                let h = 1e-5;
                let step = |s: f64| match var {
                    Variable::X => [p[0] + s, p[1]],
                    _ => [p[0], p[1] + s],
                };
                let fd = (e.eval(step(h)) - e.eval(step(-h))) / (2.0 * h);
                assert!(
                    (fd - d.eval(p)).abs() < 1e-7 * (1.0 + fd.abs()),
                    "{text}: {fd} vs {}",
                    d.eval(p)
                );
            }
        }
    }
}
