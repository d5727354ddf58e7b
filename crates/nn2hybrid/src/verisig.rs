//! The Verisig translation: a sigmoid or tanh neuron is the solution at t = 1 of
//!   sigmoid: dz/dt = a z (1 - z), z(0) = 1/2;   tanh: dz/dt = a (1 - z^2), z(0) = 0,
//! with a the neuron's pre-activation held constant (a' = 0). Verisig makes each layer one
//! hybrid-automaton mode over all its neurons, with the affine maps as resets between modes;
//! here the resets are the same exact matrix products as in [`crate::propagate`], and the mode
//! is integrated neuron by neuron (each neuron's ODE depends only on its own a, so this is the
//! same flow, and the neurons run in parallel).
//!
//! Integration is a Taylor-model Picard loop over the input variables plus a normalised time
//! variable s in [0, 1] per step of length h: the polynomial part comes from k Picard
//! iterations p <- z0 + h int_0^s f(a, p), and its remainder is verified by Schauder's theorem
//! (the Picard operator maps p + I into p + J with J inside I), a's own remainder included, so
//! the flow is enclosed for every value of a. The state at s = 1 starts the next step. The
//! initial state is exact and a is time-invariant, so no preconditioning is needed: the models
//! stay functions of the network inputs throughout, as in Verisig's Flow* runs with parameters.
//! The integration works at twice the network's order: in (x, s) the time variable uses up
//! degrees (sigmoid(a t) has terms (a t)^j of degree 2j), and truncating at the network's order
//! would throw the x^j s terms of every step into the remainder; z(1) is truncated back at the end.
//! ReLU neurons (for which Verisig switches modes) use the direct method's relaxation.
use crate::activation::Smooth;
use crate::error::{NetworkError, Result};
use crate::network::{Layer, Network};
use crate::propagate::{activate_with, bounds_with, propagate_with, Models, NeuronOut, Settings};
use taylor::{Ctx, Interval, TaylorModel};

/// Steps per unit of |a| (the local rate): the solution's Taylor radius in t is pi / |a| for
/// sigmoid and pi / (2 |a|) for tanh; steps of a tenth of that keep the truncation tiny.
const RATE_STEP: f64 = 0.3;
/// Halvings of a step before the neuron is given up.
const MAX_HALVINGS: usize = 12;
/// Most steps per neuron.
const MAX_STEPS: usize = 100_000;

fn rhs(f: Smooth, a: &TaylorModel, z: &TaylorModel, ctx: &Ctx) -> TaylorModel {
    match f {
        Smooth::Sigmoid => a.mul(&z.mul(&TaylorModel::constant(1.0).sub(z), ctx), ctx),
        Smooth::Tanh => a.mul(&TaylorModel::constant(1.0).sub(&z.square(ctx)), ctx),
    }
}

/// One step of length h from z0; the enclosure of z over the step, as a model in (x, s).
fn step(f: Smooth, a: &TaylorModel, z0: &TaylorModel, h: f64, t: usize, ctx: &Ctx) -> Option<TaylorModel> {
    let poly = |m: &TaylorModel| TaylorModel { coef: m.coef.clone(), rem: Interval::ZERO };
    let (a_poly, z0_poly) = (poly(a), poly(z0));
    let mut p = z0_poly.clone();
    for _ in 0..ctx.order {
        p = poly(&z0_poly.add(&rhs(f, &a_poly, &p, ctx).integrate(t, ctx).scale(h)));
    }
    // The Picard operator on p + I, with a's and z0's remainders: its image is p + J.
    let apply = |rem: Interval| -> Interval {
        let z = TaylorModel { coef: p.coef.clone(), rem };
        let image = z0.add(&rhs(f, a, &z, ctx).integrate(t, ctx).scale(h));
        image.rem + poly(&image).sub(&p).bound(&ctx.space)
    };
    let mut guess = Interval::symmetric(1e-12 + z0.rem.mag());
    for _ in 0..8 {
        let image = apply(guess);
        if !image.is_bounded() {
            return None;
        }
        if guess.contains_interval(&image) {
            // Every re-application of the operator is again an enclosure: refine once.
            let refined = apply(image).intersect(&image);
            let rem = if refined.is_empty() { image } else { refined };
            return Some(TaylorModel { coef: p.coef, rem });
        }
        let hull = guess.hull(&image);
        guess = hull.inflate(0.5 * hull.width());
    }
    None
}

