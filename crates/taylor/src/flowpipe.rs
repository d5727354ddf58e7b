//! Flowpipes of ODEs x' = f(x) by Taylor-model Picard iteration, in the manner of Flow*.
//!
//! Each step works in normalised time s = t / h in [0, 1] (variable 0 of the space) and the
//! normalised state x̂ in [-1, 1]^n (variables 1..=n):
//! 1. precondition the current state into x0(x̂) and right(z) ([`crate::precondition`]);
//! 2. compute the polynomial part p by k Picard iterations p <- x0 + h ∫ f(p), the i-th one
//!    truncated at order i (each iteration fixes one more degree);
//! 3. verify a remainder I by Schauder's theorem: if P(p + I) = x0 + h ∫ f(p + I) ⊆ p + J
//!    with J ⊆ I, the true flow lies in p + J; then refine J by re-applying P (each result
//!    is again an enclosure because the fixed point is in p + J);
//! 4. the reach set over the step is the range of p + J; the state at the step end is
//!    p(1, right(z)) + J by Taylor-model composition.
//!
//! Adaptive step halves on failure and grows by 1.1 after success, as in Flow*. Adaptive order
//! raises the order on failure and keeps it: lowering it after each success (Flow*'s policy)
//! was measured to let low-order truncation errors pile up until no order can recover.
use crate::bound::{bound_all, Bounder};
use crate::error::{Result, TaylorError};
use crate::expr::{Expr, Program, TaylorModels};
use crate::interval::{add_up, mul_up, Interval};
use crate::precondition::{precondition, Precondition};
use crate::space::Space;
use crate::symbolic::{mat_mul, mat_vec, SymbolicRemainder};
// hybrid.rs and bound.rs reach the shared monomial builder here.
use crate::tm::compose_all;
use crate::tm::{Ctx, TaylorModel};
use std::sync::Arc;
use std::time::Instant;

/// A system x' = f(x) with named state variables.
#[derive(Clone, Debug)]
pub struct Ode {
    pub names: Vec<String>,
    pub program: Program,
}

