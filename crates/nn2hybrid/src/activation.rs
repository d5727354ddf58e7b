//! Rigorous polynomial enclosures of sigmoid and tanh on an interval of pre-activations.
//!
//! Why not a Taylor expansion at the centre (as `taylor::Func::eval_tm` does): its Lagrange
//! remainder only shrinks when the range's radius is well inside the radius of convergence
//! (pi for sigmoid, pi/2 for tanh), but in image networks pre-activations routinely span 5-12
//! units. A Chebyshev interpolant stays accurate there (its error decays geometrically with the
//! degree at a rate set by the distance of the poles to the interval, not by the radius).
//!
//! The enclosure is q(s (y - c)) with q the Chebyshev interpolant at d + 3 nodes truncated to
//! degree d or lower (within a budget), computed in floats (any q is fine: the bound is what must
//! be rigorous). The bound max |phi(y) - q(s (y - c))| over [lo, hi] is computed per piece of a
//! subdivision: on a piece with centre c_p and half-width h_p, the difference is expanded to order
//! K around c_p (Taylor coefficients of phi by its ODE recurrence in interval arithmetic; q shifted
//! exactly), the expansion is converted to the Chebyshev basis of the piece and bounded by the sum
//! of |coefficients|, and the (Lagrange) tail is bounded by Cauchy's estimate on a disc where phi
//! is analytic: |phi^(n)(x)| / n! <= M / rho^n for every x of the piece. The discs are either fixed
//! ones inside the strip around the real axis, or, for pieces away from 0 where phi saturates,
//! discs whose M is small because phi is nearly constant there. Pieces and K are chosen to make
//! that tail negligible at the least cost, so narrow ranges need one piece.
//!
//! The rigorous arithmetic is midpoint-radius ("ball") arithmetic on floats: each radius absorbs
//! u |midpoint| and is computed in round-to-nearest, then scaled by a factor covering its few
//! roundings. It is several times cheaper than endpoint intervals, and this bound runs for
//! every neuron.
use std::sync::OnceLock;
use taylor::interval::{add_up, mul_up};
use taylor::tm::{etas, gamma, ETA, U};
use taylor::Interval;

/// [m - r, m + r] with r an upper bound of the distance to the true value.
#[derive(Clone, Copy, Debug)]
struct Ball {
    m: f64,
    r: f64,
}

/// Radii are sums of at most four rounded non-negative terms, computed in round-to-nearest: the
/// exact sum is at most (1 - u)^-4 times the float one, and one product by 1 + 8u (exact in
/// f64) covers that with room for its own rounding and that of adding the underflow terms
/// (eta per product that may underflow, added after). Cheaper than rounding every operation up.
const GROW: f64 = 1.0 + 8.0 * U;

impl Ball {
    const ZERO: Ball = Ball { m: 0.0, r: 0.0 };
    fn point(m: f64) -> Ball {
        Ball { m, r: 0.0 }
    }
    fn from_interval(x: Interval) -> Ball {
        Ball { m: x.mid(), r: x.radius() }
    }
    /// |fl(x) - x| <= u |fl(x)| for the rounded midpoint (u |m| itself may underflow).
    fn add(self, o: Ball) -> Ball {
        let m = self.m + o.m;
        Ball { m, r: (self.r + o.r + U * m.abs()) * GROW + 2.0 * ETA }
    }
    fn sub(self, o: Ball) -> Ball {
        self.add(Ball { m: -o.m, r: o.r })
    }
    /// Each of the five products may underflow: eta each (and a margin).
    fn mul(self, o: Ball) -> Ball {
        let m = self.m * o.m;
        let spread = self.m.abs() * o.r + self.r * o.m.abs() + self.r * o.r;
        Ball { m, r: (spread + U * m.abs()) * GROW + 6.0 * ETA }
    }
    /// self / k for an exact positive float k.
    fn div(self, k: f64) -> Ball {
        let m = self.m / k;
        Ball { m, r: (self.r / k + U * m.abs()) * GROW + 3.0 * ETA }
    }
}

