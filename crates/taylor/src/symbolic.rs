//! Symbolic remainders (Flow*'s `Symbolic_Remainder`): instead of boxing each step's interval
//! remainder J_i into the state, keep the list of J_i with the product M_i of the linear parts
//! of the step maps applied since, and box only the sum of the M_i J_i when a bound is needed.
//! Boxing at every step re-wraps the remainder in the axes each time (the wrapping effect) and
//! grows it geometrically on rotating or contracting flows; a linear image of a box boxed once
//! does not. Matrices are interval matrices, so the products stay rigorous.
//!
//! The products M_i are kept as float matrices, not interval matrices: an interval product
//! widens by |Phi| rad(M) at every step, and |Phi_k| ... |Phi_1| (absolute values) grows much
//! faster than the product itself on rotating or chaotic flows, so interval M_i became wider
//! than their own magnitude (Lorenz: radius 1e10 against 1e-1 after 900 steps) and the boxed sum
//! exploded. Instead each step bounds what the float product misses, (gamma_n |B| + rad Phi)
//! |M_i| |J_i| summed over the terms, and adds that bound to the remainder entering next.
use crate::interval::{add_up, mul_up, Interval};
use crate::tm::{etas, gamma};

pub struct SymbolicRemainder {
    n: usize,
    capacity: usize,
    /// (M row-major n x n, exact floats; J) pairs, oldest first.
    terms: Vec<(Vec<f64>, Vec<Interval>)>,
    /// Half-widths bounding what the float products have missed since the last `push`.
    pending: Vec<f64>,
}

