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
use crate::error::{Result, TaylorError};
use crate::interval::Interval;
use crate::space::Space;
use crate::tm::compose_all;
use crate::tm::{Ctx, TaylorModel};
use std::sync::Arc;

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

/// [`range`], or the point a constant model is: the naive bound rounds outward, which made the
/// box of a variable reset to 0 a side of subnormal width (a symbol or coordinate of that
/// radius, whose inverse scaling spoilt the flowpipes that started from it).
pub fn range_or_point(m: &TaylorModel, space: &Space) -> Interval {
    match m.coef[..] {
        [] | [_] if m.rem == Interval::ZERO => Interval::point(m.constant_term()),
        _ => range(m, space),
    }
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
                let covers = if linear[v] > 0.0 {
                    nc - nr <= end && nc + nr >= end + delta * r
                } else {
                    nc + nr >= end && nc - nr <= end - delta * r
                };
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

/// How a model's range is bounded: a trade of time for tightness, and the way to compare
/// with another tool like for like (Flow* prints [`Bounder::Interval`] boxes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bounder {
    /// The linear dominated bounder [`range`].
    Dominated,
    /// Monomial by monomial interval evaluation ([`TaylorModel::bound`]).
    Interval,
    /// The domain cut into k pieces along every variable the models use; each piece
    /// re-expanded around its centre and bounded monomial by monomial; the hull of the pieces.
    Subdivision(usize),
    /// The hull of the Bernstein coefficients (exact at the corners; costs prod (degree + 1)).
    Bernstein,
}

/// Most pieces (subdivision) or Bernstein coefficients per model before refusing: beyond,
/// the bound takes longer than the flowpipe.
pub const MAX_PIECES: usize = 1 << 20;

/// Encloses the range of each model over the domain of `space` with the chosen bounder.
pub fn bound_all(models: &[TaylorModel], space: &Arc<Space>, bounder: Bounder) -> Result<Vec<Interval>> {
    match bounder {
        Bounder::Dominated => Ok(models.iter().map(|m| range(m, space)).collect()),
        Bounder::Interval => Ok(models.iter().map(|m| m.bound(space)).collect()),
        Bounder::Subdivision(k) => subdivided(models, space, k),
        Bounder::Bernstein => models.iter().map(|m| bernstein(m, space)).collect(),
    }
}

/// Variables that occur in some model with a nonzero coefficient.
fn used_variables(models: &[TaylorModel], space: &Space) -> Vec<usize> {
    (0..space.nvars)
        .filter(|&v| models.iter().any(|m| m.coef.iter().enumerate().any(|(i, &c)| c != 0.0 && space.exponent(i, v) > 0)))
        .collect()
}

/// The models rewritten over only the variables they use (same domains, same values): the
/// re-expansions below cost far less in the smaller space (Laub-Loomis: 7 of 9 variables).
fn restrict(models: &[TaylorModel], space: &Space) -> Result<(Arc<Space>, Vec<TaylorModel>)> {
    let used = used_variables(models, space);
    let mask = used.iter().enumerate().fold(0u64, |m, (k, &v)| if space.is_unit(v) { m | 1 << k } else { m });
    let small = Space::get(used.len().max(1), space.order, mask)?;
    let index: std::collections::HashMap<&[u8], usize> = (0..small.len()).map(|i| (small.exponents(i), i)).collect();
    let mut exps = vec![0u8; small.nvars];
    let out = models
        .iter()
        .map(|m| {
            let mut coef = vec![0.0; small.len()];
            for (i, &c) in m.coef.iter().enumerate().filter(|(_, c)| **c != 0.0) {
                for (k, &v) in used.iter().enumerate() {
                    exps[k] = space.exponent(i, v);
                }
                coef[index[&exps[..]]] = c;
            }
            let mut t = TaylorModel { coef, rem: m.rem };
            t.trim();
            t
        })
        .collect();
    Ok((small, out))
}

