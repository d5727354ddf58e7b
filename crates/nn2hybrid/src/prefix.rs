//! A network's one-input prefix: the layers before the first one that mixes the part reading
//! one input alone with the other inputs. A perception chain's image generator reads the
//! position alone (Mountain Car: 1 -> 50 -> 100 -> 600, the velocity and noise parameters
//! carried past it as identity neurons); as models over a cell's variables its 750 smooth
//! neurons cost one multivariate composition each, every step. Over the input's range as the
//! only variable they cost order + 1 coefficients each, and the mixing layer's weights bring
//! the 600 pixels down to its 50 neurons before anything is composed with the input's model.
//!
//! Soundness: the prefix's models hold g(c + r s) for every s in [-1, 1] (their symbols, like
//! every activation error, are values in [-1, 1] at each point), and [c - r, c + r] holds both
//! the input's polynomial part P and the input y = P + D (D: its symbols and remainder), so at
//! s = (y - c) / r they hold g(y). With T = (P - c) / r, a polynomial output Q of the prefix
//! satisfies Q(s) = Q(T) + Q'(xi) D / r for some xi in [-1, 1]: Q(T) is summed from the powers
//! of T in Taylor-model arithmetic (truncation and rounding in their remainders), and
//! Q'([-1, 1]) / r = m +- w by interval arithmetic, so D's symbols are scaled by m (cancelling
//! as the dense propagation's mean-value step lets them) and w |D| joins the remainder.
use crate::error::Result;
use crate::network::{Activation, Layer, LayerArrays, Network};
use crate::propagate::{propagate_from, propagate_with, Activate, Models, Settings};
use nalgebra::DMatrix;
use taylor::interval::{add_up, mul_up};
use taylor::tm::{abs_sum, etas, gamma, U};
use taylor::{Interval, TaylorModel};

#[derive(Debug)]
pub(crate) struct Prefix {
    /// The input the prefix reads.
    input: usize,
    /// The first layer that mixes both parts: its affine map is split between them.
    end: usize,
    /// The input's part: the layers before `end` restricted to the neurons that depend on the
    /// input alone, then layer `end`'s weights from them (identity, with its bias).
    one: Network,
    /// The other inputs and their part: identity neurons, then layer `end`'s weights from them
    /// (no bias). None when none of them reaches layer `end`.
    rest: Option<(Vec<usize>, Network)>,
}

/// Layer `layer` restricted to neurons `rows` and inputs `cols`, with identity activations
/// and without bias unless `own` (activations and bias kept).
fn part(layer: &Layer, rows: &[usize], cols: &[usize], own: bool) -> LayerArrays {
    LayerArrays {
        n_out: rows.len(),
        n_in: cols.len(),
        weight: rows.iter().flat_map(|&i| cols.iter().map(move |&j| layer.weight(i, j))).collect(),
        bias: rows.iter().map(|&i| if own { layer.bias[i] } else { 0.0 }).collect(),
        activations: rows.iter().map(|&i| if own { layer.activations[i] } else { Activation::Identity }).collect(),
    }
}

fn which(flags: &[bool], value: bool) -> Vec<usize> {
    (0..flags.len()).filter(|&i| flags[i] == value).collect()
}

impl Prefix {
    /// The first input with a prefix, if any.
    pub(crate) fn find(net: &Network) -> Option<Prefix> {
        (0..net.n_in()).find_map(|i| Prefix::reading(net, i))
    }

