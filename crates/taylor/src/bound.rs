//! Range bounding sharper than monomial-wise interval evaluation: a linear dominated bounder
//! (Makino and Berz, 2005).
//!
//! Why LDB: the final boxes of flowpipes and the safety checks are dominated by the linear
//! part of the model, and LDB uses exactly that: for the lower bound, the corner minimising
//! the linear part is a candidate minimiser; any point farther than (width of the nonlinear
//! part) / |a_v| from it along x_v is provably worse, so the box shrinks towards the corner
//! and the polynomial is re-expanded on the smaller box, where the naive bound is tighter.
//! Each lower bound found is valid because the global minimiser never leaves the box.
//! Bernstein bounds were not chosen: their cost grows with (order + 1)^n.
use crate::interval::Interval;
use crate::space::Space;
use crate::tm::{Ctx, TaylorModel};

/// Iterations of shrinking; each costs one polynomial re-expansion.
const ITERATIONS: usize = 4;

/// A rigorous enclosure of the range of `m` over its domain, at least as tight as the naive one.
pub fn range(m: &TaylorModel, space: &Space) -> Interval {
    let naive = m.poly_bound(space);
    if m.coef.len() <= 1 + space.nvars {
        // Affine: the naive bound is exact.
        return naive + m.rem;
    }
    let poly = TaylorModel { coef: m.coef.clone(), rem: Interval::ZERO };
    let lo = lower(&poly, space).max(naive.lo());
    let hi = (-lower(&poly.neg(), space)).min(naive.hi());
    Interval::raw(lo, hi) + m.rem
}

/// A lower bound of the polynomial over the domain of `space`.
fn lower(p: &TaylorModel, space: &Space) -> f64 {
    let Ok(sym) = Space::get(space.nvars, space.order, 0) else { return p.poly_bound(space).lo() };
    let ctx = Ctx::new(sym.clone(), space.order, 0.0);
    // Current box per variable as (centre, radius) in the original coordinates.
    let mut boxes: Vec<(f64, f64)> = (0..space.nvars).map(|v| if space.is_unit(v) { (0.5, 0.5) } else { (0.0, 1.0) }).collect();
    let mut best = p.poly_bound(space).lo();
    for _ in 0..ITERATIONS {
        // q(y) = p(c + r y) over y in [-1, 1]^n.
        let args: Vec<TaylorModel> = boxes.iter().enumerate().map(|(v, &(c, r))| TaylorModel::affine(&ctx, c, v, r)).collect();
        let q = p.compose(&args, &ctx);
        let whole = q.bound(&sym);
        best = best.max(whole.lo());
        let mut nonlinear = q.clone();
        let linear: Vec<f64> = (0..space.nvars).map(|v| q.linear_coefficient(&sym, v)).collect();
        for v in 0..space.nvars {
            if let Some(c) = nonlinear.coef.get_mut(sym.var_index(v)) {
                *c = 0.0;
            }
        }
        let nb = nonlinear.bound(&sym);
        let w = (nb.hi() - nb.lo()).next_up();
        let mut shrunk = false;
        for v in 0..space.nvars {
            let a = linear[v].abs();
            if a == 0.0 {
                continue;
            }
            // Minimiser within delta of the end y_v = -sign(a_v), in y units.
            let delta = ((w / a).next_up() * (1.0 + 1e-12)).next_up();
            if delta < 1.0 {
                let (c, r) = boxes[v];
                let end = if linear[v] > 0.0 { c - r } else { c + r };
                // New half-width delta * r / 2 around the point delta * r / 2 inside the end.
                let nr = (0.5 * delta * r).next_up();
                let nc = if linear[v] > 0.0 { end + nr } else { end - nr };
                // The new box must still contain the region [end, end +- delta r].
                let covers = if linear[v] > 0.0 { nc - nr <= end && nc + nr >= end + delta * r } else { nc + nr >= end && nc - nr <= end - delta * r };
                if covers {
                    boxes[v] = (nc, nr);
                    shrunk = true;
                }
            }
        }
        if !shrunk {
            break;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_coefficient_vectors_do_not_panic() {
        // x0 * x1 re-expanded on a degenerate box can lose every term past x0.
        let space = Space::get(3, 3, 0).unwrap();
        let ctx = Ctx::new(space.clone(), 3, 0.0);
        let p = TaylorModel::var(&ctx, 0).mul(&TaylorModel::var(&ctx, 1), &ctx).scale(1e-300);
        let r = range(&p, &space);
        assert!(r.contains(0.0));
        let short = TaylorModel { coef: vec![1.0, 0.5, 0.0, 0.0, 1e-3], rem: Interval::ZERO };
        assert!(range(&short, &space).contains(1.5));
    }

    #[test]
    fn tighter_than_naive_and_sound() {
        let space = Space::get(2, 4, 0).unwrap();
        let ctx = Ctx::new(space.clone(), 4, 0.0);
        let x = TaylorModel::var(&ctx, 0);
        let y = TaylorModel::var(&ctx, 1);
        // p = 2x + y + 0.3 x y + 0.2 x^2: min near (-1, -1).
        let p = x.scale(2.0).add(&y).add(&x.mul(&y, &ctx).scale(0.3)).add(&x.square(&ctx).scale(0.2));
        let naive = p.bound(&space);
        let tight = range(&p, &space);
        assert!(tight.lo() > naive.lo() + 0.1, "{tight} vs {naive}");
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for i in 0..=100 {
            for j in 0..=100 {
                let (a, b) = (-1.0 + i as f64 / 50.0, -1.0 + j as f64 / 50.0);
                let v = 2.0 * a + b + 0.3 * a * b + 0.2 * a * a;
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        assert!(tight.lo() <= lo && tight.hi() >= hi, "{tight} vs sampled [{lo}, {hi}]");
    }
}
