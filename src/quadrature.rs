//! Quadrature rules on the reference triangle and on segments.
//!
//! Triangle rules are given in barycentric coordinates with weights that sum
//! to 1 (multiply by |T|). Which rule is exact for which degree:
//!
//! | degree | rule                                   | points |
//! |--------|----------------------------------------|--------|
//! | 1      | centroid                               | 1      |
//! | 2      | interior points (2/3, 1/6, 1/6)        | 3      |
//! | 5      | Radon (FreeFEM's `qf5pT`, its default) | 7      |
//! | 6      | Dunavant                               | 12     |
//! | ≥ 7    | collapsed Gauss–Legendre (Duffy)       | m²     |
//!
//! The symmetric rules (degrees ≤ 6) are invariant under permutations of the
//! vertices, so mirror-symmetric meshes give mirror-symmetric discrete
//! problems even for non-polynomial coefficients. Exactness of every rule is
//! checked against ∫_T λ1^a λ2^b λ3^c = 2|T| a! b! c! / (a+b+c+2)! in the tests.

/// A rule on the reference triangle: barycentric points, weights summing to 1.
#[derive(Debug, Clone)]
pub struct TriangleRule {
    pub points: Vec<[f64; 3]>,
    pub weights: Vec<f64>,
    pub degree: usize,
}

impl TriangleRule {
    /// The cheapest rule here that integrates polynomials of `degree` exactly.
    pub fn exact_for(degree: usize) -> TriangleRule {
        match degree {
            0 | 1 => TriangleRule {
                points: vec![[1.0 / 3.0; 3]],
                weights: vec![1.0],
                degree: 1,
            },
            2 => {
                let mut r = TriangleRule {
                    points: vec![],
                    weights: vec![],
                    degree: 2,
                };
                r.push_orbit3(2.0 / 3.0, 1.0 / 3.0);
                r
            }
            3..=5 => radon7(),
            6 => dunavant12(),
            d => collapsed_gauss(d),
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Adds the 3 points (a, b, b), (b, a, b), (b, b, a) with weight w each.
    fn push_orbit3(&mut self, a: f64, w: f64) {
        let b = (1.0 - a) / 2.0;
        for p in [[a, b, b], [b, a, b], [b, b, a]] {
            self.points.push(p);
            self.weights.push(w);
        }
    }

    /// Adds the 6 permutations of (a, b, c) with weight w each.
    fn push_orbit6(&mut self, a: f64, b: f64, w: f64) {
        let c = 1.0 - a - b;
        for p in [
            [a, b, c],
            [a, c, b],
            [b, a, c],
            [b, c, a],
            [c, a, b],
            [c, b, a],
        ] {
            self.points.push(p);
            self.weights.push(w);
        }
    }
}

/// Radon's 7-point rule, exact for degree 5 (closed form).
fn radon7() -> TriangleRule {
    let s15 = 15f64.sqrt();
    let mut r = TriangleRule {
        points: vec![[1.0 / 3.0; 3]],
        weights: vec![9.0 / 40.0],
        degree: 5,
    };
    let a1 = (6.0 - s15) / 21.0;
    let a2 = (6.0 + s15) / 21.0;
    r.push_orbit3(1.0 - 2.0 * a1, (155.0 - s15) / 1200.0);
    r.push_orbit3(1.0 - 2.0 * a2, (155.0 + s15) / 1200.0);
    r
}

/// Dunavant's 12-point rule, exact for degree 6.
fn dunavant12() -> TriangleRule {
    let mut r = TriangleRule {
        points: vec![],
        weights: vec![],
        degree: 6,
    };
    r.push_orbit3(0.501_426_509_658_179, 0.116_786_275_726_379);
    r.push_orbit3(0.873_821_971_016_996, 0.050_844_906_370_207);
    r.push_orbit6(
        0.053_145_049_844_817,
        0.310_352_451_033_784,
        0.082_851_075_618_374,
    );
    r
}

/// Gauss–Legendre on both axes of the square, collapsed onto the triangle:
/// with m points per axis it is exact for degree 2m − 2 (the Duffy Jacobian
/// costs one degree in one direction).
fn collapsed_gauss(degree: usize) -> TriangleRule {
    let m = (degree + 3) / 2;
    let (x, w) = gauss_legendre(m);
    let mut r = TriangleRule {
        points: vec![],
        weights: vec![],
        degree: 2 * m - 2,
    };
    for i in 0..m {
        let u = 0.5 * (x[i] + 1.0);
        for j in 0..m {
            let v = 0.5 * (x[j] + 1.0);
            // (u, v) in the unit square -> (s, t) = (u, v(1 − u)) in the triangle.
            let s = u;
            let t = v * (1.0 - u);
            // Reference area 1/2; weights normalised to sum 1.
            let weight = 0.25 * w[i] * w[j] * (1.0 - u) * 2.0;
            r.points.push([1.0 - s - t, s, t]);
            r.weights.push(weight);
        }
    }
    r
}

/// Gauss–Legendre nodes and weights on [−1, 1] (Newton on the Legendre
/// recurrence; exact for degree 2n − 1).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        for _ in 0..100 {
            let (p, dp) = legendre(n, z);
            let dz = p / dp;
            z -= dz;
            if dz.abs() < 1e-16 {
                break;
            }
        }
        let (_, dp) = legendre(n, z);
        x[i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
    }
    (x, w)
}

