//! Which variables of an ODE flow together, and flowpipes of wide ODEs group by group.
//!
//! A flowpipe step gives every state variable a normalised coordinate of its own (a variable
//! of the dense [`Space`]), so an ODE over n variables needs a space of more than n: at most
//! 31. Wide automata are mostly structure, not coupling: in a network translated to modes
//! (Verisig's), a layer's mode moves each neuron's `z' = a z (1 - z)` from its own
//! pre-activation `a`, every other variable is still (`x' = 0`) and the clocks drift
//! (`c' = 1`). So a mode's variables are split by the dependency graph of its right-hand
//! sides into
//! - still variables (right-hand side 0), which keep their models exactly;
//! - drifting ones (a constant right-hand side c, read by no moving variable): x0 + c t;
//! - groups: each set of moving variables connected through what their right-hand sides
//!   read, with the still variables they read as parameters (right-hand side 0 in the group,
//!   so their dependence on the initial set is kept). Each group is integrated on its own,
//!   in a space only as wide as the group; a still variable read by two groups is a parameter
//!   of both (it does not change, so nothing couples them).
//!
//! Groups integrated in the same run share the state's variables (the initial set's symbols)
//! but not their steps: they are run in lockstep, every group one step of the shared time
//! grid at a time (several if it halves its step), so the hybrid run sees the whole state at
//! every step end, as with one flowpipe. Each lockstep step starts a group's flowpipe anew
//! from its state, its interval remainder folded in (no symbolic remainder across steps); a
//! group whose step cannot be enclosed flows on from its entry box, bisected (see [`boxed_flow`]).
//! Where the run boxes its state at every jump anyway (`boxes`), every group flows from its
//! entry box from the start, in a space of its own: what box runners do, and what keeps a wide
//! automaton's boxes at the width of interval propagation (in the run's space, a group reads
//! most of its parameters as interval constants the Picard iteration cannot follow).
use crate::error::{Result, TaylorError};
use crate::expr::{Op, Program};
use crate::flowpipe::{box_models, on_grid, reach_from_steps, time_grid, Ode, Segment, Settings, StepSize};
use crate::interval::Interval;
use crate::space::Space;
use crate::tm::{Ctx, TaylorModel};
use std::sync::Arc;

/// One set of variables integrated together: `vars[..moving]` move, the rest are parameters.
#[derive(Clone, Debug)]
struct Group {
    vars: Vec<usize>,
    moving: usize,
    ode: Ode,
}

/// How a mode's variables flow: see the module's documentation.
#[derive(Clone, Debug)]
pub struct Coupling {
    drifting: Vec<(usize, f64)>,
    groups: Vec<Group>,
    /// Whether the groups are the whole ODE (it fits the space): one flowpipe, as it is.
    whole: bool,
}

/// A mode's variables by how they flow: the drifting ones with their rates, the finest groups
/// (variables, moving first, and how many move) and all moving variables as one group.
struct Split {
    drifting: Vec<(usize, f64)>,
    sets: Vec<(Vec<usize>, usize)>,
    union: (Vec<usize>, usize),
}

impl Split {
    fn of(ode: &Ode) -> Split {
        let n = ode.dim();
        let p = &ode.program;
        let reads = p.dependencies();
        let rate = |i: usize| constant(p, p.outputs[i]);
        let moving: Vec<bool> = (0..n).map(|i| rate(i) != Some(0.0)).collect();
        // Union-find over the moving variables, joined through what they read.
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        let mut read_by_moving = vec![false; n];
        for i in (0..n).filter(|&i| moving[i]) {
            for j in (0..n).filter(|&j| reads[i][j]) {
                read_by_moving[j] |= j != i;
                if moving[j] {
                    let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                    parent[a] = b;
                }
            }
        }
        let mut drifting = vec![];
        let mut members: Vec<Vec<usize>> = vec![vec![]; n];
        for i in (0..n).filter(|&i| moving[i]) {
            match rate(i) {
                Some(c) if !read_by_moving[i] => drifting.push((i, c)),
                _ => {
                    let r = root(&mut parent, i);
                    members[r].push(i);
                }
            }
        }
        let with_parameters = |set: Vec<usize>| -> (Vec<usize>, usize) {
            let parameters: Vec<usize> = (0..n).filter(|&j| !moving[j] && set.iter().any(|&i| reads[i][j])).collect();
            let count = set.len();
            (set.into_iter().chain(parameters).collect(), count)
        };
        let sets: Vec<Vec<usize>> = members.into_iter().filter(|m| !m.is_empty()).collect();
        let union = with_parameters(sets.iter().flatten().copied().collect());
        Split { drifting, sets: sets.into_iter().map(with_parameters).collect(), union }
    }
}

