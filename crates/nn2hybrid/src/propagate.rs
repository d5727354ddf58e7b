//! Sound bounds of a network over a set of inputs: direct Taylor-model propagation (Verisig 2.0
//! / POLAR style) and naive interval propagation.
//!
//! Representation ([`Models`]): every neuron of a layer is
//!   p_i(x) + sum_k g_ik eps_k + r_i,
//! a polynomial in the few input variables x in [-1, 1]^n (the graded layout of a
//! `taylor::Space`), a linear combination of error symbols eps_k in [-1, 1], and an interval
//! remainder for rounding errors. The symbols are the activation-approximation errors of earlier
//! neurons (and any inputs beyond the polynomial variables): keeping them symbolic instead of
//! boxing them into remainders lets later affine layers cancel them (POLAR's symbolic
//! remainders; a zonotope in the symbols). Without them, an error passing a 600-wide layer is
//! multiplied by sum |W| at every layer.
//!
//! An affine layer is ONE matrix product of the coefficient matrix (polynomial coefficients and
//! symbol coefficients of all neurons) with W^T. Its floating-point error is bounded a
//! posteriori: each coefficient of W C is a dot product of length n_in, off by at most
//! gamma_(n_in) (|W| |C|), and every monomial and symbol is bounded by 1, so neuron i's error
//! is at most gamma_(n_in) sum_j |W_ij| sum_col |C_j,col|, added to its remainder with the
//! remainders themselves propagated as |W| r (their midpoints are moved into the constant terms).
//!
//! Activations, per neuron, for y = p + delta with delta the symbols and remainder:
//! - sigmoid/tanh: phi(p + delta) = phi(p) + phi'(xi) delta (mean value). phi(p) is enclosed by
//!   q(s (p - c)) +- e with q the Chebyshev-fitted polynomial of [`crate::activation`], composed
//!   with p by Horner's scheme on float polynomials with one error bound at the end; phi'(xi)
//!   lies in [m - w, m + w] = phi'(range of y), so the old symbols are scaled by m and w |delta|
//!   joins the neuron's new error;
//! - ReLU: identity or zero when the sign is decided; otherwise the linear relaxation
//!   relu(y) in lambda y + [0, mu] with lambda = u / (u - l), mu = -lambda l on [l, u] (exact
//!   for the symbols, which are scaled by lambda). [l, u] is the model's range intersected with
//!   the bound found by back-substituting the layers since the input or the last smooth layer
//!   ([`crate::crown`], optionally with optimised slopes): decided signs and narrower chords;
//! - identity: nothing.
//!
//! All of a neuron's new error becomes one new symbol (or its remainder if symbols are off),
//! kept beside the coefficient matrix until the next affine map (a diagonal block otherwise).
//!
//! Domain splitting: a variable can be split into pieces, lazily: the layers before the first
//! nonlinear neuron that depends on it are propagated once (for a perception chain, the whole
//! image generator), then each piece substitutes x_v = c + r x_v' and continues.
use crate::activation::{enclose, image_and_derivative, Smooth};
use crate::crown::{passable, Crown};
use crate::error::{NetworkError, Result};
use crate::network::{Activation, Layer, Network};
use nalgebra::DMatrix;
use rayon::prelude::*;
use std::sync::Arc;
use taylor::error_symbols::ErrorSymbols;
use taylor::interval::{add_up, mul_up};
use taylor::tm::{etas, gamma, poly_bound_of, U};
use taylor::{Ctx, Interval, Space, TaylorModel};

/// A smooth neuron's model is replaced by the interval image when it is this much wider.
const WIDER_THAN_IMAGE: f64 = 2.0;
/// Errors below this are rounding noise: they stay in remainders, never become symbols.
const SYMBOL_FLOOR: f64 = 1e-12;

#[derive(Clone, Debug)]
pub struct Settings {
    /// Taylor-model order (also the degree of the activation polynomials).
    pub order: usize,
    /// Coefficients below this magnitude are swept into the remainder.
    pub cutoff: f64,
    /// Keep activation errors as symbols (else they go to interval remainders).
    pub symbolic: bool,
    /// Most symbols kept; beyond, the smallest are boxed into remainders.
    pub max_symbols: usize,
    /// A neuron's new error stays in its remainder instead of becoming a symbol when it is below
    /// this fraction of the neuron's range: symbols pay off only where errors are a visible part
    /// of a value, and each costs a column in every later matrix product.
    pub symbol_min: f64,
    /// How many box inputs (the widest) become polynomial variables; the rest become symbols.
    pub max_vars: usize,
    /// At a narrow layer (at most a quarter as many neurons as shared symbols), the symbols beyond
    /// the `narrow_symbols` largest (pinned ones aside) are boxed into one new symbol per neuron.
    /// An image model's 600 pixel errors, mixed into 50 hidden neurons, span at most 50
    /// directions: the largest carry the cancellations, and the boxed rest keeps its magnitude
    /// per neuron, while the next (wide) product shrinks from ~1,400 rows to ~240. Measured on
    /// the composite Mountain Car row (108 cells): keeping 64 tripled the domain splits, 96-256
    /// did not add any, and 128 was the fastest of those with margin. None: never.
    pub narrow_symbols: Option<usize>,
    /// (input index, pieces): split that input's interval into equal pieces (bounds only).
    pub splits: Vec<(usize, usize)>,
    /// Tighten ReLU neurons' ranges by back-substitution ([`crate::crown`]); off, the models'
    /// own ranges (the zonotope relaxation alone).
    pub back_substitution: bool,
    /// Gradient steps optimising the lower slopes of unstable ReLUs per back-substituted bound
    /// (alpha-CROWN); each step costs about two back-substitutions. 0: the adaptive slopes.
    pub alpha_steps: usize,
}

impl Default for Settings {
    fn default() -> Settings {
        Settings {
            order: 5,
            cutoff: 1e-15,
            symbolic: true,
            max_symbols: 4096,
            symbol_min: 1e-4,
            max_vars: 4,
            narrow_symbols: Some(128),
            splits: vec![],
            back_substitution: true,
            alpha_steps: 0,
        }
    }
}

impl Settings {
    /// The back-substitution to run: None (off) or the slope optimisation's steps.
    pub(crate) fn back_substitution(&self) -> Option<usize> {
        self.back_substitution.then_some(self.alpha_steps)
    }

    pub fn validate(&self) -> Result<()> {
        if self.order == 0 || self.order > taylor::space::MAX_ORDER {
            return Err(NetworkError::input(format!(
                "Taylor-model order must be between 1 and {}, got {}",
                taylor::space::MAX_ORDER,
                self.order
            )));
        }
        let valid = |x: f64, hi: f64| (0.0..hi).contains(&x);
        if !valid(self.cutoff, 1.0) || !valid(self.symbol_min, f64::INFINITY) {
            return Err(NetworkError::input(format!(
                "cutoff must be in [0, 1) and symbol_min >= 0, got {} and {}",
                self.cutoff, self.symbol_min
            )));
        }
        if self.max_vars == 0 || self.max_vars > taylor::space::MAX_VARS - 1 {
            return Err(NetworkError::input(format!(
                "max_vars must be between 1 and {}, got {}",
                taylor::space::MAX_VARS - 1,
                self.max_vars
            )));
        }
        if self.alpha_steps > 1000 {
            return Err(NetworkError::input(format!("alpha_steps is {}; use 0 to 1000", self.alpha_steps)));
        }
        if let Some(&(i, p)) = self.splits.iter().find(|&&(_, p)| p == 0 || p > 4096) {
            return Err(NetworkError::input(format!("input {i} is split into {p} pieces; use 1 to 4096")));
        }
        Ok(())
    }
}

/// Taylor models of all neurons of one layer, in matrix form (see the module doc).
#[derive(Clone)]
pub struct Models {
    pub ctx: Ctx,
    /// Polynomial coefficients per neuron: space.len_upto(order).
    pub(crate) m: usize,
    /// (m + shared symbols) x neurons, column-major: a neuron's coefficients are contiguous.
    pub(crate) coef: DMatrix<f64>,
    /// Symbols of one neuron each, as an activation creates them: own[i] is neuron i's
    /// coefficient of its own symbol (0: none). Kept apart from `coef` until the next affine
    /// map mixes them, because as rows of `coef` they would be a diagonal block (600 new symbols
    /// of a 600-wide layer: a 600 x 600 block, and a product 600 times larger than needed).
    pub(crate) own: Option<Vec<f64>>,
    pub(crate) rem: Vec<Interval>,
    /// For models built from a box: input i = centre + radius x_v for (i, v, centre, radius).
    pub variables: Vec<(usize, usize, f64, f64)>,
    /// The variable over [0, 1] that the Verisig ODEs integrate over, once added. Kept apart from
    /// the space's other unit variables (a closed loop's own time), which it must not reuse.
    pub(crate) time_var: Option<usize>,
    /// The first `pinned` shared symbols are a closed loop's state error symbols: never dropped
    /// or reordered, so that the outputs can be read back over the same symbols.
    pub(crate) pinned: usize,
}

