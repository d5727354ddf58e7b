//! Enclosing a zonotope G [-1, 1]^g (d x g generators) by a parallelotope B diag(s) [-1, 1]^d:
//! the order reduction that lets a discrete-time loop keep its remainders as d error symbols
//! from step to step (Lohner's parallelepiped method) instead of boxing them every step. A box
//! is the parallelotope with B = I; boxing re-wraps the set in the axes at every step, and a
//! map that rotates or shears the remainder (a controller's correction feeding one state's
//! error into another) then grows it geometrically although the true error may contract.
//!
//! For any invertible B, G xi = B (B^-1 G xi) and |(B^-1 G xi)_j| <= sum_k |(B^-1 G)_jk| = s_j,
//! so the reduction is sound with B^-1 enclosed in intervals ([`inverse`]). Candidates for B:
//! the carried symbols' own directions (the remainder is absorbed along them), the orthogonal
//! factor of G's column-pivoted QR (Lohner), and the axes; the smallest volume wins.
use crate::interval::{add_up, mul_up, Interval};
use nalgebra::DMatrix;

/// `generators` (d x g); the first d columns, when given as `carried`, are the directions of the
/// symbols the set already has. Returns the new generator matrix (d x d, floats) and per row the
/// slack to add to its remainder for the rounding of B diag(s).
pub fn reduce(generators: &DMatrix<f64>, carried: bool) -> (DMatrix<f64>, Vec<f64>) {
    let d = generators.nrows();
    // Candidates are formed and compared with each row scaled to its box radius: rows of very
    // different scales (a position error of 1e-3 beside a reward error of 1) would otherwise let
    // the QR basis mix the large row's error into the small ones. Scaling by powers of two keeps
    // the scaled matrix exact.
    let scale: Vec<f64> = (0..d)
        .map(|i| {
            let r = generators.row(i).abs().sum();
            if r > 0.0 && r.is_finite() {
                2f64.powi((r.log2().round() as i32).clamp(-1000, 1000))
            } else {
                1.0
            }
        })
        .collect();
    let scaled = DMatrix::from_fn(d, generators.ncols(), |i, k| generators[(i, k)] / scale[i]);
    let mut candidates = vec![DMatrix::identity(d, d)];
    if carried && scaled.ncols() >= d {
        let mut b = scaled.columns(0, d).into_owned();
        if b.column_iter().all(|c| c.norm() > 0.0) {
            b.column_iter_mut().for_each(|mut c| c /= c.norm());
            candidates.push(b);
        }
    }
    if scaled.iter().all(|x| x.is_finite()) && scaled.ncols() >= d {
        let q = scaled.clone().col_piv_qr().q();
        if q.ncols() == d && q.iter().all(|x| x.is_finite()) {
            candidates.push(q);
        }
    }
    // Directions flatter than this count as flat in every candidate alike (rounding-level
    // generators must not decide the choice).
    let floor = (0..d).map(|i| scaled.row(i).abs().sum()).fold(0.0, f64::max) * 1e-9;
    let mut best: Option<(f64, DMatrix<f64>, Vec<f64>)> = None;
    for b in candidates {
        let Some(inv) = inverse(&b) else { continue };
        let s = scales(&inv, &scaled);
        // log volume: sum ln s_j + ln |det B|.
        let det = b.determinant().abs();
        if !(det > 0.0) || s.iter().any(|x| !x.is_finite()) {
            continue;
        }
        let volume = s.iter().map(|&x| x.max(floor).max(f64::MIN_POSITIVE).ln()).sum::<f64>() + det.ln();
        if best.as_ref().is_none_or(|(v, _, _)| volume < *v) {
            best = Some((volume, b, s));
        }
    }
    // Scales beyond the floats' range (no candidate usable): the box, in the rows' own scales.
    let Some((_, b, s)) = best else { return boxed(generators) };
    // Back to the rows' own scales: D B diag(s), D exact powers of two.
    let mut out = DMatrix::zeros(d, d);
    let mut slack = vec![0.0; d];
    for i in 0..d {
        for j in 0..d {
            let exact = Interval::point(b[(i, j)] * scale[i]) * Interval::point(s[j]);
            let m = exact.mid();
            out[(i, j)] = m;
            slack[i] = add_up(slack[i], (exact - Interval::point(m)).mag());
        }
    }
    (out, slack)
}

/// The box of the zonotope: B = I, s_i = sum_k |G_ik| rounded up.
fn boxed(generators: &DMatrix<f64>) -> (DMatrix<f64>, Vec<f64>) {
    let d = generators.nrows();
    let s: Vec<f64> = (0..d).map(|i| generators.row(i).iter().fold(0.0, |acc, x| add_up(acc, x.abs()))).collect();
    (DMatrix::from_fn(d, d, |i, j| if i == j { s[i] } else { 0.0 }), vec![0.0; d])
}

/// s_j >= sum_k |(inv G)_jk| for an interval matrix `inv`.
fn scales(inv: &[Interval], generators: &DMatrix<f64>) -> Vec<f64> {
    let d = generators.nrows();
    (0..d)
        .map(|j| {
            (0..generators.ncols()).fold(0.0, |s, k| {
                let entry = (0..d).fold(Interval::ZERO, |acc, l| acc + inv[j * d + l] * Interval::point(generators[(l, k)]));
                add_up(s, entry.mag())
            })
        })
        .collect()
}