/// The constant value of a program's output slot, if it is one.
fn constant(p: &Program, slot: usize) -> Option<f64> {
    match p.ops[slot] {
        Op::Const(c) => Some(c),
        _ => None,
    }
}

impl Coupling {
    /// The coupling of `ode` for flowpipes of at most `width` variables (a space's variables
    /// but time): the whole ODE if it fits, else all its moving variables in one group if they
    /// fit (with their parameters), else the finest groups; an error if a group exceeds it.
    pub fn of(ode: &Ode, width: usize) -> Result<Coupling> {
        let n = ode.dim();
        if n <= width {
            let all = Group { vars: (0..n).collect(), moving: n, ode: ode.clone() };
            return Ok(Coupling { drifting: vec![], groups: vec![all], whole: true });
        }
        let Split { drifting, sets, union } = Split::of(ode);
        let sets = if union.0.len() <= width { vec![union] } else { sets };
        Coupling::of_sets(ode, drifting, sets, width)
    }

    /// The coupling of `ode` for a run that boxes its state at every jump: its finest groups
    /// whenever there are several, even where the whole ODE fits one flowpipe. Each group then
    /// flows from its own box; one flowpipe over independent groups from fresh symbols made
    /// every model dense in all of them.
    pub fn apart(ode: &Ode, width: usize) -> Result<Coupling> {
        let Split { drifting, sets, .. } = Split::of(ode);
        if sets.len() < 2 {
            return Coupling::of(ode, width);
        }
        Coupling::of_sets(ode, drifting, sets, width)
    }

    /// The groups of `sets` (variables, moving first, and how many move); an error if one
    /// exceeds `width`.
    fn of_sets(ode: &Ode, drifting: Vec<(usize, f64)>, sets: Vec<(Vec<usize>, usize)>, width: usize) -> Result<Coupling> {
        let mut groups = Vec::with_capacity(sets.len());
        for (vars, moving) in sets {
            if vars.len() > width {
                let names: Vec<&str> = vars.iter().take(6).map(|&v| ode.names[v].as_str()).collect();
                return Err(TaylorError::input(format!(
                    "{} variables ({}{}) move together, through what their derivatives read; a Taylor-model flowpipe \
                     integrates at most {width} coupled variables",
                    vars.len(),
                    names.join(", "),
                    if vars.len() > 6 { ", ..." } else { "" }
                )));
            }
            let ode = Ode { names: vars.iter().map(|&v| ode.names[v].clone()).collect(), program: slice(&ode.program, &vars, moving) };
            groups.push(Group { vars, moving, ode });
        }
        Ok(Coupling { drifting, groups, whole: false })
    }

    /// The most variables a flowpipe of `ode` must integrate together (its widest group, with
    /// the group's parameters): the least width [`Coupling::of`] accepts.
    pub fn least_width(ode: &Ode) -> usize {
        Split::of(ode).sets.iter().map(|(vars, _)| vars.len()).max().unwrap_or(0)
    }

    /// The most variables one of its flowpipes integrates.
    pub fn width(&self) -> usize {
        self.groups.iter().map(|g| g.vars.len()).max().unwrap_or(0)
    }

    /// The state at time t of the flow from `entry` given the groups' states `now` (per group,
    /// its moving variables'): still variables as they entered, drifting ones moved by c t.
    fn state(&self, entry: &[TaylorModel], now: &[Vec<TaylorModel>], t: f64) -> Vec<TaylorModel> {
        let mut out = entry.to_vec();
        for &(i, c) in &self.drifting {
            out[i] = entry[i].add(&TaylorModel::from_interval(Interval::point(c) * Interval::point(t)));
        }
        for (g, models) in self.groups.iter().zip(now) {
            for (&v, m) in g.vars.iter().zip(models) {
                out[v] = m.clone();
            }
        }
        out
    }

    /// Bounds over [t0, t1] of every variable: the groups' from `bounds` (per group, its moving
    /// variables'), the rest from the entry's bounds.
    fn bounds(&self, entry: &[Interval], bounds: &[Vec<Interval>], t0: f64, t1: f64) -> Vec<Interval> {
        let mut out = entry.to_vec();
        let span = Interval::new(t0, t1).expect("t0 <= t1");
        for &(i, c) in &self.drifting {
            out[i] = entry[i] + Interval::point(c) * span;
        }
        for (g, b) in self.groups.iter().zip(bounds) {
            for (&v, iv) in g.vars.iter().zip(b) {
                out[v] = *iv;
            }
        }
        out
    }

