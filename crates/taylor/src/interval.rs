//! Closed intervals of f64 with outward rounding.
//!
//! Every arithmetic result is computed in round-to-nearest and then moved one ulp outward
//! (`next_down`/`next_up`), which encloses the exact result because a correctly rounded
//! operation is off by at most half an ulp. Transcendental functions come from the platform
//! libm, whose documented error is below [`LIBM_ULPS`] ulps (glibc: at most 2 ulps for the
//! functions used here), so their results are widened by that many ulps plus one.
//!
//! The empty set is a first-class value ([`Interval::EMPTY`]); NaN never appears inside an
//! interval: constructors reject it and operations that would produce it return the empty
//! set or the whole line, as documented on each operation.
use crate::error::{Result, TaylorError};
use std::fmt;
use std::ops::{Add, Mul, Neg, Sub};

/// Ulps by which libm results are widened (documented glibc bound + 1 of safety).
pub const LIBM_ULPS: u32 = 3;

#[derive(Clone, Copy, PartialEq)]
pub struct Interval {
    lo: f64,
    hi: f64,
}

fn down(x: f64) -> f64 {
    if x.is_nan() {
        f64::NEG_INFINITY
    } else {
        x.next_down()
    }
}

fn up(x: f64) -> f64 {
    if x.is_nan() {
        f64::INFINITY
    } else {
        x.next_up()
    }
}

fn down_n(mut x: f64, n: u32) -> f64 {
    for _ in 0..n {
        x = down(x);
    }
    x
}

fn up_n(mut x: f64, n: u32) -> f64 {
    for _ in 0..n {
        x = up(x);
    }
    x
}

/// Rounded-up sum and product helpers for error bounds (non-negative quantities).
pub fn add_up(a: f64, b: f64) -> f64 {
    up(a + b)
}
pub fn mul_up(a: f64, b: f64) -> f64 {
    up(a * b)
}

impl Interval {
    pub const EMPTY: Interval = Interval { lo: f64::INFINITY, hi: f64::NEG_INFINITY };
    pub const ENTIRE: Interval = Interval { lo: f64::NEG_INFINITY, hi: f64::INFINITY };
    pub const ZERO: Interval = Interval { lo: 0.0, hi: 0.0 };
    pub const ONE: Interval = Interval { lo: 1.0, hi: 1.0 };
    pub const UNIT: Interval = Interval { lo: 0.0, hi: 1.0 };
    pub const SYMMETRIC: Interval = Interval { lo: -1.0, hi: 1.0 };

    /// A checked constructor: NaN bounds and `lo > hi` are user errors.
    pub fn new(lo: f64, hi: f64) -> Result<Interval> {
        if lo.is_nan() || hi.is_nan() {
            return Err(TaylorError::input(format!("interval bound is NaN: [{lo}, {hi}]")));
        }
        if lo > hi {
            return Err(TaylorError::input(format!("empty interval: lower bound {lo} is above upper bound {hi}; swap them")));
        }
        if lo == f64::INFINITY || hi == f64::NEG_INFINITY {
            return Err(TaylorError::input(format!("interval [{lo}, {hi}] holds no real number")));
        }
        Ok(Interval { lo, hi })
    }

    /// For internal use where `lo <= hi` holds by construction (NaN maps to the entire line).
    pub(crate) fn raw(lo: f64, hi: f64) -> Interval {
        Interval { lo: if lo.is_nan() { f64::NEG_INFINITY } else { lo }, hi: if hi.is_nan() { f64::INFINITY } else { hi } }
    }

    pub fn point(x: f64) -> Interval {
        if x.is_nan() {
            Interval::ENTIRE
        } else {
            Interval { lo: x, hi: x }
        }
    }

    /// [-r, r] for a magnitude bound r >= 0.
    pub fn symmetric(r: f64) -> Interval {
        Interval::raw(-r, r)
    }

