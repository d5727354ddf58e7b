//! Error symbols of a discrete-time state, kept from step to step.
//!
//! A state x_i(z) + r_i (a Taylor model over the domain variables z with an interval remainder)
//! loses, at every step, the relation between the remainders of different states: the next
//! state's remainder is a sum of intervals, and a loop whose map feeds one state's error back
//! into another (a controller's gain on a velocity) grows it geometrically even when the true
//! error contracts (the wrapping effect). Here the space has, after the domain variables, `d`
//! more variables e_1..e_d over [-1, 1], the error symbols: a state is
//!   x_i(z) + sum_j a_ij e_j,
//! and everything computed from it (networks, expressions) carries the e_j like any variable.
//! After each step [`ErrorSymbols::renew`] folds the step's new remainders and the terms that are
//! not linear in the symbols into d fresh symbols (a parallelotope enclosure,
//! [`crate::parallelotope`]).
//!
//! Soundness: for every z there is some e in [-1, 1]^d with the true state equal to
//! x(z) + A e (not the same e at every step, which is why the symbols are renewed rather than
//! kept: a margin claimed "for this z" must hold for every e, see [`ErrorSymbols::domain_part`]).
use crate::error::Result;
use crate::interval::{add_up, Interval};
use crate::parallelotope;
use crate::space::Space;
use crate::tm::{Ctx, TaylorModel};
use nalgebra::DMatrix;
use std::sync::Arc;

#[derive(Clone)]
pub struct ErrorSymbols {
    /// Domain variables first, then one variable per symbol.
    pub ctx: Ctx,
    /// The domain variables alone (same order, same degree limit).
    pub domain: Ctx,
    /// The states (indices into the state vector) whose errors are symbols, one symbol each.
    pub states: Vec<usize>,
    /// Index in `ctx`'s space of each monomial of `domain`'s space.
    to_full: Vec<usize>,
    /// Per monomial of `ctx`'s space: Some(domain index) when it has no symbol, else the symbol
    /// of a degree-1 monomial e_j as Err(Some(j)) and any other as Err(None).
    kind: Vec<std::result::Result<usize, Option<usize>>>,
}

/// What [`ErrorSymbols::split`] returns: a model as domain polynomial, linear symbol
/// coefficients and a remainder (the model's own and every other symbol term's range).
pub struct Parts {
    pub poly: TaylorModel,
    pub linear: Vec<f64>,
}

impl ErrorSymbols {
    /// `nvars` domain variables; symbols for `states`. No symbols gives the plain domain space.
    pub fn new(nvars: usize, states: Vec<usize>, order: usize, cutoff: f64) -> Result<ErrorSymbols> {
        let d = states.len();
        let full = Space::get(nvars + d, order, 0)?;
        let dom = Space::get(nvars, order, 0)?;
        let index: std::collections::HashMap<&[u8], usize> = (0..full.len()).map(|k| (full.exponents(k), k)).collect();
        let to_full = (0..dom.len())
            .map(|k| {
                let mut e = dom.exponents(k).to_vec();
                e.resize(nvars + d, 0);
                index[&e[..]]
            })
            .collect();
        let dom_index: std::collections::HashMap<&[u8], usize> = (0..dom.len()).map(|k| (dom.exponents(k), k)).collect();
        let kind = (0..full.len())
            .map(|k| {
                let e = full.exponents(k);
                let sym = &e[nvars..];
                if sym.iter().all(|&x| x == 0) {
                    Ok(dom_index[&e[..nvars]])
                } else if sym.iter().map(|&x| x as usize).sum::<usize>() == 1 && e[..nvars].iter().all(|&x| x == 0) {
                    Err(sym.iter().position(|&x| x == 1))
                } else {
                    Err(None)
                }
            })
            .collect();
        Ok(ErrorSymbols { ctx: Ctx::new(full, order, cutoff), domain: Ctx::new(dom, order, cutoff), states, to_full, kind })
    }

    pub fn count(&self) -> usize {
        self.states.len()
    }

    pub fn nvars(&self) -> usize {
        self.domain.space.nvars
    }

    pub fn space(&self) -> &Arc<Space> {
        &self.ctx.space
    }

    /// `t` (over the full space) as domain polynomial + linear symbol coefficients; the remainder
    /// of `poly` holds `t`'s own and the range of every term that is neither.
    pub fn split(&self, t: &TaylorModel) -> Parts {
        if self.count() == 0 {
            // The full space is the domain's: nothing to separate (a network input per step).
            return Parts { poly: t.clone(), linear: vec![] };
        }
        let mut poly = vec![0.0; self.domain.space.len()];
        let mut linear = vec![0.0; self.count()];
        let mut other = TaylorModel { coef: vec![0.0; t.coef.len()], rem: Interval::ZERO };
        for (k, &c) in t.coef.iter().enumerate() {
            if c == 0.0 {
                continue;
            }
            match self.kind[k] {
                Ok(i) => poly[i] = c,
                Err(Some(j)) => linear[j] = c,
                Err(None) => other.coef[k] = c,
            }
        }
        let rem = t.rem + other.poly_bound(&self.ctx.space);
        let mut poly = TaylorModel { coef: poly, rem };
        poly.trim();
        Parts { poly, linear }
    }

    /// The model over the full space from domain polynomial (with its remainder) and linear
    /// symbol coefficients.
    pub fn join(&self, poly: &TaylorModel, linear: &[f64]) -> TaylorModel {
        let mut coef = vec![0.0; self.ctx.space.len_upto(self.ctx.order.max(1))];
        for (k, &c) in poly.coef.iter().enumerate() {
            coef[self.to_full[k]] = c;
        }
        for (j, &c) in linear.iter().enumerate() {
            coef[self.ctx.space.var_index(self.nvars() + j)] = c;
        }
        let mut t = TaylorModel { coef, rem: poly.rem };
        t.trim();
        t
    }