fn legendre(n: usize, z: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, z);
    if n == 0 {
        return (1.0, 0.0);
    }
    for k in 2..=n {
        let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
        p0 = p1;
        p1 = p2;
    }
    let dp = n as f64 * (z * p1 - p0) / (z * z - 1.0);
    (p1, dp)
}

/// A rule on the unit segment [0, 1]: points t, weights summing to 1.
#[derive(Debug, Clone)]
pub struct SegmentRule {
    pub points: Vec<f64>,
    pub weights: Vec<f64>,
}

impl SegmentRule {
    /// Gauss–Legendre exact for `degree`.
    pub fn exact_for(degree: usize) -> SegmentRule {
        let n = degree / 2 + 1;
        let (x, w) = gauss_legendre(n);
        SegmentRule {
            points: x.iter().map(|x| 0.5 * (x + 1.0)).collect(),
            weights: w.iter().map(|w| 0.5 * w).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn factorial(n: usize) -> f64 {
        (1..=n).map(|k| k as f64).product()
    }

    /// ∫ over the reference triangle normalised to area 1.
    fn exact_monomial(a: usize, b: usize, c: usize) -> f64 {
        2.0 * factorial(a) * factorial(b) * factorial(c) / factorial(a + b + c + 2)
    }

    #[test]
    fn every_rule_is_exact_for_its_degree() {
        for d in 0..=12 {
            let rule = TriangleRule::exact_for(d);
            assert!(rule.degree >= d);
            let sum: f64 = rule.weights.iter().sum();
            assert!((sum - 1.0).abs() < 1e-14, "degree {d}: weights sum {sum}");
            for a in 0..=d {
                for b in 0..=d - a {
                    let c = d - a - b;
                    let q: f64 = rule
                        .points
                        .iter()
                        .zip(&rule.weights)
                        .map(|(p, w)| {
                            w * p[0].powi(a as i32) * p[1].powi(b as i32) * p[2].powi(c as i32)
                        })
                        .sum();
                    let e = exact_monomial(a, b, c);
                    assert!(
                        (q - e).abs() < 1e-13 * e.max(1e-3),
                        "rule for degree {d} fails on λ^({a},{b},{c}): {q} vs {e}"
                    );
                }
            }
        }
    }

    #[test]
    fn symmetric_rules_are_permutation_invariant() {
        for d in 1..=6 {
            let rule = TriangleRule::exact_for(d);
            for (p, w) in rule.points.iter().zip(&rule.weights) {
                let q = [p[1], p[0], p[2]];
                assert!(rule
                    .points
                    .iter()
                    .zip(&rule.weights)
                    .any(|(r, v)| (0..3).all(|k| (r[k] - q[k]).abs() < 1e-15)
                        && (v - w).abs() < 1e-15));
            }
        }
    }

    #[test]
    fn segment_rules_are_exact() {
        for d in 0..=9 {
            let rule = SegmentRule::exact_for(d);
            let q: f64 = rule
                .points
                .iter()
                .zip(&rule.weights)
                .map(|(t, w)| w * t.powi(d as i32))
                .sum();
            assert!((q - 1.0 / (d as f64 + 1.0)).abs() < 1e-14);
        }
    }
}