    pub fn lo(&self) -> f64 {
        self.lo
    }
    pub fn hi(&self) -> f64 {
        self.hi
    }
    pub fn is_empty(&self) -> bool {
        self.lo > self.hi
    }
    pub fn is_bounded(&self) -> bool {
        self.lo.is_finite() && self.hi.is_finite()
    }
    /// Midpoint rounded to nearest; any point inside works for centred forms.
    pub fn mid(&self) -> f64 {
        if self.lo == f64::NEG_INFINITY || self.hi == f64::INFINITY {
            if self.lo.is_finite() {
                return self.lo;
            }
            if self.hi.is_finite() {
                return self.hi;
            }
            return 0.0;
        }
        let m = 0.5 * self.lo + 0.5 * self.hi;
        m.clamp(self.lo, self.hi)
    }
    /// Width rounded up.
    pub fn width(&self) -> f64 {
        if self.is_empty() {
            0.0
        } else {
            up(self.hi - self.lo)
        }
    }
    /// Largest distance from the midpoint, rounded up.
    pub fn radius(&self) -> f64 {
        let m = self.mid();
        up((self.hi - m).max(m - self.lo))
    }
    /// max |x| over the interval.
    pub fn mag(&self) -> f64 {
        self.lo.abs().max(self.hi.abs())
    }
    /// min |x| over the interval.
    pub fn mig(&self) -> f64 {
        if self.contains(0.0) {
            0.0
        } else {
            self.lo.abs().min(self.hi.abs())
        }
    }
    pub fn contains(&self, x: f64) -> bool {
        self.lo <= x && x <= self.hi
    }
    pub fn contains_interval(&self, other: &Interval) -> bool {
        other.is_empty() || (self.lo <= other.lo && other.hi <= self.hi)
    }
    pub fn hull(&self, other: &Interval) -> Interval {
        if self.is_empty() {
            return *other;
        }
        if other.is_empty() {
            return *self;
        }
        Interval { lo: self.lo.min(other.lo), hi: self.hi.max(other.hi) }
    }
    pub fn intersect(&self, other: &Interval) -> Interval {
        let lo = self.lo.max(other.lo);
        let hi = self.hi.min(other.hi);
        if lo > hi {
            Interval::EMPTY
        } else {
            Interval { lo, hi }
        }
    }
    /// The part at or above 0: what is left of an enclosure of a value known to be nonnegative.
    pub fn nonnegative_part(&self) -> Interval {
        self.intersect(&Interval { lo: 0.0, hi: f64::INFINITY })
    }
    /// Widen both ends by a non-negative amount (rounded outward).
    pub fn inflate(&self, r: f64) -> Interval {
        Interval::raw(down(self.lo - r), up(self.hi + r))
    }
    fn outward(lo: f64, hi: f64) -> Interval {
        Interval::raw(down(lo), up(hi))
    }
    fn libm(lo: f64, hi: f64) -> Interval {
        Interval::raw(down_n(lo, LIBM_ULPS), up_n(hi, LIBM_ULPS))
    }

    pub fn sqr(&self) -> Interval {
        if self.is_empty() {
            return Interval::EMPTY;
        }
        let (a, b) = (self.mig(), self.mag());
        Interval::raw(if a == 0.0 { 0.0 } else { down(a * a).max(0.0) }, up(b * b))
    }

    /// Integer power, tight for even powers across zero.
    pub fn powi(&self, n: i32) -> Result<Interval> {
        if self.is_empty() {
            return Ok(Interval::EMPTY);
        }
        if n < 0 {
            // Reciprocal first: x^n may underflow to an enclosure of 0 although 1/x^n is finite.
            return self.recip()?.powi(-n);
        }
        if n == 0 {
            return Ok(Interval::ONE);
        }
        // Repeated squaring of each endpoint as a point interval keeps rigour.
        let pow_point = |x: f64| -> Interval {
            let mut base = Interval::point(x);
            let mut acc = Interval::ONE;
            let mut e = n;
            while e > 0 {
                if e & 1 == 1 {
                    acc = acc * base;
                }
                base = base.sqr();
                e >>= 1;
            }
            acc
        };
        if n % 2 == 0 {
            let hi = pow_point(self.mag()).hi;
            let lo = if self.contains(0.0) { 0.0 } else { pow_point(self.mig()).lo };
            Ok(Interval::raw(lo.max(0.0), hi))
        } else {
            Ok(Interval::raw(pow_point(self.lo).lo, pow_point(self.hi).hi))
        }
    }

    /// 1/x. Zero inside the interval is a domain error: the result would not be an interval.
    pub fn recip(&self) -> Result<Interval> {
        if self.is_empty() {
            return Ok(Interval::EMPTY);
        }
        if self.contains(0.0) {
            return Err(TaylorError::Domain {
                function: "division",
                argument: self.to_string(),
                hint: "the divisor's range contains zero; split the set or bound it away from zero",
            });
        }
        Ok(Interval::outward(1.0 / self.hi, 1.0 / self.lo))
    }