fn iv(lo: f64, hi: f64) -> Interval {
    Interval::new(lo, hi).unwrap_or(Interval::ENTIRE)
}

/// An upper bound of sum_j |a_j| b_j for non-negative b.
pub(crate) fn dot_up(a: &[f64], b: &[f64]) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| x.abs() * y).sum();
    dot_bound(s, a.len())
}

/// An upper bound of a sum of n non-negative products (or terms) computed as `s` in floats.
pub(crate) fn dot_bound(s: f64, n: usize) -> f64 {
    add_up(mul_up(s, 1.0 + 2.0 * gamma(n + 1)), etas(n))
}

/// Column i of a layer's W^T (the weights into neuron i), contiguous.
fn weights_into(layer: &Layer, i: usize) -> &[f64] {
    let n = layer.n_in();
    &layer.weight_t.as_slice()[i * n..(i + 1) * n]
}

/// Sum of |x| rounded up.
fn abs_sum(v: &[f64]) -> f64 {
    taylor::tm::abs_sum(v)
}

impl Models {
    pub fn n(&self) -> usize {
        self.coef.ncols()
    }
    pub fn space(&self) -> &Arc<Space> {
        &self.ctx.space
    }
    pub fn symbols(&self) -> usize {
        self.coef.nrows() - self.m + self.own.as_ref().map_or(0, |own| own.iter().filter(|&&g| g != 0.0).count())
    }

    /// The same models with the neurons' own symbols moved into rows of `coef`.
    pub(crate) fn materialized(&self) -> Models {
        let Some(own) = &self.own else { return self.clone() };
        let owners: Vec<usize> = (0..own.len()).filter(|&i| own[i] != 0.0).collect();
        let rows = self.coef.nrows();
        let mut coef = DMatrix::zeros(rows + owners.len(), self.n());
        coef.rows_mut(0, rows).copy_from(&self.coef);
        for (k, &i) in owners.iter().enumerate() {
            coef[(rows + k, i)] = own[i];
        }
        Models { coef, own: None, ..self.clone() }
    }

    /// The models of neurons `which`, in that order, own symbols as rows.
    pub(crate) fn columns(&self, which: &[usize]) -> Models {
        let all = self.materialized();
        let mut coef = DMatrix::zeros(all.coef.nrows(), which.len());
        for (k, &i) in which.iter().enumerate() {
            coef.column_mut(k).copy_from(&all.coef.column(i));
        }
        Models { coef, rem: which.iter().map(|&i| all.rem[i]).collect(), ..all }
    }

    /// |coefficient| of neuron i's own symbol.
    pub(crate) fn own_mag(&self, i: usize) -> f64 {
        self.own_coef(i).abs()
    }

    /// Neuron i's coefficient of its own symbol (0: none).
    pub(crate) fn own_coef(&self, i: usize) -> f64 {
        self.own.as_ref().map_or(0.0, |own| own[i])
    }

    /// The coefficients (polynomial, then shared symbols) of all neurons, one column each.
    pub(crate) fn coef_matrix(&self) -> &DMatrix<f64> {
        &self.coef
    }

    /// The range of neuron i: its polynomial's bound plus symbols and remainder (what a ReLU's
    /// relaxation starts from).
    pub(crate) fn range(&self, i: usize) -> Interval {
        poly_bound_of(self.poly(i), &self.ctx.space) + self.rem[i].inflate(self.sym_mag(i))
    }

    /// Models of the box `input`: the `max_vars` widest non-degenerate inputs become polynomial
    /// variables (in input order), the other non-degenerate ones symbols (or remainders when
    /// symbols are off). `time_var` adds a last variable over [0, 1] (for the Verisig ODEs) and
    /// room for twice the order, which the ODE integration works at (see [`crate::verisig`]).
    pub fn from_box(input: &[Interval], settings: &Settings, time_var: bool) -> Result<Models> {
        settings.validate()?;
        for (i, b) in input.iter().enumerate() {
            if b.is_empty() || !b.is_bounded() {
                return Err(NetworkError::input(format!("input {i}: the interval {b} must be bounded and non-empty")));
            }
        }
        let mut wide: Vec<usize> = (0..input.len()).filter(|&i| input[i].lo() < input[i].hi()).collect();
        wide.sort_by(|&a, &b| input[b].width().total_cmp(&input[a].width()).then(a.cmp(&b)));
        let mut as_var: Vec<usize> = wide.iter().copied().take(settings.max_vars).collect();
        as_var.sort_unstable();
        let nv = as_var.len().max(1);
        let nvars = nv + time_var as usize;
        let space = Space::get(nvars, settings.order * if time_var { 2 } else { 1 }, if time_var { 1 << nv } else { 0 })?;
        let ctx = Ctx::new(space.clone(), settings.order, settings.cutoff);
        let m = space.len_upto(settings.order);
        let symbolic: Vec<usize> = if settings.symbolic { wide.iter().copied().filter(|i| !as_var.contains(i)).collect() } else { vec![] };
        let mut coef = DMatrix::zeros(m + symbolic.len(), input.len());
        let mut rem = vec![Interval::ZERO; input.len()];
        let mut variables = Vec::new();
        for (i, b) in input.iter().enumerate() {
            let c = b.mid();
            let r = (b.hi() - c).max(c - b.lo()).next_up();
            coef[(0, i)] = c;
            if let Some(v) = as_var.iter().position(|&j| j == i) {
                coef[(space.var_index(v), i)] = r;
                variables.push((i, v, c, r));
            } else if let Some(k) = symbolic.iter().position(|&j| j == i) {
                coef[(m + k, i)] = r;
            } else if b.lo() < b.hi() {
                rem[i] = Interval::symmetric(r);
            }
        }
        Ok(Models { ctx, m, coef, own: None, rem, variables, time_var: time_var.then_some(nv), pinned: 0 })
    }

    /// Models of given Taylor models (all in `ctx`), e.g. a closed loop's state. Each input's
    /// remainder becomes a shared symbol (centre + radius x symbol): the layers then carry it
    /// linearly into every neuron, instead of adding |w| x remainder per neuron as independent
    /// intervals. In a closed loop the state's remainders are most of what the networks see of
    /// the earlier steps' errors, and as intervals a 600-pixel chain amplifies them many times
    /// over the true gain.
    pub fn from_taylor_models(inputs: &[TaylorModel], ctx: &Ctx) -> Result<Models> {
        Models::from_parts(inputs, ctx, ctx, 0, &|t: TaylorModel| (t, vec![]))
    }

    /// Models of a state that carries error symbols ([`ErrorSymbols`]): the polynomials are over
    /// the domain variables alone (the networks' cost grows with the number of monomials), and
    /// the state's symbols become the first, pinned shared symbols, which [`Models::to_state`]
    /// reads back as the same symbols.
    pub fn from_state(inputs: &[TaylorModel], symbols: &ErrorSymbols) -> Result<Models> {
        Models::from_parts(inputs, &symbols.ctx, &symbols.domain, symbols.count(), &|t: TaylorModel| {
            let parts = symbols.split(&t);
            (parts.poly, parts.linear)
        })
    }

    /// `split` turns a model of `ctx` into a polynomial of `domain` and `pinned` linear symbol
    /// coefficients.
    fn from_parts(
        inputs: &[TaylorModel],
        ctx: &Ctx,
        domain: &Ctx,
        pinned: usize,
        split: &dyn Fn(TaylorModel) -> (TaylorModel, Vec<f64>),
    ) -> Result<Models> {
        if inputs.is_empty() {
            return Err(NetworkError::input("no input Taylor models given"));
        }
        let mut models = Vec::with_capacity(inputs.len());
        for (i, t) in inputs.iter().enumerate() {
            let mut t = t.clone();
            t.sweep(ctx);
            if t.coef.iter().any(|c| !c.is_finite()) || !t.rem.is_bounded() || t.rem.is_empty() {
                return Err(NetworkError::input(format!("input Taylor model {i} has a non-finite coefficient or an unbounded remainder")));
            }
            models.push(split(t));
        }
        let symbolic = |t: &TaylorModel| t.rem.radius() > SYMBOL_FLOOR;
        let m = domain.space.len_upto(domain.order);
        let mut coef = DMatrix::zeros(m + pinned + models.iter().filter(|(t, _)| symbolic(t)).count(), inputs.len());
        let mut rem = Vec::with_capacity(inputs.len());
        let mut k = m + pinned;
        for (i, (t, linear)) in models.into_iter().enumerate() {
            coef.view_mut((0, i), (t.coef.len(), 1)).copy_from_slice(&t.coef);
            coef.view_mut((m, i), (linear.len(), 1)).copy_from_slice(&linear);
            if symbolic(&t) {
                // The centre moves into the constant; its rounding error widens the symbol.
                let sum = coef[(0, i)] + t.rem.mid();
                coef[(0, i)] = sum;
                coef[(k, i)] = add_up(t.rem.radius(), mul_up(2.0 * U, sum.abs()));
                k += 1;
                rem.push(Interval::ZERO);
            } else {
                rem.push(t.rem);
            }
        }
        Ok(Models { ctx: domain.clone(), m, coef, own: None, rem, variables: vec![], time_var: None, pinned })
    }

