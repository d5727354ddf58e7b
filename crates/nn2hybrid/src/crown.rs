//! Pre-activation bounds of ReLU layers by back-substitution (CROWN / DeepPoly), rigorous.
//!
//! Why: the zonotope relaxation of [`crate::propagate`] bounds a neuron by the range of its
//! model, where every earlier unstable neuron's gap is a symbol of its own; in a deep ReLU
//! network those gaps add up, and each loose range makes the next relaxations looser. Bounding
//! c^T z_k instead by substituting the layers back, each unstable ReLU replaced by its upper
//! relaxation s z + t (the chord) where its coefficient is positive and by a z (a = 0 or 1,
//! whichever is closer over [l, u]) where it is negative, keeps the signs of the relaxations
//! apart and ends at the anchor: models (the network's input, or the output of the last layer
//! with a smooth activation) each neuron of which is linear in the models' basis (monomials in
//! [-1, 1], or in [0, 1] when nonnegative, and error symbols in [-1, 1]). Both bounds are sound,
//! so a neuron's range is their intersection, and the tighter ranges feed the relaxations of the
//! next layers on both sides.
//!
//! Rigour: a row's bound is c^T z_k <= L h_j + k with k accumulated upward. Scaling L by the float
//! chord slope is off by at most u |L s| + eta per entry, times |z| <= max(|l|, |u|); the product
//! L W_j in floats is off by gamma_(n_j) |L| |W_j|, which applied to |h_(j-1)| <= the magnitude
//! of its bounds adds gamma_(n_j) |L| (|W_j| |h_(j-1)|), one matrix-vector product per layer; the
//! dot products L b_j likewise. At the anchor, the product with the coefficient matrix is bounded
//! the same way by each anchor neuron's sum of |coefficients|, and the interval remainders enter
//! in interval arithmetic.
use crate::network::{Activation, Layer};
use crate::propagate::{dot_bound, dot_up, Models};
use nalgebra::DMatrix;
use taylor::interval::{add_up, mul_up};
use taylor::tm::{gamma, ETA, U};
use taylor::Interval;

/// The layers since the anchor, with the pre-activation bounds of their neurons.
pub(crate) struct Crown<'a> {
    anchor: Models,
    /// Per anchor neuron: an upper bound of the sum of |coefficients| (the magnitude the
    /// coefficient product's rounding error scales with).
    anchor_mags: Vec<f64>,
    /// Per anchor neuron: an upper bound of its |value|.
    anchor_range: Vec<f64>,
    layers: Vec<(&'a Layer, Vec<Interval>)>,
    relaxes: bool,
}

/// Whether back-substitution can pass the layer (ReLU and identity neurons only).
pub(crate) fn passable(layer: &Layer) -> bool {
    layer.activations.iter().all(|a| matches!(a, Activation::Relu | Activation::Identity))
}

fn relu_image(z: Interval) -> Interval {
    z.max(&Interval::ZERO)
}

/// The relaxation of an unstable ReLU on [l, u] (l < 0 < u): upper s z + t, lower a z.
fn relaxation(z: Interval) -> (f64, f64, f64) {
    let (l, u) = (z.lo(), z.hi());
    let s = (u / (u - l)).clamp(0.0, 1.0);
    // max of relu(z) - s z over [l, u] (at an end: the difference is piecewise linear).
    let sp = Interval::point(s);
    let t = (-(sp * Interval::point(l))).hull(&(Interval::point(u) - sp * Interval::point(u))).hi().max(0.0);
    let a = if u > -l { 1.0 } else { 0.0 };
    (s, t, a)
}

