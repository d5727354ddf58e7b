//! Elementary functions of Taylor models with rigorous Lagrange remainders.
//!
//! For x = c + d (c the constant term, d the rest with range R), phi(x) is the Taylor
//! polynomial of phi at c evaluated on d by Horner in Taylor-model arithmetic, plus the
//! Lagrange term phi^(k+1)(xi) / (k+1)! d^(k+1) with xi in c + hull(R, 0). The Taylor
//! coefficients are computed in interval arithmetic at the point c; their midpoints go into
//! the polynomial and their radii, times the range of d^j, into the remainder.
//!
//! sigmoid, tanh and tan solve y' = Q(y) for a polynomial Q, so their n-th derivative is a
//! polynomial P_n(y) with P_{n+1} = P_n' Q; that gives both the coefficients and the
//! remainder. If the model is useless against the interval image of the argument's range (very
//! wide arguments), the interval image is returned as a constant model.
use crate::error::Result;
use crate::interval::Interval;
use crate::space::MAX_ORDER;
use crate::tm::{Ctx, TaylorModel};
use std::sync::OnceLock;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Func {
    Exp,
    Log,
    Sqrt,
    Sin,
    Cos,
    Tan,
    Atan,
    Tanh,
    Sigmoid,
    Recip,
    Abs,
}