    /// The prefix of `input`: the layers whose neurons either depend on `input` alone (any
    /// activation; a neuron reading nothing counts as such) or are identity neurons of the
    /// others, up to the first layer with a neuron of neither kind. Only worth it, and only
    /// built, with a smooth neuron before that layer.
    fn reading(net: &Network, input: usize) -> Option<Prefix> {
        // sides[l][j]: whether input j of layer l depends on `input` alone.
        let mut sides = vec![(0..net.n_in()).map(|j| j == input).collect::<Vec<bool>>()];
        let mut smooth = false;
        for (l, layer) in net.layers().iter().enumerate() {
            let side = &sides[l];
            let mut next = Vec::with_capacity(layer.n_out());
            let mut layer_smooth = false;
            for i in 0..layer.n_out() {
                let reads = |one: bool| layer.weight_t.column(i).iter().zip(side).any(|(&w, &s)| w != 0.0 && s == one);
                let (reads_one, reads_rest) = (reads(true), reads(false));
                if reads_rest && (reads_one || layer.activations[i] != Activation::Identity) {
                    return (l > 0 && smooth).then(|| Prefix::build(net, input, l, &sides)).flatten();
                }
                next.push(!reads_rest);
                layer_smooth |= !reads_rest && matches!(layer.activations[i], Activation::Sigmoid | Activation::Tanh);
            }
            smooth |= layer_smooth;
            sides.push(next);
        }
        None
    }

    fn build(net: &Network, input: usize, end: usize, sides: &[Vec<bool>]) -> Option<Prefix> {
        let layers = net.layers();
        let all: Vec<usize> = (0..layers[end].n_out()).collect();
        let mut one = Vec::with_capacity(end + 1);
        let mut rest = Vec::with_capacity(end + 1);
        for l in 0..end {
            one.push(part(&layers[l], &which(&sides[l + 1], true), &which(&sides[l], true), true));
            rest.push(part(&layers[l], &which(&sides[l + 1], false), &which(&sides[l], false), true));
        }
        one.push(part(&layers[end], &all, &which(&sides[end], true), false));
        one[end].bias.clone_from(&layers[end].bias);
        rest.push(part(&layers[end], &all, &which(&sides[end], false), false));
        let others = which(&sides[0], false);
        // Any empty layer of the other part means nothing of the other inputs reaches `end`.
        let rest = if rest.iter().all(|a| a.n_in > 0 && a.n_out > 0) { Some((others, Network::new(rest, None, None).ok()?)) } else { None };
        Some(Prefix { input, end, one: Network::new(one, None, None).ok()?, rest })
    }

    /// The network's outputs for `input` through the prefix; None when the input's range is a
    /// point or unbounded (the dense propagation handles those).
    pub(crate) fn propagate(&self, net: &Network, input: &Models, settings: &Settings, activate: &Activate) -> Result<Option<Models>> {
        let input = input.materialized();
        let y = input.column(self.input);
        let m = input.m;
        let poly = TaylorModel { coef: y[..m].to_vec(), rem: Interval::ZERO };
        // The range of P and of P + D together.
        let range = poly.poly_bound(&input.ctx.space) + input.rem[self.input].hull(&Interval::ZERO).inflate(input.sym_mag(self.input));
        if !range.is_bounded() || range.lo() >= range.hi() {
            return Ok(None);
        }
        let line = Settings { max_vars: 1, splits: vec![], ..settings.clone() };
        let start = Models::from_box(&[range], &line, false)?;
        let (_, _, c, r) = start.variables[0];
        let one = propagate_with(&self.one, &start, settings.back_substitution(), activate)?;
        let rest = match &self.rest {
            Some((inputs, part)) => Some(propagate_with(part, &input.columns(inputs), None, activate)?),
            None => None,
        };
        let pre = compose(&one, c, r, &input, self.input, rest.as_ref());
        let after = activate(&pre, &net.layers()[self.end], self.end + 1, None)?;
        Ok(Some(propagate_from(net, after, self.end + 1, settings.back_substitution(), activate)?))
    }
}

/// Q'([-1, 1]) for the polynomial with coefficients `q` (by degree), by Horner's scheme in
/// interval arithmetic.
fn derivative_range(q: &[f64]) -> Interval {
    (1..q.len()).rev().fold(Interval::ZERO, |acc, k| acc * Interval::SYMMETRIC + Interval::point(k as f64) * Interval::point(q[k]))
}

