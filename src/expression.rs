//! Scene data as expressions in the coordinates: a number, or a formula in
//! `x`, `y` and `r` = √(x² + y²). The grammar is docs/expressions.md.
//!
//! One recursive-descent parser reads the text into one tree (no string
//! rewriting); everything else works on that tree:
//!
//! * [`Expression::eval`] evaluates it at a point: the nodes are stored
//!   children before parents, so one pass in storage order computes every
//!   node from values already computed: no recursion, cost linear in the size;
//! * [`Expression::derivative`] builds the exact partial derivative ∂/∂x or
//!   ∂/∂y as another expression (symbolic differentiation on the same tree;
//!   the shell's charts need first and second derivatives);
//! * [`Expression::freefem`] prints it in FreeFEM's syntax for the FreeFEM
//!   twin, and `Display` prints it in the scene's own syntax (the property
//!   tests parse what it prints).
//!
//! The conventions are those of mathematics and of FreeFEM: `^` is
//! right-associative and binds tighter than a sign (`-x^2` = −(x²), `2^3^2` =
//! 2⁹), blanks only separate tokens (`1 2` is an error, never 12). Nesting
//! (parentheses, calls, signs, powers) deeper than [`MAX_NESTING`] is an error,
//! so the parser's recursion is bounded on any thread's stack; a long flat sum
//! is no nesting and costs no recursion anywhere.
//!
//! Why a parser of our own rather than an expression crate: exmex (MIT/Apache)
//! has no three-argument function (`if`), no positions in its errors and a
//! left-associative `^`; evalexpr is AGPL; and the tree a parser builds is
//! what exact derivatives and the FreeFEM printer need anyway.

use serde::Deserialize;
use std::fmt;

/// Data values beyond this magnitude are refused: assembly and the solvers
/// multiply a few of them (E ε³, g × area, squares in norms), which must stay
/// within f64.
pub const MAGNITUDE_LIMIT: f64 = 1e100;

/// Nesting levels the parser accepts (parentheses, function calls, signs and
/// powers each add one).
pub const MAX_NESTING: usize = 200;

/// Nodes an expression (with its derivatives) may have.
const MAX_NODES: usize = 4_000_000;

/// A coordinate an expression reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variable {
    X,
    Y,
    /// r = √(x² + y²).
    R,
}

/// Functions of one argument.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Function {
    Sqrt,
    Exp,
    Ln,
    Sin,
    Cos,
    Tan,
    Asin,
    Acos,
    Atan,
    Sinh,
    Cosh,
    Tanh,
    Abs,
}

const FUNCTIONS: [(&str, Function); 13] = [
    ("sqrt", Function::Sqrt),
    ("exp", Function::Exp),
    ("ln", Function::Ln),
    ("sin", Function::Sin),
    ("cos", Function::Cos),
    ("tan", Function::Tan),
    ("asin", Function::Asin),
    ("acos", Function::Acos),
    ("atan", Function::Atan),
    ("sinh", Function::Sinh),
    ("cosh", Function::Cosh),
    ("tanh", Function::Tanh),
    ("abs", Function::Abs),
];

impl Function {
    fn apply(self, a: f64) -> f64 {
        match self {
            Function::Sqrt => a.sqrt(),
            Function::Exp => a.exp(),
            Function::Ln => a.ln(),
            Function::Sin => a.sin(),
            Function::Cos => a.cos(),
            Function::Tan => a.tan(),
            Function::Asin => a.asin(),
            Function::Acos => a.acos(),
            Function::Atan => a.atan(),
            Function::Sinh => a.sinh(),
            Function::Cosh => a.cosh(),
            Function::Tanh => a.tanh(),
            Function::Abs => a.abs(),
        }
    }

    fn name(self) -> &'static str {
        FUNCTIONS
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("?", |p| p.0)
    }

    fn freefem_name(self) -> &'static str {
        match self {
            Function::Ln => "log",
            f => f.name(),
        }
    }
}

/// Operators of two operands: arithmetic, comparisons (1 or 0), and the
/// two-argument functions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Binary {
    Add,
    Sub,
    Mul,
    Div,
    Pow,
    Lt,
    Le,
    Gt,
    Ge,
    Min,
    Max,
    Atan2,
}

impl Binary {
    fn apply(self, a: f64, b: f64) -> f64 {
        // A comparison with NaN is NaN, so an undefined condition is caught as
        // a non-finite value, never read as "false".
        let compare = |holds: bool| {
            if a.is_nan() || b.is_nan() {
                f64::NAN
            } else {
                f64::from(holds)
            }
        };
        match self {
            Binary::Add => a + b,
            Binary::Sub => a - b,
            Binary::Mul => a * b,
            Binary::Div => a / b,
            // x² as a product: correctly rounded, where libm's pow is within
            // 0.52 ulp, and several times cheaper (r^2 is in most scenes).
            Binary::Pow if b == 2.0 => a * a,
            Binary::Pow => a.powf(b),
            Binary::Lt => compare(a < b),
            Binary::Le => compare(a <= b),
            Binary::Gt => compare(a > b),
            Binary::Ge => compare(a >= b),
            Binary::Min => a.min(b),
            Binary::Max => a.max(b),
            Binary::Atan2 => a.atan2(b),
        }
    }

    /// The infix symbol, or None for a call (`min(a, b)`).
    fn symbol(self) -> Option<&'static str> {
        Some(match self {
            Binary::Add => "+",
            Binary::Sub => "-",
            Binary::Mul => "*",
            Binary::Div => "/",
            Binary::Pow => "^",
            Binary::Lt => "<",
            Binary::Le => "<=",
            Binary::Gt => ">",
            Binary::Ge => ">=",
            Binary::Min | Binary::Max | Binary::Atan2 => return None,
        })
    }

    fn call_name(self) -> &'static str {
        match self {
            Binary::Min => "min",
            Binary::Max => "max",
            _ => "atan2",
        }
    }

    /// Binding strength of an infix operator (higher binds tighter).
    fn precedence(self) -> u8 {
        match self {
            Binary::Lt | Binary::Le | Binary::Gt | Binary::Ge => 1,
            Binary::Add | Binary::Sub => 2,
            Binary::Mul | Binary::Div => 3,
            Binary::Pow => 5,
            Binary::Min | Binary::Max | Binary::Atan2 => 7,
        }
    }
}

/// Precedence of a sign (between `*` and `^`: `-x^2` = −(x²), `-x*y` = (−x)y).
const SIGN_PRECEDENCE: u8 = 4;
/// Precedence of a number, a variable or a call.
const ATOM_PRECEDENCE: u8 = 7;

/// A node of the tree; children are indices of nodes stored before it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Node {
    Number(f64),
    Variable(Variable),
    Neg(u32),
    Unary(Function, u32),
    Binary(Binary, u32, u32),
    /// if(cond, a, b): a where cond ≠ 0, else b; NaN where cond is NaN.
    If(u32, u32, u32),
}

impl Node {
    fn children(&self) -> impl Iterator<Item = usize> {
        let (list, n): ([u32; 3], usize) = match *self {
            Node::Number(_) | Node::Variable(_) => ([0; 3], 0),
            Node::Neg(a) | Node::Unary(_, a) => ([a, 0, 0], 1),
            Node::Binary(_, a, b) => ([a, b, 0], 2),
            Node::If(c, a, b) => ([c, a, b], 3),
        };
        list.into_iter().take(n).map(|i| i as usize)
    }

    /// The same node with every child index i replaced by `m(i)`.
    fn map_children(self, m: impl Fn(u32) -> u32) -> Node {
        match self {
            Node::Neg(a) => Node::Neg(m(a)),
            Node::Unary(f, a) => Node::Unary(f, m(a)),
            Node::Binary(op, a, b) => Node::Binary(op, m(a), m(b)),
            Node::If(c, a, b) => Node::If(m(c), m(a), m(b)),
            leaf => leaf,
        }
    }

