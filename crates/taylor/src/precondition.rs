//! Preconditioning: split the state at a step start into a "right" model (the normalised
//! coordinates x̂ as functions of the initial-set variables z, with range inside [-1, 1]) and an
//! affine "left" initial condition x0(x̂) = c + M x̂ from which the next Picard step starts.
//!
//! Flow* only translates and scales (M diagonal; "identity"); "QR" additionally rotates by the
//! orthogonal factor of the linear part (Makino and Berz' QR preconditioning), which keeps
//! sheared sets from being boxed in the wrong axes. Caveat, measured: the interval remainder
//! is then boxed in rotated axes at every step, growing by up to (|cos| + |sin|)^2 per step
//! for rotating flows, so identity is the default (and what Flow* 2.1.0 actually runs for
//! both keywords). Keeping the remainder on the left instead was tried and was worse still:
//! it then passes through the Picard validation as an interval (wrapping). The inverse of the float matrix used for
//! the right model is enclosed rigorously, and its error goes into x0's remainder, so
//! x = c + M (right(z)) holds exactly for every true state.
use crate::interval::{add_up, mul_up, Interval};
use crate::tm::{Ctx, TaylorModel};
use nalgebra::DMatrix;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precondition {
    Identity,
    Qr,
}

pub struct Preconditioned {
    /// x0_i(x̂) = c_i + sum_j M_ij x̂_j + E_i, over variables 1..=n of the space.
    pub x0: Vec<TaylorModel>,
    /// x̂_j(z): range within [-1, 1] for every true state.
    pub right: Vec<TaylorModel>,
    /// The linear map T with x̂ = T (x - c), row-major n x n (as used for `right`).
    pub to_normalised: Vec<Interval>,
}

/// `x[i]` are models over the initial-set variables z_1..z_n (variables 1..=n; 0 is time);
/// the true state may differ from them by up to `extra[i]` (a symbolic remainder's box), which
/// the scaling makes room for.
pub fn precondition(x: &[TaylorModel], extra: &[f64], kind: Precondition, ctx: &Ctx) -> Preconditioned {
    let n = x.len();
    let space = &ctx.space;
    let centre: Vec<f64> = x.iter().map(|t| t.constant_term()).collect();
    let y: Vec<TaylorModel> = x.iter().zip(&centre).map(|(t, &c)| t.add_constant(-c)).collect();
    let q = match kind {
        Precondition::Identity => DMatrix::<f64>::identity(n, n),
        // The linear part in the set's variables is square only when they match the state.
        Precondition::Qr if space.nvars == n + 1 => {
            let a = DMatrix::from_fn(n, n, |i, j| y[i].linear_coefficient(space, j + 1));
            orthogonal_factor(a)
        }
        Precondition::Qr => DMatrix::<f64>::identity(n, n),
    };
    // y' = Q^T y, then scale each row into [-1, 1].
    let rotated: Vec<TaylorModel> = match kind {
        Precondition::Qr if space.nvars == n + 1 => (0..n)
            .map(|i| (0..n).fold(TaylorModel::zero(), |acc, j| if q[(j, i)] == 0.0 { acc } else { acc.add(&y[j].scale(q[(j, i)])) }))
            .collect(),
        _ => y,
    };
    let mut inv_d = Vec::with_capacity(n);
    let mut right = Vec::with_capacity(n);
    let mut to_normalised = vec![Interval::ZERO; n * n];
    // Each row is centred on the midpoint of its range, not on its constant term: x0 spans
    // centre +- b, so a nonlinear row whose range is lopsided about its constant term (a
    // saturating tanh controller's held output) would otherwise widen every segment's box and
    // the next step's start by the difference (bench/README.md, ARCH-COMP docking).
    let mut mids = vec![0.0; n];
    for (i, r) in rotated.iter().enumerate() {
        let slack = (0..n).fold(0.0, |s, j| add_up(s, mul_up(q[(j, i)].abs(), extra[j])));
        let range = r.bound(space);
        mids[i] = if range.is_bounded() { range.mid() } else { 0.0 };
        let r = &r.add_constant(-mids[i]);
        let b = add_up((range - Interval::point(mids[i])).mag(), slack);
        if b == 0.0 {
            inv_d.push(None);
            right.push(TaylorModel::zero());
        } else {
            // d <= 1 / b exactly, so d * |y'| <= 1 for every true value.
            let d = (1.0 / b).next_down();
            inv_d.push(Some(Interval::point(d).recip().expect("d > 0")));
            right.push(r.scale(d));
            for j in 0..n {
                to_normalised[i * n + j] = Interval::point(d) * Interval::point(q[(j, i)]);
            }
        }
    }
    // Enclose M = Q^{-T} D^{-1} = Q (I - F)^{-1} D^{-1} with F = I - Q^T Q.
    let delta = if q.is_identity(0.0) { 0.0 } else { inverse_defect(&q) };
    let row_abs: Vec<f64> = (0..n).map(|i| (0..n).fold(0.0, |s, l| add_up(s, q[(i, l)].abs()))).collect();
    let mut x0 = Vec::with_capacity(n);
    // x = c + Q^{-T} (D^{-1} x̂ + mids) with Q^{-T} = Q (I + E), |E_lj| <= delta.
    let mids_abs = mids.iter().fold(0.0, |s, m| add_up(s, m.abs()));
    for i in 0..n {
        let mut t = TaylorModel::constant(centre[i]);
        let constant = (0..n).fold(Interval::point(centre[i]), |acc, j| acc + Interval::point(q[(i, j)]) * Interval::point(mids[j]));
        let mut coef = vec![0.0; space.var_index(n) + 1];
        coef[0] = constant.mid();
        let mut err = add_up((constant - Interval::point(coef[0])).mag(), mul_up(mul_up(delta, row_abs[i]), mids_abs));
        for j in 0..n {
            let Some(id) = inv_d[j] else { continue };
            let m = Interval::point(q[(i, j)]) * id;
            let p = m.mid();
            coef[space.var_index(j + 1)] = p;
            err = add_up(err, (m - Interval::point(p)).mag());
            err = add_up(err, mul_up(mul_up(delta, row_abs[i]), id.mag()));
        }
        t.coef = coef;
        t.rem = Interval::symmetric(err);
        x0.push(t);
    }
    Preconditioned { x0, right, to_normalised }
}