impl Func {
    pub fn name(&self) -> &'static str {
        match self {
            Func::Exp => "exp",
            Func::Log => "log",
            Func::Sqrt => "sqrt",
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tan => "tan",
            Func::Atan => "atan",
            Func::Tanh => "tanh",
            Func::Sigmoid => "sigmoid",
            Func::Recip => "recip",
            Func::Abs => "abs",
        }
    }

    pub fn from_name(name: &str) -> Option<Func> {
        Some(match name {
            "exp" => Func::Exp,
            "log" | "ln" => Func::Log,
            "sqrt" => Func::Sqrt,
            "sin" => Func::Sin,
            "cos" => Func::Cos,
            "tan" => Func::Tan,
            "atan" | "arctan" => Func::Atan,
            "tanh" => Func::Tanh,
            "sigmoid" => Func::Sigmoid,
            "abs" => Func::Abs,
            _ => return None,
        })
    }

    pub fn eval_f64(&self, x: f64) -> f64 {
        match self {
            Func::Exp => x.exp(),
            Func::Log => x.ln(),
            Func::Sqrt => x.sqrt(),
            Func::Sin => x.sin(),
            Func::Cos => x.cos(),
            Func::Tan => x.tan(),
            Func::Atan => x.atan(),
            Func::Tanh => x.tanh(),
            Func::Sigmoid => 1.0 / (1.0 + (-x).exp()),
            Func::Recip => 1.0 / x,
            Func::Abs => x.abs(),
        }
    }

    pub fn eval_interval(&self, x: Interval) -> Result<Interval> {
        Ok(match self {
            Func::Exp => x.exp(),
            Func::Log => x.ln()?,
            Func::Sqrt => x.sqrt()?,
            Func::Sin => x.sin(),
            Func::Cos => x.cos(),
            Func::Tan => x.tan()?,
            Func::Atan => x.atan(),
            Func::Tanh => x.tanh(),
            Func::Sigmoid => x.sigmoid(),
            Func::Recip => x.recip()?,
            Func::Abs => x.abs(),
        })
    }

    /// phi(x) as a Taylor model.
    pub fn eval_tm(&self, x: &TaylorModel, ctx: &Ctx) -> Result<TaylorModel> {
        let space = &ctx.space;
        let range = x.bound(space);
        let image = self.eval_interval(range)?; // also checks the domain on the whole range
        let c = x.constant_term();
        let mut d = x.clone();
        if let Some(first) = d.coef.first_mut() {
            *first = 0.0;
        }
        let d_poly = d.poly_bound(space);
        let dev = d_poly + d.rem;
        if *self == Func::Abs || !range.is_bounded() {
            // |x| is not smooth at 0; away from 0 it is +-x.
            return Ok(if *self == Func::Abs && range.lo() >= 0.0 {
                x.clone()
            } else if *self == Func::Abs && range.hi() <= 0.0 {
                x.neg()
            } else {
                TaylorModel::from_interval(image)
            });
        }
        let k = ctx.order;
        let around = Interval::point(c);
        let xi = around + dev.hull(&Interval::ZERO);
        let coefficients = self.taylor_coefficients(around, k)?;
        let lagrange = self.lagrange(xi, k)? * dev.hull(&Interval::ZERO).powi(k as i32 + 1)?;
        // Horner: (((a_k d + a_{k-1}) d + ...) d + a_0.
        let mut acc = TaylorModel::from_interval(coefficients[k]);
        for j in (0..k).rev() {
            acc = acc.mul_bounded(&d, Some(d_poly), ctx);
            acc.add_interval_in_place(coefficients[j]);
        }
        acc.rem = acc.rem + lagrange;
        Ok(prefer_image(acc, image, space))
    }

    /// Enclosures of phi^(j)(c) / j! for j = 0..=k at the point interval c.
    fn taylor_coefficients(&self, c: Interval, k: usize) -> Result<Vec<Interval>> {
        let mut a = Vec::with_capacity(k + 1);
        match self {
            Func::Exp => {
                let e = c.exp();
                a.extend(inverse_factorials()[..=k].iter().map(|&f| e * f));
            }
            Func::Log => {
                a.push(c.ln()?);
                let r = c.recip()?;
                let mut p = Interval::ONE;
                for j in 1..=k {
                    p = p * r;
                    let s = if j % 2 == 1 { 1.0 } else { -1.0 };
                    a.push(p * Interval::point(s) * Interval::point(j as f64).recip()?);
                }
            }
            Func::Recip => {
                let r = c.recip()?;
                let mut p = r;
                for j in 0..=k {
                    a.push(if j % 2 == 0 { p } else { -p });
                    p = p * r;
                }
            }
            Func::Sqrt => return power_coefficients(c, 0.5, k),
            Func::Sin | Func::Cos => {
                let (s, co) = (c.sin(), c.cos());
                let cycle = if *self == Func::Sin { [s, co, -s, -co] } else { [co, -s, -co, s] };
                a.extend(inverse_factorials()[..=k].iter().enumerate().map(|(j, &f)| cycle[j % 4] * f));
            }
            Func::Atan => {
                // 1 / (1 + (c + t)^2) = sum s_m t^m with (1 + c^2) s_m = -(2 c s_{m-1} + s_{m-2}).
                let q = (Interval::ONE + c.sqr()).recip()?;
                let two_c = Interval::point(2.0) * c;
                let mut s: Vec<Interval> = Vec::with_capacity(k);
                for m in 0..k {
                    let v = match m {
                        0 => q,
                        1 => -(two_c * s[0]) * q,
                        _ => -(two_c * s[m - 1] + s[m - 2]) * q,
                    };
                    s.push(v);
                }
                a.push(c.atan());
                for j in 1..=k {
                    a.push(s[j - 1] * Interval::point(j as f64).recip()?);
                }
            }
            Func::Tan | Func::Tanh | Func::Sigmoid => {
                let y = self.eval_interval(c)?;
                let p = self.derivative_polynomials();
                a.extend(inverse_factorials()[..=k].iter().enumerate().map(|(j, &f)| horner(&p[j], y) * f));
            }
            Func::Abs => unreachable!("abs is handled by cases"),
        }
        Ok(a)
    }

    /// An enclosure of phi^(k+1)(xi) / (k+1)! over xi in `x`.
    fn lagrange(&self, x: Interval, k: usize) -> Result<Interval> {
        let n = k + 1;
        let inv_fact = inverse_factorials()[n];
        Ok(match self {
            Func::Exp => x.exp() * inv_fact,
            // log^(n)(x) / n! = (-1)^(n+1) / (n x^n)
            Func::Log => {
                let s = if n % 2 == 1 { 1.0 } else { -1.0 };
                // (1/x)^n rather than 1/x^n: x^n may underflow to an enclosure of 0.
                Interval::point(s) * x.recip()?.powi(n as i32)? * Interval::point(n as f64).recip()?
            }
            // (1/x)^(n) / n! = (-1)^n / x^(n+1)
            Func::Recip => {
                let s = if n.is_multiple_of(2) { 1.0 } else { -1.0 };
                Interval::point(s) * x.recip()?.powi(n as i32 + 1)?
            }
            Func::Sqrt => power_coefficient(0.5, n)? * x.powf(0.5 - n as f64)?,
            Func::Sin | Func::Cos => {
                let (s, c) = (x.sin(), x.cos());
                let cycle = if *self == Func::Sin { [s, c, -s, -c] } else { [c, -s, -c, s] };
                cycle[n % 4] * inv_fact
            }
            // |atan^(n)(x)| <= (n-1)! / (1 + x^2)^(n/2)
            Func::Atan => {
                let base = (Interval::ONE + Interval::point(x.mig()).sqr()).sqrt()?;
                let m = (Interval::point(n as f64) * base.powi(n as i32)?).recip()?;
                Interval::symmetric(m.hi())
            }
            Func::Tan | Func::Tanh | Func::Sigmoid => {
                let y = self.eval_interval(x)?;
                horner(&self.derivative_polynomials()[n], y) * inv_fact
            }
            Func::Abs => unreachable!("abs is handled by cases"),
        })
    }

    /// P_0 = y, ..., P_(MAX_ORDER + 1) for tan, tanh or sigmoid (see `next_derivative`):
    /// constants of the function, built once instead of at every evaluation of a Taylor model.
    fn derivative_polynomials(&self) -> &'static [Vec<Interval>] {
        static TABLES: [OnceLock<Vec<Vec<Interval>>>; 3] = [const { OnceLock::new() }; 3];
        let slot = match self {
            Func::Tan => 0,
            Func::Tanh => 1,
            _ => 2,
        };
        TABLES[slot].get_or_init(|| {
            let mut p = vec![vec![Interval::ZERO, Interval::ONE]];
            for n in 0..=MAX_ORDER {
                p.push(self.next_derivative(&p[n]));
            }
            p
        })
    }

    /// P_{n+1} = P_n' Q for y' = Q(y): Q = 1 + y^2 (tan), 1 - y^2 (tanh), y - y^2 (sigmoid).
    /// The coefficients are integers, kept as intervals so that they stay rigorous once they
    /// outgrow 2^53 at high orders.
    fn next_derivative(&self, p: &[Interval]) -> Vec<Interval> {
        let q: [f64; 3] = match self {
            Func::Tan => [1.0, 0.0, 1.0],
            Func::Tanh => [1.0, 0.0, -1.0],
            _ => [0.0, 1.0, -1.0],
        };
        let dp: Vec<Interval> = (1..p.len()).map(|i| p[i] * Interval::point(i as f64)).collect();
        let mut out = vec![Interval::ZERO; dp.len() + 2];
        for (i, &a) in dp.iter().enumerate() {
            for (j, &b) in q.iter().enumerate() {
                if b != 0.0 {
                    out[i + j] = out[i + j] + a * Interval::point(b);
                }
            }
        }
        out
    }
}

