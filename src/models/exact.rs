//! The exact solution of the radial obstacle problem on the unit disk
//! (docs/formulation.md §1): −Δu = g (g constant), u = 0 on r = 1, u ≥ φ = c − k r².
//!
//! Outside the contact disk r < a, Δu = −g gives u = −g r²/4 + A ln r + g/4
//! (u(1) = 0). Smooth contact at r = a (u = φ, u' = φ') gives
//! A = (g/2 − 2k) a² and the equation for a:
//!
//! ```text
//!     −g a²/4 + A ln a + g/4 − (c − k a²) = 0.
//! ```
//!
//! With g = −4, c = 0.3, k = 1 this is 1.3 − 2a² + 4a² ln a = 0,
//! a = 0.539279199476…, and λ = −Δφ − g = 4k − g = 8 in the contact disk.

#[derive(Debug, Clone, Copy)]
pub struct RadialObstacle {
    pub g: f64,
    pub height: f64,
    pub curvature: f64,
    /// Contact radius (0: no contact).
    pub a: f64,
}

impl RadialObstacle {
    /// Solves for the contact radius; None if the data have no radial
    /// solution of this form (the multiplier 4k − g would be negative).
    pub fn new(g: f64, height: f64, curvature: f64) -> Option<Self> {
        if 4.0 * curvature - g < 0.0 {
            return None;
        }
        let mut s = RadialObstacle {
            g,
            height,
            curvature,
            a: 0.0,
        };
        // Without contact u = g (1 − r²)/4; contact iff it dips below φ somewhere,
        // and for this family first at the centre.
        if g / 4.0 >= height {
            return Some(s);
        }
        let f = |a: f64| {
            let big_a = (g / 2.0 - 2.0 * curvature) * a * a;
            -g * a * a / 4.0 + big_a * a.ln() + g / 4.0 - (height - curvature * a * a)
        };
        // f(1) = −(c − k) − ... ; bisection on (0, 1) where f changes sign.
        let (mut lo, mut hi) = (1e-12, 1.0 - 1e-15);
        let (flo, fhi) = (f(lo), f(hi));
        if flo.signum() == fhi.signum() {
            return None;
        }
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if f(mid).signum() == flo.signum() {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        s.a = 0.5 * (lo + hi);
        Some(s)
    }

    fn log_coefficient(&self) -> f64 {
        (self.g / 2.0 - 2.0 * self.curvature) * self.a * self.a
    }

    pub fn u(&self, x: [f64; 2]) -> f64 {
        let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
        if r <= self.a {
            self.height - self.curvature * r * r
        } else {
            -self.g * r * r / 4.0 + self.log_coefficient() * r.ln() + self.g / 4.0
        }
    }

    pub fn grad_u(&self, x: [f64; 2]) -> [f64; 2] {
        let r2 = x[0] * x[0] + x[1] * x[1];
        let r = r2.sqrt();
        // du/dr / r, so that ∇u = (du/dr / r) x.
        let dudr_over_r = if r <= self.a {
            -2.0 * self.curvature
        } else {
            -self.g / 2.0 + self.log_coefficient() / r2
        };
        [dudr_over_r * x[0], dudr_over_r * x[1]]
    }

    pub fn lambda(&self, x: [f64; 2]) -> f64 {
        let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
        if r < self.a {
            4.0 * self.curvature - self.g
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_contact_radius() {
        let s = RadialObstacle::new(-4.0, 0.3, 1.0).unwrap();
        assert!((s.a - 0.539_279_199_476).abs() < 1e-11, "a = {}", s.a);
        assert!((s.a * s.a - 0.2908).abs() < 1e-4);
        // u = r² − 4a² ln r − 1 outside, continuous with φ and C¹ at r = a.
        let r = 0.8;
        let expected = r * r - 4.0 * s.a * s.a * f64::ln(r) - 1.0;
        assert!((s.u([r, 0.0]) - expected).abs() < 1e-14);
        let e = 1e-7;
        let (inside, outside) = (s.u([s.a - e, 0.0]), s.u([s.a + e, 0.0]));
        assert!((inside - outside).abs() < 1e-6);
        let (gi, go) = (s.grad_u([s.a - e, 0.0]), s.grad_u([s.a + e, 0.0]));
        assert!((gi[0] - go[0]).abs() < 1e-6);
        assert!(s.u([1.0, 0.0]).abs() < 1e-14);
        assert_eq!(s.lambda([0.1, 0.1]), 8.0);
    }
}