impl Ode {
    pub fn new(names: Vec<String>, rhs: Vec<Expr>) -> Result<Ode> {
        if names.is_empty() {
            return Err(TaylorError::input("an ODE needs at least one state variable"));
        }
        if names.len() != rhs.len() {
            return Err(TaylorError::input(format!(
                "{} state variables but {} right-hand sides; give one equation per variable",
                names.len(),
                rhs.len()
            )));
        }
        let mut seen = std::collections::HashSet::new();
        for n in &names {
            if !seen.insert(n) {
                return Err(TaylorError::input(format!("state variable '{n}' is declared twice")));
            }
        }
        let program = Program::compile(&rhs, &names)?;
        Ok(Ode { names, program })
    }
    pub fn dim(&self) -> usize {
        self.names.len()
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepSize {
    Fixed(f64),
    Adaptive { min: f64, max: f64 },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OrderPolicy {
    Fixed(usize),
    Adaptive { min: usize, max: usize },
}

#[derive(Clone, Debug)]
pub struct Settings {
    pub step: StepSize,
    pub order: OrderPolicy,
    pub t_end: f64,
    pub cutoff: f64,
    /// Initial remainder guess per variable (Flow*'s `remainder estimation`), a half-width.
    pub remainder_estimate: Vec<f64>,
    pub precondition: Precondition,
    /// Most extra applications of the Picard operator to shrink a verified remainder; it stops
    /// earlier once an application shrinks it by less than 1% (Flow*'s stop ratio 0.99).
    pub refinements: usize,
    /// Length of the symbolic remainder queue (Flow*'s `nonpoly ode { N }`).
    pub symbolic_queue: usize,
}

impl Settings {
    fn validate(&self, dim: usize) -> Result<()> {
        let bad = |m: String| Err(TaylorError::input(m));
        match self.step {
            StepSize::Fixed(h) if !(h > 0.0 && h.is_finite()) => return bad(format!("step must be positive, got {h}")),
            StepSize::Adaptive { min, max } if !(min > 0.0 && max >= min && max.is_finite()) => {
                return bad(format!("adaptive steps need 0 < min <= max, got min {min}, max {max}"))
            }
            _ => {}
        }
        match self.order {
            OrderPolicy::Fixed(0) => return bad("order must be at least 1, got 0".into()),
            OrderPolicy::Adaptive { min, max } if min == 0 || max < min => {
                return bad(format!("adaptive orders need 1 <= min <= max, got min {min}, max {max}"))
            }
            _ => {}
        }
        if !(self.t_end >= 0.0 && self.t_end.is_finite()) {
            return bad(format!("time horizon must be finite and non-negative, got {}", self.t_end));
        }
        if !(self.cutoff >= 0.0) {
            return bad(format!("cutoff must be non-negative, got {}", self.cutoff));
        }
        if self.remainder_estimate.len() != dim || self.remainder_estimate.iter().any(|r| !(*r > 0.0 && r.is_finite())) {
            return bad("remainder estimate must be one positive number per state variable".into());
        }
        Ok(())
    }
    /// The highest order a step may use (the space's order must reach it).
    pub fn max_order(&self) -> usize {
        match self.order {
            OrderPolicy::Fixed(k) => k,
            OrderPolicy::Adaptive { max, .. } => max,
        }
    }
}

/// The reach set over one time step [t0, t1], boxed per variable.
#[derive(Clone, Debug)]
pub struct Segment {
    pub t0: f64,
    pub t1: f64,
    pub bounds: Vec<Interval>,
    pub order: usize,
}

#[derive(Clone, Debug, Default)]
pub struct Stats {
    pub steps: usize,
    pub rejected_steps: usize,
    pub seconds: f64,
    pub picard_seconds: f64,
    pub validation_seconds: f64,
    pub composition_seconds: f64,
}

#[derive(Clone)]
pub struct Flowpipe {
    pub names: Vec<String>,
    pub segments: Vec<Segment>,
    /// The state at `time_reached` as Taylor models over the initial set, and its box.
    pub final_state: Vec<TaylorModel>,
    pub final_box: Vec<Interval>,
    pub time_reached: f64,
    /// Why the computation stopped before `t_end`, if it did. Segments so far stay valid.
    pub failure: Option<TaylorError>,
    pub stats: Stats,
    /// The space of `final_state` (variable 0 is time, unused by the final models).
    pub space: Arc<Space>,
}

impl std::fmt::Debug for Flowpipe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Flowpipe")
            .field("names", &self.names)
            .field("segments", &self.segments.len())
            .field("final_box", &self.final_box)
            .field("time_reached", &self.time_reached)
            .field("failure", &self.failure)
            .finish()
    }
}

impl Flowpipe {
    /// The final state's box with the chosen bounder (`final_box` is the dominated one).
    pub fn final_bound(&self, bounder: Bounder) -> Result<Vec<Interval>> {
        bound_all(&self.final_state, &self.space, bounder)
    }
}

/// x = c + r z maps z in [-1, 1] onto a box side (r rounded up, so the image covers it).
pub(crate) fn initial_affine(iv: &Interval) -> (f64, f64) {
    let m = iv.mid();
    (m, (iv.hi() - m).max(m - iv.lo()).next_up())
}

/// The normalised coordinates z (as intervals holding the exact values) of a point of the
/// initial box `init`, as [`reach`] defines them: the arguments at which the final models
/// enclose the state reached from that point. None if the point lies outside the box.
pub fn normalise_initial_point(init: &[Interval], x: &[f64]) -> Option<Vec<Interval>> {
    if x.len() != init.len() || init.iter().zip(x).any(|(iv, &v)| !iv.contains(v)) {
        return None;
    }
    Some(
        init.iter()
            .zip(x)
            .map(|(iv, &v)| {
                if iv.lo() == iv.hi() {
                    return Interval::ZERO;
                }
                let (c, r) = initial_affine(iv);
                let z = (Interval::point(v) - Interval::point(c)) * Interval::point(r).recip().expect("r > 0");
                z.intersect(&Interval::SYMMETRIC)
            })
            .collect(),
    )
}

/// Computes the flowpipe from the box `init`. `observer(t)` is told the time after every
/// step and may return false to stop early (the result is then partial but sound).
pub fn reach(ode: &Ode, init: &[Interval], settings: &Settings, observer: &mut dyn FnMut(f64) -> bool) -> Result<Flowpipe> {
    let n = ode.dim();
    if init.len() != n {
        return Err(TaylorError::input(format!("initial set has {} intervals for {} state variables", init.len(), n)));
    }
    for (name, iv) in ode.names.iter().zip(init) {
        if iv.is_empty() || !iv.is_bounded() {
            return Err(TaylorError::input(format!("initial interval of '{name}' must be bounded and non-empty, got {iv}")));
        }
    }
    settings.validate(n)?;
    let space = Space::get(n + 1, settings.max_order(), 1)?;
    let full = Ctx::new(space.clone(), settings.max_order(), settings.cutoff);
    reach_from(ode, box_models(init, &full), &space, settings, observer)
}

/// The box `init` as models over z in [-1, 1]^n, side i over variable i + 1 (a point side is
/// a constant).
pub(crate) fn box_models(init: &[Interval], ctx: &Ctx) -> Vec<TaylorModel> {
    init.iter()
        .enumerate()
        .map(|(i, iv)| {
            let (m, r) = initial_affine(iv);
            if iv.lo() == iv.hi() {
                TaylorModel::constant(m)
            } else {
                TaylorModel::affine(ctx, m, i + 1, r)
            }
        })
        .collect()
}

/// Computes the flowpipe from a set given as Taylor models over variables 1..=m of `space`
/// (variable 0 must be a unit variable, free for time; `space.nvars` must exceed both m and
/// the ODE's dimension). This is how a closed loop integrates its plant from a state that
/// depends on the cell's variables.
pub fn reach_from(
    ode: &Ode,
    state: Vec<TaylorModel>,
    space: &Arc<Space>,
    settings: &Settings,
    observer: &mut dyn FnMut(f64) -> bool,
) -> Result<Flowpipe> {
    flow_from(ode, state, space, settings, &mut |t, _, _, _| observer(t), crate::bound::range)
}

/// [`reach_from`] that hands `on_step(t, segment, state)` the state at time t (the end of the
/// step, as Taylor models with the symbolic remainder folded in) after every step: hybrid
/// automata take jumps from the states between the segments. Its `final_box` is the naive
/// bound: hybrid runs go on from `final_state` (the dominated bounder there cost most of a run
/// at order 4).
pub fn reach_from_steps(
    ode: &Ode,
    state: Vec<TaylorModel>,
    space: &Arc<Space>,
    settings: &Settings,
    on_step: &mut dyn FnMut(f64, &Segment, Vec<TaylorModel>) -> bool,
) -> Result<Flowpipe> {
    flow_from(ode, state, space, settings, &mut |t, seg, state, _| on_step(t, seg, state()), TaylorModel::bound)
}

/// [`reach_from`] with `final_box` the naive bound of each final model (monomial by monomial,
/// plus remainder) instead of the linear dominated bound: for callers that read only
/// `final_state`, such as the Verisig translation, which runs one short flowpipe per neuron
/// (the dominated bounder took more time than the integration there).
pub fn reach_from_naive_box(
    ode: &Ode,
    state: Vec<TaylorModel>,
    space: &Arc<Space>,
    settings: &Settings,
    observer: &mut dyn FnMut(f64) -> bool,
) -> Result<Flowpipe> {
    flow_from(ode, state, space, settings, &mut |t, _, _, _| observer(t), TaylorModel::bound)
}

/// [`reach_from`] that hands `check(segment, models)` every segment as it is computed, with a
/// way to build the segment's Taylor models over the initial set's variables and normalised
/// time (variable 0), [`segment_over_initial`]; the flowpipe stops when it returns false. A
/// property of several states (a speed limit that grows with the distance) holds on those
/// models where the segment's box, which drops how the states move together, fails it.
pub fn reach_from_checked(
    ode: &Ode,
    state: Vec<TaylorModel>,
    space: &Arc<Space>,
    settings: &Settings,
    check: &mut dyn FnMut(&Segment, &dyn Fn() -> Vec<TaylorModel>) -> bool,
) -> Result<Flowpipe> {
    flow_from(ode, state, space, settings, &mut |_, seg, _, models| check(seg, models), crate::bound::range)
}

/// What the step loop hands its observer: the time, the step's segment, a way to build the
/// state at that time and one to build the segment's models over the initial set (each built
/// only by observers that want it).
type StepObserver<'a> = dyn FnMut(f64, &Segment, &dyn Fn() -> Vec<TaylorModel>, &dyn Fn() -> Vec<TaylorModel>) -> bool + 'a;

fn flow_from(
    ode: &Ode,
    mut state: Vec<TaylorModel>,
    space: &Arc<Space>,
    settings: &Settings,
    observer: &mut StepObserver,
    bounder: fn(&TaylorModel, &Space) -> Interval,
) -> Result<Flowpipe> {
    let n = ode.dim();
    settings.validate(n)?;
    if state.len() != n || !space.is_unit(0) || space.nvars <= n || space.order < settings.max_order() {
        return Err(TaylorError::input(format!(
            "reach_from needs {n} models in a space with a unit variable 0, more than {n} variables and order >= {}",
            settings.max_order()
        )));
    }
    let space = space.clone();
    let full = Ctx::new(space.clone(), settings.max_order(), settings.cutoff);
    let started = Instant::now();
    let mut stats = Stats::default();
    let (mut h, h_min) = match settings.step {
        StepSize::Fixed(h) => (h, h),
        StepSize::Adaptive { min, max } => (max, min),
    };
    let (k_min, k_max) = match settings.order {
        OrderPolicy::Fixed(k) => (k, k),
        OrderPolicy::Adaptive { min, max } => (min, max),
    };
    let mut k = k_min;
    // Every step length is a multiple of the grid, so every step time is too and every sum is
    // exact: segments tile [0, t_end] with no float gap between one's end and the next's start
    // (a gap would leave true states at those times in no segment), and the last ends on t_end.
    let grid = time_grid(settings.t_end);
    let mut t = 0.0;
    let mut segments = Vec::new();
    let mut failure = None;
    let mut symbolic = SymbolicRemainder::new(n, settings.symbolic_queue);
    // The last step's verified remainder: the next step's first guess (see `picard_step`).
    let mut last_rem: Option<Vec<Interval>> = None;
    while t < settings.t_end {
        let ctx = full.with_order(k);
        let r_box = symbolic.enclosure();
        let extra: Vec<f64> = r_box.iter().map(|r| r.mag()).collect();
        let pre = precondition(&state, &extra, settings.precondition, &ctx);
        let remaining = settings.t_end - t; // exact: both on the grid
        let mut h_try = if h >= remaining * (1.0 - 1e-12) { remaining } else { on_grid(h, grid) };
        // The remainder estimate is a tolerance while the step or order can still adapt (as
        // in Flow*); only when neither can is the estimate enlarged before giving up.
        let mut enlarge = false;
        let left = loop {
            match picard_step(ode, &pre.x0, h_try, &ctx, settings, enlarge, last_rem.as_deref(), &mut stats) {
                Ok(left) => break Some(left),
                Err(reason) => {
                    stats.rejected_steps += 1;
                    // On the grid a step of one grid unit cannot halve: it stays, so stop there too.
                    let half = on_grid(h_try * 0.5, grid);
                    let can_halve = matches!(settings.step, StepSize::Adaptive { .. }) && h_try * 0.5 >= h_min && half < h_try;
                    if can_halve {
                        h_try = half;
                    } else if k < k_max {
                        k += 1;
                        break None;
                    } else if !enlarge {
                        enlarge = true;
                    } else {
                        failure = Some(TaylorError::BlowUp { time_reached: t, reason });
                        break None;
                    }
                }
            }
        };
        if failure.is_some() {
            break;
        }
        let Some(left) = left else { continue }; // order raised: redo the step
        last_rem = Some(left.iter().map(|m| m.rem).collect());
        let composing = Instant::now();
        // The symbolic remainder in normalised coordinates: x̂_true = right(z) + T R.
        let shift: Vec<f64> = mat_vec(&pre.to_normalised, &r_box, n).iter().map(|v| v.mag()).collect();
        // x̂_true stays in [-1, 1] (the preconditioning scaled room for T R), where `left` is
        // valid: its bound over the whole domain already holds every true state, so adding the
        // gradient times the shift would count the remainder twice.
        segments.push(Segment { t0: t, t1: t + h_try, bounds: left.iter().map(|m| m.bound(&space)).collect(), order: k });
        let mut args = vec![TaylorModel::zero()];
        args.extend(pre.right.iter().cloned());
        args.resize(space.nvars, TaylorModel::zero());
        let ends: Vec<TaylorModel> = left.iter().map(|m| m.substitute(0, Interval::ONE, &ctx)).collect();
        // Step map on the symbolic part: its linear part A T exactly, the rest bounded.
        let a: Vec<Interval> = (0..n * n).map(|ij| Interval::point(ends[ij / n].linear_coefficient(&space, ij % n + 1))).collect();
        symbolic.transform(&mat_mul(&a, &pre.to_normalised, n));
        let mut entering = Vec::with_capacity(n);
        let composed = compose_all(&ends, &args, &ctx);
        state = ends
            .iter()
            .zip(composed)
            .map(|(m, mut x)| {
                entering.push(x.rem + Interval::symmetric(nonlinear_gradient_dot(m, &space, &shift)));
                x.rem = Interval::ZERO;
                x
            })
            .collect();
        symbolic.push(entering);
        stats.composition_seconds += composing.elapsed().as_secs_f64();
        stats.steps += 1;
        t += h_try; // exact on the grid
        if let StepSize::Adaptive { max, .. } = settings.step {
            h = (h_try * 1.1).min(max);
        }
        if state.iter().any(|m| !m.bound(&space).is_bounded()) || symbolic.enclosure().iter().any(|r| !r.is_bounded()) {
            failure = Some(TaylorError::BlowUp { time_reached: t, reason: "the state enclosure became unbounded".into() });
            break;
        }
        let now = || state.iter().zip(symbolic.enclosure()).map(|(m, r)| TaylorModel { coef: m.coef.clone(), rem: m.rem + r }).collect();
        let over_initial = || segment_over_initial(&left, &pre.right, &shift, &ctx);
        if !observer(t, segments.last().expect("a segment per step"), &now, &over_initial) {
            break;
        }
    }
    let r_box = symbolic.enclosure();
    for (m, r) in state.iter_mut().zip(&r_box) {
        m.rem = m.rem + *r;
    }
    let final_box = state.iter().map(|m| bounder(m, &space)).collect();
    stats.seconds = started.elapsed().as_secs_f64();
    Ok(Flowpipe { names: ode.names.clone(), segments, final_state: state, final_box, time_reached: t, failure, stats, space })
}

/// A step's models `left(s, x̂)` over the initial set's variables: left(s, right(z)), time kept
/// as variable 0, plus what the symbolic remainder's shift of x̂ (at most `shift` per
/// coordinate, inside the domain where `left` holds) can add: |d left / d x̂_j| bounded over the
/// domain times shift_j (mean value theorem on the convex domain).
pub(crate) fn segment_over_initial(left: &[TaylorModel], right: &[TaylorModel], shift: &[f64], ctx: &Ctx) -> Vec<TaylorModel> {
    let space = &ctx.space;
    let mut args = vec![TaylorModel::var(ctx, 0)];
    args.extend(right.iter().cloned());
    args.resize(space.nvars, TaylorModel::zero());
    compose_all(left, &args, ctx)
        .into_iter()
        .zip(left)
        .map(|(mut x, m)| {
            let linear =
                shift.iter().enumerate().fold(0.0, |acc, (j, &s)| add_up(acc, mul_up(m.linear_coefficient(space, j + 1).abs(), s)));
            x.rem = x.rem + Interval::symmetric(add_up(linear, nonlinear_gradient_dot(m, space, shift)));
            x
        })
        .collect()
}

/// The time grid of a flowpipe to `t_end`: the float spacing just below t_end. Multiples of it
/// up to t_end are floats (t_end / grid <= 2^53), so sums and differences of them are exact.
pub(crate) fn time_grid(t_end: f64) -> f64 {
    t_end - t_end.next_down()
}

/// The step `h` rounded to the nearest multiple of `grid` (at least one): it moves by at most
/// half an ulp of t_end, far below any step's own accuracy.
pub(crate) fn on_grid(h: f64, grid: f64) -> f64 {
    ((h / grid).round() * grid).max(grid)
}

/// Bound of sum_j |d p / d x̂_j| shift_j over the domain, counting only monomials of degree
/// >= 2 (the gradient minus its linear part, which the symbolic remainder carries exactly).
/// > |d/dx̂_j of c x^e| <= |c| e_j on the domain, since every monomial is bounded by 1 there.
fn nonlinear_gradient_dot(m: &TaylorModel, space: &Space, shift: &[f64]) -> f64 {
    let mut total = 0.0f64;
    for (i, &c) in m.coef.iter().enumerate() {
        if c == 0.0 || space.deg[i] < 2 {
            continue;
        }
        for (j, &s) in shift.iter().enumerate() {
            let e = space.exponent(i, j + 1);
            if e > 0 && s > 0.0 {
                total = (total + (c.abs() * e as f64 * s).next_up()).next_up();
            }
        }
    }
    total
}

/// One Picard step of length h from x0(x̂); returns the left models p(s, x̂) + J.
///
/// The remainder is first guessed at twice the last step's (`previous`; for a first step, at
/// twice the image of a zero remainder), which holds for the next step of a smooth flow and
/// starts the refinement near its fixed point: from the settings' estimate (a tolerance, orders
/// of magnitude wider) the refinement took 7 more applications of the operator per step to
/// converge (bench/README.md, issue 30). Where that guess is not verified, the step goes on
/// from the estimate as before; the guess never exceeds the estimate.
#[allow(clippy::too_many_arguments)]
fn picard_step(
    ode: &Ode,
    x0: &[TaylorModel],
    h: f64,
    ctx: &Ctx,
    settings: &Settings,
    enlarge: bool,
    previous: Option<&[Interval]>,
    stats: &mut Stats,
) -> std::result::Result<Vec<TaylorModel>, String> {
    let k = ctx.order;
    let space = &ctx.space;
    let started = Instant::now();
    let x0_poly: Vec<TaylorModel> = x0.iter().map(|m| TaylorModel { coef: m.coef.clone(), rem: Interval::ZERO }).collect();
    let mut p = x0_poly.clone();
    for i in 1..=k {
        let c = ctx.with_order(i);
        let f = ode.program.eval(&TaylorModels { ctx: &c }, &p).map_err(|e| e.to_string())?;
        p = x0_poly
            .iter()
            .zip(&f)
            .map(|(x, fi)| {
                let mut next = x.add(&fi.integrate(0, &c).scale(h));
                next.rem = Interval::ZERO;
                next
            })
            .collect();
    }
    stats.picard_seconds += started.elapsed().as_secs_f64();
    let started = Instant::now();
    // P(p + I): f at order k, integrated at order k. Evaluating f at k - 1 (as Flow* does) is
    // cheaper but sweeps f's degree-k terms into the remainder whole, where integration would
    // have divided them by (e + 1): measured 3-10x larger step remainders on Brusselator.
    let low = ctx.clone();
    let apply = |rem: &[Interval]| -> std::result::Result<Vec<Interval>, String> {
        let x: Vec<TaylorModel> = p.iter().zip(rem).map(|(m, r)| TaylorModel { coef: m.coef.clone(), rem: *r }).collect();
        let f = ode.program.eval(&TaylorModels { ctx: &low }, &x).map_err(|e| e.to_string())?;
        Ok(x0
            .iter()
            .zip(&f)
            .zip(&p)
            .map(|((x0i, fi), pi)| {
                let image = x0i.add(&fi.integrate(0, ctx).scale(h));
                // What the image's polynomial differs from p by joins the remainder.
                let diff = TaylorModel { coef: image.coef.clone(), rem: Interval::ZERO }.sub(pi);
                image.rem + diff.bound(space)
            })
            .collect())
    };
    let mut verified = None;
    // Without a last step, the operator's image of a zero remainder (the fixed point's part
    // that does not feed back) stands in for it.
    let near = match previous.filter(|p| p.len() == x0.len()) {
        Some(p) => p.to_vec(),
        None => apply(&vec![Interval::ZERO; x0.len()])?,
    };
    if near.iter().all(|r| r.is_bounded()) {
        // Capped at the estimate, which stays the tolerance that rejects a step (adaptive
        // steps halve there instead of going on with a wider remainder).
        let guess: Vec<Interval> =
            near.iter().zip(&settings.remainder_estimate).map(|(r, &e)| Interval::symmetric(mul_up(2.0, r.mag()).min(e))).collect();
        let image = apply(&guess)?;
        if image.iter().zip(&guess).all(|(j, i)| i.contains_interval(j)) {
            verified = Some(image);
        }
    }
    let mut guess: Vec<Interval> = settings.remainder_estimate.iter().map(|&r| Interval::symmetric(r)).collect();
    for _ in 0..if verified.is_some() {
        0
    } else if enlarge {
        4
    } else {
        1
    } {
        let image = apply(&guess)?;
        if image.iter().zip(&guess).all(|(j, i)| i.contains_interval(j)) {
            verified = Some(image);
            break;
        }
        // Enlarge the guess towards what the operator produced, then try again.
        guess = guess
            .iter()
            .zip(&image)
            .map(|(i, j)| {
                let h = i.hull(j);
                h.inflate(0.5 * h.width())
            })
            .collect();
        if guess.iter().any(|g| !g.is_bounded()) {
            break;
        }
    }
    let Some(mut rem) = verified else {
        stats.validation_seconds += started.elapsed().as_secs_f64();
        return Err("the remainder could not be verified (Picard operator not contracting)".into());
    };
    for _ in 0..settings.refinements {
        let next = apply(&rem)?;
        let shrunk: Vec<Interval> = next.iter().zip(&rem).map(|(a, b)| a.intersect(b)).collect();
        // Stop when no component shrinks by 1% any more (components already at 0 do not count).
        let gain = shrunk.iter().zip(&rem).filter(|(_, b)| b.width() > 0.0).map(|(a, b)| a.width() / b.width()).fold(1.0, f64::min);
        if shrunk.iter().any(|s| s.is_empty()) {
            break;
        }
        rem = shrunk;
        if gain > 0.99 {
            break;
        }
    }
    stats.validation_seconds += started.elapsed().as_secs_f64();
    Ok(p.into_iter().zip(rem).map(|(m, r)| TaylorModel { coef: m.coef, rem: r }).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parser::parse_expr;

    fn ode(names: &[&str], rhs: &[&str]) -> Ode {
        Ode::new(names.iter().map(|s| s.to_string()).collect(), rhs.iter().map(|s| parse_expr(s).unwrap()).collect()).unwrap()
    }

    fn settings(n: usize, h: f64, k: usize, t_end: f64) -> Settings {
        Settings {
            step: StepSize::Fixed(h),
            order: OrderPolicy::Fixed(k),
            t_end,
            cutoff: 1e-12,
            remainder_estimate: vec![1e-4; n],
            precondition: Precondition::Identity,
            refinements: 2,
            symbolic_queue: 100,
        }
    }

    /// RK4 with a tiny step as the float reference.
    fn simulate(ode: &Ode, x: &[f64], t_end: f64, dt: f64) -> Vec<Vec<f64>> {
        use crate::expr::FloatBatch;
        let f = |x: &[f64]| -> Vec<f64> {
            let cols: Vec<Vec<f64>> = x.iter().map(|&v| vec![v]).collect();
            ode.program.eval(&FloatBatch::new(1), &cols).unwrap().into_iter().map(|c| c[0]).collect()
        };
        let steps = (t_end / dt).round() as usize;
        let mut out = vec![x.to_vec()];
        let mut x = x.to_vec();
        for _ in 0..steps {
            let k1 = f(&x);
            let a: Vec<f64> = x.iter().zip(&k1).map(|(x, k)| x + 0.5 * dt * k).collect();
            let k2 = f(&a);
            let b: Vec<f64> = x.iter().zip(&k2).map(|(x, k)| x + 0.5 * dt * k).collect();
            let k3 = f(&b);
            let c: Vec<f64> = x.iter().zip(&k3).map(|(x, k)| x + dt * k).collect();
            let k4 = f(&c);
            for i in 0..x.len() {
                x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
            out.push(x.clone());
        }
        out
    }

    #[test]
    fn linear_rotation_is_enclosed_and_tight() {
        let o = ode(&["x", "y"], &["y", "-x"]);
        let init = [Interval::new(0.9, 1.1).unwrap(), Interval::new(-0.1, 0.1).unwrap()];
        for pre in [Precondition::Identity, Precondition::Qr] {
            let mut s = settings(2, 0.1, 6, 3.0);
            s.precondition = pre;
            let fp = reach(&o, &init, &s, &mut |_| true).unwrap();
            assert!(fp.failure.is_none());
            assert_eq!(fp.time_reached, 3.0);
            // Exact solution: rotation; the box of a rotated square of side 0.2.
            let (c, sn) = (3.0f64.cos(), 3.0f64.sin());
            for corner in [(0.9, -0.1), (1.1, 0.1), (0.9, 0.1), (1.1, -0.1)] {
                let x = c * corner.0 + sn * corner.1;
                let y = -sn * corner.0 + c * corner.1;
                assert!(fp.final_box[0].contains(x) && fp.final_box[1].contains(y));
            }
            if pre == Precondition::Identity {
                assert!(fp.final_box[0].width() < 0.3, "{pre:?}: {}", fp.final_box[0]);
            }
        }
    }

    #[test]
    fn van_der_pol_samples_stay_inside_every_segment() {
        let o = ode(&["x", "y"], &["y", "(1 - x^2)*y - x"]);
        let init = [Interval::new(1.25, 1.55).unwrap(), Interval::new(2.28, 2.32).unwrap()];
        let s = settings(2, 0.02, 5, 2.0);
        let fp = reach(&o, &init, &s, &mut |_| true).unwrap();
        assert!(fp.failure.is_none(), "{:?}", fp.failure);
        let dt = 0.0005;
        for a in 0..=6 {
            for b in 0..=4 {
                let x0 = [1.25 + 0.3 * a as f64 / 6.0, 2.28 + 0.04 * b as f64 / 4.0];
                let traj = simulate(&o, &x0, 2.0, dt);
                for (step, x) in traj.iter().enumerate() {
                    let t = step as f64 * dt;
                    let seg = fp.segments.iter().find(|s| s.t0 <= t && t <= s.t1).unwrap();
                    for i in 0..2 {
                        assert!(seg.bounds[i].inflate(1e-9).contains(x[i]), "t={t} var {i}: {} misses {}", seg.bounds[i], x[i]);
                    }
                }
                let last = traj.last().unwrap();
                assert!(fp.final_box[0].inflate(1e-9).contains(last[0]) && fp.final_box[1].inflate(1e-9).contains(last[1]));
            }
        }
    }

    #[test]
    fn segment_models_over_the_initial_set_hold_every_run() {
        // Van der Pol from a box with the symbolic remainder on: a float run from initial point
        // z lies in the segment's models evaluated at (s, z), at every time of the segment.
        let o = ode(&["x", "y"], &["y", "(1 - x^2)*y - x"]);
        let init = [Interval::new(1.25, 1.55).unwrap(), Interval::new(2.28, 2.32).unwrap()];
        let s = settings(2, 0.02, 5, 1.0);
        let space = Space::get(3, 5, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 5, s.cutoff);
        let start = init.iter().enumerate().map(|(i, iv)| {
            let (m, r) = initial_affine(iv);
            TaylorModel::affine(&ctx, m, i + 1, r)
        });
        let mut segments = Vec::new();
        let fp = reach_from_checked(&o, start.collect(), &space, &s, &mut |seg, models| {
            segments.push((seg.clone(), models()));
            true
        })
        .unwrap();
        assert!(fp.failure.is_none() && segments.len() == 50);
        let dt = 0.0005;
        let mut tighter = 0;
        for a in 0..=6 {
            for b in 0..=4 {
                let x0 = [1.25 + 0.3 * a as f64 / 6.0, 2.28 + 0.04 * b as f64 / 4.0];
                let z = normalise_initial_point(&init, &x0).unwrap();
                for (step, x) in simulate(&o, &x0, 1.0, dt).iter().enumerate() {
                    let t = step as f64 * dt;
                    for (seg, models) in segments.iter().filter(|(seg, _)| seg.t0 <= t && t <= seg.t1) {
                        let at = [Interval::point(((t - seg.t0) / (seg.t1 - seg.t0)).clamp(0.0, 1.0)), z[0], z[1]];
                        for i in 0..2 {
                            let range = models[i].eval_interval(&space, &at);
                            assert!(range.inflate(1e-9).contains(x[i]), "t={t} var {i}: {range} misses {}", x[i]);
                            tighter += usize::from(range.width() < 0.5 * seg.bounds[i].width());
                        }
                    }
                }
            }
        }
        // At a point of the initial set the models are far narrower than the segment's box.
        assert!(tighter > 1000, "{tighter}");
    }

    #[test]
    fn naive_final_box_keeps_the_state_and_contains_the_dominated_one() {
        let o = ode(&["x", "y"], &["y", "(1 - x^2)*y - x"]);
        let space = Space::get(3, 5, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 5, 0.0);
        let init = vec![TaylorModel::affine(&ctx, 1.4, 1, 0.15), TaylorModel::affine(&ctx, 2.3, 2, 0.02)];
        let s = settings(2, 0.02, 5, 0.5);
        let dominated = reach_from(&o, init.clone(), &space, &s, &mut |_| true).unwrap();
        let naive = reach_from_naive_box(&o, init, &space, &s, &mut |_| true).unwrap();
        assert_eq!(dominated.final_state, naive.final_state);
        for (d, n) in dominated.final_box.iter().zip(&naive.final_box) {
            assert!(n.contains_interval(d), "{n} vs {d}");
        }
    }

    #[test]
    fn non_dyadic_horizons_end_exactly_at_t_end() {
        // x' = 1: x(t_end) = t_end. Ten float steps of 0.1 sum to 1 + 5.6e-17 in exact
        // arithmetic; the final model must still hold the state at t = 1 exactly, and a
        // horizon that is not a multiple of the step must end on it too.
        let o = ode(&["x"], &["1"]);
        let init = [Interval::new(0.0, 0.0).unwrap()];
        for (h, t_end) in [(0.1, 1.0), (0.1, 0.3), (0.07, 0.25), (0.3, 0.1)] {
            let fp = reach(&o, &init, &settings(1, h, 3, t_end), &mut |_| true).unwrap();
            assert!(fp.failure.is_none());
            assert_eq!(fp.time_reached, t_end);
            let x = fp.final_box[0];
            assert!(x.contains(t_end) && x.width() < 1e-12, "h {h}, t_end {t_end}: {x}");
            let last = fp.segments.last().unwrap();
            assert!(last.t1 == t_end && last.bounds[0].contains(t_end));
            assert_tiles(&fp, t_end);
        }
    }

    /// Each segment starts on the same float where the previous one ends: a gap of even one
    /// ulp would leave the true states at the times inside it in no segment.
    fn assert_tiles(fp: &Flowpipe, t_end: f64) {
        assert_eq!(fp.segments[0].t0, 0.0);
        for pair in fp.segments.windows(2) {
            assert_eq!(pair[0].t1, pair[1].t0, "gap between segments");
        }
        assert_eq!(fp.segments.last().unwrap().t1, t_end);
    }

    #[test]
    fn halving_stops_at_the_time_grid() {
        // x' = x^2 from 1 blows up at t = 1: with a minimum step below the grid of t_end (2^-12
        // for a horizon of 2^40), halving must end at one grid unit and report the blow-up, not
        // retry the same step forever.
        let o = ode(&["x"], &["x^2"]);
        let init = [Interval::new(1.0, 1.0).unwrap()];
        let mut s = settings(1, 0.0, 3, 2f64.powi(40));
        s.step = StepSize::Adaptive { min: 1e-300, max: 0.5 };
        let fp = reach(&o, &init, &s, &mut |_| true).unwrap();
        let Some(TaylorError::BlowUp { time_reached, .. }) = fp.failure else { panic!("expected blow-up") };
        assert!(time_reached <= 1.0);
    }

    #[test]
    fn adaptive_steps_tile_time_exactly() {
        // Van der Pol from a box: adaptive steps grow by 1.1 (never dyadic) and halve on failure.
        let o = ode(&["x", "y"], &["y", "(1 - x^2)*y - x"]);
        let init = [Interval::new(1.25, 1.55).unwrap(), Interval::new(2.28, 2.32).unwrap()];
        for t_end in [0.7, 2.9] {
            let mut s = settings(2, 0.0, 5, t_end);
            s.step = StepSize::Adaptive { min: 1e-4, max: 0.13 };
            let fp = reach(&o, &init, &s, &mut |_| true).unwrap();
            assert!(fp.failure.is_none(), "{:?}", fp.failure);
            assert_eq!(fp.time_reached, t_end);
            assert_tiles(&fp, t_end);
        }
    }

    #[test]
    fn bad_settings_are_errors_and_blow_up_is_reported() {
        let o = ode(&["x"], &["x^2"]);
        let init = [Interval::new(1.0, 1.1).unwrap()];
        let mut s = settings(1, -0.1, 4, 1.0);
        assert!(reach(&o, &init, &s, &mut |_| true).is_err());
        s.step = StepSize::Fixed(0.1);
        s.order = OrderPolicy::Fixed(0);
        assert!(reach(&o, &init, &s, &mut |_| true).is_err());
        // x' = x^2 from 1 blows up at t = 1 / x0 <= 1.
        s.order = OrderPolicy::Fixed(4);
        s.t_end = 2.0;
        let fp = reach(&o, &init, &s, &mut |_| true).unwrap();
        let Some(TaylorError::BlowUp { time_reached, .. }) = fp.failure else { panic!("expected blow-up") };
        assert!(time_reached < 1.0);
        assert!(Ode::new(vec!["x".into()], vec![parse_expr("y").unwrap()]).is_err());
    }
}