    /// What identifies the node's computation: equal keys, equal values
    /// (a number by its bits, so a NaN matches itself).
    fn key(&self) -> (u8, u64, [u32; 3]) {
        match *self {
            Node::Number(v) => (0, v.to_bits(), [0; 3]),
            Node::Variable(v) => (1, v as u64, [0; 3]),
            Node::Neg(a) => (2, 0, [a, 0, 0]),
            Node::Unary(f, a) => (3, f as u64, [a, 0, 0]),
            Node::Binary(op, a, b) => (4, op as u64, [a, b, 0]),
            Node::If(c, a, b) => (5, 0, [c, a, b]),
        }
    }

    fn precedence(&self) -> u8 {
        match self {
            Node::Neg(_) => SIGN_PRECEDENCE,
            Node::Number(v) if *v < 0.0 || v.is_sign_negative() => SIGN_PRECEDENCE,
            Node::Binary(op, ..) => op.precedence(),
            _ => ATOM_PRECEDENCE,
        }
    }
}

/// The nodes of one expression, children before parents; the last is the root.
#[derive(Clone, Debug, Default, PartialEq)]
struct Tree {
    nodes: Vec<Node>,
}

impl Tree {
    fn root(&self) -> usize {
        self.nodes.len() - 1
    }

    fn push(&mut self, node: Node) -> Result<u32, String> {
        if self.nodes.len() >= MAX_NODES {
            return Err(format!("more than {MAX_NODES} terms"));
        }
        self.nodes.push(node);
        Ok((self.nodes.len() - 1) as u32)
    }

    fn number(&self, i: u32) -> Option<f64> {
        match self.nodes[i as usize] {
            Node::Number(v) => Some(v),
            _ => None,
        }
    }

    /// Adds `node`, folding it to a number when all its operands are numbers
    /// (the same arithmetic as evaluation, so folding changes no value).
    fn add(&mut self, node: Node) -> Result<u32, String> {
        let folded = match node {
            Node::Neg(a) => self.number(a).map(|v| -v),
            Node::Unary(f, a) => self.number(a).map(|v| f.apply(v)),
            Node::Binary(op, a, b) => match (self.number(a), self.number(b)) {
                (Some(u), Some(v)) => Some(op.apply(u, v)),
                _ => None,
            },
            Node::If(c, a, b) => match self.number(c) {
                Some(c) if c.is_nan() => Some(f64::NAN),
                Some(c) => return Ok(if c != 0.0 { a } else { b }),
                None => None,
            },
            _ => None,
        };
        self.push(folded.map_or(node, Node::Number))
    }

    /// Adds `node` with the algebra of 0 and 1 (x + 0 = x, 0·x = 0, …), used
    /// for derivatives only: a derivative that is 0 stays exactly 0 where the
    /// other factor is infinite (∂/∂y √x at x = 0).
    fn add_simplified(&mut self, node: Node) -> Result<u32, String> {
        let is = |i: u32, v: f64| self.number(i) == Some(v);
        let simplified = match node {
            Node::Binary(Binary::Add, a, b) if is(a, 0.0) => Some(b),
            Node::Binary(Binary::Add | Binary::Sub, a, b) if is(b, 0.0) => Some(a),
            Node::Binary(Binary::Sub, a, b) if is(a, 0.0) => {
                return self.add_simplified(Node::Neg(b))
            }
            Node::Binary(Binary::Mul, a, b) if is(a, 0.0) || is(b, 0.0) => {
                return self.add(Node::Number(0.0))
            }
            Node::Binary(Binary::Div, a, _) if is(a, 0.0) => return self.add(Node::Number(0.0)),
            Node::Binary(Binary::Mul, a, b) if is(a, 1.0) => Some(b),
            Node::Binary(Binary::Mul | Binary::Div, a, b) if is(b, 1.0) => Some(a),
            Node::Neg(a) => match self.nodes[a as usize] {
                Node::Neg(inner) => Some(inner),
                _ => None,
            },
            Node::If(_, a, b) if a == b => Some(a),
            _ => None,
        };
        match simplified {
            Some(i) => Ok(i),
            None => self.add(node),
        }
    }

    /// Keeps only the nodes the root reaches, in the same order.
    fn pruned(&self) -> Tree {
        let mut reached = vec![false; self.nodes.len()];
        reached[self.root()] = true;
        for i in (0..self.nodes.len()).rev() {
            if reached[i] {
                for c in self.nodes[i].children() {
                    reached[c] = true;
                }
            }
        }
        let mut index = vec![0u32; self.nodes.len()];
        let mut nodes = Vec::new();
        for (i, node) in self.nodes.iter().enumerate() {
            if reached[i] {
                let position = nodes.len() as u32;
                nodes.push(node.map_children(|c| index[c as usize]));
                index[i] = position;
            }
        }
        Tree { nodes }
    }

    /// The exact partial derivative with respect to `var` (x or y).
    fn derivative(&self, var: Variable) -> Result<Tree, String> {
        let mut t = self.clone();
        // d[i]: the node of ∂(node i)/∂var, built in storage order so every
        // operand's derivative exists when its parent's is built.
        let mut d: Vec<u32> = Vec::with_capacity(self.nodes.len());
        for (i, node) in self.nodes.iter().enumerate() {
            let me = i as u32;
            let di = match *node {
                Node::Number(_) => t.add(Node::Number(0.0))?,
                Node::Variable(v) if v == var => t.add(Node::Number(1.0))?,
                Node::Variable(Variable::R) => {
                    // ∂r/∂x = x/r, ∂r/∂y = y/r.
                    let coordinate = t.add(Node::Variable(var))?;
                    t.add(Node::Binary(Binary::Div, coordinate, me))?
                }
                Node::Variable(_) => t.add(Node::Number(0.0))?,
                Node::Neg(a) => t.add_simplified(Node::Neg(d[a as usize]))?,
                Node::Unary(f, a) => {
                    let da = d[a as usize];
                    if t.number(da) == Some(0.0) {
                        da
                    } else {
                        let slope = unary_slope(&mut t, f, a, me)?;
                        t.add_simplified(Node::Binary(Binary::Mul, slope, da))?
                    }
                }
                Node::Binary(Binary::Pow, a, b)
                    if self.nodes[a as usize] == Node::Variable(Variable::R) =>
                {
                    radial_power_derivative(&mut t, var, a, b, me, &d)?
                }
                Node::Binary(op, a, b) => binary_derivative(&mut t, op, a, b, me, &d)?,
                Node::If(c, a, b) => t.add_simplified(Node::If(c, d[a as usize], d[b as usize]))?,
            };
            d.push(di);
        }
        let root = d[self.root()];
        t.finished(root)
    }

    /// The tree of the node `root` alone: `root` last (a copy of it where
    /// folding or simplifying returned an earlier node), unreached nodes dropped.
    fn finished(mut self, root: u32) -> Result<Tree, String> {
        if root as usize != self.root() {
            let node = self.nodes[root as usize];
            self.push(node)?;
        }
        Ok(self.pruned())
    }
}

/// A tree made ready for evaluation: every number's value stored once,
/// every other node one step that computes it from earlier nodes' values
/// (the arithmetic dispatched once per node, a square as a product).
#[derive(Clone, Debug, Default)]
struct Program {
    /// One value per node: the numbers' values, 0 where a step computes it.
    initial: Vec<f64>,
    /// (node, how it is computed) for every node but the numbers, in storage order.
    steps: Vec<(u32, Step)>,
    /// Whether a node reads r (then r = hypot(x, y) is computed once per point).
    reads_r: bool,
}

/// How a node other than a number is computed, from the values of the nodes named.
#[derive(Clone, Copy, Debug)]
enum Step {
    X,
    Y,
    R,
    Neg(u32),
    Unary(Function, u32),
    Add(u32, u32),
    Sub(u32, u32),
    Mul(u32, u32),
    Div(u32, u32),
    /// a^2 with the exponent the number 2 ([`Binary::apply`]'s product).
    Square(u32),
    /// The other operators, through [`Binary::apply`].
    Binary(Binary, u32, u32),
    If(u32, u32, u32),
}