    /// [`reach_from_steps`] over the whole state of `ode` (whose coupling this is), group by
    /// group: `on_step(t, segment, state)` sees every variable after every step. With `boxes`,
    /// the groups of a split mode flow from their entry boxes (the state at the step ends is
    /// then a box). Returns why the flow stopped early, if it failed.
    pub fn flow(
        &self,
        entry: Vec<TaylorModel>,
        space: &Arc<Space>,
        settings: &Settings,
        boxes: bool,
        on_step: &mut dyn FnMut(f64, &Segment, Vec<TaylorModel>) -> bool,
    ) -> Result<Option<TaylorError>> {
        if self.whole {
            return Ok(reach_from_steps(&self.groups[0].ode, entry, space, settings, on_step)?.failure);
        }
        let entry_bounds: Vec<Interval> = entry.iter().map(|m| m.bound(space)).collect();
        let local = |g: &Group, s: &Settings, state: &[TaylorModel]| -> (Settings, Vec<TaylorModel>) {
            let remainder_estimate = g.vars.iter().map(|&v| s.remainder_estimate[v]).collect();
            (Settings { remainder_estimate, ..s.clone() }, g.vars.iter().map(|&v| state[v].clone()).collect())
        };
        let moving = |g: &Group, models: Vec<TaylorModel>| -> Vec<TaylorModel> { models.into_iter().take(g.moving).collect() };
        if let ([g], false) = (&self.groups[..], boxes) {
            // One group: one flowpipe over the whole time, its symbolic remainders kept.
            let (s, start) = local(g, settings, &entry);
            let mut wrapped = |t: f64, seg: &Segment, models: Vec<TaylorModel>| -> bool {
                let bounds = self.bounds(&entry_bounds, &[seg.bounds[..g.moving].to_vec()], seg.t0, seg.t1);
                let state = self.state(&entry, &[moving(g, models)], t);
                on_step(t, &Segment { bounds, ..seg.clone() }, state)
            };
            return Ok(reach_from_steps(&g.ode, start, space, &s, &mut wrapped)?.failure);
        }
        // Lockstep: the step grid of one flowpipe to t_end, each group one step at a time.
        let (mut h, max) = match settings.step {
            StepSize::Fixed(h) => (h, h),
            StepSize::Adaptive { max, .. } => (max, max),
        };
        let grid = time_grid(settings.t_end);
        let mut t = 0.0;
        let mut state = entry.clone();
        // A group's flow from its box at entry, its variables (the parameters too) the
        // coordinates of a space of its own, over [0, len]: the whole visit if it is short, else
        // at least to `until` and twice the last stretch (a visit that the run stops after a step
        // or two, past a clocked jump, is not integrated to the horizon).
        let from_box = |g: &Group, last: Option<&Boxed>, until: f64| -> std::result::Result<Boxed, TaylorError> {
            let len = match last {
                None if settings.t_end <= STRETCH_STEPS * max => settings.t_end,
                None => until,
                Some(b) => on_grid(2.0 * b.len, grid).max(until),
            };
            let (s, models) = local(g, &Settings { t_end: len.min(settings.t_end), ..settings.clone() }, &entry);
            let entry_box: Vec<Interval> = models.iter().map(|m| crate::bound::range_or_point(m, space)).collect();
            boxed_flow(&g.ode, &entry_box, &s, BOX_SPLITS).map_err(|failure| match failure {
                TaylorError::BlowUp { time_reached, reason } => {
                    let names: Vec<&str> = g.ode.names.iter().map(|n| n.as_str()).collect();
                    let reason = format!("the flow of ({}) from its box, halved up to {BOX_SPLITS} times: {reason}", names.join(", "));
                    TaylorError::BlowUp { time_reached, reason }
                }
                other => other,
            })
        };
        // Groups that flow from their entry box: all of them with `boxes`, else those whose own
        // flowpipe could not be enclosed.
        let mut from_entry = vec![boxes; self.groups.len()];
        let mut boxed: Vec<Option<Boxed>> = vec![None; self.groups.len()];
        while t < settings.t_end {
            let remaining = settings.t_end - t; // exact: both on the grid
            let dt = if h >= remaining * (1.0 - 1e-12) { remaining } else { on_grid(h, grid) };
            let step = match settings.step {
                StepSize::Fixed(_) => StepSize::Fixed(dt),
                StepSize::Adaptive { min, .. } => StepSize::Adaptive { min: min.min(dt), max: dt },
            };
            let mut now = Vec::with_capacity(self.groups.len());
            let mut bounds = Vec::with_capacity(self.groups.len());
            let mut order = 0;
            let mut halved = false;
            for (k, g) in self.groups.iter().enumerate() {
                if from_entry[k] && boxed[k].as_ref().is_none_or(|b| b.len < t + dt) {
                    match from_box(g, boxed[k].as_ref(), t + dt) {
                        Ok(b) => boxed[k] = Some(b),
                        Err(failure) => return Ok(Some(failure)),
                    }
                }
                if let Some(b) = &boxed[k] {
                    bounds.push(b.over(t, t + dt, g.moving));
                    now.push(b.over(t + dt, t + dt, g.moving).into_iter().map(TaylorModel::from_interval).collect());
                    continue;
                }
                let (s, start) = local(g, &Settings { step, t_end: dt, ..settings.clone() }, &state);
                let fp = reach_from_steps(&g.ode, start, space, &s, &mut |_, _, _| true)?;
                if let Some(failure) = fp.failure {
                    let Ok(b) = from_box(g, None, t + dt) else {
                        return Ok(Some(shifted(failure, t)));
                    };
                    bounds.push(b.over(t, t + dt, g.moving));
                    now.push(b.over(t + dt, t + dt, g.moving).into_iter().map(TaylorModel::from_interval).collect());
                    (boxed[k], from_entry[k]) = (Some(b), true);
                    continue;
                }
                halved |= fp.segments.len() > 1;
                order = order.max(fp.segments.iter().map(|s| s.order).max().unwrap_or(0));
                let hull = (0..g.moving).map(|i| fp.segments.iter().fold(Interval::EMPTY, |a, s| a.hull(&s.bounds[i]))).collect();
                bounds.push(hull);
                now.push(moving(g, fp.final_state));
            }
            let seg = Segment { t0: t, t1: t + dt, bounds: self.bounds(&entry_bounds, &bounds, t, t + dt), order };
            t += dt; // exact on the grid
            state = self.state(&entry, &now, t);
            // A group that had to halve holds the next step back as one flowpipe would.
            if matches!(settings.step, StepSize::Adaptive { .. }) {
                h = if halved { 0.5 * dt } else { (dt * 1.1).min(max) };
            }
            if !on_step(t, &seg, state.clone()) {
                break;
            }
        }
        Ok(None)
    }
}