/// Enclosures of 1 / j! for j = 0..=MAX_ORDER + 1, each the last times [1 / j] (as the
/// coefficients and Lagrange terms were built at every evaluation before): built once.
fn inverse_factorials() -> &'static [Interval] {
    static TABLE: OnceLock<Vec<Interval>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut f = vec![Interval::ONE];
        for j in 1..=MAX_ORDER + 1 {
            f.push(f[j - 1] * Interval::point(j as f64).recip().expect("j >= 1"));
        }
        f
    })
}

/// Interval Horner evaluation of a polynomial with interval coefficients.
fn horner(p: &[Interval], y: Interval) -> Interval {
    p.iter().rev().fold(Interval::ZERO, |acc, &c| acc * y + c)
}

/// binom(r, j) as an interval.
fn power_coefficient(r: f64, j: usize) -> Result<Interval> {
    let mut b = Interval::ONE;
    for i in 0..j {
        b = b * (Interval::point(r) - Interval::point(i as f64)) * Interval::point((i + 1) as f64).recip()?;
    }
    Ok(b)
}

fn power_coefficients(c: Interval, r: f64, k: usize) -> Result<Vec<Interval>> {
    (0..=k).map(|j| Ok(power_coefficient(r, j)? * c.powf(r - j as f64)?)).collect()
}

/// x^r for real r: Taylor expansion of the power function (domain x > 0 unless r is integral).
pub fn powf_tm(x: &TaylorModel, r: f64, ctx: &Ctx) -> Result<TaylorModel> {
    if r == r.trunc() && (0.0..1e6).contains(&r) {
        return Ok(x.powi(r as u32, ctx));
    }
    if r == r.trunc() && r < 0.0 && r > -1e6 {
        return Func::Recip.eval_tm(&x.powi((-r) as u32, ctx), ctx);
    }
    let space = &ctx.space;
    let range = x.bound(space);
    let image = range.powf(r)?;
    let c = x.constant_term();
    let mut d = x.clone();
    if let Some(first) = d.coef.first_mut() {
        *first = 0.0;
    }
    let dev = d.bound(space).hull(&Interval::ZERO);
    let k = ctx.order;
    let a = power_coefficients(Interval::point(c), r, k)?;
    let lagrange = power_coefficient(r, k + 1)? * (Interval::point(c) + dev).powf(r - (k + 1) as f64)? * dev.powi(k as i32 + 1)?;
    let mut acc = TaylorModel::from_interval(a[k]);
    for j in (0..k).rev() {
        acc = acc.mul(&d, ctx);
        acc.add_interval_in_place(a[j]);
    }
    acc.rem = acc.rem + lagrange;
    Ok(prefer_image(acc, image, space))
}

