//! Hybrid automata reached with Taylor models carried through the jumps, as Flow* 2.1 does:
//! each mode's flowpipe runs until its invariant is violated on the whole state set; every
//! segment where a guard may hold spawns that jump's state, the segment's time window first
//! contracted by bisection (Flow*'s domain contraction, on time only); the states one jump
//! gets from one visit of its mode are aggregated into one model (one branch per mode
//! sequence), reset by Taylor-model composition and continued in the target mode. A run ends
//! on the jumps that leave the automaton ([`Target::Exit`]): in a closed loop, the jumps that
//! return control to the controller. [`reach`] runs an automaton on its own as Flow*'s hybrid
//! reachability does: from a box, up to a time horizon and a number of jumps.
use crate::coupling::Coupling;
use crate::error::{Result, TaylorError};
use crate::expr::{BinOp, Cmp, Expr, Intervals, Op, Program, TaylorModels};
use crate::flowpipe::{Ode, Segment, Settings};
use crate::interval::Interval;
use crate::space::Space;
use crate::tm::{Ctx, TaylorModel};
use std::collections::VecDeque;
use std::sync::Arc;

/// `margin cmp 0`, the margin one expression over the automaton's variables.
#[derive(Clone, Debug)]
pub struct Constraint {
    pub margin: Arc<Program>,
    pub cmp: Cmp,
}

impl Constraint {
    fn on_models(&self, state: &[TaylorModel], ctx: &Ctx) -> Result<Option<bool>> {
        let m = self.margin.eval(&TaylorModels { ctx }, state)?;
        // The naive bound decides most constraints (a clock's) at a fraction of the cost of
        // the dominated bounder, which is asked only when it cannot.
        match self.cmp.decide(m[0].bound(&ctx.space)) {
            Some(decided) => Ok(Some(decided)),
            None => Ok(self.cmp.decide(crate::bound::range(&m[0], &ctx.space))),
        }
    }
    fn on_box(&self, b: &[Interval]) -> Result<Option<bool>> {
        Ok(self.cmp.decide(self.margin.eval(&Intervals, b)?[0]))
    }
}

/// Whether a conjunction is false for the whole set (`Some(false)`), true for all of it, or undecided.
fn conjunction(constraints: &[Constraint], decide: impl Fn(&Constraint) -> Result<Option<bool>>) -> Result<Option<bool>> {
    let mut all = Some(true);
    for c in constraints {
        match decide(c)? {
            Some(false) => return Ok(Some(false)),
            None => all = None,
            Some(true) => {}
        }
    }
    Ok(all)
}

/// A mode: an ODE over all the automaton's variables (in their order) and the invariant that
/// every run must satisfy while it flows there.
#[derive(Clone, Debug)]
pub struct Mode {
    pub name: String,
    pub ode: Ode,
    pub invariant: Vec<Constraint>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    Mode(usize),
    /// The run leaves the automaton (in a closed loop: the control period ends).
    Exit,
}

/// A jump may be taken whenever its guard holds (and must be taken then if `urgent`); the
/// reset maps every variable (one output per variable, in order), None keeps the state.
#[derive(Clone, Debug)]
pub struct Jump {
    pub source: usize,
    pub target: Target,
    pub guard: Vec<Constraint>,
    pub reset: Option<Arc<Program>>,
    pub urgent: bool,
}

#[derive(Clone, Debug)]
pub struct Automaton {
    pub names: Vec<String>,
    pub modes: Vec<Mode>,
    pub jumps: Vec<Jump>,
}

impl Automaton {
    /// Checks every index and width once, before any work.
    pub fn validate(&self) -> Result<()> {
        let n = self.names.len();
        let bad = |m: String| Err(TaylorError::input(m));
        for mode in &self.modes {
            if mode.ode.names != self.names {
                return bad(format!(
                    "mode '{}': its ODE must have the automaton's variables ({}) in order",
                    mode.name,
                    self.names.join(", ")
                ));
            }
        }
        for (k, j) in self.jumps.iter().enumerate() {
            let what = format!("jump {} (from '{}')", k + 1, self.modes.get(j.source).map_or("?", |m| &m.name));
            if j.source >= self.modes.len() || matches!(j.target, Target::Mode(m) if m >= self.modes.len()) {
                return bad(format!("{what}: mode index out of range"));
            }
            if j.reset.as_ref().is_some_and(|r| r.inputs.len() != n || r.outputs.len() != n) {
                return bad(format!("{what}: a reset must read and define all {n} variables"));
            }
        }
        let constraints = self.modes.iter().flat_map(|m| &m.invariant).chain(self.jumps.iter().flat_map(|j| &j.guard));
        if constraints.into_iter().any(|c| c.margin.inputs.len() != n || c.margin.outputs.len() != 1) {
            return bad(format!("every invariant and guard must be one expression over the {n} variables"));
        }
        Ok(())
    }
}

/// Bounds of one run: flowing beyond `max_time` or taking more than `max_jumps` jumps fails
/// it (a Zeno run or a mode never left); states are aggregated so that at most `max_branches`
/// branches are followed at once and at most `max_exits` exit states are returned (aggregating
/// the exits rather than the branches keeps each branch's jump times apart until the end).
#[derive(Clone, Debug)]
pub struct Limits {
    pub max_time: f64,
    pub max_jumps: usize,
    pub max_branches: usize,
    pub max_exits: usize,
    /// The variables of the space whose range the jumps may contract (Flow*'s domain
    /// contraction): those of the initial set, not ones shared with anything outside the run.
    pub contract: Vec<usize>,
    /// Drop the runs past `max_jumps` jumps (Flow*'s `max jumps`: the reach set of the runs with
    /// at most that many) instead of failing on them.
    pub drop_past_max_jumps: bool,
    /// Box the state at every jump (each variable a fresh symbol over its range) instead of
    /// carrying its Taylor models: what box-based runners do, kept to measure what it loses.
    pub box_at_jumps: bool,
}

