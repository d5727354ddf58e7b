//! Closed-loop reachability of discrete-time perception-control loops, cell by cell.
//!
//! A loop is: state x (plant states and noise parameters, which have zero dynamics), a chain of
//! stages (networks or expressions) computing named signals from the state and earlier
//! signals, and a plant map x+ = f(x, signals). The state of one cell is a vector of Taylor
//! models over the cell's normalised box, so the dependency between the state and everything
//! computed from it survives from step to step (no boxing in between); networks are applied
//! to Taylor models directly ([`crate::propagate`]) or through the Verisig translation
//! ([`crate::verisig`]). Piecewise plant definitions (`where`, `clip`) take the hull of both
//! branches when the condition is undecided on the set, which is sound; each such step is
//! counted as a branch.
//!
//! A cell whose enclosure is lost (blows up, cannot decide the property, leaves a function's
//! domain, or straddles a `within` goal for several steps) is split in two along the domain
//! variable that matters most, at the last step where its polynomial part still dominated,
//! and both halves continue from there (up to `max_splits` per cell). Restarting halves from
//! step 0 (the cell-level `refine`) repeats every step before the split; this does not.
//!
//! With `state_symbols`, the remainders of the states that feed back are error symbols kept from
//! step to step ([`taylor::error_symbols`]): the cell's space has those symbols after its domain
//! variables, networks carry them as pinned shared symbols, and each step ends by renewing them.
//!
//! A piece whose states, apart from running sums such as a reward, are enclosed by the start of
//! an earlier piece replays that piece's steps instead of computing them ([`Tape`]).
use crate::error::{NetworkError, Result};
use crate::network::Network;
use crate::propagate::{self, Models, Settings as NnSettings};
use crate::verisig;
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;
use taylor::error_symbols::ErrorSymbols;
use taylor::expr::{Intervals, Op, TaylorModels};
use taylor::flowpipe::{reach_from, Ode, Settings as FlowSettings};
use taylor::{Cmp, Ctx, Interval, Program, Space, TaylorModel};

#[derive(Clone, Debug)]
pub enum Component {
    Network(Arc<Network>),
    Expr(Arc<Program>),
}

/// A stage reads signals at `inputs` (indices into the environment: the state first, then
/// the outputs of earlier stages in order) and appends its outputs to the environment.
#[derive(Clone, Debug)]
pub struct Stage {
    pub component: Component,
    pub inputs: Vec<usize>,
}

impl Stage {
    fn n_out(&self) -> usize {
        match &self.component {
            Component::Network(n) => n.n_out(),
            Component::Expr(p) => p.outputs.len(),
        }
    }
}

/// `margin cmp 0` must hold; `margin` is a program over the state.
#[derive(Clone, Debug)]
pub struct Condition {
    pub margin: Arc<Program>,
    pub cmp: Cmp,
    pub label: String,
}

/// How the state moves from one control step to the next.
#[derive(Clone, Debug)]
pub enum Plant {
    /// Inputs: the whole environment; outputs: the next state, in state order.
    Discrete(Arc<Program>),
    /// x' = f(x, u) over one control period with u held: the ODE's variables are the states
    /// followed by the inputs (whose right-hand sides are 0); `inputs` are their environment
    /// indices. Safety is checked on every flowpipe segment of the period.
    Continuous { ode: Arc<Ode>, inputs: Vec<usize>, period: f64, flow: FlowSettings },
}

#[derive(Clone, Debug)]
pub struct ClosedLoop {
    pub state_names: Vec<String>,
    pub stages: Vec<Stage>,
    pub plant: Plant,
    /// Must hold at step 0 and after every step.
    pub safe: Vec<Condition>,
    /// Must hold after the last step, or at some step if `goal_within`.
    pub goal: Option<Condition>,
    pub goal_within: bool,
    pub steps: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    Taylor,
    Verisig,
}

#[derive(Clone, Debug)]
pub struct CellSettings {
    pub order: usize,
    pub cutoff: f64,
    pub method: Method,
    pub nn: NnSettings,
    pub timeout: Option<f64>,
    /// Widths beyond which a state enclosure counts as blown up.
    pub blow_up_width: f64,
    /// Branches allowed per cell: domain splits when a part is lost, and forks of parts at an
    /// expression stage's undecided conditions (0: never; conditions then take the hull).
    pub max_splits: usize,
    /// Restart a part from its box when a remainder is most of a state's enclosure: the
    /// dependency on the initial state is lost, but remainders stop feeding back through the
    /// loop (they can grow geometrically when the controller's correction adds to them).
    pub rebox: bool,
    /// Keep the state's remainders as error symbols from step to step
    /// ([`taylor::error_symbols`]) instead of intervals (Taylor method, discrete plants, no
    /// rebox): their correlations survive the loop, so a controller's correction can cancel an
    /// error instead of adding its magnitude again at every step.
    pub state_symbols: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Every state of the cell satisfies the property.
    Verified,
    /// The engine could not decide; `reason` says where.
    Unknown,
    /// Every state of the cell violates the property at some step (certain, set-level).
    Violated,
}

#[derive(Clone, Debug)]
pub struct CellOutcome {
    pub verdict: Verdict,
    pub reason: Option<String>,
    /// Steps completed (the reach boxes cover steps 0..=steps_done).
    pub steps_done: usize,
    /// State box per step, step 0 first.
    pub boxes: Vec<Vec<Interval>>,
    pub seconds: f64,
    pub nn_seconds: f64,
    pub branches: usize,
    /// Steps a piece replayed from another piece's tape instead of computing them ([`Tape`]).
    pub replayed: usize,
    /// The state the engine would have split next when it gave up (or split most often): a
    /// caller that bisects the cell halves this one, not merely the widest.
    pub split: Option<usize>,
}

impl ClosedLoop {
    /// Checks indices and widths once, before any work.
    pub fn validate(&self) -> Result<()> {
        let n = self.state_names.len();
        if n == 0 {
            return Err(NetworkError::input("the closed loop has no state variables"));
        }
        let mut env = n;
        for (k, stage) in self.stages.iter().enumerate() {
            if let Some(&bad) = stage.inputs.iter().find(|&&i| i >= env) {
                return Err(NetworkError::input(format!("stage {}: input index {bad} is not computed before it", k + 1)));
            }
            let want = match &stage.component {
                Component::Network(net) => net.n_in(),
                Component::Expr(p) => p.inputs.len(),
            };
            if want != stage.inputs.len() {
                return Err(NetworkError::input(format!("stage {}: the component takes {want} inputs but {} are wired to it", k + 1, stage.inputs.len())));
            }
            env += stage.n_out();
        }
        match &self.plant {
            Plant::Discrete(p) if p.inputs.len() != env || p.outputs.len() != n => {
                return Err(NetworkError::input(format!(
                    "the plant must read the {env} signals of the loop and define all {n} states, got {} inputs and {} outputs",
                    p.inputs.len(),
                    p.outputs.len()
                )));
            }
            Plant::Continuous { ode, inputs, period, .. } => {
                if ode.dim() != n + inputs.len() || inputs.iter().any(|&i| i >= env) {
                    return Err(NetworkError::input(format!(
                        "the continuous plant's ODE must have the {n} states then the {} inputs as variables",
                        inputs.len()
                    )));
                }
                if !(*period > 0.0) {
                    return Err(NetworkError::input(format!("the control period must be positive, got {period}")));
                }
            }
            _ => {}
        }
        for c in self.safe.iter().chain(self.goal.iter()) {
            if c.margin.inputs.len() != n || c.margin.outputs.len() != 1 {
                return Err(NetworkError::input(format!("property '{}' must be one expression over the state", c.label)));
            }
        }
        Ok(())
    }
}