/// The smooth activations (those that need a polynomial enclosure).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Smooth {
    Sigmoid,
    Tanh,
}

/// q(s (y - c)) with |phi(y) - q(s (y - c))| <= err for every y of the range; s |y - c| <= 1.
#[derive(Clone, Debug)]
pub struct PolyEnclosure {
    pub centre: f64,
    pub scale: f64,
    /// Power-basis coefficients of q in tau = s (y - c).
    pub coef: Vec<f64>,
    pub err: f64,
}

/// Highest expansion order of a piece (sizes the Chebyshev conversion table).
const K_MAX: usize = 40;
/// The truncated Taylor tail of a piece is made this much smaller than the estimated fit error
/// (so that the bound is within a few per cent of the truth), but need not go below TAIL_MIN.
const TAIL_FRACTION: f64 = 0.5;
const TAIL_MIN: f64 = 1e-15;
/// Values of a = rho - d (see `Smooth::saturated_m`) tried for the saturated discs.
const SATURATED: [f64; 2] = [-1.0, -3.0];
/// Piece counts tried (more pieces, lower expansion order).
const PIECES: [usize; 12] = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64];

impl Smooth {
    pub fn image(&self, x: Interval) -> Interval {
        if x.is_empty() {
            return Interval::EMPTY;
        }
        self.at(x.lo()).hull(&self.at(x.hi()))
    }

    /// An enclosure of phi(x): half the work of `Interval::sigmoid` on a point, which encloses
    /// the value at each end separately.
    fn at(&self, x: f64) -> Interval {
        match self {
            Smooth::Sigmoid => (Interval::ONE + Interval::point(-x).exp()).recip().unwrap_or(Interval::UNIT).intersect(&Interval::UNIT),
            Smooth::Tanh => Interval::point(x).tanh(),
        }
    }

    fn eval(&self, x: f64) -> f64 {
        match self {
            Smooth::Sigmoid => crate::network::Activation::Sigmoid.eval(x),
            Smooth::Tanh => x.tanh(),
        }
    }

    /// Cauchy discs (rho, M) with |phi^(n)(x)| / n! <= M / rho^n for all real x and n >= 1.
    /// Sigmoid: on |Im z| <= r < pi, |1 + e^-z| >= 1 if r <= pi/2, else >= sin r, so M = 1, 2, 4
    /// for r = pi/2, 5pi/6, pi - asin(1/4) (radii rounded down). Tanh: tanh^(n)(x) =
    /// 2^(n+1) sigmoid^(n)(2x), so the radii halve and M doubles.
    #[allow(clippy::approx_constant)] // radii rounded down on purpose: M holds on smaller discs
    fn discs(&self) -> [(f64, f64); 3] {
        const SIG: [(f64, f64); 3] = [(1.5707, 1.0), (2.6179, 2.0), (2.8888, 4.0)];
        match self {
            Smooth::Sigmoid => SIG,
            Smooth::Tanh => SIG.map(|(r, m)| (r * 0.5, 2.0 * m)),
        }
    }