    /// Division with the extended rule: a divisor interval containing zero gives the entire
    /// line (or the empty set for the divisor [0, 0]); use [`Interval::recip`] to be told.
    pub fn div_extended(&self, other: &Interval) -> Interval {
        if self.is_empty() || other.is_empty() || (other.lo == 0.0 && other.hi == 0.0) {
            return Interval::EMPTY;
        }
        match other.recip() {
            Ok(r) => *self * r,
            Err(_) => Interval::ENTIRE,
        }
    }

    pub fn sqrt(&self) -> Result<Interval> {
        if self.is_empty() {
            return Ok(Interval::EMPTY);
        }
        if self.lo < 0.0 {
            return Err(TaylorError::Domain {
                function: "sqrt",
                argument: self.to_string(),
                hint: "the argument's range reaches below zero",
            });
        }
        // IEEE sqrt is correctly rounded: one ulp outward suffices.
        Ok(Interval::raw(down(self.lo.sqrt()).max(0.0), up(self.hi.sqrt())))
    }

    pub fn exp(&self) -> Interval {
        if self.is_empty() {
            return Interval::EMPTY;
        }
        Interval::libm(self.lo.exp(), self.hi.exp()).intersect(&Interval::raw(0.0, f64::INFINITY))
    }

    pub fn ln(&self) -> Result<Interval> {
        if self.is_empty() {
            return Ok(Interval::EMPTY);
        }
        if self.lo <= 0.0 {
            return Err(TaylorError::Domain {
                function: "log",
                argument: self.to_string(),
                hint: "the argument's range reaches zero or below",
            });
        }
        Ok(Interval::libm(self.lo.ln(), self.hi.ln()))
    }

    pub fn atan(&self) -> Interval {
        if self.is_empty() {
            return Interval::EMPTY;
        }
        let bound = up(std::f64::consts::FRAC_PI_2);
        Interval::libm(self.lo.atan(), self.hi.atan()).intersect(&Interval::raw(-bound, bound))
    }

    pub fn tanh(&self) -> Interval {
        if self.is_empty() {
            return Interval::EMPTY;
        }
        Interval::libm(self.lo.tanh(), self.hi.tanh()).intersect(&Interval::SYMMETRIC)
    }

    /// 1 / (1 + exp(-x)), evaluated in interval arithmetic at each end (it is increasing).
    pub fn sigmoid(&self) -> Interval {
        if self.is_empty() {
            return Interval::EMPTY;
        }
        let at = |x: f64| -> Interval {
            let e = Interval::point(-x).exp();
            (Interval::ONE + e).recip().unwrap_or(Interval::UNIT)
        };
        Interval::raw(at(self.lo).lo, at(self.hi).hi).intersect(&Interval::UNIT)
    }

    pub fn sin(&self) -> Interval {
        self.periodic(0.0)
    }

    pub fn cos(&self) -> Interval {
        self.periodic(std::f64::consts::FRAC_PI_2)
    }

    /// sin(x + shift): the extrema at pi/2 + 2k pi (max) and -pi/2 + 2k pi (min) are included
    /// whenever they may lie in the (slightly widened) argument, so a rounding doubt widens.
    fn periodic(&self, shift: f64) -> Interval {
        use std::f64::consts::{FRAC_PI_2, PI};
        if self.is_empty() {
            return Interval::EMPTY;
        }
        let f = |x: f64| if shift == 0.0 { x.sin() } else { x.cos() };
        if !self.is_bounded() || self.width() >= 2.0 * PI || self.mag() > 1e12 {
            return Interval::SYMMETRIC;
        }
        let (a, b) = (self.lo + shift, self.hi + shift);
        let slack = 1e-9 * (1.0 + self.mag());
        let hits = |centre: f64| -> bool {
            // Is there k with centre + 2k pi in [a - slack, b + slack]?
            let k = ((a - slack - centre) / (2.0 * PI)).ceil();
            centre + 2.0 * PI * k <= b + slack
        };
        let (fa, fb) = (f(self.lo), f(self.hi));
        let mut out = Interval::libm(fa.min(fb), fa.max(fb));
        if hits(FRAC_PI_2) {
            out = Interval::raw(out.lo, 1.0);
        }
        if hits(-FRAC_PI_2) {
            out = Interval::raw(-1.0, out.hi);
        }
        out.intersect(&Interval::SYMMETRIC)
    }