impl Program {
    fn of(tree: &Tree) -> Program {
        let mut initial = vec![0.0; tree.nodes.len()];
        let mut steps = Vec::new();
        for (i, node) in tree.nodes.iter().enumerate() {
            let step = match *node {
                Node::Number(v) => {
                    initial[i] = v;
                    continue;
                }
                Node::Variable(Variable::X) => Step::X,
                Node::Variable(Variable::Y) => Step::Y,
                Node::Variable(Variable::R) => Step::R,
                Node::Neg(a) => Step::Neg(a),
                Node::Unary(f, a) => Step::Unary(f, a),
                Node::Binary(Binary::Add, a, b) => Step::Add(a, b),
                Node::Binary(Binary::Sub, a, b) => Step::Sub(a, b),
                Node::Binary(Binary::Mul, a, b) => Step::Mul(a, b),
                Node::Binary(Binary::Div, a, b) => Step::Div(a, b),
                Node::Binary(Binary::Pow, a, b) if tree.number(b) == Some(2.0) => Step::Square(a),
                Node::Binary(op, a, b) => Step::Binary(op, a, b),
                Node::If(c, a, b) => Step::If(c, a, b),
            };
            steps.push((i as u32, step));
        }
        let reads_r = steps.iter().any(|(_, step)| matches!(step, Step::R));
        Program {
            initial,
            steps,
            reads_r,
        }
    }

    /// Every node's value at (x, y) into `values`, which holds
    /// [`Program::initial`]'s numbers (the steps never write them).
    fn run(&self, x: f64, y: f64, values: &mut [f64]) {
        let r = if self.reads_r { x.hypot(y) } else { 0.0 };
        for &(i, step) in &self.steps {
            let v = |j: u32| values[j as usize];
            values[i as usize] = match step {
                Step::X => x,
                Step::Y => y,
                Step::R => r,
                Step::Neg(a) => -v(a),
                Step::Unary(f, a) => f.apply(v(a)),
                Step::Add(a, b) => v(a) + v(b),
                Step::Sub(a, b) => v(a) - v(b),
                Step::Mul(a, b) => v(a) * v(b),
                Step::Div(a, b) => v(a) / v(b),
                Step::Square(a) => v(a) * v(a),
                Step::Binary(op, a, b) => op.apply(v(a), v(b)),
                Step::If(c, a, b) => {
                    let c = v(c);
                    if c.is_nan() {
                        f64::NAN
                    } else if c != 0.0 {
                        v(a)
                    } else {
                        v(b)
                    }
                }
            };
        }
    }
}

/// f′(a) for the node `me` = f(a).
fn unary_slope(t: &mut Tree, f: Function, a: u32, me: u32) -> Result<u32, String> {
    use Binary::{Add, Div, Mul, Sub};
    let one = t.add(Node::Number(1.0))?;
    Ok(match f {
        // 1/(2√a)
        Function::Sqrt => {
            let two = t.add(Node::Number(2.0))?;
            let twice = t.add(Node::Binary(Mul, two, me))?;
            t.add(Node::Binary(Div, one, twice))?
        }
        Function::Exp => me,
        Function::Ln => t.add(Node::Binary(Div, one, a))?,
        Function::Sin => t.add(Node::Unary(Function::Cos, a))?,
        Function::Cos => {
            let s = t.add(Node::Unary(Function::Sin, a))?;
            t.add(Node::Neg(s))?
        }
        // 1 + tan², 1 − tanh²
        Function::Tan | Function::Tanh => {
            let square = t.add(Node::Binary(Mul, me, me))?;
            let op = if f == Function::Tan { Add } else { Sub };
            t.add(Node::Binary(op, one, square))?
        }
        // ±1/√(1 − a²)
        Function::Asin | Function::Acos => {
            let square = t.add(Node::Binary(Mul, a, a))?;
            let rest = t.add(Node::Binary(Sub, one, square))?;
            let root = t.add(Node::Unary(Function::Sqrt, rest))?;
            let slope = t.add(Node::Binary(Div, one, root))?;
            if f == Function::Asin {
                slope
            } else {
                t.add(Node::Neg(slope))?
            }
        }
        // 1/(1 + a²)
        Function::Atan => {
            let square = t.add(Node::Binary(Mul, a, a))?;
            let sum = t.add(Node::Binary(Add, one, square))?;
            t.add(Node::Binary(Div, one, sum))?
        }
        Function::Sinh => t.add(Node::Unary(Function::Cosh, a))?,
        Function::Cosh => t.add(Node::Unary(Function::Sinh, a))?,
        // sign(a); at a = 0 the right derivative, 1.
        Function::Abs => {
            let zero = t.add(Node::Number(0.0))?;
            let negative = t.add(Node::Binary(Binary::Lt, a, zero))?;
            let minus = t.add(Node::Number(-1.0))?;
            t.add(Node::If(negative, minus, one))?
        }
    })
}

/// ∂(r^b)/∂var = b r^(b−2) var for a constant b: finite at r = 0 for b ≥ 2
/// (r² = x² + y² is smooth there, its derivatives 2x, 2y), where the chain
/// rule through ∂r/∂x = x/r would divide by zero. A b that varies takes the
/// general rule.
fn radial_power_derivative(
    t: &mut Tree,
    var: Variable,
    r: u32,
    b: u32,
    me: u32,
    d: &[u32],
) -> Result<u32, String> {
    if t.number(d[b as usize]) != Some(0.0) {
        return binary_derivative(t, Binary::Pow, r, b, me, d);
    }
    let two = t.add(Node::Number(2.0))?;
    let lowered = t.add(Node::Binary(Binary::Sub, b, two))?;
    let power = t.add(Node::Binary(Binary::Pow, r, lowered))?;
    let slope = t.add_simplified(Node::Binary(Binary::Mul, b, power))?;
    let coordinate = t.add(Node::Variable(var))?;
    t.add_simplified(Node::Binary(Binary::Mul, slope, coordinate))
}

/// ∂(a op b) for the node `me` = a op b, with d[i] the derivative of node i.
fn binary_derivative(
    t: &mut Tree,
    op: Binary,
    a: u32,
    b: u32,
    me: u32,
    d: &[u32],
) -> Result<u32, String> {
    use Binary::*;
    let (da, db) = (d[a as usize], d[b as usize]);
    let zero = |t: &Tree, i: u32| t.number(i) == Some(0.0);
    Ok(match op {
        Add | Sub => t.add_simplified(Node::Binary(op, da, db))?,
        Mul => {
            let left = t.add_simplified(Node::Binary(Mul, da, b))?;
            let right = t.add_simplified(Node::Binary(Mul, a, db))?;
            t.add_simplified(Node::Binary(Add, left, right))?
        }
        // (da − (a/b) db)/b
        Div => {
            let q_db = t.add_simplified(Node::Binary(Mul, me, db))?;
            let top = t.add_simplified(Node::Binary(Sub, da, q_db))?;
            t.add_simplified(Node::Binary(Div, top, b))?
        }
        Pow => {
            // b a^(b−1) da where the exponent is constant in var; then
            // a^b ln(a) db where the base is; else both.
            let base_part = if zero(t, da) {
                t.add(Node::Number(0.0))?
            } else {
                let one = t.add(Node::Number(1.0))?;
                let lowered = t.add(Node::Binary(Sub, b, one))?;
                let power = t.add(Node::Binary(Pow, a, lowered))?;
                let slope = t.add_simplified(Node::Binary(Mul, b, power))?;
                t.add_simplified(Node::Binary(Mul, slope, da))?
            };
            let exponent_part = if zero(t, db) {
                t.add(Node::Number(0.0))?
            } else {
                let ln = t.add(Node::Unary(Function::Ln, a))?;
                let slope = t.add_simplified(Node::Binary(Mul, me, ln))?;
                t.add_simplified(Node::Binary(Mul, slope, db))?
            };
            t.add_simplified(Node::Binary(Add, base_part, exponent_part))?
        }
        Lt | Le | Gt | Ge => t.add(Node::Number(0.0))?,
        // The derivative of the operand that is taken (a at a tie).
        Min | Max => {
            let test = if op == Min { Le } else { Ge };
            let takes_a = t.add(Node::Binary(test, a, b))?;
            t.add_simplified(Node::If(takes_a, da, db))?
        }
        // atan2(a, b): (b da − a db)/(a² + b²)
        Atan2 => {
            let left = t.add_simplified(Node::Binary(Mul, b, da))?;
            let right = t.add_simplified(Node::Binary(Mul, a, db))?;
            let top = t.add_simplified(Node::Binary(Sub, left, right))?;
            let aa = t.add(Node::Binary(Mul, a, a))?;
            let bb = t.add(Node::Binary(Mul, b, b))?;
            let bottom = t.add(Node::Binary(Add, aa, bb))?;
            t.add_simplified(Node::Binary(Div, top, bottom))?
        }
    })
}