/// Q of a column-pivoted QR factorisation (columns of largest norm first, as Makino and Berz
/// recommend), or the identity when the factorisation is unusable.
fn orthogonal_factor(a: DMatrix<f64>) -> DMatrix<f64> {
    let n = a.nrows();
    if a.iter().any(|v| !v.is_finite()) {
        return DMatrix::identity(n, n);
    }
    let qr = a.col_piv_qr();
    let q = qr.q();
    if q.iter().all(|v| v.is_finite()) && q.nrows() == n && q.ncols() == n {
        q
    } else {
        DMatrix::identity(n, n)
    }
}

/// delta >= max |((Q^T Q)^{-1} - I)_ij|, from phi = ||I - Q^T Q||_inf computed in intervals.
fn inverse_defect(q: &DMatrix<f64>) -> f64 {
    let n = q.nrows();
    let mut phi = 0.0f64;
    for i in 0..n {
        let mut row = 0.0;
        for j in 0..n {
            let mut g = Interval::ZERO;
            for l in 0..n {
                g = g + Interval::point(q[(l, i)]) * Interval::point(q[(l, j)]);
            }
            let f = if i == j { Interval::ONE - g } else { -g };
            row = add_up(row, f.mag());
        }
        phi = phi.max(row);
    }
    assert!(phi < 0.5, "orthogonal factor is not orthogonal (defect {phi})");
    // phi / (1 - phi), rounded up.
    let denom = (1.0 - phi).next_down();
    (phi / denom).next_up()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::Space;

    #[test]
    fn left_of_right_reproduces_the_state() {
        let ctx = Ctx::new(Space::get(3, 4, 1).unwrap(), 4, 0.0);
        let z1 = TaylorModel::var(&ctx, 1);
        let z2 = TaylorModel::var(&ctx, 2);
        // A sheared, slightly nonlinear set.
        let x = vec![
            z1.scale(0.3).add(&z2.scale(0.1)).add_constant(1.0),
            z1.scale(0.29).add(&z2.scale(0.12)).add(&z1.mul(&z2, &ctx).scale(0.01)).add_constant(-2.0),
        ];
        for kind in [Precondition::Identity, Precondition::Qr] {
            let p = precondition(&x, &[0.0, 0.0], kind, &ctx);
            let args = vec![TaylorModel::zero(), p.right[0].clone(), p.right[1].clone()];
            for i in 0..2 {
                let back = p.x0[i].compose(&args, &ctx);
                for a in 0..=20 {
                    for b in 0..=20 {
                        let pt = [Interval::ZERO, Interval::point(-1.0 + a as f64 / 10.0), Interval::point(-1.0 + b as f64 / 10.0)];
                        let truth = x[i].eval_interval(&ctx.space, &pt);
                        let got = back.eval_interval(&ctx.space, &pt);
                        assert!(got.contains(truth.mid()), "{kind:?} {got} misses {truth}");
                    }
                }
                assert!(p.right[i].bound(&ctx.space).mag() <= 1.0 + 1e-12);
            }
        }
    }

    #[test]
    fn a_lopsided_row_spans_its_range_not_more() {
        // x = 1 + z1^2 + z2^2 / 2 has range [1, 2.5] and constant term 1: the box x0 spans
        // must be that range, not 1 +- 1.5, and still reproduce the state.
        let ctx = Ctx::new(Space::get(3, 4, 1).unwrap(), 4, 0.0);
        let z1 = TaylorModel::var(&ctx, 1);
        let z2 = TaylorModel::var(&ctx, 2);
        let x = vec![z1.mul(&z1, &ctx).add(&z2.mul(&z2, &ctx).scale(0.5)).add_constant(1.0), z2.clone()];
        let p = precondition(&x, &[0.0, 0.0], Precondition::Identity, &ctx);
        let span = p.x0[0].bound(&ctx.space);
        assert!(span.lo() >= 1.0 - 1e-9 && span.hi() <= 2.5 + 1e-9, "{span}");
        let args = vec![TaylorModel::zero(), p.right[0].clone(), p.right[1].clone()];
        let back = p.x0[0].compose(&args, &ctx);
        for a in 0..=20 {
            for b in 0..=20 {
                let (u, v) = (-1.0 + a as f64 / 10.0, -1.0 + b as f64 / 10.0);
                let pt = [Interval::ZERO, Interval::point(u), Interval::point(v)];
                let truth = 1.0 + u * u + v * v / 2.0;
                assert!(back.eval_interval(&ctx.space, &pt).inflate(1e-12).contains(truth), "({u}, {v})");
            }
        }
    }
}