/// Bisections of a group's box before its lockstep step counts as lost (at most 2^6 pieces).
const BOX_SPLITS: usize = 6;

/// Most steps of the longest length in a visit that a group's flow from its box covers at once.
const STRETCH_STEPS: f64 = 32.0;

/// A group's flow over [0, len] of a visit from its box at entry, every piece's segments and
/// its boxes at the ends of its steps.
#[derive(Clone, Default)]
struct Boxed {
    len: f64,
    segments: Vec<Segment>,
    ends: Vec<(f64, Vec<Interval>)>,
}

impl Boxed {
    /// A one-piece flow's box at the end of its last step.
    fn last(&self) -> &[Interval] {
        &self.ends.last().expect("a flow's box at time 0").1
    }

    /// The hull over [t0, t1] of the first `n` variables: every piece's segments that meet
    /// it, or at a single time its boxes there where every piece has a step ending there.
    fn over(&self, t0: f64, t1: f64, n: usize) -> Vec<Interval> {
        let pieces = self.ends.iter().filter(|(t, _)| *t == 0.0).count().max(1);
        let at: Vec<&Vec<Interval>> = self.ends.iter().filter(|(t, _)| t0 == t1 && *t == t1).map(|(_, b)| b).collect();
        let boxes: Vec<&Vec<Interval>> =
            if at.len() == pieces { at } else { self.segments.iter().filter(|s| s.t0 <= t1 && t0 <= s.t1).map(|s| &s.bounds).collect() };
        let mut hull = vec![Interval::EMPTY; n];
        for b in boxes {
            for (h, iv) in hull.iter_mut().zip(b) {
                *h = h.hull(iv);
            }
        }
        hull
    }
}