/// A scalar of a scene: a number or a compiled expression in x, y, r.
#[derive(Clone, Debug)]
pub struct Expression {
    /// The text as written (a number's shortest representation; a
    /// derivative's printed form).
    text: String,
    tree: Tree,
    /// `tree` made ready for evaluation.
    program: Program,
}

impl PartialEq for Expression {
    fn eq(&self, other: &Expression) -> bool {
        self.tree == other.tree
    }
}

impl Expression {
    fn new(text: String, tree: Tree) -> Expression {
        let program = Program::of(&tree);
        Expression {
            text,
            tree,
            program,
        }
    }

    pub fn constant(v: f64) -> Expression {
        let tree = Tree {
            nodes: vec![Node::Number(v)],
        };
        Expression::new(format!("{v:?}"), tree)
    }

    /// Compiles `text`; the error says where (1-based character) and why.
    pub fn parse(text: &str) -> Result<Expression, String> {
        let tokens = tokenize(text).map_err(|(at, reason)| locate(text, at, &reason))?;
        let mut parser = Parser {
            tokens: &tokens,
            next: 0,
            depth: 0,
            end: text.chars().count(),
            tree: Tree::default(),
        };
        let root = parser
            .parse_all()
            .map_err(|(at, reason)| locate(text, at, &reason))?;
        let tree = parser
            .tree
            .finished(root)
            .map_err(|reason| locate(text, 0, &reason))?;
        Ok(Expression::new(text.to_string(), tree))
    }

    /// The value at the point (x, y).
    pub fn eval(&self, p: [f64; 2]) -> f64 {
        let n = self.tree.nodes.len();
        if let [Node::Number(v)] = self.tree.nodes[..] {
            return v;
        }
        // Small expressions (nearly all scenes') evaluate on the stack.
        const ON_STACK: usize = 64;
        let evaluate = |values: &mut [f64]| {
            values.copy_from_slice(&self.program.initial);
            self.program.run(p[0], p[1], values);
            values[n - 1]
        };
        if n <= ON_STACK {
            evaluate(&mut [0.0; ON_STACK][..n])
        } else {
            thread_local! {
                static VALUES: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
            }
            VALUES.with(|values| {
                let mut values = values.borrow_mut();
                values.resize(n, 0.0);
                evaluate(&mut values)
            })
        }
    }

    /// The value when the expression is a number.
    pub fn as_constant(&self) -> Option<f64> {
        match self.tree.nodes[..] {
            [Node::Number(v)] => Some(v),
            _ => None,
        }
    }

    /// The text as written in the scene.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The exact partial derivative ∂/∂x or ∂/∂y (`var` = R is refused: r is
    /// not an independent coordinate). Where the expression is not
    /// differentiable (a kink of `abs`, `min`, `max`, a jump of `if` or a
    /// comparison) it is the derivative of the branch taken there.
    pub fn derivative(&self, var: Variable) -> Result<Expression, String> {
        if var == Variable::R {
            return Err("derivatives are taken in x or y, not r".into());
        }
        let tree = self
            .tree
            .derivative(var)
            .map_err(|e| format!("expression \"{}\": its derivative has {e}", self.text))?;
        let text = Printer::scene().print(&tree);
        Ok(Expression::new(text, tree))
    }

    /// The formula in FreeFEM's syntax (a `func` body in x, y).
    pub fn freefem(&self) -> String {
        format!("({})", Printer::freefem().print(&self.tree))
    }

    /// The first of `points` where the value is not a finite number of
    /// magnitude at most [`MAGNITUDE_LIMIT`]: the error names the scene key,
    /// the point and the value.
    pub fn check_finite_at(
        &self,
        key: &str,
        points: impl IntoIterator<Item = [f64; 2]>,
    ) -> Result<(), String> {
        if let Some(v) = self.as_constant() {
            return self.refusal(key, [0.0; 2], v).map_or(Ok(()), Err);
        }
        for p in points {
            if let Some(reason) = self.refusal(key, p, self.eval(p)) {
                return Err(reason);
            }
        }
        Ok(())
    }

    /// Why the value `v` at the point `p` is refused (see
    /// [`Expression::check_finite_at`]), or None when it is accepted.
    fn refusal(&self, key: &str, p: [f64; 2], v: f64) -> Option<String> {
        if accepted(v) {
            return None;
        }
        Some(match self.as_constant() {
            Some(c) if !c.is_finite() => format!("{key} = {c} is not a finite number"),
            Some(c) => format!("{key} = {c:e} is beyond ±1e100"),
            None => {
                let why = if v.is_finite() {
                    format!("{v:e}, beyond ±1e100")
                } else {
                    format!("{v}")
                };
                format!(
                    "{key} = \"{}\" is {why} at the point ({:.6}, {:.6}): the expression must be a finite number of magnitude at most 1e100 everywhere on the mesh",
                    self.text, p[0], p[1]
                )
            }
        })
    }
}

/// A finite number of magnitude at most [`MAGNITUDE_LIMIT`] (not NaN).
fn accepted(v: f64) -> bool {
    v.abs() <= MAGNITUDE_LIMIT
}

/// Several expressions evaluated together, each under the scene key that
/// names it in errors: one tree holds every distinct node of all of them
/// once (the terms they share, e.g. u's inside its derivatives, and r), so
/// one pass per point computes them all with the values each alone gives.
/// For data evaluated at millions of quadrature points, such as an exact
/// solution's u, ∇u and λ.
#[derive(Clone, Debug)]
pub struct ExpressionSet {
    members: Vec<(String, Expression)>,
    /// The merged tree, ready for evaluation.
    program: Program,
    /// Each member's node in the merged tree.
    roots: Vec<usize>,
}

impl ExpressionSet {
    /// The members (key, expression) merged into one tree.
    pub fn new(members: Vec<(String, Expression)>) -> ExpressionSet {
        let mut tree = Tree::default();
        let mut known = std::collections::HashMap::new();
        let mut roots = Vec::with_capacity(members.len());
        for (_, e) in &members {
            // index[i]: the merged node of the member's node i.
            let mut index: Vec<u32> = Vec::with_capacity(e.tree.nodes.len());
            for node in &e.tree.nodes {
                let node = node.map_children(|c| index[c as usize]);
                let merged = *known.entry(node.key()).or_insert_with(|| {
                    tree.nodes.push(node);
                    (tree.nodes.len() - 1) as u32
                });
                index.push(merged);
            }
            roots.push(*index.last().expect("an expression has a root") as usize);
        }
        ExpressionSet {
            members,
            program: Program::of(&tree),
            roots,
        }
    }

    /// The number of members.
    pub fn len(&self) -> usize {
        self.members.len()
    }

    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }

    /// An evaluator of the set (its scratch space reused from point to point).
    pub fn evaluator(&self) -> SetEvaluator<'_> {
        SetEvaluator {
            set: self,
            nodes: self.program.initial.clone(),
            values: vec![0.0; self.members.len()],
        }
    }

    /// The first of `points` where a member is refused as
    /// [`Expression::check_finite_at`] refuses it: (its key, the reason).
    pub fn check_finite_at(
        &self,
        points: impl IntoIterator<Item = [f64; 2]>,
    ) -> Result<(), (&str, String)> {
        let mut evaluator = self.evaluator();
        for p in points {
            evaluator.finite_at(p)?;
        }
        Ok(())
    }
}