    /// tan is increasing between poles; an argument that may contain a pole is a domain error.
    pub fn tan(&self) -> Result<Interval> {
        use std::f64::consts::{FRAC_PI_2, PI};
        if self.is_empty() {
            return Ok(Interval::EMPTY);
        }
        let slack = 1e-9 * (1.0 + self.mag());
        let k = ((self.lo - slack - FRAC_PI_2) / PI).ceil();
        if !self.is_bounded() || self.width() >= PI || FRAC_PI_2 + PI * k <= self.hi + slack {
            return Err(TaylorError::Domain {
                function: "tan",
                argument: self.to_string(),
                hint: "the argument's range may contain a pole (pi/2 + k pi)",
            });
        }
        Ok(Interval::libm(self.lo.tan(), self.hi.tan()))
    }

    /// x^y for real y, defined for x > 0 (and x >= 0 when y > 0) as exp(y ln x).
    pub fn powf(&self, y: f64) -> Result<Interval> {
        if self.is_empty() {
            return Ok(Interval::EMPTY);
        }
        if y == y.trunc() && y.abs() < 1e9 {
            return self.powi(y as i32);
        }
        if y > 0.0 && self.lo >= 0.0 {
            // x^y is increasing; each end separately (0^y = 0), subnormal ends included.
            let at = |x: f64| -> Result<Interval> {
                if x == 0.0 {
                    Ok(Interval::ZERO)
                } else {
                    Ok((Interval::point(x).ln()? * Interval::point(y)).exp())
                }
            };
            return Ok(Interval::raw(at(self.lo)?.lo.max(0.0), at(self.hi)?.hi));
        }
        if self.lo <= 0.0 {
            return Err(TaylorError::Domain {
                function: "pow",
                argument: self.to_string(),
                hint: "a non-integer power needs a positive base",
            });
        }
        Ok((self.ln()? * Interval::point(y)).exp())
    }

    pub fn min(&self, other: &Interval) -> Interval {
        if self.is_empty() || other.is_empty() {
            return Interval::EMPTY;
        }
        Interval::raw(self.lo.min(other.lo), self.hi.min(other.hi))
    }

    pub fn max(&self, other: &Interval) -> Interval {
        if self.is_empty() || other.is_empty() {
            return Interval::EMPTY;
        }
        Interval::raw(self.lo.max(other.lo), self.hi.max(other.hi))
    }

    pub fn abs(&self) -> Interval {
        if self.is_empty() {
            return Interval::EMPTY;
        }
        Interval::raw(self.mig(), self.mag())
    }
}

impl Add for Interval {
    type Output = Interval;
    fn add(self, o: Interval) -> Interval {
        if self.is_empty() || o.is_empty() {
            return Interval::EMPTY;
        }
        Interval::outward(self.lo + o.lo, self.hi + o.hi)
    }
}

impl Sub for Interval {
    type Output = Interval;
    fn sub(self, o: Interval) -> Interval {
        if self.is_empty() || o.is_empty() {
            return Interval::EMPTY;
        }
        Interval::outward(self.lo - o.hi, self.hi - o.lo)
    }
}

impl Neg for Interval {
    type Output = Interval;
    fn neg(self) -> Interval {
        if self.is_empty() {
            return self;
        }
        Interval { lo: -self.hi, hi: -self.lo }
    }
}

impl Mul for Interval {
    type Output = Interval;
    /// The signs of the bounds name the corners where the exact product's ends lie, so only
    /// those (two, or four when both straddle 0) are computed and each rounded one way: this
    /// product runs for every term of every Taylor-model operation's remainder.
    fn mul(self, o: Interval) -> Interval {
        if self.is_empty() || o.is_empty() {
            return Interval::EMPTY;
        }
        let (a1, a2, b1, b2) = (self.lo, self.hi, o.lo, o.hi);
        let (lo, hi) = if a1 >= 0.0 {
            if b1 >= 0.0 {
                (product_down(a1, b1), product_up(a2, b2))
            } else if b2 <= 0.0 {
                (product_down(a2, b1), product_up(a1, b2))
            } else {
                (product_down(a2, b1), product_up(a2, b2))
            }
        } else if a2 <= 0.0 {
            if b1 >= 0.0 {
                (product_down(a1, b2), product_up(a2, b1))
            } else if b2 <= 0.0 {
                (product_down(a2, b2), product_up(a1, b1))
            } else {
                (product_down(a1, b2), product_up(a1, b1))
            }
        } else if b1 >= 0.0 {
            (product_down(a1, b2), product_up(a2, b2))
        } else if b2 <= 0.0 {
            (product_down(a2, b1), product_up(a1, b1))
        } else {
            (product_down(a1, b2).min(product_down(a2, b1)), product_up(a1, b1).max(product_up(a2, b2)))
        };
        Interval::raw(lo, hi)
    }
}