/// d f / d z over a range of z and a: a (1 - 2z) for sigmoid, -2 a z for tanh.
fn slope(f: Smooth, a: Interval, z: Interval) -> Interval {
    match f {
        Smooth::Sigmoid => a * (Interval::ONE - Interval::point(2.0) * z),
        Smooth::Tanh => Interval::point(-2.0) * a * z,
    }
}

/// One verified step of length h from z0, or None. The step starts from z0's polynomial only;
/// z0's remainder R is carried by the mean value theorem: the flow maps z0 + d to
/// z(h; z0) + d exp(int_0^h df/dz), and the exponent is bounded over an enclosure of every
/// trajectory from z0 + hull(R, 0). Pushing R through the Picard operator instead would inflate
/// it by (1 + h |a|) per step even where the flow contracts (by e^20 over [0, 1] for a = -20).
fn carry(f: Smooth, a: &TaylorModel, z0: &TaylorModel, h: f64, t: usize, ctx: &Ctx) -> Option<TaylorModel> {
    let poly = TaylorModel { coef: z0.coef.clone(), rem: Interval::ZERO };
    let mut left = step(f, a, &poly, h, t, ctx)?;
    if z0.rem != Interval::ZERO {
        let all = TaylorModel { coef: z0.coef.clone(), rem: z0.rem.hull(&Interval::ZERO) };
        let range = step(f, a, &all, h, t, ctx)?.bound(&ctx.space);
        let gain = (Interval::point(h) * slope(f, a.bound(&ctx.space), range)).exp();
        left.rem = left.rem + z0.rem * gain;
    }
    Some(left)
}

/// z(1) for one neuron with pre-activation a (a model over the inputs, remainder included).
fn integrate(f: Smooth, a: &TaylorModel, ctx: &Ctx, t: usize) -> std::result::Result<TaylorModel, String> {
    let rate = a.bound(&ctx.space).mag() * if f == Smooth::Tanh { 2.0 } else { 1.0 };
    // Powers of two as steps: every time reached is a dyadic rational, so the steps add up to
    // exactly 1 in floating point and z is read at t = 1, not near it.
    let mut h = if rate > RATE_STEP { 0.5f64.powi((rate / RATE_STEP).log2().ceil() as i32) } else { 1.0 };
    let mut z = TaylorModel::constant(if f == Smooth::Sigmoid { 0.5 } else { 0.0 });
    let mut time = 0.0;
    let mut steps = 0;
    while time < 1.0 {
        let h_try = h.min(1.0 - time);
        let mut halvings = 0;
        let mut trial = h_try;
        let left = loop {
            if let Some(left) = carry(f, a, &z, trial, t, ctx) {
                break left;
            }
            halvings += 1;
            if halvings > MAX_HALVINGS {
                return Err(format!("no step from t = {time} could be verified (pre-activation range {})", a.bound(&ctx.space)));
            }
            trial *= 0.5;
        };
        z = left.substitute(t, Interval::ONE, ctx);
        // The true z stays in (0, 1) or (-1, 1): a remainder as wide as that has lost the flow,
        // and it only grows from there (outside the range the ODEs are unstable).
        if z.rem.width() > 1.0 {
            return Err(format!("the enclosure of z diverged (remainder {}) at t = {}", z.rem, time + trial));
        }
        // TwoSum: the new time must be the exact sum, else z would be read off t = 1.
        let next = time + trial;
        let back = next - time;
        if (time - (next - back)) + (trial - back) != 0.0 {
            return Err(format!("the time steps no longer add up exactly at t = {time} (steps of {trial})"));
        }
        time = next;
        if halvings > 0 {
            // Next steps: the largest power of two not above the verified step.
            h = h.min(2f64.powi(trial.log2().floor() as i32));
        }
        steps += 1;
        if steps > MAX_STEPS {
            return Err(format!("more than {MAX_STEPS} steps needed"));
        }
    }
    Ok(z)
}