    /// The outputs as a state with error symbols: the pinned symbols become the symbols'
    /// variables again, every other symbol goes into the remainder.
    pub fn to_state(&self, symbols: &ErrorSymbols) -> Vec<TaylorModel> {
        let p = self.pinned.min(symbols.count());
        (0..self.n())
            .map(|i| {
                let column = self.column(i);
                let linear = &column[self.m..self.m + p];
                let others = add_up(abs_sum(&column[self.m + p..]), self.own_mag(i));
                let poly = TaylorModel { coef: column[..self.m].to_vec(), rem: self.rem[i].inflate(others) };
                symbols.join(&poly, linear)
            })
            .collect()
    }

    /// The variable over [0, 1] that the Verisig ODEs integrate over, if one was added.
    pub fn time_var(&self) -> Option<usize> {
        self.time_var
    }

    /// The same models in a space with one more variable, over [0, 1], for the Verisig ODEs.
    pub fn with_time_var(&self) -> Result<Models> {
        if self.time_var().is_some() {
            return Ok(self.clone());
        }
        if self.own.is_some() {
            return self.materialized().with_time_var();
        }
        let old = &self.ctx.space;
        let nv = old.nvars;
        let space = Space::get(nv + 1, 2 * self.ctx.order, old.unit_mask | 1 << nv)?;
        let m = space.len_upto(self.ctx.order);
        let index: std::collections::HashMap<&[u8], usize> =
            (0..m).filter(|&k| space.exponent(k, nv) == 0).map(|k| (&space.exponents(k)[..nv], k)).collect();
        let s = self.symbols();
        let mut coef = DMatrix::zeros(m + s, self.n());
        for i in 0..self.n() {
            let src = self.column(i);
            for (k, &c) in src[..self.m].iter().enumerate() {
                coef[(index[old.exponents(k)], i)] = c;
            }
            for k in 0..s {
                coef[(m + k, i)] = src[self.m + k];
            }
        }
        let ctx = Ctx::new(space, self.ctx.order, self.ctx.cutoff);
        Ok(Models {
            ctx,
            m,
            coef,
            own: None,
            rem: self.rem.clone(),
            variables: self.variables.clone(),
            time_var: Some(nv),
            pinned: self.pinned,
        })
    }

    /// Neuron i as a Taylor model: polynomial plus remainder plus the symbols' range.
    pub fn taylor_model(&self, i: usize) -> TaylorModel {
        let poly = self.column(i);
        let mut t = TaylorModel { coef: poly[..self.m].to_vec(), rem: self.rem[i].inflate(self.sym_mag(i)) };
        while t.coef.len() > 1 && t.coef.last() == Some(&0.0) {
            t.coef.pop();
        }
        t
    }

    pub fn to_taylor_models(&self) -> Vec<TaylorModel> {
        (0..self.n()).map(|i| self.taylor_model(i)).collect()
    }

    /// Range of every neuron, the polynomial part bounded by the linear dominated bounder.
    pub fn bounds(&self) -> Vec<Interval> {
        (0..self.n())
            .map(|i| {
                let t = self.taylor_model(i);
                let poly = TaylorModel { coef: t.coef, rem: Interval::ZERO };
                taylor::bound::range(&poly, &self.ctx.space) + t.rem
            })
            .collect()
    }

    /// Neuron i's coefficients: polynomial then shared symbols.
    pub(crate) fn column(&self, i: usize) -> &[f64] {
        let w = self.coef.nrows();
        &self.coef.as_slice()[i * w..(i + 1) * w]
    }

    pub(crate) fn poly(&self, i: usize) -> &[f64] {
        &self.column(i)[..self.m]
    }

    pub(crate) fn sym_mag(&self, i: usize) -> f64 {
        add_up(abs_sum(&self.column(i)[self.m..]), self.own_mag(i))
    }

    /// W h + b for the layer, with the product's rounding error bounded a posteriori.
    pub fn affine(&self, layer: &Layer) -> Result<Models> {
        if layer.n_in() != self.n() {
            return Err(NetworkError::input(format!("the layer takes {} inputs but {} models were given", layer.n_in(), self.n())));
        }
        let n_in = self.n();
        // v_j = gamma |C_j| + r_j with r_j the remainder's radius: |W| v bounds the product's
        // error and the remainders together; the remainders' midpoints enter as W mid. (A
        // neuron's own symbol is part of its column C_j; its products g_j W_ij are exact to u.)
        let g = gamma(n_in);
        let v: Vec<f64> =
            (0..n_in).map(|j| add_up(mul_up(g, add_up(abs_sum(self.column(j)), self.own_mag(j))), self.rem[j].radius())).collect();
        let mids: Vec<f64> = self.rem.iter().map(|r| r.mid()).collect();
        let abs_mids: Vec<f64> = mids.iter().map(|m| m.abs()).collect();
        let mut out = self.product(layer);
        let rem = (0..layer.n_out())
            .map(|i| {
                let w = weights_into(layer, i);
                // One pass: |W_i| v, and the constant term's gain b_i + W_i mid (a dot product
                // and two additions) with its |W_i| |mid|.
                let (mut err, mut shift, mut abs_shift) = (0.0, 0.0, 0.0);
                for ((w, v), (m, am)) in w.iter().zip(&v).zip(mids.iter().zip(&abs_mids)) {
                    err += w.abs() * v;
                    shift += w * m;
                    abs_shift += w.abs() * am;
                }
                let mut err = dot_bound(err, n_in);
                err = add_up(err, mul_up(gamma(n_in), dot_bound(abs_shift, n_in)));
                let sum = out[(0, i)] + shift + layer.bias[i];
                err = add_up(err, mul_up(4.0 * U, add_up(sum.abs(), layer.bias[i].abs())));
                out[(0, i)] = sum;
                Interval::symmetric(err)
            })
            .collect();
        Ok(Models {
            ctx: self.ctx.clone(),
            m: self.m,
            coef: out,
            own: None,
            rem,
            variables: self.variables.clone(),
            time_var: self.time_var,
            pinned: self.pinned,
        })
    }

    /// C W^T with the own symbols as rows of their own: the shared part is one dense product,
    /// and the own symbol of input j becomes the row g_j W_(., j).
    fn product(&self, layer: &Layer) -> DMatrix<f64> {
        let Some(own) = &self.own else { return &self.coef * &layer.weight_t };
        let owners: Vec<usize> = (0..own.len()).filter(|&j| own[j] != 0.0).collect();
        let rows = self.coef.nrows();
        let mut out = DMatrix::zeros(rows + owners.len(), layer.n_out());
        out.rows_mut(0, rows).gemm(1.0, &self.coef, &layer.weight_t, 0.0);
        for (k, &j) in owners.iter().enumerate() {
            let g = own[j];
            let w = layer.weight_t.row(j);
            for (i, &wij) in w.iter().enumerate() {
                out[(rows + k, i)] = g * wij;
            }
        }
        out
    }

    /// The output map y <- scale * h + offset.
    pub fn output_map(&self, scale: Option<&[f64]>, offset: Option<&[f64]>) -> Models {
        let mut out = self.materialized();
        for i in 0..out.n() {
            let mut column = out.coef.column_mut(i);
            if let Some(s) = scale {
                let s = s[i];
                column.iter_mut().for_each(|c| *c *= s);
                let err = add_up(mul_up(2.0 * U, abs_sum(column.as_slice())), etas(column.len()));
                out.rem[i] = (self.rem[i] * Interval::point(s)).inflate(err);
            }
            if let Some(o) = offset {
                let sum = column[0] + o[i];
                column[0] = sum;
                out.rem[i] = out.rem[i].inflate(mul_up(2.0 * U, sum.abs()));
            }
        }
        out
    }