#[derive(Clone, Debug, Default)]
pub struct Run {
    /// The states on leaving the automaton, after the exit jumps' resets.
    pub exits: Vec<Vec<TaylorModel>>,
    /// Every flowpipe segment with its mode, times counted from the start of the run.
    pub segments: Vec<(usize, Segment)>,
    /// Why the run stopped before every branch left; the exits so far are then incomplete.
    pub failure: Option<String>,
    /// How many times several states were aggregated into one.
    pub aggregations: usize,
    /// The mode each exit state left, while the exits are not aggregated (empty after).
    pub exit_modes: Vec<usize>,
}

struct Branch {
    mode: usize,
    state: Vec<TaylorModel>,
    /// Earliest and latest time (since the start) at which the runs of the branch entered.
    elapsed: (f64, f64),
    jumps: usize,
}

/// Runs the automaton from `state` (models over variables 1.. of `space`, whose variable 0 is
/// free for time) in mode `start`, with the flowpipe `flow` (its `t_end` is set per mode).
pub fn run(aut: &Automaton, start: usize, state: Vec<TaylorModel>, space: &Arc<Space>, flow: &Settings, limits: &Limits) -> Result<Run> {
    aut.validate()?;
    if start >= aut.modes.len() || state.len() != aut.names.len() {
        return Err(TaylorError::input("the start mode or the initial state does not fit the automaton"));
    }
    let ctx = Ctx::new(space.clone(), space.order, flow.cutoff);
    let couplings = aut
        .modes
        .iter()
        .map(|m| {
            let width = space.nvars - 1;
            let coupling = if limits.box_at_jumps { Coupling::apart(&m.ode, width) } else { Coupling::of(&m.ode, width) };
            coupling.map_err(|e| TaylorError::input(format!("mode '{}': {e}", m.name)))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut out = Run::default();
    let mut queue = VecDeque::from([Branch { mode: start, state, elapsed: (0.0, 0.0), jumps: 0 }]);
    while let Some(branch) = queue.pop_front() {
        let name = &aut.modes[branch.mode].name;
        if branch.jumps > limits.max_jumps {
            if limits.drop_past_max_jumps {
                continue;
            }
            out.failure =
                Some(format!("more than {} jumps (last into mode '{name}'); a Zeno run or a cycle that never exits", limits.max_jumps));
            return Ok(out);
        }
        let outgoing: Vec<&Jump> = aut.jumps.iter().filter(|j| j.source == branch.mode).collect();
        let visit = match visit(aut, &couplings[branch.mode], &branch, &outgoing, space, &ctx, flow, limits, &mut out.segments)? {
            Ok(v) => v,
            Err(reason) => {
                out.failure = Some(reason);
                return Ok(out);
            }
        };
        for (jump, (found, earliest, latest)) in outgoing.iter().zip(visit) {
            if found.is_empty() {
                continue;
            }
            // Each state its own branch while the budget allows (a branch keeps its jump time
            // to a step's precision); beyond, consecutive ones are aggregated.
            let room = limits.max_branches.saturating_sub(queue.len() + out.exits.len()).max(1);
            let source = &aut.modes[branch.mode].invariant;
            let holds: Vec<&Constraint> = jump.guard.iter().chain(source).collect();
            let found = merge_alike(found, &ctx.space);
            for taken in groups(&found, room, &ctx.space, &mut out.aggregations) {
                let Some(taken) = contract(taken, &holds, &limits.contract, &ctx)? else { continue };
                let mut next = match &jump.reset {
                    Some(r) => r.eval(&TaylorModels { ctx: &ctx }, &taken)?,
                    None => taken,
                };
                if limits.box_at_jumps {
                    next = boxed(&next, &ctx);
                }
                match jump.target {
                    Target::Exit => {
                        out.exits.push(next);
                        out.exit_modes.push(branch.mode);
                    }
                    Target::Mode(m) => {
                        // A state outside the target's invariant has no run to continue.
                        if conjunction(&aut.modes[m].invariant, |c| c.on_models(&next, &ctx))? != Some(false) {
                            queue.push_back(Branch {
                                mode: m,
                                state: next,
                                elapsed: (branch.elapsed.0 + earliest, branch.elapsed.1 + latest),
                                jumps: branch.jumps + 1,
                            });
                        }
                    }
                }
            }
        }
    }
    if out.exits.len() > limits.max_exits {
        out.exits = groups(&out.exits, limits.max_exits, &ctx.space, &mut out.aggregations);
        out.exit_modes.clear();
    }
    Ok(out)
}

/// The name of the clock [`reach`] adds: the time since the start, in every segment's box.
pub const TIME: &str = "time";

/// Runs the automaton from the box `init` in mode `start` up to the horizon `t_end`, as Flow*'s
/// hybrid reachability does: Taylor models over the box's normalised variables (1..=n of a
/// space with time as variable 0). The horizon is a clock [`TIME`] added as the last variable:
/// every mode gets the invariant `time <= t_end` and an exit jump `time >= t_end`, so the
/// exits are the states at the horizon, found as any jump's are (a branch's runs entered its
/// mode at different times; the clock tells them apart exactly). Returns the run and the space
/// of its models.
pub fn reach(aut: &Automaton, start: usize, init: &[Interval], t_end: f64, flow: &Settings, limits: &Limits) -> Result<(Run, Arc<Space>)> {
    let n = aut.names.len();
    if init.len() != n || init.iter().any(|iv| iv.is_empty() || !iv.is_bounded()) {
        return Err(TaylorError::input(format!(
            "the initial set needs one bounded, non-empty interval per variable ({})",
            aut.names.join(", ")
        )));
    }
    if !(t_end > 0.0 && t_end.is_finite()) {
        return Err(TaylorError::input(format!("the time horizon must be positive and finite, got {t_end}")));
    }
    if aut.names.iter().any(|v| v == TIME) {
        return Err(TaylorError::input(format!("'{TIME}' is the clock reachability adds; rename the automaton's variable")));
    }
    let timed = with_horizon(aut, t_end)?;
    let order = flow.max_order();
    // The models' variables: time, then the symbols of the initial set (or, boxing at the
    // jumps, of every jump's box), and as many as the widest group of coupled variables needs.
    let budget = symbol_budget(n + 1, order);
    let uncertain = init.iter().filter(|iv| iv.lo() < iv.hi()).count();
    let symbols = if limits.box_at_jumps { budget } else { uncertain.min(budget) };
    let widest = timed.modes.iter().max_by_key(|m| Coupling::least_width(&m.ode));
    let coupled = widest.map_or(0, |m| Coupling::least_width(&m.ode));
    let nvars = 1 + symbols.max(coupled).max(1);
    if let Some(mode) = widest.filter(|_| nvars > crate::space::MAX_VARS) {
        let too_wide = Coupling::of(&mode.ode, crate::space::MAX_VARS - 1).expect_err("its widest group exceeds the limit");
        return Err(TaylorError::input(format!("mode '{}': {too_wide}", mode.name)));
    }
    let space = Space::get(nvars, order, 1)?;
    let ctx = Ctx::new(space.clone(), order, flow.cutoff);
    let state = symbolize(&init.iter().copied().chain([Interval::ZERO]).collect::<Vec<_>>(), &ctx);
    let mut remainder = flow.remainder_estimate.clone();
    // The clock's estimate is a tolerance like the others (the smallest): one at the underflow
    // level failed every Picard check by the clock's rounding, which no step length shrinks,
    // so adaptive steps halved to their minimum at every step (exported networks at 1e-6).
    remainder.push(remainder.iter().copied().fold(f64::INFINITY, f64::min));
    let flow = Settings { remainder_estimate: remainder, ..flow.clone() };
    // Never the reason a run stops (the clock is): a visit flows at most t_end and a step past
    // it, and a branch's latest entry time sums its visits' latest jump times.
    let step = match flow.step {
        crate::StepSize::Fixed(h) => h,
        crate::StepSize::Adaptive { max, .. } => max,
    };
    let max_time = (t_end + step) * (limits.max_jumps as f64 + 2.0);
    let limits = Limits { contract: (1..nvars).collect(), max_time, ..limits.clone() };
    Ok((run(&timed, start, state, &space, &flow, &limits)?, space))
}

/// The automaton with the clock [`TIME`] appended, its invariants `time <= t_end` and its exits
/// `time >= t_end` (the automaton's own exits are kept).
fn with_horizon(aut: &Automaton, t_end: f64) -> Result<Automaton> {
    let n = aut.names.len();
    let names: Vec<String> = aut.names.iter().cloned().chain([TIME.to_string()]).collect();
    // A program over the longer list: its inputs keep their places, the clock comes last; `extra`
    // is one more output.
    let widen = |p: &Program, extra: Option<Op>| -> Program {
        let mut p = Program { inputs: names.clone(), ..p.clone() };
        if let Some(op) = extra {
            p.ops.push(op);
            p.outputs.push(p.ops.len() - 1);
        }
        p
    };
    let widen_all = |cs: &[Constraint]| -> Vec<Constraint> {
        cs.iter().map(|c| Constraint { margin: Arc::new(widen(&c.margin, None)), cmp: c.cmp }).collect()
    };
    let clock = Expr::binary(BinOp::Sub, &Expr::var(TIME), &Expr::constant(t_end));
    let margin = Arc::new(Program::compile(&[clock], &names)?);
    let mut modes = Vec::with_capacity(aut.modes.len());
    let mut jumps = Vec::with_capacity(aut.jumps.len() + aut.modes.len());
    for (m, mode) in aut.modes.iter().enumerate() {
        let mut invariant = widen_all(&mode.invariant);
        invariant.push(Constraint { margin: margin.clone(), cmp: Cmp::Le });
        let ode = Ode { names: names.clone(), program: widen(&mode.ode.program, Some(Op::Const(1.0))) };
        modes.push(Mode { name: mode.name.clone(), ode, invariant });
        jumps.push(Jump {
            source: m,
            target: Target::Exit,
            guard: vec![Constraint { margin: margin.clone(), cmp: Cmp::Ge }],
            reset: None,
            urgent: false,
        });
    }
    for j in &aut.jumps {
        let reset = j.reset.as_ref().map(|r| Arc::new(widen(r, Some(Op::Input(n)))));
        jumps.push(Jump { source: j.source, target: j.target, guard: widen_all(&j.guard), reset, urgent: j.urgent });
    }
    let timed = Automaton { names, modes, jumps };
    timed.validate()?;
    Ok(timed)
}

/// Most monomials of the models' space when the automaton is too wide for a symbol per
/// variable: 14 symbols at order 4 (3,876), whose states of 600 variables take 19 MB; every
/// product of two models of a wider space costs more than a whole narrow run's flowpipe step.
const MONOMIAL_BUDGET: f64 = 4096.0;

/// How many symbols the models of `n` variables at `order` may have: one per variable if they
/// fit a space with time, else as many as keep the space within [`MONOMIAL_BUDGET`].
fn symbol_budget(n: usize, order: usize) -> usize {
    let max = crate::space::MAX_VARS - 1;
    if n <= max {
        return n;
    }
    // Monomials of degree <= order in k + 1 variables: C(k + 1 + order, order).
    let monomials = |k: usize| (1..=order).fold(1.0, |acc: f64, i| acc * (k + 1 + i) as f64 / i as f64);
    (1..=max).take_while(|&k| monomials(k) <= MONOMIAL_BUDGET).last().unwrap_or(1)
}

/// The box `ranges` as models: the widest intervals (as many as the space has variables
/// besides time) each an affine map c + r x_v of a symbol of its own (r rounded up, so that it
/// encloses the interval), the others constants with the interval as remainder (sound: their
/// dependence on the rest is forgotten), points constants.
fn symbolize(ranges: &[Interval], ctx: &Ctx) -> Vec<TaylorModel> {
    let mut wide: Vec<usize> = (0..ranges.len()).filter(|&i| ranges[i].lo() < ranges[i].hi()).collect();
    wide.sort_by(|&a, &b| ranges[b].width().total_cmp(&ranges[a].width()));
    wide.truncate(ctx.space.nvars - 1);
    wide.sort_unstable();
    // A point is an exact constant (`from_interval` would round its zero remainder outward).
    let mut out: Vec<TaylorModel> =
        ranges.iter().map(|iv| if iv.lo() == iv.hi() { TaylorModel::constant(iv.lo()) } else { TaylorModel::from_interval(*iv) }).collect();
    for (k, &i) in wide.iter().enumerate() {
        let (c, r) = crate::flowpipe::initial_affine(&ranges[i]);
        out[i] = TaylorModel::affine(ctx, c, k + 1, r);
    }
    out
}

/// The state's box, each variable a fresh symbol while the space has them (see [`symbolize`]):
/// the dependence on the initial set and between the variables is forgotten.
fn boxed(state: &[TaylorModel], ctx: &Ctx) -> Vec<TaylorModel> {
    symbolize(&state.iter().map(|m| crate::bound::range_or_point(m, &ctx.space)).collect::<Vec<_>>(), ctx)
}

/// The states a jump may be taken from during one visit of its mode, and the earliest and latest
/// time (since the mode was entered) it may be taken at.
type Found = (Vec<Vec<TaylorModel>>, f64, f64);

/// Per outgoing jump, what it may be taken from during this visit. Ok(Err(reason)) when the
/// flow fails.
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn visit(
    aut: &Automaton,
    coupling: &Coupling,
    branch: &Branch,
    outgoing: &[&Jump],
    space: &Arc<Space>,
    ctx: &Ctx,
    flow: &Settings,
    limits: &Limits,
    segments: &mut Vec<(usize, Segment)>,
) -> Result<std::result::Result<Vec<Found>, String>> {
    let mode = &aut.modes[branch.mode];
    let mut found: Vec<Found> = vec![(Vec::new(), f64::INFINITY, 0.0); outgoing.len()];
    // The entry itself: jumps enabled at once, and a flow that never starts if an urgent one holds.
    let mut stopped = false;
    for (k, j) in outgoing.iter().enumerate() {
        let enabled = conjunction(&j.guard, |c| c.on_models(&branch.state, ctx))?;
        if enabled != Some(false) {
            found[k] = (vec![branch.state.clone()], 0.0, 0.0);
        }
        stopped |= j.urgent && enabled == Some(true);
    }
    if stopped {
        return Ok(Ok(found));
    }
    let remaining = limits.max_time - branch.elapsed.1;
    if !(remaining > 0.0) {
        return Ok(Err(format!("the run is still in mode '{}' after {} time units", mode.name, limits.max_time)));
    }
    // A clock that surely ends the invariant at a known time ends the first flowpipe there,
    // so that a step ends exactly where the time-triggered jumps happen.
    let phases = match dwell_hint(mode, &branch.state, ctx)? {
        Some(d) if d > 0.0 && d < remaining => vec![d, remaining],
        _ => vec![remaining],
    };
    let mut start = branch.state.clone();
    let mut t_base = 0.0;
    for &t_phase in &phases {
        let settings = Settings { t_end: t_phase - t_base, ..flow.clone() };
        let mut prev = start.clone();
        let mut t_prev = 0.0;
        let mut error = None;
        let failure = coupling.flow(start, space, &settings, limits.box_at_jumps, &mut |t, seg, now| {
            let window =
                Window { ode: &mode.ode, invariant: &mode.invariant, start: &prev, end: &now, seg, h: t - t_prev, space: &ctx.space };
            let step = (|| -> Result<bool> {
                // The runs in the segment satisfy the invariant: what violates it is cut off.
                if let Some(bounds) = contract_box(&seg.bounds, &mode.invariant)? {
                    let (t0, t1) = (seg.t0 + branch.elapsed.0 + t_base, seg.t1 + branch.elapsed.1 + t_base);
                    segments.push((branch.mode, Segment { t0, t1, bounds, order: seg.order }));
                }
                for (k, j) in outgoing.iter().enumerate() {
                    if let Some(state) = window.jump_state(&j.guard)? {
                        found[k].0.push(state);
                        found[k].1 = found[k].1.min(t_base + t_prev);
                        found[k].2 = t_base + t;
                    }
                }
                // All runs have left the invariant, or have all taken an urgent jump by now.
                if conjunction(&mode.invariant, |c| c.on_models(&now, ctx))? == Some(false) {
                    return Ok(false);
                }
                for j in outgoing.iter().filter(|j| j.urgent) {
                    if conjunction(&j.guard, |c| c.on_models(&now, ctx))? == Some(true) {
                        return Ok(false);
                    }
                }
                Ok(true)
            })();
            match step {
                Ok(go) => {
                    stopped = !go;
                    (prev, t_prev) = (now, t);
                    go
                }
                Err(e) => {
                    error = Some(e);
                    false
                }
            }
        })?;
        if let Some(e) = error {
            return Err(e);
        }
        if let Some(f) = failure {
            return Ok(Err(format!("in mode '{}': {f}", mode.name)));
        }
        if stopped {
            return Ok(Ok(found));
        }
        start = prev;
        t_base = t_phase;
    }
    Ok(Err(format!("the run is still in mode '{}' after {} time units; check its invariant", mode.name, limits.max_time)))
}

/// The time `d` after which an invariant `c - x <= 0`-like constraint on a clock (x' = 1, its
/// margin a point that reaches 0 when the clock has advanced by d) stops holding. Only a hint
/// for where steps end: the flow goes on until the invariant is seen violated.
fn dwell_hint(mode: &Mode, entry: &[TaylorModel], ctx: &Ctx) -> Result<Option<f64>> {
    let rhs = mode.ode.program.eval(&TaylorModels { ctx }, entry)?;
    let clocks: Vec<usize> = (0..rhs.len())
        .filter(|&i| rhs[i].rem == Interval::ZERO && rhs[i].coef.iter().enumerate().all(|(k, &c)| c == if k == 0 { 1.0 } else { 0.0 }))
        .collect();
    let mut best: Option<f64> = None;
    for c in &mode.invariant {
        let margin = |state: &[TaylorModel]| -> Result<Interval> {
            Ok(crate::bound::range(&c.margin.eval(&TaylorModels { ctx }, state)?[0], &ctx.space))
        };
        let m0 = margin(entry)?;
        let d = match c.cmp {
            Cmp::Le | Cmp::Lt => -m0.mid(),
            Cmp::Ge | Cmp::Gt => m0.mid(),
        };
        if m0.width() > 1e-12 || !(d > 0.0) {
            continue;
        }
        for &i in &clocks {
            let mut later = entry.to_vec();
            later[i] = later[i].add_constant(d);
            if margin(&later)?.mag() <= 1e-12 {
                best = Some(best.map_or(d, |b| b.min(d)));
            }
        }
    }
    Ok(best)
}

/// One flowpipe step from `start` (time 0) to `end` (time h) within the segment box.
struct Window<'a> {
    ode: &'a Ode,
    invariant: &'a [Constraint],
    start: &'a [TaylorModel],
    end: &'a [TaylorModel],
    seg: &'a Segment,
    h: f64,
    space: &'a Space,
}

/// Bisection depth of the time window (its ends are found to h / 2^DEPTH) and the most interval
/// evaluations one end may cost (beyond, the end found so far is kept: wider, still sound).
const DEPTH: usize = 30;
const BUDGET: usize = 400;

impl Window<'_> {
    /// The state at the times of the step where `guard` and the invariant may hold, or None if
    /// they hold nowhere: x(τ) = x(0) + ∫ f over [0, τ] lies in start + τ F and in end - (h - τ) F
    /// with F the range of f over the segment box.
    fn jump_state(&self, guard: &[Constraint]) -> Result<Option<Vec<TaylorModel>>> {
        let b = &self.seg.bounds;
        let f = self.ode.program.eval(&Intervals, b)?;
        // Naive bounds: they only bracket the times, and the dominated bounder on every
        // variable at every step cost most of a run's time.
        let sb: Vec<Interval> = self.start.iter().map(|m| m.bound(self.space)).collect();
        let eb: Vec<Interval> = self.end.iter().map(|m| m.bound(self.space)).collect();
        // Float step lengths may be off by an ulp; the slack keeps the time intervals enclosing.
        let slack = 1e-12 * self.h + f64::MIN_POSITIVE;
        let since = |a: f64, b: f64| Interval::new((a - slack).max(0.0), b + slack).expect("a <= b");
        let until = |a: f64, b: f64| since(self.h - b, self.h - a);
        let sub_box = |a: f64, b_: f64| -> Vec<Interval> {
            (0..b.len()).map(|i| (sb[i] + since(a, b_) * f[i]).intersect(&(eb[i] - until(a, b_) * f[i])).intersect(&b[i])).collect()
        };
        let feasible = |a: f64, b_: f64| -> Result<bool> {
            let x = sub_box(a, b_);
            if x.iter().any(|i| i.is_empty()) {
                return Ok(false);
            }
            Ok(conjunction(guard, |c| c.on_box(&x))? != Some(false) && conjunction(self.invariant, |c| c.on_box(&x))? != Some(false))
        };
        let mut budget = BUDGET;
        let Some(lo) = edge(0.0, self.h, DEPTH, true, &feasible, &mut budget)? else { return Ok(None) };
        budget = BUDGET;
        let hi = edge(lo, self.h, DEPTH, false, &feasible, &mut budget)?.unwrap_or(self.h);
        // Each variable from the nearer anchor.
        let state = (0..b.len())
            .map(|i| {
                let (from_start, from_end) = (since(lo, hi) * f[i], -(until(lo, hi) * f[i]));
                if from_start.width() <= from_end.width() {
                    self.start[i].add_interval(from_start)
                } else {
                    self.end[i].add_interval(from_end)
                }
            })
            .collect();
        Ok(Some(state))
    }
}