fn decide(c: &Condition, state: &[TaylorModel], ctx: &Ctx) -> Result<Option<bool>> {
    let m = c.margin.eval(&TaylorModels { ctx }, state)?;
    let range = taylor::bound::range(&m[0], &ctx.space);
    Ok(c.cmp.decide(range))
}

/// Output Taylor models of a network in `ctx`; the Verisig route adds a time variable, which
/// is evaluated at t = 1 and dropped again.
fn apply_network(net: &Network, inputs: &[TaylorModel], symbols: &ErrorSymbols, settings: &CellSettings) -> Result<Vec<TaylorModel>> {
    if settings.method == Method::Taylor {
        return Ok(propagate::propagate(net, &Models::from_state(inputs, symbols)?, &settings.nn)?.to_state(symbols));
    }
    let ctx = &symbols.ctx;
    let out = verisig::propagate(net, &Models::from_taylor_models(inputs, ctx)?, &settings.nn)?;
    let space = out.space().clone();
    if space.nvars == ctx.space.nvars {
        return Ok(out.to_taylor_models());
    }
    let t = out.time_var().ok_or_else(|| NetworkError::input("Verisig output has an unexpected variable layout"))?;
    let big = Ctx::new(space.clone(), ctx.order, ctx.cutoff);
    let index: std::collections::HashMap<&[u8], usize> = (0..ctx.space.len_upto(ctx.order)).map(|k| (ctx.space.exponents(k), k)).collect();
    Ok(out
        .to_taylor_models()
        .iter()
        .map(|m| {
            let at_end = m.substitute(t, Interval::ONE, &big);
            let mut coef = vec![0.0; ctx.space.len_upto(ctx.order)];
            for (k, &c) in at_end.coef.iter().enumerate() {
                if c != 0.0 {
                    let e = space.exponents(k);
                    let mut key = e.to_vec();
                    key.remove(t);
                    coef[index[&key[..]]] += c;
                }
            }
            TaylorModel { coef, rem: at_end.rem }
        })
        .collect())
}

/// Runs one cell: the initial box `cell` (one interval per state variable).
pub fn verify_cell(lp: &ClosedLoop, cell: &[Interval], settings: &CellSettings) -> CellOutcome {
    let started = Instant::now();
    let mut out = CellOutcome { verdict: Verdict::Unknown, reason: None, steps_done: 0, boxes: Vec::new(), seconds: 0.0, nn_seconds: 0.0, branches: 0, replayed: 0, split: None };
    if let Err(e) = run(lp, cell, settings, &mut out, started) {
        out.verdict = Verdict::Unknown;
        out.reason = Some(e.to_string());
    }
    out.seconds = started.elapsed().as_secs_f64();
    out
}

/// A part of the cell's domain carried through the steps on its own. Its Taylor models are
/// over the whole normalised domain [-1, 1]^n; a split re-parameterises one variable to half
/// of its range (x = ±1/2 + x/2), which keeps every enclosure sound and lets the pieces
/// continue from where their parent was instead of restarting at step 0.
struct Piece {
    step: usize,
    state: Vec<TaylorModel>,
    /// The states of every step so far, oldest first: a lost piece is split at one of them.
    history: Vec<(usize, Vec<TaylorModel>)>,
    /// Where the goal first held on part of the piece: if the piece is lost later, it is split
    /// there so that the arrived part stops.
    arrival: Option<Arrival>,
    /// The goal's margin at every step since then at which it held on part of the piece. A
    /// point of the domain whose margin is positive at one of them has reached the goal; when
    /// that covers the domain the piece is done without a split ([`arrived`]).
    margins: Vec<(usize, TaylorModel)>,
}

impl Piece {
    fn new(step: usize, state: Vec<TaylorModel>, history: Vec<(usize, Vec<TaylorModel>)>, margins: Vec<(usize, TaylorModel)>) -> Piece {
        Piece { step, state, history, arrival: None, margins }
    }
}

/// Steps a piece may straddle the goal without more of its runs arriving before it is split
/// where it first straddled: parts that arrived would otherwise be carried past the goal (where
/// models may not hold) for long.
const ARRIVAL_PATIENCE: usize = 3;

#[derive(Clone)]
struct Arrival {
    step: usize,
    state: Vec<TaylorModel>,
    /// The goal's margin over the piece at that step.
    margin: TaylorModel,
    /// The last step at which the fraction of the piece's runs known to have arrived grew, and
    /// that fraction (see [`arrived`]).
    progress: usize,
    fraction: f64,
}

/// How one piece ended.
enum End {
    /// Every state of the piece satisfies the property.
    Done,
    /// Every state of the piece violates the property (whole-cell violation if there was no split).
    Violated(String),
    /// The engine lost the piece at `step`; splitting it a few steps earlier may help.
    Lost { step: usize, reason: String },
    /// Out of time: nothing more is tried.
    Timeout(String),
    /// An undecided condition of a stage split the piece into these successors.
    Forked(Vec<Piece>),
}