    /// Whether a nonlinear neuron's polynomial involves variable v.
    fn nonlinear_depends_on(&self, v: usize, activations: &[Activation]) -> bool {
        let space = &self.ctx.space;
        (0..self.n()).any(|i| {
            activations[i] != Activation::Identity && self.poly(i).iter().enumerate().any(|(k, &c)| c != 0.0 && space.exponent(k, v) > 0)
        })
    }

    /// Substitutes x_v = c + r x_v' (a piece of x_v's domain) in every polynomial.
    fn substitute(&self, v: usize, c: f64, r: f64) -> Models {
        let space = &self.ctx.space;
        let order = self.ctx.order;
        // pw[e][t] = C(e, t) c^(e - t) r^t, each within gamma_(e + 1) of its value.
        let pw: Vec<Vec<f64>> = (0..=order)
            .map(|e| {
                let mut binom = 1.0;
                (0..=e)
                    .map(|t| {
                        let value = binom * c.powi((e - t) as i32) * r.powi(t as i32);
                        binom = binom * (e - t) as f64 / (t + 1) as f64;
                        value
                    })
                    .collect()
            })
            .collect();
        // Each result is a sum of at most order + 1 terms, each term a product of at most
        // 2 order + 2 rounded factors: relative error gamma_(3 order + 4) of the sum of |terms|.
        let g = gamma(3 * order + 4);
        let mut out = self.clone();
        for i in 0..self.n() {
            let poly = self.poly(i);
            let mut fresh = vec![0.0; self.m];
            let mut magnitude = 0.0;
            let mut terms = 0usize;
            for (k, &a) in poly.iter().enumerate() {
                if a == 0.0 {
                    continue;
                }
                let e = space.exponent(k, v) as usize;
                let mut target = space.without_var(k, v);
                for (t, &p) in pw[e].iter().enumerate() {
                    if t > 0 {
                        target = space.times_var(target, v).expect("degree does not grow");
                    }
                    let term = a * p;
                    fresh[target] += term;
                    magnitude += term.abs();
                    terms += 1;
                }
            }
            let err = add_up(mul_up(mul_up(magnitude, 1.0 + gamma(terms)), g), etas(terms));
            out.coef.column_mut(i).as_mut_slice()[..self.m].copy_from_slice(&fresh);
            out.rem[i] = self.rem[i].inflate(err);
        }
        out
    }
}

/// What an activation did to one neuron: its new polynomial, the factor of the old symbols, and
/// the new error (to become a symbol or a remainder).
pub(crate) struct NeuronOut {
    pub poly: TaylorModel,
    pub sym_factor: f64,
    pub error: Interval,
    /// Whether the error may become a symbol (not for identity neurons: only rounding there).
    pub symbolic: bool,
}

/// Applies a per-neuron activation result to the models, creating and capping symbols.
fn assemble(models: &Models, outs: Vec<NeuronOut>, settings: &Settings) -> Models {
    if models.own.is_some() {
        return assemble(&models.materialized(), outs, settings);
    }
    let (m, old) = (models.m, models.symbols());
    let n = outs.len();
    let space = &models.ctx.space;
    let new_symbol: Vec<bool> = outs
        .iter()
        .map(|o| {
            let r = o.error.radius();
            settings.symbolic
                && o.symbolic
                && r > SYMBOL_FLOOR
                && r > settings.symbol_min * (o.poly.poly_bound(space).width() + o.error.width())
        })
        .collect();
    let mut coef = DMatrix::zeros(m + old, n);
    let mut own = vec![0.0; n];
    let mut rem = Vec::with_capacity(n);
    for (i, o) in outs.into_iter().enumerate() {
        let mut column = coef.column_mut(i);
        let dst = column.as_mut_slice();
        let len = o.poly.coef.len().min(m);
        dst[..len].copy_from_slice(&o.poly.coef[..len]);
        let mut r = o.poly.rem;
        if o.sym_factor != 0.0 && old > 0 {
            let src = &models.column(i)[m..];
            for (d, s) in dst[m..m + old].iter_mut().zip(src) {
                *d = s * o.sym_factor;
            }
            r = r.inflate(add_up(mul_up(2.0 * U, abs_sum(&dst[m..m + old])), etas(old)));
        }
        if new_symbol[i] {
            let mid = o.error.mid();
            let sum = dst[0] + mid;
            dst[0] = sum;
            own[i] = add_up(o.error.radius(), mul_up(2.0 * U, sum.abs()));
        } else {
            r = r + o.error;
        }
        rem.push(r);
    }
    let own = new_symbol.contains(&true).then_some(own);
    let mut out = Models {
        ctx: models.ctx.clone(),
        m,
        coef,
        own,
        rem,
        variables: models.variables.clone(),
        time_var: models.time_var,
        pinned: models.pinned,
    };
    cap_symbols(&mut out, settings.max_symbols);
    out
}

/// A layer this many times narrower than its shared symbols is narrow (see
/// [`Settings::narrow_symbols`]).
const NARROW: usize = 4;

/// The models with all but the `keep` largest unpinned shared symbols (by total |coefficient|)
/// boxed into one new own symbol per neuron, when the layer is narrow; None otherwise. Sound:
/// neuron i's part sum_k g_ik eps_k over the boxed k lies in [-d_i, d_i] with d_i = sum |g_ik|,
/// which is d_i eps'_i for a new symbol eps'_i in [-1, 1]. Each neuron's magnitude is unchanged
/// (so is its activation); only correlations through the boxed symbols are lost.
fn box_minor_symbols(models: &Models, keep: usize) -> Option<Models> {
    let s = models.coef.nrows() - models.m;
    let pinned = models.pinned.min(s);
    if models.own.is_some() || s < NARROW * models.n() || s - pinned <= keep + models.n() {
        return None;
    }
    let (coef, own) = largest_symbols(models, &symbol_weights(models), keep);
    let (ctx, rem, variables) = (models.ctx.clone(), models.rem.clone(), models.variables.clone());
    Some(Models { ctx, m: models.m, coef, own: Some(own), rem, variables, time_var: models.time_var, pinned: models.pinned })
}

/// Boxes all but the `max` largest symbols (by total |coefficient|) into the remainders, and
/// drops symbols no neuron uses any more.
fn cap_symbols(models: &mut Models, max: usize) {
    if models.own.is_some() && models.symbols() > max {
        *models = models.materialized();
    }
    // The shared symbols (the own ones are in use, and within `max` together with these).
    let s = models.coef.nrows() - models.m;
    if s == 0 {
        return;
    }
    let weight = symbol_weights(models);
    let pinned = models.pinned.min(s);
    if s <= max.max(pinned) && weight[pinned..].iter().all(|&w| w > 0.0) {
        return;
    }
    let (coef, dropped) = largest_symbols(models, &weight, max.saturating_sub(pinned));
    for (r, d) in models.rem.iter_mut().zip(dropped) {
        *r = r.inflate(d);
    }
    models.coef = coef;
}

/// Each shared symbol's total |coefficient| over the neurons.
fn symbol_weights(models: &Models) -> Vec<f64> {
    let m = models.m;
    let mut weight = vec![0.0; models.coef.nrows() - m];
    for i in 0..models.n() {
        for (w, c) in weight.iter_mut().zip(&models.column(i)[m..]) {
            *w += c.abs();
        }
    }
    weight
}

/// The coefficient matrix with the pinned symbols (in place) and the `keep` heaviest others in
/// use, and per neuron the sum of the |coefficients| left out, rounded up.
fn largest_symbols(models: &Models, weight: &[f64], keep: usize) -> (DMatrix<f64>, Vec<f64>) {
    let (m, n, s) = (models.m, models.n(), weight.len());
    let pinned = models.pinned.min(s);
    let mut order: Vec<usize> = (pinned..s).filter(|&k| weight[k] > 0.0).collect();
    order.sort_by(|&a, &b| weight[b].total_cmp(&weight[a]));
    let kept: Vec<usize> = (0..pinned).chain(order.into_iter().take(keep)).collect();
    let mut left_out = vec![true; s];
    kept.iter().for_each(|&k| left_out[k] = false);
    let mut coef = DMatrix::zeros(m + kept.len(), n);
    let mut dropped = vec![0.0; n];
    for i in 0..n {
        let src = models.column(i);
        let mut column = coef.column_mut(i);
        let dst = column.as_mut_slice();
        dst[..m].copy_from_slice(&src[..m]);
        for (slot, &k) in kept.iter().enumerate() {
            dst[m + slot] = src[m + k];
        }
        dropped[i] = src[m..].iter().zip(&left_out).filter(|(_, &out)| out).fold(0.0, |d, (g, _)| add_up(d, g.abs()));
    }
    (coef, dropped)
}