/// The lowest (`from_left`) or highest time of [a, b] whose neighbourhood is feasible, to the
/// resolution of `depth` bisections; None if [a, b] is infeasible.
fn edge(
    a: f64,
    b: f64,
    depth: usize,
    from_left: bool,
    feasible: &dyn Fn(f64, f64) -> Result<bool>,
    budget: &mut usize,
) -> Result<Option<f64>> {
    if *budget == 0 {
        return Ok(Some(if from_left { a } else { b }));
    }
    *budget -= 1;
    if !feasible(a, b)? {
        return Ok(None);
    }
    if depth == 0 {
        return Ok(Some(if from_left { a } else { b }));
    }
    let m = 0.5 * (a + b);
    let (first, second) = if from_left { ((a, m), (m, b)) } else { ((m, b), (a, m)) };
    if let Some(t) = edge(first.0, first.1, depth - 1, from_left, feasible, budget)? {
        return Ok(Some(t));
    }
    edge(second.0, second.1, depth - 1, from_left, feasible, budget)
}

/// Depth of the bisection that contracts a variable's range, and the evaluations one bound may
/// cost.
const CONTRACT_DEPTH: usize = 12;
const CONTRACT_BUDGET: usize = 60;

/// The state re-parameterised onto the sub-box of `vars` (each in [-1, 1]) outside which
/// `constraints` surely fail (x_v = m + r x_v' for the range [m - r, m + r] kept): the runs
/// cut off cannot take the jump. None when no point of the domain may satisfy them.
fn contract(state: Vec<TaylorModel>, constraints: &[&Constraint], vars: &[usize], ctx: &Ctx) -> Result<Option<Vec<TaylorModel>>> {
    let space = &ctx.space;
    let mut domain: Vec<Interval> = (0..space.nvars).map(|v| if space.is_unit(v) { Interval::UNIT } else { Interval::SYMMETRIC }).collect();
    let feasible = |domain: &[Interval]| -> Result<bool> {
        let values: Vec<Interval> = state.iter().map(|m| m.eval_interval(space, domain)).collect();
        for c in constraints {
            if c.on_box(&values)? == Some(false) {
                return Ok(false);
            }
        }
        Ok(true)
    };
    if !feasible(&domain)? {
        return Ok(None);
    }
    let mut changed = false;
    for &v in vars {
        let at = |d: &[Interval], a: f64, b: f64| -> Result<bool> {
            let mut d = d.to_vec();
            d[v] = Interval::new(a, b).expect("a <= b");
            feasible(&d)
        };
        let (a, b) = (domain[v].lo(), domain[v].hi());
        let current = domain.clone();
        let mut budget = CONTRACT_BUDGET;
        let Some(lo) = edge(a, b, CONTRACT_DEPTH, true, &|x, y| at(&current, x, y), &mut budget)? else { return Ok(None) };
        budget = CONTRACT_BUDGET;
        let hi = edge(lo, b, CONTRACT_DEPTH, false, &|x, y| at(&current, x, y), &mut budget)?.unwrap_or(b);
        if lo > a || hi < b {
            domain[v] = Interval::new(lo, hi).expect("lo <= hi");
            changed = true;
        }
    }
    if !changed {
        return Ok(Some(state));
    }
    // Bisection points are dyadic, so centre and radius are exact.
    let args: Vec<TaylorModel> = (0..space.nvars)
        .map(|v| {
            if vars.contains(&v) {
                TaylorModel::affine(ctx, domain[v].mid(), v, 0.5 * domain[v].width())
            } else {
                TaylorModel::var(ctx, v)
            }
        })
        .collect();
    Ok(Some(crate::tm::compose_all(&state, &args, ctx)))
}