/// A float at or below a * b, where 0 * inf is taken as 0 (the interval holds reals only, so
/// the product is 0). A product is exact (needs no widening) only when an operand is exactly
/// zero or the fused a*b - x is 0 with x far from underflow: this keeps products of small
/// integers and dyadic numbers tight; a nonzero product that underflowed to 0.0 is still moved
/// to the neighbouring subnormal.
fn product_down(a: f64, b: f64) -> f64 {
    match exact_product(a, b) {
        Ok(x) => x,
        Err(x) => down(x),
    }
}

/// A float at or above a * b (see [`product_down`]).
fn product_up(a: f64, b: f64) -> f64 {
    match exact_product(a, b) {
        Ok(x) => x,
        Err(x) => up(x),
    }
}

/// Ok(a * b) when the float product is exact, else Err(the rounded product).
fn exact_product(a: f64, b: f64) -> std::result::Result<f64, f64> {
    if a == 0.0 || b == 0.0 {
        return Ok(0.0);
    }
    let x = a * b;
    if x.is_finite() && x.abs() > 1e-290 && a.mul_add(b, -x) == 0.0 {
        Ok(x)
    } else {
        Err(x)
    }
}

impl fmt::Display for Interval {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_empty() {
            write!(f, "[empty]")
        } else {
            write!(f, "[{:e}, {:e}]", self.lo, self.hi)
        }
    }
}

impl fmt::Debug for Interval {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn iv(a: f64, b: f64) -> Interval {
        Interval::new(a, b).unwrap()
    }

    #[test]
    fn constructor_rejects_nan_and_reversed_bounds() {
        assert!(Interval::new(f64::NAN, 1.0).is_err());
        assert!(Interval::new(2.0, 1.0).is_err());
        assert!(Interval::new(f64::INFINITY, f64::INFINITY).is_err());
    }

    #[test]
    fn addition_is_outward_rounded() {
        let s = iv(0.1, 0.1) + iv(0.2, 0.2);
        assert!(s.lo() < 0.30000000000000004 && s.hi() >= 0.30000000000000004);
        assert!(s.contains(0.3));
    }

    #[test]
    fn product_signs_and_zero_anchoring() {
        assert_eq!((iv(-2.0, 3.0) * iv(-1.0, 4.0)).lo(), -8.0); // exact products stay exact
        assert!((iv(0.1, 0.1) * iv(0.3, 0.3)).width() > 0.0); // inexact ones are widened
        let z = iv(0.0, 2.0) * iv(0.0, 3.0);
        assert_eq!(z.lo(), 0.0);
        let e = Interval::EMPTY * iv(1.0, 2.0);
        assert!(e.is_empty());
    }