impl<'a> Crown<'a> {
    pub(crate) fn new(anchor: &Models) -> Crown<'a> {
        let anchor_mags = (0..anchor.n()).map(|i| add_up(taylor::tm::abs_sum(anchor.column(i)), anchor.own_mag(i))).collect();
        let anchor_range = (0..anchor.n()).map(|i| anchor.range(i).mag()).collect();
        Crown { anchor: anchor.clone(), anchor_mags, anchor_range, layers: vec![], relaxes: false }
    }

    /// Records a layer (ReLU and identity neurons only) with its neurons' pre-activation bounds.
    pub(crate) fn push(&mut self, layer: &'a Layer, bounds: Vec<Interval>) {
        debug_assert!(passable(layer) && bounds.len() == layer.n_out());
        self.relaxes |= unstable(layer, &bounds).next().is_some();
        self.layers.push((layer, bounds));
    }

    /// Whether a recorded layer has an unstable ReLU (else a bound is the anchor's affine image).
    pub(crate) fn relaxes(&self) -> bool {
        self.relaxes
    }

    /// Upper bound of |h| per neuron of the output of layer j (the anchor for j = 0).
    fn magnitudes(&self, j: usize) -> Vec<f64> {
        if j == 0 {
            return self.anchor_range.clone();
        }
        let (layer, bounds) = &self.layers[j - 1];
        bounds.iter().zip(&layer.activations).map(|(z, a)| if *a == Activation::Relu { relu_image(*z).mag() } else { z.mag() }).collect()
    }

    /// Bounds of the pre-activations `rows` of `layer`, whose input is the output of the last
    /// recorded layer (or the anchor): one upper and one lower bound per row. `steps` > 0
    /// optimises the lower slopes of the unstable ReLUs per bound (alpha-CROWN: projected
    /// gradient steps, Adam, from the adaptive 0 / 1 slopes); every slope in [0, 1] gives a sound
    /// bound, so each bound is the best one met.
    pub(crate) fn bounds(&self, layer: &Layer, rows: &[usize], steps: usize) -> Vec<Interval> {
        if rows.is_empty() {
            return vec![];
        }
        let r = rows.len();
        let mut upper = self.pass(layer, rows, None).0;
        if steps > 0 && self.relaxes {
            let mut alpha: Vec<DMatrix<f64>> =
                self.layers.iter().map(|(l, b)| DMatrix::from_fn(l.n_out(), 2 * r, |p, _| relaxation_or_zero(l, b, p).2)).collect();
            let mut adam = Adam::new(&alpha);
            for _ in 0..steps {
                let (bound, trace) = self.pass(layer, rows, Some(&alpha));
                upper.iter_mut().zip(&bound).for_each(|(u, b)| *u = u.min(*b));
                let gradient = self.gradient(&trace.expect("recorded"));
                adam.step(&mut alpha, &gradient);
            }
            let last = self.pass(layer, rows, Some(&alpha)).0;
            upper.iter_mut().zip(&last).for_each(|(u, b)| *u = u.min(*b));
        }
        (0..r)
            .map(|q| {
                let (lo, hi) = (-upper[q + r], upper[q]);
                Interval::new(lo, hi).unwrap_or(Interval::ENTIRE)
            })
            .collect()
    }

    /// One back-substitution: the upper bounds of the rows (column q < r of the coefficients:
    /// z_rows[q], q >= r: -z_rows[q - r]) with lower slopes `alpha` (per layer, neuron and
    /// bound; None: adaptive), and with `alpha` what the gradient needs.
    fn pass(&self, layer: &Layer, rows: &[usize], alpha: Option<&[DMatrix<f64>]>) -> (Vec<f64>, Option<Trace>) {
        let r = rows.len();
        let n_in = layer.n_in();
        let mut lt = DMatrix::zeros(n_in, 2 * r);
        let mut k = vec![0.0; 2 * r];
        for (q, &i) in rows.iter().enumerate() {
            let w = layer.weight_t.column(i);
            lt.column_mut(q).copy_from(&w);
            lt.column_mut(q + r).copy_from(&(-w));
            k[q] = layer.bias[i];
            k[q + r] = -layer.bias[i];
        }
        let mut before = Vec::new();
        for j in (0..self.layers.len()).rev() {
            let (prev, bounds) = &self.layers[j];
            if alpha.is_some() {
                before.push(lt.clone());
            }
            self.relax(prev, bounds, &mut lt, &mut k, alpha.map(|a| &a[j]));
            lt = self.substitute(prev, j, &lt, &mut k);
        }
        let upper = self.at_anchor(&lt, &k);
        before.reverse();
        (upper, alpha.map(|a| Trace { before, anchor: lt, alpha: a.to_vec() }))
    }

    /// The gradient of the bounds (each bound its own column) in the lower slopes, by going
    /// back up the recorded pass: d bound / d L at the anchor, through each layer's W^T and
    /// relaxation (a float estimate: it only steers).
    fn gradient(&self, trace: &Trace) -> Vec<DMatrix<f64>> {
        let a = &self.anchor;
        let gt = a.coef_matrix() * &trace.anchor;
        let nonneg = &a.space().nonneg;
        let f = DMatrix::from_fn(gt.nrows(), gt.ncols(), |idx, q| {
            let v = gt[(idx, q)];
            if idx == 0 {
                1.0
            } else if idx < a.m && nonneg[idx] {
                (v > 0.0) as u8 as f64
            } else {
                v.signum()
            }
        });
        let mut g = a.coef_matrix().transpose() * f;
        for (i, mut row) in g.row_iter_mut().enumerate() {
            let (own, rem) = (a.own_coef(i).abs(), a.rem[i]);
            for (q, v) in row.iter_mut().enumerate() {
                *v += own * trace.anchor[(i, q)].signum() + rem.mid() + rem.radius() * trace.anchor[(i, q)].signum();
            }
        }
        let mut out = vec![DMatrix::zeros(0, 0); self.layers.len()];
        for j in 0..self.layers.len() {
            let (layer, bounds) = &self.layers[j];
            // d / d L' (after the relaxation) = W g + b.
            let mut gp = layer.weight_t.transpose() * &g;
            for (mut row, b) in gp.row_iter_mut().zip(&layer.bias) {
                row.add_scalar_mut(*b);
            }
            let before = &trace.before[j];
            let mut grad = DMatrix::zeros(layer.n_out(), before.ncols());
            for p in 0..layer.n_out() {
                let (s, t, _) = relaxation_or_zero(layer, bounds, p);
                let open = layer.activations[p] == Activation::Relu && bounds[p].lo() < 0.0 && bounds[p].hi() > 0.0;
                let dead = layer.activations[p] == Activation::Relu && bounds[p].hi() <= 0.0;
                for q in 0..before.ncols() {
                    let v = before[(p, q)];
                    if dead {
                        gp[(p, q)] = 0.0;
                    } else if open && v > 0.0 {
                        gp[(p, q)] = gp[(p, q)] * s + t;
                    } else if open {
                        grad[(p, q)] = gp[(p, q)] * v;
                        gp[(p, q)] *= trace.alpha[j][(p, q)];
                    }
                }
            }
            out[j] = grad;
            g = gp;
        }
        out
    }

    /// L h_j <= L' z_j + (added to k): each ReLU by its relaxation, by the sign of its
    /// coefficient; the lower slope is `alpha`'s (per neuron and bound) or the adaptive one.
    fn relax(&self, layer: &Layer, bounds: &[Interval], lt: &mut DMatrix<f64>, k: &mut [f64], alpha: Option<&DMatrix<f64>>) {
        for (p, (act, z)) in layer.activations.iter().zip(bounds).enumerate() {
            if *act != Activation::Relu || z.lo() >= 0.0 {
                continue;
            }
            let mut row = lt.row_mut(p);
            if z.hi() <= 0.0 {
                row.fill(0.0);
                continue;
            }
            let (s, t, a) = relaxation(*z);
            let zmag = z.mag();
            for (q, (v, kq)) in row.iter_mut().zip(k.iter_mut()).enumerate() {
                let slope = if *v > 0.0 { s } else { alpha.map_or(a, |al| al[(p, q)].clamp(0.0, 1.0)) };
                let scaled = *v * slope;
                if slope != 0.0 && slope != 1.0 {
                    *kq = add_up(*kq, mul_up(add_up(mul_up(U, scaled.abs()), ETA), zmag));
                }
                if *v > 0.0 {
                    *kq = add_up(*kq, mul_up(*v, t));
                }
                *v = scaled;
            }
        }
    }

    /// L z_j = (L W_j) h_(j-1) + L b_j: the new coefficients, the constant and the rounding of
    /// both added to k.
    fn substitute(&self, layer: &Layer, j: usize, lt: &DMatrix<f64>, k: &mut [f64]) -> DMatrix<f64> {
        let hmag = self.magnitudes(j);
        let n = layer.n_out();
        // w_p = |W_p| |h| + |b_p|: what row p of the product and the bias scale the error with.
        let w: Vec<f64> = (0..n).map(|p| add_up(dot_up(layer.weight_t.column(p).as_slice(), &hmag), layer.bias[p].abs())).collect();
        let g = gamma(n + 1);
        for (q, kq) in k.iter_mut().enumerate() {
            let column = lt.column(q);
            let dot: f64 = column.iter().zip(&layer.bias).map(|(l, b)| l * b).sum();
            *kq = add_up(add_up(*kq, dot), mul_up(g, dot_up(column.as_slice(), &w)));
        }
        &layer.weight_t * lt
    }

    /// Upper bounds of L h_0 + k over the anchor's models.
    fn at_anchor(&self, lt: &DMatrix<f64>, k: &[f64]) -> Vec<f64> {
        let a = &self.anchor;
        let (m, n) = (a.m, a.n());
        let gt = a.coef_matrix() * lt;
        let g = gamma(n + 1);
        let nonneg = &a.space().nonneg;
        (0..lt.ncols())
            .map(|q| {
                let l = lt.column(q);
                let c = gt.column(q);
                let mut hi = add_up(k[q], c[0]);
                let (mut both, mut pos) = (0.0, 0.0);
                for (idx, &v) in c.iter().enumerate().skip(1) {
                    if idx < m && nonneg[idx] {
                        pos += v.max(0.0);
                    } else {
                        both += v.abs();
                    }
                }
                let terms = c.len();
                hi = add_up(hi, dot_bound(add_up(both, pos), terms));
                let own: f64 = (0..n).map(|i| (l[i] * a.own_coef(i)).abs()).sum();
                hi = add_up(hi, dot_bound(own, n));
                hi = add_up(hi, mul_up(g, dot_up(l.as_slice(), &self.anchor_mags)));
                let rem = (0..n).fold(Interval::ZERO, |acc, i| acc + Interval::point(l[i]) * a.rem[i]);
                add_up(hi, rem.hi())
            })
            .collect()
    }
}