/// The box shrunk, variable by variable, to where `constraints` may hold (interval evaluation,
/// bisection); None if they hold nowhere in it. Only the variables they read can shrink: the
/// others are left as they are (bisecting each of a wide automaton's 1,200 variables against a
/// clock's invariant took most of a run).
fn contract_box(b: &[Interval], constraints: &[Constraint]) -> Result<Option<Vec<Interval>>> {
    let feasible = |x: &[Interval]| -> Result<bool> { Ok(conjunction(constraints, |c| c.on_box(x))? != Some(false)) };
    if constraints.is_empty() {
        return Ok(Some(b.to_vec()));
    }
    if !feasible(b)? {
        return Ok(None);
    }
    let mut read = vec![false; b.len()];
    for c in constraints {
        for (r, &d) in read.iter_mut().zip(&c.margin.dependencies()[0]) {
            *r |= d;
        }
    }
    let mut out = b.to_vec();
    for v in (0..b.len()).filter(|&v| read[v]) {
        let (a, z) = (out[v].lo(), out[v].hi());
        if a == z || !out[v].is_bounded() {
            continue;
        }
        let current = out.clone();
        let at = |lo: f64, hi: f64| -> Result<bool> {
            let mut x = current.clone();
            x[v] = Interval::new(lo, hi).expect("lo <= hi");
            feasible(&x)
        };
        let mut budget = CONTRACT_BUDGET;
        let Some(lo) = edge(a, z, CONTRACT_DEPTH, true, &at, &mut budget)? else { return Ok(None) };
        budget = CONTRACT_BUDGET;
        let hi = edge(lo, z, CONTRACT_DEPTH, false, &at, &mut budget)?.unwrap_or(z);
        out[v] = Interval::new(lo, hi).expect("lo <= hi");
    }
    Ok(Some(out))
}