    /// (ln rho, ln M) of the discs, for planning.
    fn log_discs(&self) -> &'static [(f64, f64); 3] {
        static LN: [OnceLock<[(f64, f64); 3]>; 2] = [const { OnceLock::new() }; 2];
        LN[*self as usize].get_or_init(|| self.discs().map(|(rho, m)| (rho.ln(), m.ln())))
    }

    /// Away from 0, phi is nearly constant and the fixed discs overestimate its derivatives by
    /// far. If every x of a piece has |x| >= d and rho < d, the disc of radius rho around x has
    /// Re z of one sign with |Re z| >= d - rho =: -a, and there (derivatives of phi - phi(+-inf)
    /// are phi's) |sigmoid(z) - 0 or 1| <= e^a / (1 - e^a) and |tanh(z) -+ 1| <= 2 e^(2a) /
    /// (1 - e^(2a)): no pole is near, so M stays small for any rho. An upper bound of M for a.
    fn saturated_m(&self, a: f64) -> f64 {
        let e = match self {
            Smooth::Sigmoid => Interval::point(a).exp(),
            Smooth::Tanh => Interval::point(2.0 * a).exp(),
        };
        let m = (e * (Interval::ONE - e).recip().unwrap_or(Interval::ENTIRE)).hi();
        if *self == Smooth::Tanh {
            mul_up(2.0, m)
        } else {
            m
        }
    }

    /// (M, ln M) of the saturated discs for each a in SATURATED, computed once.
    fn saturated(&self) -> &'static [(f64, f64); SATURATED.len()] {
        static M: [OnceLock<[(f64, f64); SATURATED.len()]>; 2] = [const { OnceLock::new() }; 2];
        M[*self as usize].get_or_init(|| SATURATED.map(|a| (self.saturated_m(a), self.saturated_m(a).ln())))
    }

    /// An upper bound of sup_x |phi^(n)(x)| / n! * h^n (n >= 1) over the piece c +- h from
    /// `disc` (for the Lagrange remainder of the expansion at c).
    fn tail(&self, disc: Disc, n: usize, c: f64, h: f64) -> f64 {
        let (rho, m) = match disc {
            Disc::Fixed(i) => self.discs()[i],
            Disc::Saturated(rho, k) => {
                let distance = (c.abs() - h).next_down();
                if distance.is_nan() || rho >= distance {
                    return f64::INFINITY;
                }
                // M grows with a: the planned a (for the whole range) holds for every piece.
                let a = (rho - distance).next_up();
                (rho, if a <= SATURATED[k] { self.saturated()[k].0 } else { self.saturated_m(a) })
            }
        };
        let ratio = (h / rho).next_up();
        (0..n).fold(m, |acc, _| mul_up(acc, ratio))
    }

    /// Enclosures of phi^(j)(c) / j! h^j for j = 0..=k (the expansion in w = (y - c) / h), from
    /// the ODE phi' = phi - phi^2 (sigmoid) or phi' = 1 - phi^2 (tanh): with z_n = y_n h^n,
    /// (n + 1) z_(n+1) = h ([sigmoid] z_n or [tanh] [n = 0] - sum_i z_i z_(n-i)).
    /// (On the stack: this runs for every piece of every neuron; k <= K_MAX.)
    fn taylor(&self, c: f64, h: f64, k: usize) -> [Ball; K_MAX + 1] {
        let h = Ball::point(h);
        let mut y = [Ball::ZERO; K_MAX + 1];
        y[0] = Ball::from_interval(self.at(c));
        for n in 0..k {
            let mut conv = Ball::ZERO;
            for i in 0..n.div_ceil(2) {
                conv = conv.add(y[i].mul(y[n - i]));
            }
            conv = conv.add(conv);
            if n % 2 == 0 {
                conv = conv.add(y[n / 2].mul(y[n / 2]));
            }
            let linear = match self {
                Smooth::Sigmoid => y[n],
                Smooth::Tanh if n == 0 => Ball::point(1.0),
                Smooth::Tanh => Ball::ZERO,
            };
            y[n + 1] = h.mul(linear.sub(conv)).div((n + 1) as f64);
        }
        y
    }
}