/// An interval matrix (row-major) containing B^-1, or None when B is too ill-conditioned for
/// the check: with M a float inverse and R = I - M B (in intervals), ||R|| <= 1/2 gives
/// B^-1 = (I - R)^-1 M = M + S M with every |S_ij| <= ||R|| / (1 - ||R||).
pub fn inverse(b: &DMatrix<f64>) -> Option<Vec<Interval>> {
    let d = b.nrows();
    let m = b.clone().try_inverse()?;
    if m.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let mut norm = 0.0f64;
    for i in 0..d {
        let mut row = 0.0;
        for j in 0..d {
            let mb = (0..d).fold(Interval::ZERO, |acc, l| acc + Interval::point(m[(i, l)]) * Interval::point(b[(l, j)]));
            let r = if i == j { Interval::ONE - mb } else { -mb };
            row = add_up(row, r.mag());
        }
        norm = norm.max(row);
    }
    if !(norm <= 0.5) {
        return None;
    }
    let delta = (norm / (1.0 - norm).next_down()).next_up();
    let col_abs: Vec<f64> = (0..d).map(|j| (0..d).fold(0.0, |s, l| add_up(s, m[(l, j)].abs()))).collect();
    Some((0..d * d).map(|k| Interval::point(m[(k / d, k % d)]).inflate(mul_up(delta, col_abs[k % d]))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points G xi for xi at the corners and at random inside lie in the parallelotope:
    /// xi' = (A')^-1 (G xi) has |xi'_j| <= 1 up to the slack.
    fn contains_zonotope(g: &DMatrix<f64>, a: &DMatrix<f64>, slack: &[f64]) -> bool {
        let d = g.nrows();
        let inv = a.clone().try_inverse().expect("invertible");
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        (0..4000).all(|k| {
            let xi: Vec<f64> = (0..g.ncols()).map(|_| if k % 2 == 0 { next().signum() } else { next() }).collect();
            let x = g * nalgebra::DVector::from_vec(xi);
            let e = &inv * &x;
            // The slack is a box around the parallelotope: allow it through the inverse.
            let tol: f64 = slack.iter().sum::<f64>() * inv.abs().max() * d as f64 + 1e-12;
            e.iter().all(|v| v.abs() <= 1.0 + tol)
        })
    }

    #[test]
    fn sheared_zonotope_is_enclosed_tighter_than_its_box() {
        // A thin set along the diagonal plus a small box: boxing it doubles the area many times.
        let g = DMatrix::from_row_slice(2, 4, &[1.0, 0.99, 0.01, 0.0, 1.0, 1.01, 0.0, 0.01]);
        let (a, slack) = reduce(&g, true);
        assert!(contains_zonotope(&g, &a, &slack));
        let area = a.determinant().abs() * 4.0;
        let box_area = 4.0 * (g.row(0).abs().sum() * g.row(1).abs().sum());
        assert!(area < 0.1 * box_area, "parallelotope {area} against box {box_area}");
    }

    #[test]
    fn every_candidate_encloses() {
        let g = DMatrix::from_row_slice(
            3,
            6,
            &[0.3, -0.2, 0.1, 0.05, 0.0, 0.0, 0.1, 0.4, -0.3, 0.0, 0.02, 0.0, -0.2, 0.1, 0.5, 0.0, 0.0, 0.01],
        );
        for carried in [false, true] {
            let (a, slack) = reduce(&g, carried);
            assert!(contains_zonotope(&g, &a, &slack));
        }
    }

    #[test]
    fn extreme_scales_fall_back_to_the_box() {
        // Rows near the floats' limits: no candidate's scales are finite, the box still encloses.
        let g = DMatrix::from_row_slice(2, 4, &[1e300, 1e300, 1e300, 0.0, 1e-300, -1e-300, 0.0, 1e-300]);
        let (a, slack) = reduce(&g, true);
        assert!(a.iter().all(|x| x.is_finite()) && slack.iter().all(|x| x.is_finite()));
        assert!(a[(0, 0)].abs() + a[(0, 1)].abs() >= 3e300 && a[(1, 0)].abs() + a[(1, 1)].abs() >= 3e-300);
    }

    #[test]
    fn inverse_encloses_the_true_inverse() {
        let b = DMatrix::from_row_slice(2, 2, &[1.0, 0.3, 0.2, 0.7]);
        let inv = inverse(&b).unwrap();
        // The exact inverse of [[1, 0.3], [0.2, 0.7]] is [[0.7, -0.3], [-0.2, 1]] / 0.64.
        let exact = [0.7 / 0.64, -0.3 / 0.64, -0.2 / 0.64, 1.0 / 0.64];
        for (i, e) in inv.iter().zip(exact) {
            assert!(i.contains(e) && i.width() < 1e-12, "{i} vs {e}");
        }
        assert!(inverse(&DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 1.0, 1.0])).is_none());
    }
}
