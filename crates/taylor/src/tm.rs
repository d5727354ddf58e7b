//! Taylor models: a float polynomial over the normalised domain plus an interval remainder.
//!
//! Coefficients are plain f64 (fast, like the Flow* toolbox), but unlike the toolbox every
//! operation bounds its own floating-point error a posteriori and adds it to the remainder:
//! a sum of m products computed in round-to-nearest is off by at most gamma_m times the sum
//! of the products' magnitudes (Higham, Accuracy and Stability, eq. 3.5), and every monomial
//! is bounded by 1 on the domain, so the error of the whole polynomial is bounded by norms.
//! Terms above the truncation order and below the cutoff are swept into the remainder with
//! the monomial's range. The invariant is: for every point of the domain, the function being
//! modelled lies in `poly(point) + rem`.
use crate::interval::{add_up, mul_up, Interval};
use crate::space::{Space, MAX_ORDER};
use std::sync::Arc;

/// Unit roundoff of binary64.
pub const U: f64 = 1.0 / 9007199254740992.0;
/// Smallest subnormal: the absolute error a product may lose to underflow.
pub const ETA: f64 = f64::from_bits(1);

/// n ETA rounded up (the underflow error of n products), built from its bits: a multiply with a
/// subnormal operand or result takes about 60 times as long as a normal one (32 ns against
/// 0.5 ns on an Intel Xeon, model 167), and these bounds are computed for every neuron.
pub fn etas(n: usize) -> f64 {
    // n ETA is exact below 2^52 ETA = f64::MIN_POSITIVE.
    match u64::try_from(n) {
        Ok(bits) if bits < 1 << 52 => f64::from_bits(bits),
        _ => mul_up(n as f64, ETA),
    }
}

/// gamma_n = n u / (1 - n u), rounded up.
pub fn gamma(n: usize) -> f64 {
    GAMMAS.get(n).copied().unwrap_or_else(|| gamma_of(n))
}

const fn gamma_of(n: usize) -> f64 {
    let nu = (n as f64 + 1.0) * U;
    (nu / (1.0 - nu)).next_up()
}

/// gamma_n for the lengths of most models and rows, built at compile time: error bounds ask for
/// it several times per Taylor-model operation, and a division each time showed in profiles.
static GAMMAS: [f64; 1024] = {
    let mut table = [0.0; 1024];
    let mut n = 0;
    while n < table.len() {
        table[n] = gamma_of(n);
        n += 1;
    }
    table
};

/// Sum of |x| rounded up.
pub fn abs_sum(v: &[f64]) -> f64 {
    let s: f64 = v.iter().map(|x| x.abs()).sum();
    mul_up(s, 1.0 + gamma(v.len()))
}

/// [`TaylorModel::poly_bound`] of the coefficients `coef` (a neuron's column, without a copy).
pub fn poly_bound_of(coef: &[f64], space: &Space) -> Interval {
    let Some((&c0, rest)) = coef.split_first() else { return Interval::ZERO };
    let (mut both, mut pos, mut neg) = (0.0f64, 0.0f64, 0.0f64);
    for (&c, &nonneg) in rest.iter().zip(&space.nonneg[1..coef.len()]) {
        let a = c.abs();
        both += if nonneg { 0.0 } else { a };
        pos += if nonneg { 0.5 * (a + c) } else { 0.0 };
        neg += if nonneg { 0.5 * (a - c) } else { 0.0 };
    }
    if !(c0 + both + pos + neg).is_finite() {
        let (mut lo, mut hi) = (c0, c0);
        for (i, &c) in coef.iter().enumerate().skip(1) {
            add_term_range(&mut lo, &mut hi, c, space.nonneg[i]);
        }
        return Interval::raw(lo, hi);
    }
    // Two more roundings: adding `both` to each one-sided sum.
    let grow = 1.0 + gamma(coef.len() + 1);
    let below = mul_up(both + neg, grow);
    let above = mul_up(both + pos, grow);
    Interval::raw((c0 - below).next_down(), (c0 + above).next_up())
}

/// The truncation order, cutoff and monomial space in force for an operation.
#[derive(Clone)]
pub struct Ctx {
    pub space: Arc<Space>,
    pub order: usize,
    pub cutoff: f64,
}