/// P2C[n] = Chebyshev coefficients of x^n: x^n = 2^(1-n) sum' C(n, i) T_(n-2i), exact dyadic
/// rationals in f64 for n <= K_MAX (binomials below 2^53).
fn power_to_chebyshev() -> &'static Vec<Vec<f64>> {
    static TABLE: OnceLock<Vec<Vec<f64>>> = OnceLock::new();
    TABLE.get_or_init(|| {
        (0..=K_MAX)
            .map(|n| {
                let mut row = vec![0.0; n + 1];
                let mut binom: u64 = 1;
                for i in 0..=n / 2 {
                    let half = if n - 2 * i == 0 { 0.5 } else { 1.0 };
                    row[n - 2 * i] = binom as f64 * half * 2f64.powi(1 - n as i32);
                    binom = binom * (n - i) as u64 / (i + 1) as u64;
                }
                row
            })
            .collect()
    })
}

/// sum |Chebyshev coefficients| of the polynomial with power coefficients `p` on [-1, 1]: a
/// bound of its magnitude there (|T_m| <= 1), far tighter than sum |p_j| for oscillating p.
/// The conversion runs on the midpoints in floats; each x^n has non-negative Chebyshev
/// coefficients summing to 1, so the radii add up to sum r_n, and the float error of all
/// conversion sums together is at most gamma_(K+1) sum |m_n|.
fn chebyshev_norm(p: &[Ball]) -> f64 {
    let table = power_to_chebyshev();
    let mut cheb = [0.0; K_MAX + 1];
    let (mut radii, mut mags) = (0.0, 0.0);
    for (n, b) in p.iter().enumerate() {
        for (m, &t) in table[n].iter().enumerate() {
            cheb[m] += t * b.m;
        }
        radii = add_up(radii, b.r);
        mags = add_up(mags, b.m.abs());
    }
    let sum = taylor::tm::abs_sum(&cheb[..p.len()]);
    add_up(add_up(sum, radii), add_up(mul_up(gamma(p.len() + 1), mags), etas(p.len() * p.len())))
}

/// C2P[m] = power-basis coefficients of T_m (integers, exact in f64 for m <= K_MAX).
fn chebyshev_to_power() -> &'static Vec<Vec<f64>> {
    static TABLE: OnceLock<Vec<Vec<f64>>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rows: Vec<Vec<f64>> = vec![vec![1.0], vec![0.0, 1.0]];
        for m in 2..=K_MAX {
            let mut next = vec![0.0; m + 1];
            for (j, &c) in rows[m - 1].iter().enumerate() {
                next[j + 1] += 2.0 * c;
            }
            for (j, &c) in rows[m - 2].iter().enumerate() {
                next[j] -= c;
            }
            rows.push(next);
        }
        rows
    })
}

/// The linear map from phi's values at the n = d + 3 Chebyshev nodes to the Chebyshev
/// coefficients of their interpolant (row m for T_m): fixed per degree, so it is built once.
struct Interpolation {
    nodes: Vec<f64>,
    rows: Vec<Vec<f64>>,
}

fn interpolation(d: usize) -> &'static Interpolation {
    static TABLES: [OnceLock<Interpolation>; taylor::space::MAX_ORDER + 1] = [const { OnceLock::new() }; taylor::space::MAX_ORDER + 1];
    TABLES[d].get_or_init(|| {
        let n = d + 3;
        let nodes: Vec<f64> = (0..n).map(|i| (std::f64::consts::PI * (i as f64 + 0.5) / n as f64).cos()).collect();
        // T_m at the nodes by T_(m+1) = 2x T_m - T_(m-1); coefficient m by discrete
        // orthogonality, c_m = w_m sum_i T_m(x_i) v_i.
        let (mut t_prev, mut t_cur) = (vec![0.0; n], vec![1.0; n]);
        let mut rows = Vec::with_capacity(n);
        for m in 0..n {
            let w = if m == 0 { 1.0 } else { 2.0 } / n as f64;
            rows.push(t_cur.iter().map(|t| w * t).collect());
            let factor = if m == 0 { 1.0 } else { 2.0 };
            for i in 0..n {
                let next = factor * nodes[i] * t_cur[i] - t_prev[i];
                t_prev[i] = t_cur[i];
                t_cur[i] = next;
            }
        }
        Interpolation { nodes, rows }
    })
}