    /// `t` over the domain alone, valid for every value of the symbols (their terms are bounded
    /// into the remainder): what holds "for this z" whatever the step's errors were.
    pub fn domain_part(&self, t: &TaylorModel) -> TaylorModel {
        let Parts { mut poly, linear } = self.split(t);
        poly.rem = poly.rem.inflate(crate::tm::abs_sum(&linear));
        poly
    }

    /// Width of `t`'s part that is not its domain polynomial: remainder and symbol terms.
    pub fn error_width(&self, t: &TaylorModel) -> f64 {
        let p = self.domain_part(t);
        p.rem.width()
    }

    /// Folds the remainders and the non-linear symbol terms of the states with symbols into
    /// fresh symbols: afterwards each such state is x_i(z) + sum_j a_ij e_j with a remainder of
    /// rounding only. The other states (a reward sum) keep no symbol terms: the fresh symbols
    /// are new quantities, so terms in the old ones would be read as the new ones' and could
    /// cancel against them where the true errors do not (a sum of terms of opposite sign); they
    /// are bounded into the remainder instead.
    pub fn renew(&self, state: &mut [TaylorModel]) {
        let d = self.count();
        if d == 0 {
            return;
        }
        for (i, t) in state.iter_mut().enumerate() {
            if !self.states.contains(&i) && t.coef.iter().enumerate().any(|(k, &c)| c != 0.0 && self.kind[k].is_err()) {
                *t = self.join(&self.domain_part(t), &[]);
            }
        }
        let mut polys = Vec::with_capacity(d);
        let mut g = DMatrix::zeros(d, 2 * d);
        for (row, &i) in self.states.iter().enumerate() {
            let Parts { mut poly, linear } = self.split(&state[i]);
            // The remainder's centre moves into the constant; its rounding widens the radius.
            let centre = poly.rem.mid();
            let c0 = poly.coef.first().copied().unwrap_or(0.0);
            let sum = c0 + centre;
            let radius = add_up(poly.rem.radius(), (Interval::point(c0) + Interval::point(centre) - Interval::point(sum)).mag());
            if poly.coef.is_empty() {
                poly.coef.push(sum);
            } else {
                poly.coef[0] = sum;
            }
            poly.rem = Interval::ZERO;
            for (j, &a) in linear.iter().enumerate() {
                g[(row, j)] = a;
            }
            g[(row, d + row)] = radius;
            polys.push(poly);
        }
        if g.iter().any(|x| !x.is_finite()) {
            return;
        }
        let (a, slack) = parallelotope::reduce(&g, true);
        for (row, (&i, mut poly)) in self.states.iter().zip(polys).enumerate() {
            poly.rem = Interval::symmetric(slack[row]);
            let linear: Vec<f64> = (0..d).map(|j| a[(row, j)]).collect();
            state[i] = self.join(&poly, &linear);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// x+ = R x with R a rotation by 0.3 rad and a fresh remainder of 1e-3 each step: boxing
    /// each step grows the remainder by |cos| + |sin| = 1.25 per step, symbols do not.
    #[test]
    fn renewed_symbols_do_not_wrap() {
        let sym = ErrorSymbols::new(1, vec![0, 1], 3, 0.0).unwrap();
        let ctx = &sym.ctx;
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let mut state = vec![TaylorModel::affine(ctx, 0.0, 0, 0.1), TaylorModel::constant(0.0)];
        let mut boxed = state.clone();
        // Float runs: z, and an error of at most 1e-3 per state and step.
        let mut seed = 7u64;
        let mut uniform = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        let mut runs: Vec<(f64, [f64; 2])> = (0..2000)
            .map(|_| {
                let z = uniform();
                (z, [0.1 * z, 0.0])
            })
            .collect();
        for _ in 0..30 {
            let step = |x: &[TaylorModel]| {
                let mut y = vec![x[0].scale(c).sub(&x[1].scale(s)), x[0].scale(s).add(&x[1].scale(c))];
                y.iter_mut().for_each(|t| t.rem = t.rem.inflate(1e-3));
                y
            };
            state = step(&state);
            sym.renew(&mut state);
            boxed = step(&boxed);
            boxed = boxed.iter().map(|t| sym.domain_part(t)).map(|p| sym.join(&p, &[0.0, 0.0])).collect();
            for (z, x) in runs.iter_mut() {
                *x = [c * x[0] - s * x[1] + 1e-3 * uniform(), s * x[0] + c * x[1] + 1e-3 * uniform()];
                let at = [Interval::point(*z), Interval::symmetric(1.0), Interval::symmetric(1.0)];
                for i in 0..2 {
                    let range = state[i].eval_interval(&ctx.space, &at);
                    assert!(range.contains(x[i]), "z = {z}: state {i} = {} outside {range}", x[i]);
                }
            }
        }
        let w = |x: &[TaylorModel]| x[0].bound(&ctx.space).width();
        // The true hull of x: the rotated segment plus the 30 rotated error boxes (0.2585).
        let exact =
            0.2 * 9.0f64.cos().abs() + 2e-3 * (0..30).map(|k| (0.3 * k as f64).cos().abs() + (0.3 * k as f64).sin().abs()).sum::<f64>();
        assert!(w(&state) < 1.2 * exact, "symbols: {} against the true {exact}", w(&state));
        assert!(w(&boxed) > 10.0 * w(&state), "boxing: {} against {}", w(&boxed), w(&state));
        assert!(w(&boxed) > 2.0 * w(&state), "boxing: {} against {}", w(&boxed), w(&state));
    }
}