/// q(tau) for tau = s (p - c) and a polynomial p (no remainder), by Horner's scheme on float
/// polynomials truncated at the order, with ONE error bound at the end instead of Taylor-model
/// arithmetic per step. Let T be the float polynomial computed for tau (|T - tau| <= e_T) and
/// A_k = A_(k+1) T + q_k + E_k the steps, E_k the terms beyond the order dropped by step k plus
/// its rounding (each monomial is in [-1, 1], so |E_k| <= e_k, the sums of |coefficients|).
/// Then A_0 = q(T) + sum_k E_k T^k, and |T| <= 1 + e_T = B because |tau| <= 1 (s |y - c| <= 1 on
/// the range), so |phi(p) - A_0| <= err + B^(d-1) sum_k e_k + e_T max_{|z| <= B} |q'(z)|.
/// Horner's scheme in Taylor-model arithmetic gives the same bound (the test below checks that
/// this one is never wider) at several times the cost: interval remainders, range bounds and
/// allocations at every step. (Estrin's scheme, tried there: 15% faster, 10-30% wider.)
fn compose(q: &[f64], centre: f64, scale: f64, p: &[f64], ctx: &Ctx) -> TaylorModel {
    let space = &ctx.space;
    let len = space.len_upto(ctx.order).min(p.len()).max(1);
    // One allocation for T, the suffix sums of |T| and the step buffer (this runs for every
    // neuron); `a` becomes the result.
    let mut scratch = vec![0.0; 3 * len + 1];
    let (t, rest) = scratch.split_at_mut(len);
    let (suffix, next) = rest.split_at_mut(len + 1);
    t.iter_mut().zip(p).for_each(|(t, &c)| *t = c * scale);
    let shifted = p[0] - centre;
    t[0] = shifted * scale;
    // Each coefficient of T is one rounded product (t_0 also a rounded difference): within
    // u |t_k| (+ the underflow eta), and t_0 within s u |p_0 - c| more.
    let e_tau = add_up(add_up(mul_up(U, abs_sum(t)), mul_up(mul_up(U, scale), shifted.abs())), etas(len));
    let bound = add_up(1.0, e_tau);
    // suffix[j] = sum_(k >= j) |t_k|: the part of T that a term of A times T drops beyond the order.
    for j in (0..len).rev() {
        suffix[j] = suffix[j + 1] + t[j].abs();
    }
    // Only T's non-zero terms take part (a small cell's models keep few of their monomials).
    let nonzero: Vec<u32> = (0..len as u32).filter(|&j| t[j as usize] != 0.0).collect();
    let grow = 1.0 + gamma(2 * len + 2);
    let g = gamma(len + 2);
    let d = q.len() - 1;
    let mut a = vec![0.0; len];
    a[0] = q[d];
    let mut steps = 0.0;
    for k in (0..d).rev() {
        next.fill(0.0);
        let (mut dropped, mut sa) = (0.0, 0.0);
        for (i, &ai) in a.iter().enumerate() {
            if ai == 0.0 {
                continue;
            }
            sa += ai.abs();
            let lim = len.min(space.len_upto(ctx.order - space.deg[i] as usize));
            // The pairs of i list j = 0, 1, ... in order: the first lim are those with t_j.
            let pairs = space.pairs_of(i);
            for &j in nonzero.iter().take_while(|&&j| (j as usize) < lim) {
                next[pairs[j as usize].1 as usize] += ai * t[j as usize];
            }
            dropped += ai.abs() * suffix[lim];
        }
        next[0] += q[k];
        // Float sums of non-negative terms are within a factor grow of the exact ones; each
        // coefficient is a sum of at most len products and q_k: rounding gamma_(len + 2).
        let rounding = mul_up(g, add_up(mul_up(mul_up(sa, suffix[0]), grow), q[k].abs()));
        let e_k = add_up(add_up(mul_up(dropped, grow), rounding), etas(len * len));
        steps = add_up(steps, e_k);
        a.copy_from_slice(next);
    }
    let (mut power, mut lipschitz) = (1.0, 0.0);
    for (j, &qj) in q.iter().enumerate().skip(1) {
        lipschitz = add_up(lipschitz, mul_up(mul_up(j as f64, qj.abs()), power));
        power = mul_up(power, bound);
    }
    // power is now B^d >= B^(d-1).
    let err = add_up(mul_up(power, steps), mul_up(lipschitz, e_tau));
    let mut out = TaylorModel { coef: a, rem: Interval::symmetric(err) };
    out.sweep(ctx);
    out
}

/// The activation polynomial's top degrees are dropped while their error stays below this share
/// of what the neuron carries already (|phi'| |delta|, from earlier layers): composing at degree
/// 2-3 instead of the order costs half as much (most pixels of an image model are nearly
/// saturated and nearly linear in the cell). Measured on hard composite Mountain Car cells (24
/// near the wall, Chebyshev truncation): 1% was no faster (within noise), 5% left 3 unknown.
const TRUNCATION_SHARE: f64 = 0.001;

/// One smooth neuron: phi(p + delta) in q(s (p - c)) +- e + phi'(Y) delta.
fn smooth_neuron(f: Smooth, models: &Models, i: usize) -> NeuronOut {
    let ctx = &models.ctx;
    let p = models.poly(i);
    let range = poly_bound_of(p, &ctx.space);
    let symbols = models.sym_mag(i);
    let delta = models.rem[i].inflate(symbols);
    let y = range + delta;
    let (image, slope) = image_and_derivative(f, y);
    let constant = || NeuronOut {
        poly: TaylorModel::constant(image.mid()),
        sym_factor: 0.0,
        error: image - Interval::point(image.mid()),
        symbolic: true,
    };
    if !y.is_bounded() {
        return constant();
    }
    let enc = enclose(f, range, ctx.order, TRUNCATION_SHARE * slope.mag() * delta.mag());
    let mut poly = if enc.scale == 0.0 { TaylorModel::constant(enc.coef[0]) } else { compose(&enc.coef, enc.centre, enc.scale, p, ctx) };
    let mut error = Interval::symmetric(enc.err) + poly.rem;
    poly.rem = Interval::ZERO;
    let mut sym_factor = 0.0;
    if delta != Interval::ZERO {
        let mid = slope.mid();
        let spread = (slope - Interval::point(mid)).mag();
        sym_factor = mid;
        // mid * (remainder part of delta) + spread * |delta|; the symbols keep mid * g.
        error = error + models.rem[i] * Interval::point(mid) + Interval::symmetric(mul_up(spread, delta.mag()));
    }
    // On wide ranges the model can be far wider than the interval image phi(y), which saturates:
    // then the image is the better enclosure, and without this swap the excess would grow layer
    // by layer. A model somewhat wider than the image is kept: its correlations pay off later.
    let width = (poly.poly_bound(&ctx.space) + error).width() + 2.0 * sym_factor.abs() * symbols;
    if width > WIDER_THAN_IMAGE * image.width() {
        return constant();
    }
    NeuronOut { poly, sym_factor, error, symbolic: true }
}

/// ReLU: decided signs exactly; undecided by relu(y) in lambda y + [0, mu]. `known` is a range
/// of the pre-activation known otherwise (back-substitution), intersected with the model's.
fn relu_neuron(models: &Models, i: usize, known: Option<Interval>) -> NeuronOut {
    let p = TaylorModel { coef: models.poly(i).to_vec(), rem: Interval::ZERO };
    let own = models.range(i);
    let y = known.map(|k| own.intersect(&k)).filter(|y| !y.is_empty()).unwrap_or(own);
    if y.hi() <= 0.0 {
        return NeuronOut { poly: TaylorModel::zero(), sym_factor: 0.0, error: Interval::ZERO, symbolic: false };
    }
    if y.lo() >= 0.0 {
        return NeuronOut { poly: p, sym_factor: 1.0, error: models.rem[i], symbolic: false };
    }
    let (l, u) = (y.lo(), y.hi());
    let lambda = u / (u - l);
    if !lambda.is_finite() {
        return NeuronOut { poly: TaylorModel::constant(0.5 * u), sym_factor: 0.0, error: iv(-0.5 * u, 0.5 * u), symbolic: true };
    }
    // relu(y) - lambda y is piecewise linear: its extremes are at l, 0 and u.
    let li = Interval::point(lambda);
    let gap = (-(li * Interval::point(l))).hull(&Interval::ZERO).hull(&(Interval::point(u) - li * Interval::point(u)));
    let mut poly = p.scale(lambda);
    let error = gap + models.rem[i] * li + poly.rem;
    poly.rem = Interval::ZERO;
    NeuronOut { poly, sym_factor: lambda, error, symbolic: true }
}