/// A pass recorded for the gradient: the coefficients before each layer's relaxation (in layer
/// order), at the anchor, and the slopes used.
struct Trace {
    before: Vec<DMatrix<f64>>,
    anchor: DMatrix<f64>,
    alpha: Vec<DMatrix<f64>>,
}

/// The unstable ReLU neurons of a recorded layer.
fn unstable<'b>(layer: &'b Layer, bounds: &'b [Interval]) -> impl Iterator<Item = usize> + 'b {
    (0..layer.n_out()).filter(|&p| layer.activations[p] == Activation::Relu && bounds[p].lo() < 0.0 && bounds[p].hi() > 0.0)
}

/// The relaxation of neuron p if it is an unstable ReLU, else zeros (never used).
fn relaxation_or_zero(layer: &Layer, bounds: &[Interval], p: usize) -> (f64, f64, f64) {
    if layer.activations[p] == Activation::Relu && bounds[p].lo() < 0.0 && bounds[p].hi() > 0.0 {
        relaxation(bounds[p])
    } else {
        (0.0, 0.0, 0.0)
    }
}

/// Adam on the slopes, projected onto [0, 1]: the bounds are sums of many piecewise-linear
/// terms, whose raw gradients differ in scale by orders of magnitude between neurons.
struct Adam {
    m: Vec<DMatrix<f64>>,
    v: Vec<DMatrix<f64>>,
    t: i32,
}