/// Evaluates an [`ExpressionSet`] point by point without allocating.
pub struct SetEvaluator<'s> {
    set: &'s ExpressionSet,
    /// Every node's value at the last point (the numbers' from the start).
    nodes: Vec<f64>,
    /// Every member's value at the last point, in the set's order.
    values: Vec<f64>,
}

impl<'s> SetEvaluator<'s> {
    /// Every member's value at `p`, in the set's order.
    pub fn at(&mut self, p: [f64; 2]) -> &[f64] {
        self.set.program.run(p[0], p[1], &mut self.nodes);
        for (value, &root) in self.values.iter_mut().zip(&self.set.roots) {
            *value = self.nodes[root];
        }
        &self.values
    }

    /// Every member's value at `p`, or the first member (in the set's
    /// order) refused there: its key and the reason, as
    /// [`Expression::check_finite_at`] words it.
    pub fn finite_at(&mut self, p: [f64; 2]) -> Result<&[f64], (&'s str, String)> {
        let set = self.set;
        self.at(p);
        if self.values.iter().all(|&v| accepted(v)) {
            return Ok(&self.values);
        }
        for ((key, e), &v) in set.members.iter().zip(&self.values) {
            if let Some(reason) = e.refusal(key, p, v) {
                return Err((key.as_str(), reason));
            }
        }
        Ok(&self.values)
    }
}

/// Prints in the scene's syntax (parseable back to the same tree).
impl fmt::Display for Expression {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(&Printer::scene().print(&self.tree))
    }
}

/// A number (TOML integer or float) or an expression string.
impl<'de> Deserialize<'de> for Expression {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = Expression;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
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
    // Long expressions are quoted by their start only.
    let shown: String = text.chars().take(80).collect();
    let shown = if shown.len() < text.len() {
        format!("{shown}…")
    } else {
        shown
    };
    format!("expression \"{shown}\", at character {}: {reason}", at + 1)
}

const KNOWN: &str = "variables x, y, r; constant pi; functions sqrt exp ln sin cos tan asin acos atan sinh cosh tanh abs min max atan2 if";

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Number(f64),
    Name(String),
    /// `+ - * / ^ < <= > >=`
    Op(&'static str),
    Open,
    Close,
    Comma,
}

impl Token {
    fn describe(&self) -> String {
        match self {
            Token::Number(v) => format!("the number {v}"),
            Token::Name(n) => format!("`{n}`"),
            Token::Op(op) => format!("`{op}`"),
            Token::Open => "`(`".into(),
            Token::Close => "`)`".into(),
            Token::Comma => "`,`".into(),
        }
    }
}

