//! Symbolic remainders (Flow*'s `Symbolic_Remainder`): instead of boxing each step's interval
//! remainder J_i into the state, keep the list of J_i with the product M_i of the linear parts
//! of the step maps applied since, and box only the sum of the M_i J_i when a bound is needed.
//! Boxing at every step re-wraps the remainder in the axes each time (the wrapping effect) and
//! grows it geometrically on rotating or contracting flows; a linear image of a box boxed once
//! does not. Matrices are interval matrices, so the products stay rigorous.
use crate::interval::Interval;

pub struct SymbolicRemainder {
    n: usize,
    capacity: usize,
    /// (M row-major n x n, J) pairs, oldest first.
    terms: Vec<(Vec<Interval>, Vec<Interval>)>,
}

fn identity(n: usize) -> Vec<Interval> {
    (0..n * n).map(|k| if k / n == k % n { Interval::ONE } else { Interval::ZERO }).collect()
}

/// a (n x n) times b (n x n), interval arithmetic.
pub fn mat_mul(a: &[Interval], b: &[Interval], n: usize) -> Vec<Interval> {
    let mut out = vec![Interval::ZERO; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            if aik == Interval::ZERO {
                continue;
            }
            for j in 0..n {
                out[i * n + j] = out[i * n + j] + aik * b[k * n + j];
            }
        }
    }
    out
}

/// a (n x n) times v (n).
pub fn mat_vec(a: &[Interval], v: &[Interval], n: usize) -> Vec<Interval> {
    (0..n).map(|i| (0..n).fold(Interval::ZERO, |s, j| s + a[i * n + j] * v[j])).collect()
}

impl SymbolicRemainder {
    pub fn new(n: usize, capacity: usize) -> Self {
        SymbolicRemainder { n, capacity: capacity.max(1), terms: Vec::new() }
    }

    /// A new remainder in state coordinates, entering at the current step.
    pub fn push(&mut self, j: Vec<Interval>) {
        if j.iter().any(|x| *x != Interval::ZERO) {
            self.terms.push((identity(self.n), j));
        }
        if self.terms.len() > self.capacity {
            // Box the older half into one term: sound, and bounds the cost per step.
            let half = self.terms.len() / 2;
            let merged = self.terms.drain(..half).fold(vec![Interval::ZERO; self.n], |acc, (m, j)| {
                acc.iter().zip(mat_vec(&m, &j, self.n)).map(|(a, b)| *a + b).collect()
            });
            self.terms.insert(0, (identity(self.n), merged));
        }
    }

    /// Every stored remainder passes through the step's linear map `phi`.
    pub fn transform(&mut self, phi: &[Interval]) {
        for (m, _) in &mut self.terms {
            *m = mat_mul(phi, m, self.n);
        }
    }

    /// The box of the sum of M_i J_i.
    pub fn enclosure(&self) -> Vec<Interval> {
        self.terms.iter().fold(vec![Interval::ZERO; self.n], |acc, (m, j)| {
            acc.iter().zip(mat_vec(m, j, self.n)).map(|(a, b)| *a + b).collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_does_not_wrap() {
        // 100 rotations by 0.1 rad of a unit box remainder: boxing each step would grow it by
        // (|cos| + |sin|) per step (about 1.1^100); the symbolic form stays within sqrt(2).
        let (c, s) = (0.1f64.cos(), 0.1f64.sin());
        let phi = vec![Interval::point(c), Interval::point(-s), Interval::point(s), Interval::point(c)];
        let mut r = SymbolicRemainder::new(2, 200);
        r.push(vec![Interval::symmetric(1.0), Interval::symmetric(1.0)]);
        for _ in 0..100 {
            r.transform(&phi);
        }
        let e = r.enclosure();
        assert!(e[0].mag() <= 1.4143 && e[0].mag() >= 1.0, "{}", e[0]);
    }

    #[test]
    fn compaction_keeps_the_sum() {
        let mut r = SymbolicRemainder::new(1, 4);
        for _ in 0..10 {
            r.push(vec![Interval::symmetric(1.0)]);
        }
        assert!(r.enclosure()[0].contains(10.0) && r.enclosure()[0].contains(-10.0));
        assert!(r.terms.len() <= 4);
    }
}