/// The models `one` of one variable s in [-1, 1] at s = (y - c) / r for y the neuron `col` of
/// `input` (materialized), plus `rest` (over `input`'s variables and symbols), over `input`'s
/// variables: its symbols first, then `one`'s. See the module doc for why this encloses.
pub(crate) fn compose(one: &Models, c: f64, r: f64, input: &Models, col: usize, rest: Option<&Models>) -> Models {
    let ctx = &input.ctx;
    let (m, m1) = (input.m, one.m);
    let one = one.materialized();
    let (s_in, s_one) = (input.coef.nrows() - m, one.coef.nrows() - m1);
    let y = input.column(col);
    // T = (P - c) / r: each coefficient within 3u of its value (the difference, 1 / r, the
    // product), so within 4u of the computed one.
    let f = 1.0 / r;
    let mut t: Vec<f64> = y[..m].iter().map(|&p| p * f).collect();
    t[0] = (y[0] - c) * f;
    let e_t = add_up(mul_up(4.0 * U, abs_sum(&t)), etas(m));
    let base = TaylorModel { coef: t, rem: Interval::symmetric(e_t) };
    let mut powers = vec![TaylorModel::constant(1.0), base.clone()];
    while powers.len() < m1 {
        let next = powers[powers.len() - 1].mul(&base, ctx);
        powers.push(next);
    }
    let sizes: Vec<f64> = powers.iter().map(|p| abs_sum(&p.coef)).collect();
    let d_rem = input.rem[col];
    let d_mag = add_up(input.sym_mag(col), d_rem.mag());
    let d_sizes = abs_sum(&y[m..]);
    let inv_r = Interval::point(r).recip().expect("a positive radius");
    // Each coefficient is a sum of at most m1 + 1 rounded products.
    let g = gamma(m1 + 2);
    let mut coef = DMatrix::zeros(m + s_in + s_one, one.n());
    let mut rem = Vec::with_capacity(one.n());
    for j in 0..one.n() {
        let q = one.poly(j);
        let mut column = coef.column_mut(j);
        let dst = column.as_mut_slice();
        let mut size = 0.0;
        let mut r_j = one.rem[j];
        for (k, &qk) in q.iter().enumerate().filter(|(_, &qk)| qk != 0.0) {
            for (d, &p) in dst.iter_mut().zip(&powers[k].coef) {
                *d += qk * p;
            }
            size = add_up(size, mul_up(qk.abs(), sizes[k]));
            r_j = r_j + Interval::point(qk) * powers[k].rem;
        }
        let slope = derivative_range(q) * inv_r;
        let mid = slope.mid();
        for (d, &a) in dst[m..m + s_in].iter_mut().zip(&y[m..]) {
            *d = mid * a;
        }
        size = add_up(size, mul_up(mid.abs(), d_sizes));
        r_j = r_j + d_rem * Interval::point(mid) + Interval::symmetric(mul_up((slope - Interval::point(mid)).mag(), d_mag));
        if let Some(rest) = rest {
            let other = rest.column(j);
            for (d, &o) in dst.iter_mut().zip(other) {
                *d += o;
            }
            size = add_up(size, abs_sum(other));
            r_j = r_j + rest.rem[j];
        }
        dst[m + s_in..].copy_from_slice(&one.column(j)[m1..]);
        let rounding = add_up(mul_up(g, size), etas((m + s_in) * (m1 + 1)));
        rem.push(r_j.inflate(rounding));
    }
    Models { ctx: ctx.clone(), m, coef, own: None, rem, variables: input.variables.clone(), time_var: None, pinned: input.pinned }
}

#[cfg(test)]
mod tests {
    use super::*;
    use taylor::{Ctx, Space};

    /// Deterministic numbers in [-1, 1).
    fn noise(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        2.0 * ((*state >> 11) as f64 / (1u64 << 53) as f64) - 1.0
    }