fn run(lp: &ClosedLoop, cell: &[Interval], settings: &CellSettings, out: &mut CellOutcome, started: Instant) -> Result<()> {
    let n = lp.state_names.len();
    if cell.len() != n {
        return Err(NetworkError::input(format!("cell has {} intervals for {n} state variables", cell.len())));
    }
    // Domain variables only for the cell's non-degenerate intervals (v0 = 0, a reward sum r = 0
    // and the like take none): the cost of every operation grows with the number of monomials,
    // C(vars + order, order), so Mountain Car's contrast cells (p, dc of p, v, dc, r) need 21
    // coefficients instead of 126. `rebox` restarts from a box of every state, so it keeps one
    // variable per state.
    let nvars = if settings.rebox { n } else { cell.iter().filter(|iv| iv.lo() < iv.hi()).count().max(1) };
    let symbols = ErrorSymbols::new(nvars, symbol_states(lp, settings), settings.order, settings.cutoff)?;
    let ctx = symbols.ctx.clone();
    let space = ctx.space.clone();
    let state = box_models(cell, &ctx);
    let mut boxes: Vec<Option<Vec<Interval>>> = vec![None; lp.steps + 1];
    boxes[0] = Some(cell.to_vec());
    let mut work = vec![Piece::new(0, state, Vec::new(), Vec::new())];
    // Domain variable -> state: one per non-degenerate interval (every state with rebox).
    let state_of: Vec<usize> = (0..n).filter(|&i| settings.rebox || cell[i].lo() < cell[i].hi()).collect();
    let mut split_count = vec![0usize; space.nvars];
    let mut splits = 0;
    let mut hulls = 0;
    let mut verified = true;
    // Where the boxes stop being complete when the cell stops early: pieces still waiting (and
    // the one that stopped) have put their states into the boxes only up to their own step.
    let mut stopped_at = None;
    let sums = sums(lp, settings);
    let mut tapes: Vec<Tape> = Vec::new();
    while let Some(mut piece) = work.pop() {
        let forks = settings.max_splits.saturating_sub(splits);
        let mut on_tape = (!sums.is_empty()).then(|| {
            let start: Vec<TaylorModel> = piece.state.iter().enumerate().filter(|(i, _)| !sums.contains(i)).map(|(_, m)| m.clone()).collect();
            let k = tapes.iter().position(|t| t.encloses(&start)).unwrap_or_else(|| {
                tapes.push(Tape { start, steps: Vec::new() });
                tapes.len() - 1
            });
            OnTape { tape: &mut tapes[k], sums: &sums, from: piece.step, base: sums.iter().map(|&i| piece.state[i].clone()).collect() }
        });
        match advance(lp, &mut piece, &symbols, settings, forks, out, &mut boxes, &mut hulls, on_tape.as_mut(), started)? {
            End::Done => {}
            End::Forked(pieces) => {
                splits += pieces.len() - 1;
                work.extend(pieces);
            }
            End::Violated(reason) => {
                verified = false;
                stopped_at = Some(piece.step);
                out.verdict = if splits == 0 { Verdict::Violated } else { Verdict::Unknown };
                out.reason = Some(if splits == 0 { reason } else { format!("{reason} (on part of the cell, after {splits} splits)") });
                break;
            }
            End::Timeout(reason) => {
                verified = false;
                stopped_at = Some(piece.step);
                out.reason = Some(reason);
                break;
            }
            End::Lost { step, reason } => {
                // A piece lost after part of it reached the goal is split where that happened,
                // along the variable that decides arrival, if its polynomial part still tells the
                // arrived part apart there; otherwise where the enclosure was last precise.
                let arrival = piece.arrival.take().filter(|a| precise(std::slice::from_ref(&a.margin), &symbols.domain.space, &|m| m.rem.width()));
                let (history, v) = match arrival {
                    Some(arrival) => {
                        let v = split_variable(&[std::slice::from_ref(&arrival.margin)], &symbols.domain.space, symbols.nvars());
                        (vec![(arrival.step, arrival.state)], v)
                    }
                    None => {
                        let before = piece.history.iter().filter(|(s, _)| *s < step.max(1)).count().max(1);
                        let at = piece.history[..before].iter().rposition(|(_, st)| precise(st, &space, &|m| symbols.error_width(m))).unwrap_or(0);
                        // The split state first; the later ones when it shows no dependence yet.
                        let later: Vec<&[TaylorModel]> = piece.history[at..].iter().map(|(_, st)| &st[..]).chain([&piece.state[..]]).collect();
                        let v = split_variable(&later, &space, symbols.nvars());
                        piece.history.truncate(at + 1);
                        (piece.history, v)
                    }
                };
                match v.filter(|_| splits < settings.max_splits) {
                    Some(v) => {
                        let from = history.last().expect("non-empty").0;
                        for half in [-0.5, 0.5] {
                            let history: Vec<_> = history.iter().map(|(k, s)| (*k, restrict_half(s, v, half, &ctx))).collect();
                            // Margins from `from` on are computed again by the halves.
                            let margins = piece
                                .margins
                                .iter()
                                .filter(|(k, _)| *k < from)
                                .map(|(k, m)| (*k, restrict_half(std::slice::from_ref(m), v, half, &symbols.domain).remove(0)))
                                .collect();
                            let state = history.last().expect("non-empty").1.clone();
                            work.push(Piece::new(from, state, history, margins));
                        }
                        splits += 1;
                        split_count[v] += 1;
                    }
                    None => {
                        verified = false;
                        stopped_at = Some(piece.step);
                        out.split = v.and_then(|v| state_of.get(v).copied());
                        out.reason = Some(if splits == 0 { reason } else { format!("{reason} (after {splits} splits)") });
                        break;
                    }
                }
            }
        }
    }
    out.branches = splits + hulls;
    if !verified && out.split.is_none() {
        let most = split_count.iter().enumerate().filter(|(_, &c)| c > 0).max_by_key(|(_, &c)| c).map(|(v, _)| v);
        out.split = most.and_then(|v| state_of.get(v).copied());
    }
    let complete = stopped_at.map(|s| work.iter().map(|p| p.step).fold(s, usize::min));
    out.boxes = boxes.into_iter().take(complete.map_or(usize::MAX, |s| s + 1)).take_while(|b| b.is_some()).map(|b| b.unwrap()).collect();
    out.steps_done = out.boxes.len() - 1;
    if verified {
        out.verdict = Verdict::Verified;
        out.reason = None;
    }
    Ok(())
}

/// The box as Taylor models: the k-th non-degenerate interval is centre + radius x_k over the
/// normalised domain, a point is a constant.
fn box_models(cell: &[Interval], ctx: &Ctx) -> Vec<TaylorModel> {
    let mut next_var = 0;
    cell.iter()
        .map(|iv| {
            let m = iv.mid();
            if iv.lo() == iv.hi() {
                return TaylorModel::constant(m);
            }
            next_var += 1;
            TaylorModel::affine(ctx, m, next_var - 1, (iv.hi() - m).max(m - iv.lo()).next_up())
        })
        .collect()
}

/// The states whose errors become symbols: with the Taylor method and a discrete plant (no
/// rebox), every state whose error can feed back, i.e. that a stage or another state's update
/// reads. Parameters the plant copies (a noise level) stay exact, and a sum that only adds to
/// itself (a reward) cannot wrap: symbols for them would only enlarge every model.
fn symbol_states(lp: &ClosedLoop, settings: &CellSettings) -> Vec<usize> {
    let Plant::Discrete(plant) = &lp.plant else { return vec![] };
    if !settings.state_symbols || settings.method != Method::Taylor || settings.rebox {
        return vec![];
    }
    let deps = plant.dependencies();
    (0..lp.state_names.len())
        .filter(|&i| {
            let copied = matches!(plant.ops[plant.outputs[i]], Op::Input(j) if j == i);
            !copied && steers(lp, &deps, i)
        })
        .collect()
}

/// Whether state `i` steers the loop: a stage reads it, or another state's update does (`deps`:
/// the plant's dependencies per output; the plant reads the environment, the states first).
fn steers(lp: &ClosedLoop, deps: &[Vec<bool>], i: usize) -> bool {
    lp.stages.iter().any(|s| s.inputs.contains(&i)) || (0..lp.state_names.len()).any(|j| j != i && deps[j][i])
}

/// The states that are sums along the run (a reward, a step counter) of a discrete plant:
/// updated as s + g or s - g with g not reading s, and steering nothing. Pieces replay each
/// other's steps through them ([`Tape`]). None with `rebox`, whose boxes drop what a sum's model
/// says about each point of the domain.
fn sums(lp: &ClosedLoop, settings: &CellSettings) -> Vec<usize> {
    let Plant::Discrete(plant) = &lp.plant else { return vec![] };
    if settings.rebox {
        return vec![];
    }
    let deps = plant.dependencies();
    let slots = plant.slot_dependencies();
    let is_own = |slot: usize, i: usize| matches!(plant.ops[slot], Op::Input(k) if k == i);
    (0..lp.state_names.len())
        .filter(|&i| {
            let adds = match plant.ops[plant.outputs[i]] {
                Op::Binary(taylor::BinOp::Add, a, b) => (is_own(a, i) && !slots[b][i]) || (is_own(b, i) && !slots[a][i]),
                Op::Binary(taylor::BinOp::Sub, a, b) => is_own(a, i) && !slots[b][i],
                _ => false,
            };
            adds && !steers(lp, &deps, i)
        })
        .collect()
}