fn subdivided(full_models: &[TaylorModel], full_space: &Arc<Space>, k: usize) -> Result<Vec<Interval>> {
    let (space, models) = restrict(full_models, full_space)?;
    let (space, models) = (&space, &models[..]);
    let used = used_variables(models, space);
    let pieces = (0..used.len()).try_fold(1usize, |p, _| p.checked_mul(k).filter(|&q| q <= MAX_PIECES));
    let Some(pieces) = pieces.filter(|_| k >= 1) else {
        return Err(TaylorError::input(format!(
            "subdivision into {k} pieces along {} variables exceeds {MAX_PIECES} pieces (or k is 0); use fewer pieces",
            used.len()
        )));
    };
    let sym = Space::get(space.nvars, space.order, 0)?;
    let ctx = Ctx::new(sym.clone(), space.order, 0.0);
    let mut hull: Vec<Option<Interval>> = vec![None; models.len()];
    for piece in 0..pieces {
        let mut args = vec![TaylorModel::zero(); space.nvars];
        let mut rest = piece;
        for &v in &used {
            let p = rest % k;
            rest /= k;
            let (lo, width) = if space.is_unit(v) { (0.0, 1.0) } else { (-1.0, 2.0) };
            let w = width / k as f64;
            let c = lo + (p as f64 + 0.5) * w;
            // Radius covering the piece despite the roundings of c and w.
            let r = (0.5 * w * (1.0 + 1e-12) + c.abs() * 1e-15).next_up();
            args[v] = TaylorModel::affine(&ctx, c, v, r);
        }
        for (h, q) in hull.iter_mut().zip(compose_all(models, &args, &ctx)) {
            let b = q.bound(&sym);
            *h = Some(h.map_or(b, |x| x.hull(&b)));
        }
    }
    // The dominated bound is cheap next to the pieces and sometimes tighter: keep both.
    Ok(hull.into_iter().zip(full_models).map(|(h, m)| h.unwrap_or(Interval::ZERO).intersect(&range(m, full_space))).collect())
}

/// Binomial coefficient as an interval (exact while it fits in 53 bits).
fn binomial(n: usize, k: usize) -> Interval {
    let mut c: u128 = 1;
    for i in 0..k {
        c = c * (n - i) as u128 / (i + 1) as u128;
    }
    let f = c as f64;
    if f as u128 == c {
        Interval::point(f)
    } else {
        Interval::raw(f.next_down(), f.next_up())
    }
}