/// Float Chebyshev approximation of phi(c + tau / s) in the power basis of tau: the interpolant
/// at d + 3 nodes truncated to the lowest degree (at most d, and at most K_MAX) whose dropped
/// Chebyshev coefficients sum to at most `budget` (|T_m| <= 1, so that sum bounds what the
/// truncation costs), and that sum over every dropped coefficient, an estimate of the fit error.
/// Truncating the Chebyshev series rather than the power series: for the same error the degree
/// is lower (power coefficients of a smooth function are larger by up to 2^(m-1)), and every
/// degree less halves the cost of composing the polynomial with a neuron's Taylor model.
/// Also returns a lower bound of phi's rise over the nodes (see `enclose`).
fn interpolate(f: Smooth, c: f64, s: f64, d: usize, budget: f64) -> (Vec<f64>, f64, f64) {
    let table = interpolation(d);
    let mut values = [0.0; taylor::space::MAX_ORDER + 3];
    table.nodes.iter().zip(values.iter_mut()).for_each(|(&x, v)| *v = f.eval(c + x / s));
    let nodes = &values[..table.nodes.len()];
    let (low, high) = nodes.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    // Each float value is within a few ulps of phi at its node (libm's tanh and exp, one
    // division): 16 ulps of the largest value cover both ends with room.
    let rise = (high - low) - 16.0 * f64::EPSILON * high.abs().max(low.abs());
    let mut cheb = [0.0; taylor::space::MAX_ORDER + 3];
    cheb.iter_mut().zip(&table.rows).for_each(|(c, row)| *c = row.iter().zip(&values).map(|(r, v)| r * v).sum());
    let cheb = &cheb[..table.rows.len()];
    let mut degree = d.min(K_MAX);
    let mut estimate: f64 = cheb[degree + 1..].iter().map(|c| c.abs()).sum();
    while degree > 0 && estimate + cheb[degree].abs() <= budget {
        estimate += cheb[degree].abs();
        degree -= 1;
    }
    let mut power = vec![0.0; degree + 1];
    for (c, row) in cheb.iter().zip(chebyshev_to_power()).take(degree + 1) {
        power.iter_mut().zip(row).for_each(|(p, t)| *p += c * t);
    }
    (power, estimate, rise)
}

/// Coefficients of q(tau_p + w) in w (repeated synthetic division; none for tau_p = 0, the
/// one-piece case of almost every neuron).
fn shift(q: &[f64], tau_p: Option<Ball>) -> [Ball; K_MAX + 1] {
    let mut b = [Ball::ZERO; K_MAX + 1];
    b.iter_mut().zip(q).for_each(|(b, &c)| *b = Ball::point(c));
    let Some(tau_p) = tau_p else { return b };
    let d = q.len();
    for i in 0..d {
        for j in (i..d.saturating_sub(1)).rev() {
            b[j] = b[j].add(tau_p.mul(b[j + 1]));
        }
    }
    b
}

/// max |phi(y) - q(s (y - c))| over y in [c_p - h_p, c_p + h_p], rounded up.
#[allow(clippy::too_many_arguments)]
fn piece_bound(f: Smooth, q: &[f64], c: f64, s: f64, c_p: f64, h_p: f64, k: usize, disc: Disc) -> f64 {
    // The expansion of phi - q: phi's coefficients minus q's shifted to c_p (q.len() <= k + 1,
    // as the plan takes k >= the degree).
    let mut diff = f.taylor(c_p, h_p, k);
    let si = Ball::point(s);
    // c_p - c is exactly 0 when the piece is the whole range. The ball of that difference would
    // carry a subnormal radius, and multiplies with subnormals are ~60x slower (`taylor::tm::etas`).
    let tau_p = (c_p != c).then(|| si.mul(Ball::point(c_p).sub(Ball::point(c))));
    let b = shift(q, tau_p);
    let shp = si.mul(Ball::point(h_p));
    let mut sh_pow = Ball::point(1.0);
    for (d, bj) in diff.iter_mut().zip(&b[..q.len()]) {
        *d = d.sub(bj.mul(sh_pow));
        sh_pow = sh_pow.mul(shp);
    }
    add_up(chebyshev_norm(&diff[..=k]), f.tail(disc, k + 1, c_p, h_p))
}