/// The steps of a piece, kept so that a later piece in the same state replays them instead of
/// computing them again. The loop does not change with time and the sums ([`sums`]) steer
/// nothing, so two pieces whose other states are the same models take the same steps, whatever
/// their sums and whatever step they are at: a step's models enclose the successors of every
/// state their predecessors enclose, and what a sum adds over the steps is enclosed by its
/// recorded model's change. At Mountain Car's left wall every run that hits it stops at p = -1.2,
/// v = 0: the pieces forked off at each step at which part of a cell hits it (up to seven per
/// cell, again in each half of a split cell) climb out the same way.
struct Tape {
    /// The states other than the sums where the tape starts.
    start: Vec<TaylorModel>,
    /// The state after each step from there; a sum as what it added since the start.
    steps: Vec<Vec<TaylorModel>>,
}

impl Tape {
    /// Whether the tape's start encloses `start` (the same polynomials, remainders no narrower):
    /// its steps then enclose the successors of every state `start` holds.
    fn encloses(&self, start: &[TaylorModel]) -> bool {
        self.start.iter().zip(start).all(|(t, s)| t.coef == s.coef && t.rem.contains_interval(&s.rem))
    }
}

/// A piece on a tape: it replays the steps the tape has and records those it computes beyond.
struct OnTape<'a> {
    tape: &'a mut Tape,
    sums: &'a [usize],
    /// The piece's step where the tape starts, and its sums there.
    from: usize,
    base: Vec<TaylorModel>,
}

impl OnTape<'_> {
    /// The state after step `step` when the tape has it.
    fn replay(&self, step: usize) -> Option<Vec<TaylorModel>> {
        let mut state = self.tape.steps.get(step - self.from)?.clone();
        for (&i, base) in self.sums.iter().zip(&self.base) {
            state[i] = base.add(&state[i]);
        }
        Some(state)
    }

    /// Keeps the state the piece computed after step `step` when it extends the tape.
    fn record(&mut self, step: usize, state: &[TaylorModel]) {
        if step - self.from == self.tape.steps.len() {
            let mut added = state.to_vec();
            for (&i, base) in self.sums.iter().zip(&self.base) {
                added[i] = state[i].sub(base);
            }
            self.tape.steps.push(added);
        }
    }
}

/// Steps one piece until it satisfies the property, violates it, or is lost.
#[allow(clippy::too_many_arguments)]
fn advance(
    lp: &ClosedLoop,
    piece: &mut Piece,
    symbols: &ErrorSymbols,
    settings: &CellSettings,
    forks: usize,
    out: &mut CellOutcome,
    boxes: &mut [Option<Vec<Interval>>],
    hulls: &mut usize,
    mut tape: Option<&mut OnTape>,
    started: Instant,
) -> Result<End> {
    let ctx = &symbols.ctx;
    let space = &ctx.space;
    loop {
        let step = piece.step;
        if piece.history.last().map(|(s, _)| *s) != Some(step) {
            piece.history.push((step, piece.state.clone()));
        }
        let here = |b: &[Option<Vec<Interval>>]| describe(&lp.state_names, b[step].as_deref().unwrap_or(&[]));
        for c in &lp.safe {
            match decide(c, &piece.state, ctx)? {
                Some(true) => {}
                Some(false) => return Ok(End::Violated(format!("step {step}: '{}' is violated by the whole set", c.label))),
                None => {
                    let reason = format!("step {step}: '{}' could not be decided (reach box {})", c.label, here(boxes));
                    return Ok(End::Lost { step, reason });
                }
            }
        }
        if let Some(g) = &lp.goal {
            if lp.goal_within || step == lp.steps {
                let margin = g.margin.eval(&TaylorModels { ctx }, &piece.state)?.remove(0);
                let decided = g.cmp.decide(taylor::bound::range(&margin, space));
                // A margin kept to say which runs arrived must hold for every value of the step's
                // error symbols (they are renewed every step).
                let margin = symbols.domain_part(&margin);
                match decided {
                    Some(true) => return Ok(End::Done),
                    // Part of the set has arrived; the whole set often arrives a step later, or
                    // its parts arrive at different steps.
                    None if lp.goal_within => {
                        piece.margins.push((step, margin.clone()));
                        let fraction = arrived(&piece.margins, &g.cmp, &symbols.domain);
                        if fraction >= 1.0 {
                            return Ok(End::Done);
                        }
                        // Patience counts from the last step at which more runs were seen to arrive.
                        if let Some(a) = piece.arrival.as_mut().filter(|a| fraction > a.fraction) {
                            (a.progress, a.fraction) = (step, fraction);
                        }
                        match &piece.arrival {
                            _ if step == lp.steps => {
                                let reason = format!("step {step}: goal '{}' could not be decided (reach box {})", g.label, here(boxes));
                                return Ok(End::Lost { step, reason });
                            }
                            None => piece.arrival = Some(Arrival { step, state: piece.state.clone(), margin, progress: step, fraction }),
                            Some(a) if step >= a.progress + ARRIVAL_PATIENCE => {
                                let reason = format!("step {step}: goal '{}' holds on part of the set only since step {}", g.label, a.step);
                                return Ok(End::Lost { step, reason });
                            }
                            Some(_) => {}
                        }
                    }
                    // Parts that arrived earlier may have left the goal again: not a violation.
                    Some(false) if step == lp.steps && piece.margins.is_empty() => {
                        return Ok(End::Violated(format!("step {step}: goal '{}' fails on the whole set", g.label)))
                    }
                    _ if step == lp.steps => {
                        let reason = format!("step {step}: goal '{}' could not be decided (reach box {})", g.label, here(boxes));
                        return Ok(End::Lost { step, reason });
                    }
                    _ => {}
                }
            }
        }
        if step == lp.steps {
            return Ok(End::Done);
        }
        if let Some(limit) = settings.timeout {
            if started.elapsed().as_secs_f64() > limit {
                return Ok(End::Timeout(format!("timeout after {limit} s at step {step}")));
            }
        }
        let replayed = tape.as_ref().and_then(|t| t.replay(step));
        let fresh = replayed.is_none();
        out.replayed += usize::from(!fresh);
        let nexts = match replayed.map(|next| Ok(Ok(vec![next]))).unwrap_or_else(|| one_step(lp, &piece.state, symbols, settings, forks, out, hulls)) {
            Ok(Ok(nexts)) => nexts,
            Err(NetworkError::Input(m)) => return Err(NetworkError::Input(m)),
            Ok(Err(reason)) => return Ok(End::Lost { step: step + 1, reason: format!("step {}: {reason}", step + 1) }),
            Err(e) => return Ok(End::Lost { step: step + 1, reason: format!("step {}: {e}", step + 1) }),
        };
        let mut states = Vec::with_capacity(nexts.len());
        for mut next in nexts {
            // A replayed state was renewed when it was recorded.
            if fresh {
                symbols.renew(&mut next);
            }
            let b: Vec<Interval> = next.iter().map(|m| m.bound(space)).collect();
            if let Some((i, w)) = b.iter().enumerate().find(|(_, w)| !w.is_bounded() || w.width() > settings.blow_up_width) {
                let reason = format!("step {}: the enclosure of '{}' blew up ({w}); split the cell or raise the order", step + 1, lp.state_names[i]);
                return Ok(End::Lost { step: step + 1, reason });
            }
            let next = if settings.rebox && next.iter().zip(&b).any(|(m, r)| m.rem.width() > 0.5 * r.width()) { box_models(&b, ctx) } else { next };
            let slot = &mut boxes[step + 1];
            *slot = Some(match slot.take() {
                None => b,
                Some(old) => old.iter().zip(&b).map(|(a, c)| a.hull(c)).collect(),
            });
            states.push(next);
        }
        if states.len() > 1 {
            let forked = states
                .into_iter()
                .map(|state| Piece { step: step + 1, state, history: piece.history.clone(), arrival: piece.arrival.clone(), margins: piece.margins.clone() })
                .collect();
            return Ok(End::Forked(forked));
        }
        piece.state = states.pop().expect("one successor");
        if let Some(t) = tape.as_mut().filter(|_| fresh) {
            t.record(step, &piece.state);
        }
        piece.step = step + 1;
    }
}