/// How a method encloses one sigmoid or tanh neuron.
pub(crate) type SmoothNeuron<'a> = dyn Fn(Smooth, &Models, usize) -> Result<NeuronOut> + Sync + 'a;

/// A layer's activations, in parallel over neurons; `smooth` handles sigmoid and tanh neurons,
/// ReLU and identity neurons are handled here for every method (`ranges`: the pre-activations'
/// ranges where back-substitution found them, see [`Activate`]).
pub(crate) fn activate_with(
    models: &Models,
    layer: &Layer,
    settings: &Settings,
    smooth: &SmoothNeuron,
    ranges: Option<&[Interval]>,
) -> Result<Models> {
    if layer.is_affine() {
        return Ok(models.clone());
    }
    let reduced = settings.narrow_symbols.and_then(|keep| box_minor_symbols(models, keep));
    let models = reduced.as_ref().unwrap_or(models);
    let outs: Vec<NeuronOut> = (0..models.n())
        .into_par_iter()
        .map(|i| match layer.activations[i] {
            Activation::Sigmoid => smooth(Smooth::Sigmoid, models, i),
            Activation::Tanh => smooth(Smooth::Tanh, models, i),
            Activation::Relu => Ok(relu_neuron(models, i, ranges.map(|r| r[i]))),
            Activation::Identity => Ok(NeuronOut {
                poly: TaylorModel { coef: models.poly(i).to_vec(), rem: Interval::ZERO },
                sym_factor: 1.0,
                error: models.rem[i],
                symbolic: false,
            }),
        })
        .collect::<Result<_>>()?;
    Ok(assemble(models, outs, settings))
}

/// The activation of a layer by the direct method.
pub fn activate(models: &Models, layer: &Layer, settings: &Settings, ranges: Option<&[Interval]>) -> Result<Models> {
    activate_with(models, layer, settings, &|f, m, i| Ok(smooth_neuron(f, m, i)), ranges)
}

/// The activation step of a propagation method (direct or Verisig): pre-activation models, the
/// layer, its number, and the neurons' pre-activation ranges where back-substitution found
/// tighter ones than the models' own (ReLU layers).
pub type Activate<'a> = dyn Fn(&Models, &Layer, usize, Option<&[Interval]>) -> Result<Models> + Sync + 'a;

/// One layer: the affine map, the ReLU neurons' ranges by back-substitution (recording the
/// layer in `crown`, which starts at `models` if it is not running yet; a layer with a smooth
/// neuron ends it; `crown` None: back-substitution is off, else its slope optimisation's steps and
/// the chain), the activation. `all`:
/// back-substitute every neuron, not only the ReLU neurons of open sign (the last layer of a
/// bound); their ranges are returned then.
fn layer_step<'a>(
    models: &Models,
    layer: &'a Layer,
    index: usize,
    crown: &mut Option<(usize, Option<Crown<'a>>)>,
    all: bool,
    activate: &Activate,
) -> Result<(Models, Option<Vec<Interval>>)> {
    let pre = models.affine(layer)?;
    let Some((steps, crown)) = crown else { return Ok((activate(&pre, layer, index, None)?, None)) };
    if !passable(layer) {
        *crown = None;
        return Ok((activate(&pre, layer, index, None)?, None));
    }
    let mut ranges: Vec<Interval> = (0..pre.n()).map(|i| pre.range(i)).collect();
    if crown.is_none() && layer.activations.contains(&Activation::Relu) {
        *crown = Some(Crown::new(models));
    }
    let Some(chain) = crown else { return Ok((activate(&pre, layer, index, None)?, all.then_some(ranges))) };
    // Without a relaxation since the anchor, back-substitution is the models' own affine image.
    if chain.relaxes() {
        let rows: Vec<usize> = (0..pre.n())
            .filter(|&i| all || (layer.activations[i] == Activation::Relu && ranges[i].lo() < 0.0 && ranges[i].hi() > 0.0))
            .collect();
        for (&i, b) in rows.iter().zip(chain.bounds(layer, &rows, *steps)) {
            let tighter = ranges[i].intersect(&b);
            if !tighter.is_empty() {
                ranges[i] = tighter;
            }
        }
    }
    let out = activate(&pre, layer, index, Some(&ranges))?;
    chain.push(layer, ranges.clone());
    Ok((out, all.then_some(ranges)))
}

/// Propagates models through all layers and the output map (no splitting).
pub fn propagate_with(net: &Network, input: &Models, back_substitution: Option<usize>, activate: &Activate) -> Result<Models> {
    if input.n() != net.n_in() {
        return Err(NetworkError::input(format!("the network takes {} inputs but {} were given", net.n_in(), input.n())));
    }
    propagate_from(net, input.clone(), 0, back_substitution, activate)
}

/// Propagates the outputs of layer `start - 1` through the layers from `start` on and the
/// output map.
pub(crate) fn propagate_from(
    net: &Network,
    mut models: Models,
    start: usize,
    back_substitution: Option<usize>,
    activate: &Activate,
) -> Result<Models> {
    let mut crown = back_substitution.map(|steps| (steps, None));
    for (index, layer) in net.layers().iter().enumerate().skip(start) {
        models = layer_step(&models, layer, index + 1, &mut crown, false, activate)?.0;
    }
    Ok(models.output_map(net.scale(), net.offset()))
}

/// Direct Taylor-model propagation of `input` through the network; a prefix that reads one
/// input alone goes over that input's range as one variable ([`crate::prefix`]).
pub fn propagate(net: &Network, input: &Models, settings: &Settings) -> Result<Models> {
    settings.validate()?;
    let activate = |m: &Models, layer: &Layer, _, ranges: Option<&[Interval]>| activate(m, layer, settings, ranges);
    if let Some(prefix) = net.prefix().filter(|_| input.n() == net.n_in() && input.time_var.is_none()) {
        if let Some(out) = prefix.propagate(net, input, settings, &activate)? {
            return Ok(out);
        }
    }
    propagate_with(net, input, settings.back_substitution(), &activate)
}

/// The network applied to Taylor models in `ctx` (e.g. a closed loop's state): the outputs as
/// Taylor models in the same context, symbols folded into the remainders.
pub fn propagate_taylor_models(net: &Network, inputs: &[TaylorModel], ctx: &Ctx, settings: &Settings) -> Result<Vec<TaylorModel>> {
    Ok(propagate(net, &Models::from_taylor_models(inputs, ctx)?, settings)?.to_taylor_models())
}

/// Sound output bounds over the box `input`, splitting inputs as `settings.splits` asks.
pub fn bounds_with(net: &Network, input: &[Interval], settings: &Settings, time_var: bool, activate: &Activate) -> Result<Vec<Interval>> {
    check_box(net, input)?;
    let models = Models::from_box(input, settings, time_var)?;
    // Splits of inputs that are polynomial variables, as (variable, pieces).
    let mut pending = Vec::new();
    for &(i, pieces) in &settings.splits {
        if i >= input.len() {
            return Err(NetworkError::input(format!("cannot split input {i}: the network has {} inputs", input.len())));
        }
        match models.variables.iter().find(|t| t.0 == i) {
            Some(&(_, v, _, _)) if pieces > 1 => pending.push((v, pieces)),
            Some(_) => {}
            None if pieces > 1 && input[i].lo() < input[i].hi() => {
                return Err(NetworkError::input(format!(
                    "cannot split input {i}: only the {} widest inputs are polynomial variables; raise max_vars",
                    settings.max_vars
                )))
            }
            None => {}
        }
    }
    run(net, models, 0, &pending, settings.back_substitution(), activate)
}