    /// Inputs (p, q): p -> 6 tanh -> 8 sigmoid with q carried past as an identity neuron, then a
    /// layer of 3 tanh reading both, then 2 identity outputs (a generator, a noise model and an
    /// estimator in miniature).
    fn chain(seed: u64) -> Network {
        let mut state = seed;
        let mut weights = |n: usize, gain: f64| (0..n).map(|_| gain * noise(&mut state)).collect::<Vec<f64>>();
        let first = weights(6, 3.0);
        let mut w1 = vec![0.0; 7 * 2];
        for i in 0..6 {
            w1[2 * i] = first[i];
        }
        w1[13] = 1.0;
        let inner = weights(8 * 6, 1.5);
        let mut w2 = vec![0.0; 9 * 7];
        for i in 0..8 {
            w2[7 * i..7 * i + 6].copy_from_slice(&inner[6 * i..6 * i + 6]);
        }
        w2[9 * 7 - 1] = 1.0;
        let mixing = weights(3 * 9, 1.0);
        let out = weights(2 * 3, 1.0);
        let (tanh, sigmoid, identity) = (Activation::Tanh, Activation::Sigmoid, Activation::Identity);
        let layers = vec![
            LayerArrays { n_out: 7, n_in: 2, weight: w1, bias: weights(7, 0.5), activations: [vec![tanh; 6], vec![identity]].concat() },
            LayerArrays { n_out: 9, n_in: 7, weight: w2, bias: weights(9, 0.5), activations: [vec![sigmoid; 8], vec![identity]].concat() },
            LayerArrays { n_out: 3, n_in: 9, weight: mixing, bias: weights(3, 0.2), activations: vec![tanh] },
            LayerArrays { n_out: 2, n_in: 3, weight: out, bias: vec![0.1, -0.1], activations: vec![identity] },
        ];
        Network::new(layers, Some(vec![2.0, 0.5]), None).unwrap()
    }

    /// The prefix's models composed with a two-variable input (polynomial, with remainders that
    /// become symbols) enclose the float network at sampled points and remainders, and are
    /// about as wide as the dense propagation's.
    #[test]
    fn composed_prefix_encloses_the_network_like_dense_propagation() {
        let net = chain(5);
        let prefix = net.prefix().expect("p alone feeds the first two layers");
        assert_eq!((prefix.input, prefix.end), (0, 2));
        assert!(prefix.rest.is_some(), "q reaches the mixing layer");
        let space = Space::get(2, 4, 0).unwrap();
        let ctx = Ctx::new(space.clone(), 4, 1e-15);
        let settings = Settings { order: 4, ..Settings::default() };
        let activate = |m: &Models, layer: &Layer, _, ranges: Option<&[Interval]>| crate::propagate::activate(m, layer, &settings, ranges);
        let mut state = 9;
        let mut ratios = vec![];
        for (scale, rem) in [(0.02, 1e-4), (0.2, 1e-3), (0.6, 0.0)] {
            // p = 0.3 + scale (x0 + x0 x1 / 2 + x1^2 / 4) + [-rem, rem], q = -0.2 + scale x1 + [0, rem]
            let p = TaylorModel { coef: vec![0.3, scale, 0.0, 0.0, 0.5 * scale, 0.25 * scale], rem: Interval::symmetric(rem) };
            let q = TaylorModel { coef: vec![-0.2, 0.0, scale], rem: Interval::new(0.0, rem).unwrap() };
            let input = Models::from_taylor_models(&[p.clone(), q.clone()], &ctx).unwrap();
            let fast = crate::propagate::propagate(&net, &input, &settings).unwrap();
            let dense = propagate_with(&net, &input, settings.back_substitution(), &activate).unwrap();
            let (fast_models, dense_models) = (fast.to_taylor_models(), dense.to_taylor_models());
            for _ in 0..2000 {
                let x = [noise(&mut state), noise(&mut state)];
                let at = [Interval::point(x[0]), Interval::point(x[1])];
                let dp = rem * noise(&mut state);
                let dq = rem * 0.5 * (1.0 + noise(&mut state));
                let truth = net.eval(&[p.eval_poly(&space, &x) + dp, q.eval_poly(&space, &x) + dq]).unwrap();
                for (k, &v) in truth.iter().enumerate() {
                    for (label, model) in [("prefix", &fast_models[k]), ("dense", &dense_models[k])] {
                        let enclosure = model.eval_interval(&space, &at);
                        assert!(enclosure.contains(v), "{label} output {k} at {x:?}: {v} outside {enclosure}");
                    }
                }
            }
            for (a, b) in fast.bounds().iter().zip(dense.bounds()) {
                ratios.push(a.width() / b.width());
            }
        }
        // The composition is a different enclosure, not a looser one.
        assert!(ratios.iter().all(|&q| q < 1.05), "prefix / dense widths {ratios:?}");
    }