/// Tokens with their character positions; blanks separate tokens and are
/// otherwise ignored.
fn tokenize(text: &str) -> Result<Vec<(usize, Token)>, (usize, String)> {
    let chars: Vec<char> = text.chars().collect();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let start = i;
        let digits = |i: &mut usize| {
            let from = *i;
            while *i < chars.len() && chars[*i].is_ascii_digit() {
                *i += 1;
            }
            *i > from
        };
        let token = match c {
            _ if c.is_whitespace() => {
                i += 1;
                continue;
            }
            // digits [ "." [digits] ] [exponent] | "." digits [exponent]
            '0'..='9' | '.' => {
                let whole = digits(&mut i);
                let mut fraction = false;
                if i < chars.len() && chars[i] == '.' {
                    i += 1;
                    fraction = digits(&mut i);
                }
                let mut complete = whole || fraction;
                if complete && i < chars.len() && matches!(chars[i], 'e' | 'E') {
                    i += 1;
                    if i < chars.len() && matches!(chars[i], '+' | '-') {
                        i += 1;
                    }
                    complete = digits(&mut i);
                }
                // A number runs into no letter, digit or point: `1.2.3`, `2x`
                // and `1e` are errors, not two tokens.
                while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '.') {
                    complete = false;
                    i += 1;
                }
                let number: String = chars[start..i].iter().collect();
                match number.parse::<f64>() {
                    Ok(v) if complete => Token::Number(v),
                    _ => return Err((start, format!("`{number}` is not a number"))),
                }
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

type ParseResult<T> = Result<T, (usize, String)>;

/// Recursive descent over the grammar of docs/expressions.md.
struct Parser<'a> {
    tokens: &'a [(usize, Token)],
    next: usize,
    /// Current nesting (parentheses, calls, signs, powers).
    depth: usize,
    /// The text's length in characters (the position of "the end").
    end: usize,
    tree: Tree,
}

impl Parser<'_> {
    fn peek(&self) -> Option<&Token> {
        self.tokens.get(self.next).map(|t| &t.1)
    }

    fn position(&self) -> usize {
        self.tokens.get(self.next).map_or(self.end, |t| t.0)
    }

    fn add(&mut self, node: Node) -> ParseResult<u32> {
        let at = self.position();
        self.tree.add(node).map_err(|e| (at, e))
    }

    /// expression, then the end of the text.
    fn parse_all(&mut self) -> ParseResult<u32> {
        let root = self.expression()?;
        match self.peek() {
            None => Ok(root),
            Some(Token::Close) => Err((self.position(), "`)` without its `(`".into())),
            Some(Token::Comma) => Err((
                self.position(),
                "a comma outside min(a, b), max(a, b), atan2(y, x) or if(cond, a, b)".into(),
            )),
            Some(t) => Err((
                self.position(),
                format!(
                    "{} follows a complete operand: an operator (+ - * / ^ < <= > >=) is missing",
                    t.describe()
                ),
            )),
        }
    }

    /// expression = sum [ comparison sum ]
    fn expression(&mut self) -> ParseResult<u32> {
        let left = self.sum()?;
        let op = match self.peek() {
            Some(Token::Op("<")) => Binary::Lt,
            Some(Token::Op("<=")) => Binary::Le,
            Some(Token::Op(">")) => Binary::Gt,
            Some(Token::Op(">=")) => Binary::Ge,
            _ => return Ok(left),
        };
        self.next += 1;
        let right = self.sum()?;
        if let Some(Token::Op(c @ ("<" | "<=" | ">" | ">="))) = self.peek() {
            return Err((
                self.position(),
                format!("comparisons do not chain: write `a < b < c` as `(a < b)*(b < c)`, here before `{c}`"),
            ));
        }
        self.add(Node::Binary(op, left, right))
    }

    /// sum = product { ("+" | "-") product }
    fn sum(&mut self) -> ParseResult<u32> {
        self.left_associative([("+", Binary::Add), ("-", Binary::Sub)], Self::product)
    }

    /// product = signed { ("*" | "/") signed }
    fn product(&mut self) -> ParseResult<u32> {
        self.left_associative([("*", Binary::Mul), ("/", Binary::Div)], Self::signed)
    }

    /// operand { op operand } for the two operators `ops`, grouped to the left
    /// by a loop (a long sum is no recursion).
    fn left_associative(
        &mut self,
        ops: [(&str, Binary); 2],
        operand: fn(&mut Self) -> ParseResult<u32>,
    ) -> ParseResult<u32> {
        let mut left = operand(self)?;
        loop {
            let Some(Token::Op(symbol)) = self.peek() else {
                return Ok(left);
            };
            let Some(&(_, op)) = ops.iter().find(|(s, _)| s == symbol) else {
                return Ok(left);
            };
            self.next += 1;
            let right = operand(self)?;
            left = self.add(Node::Binary(op, left, right))?;
        }
    }

    /// signed = ("+" | "-") signed | power
    fn signed(&mut self) -> ParseResult<u32> {
        match self.peek() {
            Some(Token::Op(sign @ ("+" | "-"))) => {
                let negate = *sign == "-";
                self.next += 1;
                let operand = self.nested(Self::signed)?;
                if negate {
                    self.add(Node::Neg(operand))
                } else {
                    Ok(operand)
                }
            }
            _ => self.power(),
        }
    }

    /// power = atom [ "^" signed ]   (right-associative: the exponent is
    /// itself a power, and may carry a sign: 2^-1)
    fn power(&mut self) -> ParseResult<u32> {
        let base = self.atom()?;
        if self.peek() != Some(&Token::Op("^")) {
            return Ok(base);
        }
        self.next += 1;
        let exponent = self.nested(Self::signed)?;
        self.add(Node::Binary(Binary::Pow, base, exponent))
    }

    /// One more level of nesting around `inner`, refused beyond [`MAX_NESTING`].
    fn nested(&mut self, inner: impl FnOnce(&mut Self) -> ParseResult<u32>) -> ParseResult<u32> {
        if self.depth >= MAX_NESTING {
            return Err((
                self.position(),
                format!("nested more than {MAX_NESTING} levels deep (parentheses, calls, signs and powers)"),
            ));
        }
        self.depth += 1;
        let result = inner(self);
        self.depth -= 1;
        result
    }

    /// atom = number | variable | "pi" | "(" expression ")" | call
    fn atom(&mut self) -> ParseResult<u32> {
        let at = self.position();
        // An operator with nothing after it is named at the operator.
        let dangling = match self.next.checked_sub(1).map(|k| &self.tokens[k]) {
            Some((op_at, Token::Op(op))) => {
                Some((*op_at, format!("`{op}` needs an operand after it")))
            }
            _ => None,
        };
        let Some(token) = self.peek().cloned() else {
            return Err(dangling.unwrap_or((at, "an operand is missing at the end".into())));
        };
        self.next += 1;
        match token {
            Token::Number(v) => self.add(Node::Number(v)),
            Token::Open => self.nested(|p| {
                let inner = p.expression()?;
                match p.peek() {
                    Some(Token::Close) => {
                        p.next += 1;
                        Ok(inner)
                    }
                    None => Err((at, "this parenthesis is never closed".into())),
                    Some(Token::Comma) => Err((
                        p.position(),
                        "a comma outside min(a, b), max(a, b), atan2(y, x) or if(cond, a, b)"
                            .into(),
                    )),
                    Some(t) => Err((
                        p.position(),
                        format!(
                            "{} follows a complete operand: an operator or `)` is missing",
                            t.describe()
                        ),
                    )),
                }
            }),
            Token::Name(name) => self.name(at, &name),
            Token::Op(op) => Err((at, format!("`{op}` needs an operand before it"))),
            Token::Close | Token::Comma if dangling.is_some() => Err(dangling.unwrap_or_default()),
            Token::Close | Token::Comma => {
                let reason = if self.next == 1 {
                    "an expression is missing here"
                } else {
                    "an operand is missing here"
                };
                Err((at, reason.into()))
            }
        }
    }

    fn name(&mut self, at: usize, name: &str) -> ParseResult<u32> {
        let call = self.peek() == Some(&Token::Open);
        let function = FUNCTIONS.iter().find(|(n, _)| *n == name).map(|p| p.1);
        let binary = match name {
            "min" => Some(Binary::Min),
            "max" => Some(Binary::Max),
            "atan2" => Some(Binary::Atan2),
            _ => None,
        };
        let is_function = function.is_some() || binary.is_some() || name == "if";
        match name {
            "x" | "y" | "r" | "pi" if call => Err((at, format!("`{name}` is not a function"))),
            "x" => self.add(Node::Variable(Variable::X)),
            "y" => self.add(Node::Variable(Variable::Y)),
            "r" => self.add(Node::Variable(Variable::R)),
            "pi" => self.add(Node::Number(std::f64::consts::PI)),
            _ if is_function && !call => Err((
                at,
                format!("a function needs its arguments in parentheses: `{name}` ({KNOWN})"),
            )),
            _ if !is_function && call => Err((at, format!("unknown function `{name}` ({KNOWN})"))),
            _ if !is_function => Err((at, format!("unknown name `{name}` ({KNOWN})"))),
            _ => {
                let arity = if function.is_some() {
                    1
                } else if binary.is_some() {
                    2
                } else {
                    3
                };
                let args = self.arguments(at, name, arity)?;
                match (function, binary) {
                    (Some(f), _) => self.add(Node::Unary(f, args[0])),
                    (_, Some(op)) => self.add(Node::Binary(op, args[0], args[1])),
                    _ => self.add(Node::If(args[0], args[1], args[2])),
                }
            }
        }
    }

    /// "(" expression { "," expression } ")" with exactly `arity` arguments.
    fn arguments(&mut self, at: usize, name: &str, arity: usize) -> ParseResult<Vec<u32>> {
        let mut args = Vec::with_capacity(arity);
        self.next += 1; // "("
        self.nested(|p| {
            loop {
                args.push(p.expression()?);
                match p.peek() {
                    Some(Token::Comma) => p.next += 1,
                    Some(Token::Close) => {
                        p.next += 1;
                        break;
                    }
                    None => {
                        return Err((
                            at + name.chars().count(),
                            "this parenthesis is never closed".into(),
                        ))
                    }
                    Some(t) => {
                        return Err((
                            p.position(),
                            format!(
                                "{} follows a complete operand: an operator, `,` or `)` is missing",
                                t.describe()
                            ),
                        ))
                    }
                }
            }
            Ok(0)
        })?;
        if args.len() != arity {
            let form = match arity {
                1 => format!("{name}(a)"),
                2 if name == "atan2" => "atan2(y, x)".into(),
                2 => format!("{name}(a, b)"),
                _ => "if(cond, a, b)".into(),
            };
            return Err((
                at,
                format!(
                    "{form} takes {arity} argument{}, got {}",
                    if arity == 1 { "" } else { "s" },
                    args.len()
                ),
            ));
        }
        Ok(args)
    }
}

/// Prints a tree with the parentheses precedence needs, in the scene's
/// syntax or FreeFEM's. One pass in storage order (no recursion): each
/// node's text is built from its operands' texts.
struct Printer {
    freefem: bool,
}

impl Printer {
    fn scene() -> Printer {
        Printer { freefem: false }
    }

    fn freefem() -> Printer {
        Printer { freefem: true }
    }

    fn number(&self, v: f64) -> String {
        if self.freefem {
            // Written as a real: FreeFEM reads `1/2` as integer division.
            if v.is_nan() {
                "(0./0.)".into()
            } else if v.is_infinite() {
                format!("({}1./0.)", if v < 0.0 { "-" } else { "" })
            } else {
                format!("{v:e}")
            }
        } else if v.is_nan() {
            "(0/0)".into()
        } else if v.is_infinite() {
            format!("({}1/0)", if v < 0.0 { "-" } else { "" })
        } else {
            format!("{v:?}")
        }
    }