impl Ctx {
    pub fn new(space: Arc<Space>, order: usize, cutoff: f64) -> Ctx {
        let order = order.min(space.order);
        Ctx { space, order, cutoff }
    }
    pub fn with_order(&self, order: usize) -> Ctx {
        Ctx { space: self.space.clone(), order: order.min(self.space.order), cutoff: self.cutoff }
    }
    pub fn nvars(&self) -> usize {
        self.space.nvars
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct TaylorModel {
    /// Coefficients in the graded layout of the space; a prefix (trailing terms are zero).
    pub coef: Vec<f64>,
    pub rem: Interval,
}

impl TaylorModel {
    pub fn zero() -> TaylorModel {
        TaylorModel { coef: vec![], rem: Interval::ZERO }
    }

    pub fn constant(c: f64) -> TaylorModel {
        TaylorModel { coef: vec![c], rem: Interval::ZERO }
    }

    /// The constant function whose value is only known to lie in `iv`.
    pub fn from_interval(iv: Interval) -> TaylorModel {
        let m = iv.mid();
        TaylorModel { coef: vec![m], rem: iv - Interval::point(m) }
    }

    /// The domain variable x_v itself.
    pub fn var(ctx: &Ctx, v: usize) -> TaylorModel {
        let mut coef = vec![0.0; ctx.space.var_index(v) + 1];
        coef[ctx.space.var_index(v)] = 1.0;
        TaylorModel { coef, rem: Interval::ZERO }
    }

    /// c + r x_v with c, r exact floats: the affine map of [-1, 1] onto a box side.
    pub fn affine(ctx: &Ctx, c: f64, v: usize, r: f64) -> TaylorModel {
        let mut t = TaylorModel::var(ctx, v);
        t.coef[0] = c;
        t.coef[ctx.space.var_index(v)] = r;
        t
    }

    pub fn constant_term(&self) -> f64 {
        self.coef.first().copied().unwrap_or(0.0)
    }

    pub fn degree(&self, space: &Space) -> usize {
        self.coef.len().checked_sub(1).map_or(0, |i| space.deg[i] as usize)
    }

    /// Range of the polynomial part by monomial-wise interval evaluation (Flow*'s bound). The
    /// three sums of |coefficients| (monomials in [-1, 1]; positive and negative ones on
    /// monomials in [0, 1], as (|c| + c) / 2 and (|c| - c) / 2, exact) are float sums of
    /// non-negative terms, rounded once at the end by 1 + gamma: a branch-free loop the compiler
    /// vectorises (it runs several times per neuron). Infinite or NaN coefficients take the
    /// term-by-term loop, which keeps them apart.
    pub fn poly_bound(&self, space: &Space) -> Interval {
        poly_bound_of(&self.coef, space)
    }

    /// Range of polynomial plus remainder.
    pub fn bound(&self, space: &Space) -> Interval {
        self.poly_bound(space) + self.rem
    }

    /// Drops trailing zero coefficients (the layout's prefix convention).
    pub(crate) fn trim(&mut self) {
        while self.coef.len() > 1 && self.coef.last() == Some(&0.0) {
            self.coef.pop();
        }
    }

    /// Moves terms with |c| < cutoff (all but the constant) and terms above `order` into the
    /// remainder, each with its monomial's range.
    pub fn sweep(&mut self, ctx: &Ctx) {
        let space = &ctx.space;
        let keep = space.len_upto(ctx.order).min(self.coef.len());
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for i in 1..self.coef.len() {
            let c = self.coef[i];
            if c != 0.0 && (i >= keep || c.abs() < ctx.cutoff) {
                add_term_range(&mut lo, &mut hi, c, space.nonneg[i]);
                self.coef[i] = 0.0;
            }
        }
        self.coef.truncate(keep.max(1));
        // Nothing swept leaves the remainder as it is (an outward sum would widen it by an ulp).
        if lo != 0.0 || hi != 0.0 {
            self.rem = self.rem + Interval::raw(lo, hi);
        }
        self.trim();
    }

    pub fn neg(&self) -> TaylorModel {
        TaylorModel { coef: self.coef.iter().map(|c| -c).collect(), rem: -self.rem }
    }

    fn combine(&self, o: &TaylorModel, sign: f64) -> TaylorModel {
        let (a, b) = (&self.coef, &o.coef);
        let shared = a.len().min(b.len());
        let mut coef = Vec::with_capacity(a.len().max(b.len()));
        coef.extend(a[..shared].iter().zip(&b[..shared]).map(|(x, y)| x + sign * y));
        // Past the shorter one, a term is one factor's own (0 + s y is s y exactly).
        coef.extend_from_slice(&a[shared..]);
        coef.extend(b[shared..].iter().map(|y| sign * y));
        // fl(a + b) is within u |fl(a + b)| / (1 - u) of a + b; bounded by 2u |c|.
        let err = mul_up(abs_sum(&coef), 2.0 * U);
        let rem = if sign > 0.0 { self.rem + o.rem } else { self.rem - o.rem };
        let mut t = TaylorModel { coef, rem: rem.inflate(err) };
        t.trim();
        t
    }

    pub fn add(&self, o: &TaylorModel) -> TaylorModel {
        self.combine(o, 1.0)
    }

    pub fn sub(&self, o: &TaylorModel) -> TaylorModel {
        self.combine(o, -1.0)
    }

    pub fn add_constant(&self, c: f64) -> TaylorModel {
        self.add(&TaylorModel::constant(c))
    }

    /// self + iv in place: the midpoint joins the constant term (its rounding, at most
    /// 2u |sum|, and the radius join the remainder). The other terms are untouched, so unlike
    /// `add` this needs no new vector and no error term for them (Horner steps of elementary
    /// functions add a constant after every product).
    pub fn add_interval_in_place(&mut self, iv: Interval) {
        let m = iv.mid();
        let sum = self.constant_term() + m;
        match self.coef.first_mut() {
            Some(c0) => *c0 = sum,
            None => self.coef.push(sum),
        }
        self.rem = (self.rem + (iv - Interval::point(m))).inflate(mul_up(2.0 * U, sum.abs()));
    }

    pub fn add_interval(&self, iv: Interval) -> TaylorModel {
        let mut t = self.clone();
        t.rem = t.rem + iv;
        t
    }

    /// s * self for an exact float s.
    pub fn scale(&self, s: f64) -> TaylorModel {
        if s == 0.0 {
            return TaylorModel::zero();
        }
        let coef: Vec<f64> = self.coef.iter().map(|c| c * s).collect();
        let err = add_up(mul_up(abs_sum(&coef), 2.0 * U), etas(coef.len()));
        TaylorModel { coef, rem: (self.rem * Interval::point(s)).inflate(err) }
    }

    /// s * self for an interval s: the midpoint scales the polynomial, the rest goes to the
    /// remainder through the polynomial's range.
    pub fn scale_interval(&self, s: Interval, space: &Space) -> TaylorModel {
        let m = s.mid();
        let mut t = self.scale(m);
        let dev = s - Interval::point(m);
        t.rem = t.rem + dev * self.poly_bound(space) + dev * self.rem;
        t
    }

    /// The product, truncated at `ctx.order`, with cutoff applied.
    pub fn mul(&self, o: &TaylorModel, ctx: &Ctx) -> TaylorModel {
        self.mul_bounded(o, None, ctx)
    }

    /// The product, given `o`'s polynomial bound where the caller has it (a factor that
    /// multiplies many models, as an elementary function's argument in its Horner steps).
    pub(crate) fn mul_bounded(&self, o: &TaylorModel, o_poly: Option<Interval>, ctx: &Ctx) -> TaylorModel {
        let space = &ctx.space;
        let o_poly = || o_poly.unwrap_or_else(|| o.poly_bound(space));
        let (la, lb) = (self.coef.len(), o.coef.len());
        if la == 0 || lb == 0 {
            let rem = self.bound(space) * (o_poly() + o.rem);
            return TaylorModel { coef: vec![], rem };
        }
        let (a, b) = (&self.coef, &o.coef);
        let out_deg = (self.degree(space) + o.degree(space)).min(ctx.order);
        let mut c = vec![0.0; space.len_upto(out_deg)];
        // A row i keeps b's terms below len_upto(order - deg i) and drops the rest: their sum of
        // |b_j| is `beyond[order - deg i]`, from sums per degree (rounded up). Only b's non-zero
        // terms take part: models of small cells keep few of the monomials below their last one
        // (most products of the cell's radii fall under the cutoff). Both on the stack for the
        // usual sizes: this product runs millions of times per cell.
        let mut by_degree = [0.0f64; MAX_ORDER + 1];
        let mut stack = [0u32; 256];
        let mut heap = Vec::new();
        let nonzero: &mut [u32] = if lb <= stack.len() {
            &mut stack[..lb]
        } else {
            heap.resize(lb, 0);
            &mut heap[..]
        };
        let mut count = 0;
        for (j, &bj) in b.iter().enumerate() {
            if bj != 0.0 {
                let d = space.deg[j] as usize;
                by_degree[d] = add_up(by_degree[d], bj.abs());
                nonzero[count] = j as u32;
                count += 1;
            }
        }
        let nonzero = &nonzero[..count];
        let mut beyond = [0.0f64; MAX_ORDER + 1];
        for d in (0..space.order).rev() {
            beyond[d] = add_up(beyond[d + 1], by_degree[d + 1]);
        }
        let b_abs = add_up(beyond[0], by_degree[0]);
        let mut top = 0; // the highest index written
        let mut trunc = 0.0;
        for i in 0..la {
            let ai = a[i];
            if ai == 0.0 {
                continue;
            }
            let di = space.deg[i] as usize;
            if di > ctx.order {
                trunc = add_up(trunc, mul_up(ai.abs(), b_abs));
                continue;
            }
            let room = ctx.order - di;
            let lim = lb.min(space.len_upto(room));
            // The pairs of i list j = 0, 1, ... in order.
            let pairs = space.pairs_of(i);
            for &j in nonzero {
                let j = j as usize;
                if j >= lim {
                    break;
                }
                let k = pairs[j].1 as usize;
                c[k] += ai * b[j];
                top = top.max(k);
            }
            if lim < lb {
                trunc = add_up(trunc, mul_up(ai.abs(), beyond[room]));
            }
        }
        c.truncate(top + 1);
        let rounding = add_up(mul_up(gamma(la.min(lb)), mul_up(abs_sum(a), b_abs)), etas(la * lb));
        // A factor without remainder (Picard iterates, boxes' models) needs no bound of the
        // other's polynomial: its terms would be exact zeros.
        let rem = match (self.rem == Interval::ZERO, o.rem == Interval::ZERO) {
            (true, true) => Interval::ZERO,
            (true, false) => self.poly_bound(space) * o.rem,
            (false, true) => self.rem * o_poly(),
            (false, false) => self.poly_bound(space) * o.rem + self.rem * o_poly() + self.rem * o.rem,
        };
        let mut t = TaylorModel { coef: c, rem: rem.inflate(add_up(trunc, rounding)) };
        t.sweep(ctx);
        t
    }

    pub fn square(&self, ctx: &Ctx) -> TaylorModel {
        self.mul(self, ctx)
    }

    /// Integer power by repeated squaring.
    pub fn powi(&self, n: u32, ctx: &Ctx) -> TaylorModel {
        let mut acc = TaylorModel::constant(1.0);
        let mut base = self.clone();
        let mut e = n;
        let mut first = true;
        while e > 0 {
            if e & 1 == 1 {
                acc = if first { base.clone() } else { acc.mul(&base, ctx) };
                first = false;
            }
            e >>= 1;
            if e > 0 {
                base = base.square(ctx);
            }
        }
        acc
    }

    /// The antiderivative in the unit variable v from 0: x_v^e -> x_v^(e+1) / (e+1).
    /// The remainder r(x_v) integrates to a value in hull(0, R) since x_v is in [0, 1].
    pub fn integrate(&self, v: usize, ctx: &Ctx) -> TaylorModel {
        let space = &ctx.space;
        debug_assert!(space.is_unit(v), "integration variable must range over [0, 1]");
        let out_deg = (self.degree(space) + 1).min(ctx.order);
        let mut c = vec![0.0; space.len_upto(out_deg)];
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        let mut out_abs = 0.0;
        for (i, &ci) in self.coef.iter().enumerate() {
            if ci == 0.0 {
                continue;
            }
            let q = ci / (space.exponent(i, v) as f64 + 1.0);
            match space.times_var(i, v).filter(|&k| (space.deg[k] as usize) <= ctx.order) {
                Some(k) => {
                    c[k] = q;
                    out_abs += q.abs();
                }
                None => {
                    // Dropped: the monomial's range times the rounded-outward quotient.
                    let m = up_abs(q);
                    if space.nonneg[i] && q > 0.0 {
                        hi = add_up(hi, m);
                    } else if space.nonneg[i] {
                        lo = (lo - m).next_down();
                    } else {
                        lo = (lo - m).next_down();
                        hi = add_up(hi, m);
                    }
                }
            }
        }
        let err = add_up(mul_up(out_abs * (1.0 + 4.0 * U), 2.0 * U), etas(self.coef.len()));
        let rem = self.rem.hull(&Interval::ZERO) + Interval::raw(lo, hi);
        let mut t = TaylorModel { coef: c, rem: rem.inflate(err) };
        t.sweep(ctx);
        t
    }

    /// Substitutes the variable v by a value in `value` (which must lie in v's domain).
    pub fn substitute(&self, v: usize, value: Interval, ctx: &Ctx) -> TaylorModel {
        let space = &ctx.space;
        let mut c = vec![0.0; self.coef.len()];
        let mut extra = Interval::ZERO;
        let mut max_len = 1;
        let mut abs_terms = 0.0;
        for (i, &ci) in self.coef.iter().enumerate() {
            if ci == 0.0 {
                continue;
            }
            let e = space.exponent(i, v);
            let k = space.without_var(i, v);
            if e == 0 {
                c[k] += ci;
                abs_terms += ci.abs();
            } else {
                let p = value.powi(e as i32).unwrap_or(Interval::ENTIRE);
                let m = p.mid();
                let q = ci * m;
                c[k] += q;
                abs_terms += q.abs();
                // Range of the rest of the monomial is within [-1, 1].
                let dev = (Interval::point(ci) * (p - Interval::point(m))).mag();
                extra = extra + Interval::symmetric(up_abs(dev + q.abs() * 2.0 * U));
            }
            max_len = max_len.max(k + 1);
        }
        c.truncate(max_len);
        let err = mul_up(abs_terms, gamma(self.coef.len()));
        let mut t = TaylorModel { coef: c, rem: (self.rem + extra).inflate(err) };
        t.trim();
        t
    }

    /// p(args): substitutes every domain variable v by the Taylor model `args[v]` (which must
    /// range within v's domain); see [`compose_all`].
    pub fn compose(&self, args: &[TaylorModel], ctx: &Ctx) -> TaylorModel {
        compose_all(std::slice::from_ref(self), args, ctx).pop().expect("one model")
    }

    /// Float evaluation of the polynomial part at a point of the domain (not rigorous).
    pub fn eval_poly(&self, space: &Space, x: &[f64]) -> f64 {
        let mut values = vec![1.0; self.coef.len()];
        let mut s = self.coef.first().copied().unwrap_or(0.0);
        for i in 1..self.coef.len() {
            let (j, v) = space.parent(i);
            values[i] = values[j] * x[v];
            s += self.coef[i] * values[i];
        }
        s
    }

    /// Rigorous enclosure of the model's values at a point: polynomial in intervals plus rem.
    pub fn eval_interval(&self, space: &Space, x: &[Interval]) -> Interval {
        let mut values = vec![Interval::ONE; self.coef.len()];
        let mut s = Interval::point(self.coef.first().copied().unwrap_or(0.0));
        for i in 1..self.coef.len() {
            let (j, v) = space.parent(i);
            values[i] = values[j] * x[v];
            if self.coef[i] != 0.0 {
                s = s + Interval::point(self.coef[i]) * values[i];
            }
        }
        s + self.rem
    }

    /// Coefficient of x_v (the linear part).
    pub fn linear_coefficient(&self, space: &Space, v: usize) -> f64 {
        self.coef.get(space.var_index(v)).copied().unwrap_or(0.0)
    }
}

/// `models[i](args)` for every i (see [`TaylorModel::compose`]). The monomials of the arguments
/// are built once, as products in graded order (each its parent's times one argument), and
/// shared by all models: composing each model on its own rebuilt every monomial n times, most
/// of a flowpipe step's time on Laub-Loomis.
pub(crate) fn compose_all(models: &[TaylorModel], args: &[TaylorModel], ctx: &Ctx) -> Vec<TaylorModel> {
    let space = &ctx.space;
    let len = models.iter().map(|m| m.coef.len()).max().unwrap_or(0);
    let mut acc = vec![TaylorModel::zero(); models.len()];
    let mut monomials: Vec<TaylorModel> = Vec::with_capacity(len);
    for i in 0..len {
        let m = if i == 0 {
            TaylorModel::constant(1.0)
        } else {
            let (j, v) = space.parent(i);
            if j == 0 {
                args[v].clone()
            } else {
                monomials[j].mul(&args[v], ctx)
            }
        };
        for (a, model) in acc.iter_mut().zip(models) {
            let ci = model.coef.get(i).copied().unwrap_or(0.0);
            if ci != 0.0 {
                *a = a.add(&m.scale(ci));
            }
        }
        monomials.push(m);
    }
    for (a, model) in acc.iter_mut().zip(models) {
        a.rem = a.rem + model.rem;
        a.sweep(ctx);
    }
    acc
}

/// Adds the range of c * (a monomial with range [0, 1] if `nonneg`, else [-1, 1]) to [lo, hi],
/// rounding outward; a NaN coefficient (an unknown term) makes it unbounded.
fn add_term_range(lo: &mut f64, hi: &mut f64, c: f64, nonneg: bool) {
    if c == 0.0 {
        return;
    }
    if c.is_nan() {
        (*lo, *hi) = (f64::NEG_INFINITY, f64::INFINITY);
        return;
    }
    if !nonneg || c < 0.0 {
        *lo = (*lo - c.abs()).next_down();
    }
    if !nonneg || c > 0.0 {
        *hi = (*hi + c.abs()).next_up();
    }
}

fn up_abs(x: f64) -> f64 {
    x.abs().next_up()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(n: usize, k: usize, unit: u64) -> Ctx {
        Ctx::new(Space::get(n, k, unit).unwrap(), k, 0.0)
    }

    /// Deterministic points of [-1, 1]^n (or [0, 1] for unit variables) for sampling tests.
    pub(crate) fn sample_points(ctx: &Ctx, count: usize, seed: u64) -> Vec<Vec<f64>> {
        let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64)
        };
        (0..count).map(|_| (0..ctx.nvars()).map(|v| if ctx.space.is_unit(v) { next() } else { 2.0 * next() - 1.0 }).collect()).collect()
    }

