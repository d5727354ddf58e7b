//! The Verisig translation: a sigmoid or tanh neuron is the solution at t = 1 of
//!   sigmoid: dz/dt = a z (1 - z), z(0) = 1/2;   tanh: dz/dt = a (1 - z^2), z(0) = 0,
//! with a the neuron's pre-activation held constant (a' = 0). Verisig makes each layer one
//! hybrid-automaton mode over all its neurons, with the affine maps as resets between modes;
//! here the resets are the same exact matrix products as in [`crate::propagate`], and each mode
//! is integrated by the `taylor` flowpipe engine ([`taylor::flowpipe::reach_from_naive_box`]) as
//! one small ODE per neuron, states (z, a), the neurons in parallel (rayon). Each neuron's ODE
//! depends only on its own a, so this is the same flow as the layer's ODE over all (z_i, a_i);
//! one ODE of the whole layer would need 2 x width state variables (up to 1,200 for a 600-wide
//! layer, where a Taylor-model space holds 32 variables) and would precondition and compose
//! every neuron in all the others' variables at every step.
//!
//! The flowpipe starts from Taylor models over the network's inputs (a from the affine reset,
//! its error symbols folded into the remainder; z(0) the constant), in a space of its own with
//! time as variable 0 and the inputs shifted up by one, and returns z(1) as a Taylor model over
//! the same inputs (Flow*'s preconditioning and composition per step, its symbolic remainders
//! carrying each step's remainder through the flow's linear part at the set's centre). The
//! models' time variable is not used; their other [0, 1] variables (a closed loop's time) range over [-1, 1] in the
//! flow space: the enclosure then holds on a larger domain, which is sound.
//! Steps are powers of two, so every time reached is exact and z is read at t = 1, not near
//! it; the step is the largest power of two with h |a| (2 h |a| for tanh, whose Taylor radius in
//! t is half of sigmoid's) below `RATE_STEP`. The integration works at twice the network's
//! order: in (x, t) the solution's terms (a t)^j have degree 2j, and truncating at the network's
//! order would throw them into the remainder at every step; z(1) is truncated back at the end.
//! A neuron whose flowpipe fails or diverges is redone once with half the step and the order
//! raised by `RAISE` (where the flow space stays small); then the error names the layer,
//! neuron and pre-activation range. Wide pre-activations are where this method ends: sigmoid(a)
//! has poles at a = +-i pi (tanh at +-i pi / 2), so over a = c + r x its Taylor series in x
//! converges only for |x| < |c + i pi| / r (|c + i pi / 2| / r), and once that is below 1 no
//! polynomial in x follows the neuron (a in [-8, 8] fails as one piece, works in 16).
//! ReLU neurons (for which Verisig switches modes) use the direct method's relaxation.
use crate::activation::Smooth;
use crate::error::{NetworkError, Result};
use crate::network::{Layer, Network};
use crate::propagate::{activate_with, bounds_with, propagate_with, Models, NeuronOut, Settings};
use std::sync::Arc;
use taylor::flowpipe::{reach_from_naive_box, Ode, OrderPolicy, Settings as FlowSettings, StepSize};
use taylor::parser::parse_expr;
use taylor::{Ctx, Interval, Precondition, Space, TaylorModel};

/// Largest h |a| per step: the solution's Taylor radius in t is pi / |a| (sigmoid).
const RATE_STEP: f64 = 0.3;
/// Order added for a neuron's second attempt (half the step, this much higher order): wide
/// pre-activations lose the flow to truncation, which a smaller step alone does not cure.
const RAISE: usize = 4;
/// Largest flow space (monomials) the raised order may use; beyond, the retry keeps the order.
const MAX_TERMS: usize = 4000;

/// One layer's neuron modes: the two ODEs and the flow space the neurons' models move to.
struct Mode {
    sigmoid: Ode,
    tanh: Ode,
    /// Time is variable 0; models variable v is flow variable v + 1.
    flow: Arc<Space>,
    /// The network's order, the integration's (twice it) and the retry's.
    order: usize,
    flow_order: usize,
    retry_order: usize,
    cutoff: f64,
    /// Flow index of each monomial of the models' polynomials (None: it uses the time variable).
    to_flow: Vec<Option<usize>>,
    /// Models index of each flow monomial of degree <= the network's order without time.
    from_flow: Vec<Option<usize>>,
}

/// Number of monomials of degree <= order in n variables.
fn terms(n: usize, order: usize) -> usize {
    (1..=n).fold(1, |acc, i| acc * (order + i) / i)
}