/// The Taylor model, unless it is useless against the plain interval image of the argument's
/// range: its remainder alone wider than the image, or its whole range more than twice as wide
/// (wide arguments, where a Taylor expansion at one point cannot follow the function).
fn prefer_image(model: TaylorModel, image: Interval, space: &crate::space::Space) -> TaylorModel {
    if !model.rem.is_bounded() || model.rem.width() > image.width() || model.bound(space).width() > 2.0 * image.width() {
        TaylorModel::from_interval(image)
    } else {
        model
    }
}

/// a / b as a * (1 / b).
pub fn div_tm(a: &TaylorModel, b: &TaylorModel, ctx: &Ctx) -> Result<TaylorModel> {
    Ok(a.mul(&Func::Recip.eval_tm(b, ctx)?, ctx))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::Space;

    const ALL: [Func; 10] =
        [Func::Exp, Func::Log, Func::Sqrt, Func::Sin, Func::Cos, Func::Tan, Func::Atan, Func::Tanh, Func::Sigmoid, Func::Recip];

    #[test]
    fn every_function_encloses_sampled_values() {
        let ctx = Ctx::new(Space::get(2, 6, 0).unwrap(), 6, 1e-15);
        for f in ALL {
            for (c, r) in [(0.7, 0.2), (1.3, 0.05), (0.4, 0.3), (2.0, 0.5)] {
                // x = c + r (0.8 x0 + 0.2 x0 x1)
                let x0 = TaylorModel::var(&ctx, 0);
                let x1 = TaylorModel::var(&ctx, 1);
                let x = x0.scale(0.8 * r).add(&x0.mul(&x1, &ctx).scale(0.2 * r)).add_constant(c);
                if f == Func::Tan && c + r > std::f64::consts::FRAC_PI_2 {
                    assert!(f.eval_tm(&x, &ctx).is_err(), "tan across its pole must be refused");
                    continue;
                }
                let y = f.eval_tm(&x, &ctx).unwrap();
                for i in 0..=40 {
                    for j in 0..=10 {
                        let (p, q) = (-1.0 + i as f64 / 20.0, -1.0 + j as f64 / 5.0);
                        let xv = c + r * (0.8 * p + 0.2 * p * q);
                        let truth = f.eval_f64(xv);
                        let e = y.eval_interval(&ctx.space, &[Interval::point(p), Interval::point(q)]);
                        assert!(e.contains(truth), "{} at {xv}: {e} misses {truth}", f.name());
                    }
                }
                // Tight for a narrow linear argument away from singularities: only Lagrange remains.
                if r > 0.2 || c < 0.7 {
                    continue;
                }
                let linear = f.eval_tm(&x0.scale(r).add_constant(c), &ctx).unwrap();
                assert!(linear.rem.width() < 1e-2 * linear.bound(&ctx.space).width(), "{} remainder {}", f.name(), linear.rem);
            }
        }
    }

    #[test]
    fn derivative_polynomials_are_integral() {
        for f in [Func::Tan, Func::Tanh, Func::Sigmoid] {
            let mut p = vec![Interval::ZERO, Interval::ONE];
            for _ in 0..12 {
                p = f.next_derivative(&p);
                assert!(p.iter().all(|c| c.width() <= 1e-12 * (1.0 + c.mag())));
            }
            // tanh'' = -2 tanh (1 - tanh^2) = -2 y + 2 y^3
            if f == Func::Tanh {
                let q = f.next_derivative(&f.next_derivative(&[Interval::ZERO, Interval::ONE]));
                for (c, want) in q.iter().zip([0.0, -2.0, 0.0, 2.0]) {
                    assert!(c.contains(want));
                }
            }
        }
    }

    #[test]
    fn domain_errors_are_reported() {
        let ctx = Ctx::new(Space::get(1, 4, 0).unwrap(), 4, 0.0);
        let x = TaylorModel::var(&ctx, 0); // range [-1, 1]
        assert!(Func::Log.eval_tm(&x, &ctx).is_err());
        assert!(Func::Sqrt.eval_tm(&x, &ctx).is_err());
        assert!(Func::Recip.eval_tm(&x, &ctx).is_err());
        assert!(powf_tm(&x, 0.5, &ctx).is_err());
    }

    #[test]
    fn real_power() {
        let ctx = Ctx::new(Space::get(1, 5, 0).unwrap(), 5, 0.0);
        let x = TaylorModel::var(&ctx, 0).scale(0.5).add_constant(2.0);
        let y = powf_tm(&x, 1.5, &ctx).unwrap();
        for i in 0..=100 {
            let p = -1.0 + i as f64 / 50.0;
            assert!(y.eval_interval(&ctx.space, &[Interval::point(p)]).contains((2.0 + 0.5 * p).powf(1.5)));
        }
    }
}
