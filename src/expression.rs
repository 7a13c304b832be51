//! Scene data as expressions in the coordinates: a number, or a formula in
//! `x`, `y` and `r` = √(x² + y²) (README, "Expressions").
//!
//! The language: numbers (`1.5`, `2e-3`), `+ - * / ^`, parentheses, `pi`,
//! `sqrt exp ln sin cos tan abs`, `min(a, b)`, `max(a, b)`, `atan2(y, x)` (the
//! angle of the point (x, y) in (−π, π], as in C and FreeFEM), comparisons
//! `< <= > >=` (1 or 0) and `if(cond, a, b)` (a where cond ≠ 0, else b).
//!
//! Compiled once, evaluated at every quadrature point: the arithmetic is
//! [exmex](https://crates.io/crates/exmex)'s `FlatEx` (a flattened operator
//! list evaluated on a slice of variable values, no re-parsing). exmex is
//! maintained (MIT/Apache, 2025 releases), takes user operators (our
//! comparisons, `pi`, `min`/`max` in call syntax) and number formats; evalexpr
//! is AGPL and evaluates a dynamically typed tree, fasteval and meval are
//! unmaintained. exmex has no three-argument function and gives no positions,
//! so a small front end here tokenizes the text first: it names the position
//! of every error, gives unary minus its usual meaning (`-x^2` = −(x²), exmex
//! binds it tighter), and compiles each `if(c, a, b)` as its own node whose
//! value the enclosing `FlatEx` reads as a variable.
//!
//! [`Expression::freefem`] writes the same formula in FreeFEM's syntax (`ln` →
//! `log`, `if` → `? :`, `r` → `sqrt(x^2+y^2)`), for the FreeFEM twin.

use exmex::{
    literal_matcher_from_pattern, BinOp, Express, FlatEx, MakeOperators, MatchLiteral, Operator,
};
use serde::Deserialize;

type Function = fn(f64) -> f64;

/// The functions of one argument, by scene name.
const UNARY: [(&str, Function); 7] = [
    ("sqrt", f64::sqrt),
    ("exp", f64::exp),
    ("ln", f64::ln),
    ("sin", f64::sin),
    ("cos", f64::cos),
    ("tan", f64::tan),
    ("abs", f64::abs),
];
const KNOWN: &str =
    "variables x, y, r; constant pi; functions sqrt exp ln sin cos tan abs min max atan2 if";

fn comparison(prio: i64, apply: fn(f64, f64) -> f64) -> BinOp<f64> {
    BinOp {
        apply,
        prio,
        is_commutative: false,
    }
}

/// The operators exmex compiles: its float arithmetic (same priorities) and
/// ours; comparisons bind loosest.
#[derive(Clone, Debug)]
struct SceneOps;
impl MakeOperators<f64> for SceneOps {
    fn make<'a>() -> Vec<Operator<'a, f64>> {
        let bin = |apply: fn(f64, f64) -> f64, prio, is_commutative| BinOp {
            apply,
            prio,
            is_commutative,
        };
        let mut ops = vec![
            Operator::make_bin("^", bin(f64::powf, 4, false)),
            Operator::make_bin("*", bin(|a, b| a * b, 2, true)),
            Operator::make_bin("/", bin(|a, b| a / b, 3, false)),
            Operator::make_bin_unary("+", bin(|a, b| a + b, 0, true), |a| a),
            Operator::make_bin_unary("-", bin(|a, b| a - b, 1, false), |a| -a),
            Operator::make_bin("min", bin(f64::min, 0, false)),
            Operator::make_bin("max", bin(f64::max, 0, false)),
            Operator::make_bin("atan2", bin(f64::atan2, 0, false)),
            Operator::make_bin("<=", comparison(-1, |a, b| f64::from(a <= b))),
            Operator::make_bin(">=", comparison(-1, |a, b| f64::from(a >= b))),
            Operator::make_bin("<", comparison(-1, |a, b| f64::from(a < b))),
            Operator::make_bin(">", comparison(-1, |a, b| f64::from(a > b))),
            Operator::make_constant("pi", std::f64::consts::PI),
        ];
        ops.extend(UNARY.iter().map(|&(name, f)| Operator::make_unary(name, f)));
        ops
    }
}

// Numbers with exponents (exmex's default matcher has none); the front end
// has checked each literal already.
literal_matcher_from_pattern!(
    SceneNumber,
    r"^([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?"
);

type Compiled = FlatEx<f64, SceneOps, SceneNumber>;

/// What a compiled piece reads for each of its variables (exmex orders them by name).
#[derive(Clone, Debug)]
enum Input {
    X,
    Y,
    R,
    Branch(Box<Node>),
}