/// Layers from `start` on; splits a pending variable at the first nonlinear layer using it. The
/// bounds are the output models' ranges, intersected with the last layer's back-substituted
/// ranges where the layers since the last smooth one allow it.
fn run(
    net: &Network,
    mut models: Models,
    start: usize,
    pending: &[(usize, usize)],
    back_substitution: Option<usize>,
    activate: &Activate,
) -> Result<Vec<Interval>> {
    let mut crown = back_substitution.map(|steps| (steps, None));
    let mut last = None;
    for index in start..net.layers().len() {
        let layer = &net.layers()[index];
        let pre = models.affine(layer)?;
        if let Some(pos) = pending.iter().position(|&(v, _)| !layer.is_affine() && pre.nonlinear_depends_on(v, &layer.activations)) {
            let (v, pieces) = pending[pos];
            let rest: Vec<(usize, usize)> = pending.iter().enumerate().filter(|&(k, _)| k != pos).map(|(_, &p)| p).collect();
            let parts: Vec<Result<Vec<Interval>>> = (0..pieces)
                .into_par_iter()
                .map(|piece| {
                    let a = -1.0 + 2.0 * piece as f64 / pieces as f64;
                    let b = if piece + 1 == pieces { 1.0 } else { -1.0 + 2.0 * (piece + 1) as f64 / pieces as f64 };
                    let c = 0.5 * a + 0.5 * b;
                    let r = (b - c).max(c - a).next_up();
                    let sub = pre.substitute(v, c, r);
                    let after = activate(&sub, layer, index + 1, None)?;
                    run(net, after, index + 1, &rest, back_substitution, activate)
                })
                .collect();
            let mut hull: Option<Vec<Interval>> = None;
            for part in parts {
                let part = part?;
                hull = Some(match hull {
                    None => part,
                    Some(h) => h.iter().zip(&part).map(|(a, b)| a.hull(b)).collect(),
                });
            }
            return Ok(hull.expect("at least one piece"));
        }
        let final_layer = index + 1 == net.layers().len();
        (models, last) = layer_step(&models, layer, index + 1, &mut crown, final_layer, activate)?;
    }
    let mut bounds = models.output_map(net.scale(), net.offset()).bounds();
    if let Some(ranges) = last {
        let layer = &net.layers()[net.layers().len() - 1];
        for (i, (b, z)) in bounds.iter_mut().zip(ranges).enumerate() {
            let mut y = if layer.activations[i] == Activation::Relu { z.max(&Interval::ZERO) } else { z };
            if let Some(s) = net.scale() {
                y = y * Interval::point(s[i]);
            }
            if let Some(o) = net.offset() {
                y = y + Interval::point(o[i]);
            }
            let tighter = b.intersect(&y);
            if !tighter.is_empty() {
                *b = tighter;
            }
        }
    }
    Ok(bounds)
}

fn check_box(net: &Network, input: &[Interval]) -> Result<()> {
    if input.len() != net.n_in() {
        return Err(NetworkError::input(format!("the network takes {} inputs but the box has {} intervals", net.n_in(), input.len())));
    }
    Ok(())
}

/// Sound output bounds over a box by direct Taylor-model propagation, intersected with the
/// naive interval bounds (cheap, and tighter when the box is too wide for polynomials).
pub fn bounds(net: &Network, input: &[Interval], settings: &Settings) -> Result<Vec<Interval>> {
    settings.validate()?;
    let models = bounds_with(net, input, settings, false, &|m: &Models, layer: &Layer, _, ranges| activate(m, layer, settings, ranges))?;
    Ok(models.iter().zip(interval_bounds(net, input)?).map(|(a, b)| a.intersect(&b)).collect())
}

/// Sound output bounds over a box, refined by branch and bound on the input: up to `leaves`
/// sub-boxes, each bounded by [`bounds`], the result their hull. A ReLU network's relaxations
/// are loose where many neurons change sign over the box (their gaps add up layer by layer), and
/// halving the box where it matters shrinks them far more than any single relaxation can. Each
/// round takes the output bound (an output's lower or upper end) that lies farthest beyond the
/// values seen at points of the box (leaf centres and probes, float evaluations: they only steer,
/// soundness rests on the leaves' bounds, which cover the box), and halves the leaf that attains
/// it along the input to which that output is most sensitive there (central difference over
/// the leaf); a child's bounds are intersected with its parent's, which contain its range too.
pub fn refined_bounds(net: &Network, input: &[Interval], settings: &Settings, leaves: usize) -> Result<Vec<Interval>> {
    let root = bounds(net, input, settings)?;
    if leaves <= 1 {
        return Ok(root);
    }
    let n_out = net.n_out();
    let mut seen = vec![(f64::INFINITY, f64::NEG_INFINITY); n_out];
    fn observe(y: &[f64], seen: &mut [(f64, f64)]) {
        for (s, &v) in seen.iter_mut().zip(y) {
            *s = (s.0.min(v), s.1.max(v));
        }
    }
    let centre = |cell: &[Interval]| cell.iter().map(|b| b.mid()).collect::<Vec<f64>>();
    observe(&net.eval(&centre(input))?, &mut seen);
    let mut cells: Vec<(Vec<Interval>, Vec<Interval>)> = vec![(input.to_vec(), root)];
    while cells.len() < leaves {
        // The output end farthest beyond the values seen, relative to the seen spread.
        let mut worst: Option<(f64, usize, usize)> = None;
        for j in 0..n_out {
            let spread = (seen[j].1 - seen[j].0).max(1e-12);
            let (lo_leaf, lo) = (0..cells.len()).map(|k| (k, cells[k].1[j].lo())).min_by(|a, b| a.1.total_cmp(&b.1)).expect("a leaf");
            let (hi_leaf, hi) = (0..cells.len()).map(|k| (k, cells[k].1[j].hi())).max_by(|a, b| a.1.total_cmp(&b.1)).expect("a leaf");
            for (gap, leaf) in [((seen[j].0 - lo) / spread, lo_leaf), ((hi - seen[j].1) / spread, hi_leaf)] {
                if gap > worst.map_or(0.0, |w| w.0) {
                    worst = Some((gap, j, leaf));
                }
            }
        }
        let Some((_, j, leaf)) = worst else { break };
        let (cell, parent) = cells.swap_remove(leaf);
        let c = centre(&cell);
        observe(&net.eval(&c)?, &mut seen);
        // The input along which output j moves most over the leaf (central difference).
        let mut best = (f64::NEG_INFINITY, usize::MAX);
        for d in (0..cell.len()).filter(|&d| cell[d].lo() < cell[d].hi()) {
            let (mut a, mut b) = (c.clone(), c.clone());
            a[d] = cell[d].lo();
            b[d] = cell[d].hi();
            let (ya, yb) = (net.eval(&a)?, net.eval(&b)?);
            observe(&ya, &mut seen);
            observe(&yb, &mut seen);
            let effect = (yb[j] - ya[j]).abs() + 1e-9 * cell[d].width();
            if effect > best.0 {
                best = (effect, d);
            }
        }
        if best.1 == usize::MAX {
            cells.push((cell, parent));
            break;
        }
        let d = best.1;
        let halves: Vec<Vec<Interval>> = [iv(cell[d].lo(), c[d]), iv(c[d], cell[d].hi())]
            .into_iter()
            .map(|piece| {
                let mut h = cell.clone();
                h[d] = piece;
                h
            })
            .collect();
        let bounded: Vec<Result<Vec<Interval>>> = halves.par_iter().map(|h| bounds(net, h, settings)).collect();
        for (h, b) in halves.into_iter().zip(bounded) {
            let b: Vec<Interval> = b?.iter().zip(&parent).map(|(x, p)| x.intersect(p)).collect();
            cells.push((h, b));
        }
    }
    let mut hull = cells[0].1.clone();
    for (_, b) in &cells[1..] {
        hull.iter_mut().zip(b).for_each(|(h, x)| *h = h.hull(x));
    }
    Ok(hull)
}