    fn print(&self, tree: &Tree) -> String {
        let nodes = &tree.nodes;
        // How often each node is an operand: its text is moved to its last user.
        let mut uses = vec![0u32; nodes.len()];
        for node in nodes {
            for c in node.children() {
                uses[c] += 1;
            }
        }
        let mut texts: Vec<String> = Vec::with_capacity(nodes.len());
        let mut take = |texts: &mut Vec<String>, c: usize| {
            uses[c] -= 1;
            if uses[c] == 0 {
                std::mem::take(&mut texts[c])
            } else {
                texts[c].clone()
            }
        };
        for node in nodes {
            let text = match *node {
                Node::Number(v) => {
                    let s = self.number(v);
                    if v.is_sign_negative() && v.is_finite() {
                        format!("({s})")
                    } else {
                        s
                    }
                }
                Node::Variable(Variable::X) => "x".into(),
                Node::Variable(Variable::Y) => "y".into(),
                Node::Variable(Variable::R) if self.freefem => "sqrt(x^2+y^2)".into(),
                Node::Variable(Variable::R) => "r".into(),
                Node::Neg(a) => {
                    // A sign takes an operand that binds tighter; FreeFEM gets
                    // every sign in parentheses (its own rules for a sign and `^`).
                    let operand = take(&mut texts, a as usize);
                    let tighter = if self.freefem {
                        ATOM_PRECEDENCE
                    } else {
                        SIGN_PRECEDENCE + 1
                    };
                    let operand = if nodes[a as usize].precedence() < tighter {
                        format!("({operand})")
                    } else {
                        operand
                    };
                    if self.freefem {
                        format!("(-{operand})")
                    } else {
                        format!("-{operand}")
                    }
                }
                Node::Unary(f, a) => {
                    let name = if self.freefem {
                        f.freefem_name()
                    } else {
                        f.name()
                    };
                    format!("{name}({})", take(&mut texts, a as usize))
                }
                Node::Binary(op, a, b) => {
                    let (left, right) =
                        (take(&mut texts, a as usize), take(&mut texts, b as usize));
                    match op.symbol() {
                        None => format!("{}({left}, {right})", op.call_name()),
                        Some(symbol) => {
                            let p = op.precedence();
                            let (pa, pb) = (
                                nodes[a as usize].precedence(),
                                nodes[b as usize].precedence(),
                            );
                            // Left-associative operators need parentheses on an
                            // equal right operand (a − (b − c)); `^` on an equal
                            // left one ((a^b)^c); comparisons do not chain.
                            let wrap_left = if op == Binary::Pow {
                                pa <= p
                            } else {
                                pa < p || (p == 1 && pa == 1)
                            };
                            let wrap_right = if op == Binary::Pow {
                                pb < SIGN_PRECEDENCE
                            } else {
                                pb <= p
                            };
                            let left = if wrap_left { format!("({left})") } else { left };
                            let right = if wrap_right {
                                format!("({right})")
                            } else {
                                right
                            };
                            if self.freefem && p == 1 {
                                // A comparison is a bool in FreeFEM: made a real.
                                format!("(({left}{symbol}{right}) ? 1. : 0.)")
                            } else if p <= 2 {
                                format!("{left} {symbol} {right}")
                            } else {
                                format!("{left}{symbol}{right}")
                            }
                        }
                    }
                }
                Node::If(c, a, b) => {
                    let (c, a, b) = (
                        take(&mut texts, c as usize),
                        take(&mut texts, a as usize),
                        take(&mut texts, b as usize),
                    );
                    if self.freefem {
                        format!("(({c}) != 0. ? ({a}) : ({b}))")
                    } else {
                        format!("if({c}, {a}, {b})")
                    }
                }
            };
            texts.push(text);
        }
        texts.pop().unwrap_or_default()
    }
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
        let cases: [(&str, f64); 24] = [
            ("1 + 2*3", 7.0),
            ("2e-3*x", 2e-3 * x),
            ("-x^2", -(x * x)),
            ("1 - -x", 1.0 + x),
            ("2*-x", -2.0 * x),
            ("2^-1", 0.5),
            ("2^3^2", 512.0),
            ("-2^2", -4.0),
            ("(-2)^2", 4.0),
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
                "max(0.1, min(0.15 + 0.1*r^2, 0.2))",
                (0.15 + 0.1 * r * r).min(0.2),
            ),
            ("min(x, min(y, 1))", y),
            ("atan2(y, atan2(x, 1))", y.atan2(x.atan2(1.0))),
            (
                "atan2(y, x) + atan2(1, -1)",
                y.atan2(x) + 0.75 * std::f64::consts::PI,
            ),
            ("if(x < 0.5, 1, 2) + if(y >= 0, 10, 20)", 21.0),
            ("if(r <= 1, sqrt(1 - r^2), 0)", (1.0 - r * r).sqrt()),
            ("(x > 0) * 3", 3.0),
            ("if(x > 0, if(y > 0, 1, 2), 3)", 2.0),
            (
                "asin(x) + acos(x) + atan(y) + sinh(x) - cosh(y) + tanh(1.)",
                std::f64::consts::FRAC_PI_2 + y.atan() + x.sinh() - y.cosh() + 1f64.tanh(),
            ),
        ];
        for (text, want) in cases {
            let got = at(text, x, y);
            assert!((got - want).abs() < 1e-14, "{text}: {got} vs {want}");
        }
        // The branch not taken may be undefined.
        assert_eq!(at("if(r < 1, ln(1 - r), 0)", 3.0, 0.0), 0.0);
        assert_eq!(Expression::parse(" 2.5 ").unwrap().as_constant(), Some(2.5));
        assert_eq!(Expression::parse("-2*3").unwrap().as_constant(), Some(-6.0));
        assert_eq!(
            Expression::parse(".5 + 1.").unwrap().as_constant(),
            Some(1.5)
        );
        // An undefined condition is undefined, not false.
        assert!(at("if(ln(x) < 0, 1, 2)", -1.0, 0.0).is_nan());
        assert!(at("ln(x) < 0", -1.0, 0.0).is_nan());
    }

    #[test]
    fn atan2_is_the_angle_in_every_quadrant() {
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
        assert_eq!(e.freefem(), "(atan2(y, x))");
        let m = Expression::parse("atan2(y)").unwrap_err();
        assert!(
            m.contains("character 1") && m.contains("2 arguments, got 1"),
            "{m}"
        );
    }

    #[test]
    fn errors_name_the_position_and_the_reason() {
        let cases = [
            ("1 + foo(x)", "character 5", "unknown function `foo`"),
            ("1 + z", "character 5", "unknown name `z`"),
            ("(x + 1", "character 1", "never closed"),
            ("x + 1)", "character 6", "without its"),
            ("x $ 2", "character 3", "unexpected character `$`"),
            ("if(x, 1)", "character 1", "3 arguments, got 2"),
            ("x +", "character 3", "`+` needs an operand after it"),
            (
                "min(x -, 1)",
                "character 7",
                "`-` needs an operand after it",
            ),
            ("(", "character 2", "operand is missing at the end"),
            ("sqrt", "character 1", "parentheses"),
            ("1, 2", "character 2", "comma"),
            ("", "character 1", "missing"),
            ("1 2", "character 3", "operator"),
            ("x + 1 0", "character 7", "operator"),
            ("2 .5", "character 3", "operator"),
            ("x y", "character 3", "operator"),
            ("2x", "character 1", "`2x` is not a number"),
            ("1.2.3", "character 1", "not a number"),
            ("1e", "character 1", "not a number"),
            ("x < y < 1", "character 7", "do not chain"),
            ("x(2)", "character 1", "not a function"),
            ("min(x, y", "character 4", "never closed"),
        ];
        for (text, position, reason) in cases {
            let m = Expression::parse(text).expect_err(text);
            assert!(m.contains(position) && m.contains(reason), "{text}: {m}");
        }
    }

    #[test]
    fn nesting_is_bounded_and_long_sums_are_not_nesting() {
        let nested = |n: usize| "if(x<0,".repeat(n) + "1" + &",2)".repeat(n);
        let e = Expression::parse(&nested(100)).unwrap();
        assert_eq!(e.eval([1.0, 0.0]), 2.0);
        assert_eq!(e.eval([-1.0, 0.0]), 1.0);
        // The deepest nesting accepted parses on a 256 KiB thread stack
        // (a study's worker threads have 2 MiB).
        let deepest = "(".repeat(MAX_NESTING) + "x" + &")".repeat(MAX_NESTING);
        let calls = "sin(".repeat(MAX_NESTING) + "x" + &")".repeat(MAX_NESTING);
        let parsed = std::thread::Builder::new()
            .stack_size(256 * 1024)
            .spawn(move || {
                let d = Expression::parse(&calls)
                    .and_then(|e| e.derivative(Variable::X).map(|d| d.to_string().len()));
                (Expression::parse(&deepest).is_ok(), d.is_ok())
            })
            .unwrap()
            .join()
            .unwrap();
        assert_eq!(parsed, (true, true));
        let m = Expression::parse(&nested(100_000)).unwrap_err();
        assert!(m.contains("nested more than 200"), "{m}");
        let m = Expression::parse(&("-".repeat(100_000) + "x")).unwrap_err();
        assert!(m.contains("nested more than"), "{m}");
        let m = Expression::parse(&("2^".repeat(100_000) + "x")).unwrap_err();
        assert!(m.contains("nested more than"), "{m}");
        // 40 000 terms: no nesting, evaluated in one linear pass, printed and
        // differentiated without recursion.
        let sum = vec!["x*y"; 40_000].join(" + ");
        let e = Expression::parse(&sum).unwrap();
        assert!((e.eval([0.5, 2.0]) - 40_000.0).abs() < 1e-8);
        assert!((e.derivative(Variable::X).unwrap().eval([0.5, 2.0]) - 80_000.0).abs() < 1e-8);
        assert!(e.freefem().len() > 40_000 * 3);
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
        // Expressions get the plain numbers' magnitude guard.
        let huge = Expression::parse("1e200*(1 + x)").unwrap();
        let m = huge.check_finite_at("load.g", [[0.0, 0.0]]).unwrap_err();
        assert!(
            m.contains("load.g") && m.contains("1e200") && m.contains("1e100"),
            "{m}"
        );
        let m = Expression::parse("1e101")
            .unwrap()
            .check_finite_at("load.g", [])
            .unwrap_err();
        assert!(m.contains("beyond"), "{m}");
    }

    /// A set's members evaluated together give each member's own value, bit
    /// for bit, from one tree that holds their shared nodes once; a refused
    /// value names its member's key and the point.
    #[test]
    fn a_set_evaluates_its_members_together() {
        let u = Expression::parse("if(r <= 0.7, sqrt(1 - r^2), -0.68*ln(r) + 0.47)").unwrap();
        let members = vec![
            ("u".to_string(), u.clone()),
            (
                "lambda".to_string(),
                Expression::parse("(2 - r^2)/(1 - r^2)^1.5").unwrap(),
            ),
            ("dx".to_string(), u.derivative(Variable::X).unwrap()),
            ("dy".to_string(), u.derivative(Variable::Y).unwrap()),
            ("c".to_string(), Expression::constant(2.5)),
        ];
        let set = ExpressionSet::new(members.clone());
        assert_eq!(set.len(), 5);
        let separate: usize = members.iter().map(|(_, e)| e.tree.nodes.len()).sum();
        let merged = set.program.initial.len();
        assert!(merged < separate, "{merged} of {separate}");
        let mut evaluator = set.evaluator();
        for p in [[0.3, -0.2], [0.5, 0.6], [-0.1, 0.0]] {
            let values = evaluator.finite_at(p).unwrap().to_vec();
            for ((_, e), v) in members.iter().zip(&values) {
                assert_eq!(v.to_bits(), e.eval(p).to_bits(), "{e} at {p:?}");
            }
        }
        // λ is not finite beyond r = 1: its key, the point, the value.
        let (key, m) = evaluator.finite_at([1.2, 0.0]).unwrap_err();
        assert_eq!(key, "lambda");
        assert!(
            m.contains("(1.200000, 0.000000)") && m.contains("NaN"),
            "{m}"
        );
        let (key, _) = set.check_finite_at([[0.1, 0.1], [0.0, 1.5]]).unwrap_err();
        assert_eq!(key, "lambda");
        assert!(set.check_finite_at([[0.1, 0.1]]).is_ok());
    }

    #[test]
    fn freefem_syntax() {
        let e = Expression::parse("if(r < 1, ln(x)*x^2, -y)").unwrap();
        assert_eq!(
            e.freefem(),
            "(((((sqrt(x^2+y^2)<1e0) ? 1. : 0.)) != 0. ? (log(x)*x^2e0) : ((-y))))"
        );
        assert_eq!(Expression::constant(-4.0).freefem(), "((-4e0))");
        assert_eq!(Expression::parse("2^3^2").unwrap().freefem(), "(5.12e2)");
        assert_eq!(Expression::parse("x^y^2").unwrap().freefem(), "(x^y^2e0)");
        assert_eq!(
            Expression::parse("(x^y)^2").unwrap().freefem(),
            "((x^y)^2e0)"
        );
        assert_eq!(Expression::parse("-x^2").unwrap().freefem(), "((-(x^2e0)))");
        assert_eq!(Expression::parse("1/2*x").unwrap().freefem(), "(5e-1*x)");
    }

    /// Central differences of step h agree with the exact derivative to
    /// O(h²): the rules, not the finite differences, are under test.
    fn check_derivatives(text: &str, points: &[[f64; 2]]) {
        let e = Expression::parse(text).unwrap();
        for var in [Variable::X, Variable::Y] {
            let d = e.derivative(var).unwrap();
            let dd = d.derivative(var).unwrap();
            for &p in points {
                let h = 1e-5;
                let shift = |s: f64| match var {
                    Variable::X => [p[0] + s, p[1]],
                    _ => [p[0], p[1] + s],
                };
                let fd = (e.eval(shift(h)) - e.eval(shift(-h))) / (2.0 * h);
                let exact = d.eval(p);
                if fd.is_nan() {
                    continue; // outside the domain (x^y at x < 0)
                }
                assert!(
                    (fd - exact).abs() < 1e-6 * (1.0 + exact.abs()),
                    "∂{var:?} {text} at {p:?}: {exact} vs {fd} ({d})"
                );
                let fd2 = (d.eval(shift(h)) - d.eval(shift(-h))) / (2.0 * h);
                let exact2 = dd.eval(p);
                assert!(
                    (fd2 - exact2).abs() < 1e-5 * (1.0 + exact2.abs()),
                    "∂²{var:?} {text} at {p:?}: {exact2} vs {fd2}"
                );
            }
        }
    }

    #[test]
    fn derivatives_are_exact() {
        let points = [[0.3, 0.4], [0.7, -0.2], [-0.5, 0.6]];
        for text in [
            "x^2*y - 3*x + 7",
            "10*cos(y)*cos(x)",
            "sqrt(1 + x^2 + y^2)",
            "r^3 + ln(r)",
            "exp(-x*y)/(1 + y^2)",
            "x^y",
            "2^x + x^2.5",
            "atan2(y, x) + tan(x) + asin(x/2) + acos(y/2) + atan(x*y)",
            "sinh(x) * cosh(y) - tanh(x - y)",
            "abs(x - 0.1) + min(x, y) + max(x^2, y)",
            "if(x < 0, x^2, x^3) + (y > 0)*y",
            "-x^2 - -y",
        ] {
            check_derivatives(text, &points);
        }
        // r^2 and r^4 are smooth at the origin, and so are their derivatives.
        for text in ["r^2", "0.05 + 0.3*r^2", "r^4"] {
            let e = Expression::parse(text).unwrap();
            for var in [Variable::X, Variable::Y] {
                let d = e.derivative(var).unwrap();
                let dd = d.derivative(Variable::X).unwrap();
                assert_eq!(d.eval([0.0, 0.0]), 0.0, "∂{var:?} {text} at 0");
                assert!(dd.eval([0.0, 0.0]).is_finite(), "∂x∂{var:?} {text} at 0");
            }
            check_derivatives(text, &points);
        }
        let dxx = Expression::parse("0.3*r^2")
            .unwrap()
            .derivative(Variable::X)
            .unwrap()
            .derivative(Variable::X)
            .unwrap();
        assert!((dxx.eval([0.0, 0.0]) - 0.6).abs() < 1e-15);
        // Exact zeros stay exact.
        let e = Expression::parse("sqrt(x)").unwrap();
        assert_eq!(e.derivative(Variable::Y).unwrap().as_constant(), Some(0.0));
        let d = Expression::parse("x^3")
            .unwrap()
            .derivative(Variable::X)
            .unwrap();
        assert_eq!(d.to_string(), "3.0*x^2.0");
        assert!(e.derivative(Variable::R).is_err());
    }
}