/// The disc a tail bound comes from: one of `Smooth::discs`, or a saturated disc of this radius.
#[derive(Clone, Copy, Debug)]
enum Disc {
    Fixed(usize),
    /// Radius and index into SATURATED.
    Saturated(f64, usize),
}

/// The (pieces, order, disc) of least cost N (K + 1)^2 whose Cauchy tail on pieces of half-width
/// h / N is below `tail`: M (h / (N rho))^(K + 1) <= tail; `distance` is the range's distance
/// from 0 (for the saturated discs). A float estimate: the bound itself is computed rigorously
/// afterwards.
fn plan(f: Smooth, h: f64, distance: f64, tail: f64, degree: usize) -> Option<(usize, usize, Disc)> {
    let (ln_h, ln_tail) = (h.ln(), tail.ln());
    let mut discs: Vec<(Disc, f64, f64)> =
        f.log_discs().iter().enumerate().map(|(i, &(ln_rho, ln_m))| (Disc::Fixed(i), ln_rho, ln_m)).collect();
    for (k, (&a, &(_, ln_m))) in SATURATED.iter().zip(f.saturated()).enumerate() {
        let rho = distance + a;
        if rho > 0.0 {
            discs.push((Disc::Saturated(rho, k), rho.ln(), ln_m));
        }
    }
    let mut best: Option<(usize, usize, Disc)> = None;
    let cost = |n: usize, k: usize| n * (k + 1) * (k + 1);
    for (n, ln_n) in PIECES.iter().zip(ln_pieces()) {
        let n = *n;
        if best.is_some_and(|(bn, bk, _)| cost(n, degree) >= cost(bn, bk)) {
            break;
        }
        let ln_hp = ln_h - ln_n;
        for &(disc, ln_rho, ln_m) in &discs {
            let ln_ratio = ln_hp - ln_rho;
            if ln_ratio >= 0.0 {
                continue;
            }
            let k = (((ln_tail - ln_m) / ln_ratio).ceil().max(1.0) as usize - 1).max(degree);
            if k <= K_MAX && best.is_none_or(|(bn, bk, _)| cost(n, k) < cost(bn, bk)) {
                best = Some((n, k, disc));
            }
        }
    }
    best
}

fn ln_pieces() -> &'static [f64; PIECES.len()] {
    static LN: OnceLock<[f64; PIECES.len()]> = OnceLock::new();
    LN.get_or_init(|| PIECES.map(|n| (n as f64).ln()))
}