    #[test]
    fn etas_is_n_times_the_smallest_subnormal_and_never_below() {
        for n in [0, 1, 2, 3, 84, 7056, (1 << 52) - 1] {
            assert_eq!(etas(n), n as f64 * ETA, "n = {n}");
        }
        for n in [1 << 52, (1 << 52) + 1, 1 << 60] {
            assert!(etas(n) >= n as f64 * ETA && etas(n) <= (n as f64 * ETA).next_up(), "n = {n}");
        }
    }

    #[test]
    fn gamma_table_matches_the_formula_and_bounds_n_u() {
        for n in [0, 1, 2, 7, 100, 1023, 1024, 5000] {
            let nu = (n as f64 + 1.0) * U;
            assert_eq!(gamma(n), (nu / (1.0 - nu)).next_up());
            assert!(gamma(n) > nu);
        }
    }

    #[test]
    fn sparse_products_enclose_and_drop_no_term() {
        // Factors with most coefficients zero (as a small cell's models are), some terms above
        // the order and under the cutoff: the product holds the pointwise product, and its
        // polynomial part is the dense schoolbook product's (truncated and swept alike). The
        // second space has more monomials than the product keeps on its stack.
        let mut state = 5u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64)
        };
        for (c, round) in (0..40).map(|r| (Ctx::new(Space::get(if r < 20 { 4 } else { 7 }, 5, 1).unwrap(), 5, 1e-12), r)) {
            let mut factor = || {
                let coef: Vec<f64> = (0..c.space.len())
                    .map(|_| if next() < 0.15 { (next() - 0.5) * if next() < 0.3 { 1e-13 } else { 1.0 } } else { 0.0 })
                    .collect();
                let mut t = TaylorModel { coef, rem: Interval::symmetric(1e-9 * next()) };
                t.trim();
                t
            };
            let (a, b) = (factor(), factor());
            let ab = a.mul(&b, &c);
            let mut dense = vec![0.0; c.space.len()];
            for i in 0..a.coef.len() {
                for j in 0..b.coef.len() {
                    if (c.space.deg[i] + c.space.deg[j]) as usize <= c.order {
                        let k = c.space.pairs_of(i)[j].1 as usize;
                        dense[k] += a.coef[i] * b.coef[j];
                    }
                }
            }
            for (k, &d) in dense.iter().enumerate() {
                let kept = ab.coef.get(k).copied().unwrap_or(0.0);
                assert!(kept == 0.0 || (kept - d).abs() <= 1e-15 * (1.0 + d.abs()), "term {k}: {kept} against {d}");
            }
            for p in sample_points(&c, 300, 17 + round) {
                let x: Vec<Interval> = p.iter().map(|&t| Interval::point(t)).collect();
                let truth = a.eval_poly(&c.space, &p) * b.eval_poly(&c.space, &p);
                let enclosure = ab.eval_interval(&c.space, &x).inflate(1e-12);
                assert!(enclosure.contains(truth), "{enclosure} misses {truth}");
            }
        }
    }

    #[test]
    fn product_encloses_pointwise_product() {
        let c = ctx(3, 4, 1);
        let x = TaylorModel::affine(&c, 0.3, 1, 0.7);
        let y = TaylorModel::affine(&c, -1.1, 2, 0.2).add(&TaylorModel::var(&c, 0));
        let xy = x.mul(&y, &c);
        let cube = xy.mul(&xy, &c).mul(&x, &c); // degree 5 > order 4: truncation
        for p in sample_points(&c, 2000, 7) {
            let xv = 0.3 + 0.7 * p[1];
            let yv = -1.1 + 0.2 * p[2] + p[0];
            let truth = xv * yv * xv * yv * xv;
            let enclosure = cube.eval_interval(&c.space, &p.iter().map(|&t| Interval::point(t)).collect::<Vec<_>>());
            assert!(enclosure.contains(truth), "{enclosure} misses {truth}");
            assert!(cube.bound(&c.space).contains(truth));
        }
    }

    #[test]
    fn poly_bound_holds_at_sampled_points_and_keeps_infinities_apart() {
        let c = ctx(3, 4, 1);
        let mut state = 11u64;
        let mut noise = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64) - 0.5
        };
        for scale in [1e-300, 1e-8, 1.0, 1e200] {
            let p = TaylorModel { coef: (0..c.space.len()).map(|_| scale * noise()).collect(), rem: Interval::ZERO };
            let b = p.poly_bound(&c.space);
            for x in sample_points(&c, 2000, 3) {
                let value = p.eval_interval(&c.space, &x.iter().map(|&t| Interval::point(t)).collect::<Vec<_>>());
                assert!(b.lo() <= value.lo() && value.hi() <= b.hi(), "scale {scale}: {b} misses {value}");
            }
            // As tight as the term-by-term sum.
            let (mut lo, mut hi) = (p.coef[0], p.coef[0]);
            p.coef.iter().enumerate().skip(1).for_each(|(i, &a)| add_term_range(&mut lo, &mut hi, a, c.space.nonneg[i]));
            assert!(b.width() <= (hi - lo) * (1.0 + 1e-12), "scale {scale}: {b} against [{lo}, {hi}]");
        }
        // x0 is in [0, 1]: +inf on it leaves the lower end alone; NaN makes both unbounded.
        let mut p = TaylorModel::affine(&c, 1.0, 1, 0.5);
        p.coef.resize(2, 0.0);
        p.coef[1] = f64::INFINITY;
        let b = p.poly_bound(&c.space);
        assert!(b.lo() == 1.0f64.next_down() || b.lo() == 1.0, "{b}");
        assert_eq!(b.hi(), f64::INFINITY);
        p.coef[1] = f64::NAN;
        let b = p.poly_bound(&c.space);
        assert!(b.lo() == f64::NEG_INFINITY && b.hi() == f64::INFINITY, "{b}");
    }

    #[test]
    fn integration_and_substitution() {
        let c = ctx(2, 5, 1);
        // f = 1 + x1 * s; integral from 0 to s: s + x1 s^2 / 2; at s = 1: 1 + x1 / 2.
        let f = TaylorModel::constant(1.0).add(&TaylorModel::var(&c, 1).mul(&TaylorModel::var(&c, 0), &c));
        let g = f.integrate(0, &c);
        let end = g.substitute(0, Interval::ONE, &c);
        for p in sample_points(&c, 500, 3) {
            let at = |t: &TaylorModel| t.eval_interval(&c.space, &[Interval::point(p[0]), Interval::point(p[1])]);
            assert!(at(&g).contains(p[0] + p[1] * p[0] * p[0] / 2.0));
            assert!(at(&end).contains(1.0 + p[1] / 2.0));
        }
    }

    #[test]
    fn cutoff_and_truncation_move_to_remainder() {
        let c = Ctx::new(Space::get(2, 3, 0).unwrap(), 3, 1e-3);
        let mut t = TaylorModel::affine(&c, 1.0, 0, 1e-4);
        t.sweep(&c);
        assert_eq!(t.coef, vec![1.0]);
        assert!(t.rem.contains(1e-4) && t.rem.contains(-1e-4));
    }

    #[test]
    fn adding_an_interval_in_place_holds_every_shifted_value() {
        // p + r + c for r in the remainder and c in the interval, at sampled points: the
        // constant 0.1 + 0.2 is inexact, so the constant term's rounding must be in the remainder.
        let c = ctx(2, 3, 0);
        let mut t = TaylorModel::affine(&c, 0.1, 0, 0.3).mul(&TaylorModel::affine(&c, -0.7, 1, 0.2), &c);
        t.rem = Interval::new(-1e-9, 2e-9).unwrap();
        let before = t.clone();
        let iv = Interval::new(0.2, 0.2 + 1e-12).unwrap();
        t.add_interval_in_place(iv);
        let mut empty = TaylorModel::zero();
        empty.add_interval_in_place(iv);
        assert!(empty.bound(&c.space).contains_interval(&iv));
        for pt in sample_points(&c, 500, 3) {
            let x: Vec<Interval> = pt.iter().map(|&v| Interval::point(v)).collect();
            let old = before.eval_interval(&c.space, &x) + iv;
            let new = t.eval_interval(&c.space, &x);
            for f in [-1.0, -0.5, 0.0, 0.5, 1.0] {
                // A value of the old model plus the constant, well inside `old`'s own roundings.
                let truth = old.mid() + f * 0.999 * old.radius();
                assert!(new.contains(truth), "{new} misses {truth}");
            }
        }
    }

    #[test]
    fn composition_encloses() {
        let c = ctx(3, 5, 1);
        // p(x1, x2) = x1^2 - x1 x2 + 0.5; substitute x1 = 0.5 x2 + 0.2 s, x2 = 0.9 x1
        let x1 = TaylorModel::var(&c, 1);
        let x2 = TaylorModel::var(&c, 2);
        let p = x1.square(&c).sub(&x1.mul(&x2, &c)).add_constant(0.5);
        let a1 = x2.scale(0.5).add(&TaylorModel::var(&c, 0).scale(0.2));
        let a2 = x1.scale(0.9);
        let args = vec![TaylorModel::var(&c, 0), a1, a2];
        let q = p.compose(&args, &c);
        for pt in sample_points(&c, 1000, 11) {
            let (u, v) = (0.5 * pt[2] + 0.2 * pt[0], 0.9 * pt[1]);
            let truth = u * u - u * v + 0.5;
            let e = q.eval_interval(&c.space, &pt.iter().map(|&t| Interval::point(t)).collect::<Vec<_>>());
            assert!(e.contains(truth));
        }
    }
}