/// The flow of `ode` from the box `start` up to `settings.t_end`, its widest side halved up
/// to `splits` times where a flowpipe cannot be enclosed or ends much wider than its float
/// solutions spread ([`LOOSENESS`]). A neuron of a translated network, z' = a (1 - z^2), has
/// no Taylor model over a wide pre-activation a (tanh(a t) is too steep), but has one over
/// each part of it; over a in [-1.41, 1.44] one flowpipe of order 4 is enclosed, 45 times
/// wider than tanh's range. It starts from the entry box, where z is a point: restarting from
/// each step's box would lose how z follows a, and the boxes would grow to |z| > 1, where the
/// ODE diverges. The group's state loses its dependence on the initial set (it becomes a box),
/// which is sound and is what a box-based runner keeps throughout. Err(why a piece failed) if
/// the pieces do not suffice and the whole box was not enclosed either.
fn boxed_flow(ode: &Ode, start: &[Interval], settings: &Settings, splits: usize) -> std::result::Result<Boxed, TaylorError> {
    let whole = box_flow(ode, start, settings);
    let widest = (0..start.len()).max_by(|&i, &j| start[i].width().total_cmp(&start[j].width()));
    let Some(widest) = widest.filter(|&i| splits > 0 && start[i].lo() < start[i].hi()) else { return whole };
    if whole.as_ref().is_ok_and(|flow| tight(ode, start, settings.t_end, flow.last())) {
        return whole;
    }
    let side = start[widest];
    let mid = side.mid();
    let mut all = Boxed { len: settings.t_end, ..Boxed::default() };
    for half in [Interval::raw(side.lo(), mid), Interval::raw(mid, side.hi())] {
        let mut piece = start.to_vec();
        piece[widest] = half;
        match boxed_flow(ode, &piece, settings, splits - 1) {
            Ok(flow) => {
                all.segments.extend(flow.segments);
                all.ends.extend(flow.ends);
            }
            Err(failure) => return whole.or(Err(failure)),
        }
    }
    Ok(all)
}

/// How much wider than the spread of float solutions from points of its box a flow's end box may
/// be before the box is halved.
const LOOSENESS: f64 = 1.5;

/// Float RK4 solutions' spread at `t_end` (per variable, max minus min) from points of the box
/// `start`: nine along its widest side (the others at their midpoints) and the corners of its
/// first six uncertain sides (a linear flow's extremes). Only the choice to halve reads it:
/// every bound stays the flowpipes'.
fn sampled_spread(ode: &Ode, start: &[Interval], t_end: f64) -> Result<Vec<f64>> {
    let n = start.len();
    let widest = (0..n).max_by(|&i, &j| start[i].width().total_cmp(&start[j].width())).unwrap_or(0);
    let mut points: Vec<Vec<f64>> = (0..=8)
        .map(|k| {
            let mut x: Vec<f64> = start.iter().map(|iv| iv.mid()).collect();
            x[widest] = start[widest].lo() + start[widest].width() * k as f64 / 8.0;
            x
        })
        .collect();
    let sides: Vec<usize> = (0..n).filter(|&i| start[i].width() > 0.0).take(6).collect();
    for corner in 0..1usize << sides.len() {
        let mut x: Vec<f64> = start.iter().map(|iv| iv.mid()).collect();
        for (b, &i) in sides.iter().enumerate() {
            x[i] = if corner >> b & 1 == 1 { start[i].hi() } else { start[i].lo() };
        }
        points.push(x);
    }
    let batch = crate::expr::FloatBatch::new(points.len());
    let mut x: Vec<Vec<f64>> = (0..n).map(|i| points.iter().map(|p| p[i]).collect()).collect();
    let steps = 200;
    let h = t_end / steps as f64;
    let f = |x: &[Vec<f64>]| ode.program.eval(&batch, x);
    let axpy = |x: &[Vec<f64>], k: &[Vec<f64>], c: f64| -> Vec<Vec<f64>> {
        x.iter().zip(k).map(|(xi, ki)| xi.iter().zip(ki).map(|(a, b)| a + c * b).collect()).collect()
    };
    for _ in 0..steps {
        let k1 = f(&x)?;
        let k2 = f(&axpy(&x, &k1, 0.5 * h))?;
        let k3 = f(&axpy(&x, &k2, 0.5 * h))?;
        let k4 = f(&axpy(&x, &k3, h))?;
        for i in 0..n {
            for j in 0..points.len() {
                x[i][j] += h / 6.0 * (k1[i][j] + 2.0 * k2[i][j] + 2.0 * k3[i][j] + k4[i][j]);
            }
        }
    }
    Ok(x.iter().map(|xi| xi.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b)) - xi.iter().fold(f64::INFINITY, |a, &b| a.min(b))).collect())
}

/// Whether a flow from `start` ending in the box `end` at `t_end` is about as wide as its float
/// solutions spread (or they cannot be computed: then halving is no better informed).
fn tight(ode: &Ode, start: &[Interval], t_end: f64, end: &[Interval]) -> bool {
    match sampled_spread(ode, start, t_end) {
        Ok(spread) => end.iter().zip(&spread).all(|(e, s)| !s.is_finite() || e.width() <= LOOSENESS * s + 1e-3),
        Err(_) => true,
    }
}