/// Naive interval bound propagation (the baseline), in midpoint-radius form: per layer a
/// float product W c + b for the centres and |W| r for the radii, the rounding error of the
/// centres bounded by gamma_(n+1) (|W| |c| + |b|); then each activation's (monotone) image.
pub fn interval_bounds(net: &Network, input: &[Interval]) -> Result<Vec<Interval>> {
    check_box(net, input)?;
    if let Some((i, b)) = input.iter().enumerate().find(|(_, b)| b.is_empty() || !b.is_bounded()) {
        return Err(NetworkError::input(format!("input {i}: the interval {b} must be bounded and non-empty")));
    }
    let mut h = input.to_vec();
    for layer in net.layers() {
        let centre: Vec<f64> = h.iter().map(|b| b.mid()).collect();
        let radius: Vec<f64> = h.iter().map(|b| b.radius()).collect();
        let magnitude: Vec<f64> = centre.iter().map(|c| c.abs()).collect();
        let g = gamma(layer.n_in() + 1);
        h = (0..layer.n_out())
            .map(|i| {
                let w = weights_into(layer, i);
                let c = w.iter().zip(&centre).map(|(w, c)| w * c).sum::<f64>() + layer.bias[i];
                let err = mul_up(g, add_up(dot_up(w, &magnitude), layer.bias[i].abs()));
                let z = Interval::point(c).inflate(add_up(dot_up(w, &radius), err));
                match layer.activations[i] {
                    Activation::Sigmoid => z.sigmoid(),
                    Activation::Tanh => z.tanh(),
                    Activation::Relu => z.max(&Interval::ZERO),
                    Activation::Identity => z,
                }
            })
            .collect();
    }
    if let Some(s) = net.scale() {
        h = h.iter().zip(s).map(|(x, &s)| *x * Interval::point(s)).collect();
    }
    if let Some(o) = net.offset() {
        h = h.iter().zip(o).map(|(x, &o)| *x + Interval::point(o)).collect();
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::LayerArrays;

    /// Deterministic numbers in [-1, 1).
    fn noise(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        2.0 * ((*state >> 11) as f64 / (1u64 << 53) as f64) - 1.0
    }

    #[test]
    fn float_horner_encloses_the_activation_of_polynomials() {
        let space = Space::get(2, 4, 0).unwrap();
        let ctx = Ctx::new(space.clone(), 4, 1e-15);
        let mut state = 7;
        for f in [Smooth::Sigmoid, Smooth::Tanh] {
            for scale in [1e-4, 0.3, 2.0, 6.0] {
                let mut coef: Vec<f64> = (0..space.len_upto(4)).map(|k| scale * noise(&mut state) / (1 + space.deg[k]) as f64).collect();
                coef[0] = 3.0 * noise(&mut state);
                let p = TaylorModel { coef: coef.clone(), rem: Interval::ZERO };
                let enc = enclose(f, p.poly_bound(&space), 4, 0.0);
                let out = compose(&enc.coef, enc.centre, enc.scale, &coef, &ctx);
                // No wider than Horner's scheme in Taylor-model arithmetic (same truncation).
                let tau = p.add_constant(-enc.centre).scale(enc.scale);
                let mut reference = TaylorModel::constant(enc.coef[enc.coef.len() - 1]);
                for &a in enc.coef.iter().rev().skip(1) {
                    reference = reference.mul(&tau, &ctx).add_constant(a);
                }
                assert!(out.rem.mag() <= reference.rem.mag() * 1.001 + 1e-15, "{f:?} scale {scale}: {} vs {}", out.rem, reference.rem);
                let model = TaylorModel { coef: out.coef.clone(), rem: out.rem.inflate(enc.err) };
                for _ in 0..400 {
                    let x = [Interval::point(noise(&mut state)), Interval::point(noise(&mut state))];
                    let truth = f.image(p.eval_interval(&space, &x));
                    let value = model.eval_interval(&space, &x);
                    assert!(value.contains_interval(&truth), "{f:?} scale {scale}: {value} misses {truth}");
                }
            }
        }
    }

    /// A random 2 -> `wide` (sigmoid) -> `narrow` (tanh) network and the models after its first
    /// layer on a fixed box: every wide neuron with a symbol of its own.
    fn wide_then_narrow(seed: u64, wide: usize, narrow: usize) -> (Network, Models) {
        let mut state = seed;
        let mut weights = |n_out: usize, n_in: usize| (0..n_out * n_in).map(|_| noise(&mut state)).collect::<Vec<f64>>();
        let layers = vec![
            LayerArrays { n_out: wide, n_in: 2, weight: weights(wide, 2), bias: vec![0.1; wide], activations: vec![Activation::Sigmoid] },
            LayerArrays {
                n_out: narrow,
                n_in: wide,
                weight: weights(narrow, wide),
                bias: vec![0.0; narrow],
                activations: vec![Activation::Tanh],
            },
        ];
        let net = Network::new(layers, None, None).unwrap();
        let settings = Settings { order: 3, symbol_min: 0.0, ..Settings::default() };
        let input = [Interval::new(-1.0, 1.0).unwrap(), Interval::new(0.5, 1.5).unwrap()];
        let pre = Models::from_box(&input, &settings, false).unwrap().affine(&net.layers()[0]).unwrap();
        let first = activate(&pre, &net.layers()[0], &settings, None).unwrap();
        assert!(first.own.is_some() && first.symbols() == wide, "every sigmoid neuron has its own symbol");
        (net, first)
    }

    /// Branch and bound on the input: the hull of the leaves' bounds contains every sampled output,
    /// and is never wider than the bounds of the whole box (children are intersected with parents).
    #[test]
    fn refined_bounds_enclose_samples_and_tighten() {
        let mut state = 11;
        let mut weights = |n_out: usize, n_in: usize| (0..n_out * n_in).map(|_| noise(&mut state)).collect::<Vec<f64>>();
        let layers = vec![
            LayerArrays { n_out: 24, n_in: 3, weight: weights(24, 3), bias: vec![0.1; 24], activations: vec![Activation::Relu] },
            LayerArrays { n_out: 24, n_in: 24, weight: weights(24, 24), bias: vec![-0.05; 24], activations: vec![Activation::Relu] },
            LayerArrays { n_out: 2, n_in: 24, weight: weights(2, 24), bias: vec![0.0; 2], activations: vec![Activation::Identity] },
        ];
        let net = Network::new(layers, None, None).unwrap();
        let input = [iv(-0.5, 0.5), iv(0.2, 1.2), iv(-1.0, 0.0)];
        let settings = Settings::default();
        let whole = bounds(&net, &input, &settings).unwrap();
        let refined = refined_bounds(&net, &input, &settings, 128).unwrap();
        let mut state = 12;
        for _ in 0..5000 {
            let x: Vec<f64> = input.iter().map(|b| b.mid() + b.radius() * noise(&mut state)).collect();
            for (y, b) in net.eval(&x).unwrap().iter().zip(&refined) {
                assert!(b.contains(*y), "{y} outside {b}");
            }
        }
        for (r, w) in refined.iter().zip(&whole) {
            assert!(r.lo() >= w.lo() && r.hi() <= w.hi(), "{r} wider than {w}");
        }
        assert!(refined.iter().zip(&whole).any(|(r, w)| r.width() < 0.9 * w.width()), "128 leaves must tighten: {refined:?} vs {whole:?}");
    }

    #[test]
    fn own_symbols_give_the_bounds_of_their_dense_rows() {
        // A wide layer creates one symbol per neuron; the next affine map must see them exactly
        // as if they were rows of the coefficient matrix.
        let (net, first) = wide_then_narrow(3, 40, 3);
        let own = first.affine(&net.layers()[1]).unwrap();
        let dense = first.materialized().affine(&net.layers()[1]).unwrap();
        assert_eq!(own.symbols(), dense.symbols());
        for (a, b) in own.bounds().iter().zip(dense.bounds()) {
            assert!((a.lo() - b.lo()).abs() <= 1e-12 && (a.hi() - b.hi()).abs() <= 1e-12, "{a} vs {b}");
        }
    }

    /// The support function of neuron combinations w over the symbols: max of sum_i w_i (shared
    /// and own symbol part of neuron i) over all symbol values in [-1, 1].
    fn support(models: &Models, w: &[f64]) -> f64 {
        let m = models.m;
        let shared: f64 =
            (m..models.coef.nrows()).map(|k| w.iter().enumerate().map(|(i, wi)| wi * models.column(i)[k]).sum::<f64>().abs()).sum();
        shared + w.iter().enumerate().map(|(i, wi)| (wi * models.own_mag(i)).abs()).sum::<f64>()
    }

    #[test]
    fn narrow_layers_box_minor_symbols_per_neuron() {
        let (net, first) = wide_then_narrow(5, 120, 6);
        let mut state = 6;
        let pre = first.affine(&net.layers()[1]).unwrap();
        assert_eq!(pre.symbols(), 120);
        assert!(box_minor_symbols(&pre, 200).is_none(), "nothing to box");
        let reduced = box_minor_symbols(&pre, 10).expect("6 neurons, 120 symbols: narrow");
        assert_eq!(reduced.symbols(), 10 + 6);
        assert_eq!(reduced.poly(3), pre.poly(3));
        // Each neuron keeps its magnitude (its activation is unchanged) ...
        for i in 0..6 {
            let (a, b) = (pre.sym_mag(i), reduced.sym_mag(i));
            assert!((a - b).abs() <= a * 1e-12, "neuron {i}: {a} -> {b}");
        }
        // ... and the reduced zonotope contains the original one: its support function is at
        // least as large in every direction of the neurons.
        let mut directions: Vec<Vec<f64>> = (0..6).map(|i| (0..6).map(|j| if i == j { 1.0 } else { 0.0 }).collect()).collect();
        directions.extend((0..500).map(|_| (0..6).map(|_| noise(&mut state)).collect()));
        let mut looser = 0;
        for w in &directions {
            let (h, g) = (support(&pre, w), support(&reduced, w));
            assert!(h <= g * (1.0 + 1e-12), "{w:?}: {h} > {g}");
            looser += (g > h * 1.001) as usize;
        }
        assert!(looser > 0, "boxing 110 of 120 symbols must lose some correlation");
    }
}