impl Adam {
    const RATE: f64 = 0.1;
    const B1: f64 = 0.9;
    const B2: f64 = 0.999;

    fn new(like: &[DMatrix<f64>]) -> Adam {
        let zeros: Vec<DMatrix<f64>> = like.iter().map(|a| DMatrix::zeros(a.nrows(), a.ncols())).collect();
        Adam { m: zeros.clone(), v: zeros, t: 0 }
    }

    fn step(&mut self, x: &mut [DMatrix<f64>], gradient: &[DMatrix<f64>]) {
        self.t += 1;
        let (c1, c2) = (1.0 - Self::B1.powi(self.t), 1.0 - Self::B2.powi(self.t));
        for ((x, g), (m, v)) in x.iter_mut().zip(gradient).zip(self.m.iter_mut().zip(self.v.iter_mut())) {
            for (((x, g), m), v) in x.iter_mut().zip(g.iter()).zip(m.iter_mut()).zip(v.iter_mut()) {
                *m = Self::B1 * *m + (1.0 - Self::B1) * g;
                *v = Self::B2 * *v + (1.0 - Self::B2) * g * g;
                *x = (*x - Self::RATE * (*m / c1) / ((*v / c2).sqrt() + 1e-12)).clamp(0.0, 1.0);
            }
        }
    }
}