#[derive(Clone, Debug)]
enum Node {
    Constant(f64),
    Formula {
        compiled: Box<Compiled>,
        inputs: Vec<Input>,
    },
    If(Box<[Node; 3]>),
}

/// At most this many variables (x, y, r and `if(...)` values) in one piece.
const MAX_INPUTS: usize = 16;

impl Node {
    fn eval(&self, x: f64, y: f64, r: f64) -> f64 {
        match self {
            Node::Constant(v) => *v,
            Node::Formula { compiled, inputs } => {
                let mut values = [0.0; MAX_INPUTS];
                for (v, input) in values.iter_mut().zip(inputs) {
                    *v = match input {
                        Input::X => x,
                        Input::Y => y,
                        Input::R => r,
                        Input::Branch(node) => node.eval(x, y, r),
                    };
                }
                compiled.eval(&values[..inputs.len()]).unwrap_or(f64::NAN)
            }
            Node::If(parts) => {
                let cond = parts[0].eval(x, y, r);
                if cond.is_nan() {
                    f64::NAN
                } else if cond != 0.0 {
                    parts[1].eval(x, y, r)
                } else {
                    parts[2].eval(x, y, r)
                }
            }
        }
    }
}

/// A scalar of a scene: a number or a compiled expression in x, y, r.
#[derive(Clone, Debug)]
pub struct Expression {
    /// The text as written (a number's shortest representation).
    text: String,
    /// The same formula in FreeFEM's syntax.
    freefem: String,
    root: Node,
}

impl Expression {
    pub fn constant(v: f64) -> Expression {
        Expression {
            text: format!("{v:?}"),
            freefem: format!("({v:e})"),
            root: Node::Constant(v),
        }
    }

    /// Compiles `text`; the error says where (1-based character) and why.
    pub fn parse(text: &str) -> Result<Expression, String> {
        let tokens = tokenize(text).map_err(|(at, reason)| locate(text, at, &reason))?;
        let (root, freefem) =
            compile(&tokens, 0, tokens.len()).map_err(|(at, reason)| locate(text, at, &reason))?;
        // A formula without variables is a number: evaluated once.
        let root = match root {
            Node::Formula { ref inputs, .. } if inputs.is_empty() => {
                Node::Constant(root.eval(0.0, 0.0, 0.0))
            }
            node => node,
        };
        Ok(Expression {
            text: text.to_string(),
            freefem,
            root,
        })
    }

    /// The value at the point (x, y).
    pub fn eval(&self, p: [f64; 2]) -> f64 {
        match &self.root {
            Node::Constant(v) => *v,
            node => node.eval(p[0], p[1], p[0].hypot(p[1])),
        }
    }

    /// The value when the expression is a number.
    pub fn as_constant(&self) -> Option<f64> {
        match self.root {
            Node::Constant(v) => Some(v),
            _ => None,
        }
    }

    /// The text as written in the scene.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The formula in FreeFEM's syntax (a `func` body in x, y).
    pub fn freefem(&self) -> &str {
        &self.freefem
    }

    /// The first of `points` where the value is not a finite number: the
    /// error names the scene key, the point and the value.
    pub fn check_finite_at(
        &self,
        key: &str,
        points: impl IntoIterator<Item = [f64; 2]>,
    ) -> Result<(), String> {
        if let Some(v) = self.as_constant() {
            return if v.is_finite() {
                Ok(())
            } else {
                Err(format!("{key} = {v} is not a finite number"))
            };
        }
        for p in points {
            let v = self.eval(p);
            if !v.is_finite() {
                return Err(format!(
                    "{key} = \"{}\" is {v} at the point ({:.6}, {:.6}): the expression must be a finite number everywhere on the mesh",
                    self.text, p[0], p[1]
                ));
            }
        }
        Ok(())
    }
}