    /// A closed loop's state: the inputs carry error symbols (pinned, read back by `to_state`),
    /// shared between p and q. At every sampled point of the domain and the symbols, the output
    /// models of the composed path hold the float network of the inputs' values there.
    #[test]
    fn composed_prefix_keeps_the_state_error_symbols() {
        let net = chain(8);
        let symbols = taylor::error_symbols::ErrorSymbols::new(2, vec![0, 1], 4, 1e-15).unwrap();
        let ctx = &symbols.ctx;
        let space = &ctx.space;
        let var = |v: usize, c: f64| TaylorModel::var(ctx, v).scale(c);
        let p = var(0, 0.04).add(&var(0, 0.02).mul(&var(1, 1.0), ctx)).add(&var(2, 0.003)).add(&var(3, -0.001)).add_constant(0.3);
        let p = p.add_interval(Interval::symmetric(1e-5));
        let q = var(1, 0.05).add(&var(2, -0.002)).add(&var(3, 0.004)).add_constant(-0.2);
        let settings = Settings { order: 4, ..Settings::default() };
        let activate = |m: &Models, layer: &Layer, _, ranges: Option<&[Interval]>| crate::propagate::activate(m, layer, &settings, ranges);
        let input = Models::from_state(&[p.clone(), q.clone()], &symbols).unwrap();
        assert!(net.prefix().is_some());
        let fast = crate::propagate::propagate(&net, &input, &settings).unwrap().to_state(&symbols);
        let dense = propagate_with(&net, &input, settings.back_substitution(), &activate).unwrap().to_state(&symbols);
        let mut state = 17;
        for _ in 0..3000 {
            let z: Vec<f64> = (0..4).map(|_| noise(&mut state)).collect();
            let at: Vec<Interval> = z.iter().map(|&v| Interval::point(v)).collect();
            let inputs = [p.eval_poly(space, &z) + 1e-5 * noise(&mut state), q.eval_poly(space, &z)];
            for (k, &v) in net.eval(&inputs).unwrap().iter().enumerate() {
                for (label, model) in [("prefix", &fast[k]), ("dense", &dense[k])] {
                    let enclosure = model.eval_interval(space, &at);
                    assert!(enclosure.contains(v), "{label} output {k} at {z:?}: {v} outside {enclosure}");
                }
            }
        }
        for (a, b) in fast.iter().zip(&dense) {
            let (wa, wb) = (a.bound(space).width(), b.bound(space).width());
            assert!(wa < 1.05 * wb, "prefix {wa} against dense {wb}");
            // The symbols stay variables of the outputs, with the dense path's gains.
            for v in 2..4 {
                let (ga, gb) = (a.linear_coefficient(space, v), b.linear_coefficient(space, v));
                assert!(gb != 0.0 && (ga - gb).abs() <= 0.05 * gb.abs(), "symbol {v}: {ga} against dense {gb}");
            }
        }
    }

    #[test]
    fn no_prefix_without_a_smooth_neuron_reading_one_input_alone() {
        let layer =
            |n_out, n_in, activations| LayerArrays { n_out, n_in, weight: vec![0.5; n_out * n_in], bias: vec![0.0; n_out], activations };
        let dense = Network::new(vec![layer(3, 2, vec![Activation::Tanh]), layer(1, 3, vec![Activation::Identity])], None, None).unwrap();
        assert!(dense.prefix().is_none(), "every neuron reads both inputs");
        assert!(chain(3).prefix().is_some());
    }

    #[test]
    fn derivative_ranges_hold_the_derivative() {
        let q = [0.3, -1.0, 0.5, 0.25];
        let range = derivative_range(&q);
        for k in 0..=100 {
            let s = -1.0 + 0.02 * k as f64;
            let value = q[1] + 2.0 * q[2] * s + 3.0 * q[3] * s * s;
            assert!(range.contains(value), "{value} outside {range}");
        }
    }
}