/// Whether the polynomial parts carry the enclosures: every remainder is at most
/// [`PRECISE_REMAINDER`] of its model's range. Splitting a piece pays off from such a state; from
/// a later one the remainders, which splitting cannot shrink, are already large enough to grow on
/// their own: a controller's gain on a state (Mountain Car's u on v: 50-150) feeds them back each
/// step with no sign, so a remainder of a quarter of the range at step 70 is the whole range by
/// step 85 in both halves (measured: 1/4 left 10 of 10 hard composite cells unknown after 16
/// splits, 1/100 verified 8 of them, and the easy cells ran faster).
/// `error` is a model's width beyond its polynomial in the domain variables (its remainder, and
/// its error symbols' terms).
fn precise(models: &[TaylorModel], space: &Space, error: &dyn Fn(&TaylorModel) -> f64) -> bool {
    models.iter().all(|m| error(m) <= PRECISE_REMAINDER * m.bound(space).width())
}

const PRECISE_REMAINDER: f64 = 0.01;

/// One control step from `state`: the stages, then the plant. An expression stage with
/// undecided conditions forks (each branch assumed in turn, see [`taylor::expr::Forking`]) while
/// `forks` allow, so one state may have several successors. Ok(Err(reason)) when a continuous
/// plant's flowpipe or a safety check along it fails.
#[allow(clippy::too_many_arguments)]
fn one_step(
    lp: &ClosedLoop,
    state: &[TaylorModel],
    symbols: &ErrorSymbols,
    settings: &CellSettings,
    forks: usize,
    out: &mut CellOutcome,
    hulls: &mut usize,
) -> Result<std::result::Result<Vec<Vec<TaylorModel>>, String>> {
    let ctx = &symbols.ctx;
    let mut envs = vec![state.to_vec()];
    for stage in &lp.stages {
        let mut grown = Vec::with_capacity(envs.len());
        for (k, env) in envs.iter().enumerate() {
            let inputs: Vec<TaylorModel> = stage.inputs.iter().map(|&i| env[i].clone()).collect();
            // Successors this environment may have: 1 + forks in all, the others keep one each.
            let most = (1 + forks).saturating_sub(grown.len() + envs.len() - k - 1).max(1);
            let alternatives = match &stage.component {
                Component::Network(net) => {
                    let t = Instant::now();
                    let o = apply_network(net, &inputs, symbols, settings)?;
                    out.nn_seconds += t.elapsed().as_secs_f64();
                    vec![o]
                }
                Component::Expr(p) => branches(p, &inputs, ctx, most)?,
            };
            for o in alternatives {
                let mut e = env.clone();
                e.extend(o);
                grown.push(e);
            }
        }
        envs = grown;
    }
    let mut nexts: Vec<Vec<TaylorModel>> = Vec::with_capacity(envs.len());
    for (k, env) in envs.iter().enumerate() {
        let successors = match &lp.plant {
            // A discrete plant's undecided conditions (a wall that some runs hit at this step)
            // fork like a stage's, within the same budget; beyond it they take the hull.
            Plant::Discrete(plant) => {
                let most = (1 + forks).saturating_sub(nexts.len() + envs.len() - k - 1).max(1);
                let alternatives = branches(plant, env, ctx, most)?;
                if alternatives.len() == 1 {
                    let values = plant.eval_all(&TaylorModels { ctx }, env)?;
                    *hulls += count_undecided(plant, &values, ctx);
                }
                alternatives
            }
            Plant::Continuous { ode, inputs, period, flow } => {
                let held: Vec<TaylorModel> = inputs.iter().map(|&i| env[i].clone()).collect();
                match integrate_period(lp, ode, state, &held, *period, flow, ctx)? {
                    Ok(next) => vec![next],
                    Err(reason) => return Ok(Err(reason)),
                }
            }
        };
        for mut next in successors {
            for m in next.iter_mut() {
                m.sweep(ctx);
            }
            nexts.push(next);
        }
    }
    Ok(Ok(nexts))
}

/// The outputs of an expression program on `inputs`, one per branch combination of its
/// undecided conditions, at most `most` of them (conditions beyond take the hull).
fn branches(program: &Program, inputs: &[TaylorModel], ctx: &Ctx, most: usize) -> Result<Vec<Vec<TaylorModel>>> {
    let mut done = Vec::new();
    let mut plans: Vec<Vec<bool>> = vec![Vec::new()];
    while let Some(plan) = plans.pop() {
        let alg = taylor::expr::Forking::new(ctx, &plan);
        let outputs = program.eval(&alg, inputs)?;
        if alg.beyond() && done.len() + plans.len() + 2 <= most {
            for choice in [false, true] {
                let mut more = plan.clone();
                more.push(choice);
                plans.push(more);
            }
        } else {
            done.push(outputs);
        }
    }
    Ok(done)
}

/// The domain variable whose halving shrinks the state's polynomial part most: the largest
/// sum over states of |d state / d x_v| (bounded by sum of k |c_k| over monomials with x_v^k),
/// relative to the state's width. None when no variable is left to split. States that are
/// still one variable of the cell (parameters such as a noise level, carried unchanged) are left
/// out: halving one only halves itself, and its fixed share would outvote the states whose
/// dependence on the cell was lost. Their influence counts through the states that use them
/// (when no state of `states[0]` depends on more than its own variable yet, as at step 0, the
/// first of the later `states` that does tells which variables the states came to depend on;
/// failing that, every state of `states[0]` counts).
/// Only the first `nvars` variables of the models' `space` are candidates (a state's error
/// symbols come after them).
fn split_variable(states: &[&[TaylorModel]], space: &Space, nvars: usize) -> Option<usize> {
    states
        .iter()
        .find_map(|state| best_variable(&moved(state, space), space, nvars))
        .or_else(|| best_variable(&states[0].iter().collect::<Vec<_>>(), space, nvars))
}

fn moved<'a>(state: &'a [TaylorModel], space: &Space) -> Vec<&'a TaylorModel> {
    state.iter().filter(|m| !own_variable(m, space)).collect()
}