fn bernstein(full: &TaylorModel, full_space: &Arc<Space>) -> Result<Interval> {
    let (space, mut small) = restrict(std::slice::from_ref(full), full_space)?;
    let (space, m) = (&space, &small.pop().expect("one model"));
    let used = used_variables(std::slice::from_ref(m), space);
    if used.is_empty() {
        return Ok(m.bound(space));
    }
    let degree: Vec<usize> = used
        .iter()
        .map(|&v| (0..m.coef.len()).filter(|&i| m.coef[i] != 0.0).map(|i| space.exponent(i, v) as usize).max().unwrap_or(0))
        .collect();
    let size = degree.iter().try_fold(1usize, |s, d| s.checked_mul(d + 1).filter(|&q| q <= MAX_PIECES));
    let Some(size) = size else {
        return Err(TaylorError::input(format!(
            "Bernstein bound needs prod (degree + 1) = more than {MAX_PIECES} coefficients here; use subdivision or the dominated bounder"
        )));
    };
    // Over u in [0, 1]^n: x_v = 2 u_v - 1 for the symmetric variables.
    let all_unit = Space::get(space.nvars, space.order, (1u64 << space.nvars) - 1)?;
    let ctx = Ctx::new(all_unit.clone(), space.order, 0.0);
    let args: Vec<TaylorModel> = (0..space.nvars)
        .map(|v| if space.is_unit(v) { TaylorModel::var(&ctx, v) } else { TaylorModel::affine(&ctx, -1.0, v, 2.0) })
        .collect();
    let q = compose_all(std::slice::from_ref(m), &args, &ctx).pop().expect("one model");
    let strides: Vec<usize> = degree
        .iter()
        .scan(1, |s, d| {
            let here = *s;
            *s *= d + 1;
            Some(here)
        })
        .collect();
    let mut t = vec![Interval::ZERO; size];
    for (i, &c) in q.coef.iter().enumerate() {
        if c == 0.0 {
            continue;
        }
        let mut at = 0;
        for (u, &v) in used.iter().enumerate() {
            at += space.exponent(i, v) as usize * strides[u];
        }
        t[at] = t[at] + Interval::point(c);
    }
    // Power to Bernstein basis one variable at a time: b_j = sum_{i<=j} C(j,i) / C(d,i) a_i.
    for (u, &d) in degree.iter().enumerate() {
        let s = strides[u];
        let ratio: Vec<Vec<Interval>> =
            (0..=d).map(|j| (0..=j).map(|i| binomial(j, i) * binomial(d, i).recip().expect("C(d, i) >= 1")).collect()).collect();
        for start in (0..size).filter(|&x| (x / s).is_multiple_of(d + 1)) {
            let a: Vec<Interval> = (0..=d).map(|i| t[start + i * s]).collect();
            for j in 0..=d {
                t[start + j * s] = (0..=j).fold(Interval::ZERO, |acc, i| acc + ratio[j][i] * a[i]);
            }
        }
    }
    let lo = t.iter().map(|x| x.lo()).fold(f64::INFINITY, f64::min);
    let hi = t.iter().map(|x| x.hi()).fold(f64::NEG_INFINITY, f64::max);
    // Without degree elevation the Bernstein hull can be wider than the naive bound: keep both.
    Ok((Interval::raw(lo, hi) + q.rem).intersect(&full.bound(full_space)))
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

    #[test]
    fn every_bounder_encloses_sampled_values_and_refines() {
        // A nonlinear model in two [-1, 1] variables plus the unit variable 0.
        let space = Space::get(3, 4, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 4, 0.0);
        let (s, x, y) = (TaylorModel::var(&ctx, 0), TaylorModel::var(&ctx, 1), TaylorModel::var(&ctx, 2));
        let mut p = x
            .scale(0.8)
            .add(&y.scale(-0.3))
            .add(&x.mul(&y, &ctx).scale(0.5))
            .add(&x.square(&ctx).mul(&x, &ctx).scale(-0.4))
            .add(&s.mul(&y, &ctx).scale(0.2));
        p.rem = Interval::symmetric(1e-3);
        let models = vec![p.clone()];
        let naive = bound_all(&models, &space, Bounder::Interval).unwrap()[0];
        let mut widths = vec![];
        for b in [Bounder::Dominated, Bounder::Subdivision(1), Bounder::Subdivision(4), Bounder::Subdivision(16), Bounder::Bernstein] {
            let r = bound_all(&models, &space, b).unwrap()[0];
            for i in 0..=40 {
                for j in 0..=40 {
                    for k in 0..=4 {
                        let pt = [k as f64 / 4.0, -1.0 + i as f64 / 20.0, -1.0 + j as f64 / 20.0];
                        let v = p.eval_interval(&space, &pt.map(Interval::point));
                        assert!(r.lo() <= v.lo() && v.hi() <= r.hi(), "{b:?}: {r} misses {v}");
                    }
                }
            }
            assert!(r.width() <= naive.width() * (1.0 + 1e-12), "{b:?}: {r} wider than {naive}");
            widths.push(r.width());
        }
        // Finer subdivision is tighter, and 16 pieces beat the single piece clearly.
        assert!(widths[3] <= widths[2] && widths[2] < 0.8 * widths[1], "{widths:?}");
        assert!(widths[4] < naive.width(), "{widths:?}");
        assert!(bound_all(&models, &space, Bounder::Subdivision(0)).is_err());
    }
}