/// The enclosure of phi on `range` by a polynomial of degree at most `degree`, lower where the
/// degrees dropped cost at most about `budget` (see `interpolate`; 0 drops only zero ones).
pub fn enclose(f: Smooth, range: Interval, degree: usize, budget: f64) -> PolyEnclosure {
    let constant = || {
        let image = f.image(range);
        PolyEnclosure { centre: range.mid(), scale: 0.0, coef: vec![image.mid()], err: image.radius() }
    };
    let c = range.mid();
    let h = (range.hi() - c).max(c - range.lo()).next_up();
    if h.is_nan() || h <= 0.0 || !h.is_finite() {
        return constant();
    }
    // s <= 1 / h, so that |s (y - c)| <= 1 on the range.
    let s = Interval::point(h).recip().expect("h > 0").lo();
    let (q, estimate, rise) = interpolate(f, c, s, degree, budget);
    let tail = (estimate * TAIL_FRACTION).max(TAIL_MIN);
    let distance = range.mig();
    let Some((pieces, k, disc)) = plan(f, h, distance, tail, q.len() - 1) else { return constant() };
    let (lo, hi) = (range.lo(), range.hi());
    let mut err = 0.0f64;
    for i in 0..pieces {
        let a = if i == 0 { lo } else { lo + (hi - lo) * (i as f64 / pieces as f64) };
        let b = if i + 1 == pieces { hi } else { lo + (hi - lo) * ((i + 1) as f64 / pieces as f64) };
        let c_p = 0.5 * a + 0.5 * b;
        let h_p = (b - c_p).max(c_p - a).next_up();
        err = err.max(piece_bound(f, &q, c, s, c_p, h_p, k, disc));
    }
    // The polynomial is kept unless its error reaches the radius of phi's image. phi increases,
    // so half the nodes' rise is below that radius: the image's two enclosures of phi are
    // computed only when the error comes near it (this runs for every neuron).
    if err.is_nan() || (!(err < 0.5 * rise) && err >= f.image(range).radius()) {
        return constant();
    }
    PolyEnclosure { centre: c, scale: s, coef: q, err }
}

/// phi(y) and the range of phi' over `y`, from one enclosure of phi at each end: phi is
/// increasing, and phi' (a function of phi) is unimodal with its peak at 0 (1/4 for sigmoid, 1
/// for tanh).
pub fn image_and_derivative(f: Smooth, y: Interval) -> (Interval, Interval) {
    let (at_lo, at_hi) = (f.at(y.lo()), f.at(y.hi()));
    let slope = |v: Interval| -> Interval {
        match f {
            Smooth::Sigmoid => v * (Interval::ONE - v),
            Smooth::Tanh => Interval::ONE - v.sqr(),
        }
        .intersect(&Interval::new(0.0, 1.0).expect("valid"))
    };
    let peak = match f {
        Smooth::Sigmoid => 0.25,
        Smooth::Tanh => 1.0,
    };
    let (a, b) = (slope(at_lo), slope(at_hi));
    let derivative = if y.lo() >= 0.0 {
        Interval::new(b.lo(), a.hi()).unwrap_or(a.hull(&b))
    } else if y.hi() <= 0.0 {
        Interval::new(a.lo(), b.hi()).unwrap_or(a.hull(&b))
    } else {
        Interval::new(a.lo().min(b.lo()), peak).expect("ordered")
    };
    (at_lo.hull(&at_hi), derivative)
}