impl Mode {
    fn new(models: &Models, cutoff: f64) -> Result<Mode> {
        let t = models.time_var().ok_or_else(|| {
            NetworkError::input("Verisig propagation needs models with a time variable; build them with Models::with_time_var")
        })?;
        let space = models.space();
        if t + 1 != space.nvars {
            return Err(NetworkError::input("the Verisig time variable must be the models' last variable"));
        }
        // reach_from needs more variables than the ODE's 2 states (their normalised copies).
        let nvars = (t + 1).max(3);
        // The models' own order (inputs from another propagation may have a higher one).
        let order = models.ctx.order;
        let flow_order = 2 * order;
        let raised = (flow_order + RAISE).min(taylor::space::MAX_ORDER);
        let retry_order = if terms(nvars, raised) <= MAX_TERMS { raised } else { flow_order };
        let flow = Space::get(nvars, retry_order, 1)?;
        let len = space.len_upto(order);
        // Monomial i = monomial j times x_v: its index follows from its parent's.
        let mut to_flow: Vec<Option<usize>> = vec![Some(0)];
        for i in 1..len {
            let (j, v) = space.parent(i);
            to_flow.push(if v == t { None } else { to_flow[j].and_then(|k| flow.times_var(k, v + 1)) });
        }
        let mut from_flow: Vec<Option<usize>> = vec![Some(0)];
        for i in 1..flow.len_upto(order) {
            let (j, v) = flow.parent(i);
            from_flow.push(if v == 0 { None } else { from_flow[j].and_then(|k| space.times_var(k, v - 1)) });
        }
        let ode = |rhs: &str| Ode::new(vec!["z".into(), "a".into()], vec![parse_expr(rhs)?, parse_expr("0")?]);
        Ok(Mode {
            sigmoid: ode("a*z*(1 - z)")?,
            tanh: ode("a*(1 - z^2)")?,
            flow,
            order,
            flow_order,
            retry_order,
            cutoff,
            to_flow,
            from_flow,
        })
    }

    /// z(1) for one neuron with pre-activation a (a model over the inputs, remainder included),
    /// as a model in the models' space at the network's order.
    fn integrate(&self, f: Smooth, a: &TaylorModel) -> std::result::Result<TaylorModel, String> {
        let mut coef = vec![0.0; self.flow.len_upto(self.order)];
        for (i, &c) in a.coef.iter().enumerate().filter(|(_, &c)| c != 0.0) {
            let k = self.to_flow.get(i).copied().flatten().ok_or("a pre-activation depends on the time variable or exceeds the order")?;
            coef[k] = c;
        }
        let a_flow = TaylorModel { coef, rem: a.rem };
        let range = a_flow.bound(&self.flow);
        let rate = range.mag() * if f == Smooth::Tanh { 2.0 } else { 1.0 };
        let h = if rate > RATE_STEP { 0.5f64.powi((rate / RATE_STEP).log2().ceil() as i32) } else { 1.0 };
        let (ode, z0) = match f {
            Smooth::Sigmoid => (&self.sigmoid, 0.5),
            Smooth::Tanh => (&self.tanh, 0.0),
        };
        let mut reason = String::new();
        for (h, order) in [(h, self.flow_order), (0.5 * h, self.retry_order)] {
            let settings = FlowSettings {
                step: StepSize::Fixed(h),
                order: OrderPolicy::Fixed(order),
                t_end: 1.0,
                cutoff: self.cutoff,
                remainder_estimate: vec![1e-12; 2],
                precondition: Precondition::Identity,
                refinements: 4,
                symbolic_queue: 128,
            };
            let state = vec![TaylorModel::constant(z0), a_flow.clone()];
            let fp = reach_from_naive_box(ode, state, &self.flow, &settings, &mut |_| true).map_err(|e| e.to_string())?;
            let mut z = fp.final_state.into_iter().next().expect("two states");
            // The true z stays in (0, 1) or (-1, 1): a remainder as wide as that has lost the
            // flow (and outside that range the ODEs are unstable).
            reason = if z.rem.width() > 1.0 {
                format!("the enclosure of z diverged (remainder {} at t = {})", z.rem, fp.time_reached)
            } else if let Some(failure) = fp.failure {
                failure.to_string()
            } else {
                z.sweep(&Ctx::new(self.flow.clone(), self.order, self.cutoff));
                return self.to_models(&z);
            };
            reason = format!("{reason} (pre-activation range {range}, steps of {h}, order {order})");
        }
        Err(reason)
    }

    /// A flow model without time, of degree <= the network's order, in the models' space.
    fn to_models(&self, z: &TaylorModel) -> std::result::Result<TaylorModel, String> {
        let mut out = TaylorModel { coef: vec![], rem: z.rem };
        for (i, &c) in z.coef.iter().enumerate().filter(|(_, &c)| c != 0.0) {
            let k = self.from_flow[i].ok_or("z(1) depends on the flow's time variable")?;
            if out.coef.len() <= k {
                out.coef.resize(k + 1, 0.0);
            }
            out.coef[k] = c;
        }
        Ok(out)
    }
}