/// One flowpipe of `ode` from the box `start` (as [`reach`] starts it), with the box of its
/// state at time 0 and at the end of every step; Err(why) if it cannot be enclosed.
fn box_flow(ode: &Ode, start: &[Interval], settings: &Settings) -> std::result::Result<Boxed, TaylorError> {
    let space = Space::get(start.len() + 1, settings.max_order(), 1)?;
    let ctx = Ctx::new(space.clone(), settings.max_order(), settings.cutoff);
    let models = box_models(start, &ctx);
    let mut ends = vec![(0.0, start.to_vec())];
    let fp = reach_from_steps(ode, models, &space, settings, &mut |t, _, state| {
        // The dominated bounder where the visit's clocked jumps read the state, naive elsewhere.
        let bound = if t == settings.t_end { crate::bound::range } else { TaylorModel::bound };
        ends.push((t, state.iter().map(|m| bound(m, &space)).collect()));
        true
    })?;
    match fp.failure {
        None => Ok(Boxed { len: settings.t_end, segments: fp.segments, ends }),
        Some(failure) => Err(failure),
    }
}

/// A failure of a group's flowpipe started at time `t0`, with the time counted from the start.
fn shifted(failure: TaylorError, t0: f64) -> TaylorError {
    match failure {
        TaylorError::BlowUp { time_reached, reason } => TaylorError::BlowUp { time_reached: t0 + time_reached, reason },
        other => other,
    }
}