/// The Verisig activation of one layer: every sigmoid/tanh neuron through its ODE.
fn activate(models: &Models, layer: &Layer, index: usize, settings: &Settings) -> Result<Models> {
    let t = models.time_var().ok_or_else(|| NetworkError::input("Verisig propagation needs models with a time variable; build them with Models::with_time_var"))?;
    let ctx = &models.ctx;
    let wide = ctx.with_order(2 * ctx.order);
    activate_with(models, layer, settings, &|f, m: &Models, i| {
        let a = TaylorModel { coef: m.poly(i).to_vec(), rem: m.rem[i].inflate(m.sym_mag(i)) };
        let mut z = integrate(f, &a, &wide, t).map_err(|reason| NetworkError::Integration { layer: index, neuron: i + 1, reason })?;
        z.sweep(ctx);
        let error = z.rem;
        z.rem = Interval::ZERO;
        // The ODE's enclosure already holds every symbol's effect: the old symbols are dropped.
        Ok(NeuronOut { poly: z, sym_factor: 0.0, error, symbolic: false })
    })
}

fn verisig_settings(settings: &Settings) -> Result<Settings> {
    settings.validate()?;
    if 2 * settings.order > taylor::space::MAX_ORDER {
        return Err(NetworkError::input(format!("the Verisig translation integrates at twice the order: use order <= {}", taylor::space::MAX_ORDER / 2)));
    }
    Ok(Settings { symbolic: false, ..settings.clone() })
}

/// Sound output bounds over a box through the Verisig translation.
pub fn bounds(net: &Network, input: &[Interval], settings: &Settings) -> Result<Vec<Interval>> {
    let s = verisig_settings(settings)?;
    bounds_with(net, input, &s, true, &|m: &Models, layer: &Layer, index| activate(m, layer, index, &s))
}

/// Models propagated through the Verisig translation (a time variable is added if missing).
pub fn propagate(net: &Network, input: &Models, settings: &Settings) -> Result<Models> {
    let s = verisig_settings(settings)?;
    propagate_with(net, &input.with_time_var()?, &|m: &Models, layer: &Layer, index| activate(m, layer, index, &s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use taylor::Space;

    #[test]
    fn neuron_odes_enclose_the_activation() {
        let space = Space::get(2, 10, 0b10).unwrap();
        let ctx = Ctx::new(space.clone(), 10, 1e-15);
        for f in [Smooth::Sigmoid, Smooth::Tanh] {
            for (c, r) in [(0.0, 1.0), (3.0, 0.5), (-20.0, 0.3), (20.0, 0.3), (7.0, 2.0)] {
                let a = TaylorModel::affine(&ctx, c, 0, r);
                let z = integrate(f, &a, &ctx, 1).unwrap_or_else(|e| panic!("{f:?} a = {c} +- {r}: {e}"));
                for i in 0..=200 {
                    let x = -1.0 + i as f64 / 100.0;
                    let y = c + r * x;
                    let truth = if f == Smooth::Sigmoid { 1.0 / (1.0 + (-y).exp()) } else { y.tanh() };
                    let e = z.eval_interval(&space, &[Interval::point(x), Interval::ONE]);
                    assert!(e.contains(truth), "{f:?} at a = {y}: {e} misses {truth}");
                }
                // Truncation in x is Taylor-like (no Chebyshev economization): tight on narrow a.
                if r <= 0.5 {
                    assert!(z.rem.width() < 1e-4, "{f:?} a = {c} +- {r}: remainder {}", z.rem);
                }
            }
        }
    }
}