/// The Verisig activation of one layer: every sigmoid/tanh neuron through its ODE.
fn activate(models: &Models, layer: &Layer, index: usize, settings: &Settings, ranges: Option<&[Interval]>) -> Result<Models> {
    if layer.is_affine() {
        return Ok(models.clone());
    }
    let mode = Mode::new(models, settings.cutoff)?;
    activate_with(
        models,
        layer,
        settings,
        &|f, m: &Models, i| {
            let a = TaylorModel { coef: m.poly(i).to_vec(), rem: m.rem[i].inflate(m.sym_mag(i)) };
            let mut z = mode.integrate(f, &a).map_err(|reason| NetworkError::Integration { layer: index, neuron: i + 1, reason })?;
            let error = z.rem;
            z.rem = Interval::ZERO;
            // The ODE's enclosure already holds every symbol's effect: the old symbols are dropped.
            Ok(NeuronOut { poly: z, sym_factor: 0.0, error, symbolic: false })
        },
        ranges,
    )
}

fn verisig_settings(settings: &Settings) -> Result<Settings> {
    settings.validate()?;
    if 2 * settings.order > taylor::space::MAX_ORDER {
        return Err(NetworkError::input(format!(
            "the Verisig translation integrates at twice the order: use order <= {}",
            taylor::space::MAX_ORDER / 2
        )));
    }
    Ok(Settings { symbolic: false, ..settings.clone() })
}

/// Sound output bounds over a box through the Verisig translation.
pub fn bounds(net: &Network, input: &[Interval], settings: &Settings) -> Result<Vec<Interval>> {
    let s = verisig_settings(settings)?;
    bounds_with(net, input, &s, true, &|m: &Models, layer: &Layer, index, ranges| activate(m, layer, index, &s, ranges))
}

/// Models propagated through the Verisig translation (a time variable is added if missing).
pub fn propagate(net: &Network, input: &Models, settings: &Settings) -> Result<Models> {
    let s = verisig_settings(settings)?;
    propagate_with(net, &input.with_time_var()?, s.back_substitution(), &|m: &Models, layer: &Layer, index, ranges| {
        activate(m, layer, index, &s, ranges)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn activation(f: Smooth, y: f64) -> f64 {
        if f == Smooth::Sigmoid {
            1.0 / (1.0 + (-y).exp())
        } else {
            y.tanh()
        }
    }

    /// The neuron's enclosure for a = c + r x over x in [-1, 1] (one input and the time variable),
    /// checked at 401 points; returns its remainder's width.
    fn check(mode: &Mode, space: &Space, ctx: &Ctx, f: Smooth, c: f64, r: f64) -> std::result::Result<f64, String> {
        let z = mode.integrate(f, &TaylorModel::affine(ctx, c, 0, r))?;
        for i in 0..=400 {
            let x = -1.0 + i as f64 / 200.0;
            let truth = activation(f, c + r * x);
            let e = z.eval_interval(space, &[Interval::point(x), Interval::ONE]);
            assert!(e.contains(truth), "{f:?} a = {c} +- {r} at x = {x}: {e} misses {truth}");
        }
        Ok(z.rem.width())
    }

    #[test]
    fn neuron_odes_enclose_the_activation() {
        let settings = Settings { order: 5, ..Settings::default() };
        let models = Models::from_box(&[Interval::new(-1.0, 1.0).unwrap()], &settings, true).unwrap();
        let mode = Mode::new(&models, settings.cutoff).unwrap();
        let space = models.space().clone();
        let ctx = Ctx::new(space.clone(), settings.order, settings.cutoff);
        for f in [Smooth::Sigmoid, Smooth::Tanh] {
            // Narrow pre-activations: tight (Taylor-like truncation in x).
            for (c, r) in [(0.5, 1e-6), (2.0, 0.05), (3.0, 0.5), (-20.0, 0.3), (20.0, 0.3)] {
                let width = check(&mode, &space, &ctx, f, c, r).unwrap_or_else(|e| panic!("{f:?} a = {c} +- {r}: {e}"));
                assert!(width < 1e-4, "{f:?} a = {c} +- {r}: remainder width {width}");
            }
            // Wide ones: [-1, 1], [5, 9] and [2.7, 17.1] (an output neuron of a Mountain Car
            // controller, which needs the retry at a higher order).
            for (c, r) in [(0.0, 1.0), (7.0, 2.0), (9.93, 7.19)] {
                check(&mode, &space, &ctx, f, c, r).unwrap_or_else(|e| panic!("{f:?} a = {c} +- {r}: {e}"));
            }
            // a = 8 x over [-1, 1]: f(8 x) has poles at |x| = pi / 8 (pi / 16 for tanh), so no
            // polynomial in x follows it; the method says so, and [-8, 8] in 16 pieces works.
            let e = mode.integrate(f, &TaylorModel::affine(&ctx, 0.0, 0, 8.0)).unwrap_err();
            assert!(e.contains("diverged") || e.contains("could not be enclosed"), "{e}");
            for piece in 0..16 {
                let c = -8.0 + 0.5 + piece as f64;
                check(&mode, &space, &ctx, f, c, 0.5).unwrap_or_else(|e| panic!("{f:?} a = {c} +- 0.5: {e}"));
            }
        }
    }
}