/// The program computing the right-hand sides of `vars[..moving]` (0 for the rest) from `vars`:
/// the operations they need, inputs renumbered.
fn slice(p: &Program, vars: &[usize], moving: usize) -> Program {
    let operands = |op: &Op| -> Vec<usize> {
        match *op {
            Op::Const(_) | Op::Uncertain { .. } | Op::Input(_) => vec![],
            Op::Neg(a) | Op::PowI(a, _) | Op::PowF(a, _) | Op::Func(_, a) => vec![a],
            Op::Binary(_, a, b) => vec![a, b],
            Op::Where { lhs, rhs, then, otherwise, .. } => vec![lhs, rhs, then, otherwise],
        }
    };
    let mut needed = vec![false; p.ops.len()];
    for &v in &vars[..moving] {
        needed[p.outputs[v]] = true;
    }
    for s in (0..p.ops.len()).rev() {
        if needed[s] {
            for a in operands(&p.ops[s]) {
                needed[a] = true;
            }
        }
    }
    let mut at = vec![usize::MAX; p.ops.len()];
    let mut ops = Vec::new();
    for (s, op) in p.ops.iter().enumerate().filter(|(s, _)| needed[*s]) {
        let m = |a: usize| at[a];
        let new = match *op {
            Op::Input(k) => Op::Input(vars.iter().position(|&v| v == k).expect("a group holds what it reads")),
            Op::Neg(a) => Op::Neg(m(a)),
            Op::PowI(a, e) => Op::PowI(m(a), e),
            Op::PowF(a, e) => Op::PowF(m(a), e),
            Op::Func(f, a) => Op::Func(f, m(a)),
            Op::Binary(b, x, y) => Op::Binary(b, m(x), m(y)),
            Op::Where { lhs, cmp, rhs, then, otherwise } => {
                Op::Where { lhs: m(lhs), cmp, rhs: m(rhs), then: m(then), otherwise: m(otherwise) }
            }
            ref other => other.clone(),
        };
        at[s] = ops.len();
        ops.push(new);
    }
    let mut outputs: Vec<usize> = vars[..moving].iter().map(|&v| at[p.outputs[v]]).collect();
    if moving < vars.len() {
        ops.push(Op::Const(0.0));
        outputs.resize(vars.len(), ops.len() - 1);
    }
    Program { inputs: vars.iter().map(|&v| p.inputs[v].clone()).collect(), ops, outputs }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flowpipe::reach;
    use crate::parser::parse_expr;
    use crate::tm::Ctx;
    use crate::{OrderPolicy, Precondition};

    fn ode(pairs: &[(&str, &str)]) -> Ode {
        let names = pairs.iter().map(|(n, _)| n.to_string()).collect();
        Ode::new(names, pairs.iter().map(|(_, e)| parse_expr(e).unwrap()).collect()).unwrap()
    }

    #[test]
    fn a_layer_mode_splits_into_neurons_with_their_pre_activations() {
        let o = ode(&[("z1", "a1 * z1 * (1 - z1)"), ("z2", "a2 * (1 - z2 * z2)"), ("a1", "0"), ("a2", "0"), ("y", "0"), ("c", "1")]);
        assert_eq!(Coupling::least_width(&o), 2);
        let c = Coupling::of(&o, 2).unwrap();
        assert!(!c.whole);
        assert_eq!(c.drifting, vec![(5, 1.0)]);
        let vars: Vec<&[usize]> = c.groups.iter().map(|g| &g.vars[..]).collect();
        assert_eq!(vars, vec![&[0, 2][..], &[1, 3][..]]);
        // A sliced program computes what the whole one does for its variables.
        let x = [0.3, -0.2, 1.5, -2.0, 7.0, 0.0];
        let whole = o.program.eval(&crate::expr::Intervals, &x.map(Interval::point)).unwrap();
        for g in &c.groups {
            let local: Vec<Interval> = g.vars.iter().map(|&v| Interval::point(x[v])).collect();
            let part = g.ode.program.eval(&crate::expr::Intervals, &local).unwrap();
            assert_eq!(part[0], whole[g.vars[0]]);
            assert_eq!(part[1], Interval::ZERO);
        }
        // All moving variables and their parameters fit four: one group; six: the whole ODE.
        assert_eq!(Coupling::of(&o, 4).unwrap().groups.len(), 1);
        assert!(Coupling::of(&o, 6).unwrap().whole);
        // Coupled through what they read: x reads y, so they are one group, too wide for 1.
        let coupled = ode(&[("x", "y"), ("y", "-x"), ("k", "0")]);
        assert!(Coupling::of(&coupled, 1).unwrap_err().to_string().contains("2 variables (x, y) move together"));
    }

    #[test]
    fn grouped_flows_hold_every_sampled_solution() {
        // Three rotations x' = w y, y' = -w x at uncertain rates w, a still variable and a
        // clock, integrated group by group in a space of four variables (the whole ODE has
        // 11): every step's box and the final models hold the exact solutions.
        let mut pairs = vec![];
        let names: Vec<(String, String, String)> = (0..3).map(|i| (format!("x{i}"), format!("y{i}"), format!("w{i}"))).collect();
        let rhs: Vec<(String, String)> = names.iter().map(|(x, y, w)| (format!("{w} * {y}"), format!("-{w} * {x}"))).collect();
        for ((x, y, _), (fx, fy)) in names.iter().zip(&rhs) {
            pairs.push((x.as_str(), fx.as_str()));
            pairs.push((y.as_str(), fy.as_str()));
        }
        for (_, _, w) in &names {
            pairs.push((w.as_str(), "0"));
        }
        pairs.extend([("s", "0"), ("c", "1")]);
        let o = ode(&pairs);
        let space = Space::get(4, 6, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 6, 1e-14);
        let coupling = Coupling::of(&o, 3).unwrap();
        assert_eq!(coupling.groups.len(), 3);
        // x0 in [0.9, 1.1] (symbol 1), w in [0.8, 1.2] (symbol 2, shared by the first pair;
        // the others' rates are interval constants), y0 = 0.
        let mut start = vec![TaylorModel::constant(0.0); 11];
        for i in 0..3 {
            start[2 * i] = TaylorModel::affine(&ctx, 1.0, 1, 0.1);
            start[6 + i] =
                if i == 0 { TaylorModel::affine(&ctx, 1.0, 2, 0.2) } else { TaylorModel::from_interval(Interval::new(0.8, 1.2).unwrap()) };
        }
        start[9] = TaylorModel::constant(2.0);
        let settings = Settings {
            step: StepSize::Adaptive { min: 1e-3, max: 0.1 },
            order: OrderPolicy::Fixed(6),
            t_end: 1.5,
            cutoff: 1e-14,
            remainder_estimate: vec![1e-6; 11],
            precondition: Precondition::Identity,
            refinements: 10,
            symbolic_queue: 50,
        };
        let (segments, last) = flow_through(&coupling, start, &space, &settings, false);
        assert_eq!(last.0, 1.5);
        for a in 0..=10 {
            for b in 0..=10 {
                let (u, v) = (-1.0 + 0.2 * a as f64, -1.0 + 0.2 * b as f64);
                let (x0, w) = (1.0 + 0.1 * u, 1.0 + 0.2 * v);
                let exact = |t: f64| (x0 * (w * t).cos(), -x0 * (w * t).sin());
                for seg in &segments {
                    for t in [seg.t0, 0.5 * (seg.t0 + seg.t1), seg.t1] {
                        let (x, y) = exact(t);
                        for i in 0..3 {
                            assert!(seg.bounds[2 * i].contains(x) && seg.bounds[2 * i + 1].contains(y), "t {t}: ({x}, {y}) pair {i}");
                        }
                        assert!(seg.bounds[9].contains(2.0) && seg.bounds[10].contains(t));
                    }
                }
                // The first pair's models at the point's own symbols.
                let mut point = vec![Interval::ZERO; 4];
                (point[1], point[2]) = (Interval::point(u), Interval::point(v));
                let (x, y) = exact(1.5);
                let at = |i: usize| last.1[i].eval_interval(&space, &point).inflate(1e-12);
                assert!(at(0).contains(x) && at(1).contains(y), "({x}, {y}) not in ({}, {})", at(0), at(1));
                assert!(at(10).contains(1.5) && at(9).contains(2.0));
            }
        }
        // Models over the symbols keep the first pair tight (the rotation's own spread).
        assert!(last.1[0].bound(&space).width() < 0.9, "{}", last.1[0].bound(&space));
    }

    #[test]
    fn a_steep_neuron_flows_from_its_bisected_box() {
        // Two tanh neurons z' = a (1 - z^2), z(0) = 0, over wide pre-activations a: no Taylor
        // model of order 4 follows tanh(a t) for a in [-8, 8] in one piece, its bisected box
        // does; every step's box and the final box hold tanh(a t) for sampled a.
        let o = ode(&[("z1", "a1 * (1 - z1 * z1)"), ("z2", "a2 * (1 - z2 * z2)"), ("a1", "0"), ("a2", "0"), ("c", "1")]);
        let space = Space::get(3, 4, 1).unwrap();
        let ctx = Ctx::new(space.clone(), 4, 1e-14);
        let coupling = Coupling::of(&o, 2).unwrap();
        assert_eq!(coupling.groups.len(), 2);
        let mut start = vec![TaylorModel::constant(0.0); 5];
        start[2] = TaylorModel::affine(&ctx, 0.0, 1, 8.0);
        start[3] = TaylorModel::affine(&ctx, 0.5, 2, 0.5);
        let settings = Settings {
            step: StepSize::Fixed(0.05),
            order: OrderPolicy::Fixed(4),
            t_end: 1.0,
            cutoff: 1e-14,
            remainder_estimate: vec![1e-4; 5],
            precondition: Precondition::Identity,
            refinements: 10,
            symbolic_queue: 50,
        };
        // The whole box in one flowpipe fails (the reason a bisection is needed at all).
        let one = ode(&[("z", "a * (1 - z * z)"), ("a", "0")]);
        let lone = reach(&one, &[Interval::ZERO, Interval::new(-8.0, 8.0).unwrap()], &settings_for(&settings, 2), &mut |_| true).unwrap();
        assert!(lone.failure.is_some());
        let (segments, last) = flow_through(&coupling, start, &space, &settings, false);
        assert_eq!(last.0, 1.0);
        for k in 0..=200 {
            let (a1, a2) = (-8.0 + 0.08 * k as f64, 1.0 * k as f64 / 200.0);
            for seg in &segments {
                for t in [seg.t0, 0.5 * (seg.t0 + seg.t1), seg.t1] {
                    assert!(seg.bounds[0].contains((a1 * t).tanh()), "z1 at t {t}, a1 {a1}: {}", seg.bounds[0]);
                    assert!(seg.bounds[1].contains((a2 * t).tanh()), "z2 at t {t}, a2 {a2}: {}", seg.bounds[1]);
                }
            }
            assert!(last.1[0].bound(&space).contains(a1.tanh()) && last.1[1].bound(&space).contains(a2.tanh()));
        }
        // A box, loose but bounded: within 2.5 times the true range [-tanh 8, tanh 8] (the
        // pieces' remainders grow where the neuron saturates).
        assert!(last.1[0].bound(&space).width() < 5.0, "{}", last.1[0].bound(&space));
    }

    /// Every segment of a coupled flow that must not fail, and its last time and models.
    fn flow_through(
        coupling: &Coupling,
        start: Vec<TaylorModel>,
        space: &Arc<Space>,
        settings: &Settings,
        boxes: bool,
    ) -> (Vec<Segment>, (f64, Vec<TaylorModel>)) {
        let mut segments = vec![];
        let mut last = (0.0, vec![]);
        let failure = coupling
            .flow(start, space, settings, boxes, &mut |t, seg, state| {
                segments.push(seg.clone());
                last = (t, state);
                true
            })
            .unwrap();
        assert!(failure.is_none(), "{failure:?}");
        (segments, last)
    }

    fn settings_for(s: &Settings, n: usize) -> Settings {
        Settings { remainder_estimate: vec![s.remainder_estimate[0]; n], ..s.clone() }
    }
}