/// A number (TOML integer or float) or an expression string.
impl<'de> Deserialize<'de> for Expression {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = Expression;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or an expression in x, y, r (a string)")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Expression, E> {
                Ok(Expression::constant(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Expression, E> {
                Ok(Expression::constant(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Expression, E> {
                Ok(Expression::constant(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Expression, E> {
                Expression::parse(v).map_err(E::custom)
            }
        }
        d.deserialize_any(Visitor)
    }
}

fn locate(text: &str, at: usize, reason: &str) -> String {
    format!("expression \"{text}\", at character {}: {reason}", at + 1)
}

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Number(String),
    Name(String),
    /// `+ - * / ^ < <= > >=`
    Op(&'static str),
    Open,
    Close,
    Comma,
}

/// Tokens with their character positions.
fn tokenize(text: &str) -> Result<Vec<(usize, Token)>, (usize, String)> {
    let chars: Vec<char> = text.chars().collect();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let start = i;
        let token = match c {
            _ if c.is_whitespace() => {
                i += 1;
                continue;
            }
            '0'..='9' | '.' => {
                while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
                    i += 1;
                }
                if i < chars.len() && matches!(chars[i], 'e' | 'E') {
                    let mut j = i + 1;
                    if j < chars.len() && matches!(chars[j], '+' | '-') {
                        j += 1;
                    }
                    if j < chars.len() && chars[j].is_ascii_digit() {
                        i = j;
                        while i < chars.len() && chars[i].is_ascii_digit() {
                            i += 1;
                        }
                    }
                }
                let number: String = chars[start..i].iter().collect();
                if number.parse::<f64>().is_err() || number.starts_with("..") {
                    return Err((start, format!("`{number}` is not a number")));
                }
                Token::Number(number)
            }
            _ if c.is_ascii_alphabetic() || c == '_' => {
                while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '_') {
                    i += 1;
                }
                Token::Name(chars[start..i].iter().collect())
            }
            '<' | '>' => {
                let or_equal = chars.get(i + 1) == Some(&'=');
                i += 1 + usize::from(or_equal);
                Token::Op(match (c, or_equal) {
                    ('<', false) => "<",
                    ('<', true) => "<=",
                    ('>', false) => ">",
                    _ => ">=",
                })
            }
            '+' | '-' | '*' | '/' | '^' | '(' | ')' | ',' => {
                i += 1;
                match c {
                    '+' => Token::Op("+"),
                    '-' => Token::Op("-"),
                    '*' => Token::Op("*"),
                    '/' => Token::Op("/"),
                    '^' => Token::Op("^"),
                    '(' => Token::Open,
                    ')' => Token::Close,
                    _ => Token::Comma,
                }
            }
            _ => {
                return Err((
                    start,
                    format!("unexpected character `{c}` (the language: numbers, + - * / ^, < <= > >=, parentheses, {KNOWN})"),
                ))
            }
        };
        tokens.push((start, token));
    }
    Ok(tokens)
}

/// The index of the `)` closing the `(` at `open`, and the top-level commas between.
fn closing(
    tokens: &[(usize, Token)],
    open: usize,
    end: usize,
) -> Result<(usize, Vec<usize>), (usize, String)> {
    let mut depth = 0;
    let mut commas = Vec::new();
    for (k, (_, t)) in tokens.iter().enumerate().take(end).skip(open) {
        match t {
            Token::Open => depth += 1,
            Token::Close => {
                depth -= 1;
                if depth == 0 {
                    return Ok((k, commas));
                }
            }
            Token::Comma if depth == 1 => commas.push(k),
            _ => {}
        }
    }
    Err((tokens[open].0, "this parenthesis is never closed".into()))
}

/// Compiles tokens[a..b] into a node and its FreeFEM text.
fn compile(
    tokens: &[(usize, Token)],
    a: usize,
    b: usize,
) -> Result<(Node, String), (usize, String)> {
    let position = |k: usize| {
        tokens
            .get(k)
            .map_or_else(|| tokens.last().map_or(0, |t| t.0 + 1), |t| t.0)
    };
    if a >= b {
        return Err((position(a), "an expression is missing here".into()));
    }
    let mut exmex_text = String::new();
    let mut freefem = String::new();
    let mut branches: Vec<Node> = Vec::new();
    let mut depth = 0i64;
    // A comma is legal inside min(...), max(...) and atan2(...) only: the depths of their parentheses.
    let mut call_depths: Vec<i64> = Vec::new();
    let mut k = a;
    while k < b {
        let (at, token) = &tokens[k];
        let previous = (k > a).then(|| &tokens[k - 1].1);
        let operand_expected = matches!(
            previous,
            None | Some(Token::Open | Token::Comma | Token::Op(_))
        );
        match token {
            Token::Number(n) => {
                exmex_text.push_str(n);
                freefem.push_str(n);
            }
            Token::Name(name) => {
                let followed_by_call =
                    tokens.get(k + 1).is_some_and(|t| t.1 == Token::Open) && k + 1 < b;
                match name.as_str() {
                    "x" | "y" | "r" | "pi" if !followed_by_call => {
                        exmex_text.push_str(name);
                        freefem.push_str(if name == "r" { "sqrt(x^2+y^2)" } else { name });
                    }
                    "if" if followed_by_call => {
                        let (close, commas) = closing(tokens, k + 1, b)?;
                        if commas.len() != 2 {
                            return Err((
                                *at,
                                format!(
                                    "if(cond, a, b) takes 3 arguments, got {}",
                                    commas.len() + 1
                                ),
                            ));
                        }
                        let (c, c_ff) = compile(tokens, k + 2, commas[0])?;
                        let (t, t_ff) = compile(tokens, commas[0] + 1, commas[1])?;
                        let (e, e_ff) = compile(tokens, commas[1] + 1, close)?;
                        if branches.len() + 3 >= MAX_INPUTS {
                            return Err((
                                *at,
                                format!("more than {} if(...) side by side", MAX_INPUTS - 3),
                            ));
                        }
                        exmex_text.push_str(&format!("_if{}", branches.len()));
                        freefem.push_str(&format!("(({c_ff}) ? ({t_ff}) : ({e_ff}))"));
                        branches.push(Node::If(Box::new([c, t, e])));
                        k = close + 1;
                        continue;
                    }
                    "min" | "max" | "atan2" if followed_by_call => {
                        exmex_text.push_str(name);
                        freefem.push_str(name);
                        call_depths.push(depth + 1);
                    }
                    f if followed_by_call && UNARY.iter().any(|(n, _)| *n == f) => {
                        exmex_text.push_str(f);
                        freefem.push_str(if f == "ln" { "log" } else { f });
                    }
                    "x" | "y" | "r" | "pi" => {
                        return Err((*at, format!("`{name}` is not a function")));
                    }
                    _ if followed_by_call
                        || matches!(name.as_str(), "if" | "min" | "max" | "atan2")
                        || UNARY.iter().any(|(n, _)| n == name) =>
                    {
                        let reason = if followed_by_call {
                            "unknown function"
                        } else {
                            "a function needs its arguments in parentheses:"
                        };
                        return Err((*at, format!("{reason} `{name}` ({KNOWN})")));
                    }
                    _ => return Err((*at, format!("unknown name `{name}` ({KNOWN})"))),
                }
            }
            Token::Op(op)
                if k + 1 == b || matches!(tokens[k + 1].1, Token::Close | Token::Comma) =>
            {
                return Err((*at, format!("`{op}` needs an operand after it")));
            }
            Token::Op(op) if operand_expected && matches!(*op, "+" | "-") => {
                // A sign. exmex binds a unary minus tighter than ^ (-x^2 = x²):
                // write it as a factor −1, which is right after ( , + − < and at
                // the start, and refuse it where a factor cannot take it.
                if let Some(Token::Op(before @ ("*" | "/" | "^"))) = previous {
                    return Err((*at, format!("a sign right after `{before}`: put the signed operand in parentheses, e.g. 2*(-x)")));
                }
                if *op == "-" {
                    exmex_text.push_str("(0-1)*");
                    freefem.push_str("(-1)*");
                }
            }
            Token::Op(op) => {
                if operand_expected {
                    return Err((*at, format!("`{op}` needs an operand before it")));
                }
                exmex_text.push_str(op);
                freefem.push_str(op);
            }
            Token::Open => {
                depth += 1;
                exmex_text.push('(');
                freefem.push('(');
            }
            Token::Close => {
                if depth == 0 {
                    return Err((*at, "`)` without its `(`".into()));
                }
                if call_depths.last() == Some(&depth) {
                    call_depths.pop();
                }
                depth -= 1;
                exmex_text.push(')');
                freefem.push(')');
            }
            Token::Comma => {
                if call_depths.last() != Some(&depth) {
                    return Err((
                        *at,
                        "a comma outside min(a, b), max(a, b), atan2(y, x) or if(cond, a, b)"
                            .into(),
                    ));
                }
                exmex_text.push(',');
                freefem.push(',');
            }
        }
        k += 1;
    }
    if depth > 0 {
        let open = (a..b)
            .rev()
            .find(|&k| tokens[k].1 == Token::Open)
            .unwrap_or(a);
        return Err((position(open), "this parenthesis is never closed".into()));
    }
    let compiled = Compiled::parse(&exmex_text).map_err(|e| (position(a), e.msg().to_string()))?;
    let mut branches: Vec<Option<Node>> = branches.into_iter().map(Some).collect();
    let inputs = compiled
        .var_names()
        .iter()
        .map(|name| match name.as_str() {
            "x" => Input::X,
            "y" => Input::Y,
            "r" => Input::R,
            branch => {
                let i: usize = branch
                    .trim_start_matches("_if")
                    .parse()
                    .expect("our placeholder");
                Input::Branch(Box::new(branches[i].take().expect("each placeholder once")))
            }
        })
        .collect();
    let compiled = Box::new(compiled);
    Ok((Node::Formula { compiled, inputs }, format!("({freefem})")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(text: &str, x: f64, y: f64) -> f64 {
        Expression::parse(text).unwrap().eval([x, y])
    }

    #[test]
    fn evaluates_the_language() {
        let (x, y): (f64, f64) = (0.3, -0.7);
        let r = x.hypot(y);
        let cases: [(&str, f64); 15] = [
            ("1 + 2*3", 7.0),
            ("2e-3*x", 2e-3 * x),
            ("-x^2", -(x * x)),
            ("1 - -x", 1.0 + x),
            ("x - y - 1", x - y - 1.0),
            ("8 / 2 / 2", 2.0),
            ("2*pi*r", 2.0 * std::f64::consts::PI * r),
            (
                "sqrt(abs(y)) + exp(x) + ln(2)",
                (-y).sqrt() + x.exp() + 2f64.ln(),
            ),
            ("sin(x)^2 + cos(x)^2", 1.0),
            ("min(x, y) + max(x, 2*y)", y + x),
            (
                "atan2(y, x) + atan2(1, -1)",
                y.atan2(x) + 0.75 * std::f64::consts::PI,
            ),
            ("if(x < 0.5, 1, 2) + if(y >= 0, 10, 20)", 21.0),
            ("if(r <= 1, sqrt(1 - r^2), 0)", (1.0 - r * r).sqrt()),
            ("(x > 0) * 3", 3.0),
            ("if(x > 0, if(y > 0, 1, 2), 3)", 2.0),
        ];
        for (text, want) in cases {
            let got = at(text, x, y);
            assert!((got - want).abs() < 1e-14, "{text}: {got} vs {want}");
        }
        // The branch not taken may be undefined.
        assert_eq!(at("if(r < 1, ln(1 - r), 0)", 3.0, 0.0), 0.0);
        assert_eq!(Expression::parse(" 2.5 ").unwrap().as_constant(), Some(2.5));
        assert_eq!(Expression::parse("-2*3").unwrap().as_constant(), Some(-6.0));
    }

    #[test]
    fn atan2_is_the_angle_in_every_quadrant() {
        // atan2(y, x) is a two-argument call: exmex must not read it as tan.
        let e = Expression::parse("atan2(y, x)").unwrap();
        for (x, y) in [
            (1.0, 0.0),
            (1.0, 1.0),
            (-1.0, 1.0),
            (-1.0, -1e-9),
            (0.0, -2.0),
        ] {
            assert_eq!(e.eval([x, y]), f64::atan2(y, x), "({x}, {y})");
        }
        assert_eq!(e.eval([-1.0, 0.0]), std::f64::consts::PI);
        assert_eq!(e.freefem(), "(atan2(y,x))");
        let m = Expression::parse("atan2(y)").unwrap_err();
        assert!(m.contains("character 1"), "{m}");
    }

    #[test]
    fn errors_name_the_position_and_the_reason() {
        let cases = [
            ("1 + foo(x)", "character 5", "unknown function `foo`"),
            ("1 + z", "character 5", "unknown name `z`"),
            ("(x + 1", "character 1", "never closed"),
            ("x + 1)", "character 6", "without its"),
            ("x $ 2", "character 3", "unexpected character `$`"),
            ("2*-x", "character 3", "a sign right after `*`"),
            ("if(x, 1)", "character 1", "3 arguments, got 2"),
            ("x +", "character 3", "operand after"),
            ("sqrt", "character 1", "parentheses"),
            ("1, 2", "character 2", "comma"),
            ("", "character 1", "missing"),
        ];
        for (text, position, reason) in cases {
            let m = Expression::parse(text).expect_err(text);
            assert!(m.contains(position) && m.contains(reason), "{text}: {m}");
        }
    }

    #[test]
    fn non_finite_values_name_the_key_and_the_point() {
        let e = Expression::parse("1/x").unwrap();
        let m = e
            .check_finite_at("load.g", [[1.0, 0.0], [0.0, 0.5]])
            .unwrap_err();
        assert!(
            m.contains("load.g") && m.contains("(0.000000, 0.500000)") && m.contains("inf"),
            "{m}"
        );
        assert!(e.check_finite_at("load.g", [[1.0, 0.0]]).is_ok());
    }

    #[test]
    fn freefem_syntax() {
        let e = Expression::parse("if(r < 1, ln(2)*x^2, -y)").unwrap();
        assert_eq!(
            e.freefem(),
            "((((sqrt(x^2+y^2)<1)) ? ((log(2)*x^2)) : (((-1)*y))))"
        );
        assert_eq!(Expression::constant(-4.0).freefem(), "(-4e0)");
    }
}