/// Consecutive states merged where their aggregate is hardly wider than the wider of them (a
/// time-triggered jump found at the end of one step and the start of the next): a branch
/// less for nothing lost. Widths are naive bounds here and in [`aggregate`]: the dominated
/// bounder on every variable of every jump state cost most of a run's time at order 4.
fn merge_alike(states: Vec<Vec<TaylorModel>>, space: &Space) -> Vec<Vec<TaylorModel>> {
    let widths = |s: &[TaylorModel]| -> Vec<f64> { s.iter().map(|m| m.bound(space).width()).collect() };
    let mut out: Vec<Vec<TaylorModel>> = Vec::with_capacity(states.len());
    for s in states {
        if let Some(last) = out.last_mut() {
            let both = aggregate(&[last.clone(), s.clone()], space);
            let (a, b, w) = (widths(last), widths(&s), widths(&both));
            if (0..w.len()).all(|i| w[i] <= 1.001 * a[i].max(b[i]) + 1e-9) {
                *last = both;
                continue;
            }
        }
        out.push(s);
    }
    out
}

/// `states` as at most `most` states (at least one), consecutive ones aggregated.
fn groups(states: &[Vec<TaylorModel>], most: usize, space: &Space, aggregations: &mut usize) -> Vec<Vec<TaylorModel>> {
    if states.len() <= most {
        return states.to_vec();
    }
    *aggregations += 1;
    states.chunks(states.len().div_ceil(most.max(1))).map(|group| aggregate(group, space)).collect()
}