    #[test]
    fn products_of_every_sign_case_hold_the_exact_sampled_products() {
        // Bounds drawn from a fixed pseudo-random sequence over every sign combination (zeros
        // and infinities included); each exact product x y of sampled points must lie in the
        // result (checked exactly: fma rounds x y - bound once, which keeps its sign), and the
        // result must be no wider than the hull of the four corners moved one ulp outward.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let specials = [0.0, -0.0, 1.0, -1.0, 0.1, -0.3, 1e-300, -1e-300, 3e300, f64::INFINITY, f64::NEG_INFINITY];
        for case in 0..4000 {
            let mut draw = || if case % 3 == 0 { specials[(next() * specials.len() as f64) as usize] } else { (next() - 0.5) * 10.0 };
            let (p, q, r, t) = (draw(), draw(), draw(), draw());
            let (Ok(a), Ok(b)) = (Interval::new(p.min(q), p.max(q)), Interval::new(r.min(t), r.max(t))) else { continue };
            let c = a * b;
            let corners = [(a.lo, b.lo), (a.lo, b.hi), (a.hi, b.lo), (a.hi, b.hi)];
            let naive = corners.iter().map(|&(x, y)| if x == 0.0 || y == 0.0 { 0.0 } else { x * y });
            let (nlo, nhi) = naive.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| (l.min(x), h.max(x)));
            assert!(c.lo >= down(nlo) && c.hi <= up(nhi), "{a} * {b} = {c}, wider than the corners");
            for _ in 0..8 {
                let x = if a.is_bounded() { a.lo + next() * (a.hi - a.lo) } else { a.lo.max(-1e3).min(a.hi) };
                let y = if b.is_bounded() { b.lo + next() * (b.hi - b.lo) } else { b.lo.max(-1e3).min(b.hi) };
                for (x, y) in [(x, y), (a.lo, b.hi), (a.hi, b.lo)] {
                    if !(x.is_finite() && y.is_finite() && (x * y).is_finite()) {
                        continue;
                    }
                    assert!(x.mul_add(y, -c.lo) >= 0.0 && x.mul_add(y, -c.hi) <= 0.0, "{x} * {y} outside {a} * {b} = {c}");
                }
            }
        }
    }

    #[test]
    fn underflowing_products_stay_enclosed() {
        // 1e-200 * 1e-200 = 1e-400 underflows to 0.0 but is positive: the upper end must be > 0.
        let p = iv(1e-200, 1e-200) * iv(1e-200, 1e-200);
        assert!(p.lo() <= 0.0 && p.hi() > 0.0);
        let n = iv(-1e-200, -1e-200) * iv(1e-200, 1e-200);
        assert!(n.lo() < 0.0 && n.hi() >= 0.0);
        assert!(iv(1e-100, 1e-100).powi(5).unwrap().hi() > 0.0);
        // Negative powers of tiny numbers are huge, not a division by zero.
        assert_eq!(iv(1e-300, 1e-300).powi(-2).unwrap().hi(), f64::INFINITY);
        // Real powers of subnormals: sqrt(1e-310) = 1e-155.
        let r = iv(1e-310, 1.0).powf(0.5).unwrap();
        assert!(r.lo() <= 1e-155 && r.hi() >= 1.0);
        assert_eq!(iv(0.0, 0.0).powf(0.5).unwrap().hi(), 0.0);
    }

    #[test]
    fn division_by_zero_crossing() {
        assert!(iv(-1.0, 1.0).recip().is_err());
        assert_eq!(iv(1.0, 2.0).div_extended(&iv(-1.0, 1.0)), Interval::ENTIRE);
        assert!(iv(1.0, 2.0).div_extended(&Interval::ZERO).is_empty());
        let r = iv(2.0, 4.0).recip().unwrap();
        assert!(r.contains(0.25) && r.contains(0.5));
    }

    #[test]
    fn domains_raise() {
        assert!(iv(-1.0, 1.0).sqrt().is_err());
        assert!(iv(0.0, 1.0).ln().is_err());
        assert!(iv(1.0, 2.0).tan().is_err());
        assert!(iv(-1.0, 2.0).powf(0.5).is_err());
    }

    #[test]
    fn periodic_functions_find_extrema() {
        let s = iv(1.0, 2.0).sin();
        assert_eq!(s.hi(), 1.0);
        assert!(s.contains(1.0f64.sin()));
        let c = iv(3.0, 3.3).cos();
        assert_eq!(c.lo(), -1.0);
        let wide = iv(-10.0, 10.0).sin();
        assert_eq!(wide, Interval::SYMMETRIC);
    }

    #[test]
    fn powers() {
        let p = iv(-2.0, 1.0).powi(2).unwrap();
        assert_eq!(p.lo(), 0.0);
        assert!(p.hi() >= 4.0);
        let q = iv(-2.0, 1.0).powi(3).unwrap();
        assert!(q.lo() <= -8.0 && q.hi() >= 1.0);
        let r = iv(4.0, 9.0).powf(0.5).unwrap();
        assert!(r.contains(2.0) && r.contains(3.0));
    }

    #[test]
    fn sampled_enclosure_of_elementary_functions() {
        // Every function's interval image contains the float image of points inside.
        let boxes = [(-3.0, -1.0), (-0.5, 0.7), (0.1, 2.0), (1e-300, 1e-299), (100.0, 700.0)];
        for (a, b) in boxes {
            let x = iv(a, b);
            for k in 0..=100 {
                let t = a + (b - a) * (k as f64) / 100.0;
                assert!(x.exp().contains(t.exp()));
                assert!(x.atan().contains(t.atan()));
                assert!(x.tanh().contains(t.tanh()));
                assert!(x.sigmoid().contains(1.0 / (1.0 + (-t).exp())));
                assert!(x.sin().contains(t.sin()));
                assert!(x.cos().contains(t.cos()));
                if a > 0.0 {
                    assert!(x.ln().unwrap().contains(t.ln()));
                    assert!(x.sqrt().unwrap().contains(t.sqrt()));
                }
            }
        }
    }
}