fn identity(n: usize) -> Vec<f64> {
    (0..n * n).map(|k| if k / n == k % n { 1.0 } else { 0.0 }).collect()
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

/// The exact float matrix m times the interval vector v, rigorously.
fn point_mat_vec(m: &[f64], v: &[Interval], n: usize) -> Vec<Interval> {
    (0..n)
        .map(|i| (0..n).fold(Interval::ZERO, |s, j| if m[i * n + j] == 0.0 { s } else { s + Interval::point(m[i * n + j]) * v[j] }))
        .collect()
}

impl SymbolicRemainder {
    pub fn new(n: usize, capacity: usize) -> Self {
        SymbolicRemainder { n, capacity: capacity.max(1), terms: Vec::new(), pending: vec![0.0; n] }
    }

    /// A new remainder in state coordinates, entering at the current step.
    pub fn push(&mut self, j: Vec<Interval>) {
        let j: Vec<Interval> = j.iter().zip(&self.pending).map(|(x, e)| if *e > 0.0 { *x + Interval::symmetric(*e) } else { *x }).collect();
        self.pending = vec![0.0; self.n];
        if j.iter().any(|x| *x != Interval::ZERO) {
            self.terms.push((identity(self.n), j));
        }
        if self.terms.len() > self.capacity {
            // Box the half of the terms whose images are smallest into one term: sound, bounds
            // the cost per step, and boxing small terms wraps least (Girard's order reduction
            // of zonotopes picks generators the same way).
            let n = self.n;
            let images: Vec<Vec<Interval>> = self.terms.iter().map(|(m, j)| point_mat_vec(m, j, n)).collect();
            let mut order: Vec<usize> = (0..self.terms.len()).collect();
            let size = |v: &Vec<Interval>| v.iter().map(|x| x.mag()).sum::<f64>();
            order.sort_by(|&a, &b| size(&images[a]).total_cmp(&size(&images[b])));
            let boxed: std::collections::HashSet<usize> = order[..self.terms.len() / 2].iter().copied().collect();
            let merged = boxed.iter().fold(vec![Interval::ZERO; n], |acc, &i| acc.iter().zip(&images[i]).map(|(a, b)| *a + *b).collect());
            let mut k = 0;
            self.terms.retain(|_| {
                k += 1;
                !boxed.contains(&(k - 1))
            });
            self.terms.insert(0, (identity(n), merged));
        }
    }

    /// Every stored remainder passes through the step's linear map, some matrix in `phi`.
    pub fn transform(&mut self, phi: &[Interval]) {
        let n = self.n;
        let b: Vec<f64> = phi.iter().map(|x| x.mid()).collect();
        // |Phi - B| <= rad, and the float product B M is within gamma_n |B| |M| (+ n eta) of B M.
        // What was pending passes through Phi too: boxed (it is a rounding-level term).
        if self.pending.iter().any(|e| *e > 0.0) {
            let p: Vec<Interval> = self.pending.iter().map(|e| Interval::symmetric(*e)).collect();
            self.pending = mat_vec(phi, &p, n).iter().map(|x| x.mag()).collect();
        }
        let g = gamma(n);
        let weight: Vec<f64> =
            phi.iter().zip(&b).map(|(x, &m)| add_up(mul_up(g, m.abs()), (x.hi() - m).max(m - x.lo()).next_up())).collect();
        for (m, j) in &mut self.terms {
            // v = |M| |J|, rounded up.
            let v: Vec<f64> = (0..n).map(|r| (0..n).fold(0.0, |s, c| add_up(s, mul_up(m[r * n + c].abs(), j[c].mag())))).collect();
            let j_sum = j.iter().fold(0.0, |s, x| add_up(s, x.mag()));
            for r in 0..n {
                let miss = (0..n).fold(mul_up(etas(n), j_sum), |s, c| add_up(s, mul_up(weight[r * n + c], v[c])));
                self.pending[r] = add_up(self.pending[r], miss);
            }
            let mut out = vec![0.0; n * n];
            for r in 0..n {
                for k in 0..n {
                    let brk = b[r * n + k];
                    if brk == 0.0 {
                        continue;
                    }
                    for c in 0..n {
                        out[r * n + c] += brk * m[k * n + c];
                    }
                }
            }
            *m = out;
        }
    }

    /// The box of the sum of M_i J_i (and of what the float products have missed).
    pub fn enclosure(&self) -> Vec<Interval> {
        let start: Vec<Interval> = self.pending.iter().map(|e| if *e > 0.0 { Interval::symmetric(*e) } else { Interval::ZERO }).collect();
        self.terms.iter().fold(start, |acc, (m, j)| acc.iter().zip(point_mat_vec(m, j, self.n)).map(|(a, b)| *a + b).collect())
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

    #[test]
    fn uncertain_maps_stay_enclosed_over_many_steps() {
        // Step maps known only to intervals of radius 1e-3 around an expanding shear-rotation:
        // every sampled product of maps inside them, applied to sampled points of the entering
        // boxes, must land in the enclosure. Dropping the rad(Phi) or rounding terms of
        // `transform` makes this fail.
        let mut state = 5u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64)
        };
        let n = 3;
        let centre = [1.02, 0.3, 0.0, -0.3, 0.98, 0.1, 0.05, 0.0, 1.01];
        let phi: Vec<Interval> = centre.iter().map(|&c| Interval::point(c).inflate(1e-3)).collect();
        let boxes: Vec<Vec<Interval>> =
            (0..40).map(|k| (0..n).map(|i| Interval::point(1e-3 * (1 + (k + i) % 4) as f64).inflate(1e-5)).collect()).collect();
        let mut r = SymbolicRemainder::new(n, 16);
        for b in &boxes {
            r.transform(&phi);
            r.push(b.clone());
        }
        let e = r.enclosure();
        for trial in 0..300 {
            let mut x = vec![0.0; n];
            for b in &boxes {
                // Extreme maps (every entry at its upper or lower end) push hardest.
                let m: Vec<f64> = match trial % 3 {
                    0 => phi.iter().map(|p| p.hi()).collect(),
                    1 => phi.iter().map(|p| p.lo()).collect(),
                    _ => phi.iter().map(|p| p.lo() + next() * (p.hi() - p.lo())).collect(),
                };
                x = (0..n).map(|i| (0..n).map(|j| m[i * n + j] * x[j]).sum()).collect();
                for i in 0..n {
                    x[i] += b[i].lo() + next() * b[i].width();
                }
            }
            for i in 0..n {
                assert!(e[i].contains(x[i]), "{} misses {}", e[i], x[i]);
            }
        }
    }
}