/// One model per variable enclosing all `states`: the middle one's polynomial with a remainder
/// that holds every state's polynomial difference from it plus that state's remainder (keeping
/// the dependence they share), or the hull of
/// their ranges when that is narrower (states of different jump times share little).
pub fn aggregate(states: &[Vec<TaylorModel>], space: &Space) -> Vec<TaylorModel> {
    let reference = &states[states.len() / 2];
    (0..reference.len())
        .map(|i| {
            // s = ref.poly + (s.poly - ref.poly) + s.rem for every state s, the reference too.
            let poly = |m: &TaylorModel| TaylorModel { coef: m.coef.clone(), rem: Interval::ZERO };
            let base = poly(&reference[i]);
            let rem = states.iter().fold(Interval::EMPTY, |acc, s| acc.hull(&(poly(&s[i]).sub(&base).bound(space) + s[i].rem)));
            let kept = base.add_interval(rem);
            let hull = states.iter().fold(Interval::EMPTY, |acc, s| acc.hull(&s[i].bound(space)));
            if hull.width() < kept.bound(space).width() {
                TaylorModel::from_interval(hull)
            } else {
                kept
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parser::parse_expr;
    use crate::{OrderPolicy, Precondition, StepSize};

    fn program(exprs: &[&str], names: &[String]) -> Arc<Program> {
        Arc::new(Program::compile(&exprs.iter().map(|e| parse_expr(e).unwrap()).collect::<Vec<_>>(), names).unwrap())
    }

    /// A ball dropped from x0 in [1, 1.1] bounces (v := -0.8 v) and leaves at t = 0.6.
    fn ball() -> Automaton {
        let names: Vec<String> = ["x", "v", "c"].iter().map(|s| s.to_string()).collect();
        let ode = Ode::new(names.clone(), ["v", "-9.81", "1"].iter().map(|e| parse_expr(e).unwrap()).collect()).unwrap();
        let c = |e: &str, cmp| Constraint { margin: program(&[e], &names), cmp };
        Automaton {
            modes: vec![Mode { name: "fly".into(), ode, invariant: vec![c("x", Cmp::Ge), c("c - 0.6", Cmp::Le)] }],
            jumps: vec![
                Jump {
                    source: 0,
                    target: Target::Mode(0),
                    guard: vec![c("x", Cmp::Le), c("v", Cmp::Le)],
                    reset: Some(program(&["x", "-0.8 * v", "c"], &names)),
                    urgent: false,
                },
                Jump { source: 0, target: Target::Exit, guard: vec![c("c - 0.6", Cmp::Ge)], reset: None, urgent: false },
            ],
            names,
        }
    }

    fn settings(order: usize) -> Settings {
        Settings {
            step: StepSize::Fixed(0.01),
            order: OrderPolicy::Fixed(order),
            t_end: 0.0,
            cutoff: 1e-12,
            remainder_estimate: vec![1e-3; 3],
            precondition: Precondition::Identity,
            refinements: 10,
            symbolic_queue: 100,
        }
    }

    #[test]
    fn bouncing_ball_exits_hold_every_sampled_run() {
        let space = Space::get(4, 5, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 5, 1e-12);
        let init = vec![TaylorModel::affine(&ctx, 1.05, 1, 0.05), TaylorModel::constant(0.0), TaylorModel::constant(0.0)];
        let limits = Limits {
            max_time: 1.0,
            max_jumps: 10,
            max_branches: 8,
            max_exits: 8,
            contract: vec![1],
            drop_past_max_jumps: false,
            box_at_jumps: false,
        };
        let run = run(&ball(), 0, init, &space, &settings(5), &limits).unwrap();
        assert!(run.failure.is_none(), "{:?}", run.failure);
        assert!(!run.exits.is_empty());
        let boxes: Vec<Vec<Interval>> = run.exits.iter().map(|s| s.iter().map(|m| m.bound(&space)).collect()).collect();
        let g = 9.81;
        for k in 0..=200 {
            let x0 = 1.0 + 0.1 * k as f64 / 200.0;
            let hit = (2.0 * x0 / g).sqrt();
            let (vb, s) = (0.8 * g * hit, 0.6 - hit);
            let (x, v) = (vb * s - 0.5 * g * s * s, vb - g * s);
            assert!(
                boxes.iter().any(|b| b[0].inflate(1e-9).contains(x) && b[1].inflate(1e-9).contains(v) && b[2].inflate(1e-9).contains(0.6)),
                "x0 {x0}: ({x}, {v}) not in {boxes:?}"
            );
        }
        // Precise enough to be useful: the runs reach x in [0.39, 0.42], v in [2.08, 2.48].
        let hull = |i: usize| boxes.iter().fold(Interval::EMPTY, |a, b| a.hull(&b[i]));
        assert!(hull(0).width() < 0.3 && hull(1).width() < 0.5, "{boxes:?}");
    }

    #[test]
    fn time_triggered_jumps_are_taken_at_a_step_end() {
        // Clock-driven modes a -> b -> exit with x' = x then x' = -x: x leaves at x0 e^0.3 e^-0.2.
        let names: Vec<String> = ["x", "c"].iter().map(|s| s.to_string()).collect();
        let c = |e: &str, cmp| Constraint { margin: program(&[e], &names), cmp };
        let mode = |name: &str, rhs: &str, until: &str| Mode {
            name: name.into(),
            ode: Ode::new(names.clone(), [rhs, "1"].iter().map(|e| parse_expr(e).unwrap()).collect()).unwrap(),
            invariant: vec![c(&format!("c - {until}"), Cmp::Le)],
        };
        let aut = Automaton {
            modes: vec![mode("a", "x", "0.3"), mode("b", "-x", "0.2")],
            jumps: vec![
                Jump {
                    source: 0,
                    target: Target::Mode(1),
                    guard: vec![c("c - 0.3", Cmp::Ge)],
                    reset: Some(program(&["x", "0"], &names)),
                    urgent: false,
                },
                Jump { source: 1, target: Target::Exit, guard: vec![c("c - 0.2", Cmp::Ge)], reset: None, urgent: false },
            ],
            names,
        };
        let space = Space::get(3, 5, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 5, 1e-12);
        let init = vec![TaylorModel::affine(&ctx, 1.0, 1, 0.1), TaylorModel::constant(0.0)];
        let mut s = settings(5);
        s.step = StepSize::Fixed(0.07); // does not divide 0.3 or 0.2
        s.remainder_estimate = vec![1e-3; 2];
        let run = run(
            &aut,
            0,
            init,
            &space,
            &s,
            &Limits {
                max_time: 1.0,
                max_jumps: 4,
                max_branches: 1,
                max_exits: 1,
                contract: vec![1],
                drop_past_max_jumps: false,
                box_at_jumps: false,
            },
        )
        .unwrap();
        assert!(run.failure.is_none(), "{:?}", run.failure);
        assert_eq!(run.exits.len(), 1);
        let x = run.exits[0][0].bound(&space);
        let factor = (0.1f64).exp();
        assert!(x.contains(0.9 * factor) && x.contains(1.1 * factor), "{x}");
        assert!(x.width() < 0.2 * factor + 1e-6, "{x}");
    }

    #[test]
    fn an_urgent_jump_ends_the_flow_once_every_run_has_taken_it() {
        // x' = 1 with no invariant: only urgency stops the flow; every run leaves at x = 0.5.
        let names: Vec<String> = vec!["x".into()];
        let ode = Ode::new(names.clone(), vec![parse_expr("1").unwrap()]).unwrap();
        let guard = vec![Constraint { margin: program(&["x - 0.5"], &names), cmp: Cmp::Ge }];
        let space = Space::get(3, 4, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 4, 1e-12);
        let init = vec![TaylorModel::affine(&ctx, 0.05, 1, 0.05)];
        let mut s = settings(4);
        s.remainder_estimate = vec![1e-3];
        for urgent in [true, false] {
            let aut = Automaton {
                modes: vec![Mode { name: "go".into(), ode: ode.clone(), invariant: vec![] }],
                jumps: vec![Jump { source: 0, target: Target::Exit, guard: guard.clone(), reset: None, urgent }],
                names: names.clone(),
            };
            let run = run(
                &aut,
                0,
                init.clone(),
                &space,
                &s,
                &Limits {
                    max_time: 2.0,
                    max_jumps: 2,
                    max_branches: 4,
                    max_exits: 1,
                    contract: vec![1],
                    drop_past_max_jumps: false,
                    box_at_jumps: false,
                },
            )
            .unwrap();
            if !urgent {
                assert!(run.failure.is_some_and(|f| f.contains("still in mode 'go'")));
                continue;
            }
            assert!(run.failure.is_none(), "{:?}", run.failure);
            let x = run.exits[0][0].bound(&space);
            // Sound (holds 0.5); each candidate carries its step's time spread, so not tight.
            assert!(x.contains(0.5) && x.lo() >= 0.4 && x.hi() <= 0.62, "{x}");
        }
    }

    #[test]
    fn horizon_runs_end_at_the_horizon_with_every_sampled_run() {
        // The ball without its exit: the runs bounce once before t = 1 and end there.
        let mut aut = ball();
        aut.jumps.truncate(1);
        aut.modes[0].invariant.truncate(1);
        let init = [Interval::new(1.0, 1.1).unwrap(), Interval::ZERO, Interval::ZERO];
        let g = 9.81;
        let exact = |x0: f64, t: f64| {
            let hit = (2.0 * x0 / g).sqrt();
            let (vb, s) = (0.8 * g * hit, t - hit);
            (vb * s - 0.5 * g * s * s, vb - g * s)
        };
        for box_at_jumps in [false, true] {
            let (run, space) = reach(&aut, 0, &init, 1.0, &settings(5), &horizon_limits(box_at_jumps)).unwrap();
            assert!(run.failure.is_none(), "{:?}", run.failure);
            assert!(!run.exits.is_empty() && run.exit_modes.len() == run.exits.len());
            let boxes: Vec<Vec<Interval>> = run.exits.iter().map(|s| s.iter().map(|m| crate::bound::range(m, &space)).collect()).collect();
            for k in 0..=200 {
                let (x, v) = exact(1.0 + 0.1 * k as f64 / 200.0, 1.0);
                assert!(boxes.iter().any(|b| b[0].contains(x) && b[1].contains(v) && b[3].contains(1.0)), "({x}, {v}) not in {boxes:?}");
            }
            // Every segment holds the sampled runs at its times.
            for k in 0..=20 {
                let x0 = 1.0 + 0.1 * k as f64 / 20.0;
                // The segments' time labels and the clock both hold the time.
                let covered = |t: f64, x: f64, v: f64| {
                    run.segments.iter().any(|(_, s)| {
                        s.t0 <= t && t <= s.t1 && s.bounds[3].contains(t) && s.bounds[0].contains(x) && s.bounds[1].contains(v)
                    })
                };
                for i in 0..=50 {
                    let t = i as f64 / 50.0;
                    let hit = (2.0 * x0 / g).sqrt();
                    let (x, v) = if t < hit { (x0 - 0.5 * g * t * t, -g * t) } else { exact(x0, t) };
                    assert!(covered(t, x, v), "x0 {x0}, t {t}: ({x}, {v}) in no segment");
                }
            }
        }
    }

    fn horizon_limits(box_at_jumps: bool) -> Limits {
        Limits {
            max_time: 0.0,
            max_jumps: 10,
            max_branches: 8,
            max_exits: usize::MAX,
            contract: vec![],
            drop_past_max_jumps: true,
            box_at_jumps,
        }
    }

    #[test]
    fn taylor_models_through_jumps_keep_what_boxes_lose() {
        // A rotation whose clock is reset every quarter turn: boxing at each jump wraps the
        // rotated box (about sqrt 2 wider per jump); the models rotate it exactly.
        let names: Vec<String> = ["x", "y", "c"].iter().map(|s| s.to_string()).collect();
        let quarter = std::f64::consts::FRAC_PI_4;
        let c = |e: &str, cmp| Constraint { margin: program(&[e], &names), cmp };
        let aut = Automaton {
            modes: vec![Mode {
                name: "turn".into(),
                ode: Ode::new(names.clone(), ["-y", "x", "1"].iter().map(|e| parse_expr(e).unwrap()).collect()).unwrap(),
                invariant: vec![c(&format!("c - {quarter}"), Cmp::Le)],
            }],
            jumps: vec![Jump {
                source: 0,
                target: Target::Mode(0),
                guard: vec![c(&format!("c - {quarter}"), Cmp::Ge)],
                reset: Some(program(&["x", "y", "0"], &names)),
                urgent: false,
            }],
            names,
        };
        let init = [Interval::new(0.9, 1.1).unwrap(), Interval::new(-0.1, 0.1).unwrap(), Interval::ZERO];
        let t_end = 3.0;
        let mut widths = vec![];
        for box_at_jumps in [false, true] {
            let (run, space) = reach(&aut, 0, &init, t_end, &settings(5), &horizon_limits(box_at_jumps)).unwrap();
            assert!(run.failure.is_none(), "{:?}", run.failure);
            let boxes: Vec<Vec<Interval>> = run.exits.iter().map(|s| s.iter().map(|m| crate::bound::range(m, &space)).collect()).collect();
            for i in 0..=20 {
                for j in 0..=20 {
                    let (x0, y0) = (0.9 + 0.01 * i as f64, -0.1 + 0.01 * j as f64);
                    let (x, y) = (x0 * t_end.cos() - y0 * t_end.sin(), x0 * t_end.sin() + y0 * t_end.cos());
                    assert!(boxes.iter().any(|b| b[0].contains(x) && b[1].contains(y)), "({x}, {y}) not in {boxes:?}");
                }
            }
            let hull = |i: usize| boxes.iter().fold(Interval::EMPTY, |a, b| a.hull(&b[i]));
            widths.push(hull(0).width() + hull(1).width());
        }
        // The exact set is a rotated square of side 0.2: its box is at most 0.57 wide in all.
        assert!(widths[0] < 0.6 && widths[1] > 1.5 * widths[0], "models {}, boxes {}", widths[0], widths[1]);
    }
}