/// The range of phi' over `y`.
pub fn derivative_range(f: Smooth, y: Interval) -> Interval {
    image_and_derivative(f, y).1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(f: Smooth, lo: f64, hi: f64, d: usize) -> PolyEnclosure {
        let e = enclose(f, Interval::new(lo, hi).unwrap(), d, 0.0);
        let mut worst = 0.0f64;
        for i in 0..=4000 {
            let y = lo + (hi - lo) * i as f64 / 4000.0;
            let tau = e.scale * (y - e.centre);
            assert!(tau.abs() <= 1.0 + 1e-12);
            let q = e.coef.iter().rev().fold(0.0, |acc, c| acc * tau + c);
            let gap = (f.eval(y) - q).abs();
            worst = worst.max(gap);
            assert!(gap <= e.err + 1e-15, "{f:?} on [{lo}, {hi}] degree {d}: gap {gap} at {y} above bound {}", e.err);
        }
        // Tight: the rigorous bound is within a small factor of the sampled error (or tiny).
        assert!(e.err <= 3.0 * worst + 1e-10, "{f:?} on [{lo}, {hi}] degree {d}: bound {} vs sampled {worst}", e.err);
        e
    }

    #[test]
    fn enclosures_hold_and_are_tight() {
        for f in [Smooth::Sigmoid, Smooth::Tanh] {
            // Ranges away from 0 take the saturated discs (see `Smooth::saturated_m`).
            for &(lo, hi) in &[
                (-0.01, 0.02),
                (0.3, 1.1),
                (-2.0, 2.0),
                (-4.0, 4.0),
                (-1.0, 7.0),
                (5.0, 12.0),
                (-30.0, 25.0),
                (-9.0, -4.0),
                (2.5, 2.6),
                (-12.5, -10.0),
                (1.0, 4.0),
            ] {
                for d in [1, 3, 5, 8] {
                    check(f, lo, hi, d);
                }
            }
        }
    }

    #[test]
    fn wide_ranges_keep_accuracy_with_degree() {
        let e4 = check(Smooth::Tanh, -4.0, 4.0, 4);
        let e10 = check(Smooth::Tanh, -4.0, 4.0, 10);
        assert!(e10.err < 0.2 * e4.err, "{} vs {}", e10.err, e4.err);
        assert!(check(Smooth::Sigmoid, -1.0, 1.0, 6).err < 1e-5);
    }

    #[test]
    fn a_budget_lowers_the_degree_and_the_bound_still_holds() {
        let (lo, hi) = (0.5, 1.5);
        let full = enclose(Smooth::Sigmoid, Interval::new(lo, hi).unwrap(), 6, 0.0);
        assert_eq!(full.coef.len(), 7);
        for budget in [1e-6, 1e-4, 1e-2] {
            let e = enclose(Smooth::Sigmoid, Interval::new(lo, hi).unwrap(), 6, budget);
            assert!(e.coef.len() < 7, "budget {budget}: degree {}", e.coef.len() - 1);
            // The dropped coefficients plus the Cauchy tail planned at half of them.
            assert!(e.err <= full.err + 2.0 * budget, "budget {budget}: {} above {} + 2 budget", e.err, full.err);
            for i in 0..=2000 {
                let y = lo + (hi - lo) * i as f64 / 2000.0;
                let tau = e.scale * (y - e.centre);
                let q = e.coef.iter().rev().fold(0.0, |acc, c| acc * tau + c);
                assert!((Smooth::Sigmoid.eval(y) - q).abs() <= e.err, "budget {budget}: at {y}");
            }
        }
        // Near-linear on a narrow range: a loose budget leaves the affine part.
        let narrow = enclose(Smooth::Tanh, Interval::new(2.0, 2.001).unwrap(), 6, 1e-6);
        assert_eq!(narrow.coef.len(), 2);
    }

    #[test]
    fn taylor_recurrence_matches_derivatives() {
        // sigmoid'(0) = 1/4, sigmoid'''(0)/6 = -1/48; tanh'(0) = 1, tanh'''(0)/6 = -1/3; in
        // w = (y - c) / h the j-th coefficient is scaled by h^j.
        let contains = |b: Ball, x: f64| (b.m - x).abs() <= b.r;
        let s = Smooth::Sigmoid.taylor(0.0, 1.0, 3);
        assert!(contains(s[1], 0.25) && contains(s[2], 0.0) && contains(s[3], -1.0 / 48.0));
        let t = Smooth::Tanh.taylor(0.0, 0.5, 3);
        assert!(contains(t[1], 0.5) && contains(t[3], -1.0 / 24.0));
    }

    #[test]
    fn derivative_ranges() {
        let r = derivative_range(Smooth::Sigmoid, Interval::new(-1.0, 2.0).unwrap());
        assert!(r.contains(0.25) && r.contains(sigmoid_prime(2.0)));
        let t = derivative_range(Smooth::Tanh, Interval::new(0.5, 1.0).unwrap());
        assert!(t.contains(1.0 - 0.5f64.tanh().powi(2)) && t.contains(1.0 - 1.0f64.tanh().powi(2)) && t.hi() < 0.8);
    }

    fn sigmoid_prime(x: f64) -> f64 {
        let s = 1.0 / (1.0 + (-x).exp());
        s * (1.0 - s)
    }
}