fn best_variable(state: &[&TaylorModel], space: &Space, nvars: usize) -> Option<usize> {
    let mut score = vec![0.0f64; nvars];
    for m in state {
        let width = m.bound(space).width();
        if !(width > 0.0) || !width.is_finite() {
            continue;
        }
        for (k, &c) in m.coef.iter().enumerate() {
            for (v, &e) in space.exponents(k).iter().take(nvars).enumerate() {
                score[v] += e as f64 * c.abs() / width;
            }
        }
    }
    score.iter().enumerate().filter(|(_, &s)| s > 0.0).max_by(|a, b| a.1.total_cmp(b.1)).map(|(v, _)| v)
}

/// `c + a x_v` with no other monomial and a remainder that is only rounding (restricting a
/// piece to a half rounds outward): a state that is one cell variable.
fn own_variable(m: &TaylorModel, space: &Space) -> bool {
    let mut terms = m.coef.iter().enumerate().filter(|(k, &c)| c != 0.0 && space.exponents(*k).iter().any(|&e| e > 0));
    match (terms.next(), terms.next()) {
        (Some((k, &a)), None) => space.exponents(k).iter().sum::<u8>() == 1 && m.rem.width() <= 1e-9 * a.abs(),
        _ => false,
    }
}

/// Sub-boxes of the domain [`arrived`] may examine per call: each costs one re-expansion of
/// every margin (tens of microseconds for Mountain Car's 3-variable models).
const COVER_BUDGET: usize = 256;

/// The fraction of the normalised domain (by volume) whose points have a margin in `margins`
/// that satisfies `cmp`, i.e. whose runs reached the goal at one of those steps; 1 when every
/// run did. Bisects the domain; on each sub-box every margin is re-expanded (a rigorous
/// composition) and bounded. Sub-boxes that fail every margin, and those beyond
/// [`COVER_BUDGET`], count as not arrived.
fn arrived(margins: &[(usize, TaylorModel)], cmp: &Cmp, ctx: &Ctx) -> f64 {
    let space = &ctx.space;
    let mut stack: Vec<(Vec<(f64, f64)>, f64)> = vec![(vec![(0.0, 1.0); space.nvars], 1.0)];
    let (mut visited, mut covered) = (0, 0.0);
    while let Some((sub, volume)) = stack.pop() {
        visited += 1;
        if visited > COVER_BUDGET {
            break;
        }
        let args: Vec<TaylorModel> = sub.iter().enumerate().map(|(v, &(c, r))| TaylorModel::affine(ctx, c, v, r)).collect();
        // The most promising undecided margin on this sub-box steers the bisection.
        let mut best: Option<(f64, TaylorModel)> = None;
        let mut done = false;
        for (_, m) in margins {
            let q = m.compose(&args, ctx);
            let range = taylor::bound::range(&q, space);
            match cmp.decide(range) {
                Some(true) => {
                    done = true;
                    break;
                }
                Some(false) => {}
                None => {
                    let promise = if matches!(cmp, Cmp::Gt | Cmp::Ge) { range.hi() } else { -range.lo() };
                    if best.as_ref().is_none_or(|(p, _)| promise > *p) {
                        best = Some((promise, q));
                    }
                }
            }
        }
        if done {
            covered += volume;
            continue;
        }
        // Either every margin fails on the whole sub-box (some of its runs have not arrived), or
        // halves may tell the arrived runs apart.
        let Some(v) = best.and_then(|(_, q)| split_variable(&[std::slice::from_ref(&q)], space, space.nvars)) else {
            continue;
        };
        let (c, r) = sub[v];
        for side in [-0.5, 0.5] {
            let mut half = sub.clone();
            half[v] = (c + side * r, 0.5 * r);
            stack.push((half, 0.5 * volume));
        }
    }
    covered
}

/// The models restricted to the half x_v in [half - 1/2, half + 1/2] of the domain, written
/// over a fresh [-1, 1] variable: x_v = half + x_v / 2 (a rigorous composition). A model without
/// x_v stays as it is, not widened by the composition's rounding: the halves' parameters (a noise
/// level) keep the models of their parent, so their pieces can share tapes ([`Tape`]).
fn restrict_half(state: &[TaylorModel], v: usize, half: f64, ctx: &Ctx) -> Vec<TaylorModel> {
    let args: Vec<TaylorModel> = (0..ctx.space.nvars).map(|w| if w == v { TaylorModel::affine(ctx, half, v, 0.5) } else { TaylorModel::var(ctx, w) }).collect();
    let reads_v = |m: &TaylorModel| m.coef.iter().enumerate().any(|(k, &c)| c != 0.0 && ctx.space.exponents(k)[v] > 0);
    state.iter().map(|m| if reads_v(m) { m.compose(&args, ctx) } else { m.clone() }).collect()
}

/// `model` with each variable v of `from` renamed to v + shift in `to` (same order).
fn shift_vars(model: &TaylorModel, from: &Space, to: &Space, shift: isize) -> Result<TaylorModel> {
    let index: std::collections::HashMap<Vec<u8>, usize> = (0..to.len()).map(|k| (to.exponents(k).to_vec(), k)).collect();
    let mut coef = vec![0.0; to.len()];
    for (k, &c) in model.coef.iter().enumerate() {
        if c == 0.0 {
            continue;
        }
        let mut e = vec![0u8; to.nvars];
        for (v, &x) in from.exponents(k).iter().enumerate() {
            if x > 0 {
                let w = v as isize + shift;
                if w < 0 || w as usize >= to.nvars {
                    return Err(NetworkError::input("a model uses a variable the target space lacks"));
                }
                e[w as usize] = x;
            }
        }
        let target = index.get(&e).ok_or_else(|| NetworkError::input("a model's degree exceeds the target order"))?;
        coef[*target] += c;
    }
    let mut t = TaylorModel { coef, rem: model.rem };
    while t.coef.len() > 1 && t.coef.last() == Some(&0.0) {
        t.coef.pop();
    }
    Ok(t)
}

/// One control period of a continuous plant from the state's Taylor models; Ok(Err(reason))
/// when the flowpipe or a safety check along it fails.
fn integrate_period(
    lp: &ClosedLoop,
    ode: &Ode,
    state: &[TaylorModel],
    held: &[TaylorModel],
    period: f64,
    flow: &FlowSettings,
    ctx: &Ctx,
) -> Result<std::result::Result<Vec<TaylorModel>, String>> {
    let n = state.len();
    let m = ode.dim();
    // The flowpipe works at the cell's order, so its end state maps back into the cell's space.
    let order = ctx.order;
    let flow_space = Space::get(1 + m.max(ctx.space.nvars), order, 1)?;
    let init: Vec<TaylorModel> = state.iter().chain(held).map(|t| shift_vars(t, &ctx.space, &flow_space, 1)).collect::<Result<_>>()?;
    let settings = FlowSettings { t_end: period, order: taylor::OrderPolicy::Fixed(order), ..flow.clone() };
    let fp = reach_from(ode, init, &flow_space, &settings, &mut |_| true)?;
    if let Some(f) = &fp.failure {
        return Ok(Err(f.to_string()));
    }
    for seg in &fp.segments {
        for c in &lp.safe {
            let margin = c.margin.eval(&Intervals, &seg.bounds[..n])?;
            if c.cmp.decide(margin[0]) != Some(true) {
                return Ok(Err(format!("'{}' could not be proved over t in [{:.4}, {:.4}] of the period", c.label, seg.t0, seg.t1)));
            }
        }
    }
    let next = fp.final_state[..n].iter().map(|t| {
        let mut t = shift_vars(t, &flow_space, &ctx.space, -1)?;
        t.sweep(ctx);
        Ok(t)
    });
    Ok(Ok(next.collect::<Result<_>>()?))
}

/// Number of `where` conditions and min/max choices (clip) of the plant that are undecided on
/// the set this step: each is a place where Verisig would branch and we take the hull.
fn count_undecided(plant: &Program, values: &[TaylorModel], ctx: &Ctx) -> usize {
    let undecided = |a: usize, b: usize| values[a].sub(&values[b]).bound(&ctx.space);
    plant
        .ops
        .iter()
        .filter(|op| match op {
            Op::Where { lhs, cmp, rhs, .. } => cmp.decide(undecided(*lhs, *rhs)).is_none(),
            Op::Binary(taylor::BinOp::Min | taylor::BinOp::Max, a, b) => {
                let d = undecided(*a, *b);
                d.lo() < 0.0 && d.hi() > 0.0
            }
            _ => false,
        })
        .count()
}

fn describe(names: &[String], b: &[Interval]) -> String {
    names.iter().zip(b).map(|(n, i)| format!("{n} in [{:.6}, {:.6}]", i.lo(), i.hi())).collect::<Vec<_>>().join(", ")
}

/// Verifies cells in parallel on `workers` threads (all cores when None), calling `done(i, &outcome)`
/// as each cell finishes (from a worker thread), so results can be journaled as they arrive.
/// When `done` returns false no further cell is started; cells not run are None.
pub fn verify_cells(
    lp: &ClosedLoop,
    cells: &[Vec<Interval>],
    settings: &CellSettings,
    workers: Option<usize>,
    done: &(dyn Fn(usize, &CellOutcome) -> bool + Sync),
) -> Result<Vec<Option<CellOutcome>>> {
    use std::sync::atomic::{AtomicBool, Ordering};
    lp.validate()?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(workers.unwrap_or(0))
        .build()
        .map_err(|e| NetworkError::input(format!("could not start worker threads: {e}")))?;
    let stop = AtomicBool::new(false);
    Ok(pool.install(|| {
        cells
            .par_iter()
            .enumerate()
            .map(|(i, c)| {
                if stop.load(Ordering::Relaxed) {
                    return None;
                }
                let o = verify_cell(lp, c, settings);
                if !done(i, &o) {
                    stop.store(true, Ordering::Relaxed);
                }
                Some(o)
            })
            .collect()
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::{Activation, LayerArrays};
    use taylor::parser::parse_expr;
    use taylor::Expr;

    /// x+ = x + 0.1 v, v+ = v + 0.1 u, u = tanh(-g x - g v) over `steps` steps, safe while x <= 2.
    fn feedback_loop(gain: f64, steps: usize) -> (ClosedLoop, Network) {
        let net = Network::new(
            vec![LayerArrays { n_out: 1, n_in: 2, weight: vec![-gain, -gain], bias: vec![0.0], activations: vec![Activation::Tanh] }],
            None,
            None,
        )
        .unwrap();
        let names: Vec<String> = ["x", "v", "u"].iter().map(|s| s.to_string()).collect();
        let plant = Program::compile(&[parse_expr("x + 0.1*v").unwrap(), parse_expr("v + 0.1*u").unwrap()], &names).unwrap();
        let safe = Program::compile(&[parse_expr("x - 2").unwrap()], &names[..2]).unwrap();
        let lp = ClosedLoop {
            state_names: names[..2].to_vec(),
            stages: vec![Stage { component: Component::Network(Arc::new(net.clone())), inputs: vec![0, 1] }],
            plant: Plant::Discrete(Arc::new(plant)),
            safe: vec![Condition { margin: Arc::new(safe), cmp: Cmp::Le, label: "x <= 2".into() }],
            goal: None,
            goal_within: false,
            steps,
        };
        lp.validate().unwrap();
        (lp, net)
    }

    fn loop_settings(state_symbols: bool) -> CellSettings {
        CellSettings {
            order: 4,
            cutoff: 1e-12,
            method: Method::Taylor,
            nn: NnSettings { order: 4, ..NnSettings::default() },
            timeout: None,
            blow_up_width: 1e6,
            max_splits: 0,
            rebox: false,
            state_symbols,
        }
    }

    /// Float runs from a grid of the cell stay in every step's box.
    fn assert_runs_inside(out: &CellOutcome, net: &Network, cell: &[Interval], steps: usize) {
        for a in 0..=10 {
            for b in 0..=10 {
                let at = |iv: Interval, k: usize| (iv.lo() + 0.1 * k as f64 * iv.width()).min(iv.hi());
                let (mut x, mut v) = (at(cell[0], a), at(cell[1], b));
                for step in 0..=steps {
                    let bx = &out.boxes[step];
                    assert!(bx[0].contains(x) && bx[1].contains(v), "step {step}: ({x}, {v}) outside {bx:?}");
                    let u = net.eval(&[x, v]).unwrap()[0];
                    (x, v) = (x + 0.1 * v, v + 0.1 * u);
                }
            }
        }
    }

    #[test]
    fn discrete_loop_encloses_simulations() {
        let (lp, net) = feedback_loop(1.0, 40);
        let cell = [Interval::new(0.5, 0.7).unwrap(), Interval::new(-0.1, 0.1).unwrap()];
        for state_symbols in [false, true] {
            let out = verify_cell(&lp, &cell, &loop_settings(state_symbols));
            assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
            assert_runs_inside(&out, &net, &cell, 40);
        }
    }

    #[test]
    fn state_symbols_stop_the_wrapping_of_a_stiff_feedback() {
        // A stiff controller feeds v's error back into v every step: as intervals the error adds
        // its magnitude each time; as symbols the correction cancels it.
        let steps = 60;
        let (lp, net) = feedback_loop(4.0, steps);
        let cell = [Interval::new(0.5, 0.52).unwrap(), Interval::new(-0.01, 0.01).unwrap()];
        let width = |state_symbols: bool| {
            let out = verify_cell(&lp, &cell, &loop_settings(state_symbols));
            assert_runs_inside(&out, &net, &cell, out.steps_done);
            out.boxes.last().map(|b| b[1].width()).unwrap_or(f64::INFINITY)
        };
        let (intervals, symbols) = (width(false), width(true));
        assert!(symbols < 0.5 * intervals, "symbols {symbols} against intervals {intervals}");
    }

    /// A one-state loop without stages, x+ = `update`, goal x >= 1 at some step up to `steps`.
    fn reach_loop(update: &str, steps: usize) -> ClosedLoop {
        let names = vec!["x".to_string()];
        ClosedLoop {
            state_names: names.clone(),
            stages: vec![],
            plant: Plant::Discrete(Arc::new(Program::compile(&[parse_expr(update).unwrap()], &names).unwrap())),
            safe: vec![],
            goal: Some(Condition {
                margin: Arc::new(Program::compile(&[parse_expr("x - 1").unwrap()], &names).unwrap()),
                cmp: Cmp::Ge,
                label: "x >= 1".into(),
            }),
            goal_within: true,
            steps,
        }
    }

    /// Every one of 1,001 float runs from `x0` meets x >= 1 at some step up to `steps`: what a
    /// "verified" from the cover claims.
    fn all_runs_arrive(update: impl Fn(f64) -> f64, x0: (f64, f64), steps: usize) -> bool {
        (0..=1000).all(|i| {
            let mut x = x0.0 + (x0.1 - x0.0) * i as f64 / 1000.0;
            (0..=steps).any(|_| {
                let arrived = x >= 1.0;
                x = update(x);
                arrived
            })
        })
    }

    fn reach_verdict(update: &str, x0: (f64, f64), steps: usize) -> CellOutcome {
        let settings = CellSettings {
            order: 3,
            cutoff: 1e-12,
            method: Method::Taylor,
            nn: NnSettings::default(),
            timeout: None,
            blow_up_width: 1e6,
            max_splits: 0,
            rebox: false,
            state_symbols: true,
        };
        verify_cell(&reach_loop(update, steps), &[Interval::new(x0.0, x0.1).unwrap()], &settings)
    }

    #[test]
    fn parts_arriving_at_different_steps_verify_without_splits() {
        // x+ = 2.2 - x: x0 >= 1 is in the goal at step 0, x0 < 1 at step 1; neither step holds
        // the whole set, and the set never arrives at once (without splits, this cell was lost).
        let out = reach_verdict("2.2 - x", (0.5, 1.5), 4);
        assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
        assert!(all_runs_arrive(|x| 2.2 - x, (0.5, 1.5), 4));
        // x+ = x: the part below 1 never arrives, so no cover may be claimed.
        let out = reach_verdict("x", (0.5, 1.5), 4);
        assert_eq!(out.verdict, Verdict::Unknown, "{:?}", out.reason);
        // x+ = 0.9 x + 0.2, x_k = 2 - 0.9^k (2 - x0): the runs from 0.5 arrive at step 4, those
        // from 0.95 at step 1, the others in between.
        let out = reach_verdict("0.9*x + 0.2", (0.5, 1.5), 10);
        assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
        assert!(all_runs_arrive(|x| 0.9 * x + 0.2, (0.5, 1.5), 10));
        let out = reach_verdict("0.9*x + 0.2", (0.5, 1.5), 3);
        assert_ne!(out.verdict, Verdict::Verified, "runs from 0.5 are at 0.907 after 3 steps");
        assert!(!all_runs_arrive(|x| 0.9 * x + 0.2, (0.5, 1.5), 3));
    }

    #[test]
    fn a_set_that_left_the_goal_is_not_a_violation() {
        // x+ = 0: the runs from x0 >= 1 reached the goal at step 0, so failing at the horizon is
        // not a violation of the whole set; from [0.2, 0.5] it is.
        let out = reach_verdict("0*x", (0.5, 1.5), 2);
        assert_eq!(out.verdict, Verdict::Unknown, "{:?}", out.reason);
        let out = reach_verdict("0*x", (0.2, 0.5), 2);
        assert_eq!(out.verdict, Verdict::Violated, "{:?}", out.reason);
    }

    /// A sum that only adds to itself (a reward) is not an error-symbol state, but its updates
    /// carry the symbols of the states it sums. Renewing the symbols each step must not leave it
    /// with terms in the old symbols: read as the new ones they cancelled against the next
    /// step's terms, and runs of this rotating loop at order 1 left the sum's box by 1.7e-3.
    #[test]
    fn a_sum_of_renewed_errors_encloses_simulations() {
        let names: Vec<String> = ["x", "y", "s"].iter().map(|s| s.to_string()).collect();
        let exprs = ["0.8*y + x*y", "-0.8*x + x*y", "s + x"].map(|e| parse_expr(e).unwrap());
        let plant = Program::compile(&exprs, &names).unwrap();
        let steps = 25;
        let lp = ClosedLoop { state_names: names, stages: vec![], plant: Plant::Discrete(Arc::new(plant.clone())), safe: vec![], goal: None, goal_within: false, steps };
        let cell = [Interval::new(0.3, 0.4).unwrap(), Interval::new(0.1, 0.2).unwrap(), Interval::point(0.0)];
        let out = verify_cell(&lp, &cell, &CellSettings { order: 1, cutoff: 0.0, ..loop_settings(true) });
        assert_eq!(out.steps_done, steps);
        for a in 0..=60 {
            for b in 0..=60 {
                let mut state = vec![0.3 + 0.1 * a as f64 / 60.0, 0.1 + 0.1 * b as f64 / 60.0, 0.0];
                for (step, bx) in out.boxes.iter().enumerate() {
                    assert!(bx.iter().zip(&state).all(|(iv, &x)| iv.contains(x)), "step {step}: {state:?} outside {bx:?}");
                    let point: Vec<Interval> = state.iter().map(|&x| Interval::point(x)).collect();
                    state = plant.eval(&Intervals, &point).unwrap().iter().map(|iv| iv.mid()).collect();
                }
            }
        }
    }

    /// Runs that hit a wall x = 0 at different steps stop there (x = v = 0) and climb out the
    /// same way: the pieces forked off at each hit replay the first one's steps ([`Tape`]) with
    /// their own sums s (of x, which only these pieces have large: the other piece carries the
    /// runs as if there were no wall). Float runs stay in every step's box, s included.
    #[test]
    fn pieces_that_hit_a_wall_at_different_steps_replay_one_climb_inside_the_simulations() {
        let names: Vec<String> = ["x", "v", "s"].iter().map(|s| s.to_string()).collect();
        let (x, s) = (Expr::var("x"), Expr::var("s"));
        let v1 = parse_expr("v + 0.03 - 0.02*x").unwrap();
        let y = Expr::binary(taylor::BinOp::Add, &x, &v1);
        let zero = Expr::constant(0.0);
        let at_wall = |then: &Expr, otherwise: &Expr| Expr::select(&y, Cmp::Le, &zero, then, otherwise);
        let sum = Expr::binary(taylor::BinOp::Add, &s, &x);
        let plant = Program::compile(&[at_wall(&zero, &y), at_wall(&zero, &v1), sum], &names).unwrap();
        let steps = 30;
        let lp = ClosedLoop { state_names: names, stages: vec![], plant: Plant::Discrete(Arc::new(plant.clone())), safe: vec![], goal: None, goal_within: false, steps };
        let cell = [Interval::new(0.5, 1.2).unwrap(), Interval::point(-0.3), Interval::point(0.0)];
        let out = verify_cell(&lp, &cell, &CellSettings { max_splits: 16, ..loop_settings(false) });
        assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
        assert!(out.replayed >= steps / 2, "{} steps replayed", out.replayed);
        for a in 0..=1000 {
            let mut state = vec![0.5 + 0.7 * a as f64 / 1000.0, -0.3, 0.0];
            for (step, bx) in out.boxes.iter().enumerate() {
                assert!(bx.iter().zip(&state).all(|(iv, &x)| iv.contains(x)), "step {step}: {state:?} outside {bx:?}");
                let point: Vec<Interval> = state.iter().map(|&x| Interval::point(x)).collect();
                state = plant.eval(&Intervals, &point).unwrap().iter().map(|iv| iv.mid()).collect();
            }
        }
    }
}
