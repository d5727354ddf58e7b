//! One piece, step by step: the property checked on its state, the stages and the plant applied
//! (networks on Taylor models, expression stages and discrete plants forking at undecided
//! conditions, continuous plants through a flowpipe per control period).
use crate::error::{ReachError, Result};
use crate::outcome::CellOutcome;
use crate::problem::{ClosedLoop, Component, Condition, Plant};
use crate::settings::{CellSettings, Method};
use crate::split::{arrived, Arrival, End, Piece, ARRIVAL_PATIENCE};
use crate::tape::OnTape;
use nn2hybrid::propagate::{self, Models};
use nn2hybrid::{verisig, Network, NetworkError};
use std::sync::atomic::Ordering;
use std::time::Instant;
use taylor::error_symbols::ErrorSymbols;
use taylor::expr::{Intervals, Op, TaylorModels};
use taylor::flowpipe::{reach_from_checked, Ode, Segment, Settings as FlowSettings};
use taylor::{Ctx, Interval, Program, Space, TaylorModel};

pub(crate) fn decide(c: &Condition, state: &[TaylorModel], ctx: &Ctx) -> Result<Option<bool>> {
    let m = c.margin.eval(&TaylorModels { ctx }, state)?;
    let range = taylor::bound::range(&m[0], &ctx.space);
    Ok(c.cmp.decide(range))
}

/// Output Taylor models of a network in `ctx`; the Verisig route adds a time variable, which
/// is evaluated at t = 1 and dropped again.
pub(crate) fn apply_network(
    net: &Network,
    inputs: &[TaylorModel],
    symbols: &ErrorSymbols,
    settings: &CellSettings,
) -> Result<Vec<TaylorModel>> {
    if settings.method == Method::Taylor {
        return Ok(propagate::propagate(net, &Models::from_state(inputs, symbols)?, &settings.nn)?.to_state(symbols));
    }
    let ctx = &symbols.ctx;
    let out = verisig::propagate(net, &Models::from_taylor_models(inputs, ctx)?, &settings.nn)?;
    let space = out.space().clone();
    if space.nvars == ctx.space.nvars {
        return Ok(out.to_taylor_models());
    }
    let t = out.time_var().ok_or_else(|| ReachError::input("Verisig output has an unexpected variable layout"))?;
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

/// The box as Taylor models: the k-th non-degenerate interval is centre + radius x_k over the
/// normalised domain, a point is a constant.
pub(crate) fn box_models(cell: &[Interval], ctx: &Ctx) -> Vec<TaylorModel> {
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

/// Steps one piece until it satisfies the property, violates it, or is lost.
#[allow(clippy::too_many_arguments)]
pub(crate) fn advance(
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
        out.deepest_step = out.deepest_step.max(step);
        if let Some(progress) = &settings.progress {
            progress.fetch_max(step, Ordering::Relaxed);
        }
        if piece.history.last().map(|(s, _)| *s) != Some(step) {
            piece.history.push((step, piece.state.clone()));
        }
        let here = |b: &[Option<Vec<Interval>>]| describe(&lp.state_names, b[step].as_deref().unwrap_or(&[]));
        for c in lp.safe.iter().filter(|c| c.applies(step as f64, step as f64)) {
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
        let nexts = match replayed
            .map(|next| Ok(Ok(vec![next])))
            .unwrap_or_else(|| one_step(lp, step, &piece.state, symbols, settings, forks, out, hulls))
        {
            Ok(Ok(nexts)) => nexts,
            // Bad input stops the cell; anything else loses only this piece.
            Err(e @ (ReachError::Input(_) | ReachError::Network(NetworkError::Input(_)))) => return Err(e),
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
                let reason =
                    format!("step {}: the enclosure of '{}' blew up ({w}); split the cell or raise the order", step + 1, lp.state_names[i]);
                return Ok(End::Lost { step: step + 1, reason });
            }
            let next = if settings.rebox && next.iter().zip(&b).any(|(m, r)| m.rem.width() > 0.5 * r.width()) {
                box_models(&b, ctx)
            } else {
                next
            };
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
                .map(|state| Piece {
                    step: step + 1,
                    state,
                    history: piece.history.clone(),
                    arrival: piece.arrival.clone(),
                    margins: piece.margins.clone(),
                })
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

/// Control step `step` from `state`: the stages, then the plant. An expression stage with
/// undecided conditions forks (each branch assumed in turn, see [`taylor::expr::Forking`]) while
/// `forks` allow, so one state may have several successors. Ok(Err(reason)) when a continuous
/// plant's flowpipe or a safety check along it fails.
#[allow(clippy::too_many_arguments)]
pub(crate) fn one_step(
    lp: &ClosedLoop,
    step: usize,
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
                match integrate_period(lp, step, ode, state, &held, *period, flow, ctx)? {
                    Ok(next) => vec![next],
                    Err(reason) => return Ok(Err(reason)),
                }
            }
            Plant::Hybrid { automaton, start, inputs, flow, max_time, max_jumps } => {
                let held: Vec<TaylorModel> = inputs.iter().map(|&i| env[i].clone()).collect();
                let most = (1 + forks).saturating_sub(nexts.len() + envs.len() - k - 1).max(1);
                // Contracting the domain re-parameterises it, which the goal's margins kept across
                // steps (`within`) could not follow.
                let contract = if lp.goal_within { vec![] } else { (1..=symbols.domain.space.nvars).collect() };
                let limits = taylor::hybrid::Limits {
                    max_time: *max_time,
                    max_jumps: *max_jumps,
                    max_branches: crate::hybrid::BRANCHES,
                    max_exits: most,
                    contract,
                    drop_past_max_jumps: false,
                    box_at_jumps: false,
                };
                match crate::hybrid::run_period(lp, step, automaton, *start, flow, limits, state, &held, ctx, hulls)? {
                    Ok(next) => next,
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
pub(crate) fn branches(program: &Program, inputs: &[TaylorModel], ctx: &Ctx, most: usize) -> Result<Vec<Vec<TaylorModel>>> {
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

/// `model` with each variable v of `from` renamed to v + shift in `to` (same order).
pub(crate) fn shift_vars(model: &TaylorModel, from: &Space, to: &Space, shift: isize) -> Result<TaylorModel> {
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
                    return Err(ReachError::input("a model uses a variable the target space lacks"));
                }
                e[w as usize] = x;
            }
        }
        let target = index.get(&e).ok_or_else(|| ReachError::input("a model's degree exceeds the target order"))?;
        coef[*target] += c;
    }
    let mut t = TaylorModel { coef, rem: model.rem };
    while t.coef.len() > 1 && t.coef.last() == Some(&0.0) {
        t.coef.pop();
    }
    Ok(t)
}

/// Control period `step` of a continuous plant from the state's Taylor models; Ok(Err(reason))
/// when the flowpipe or a safety check along it fails.
#[allow(clippy::too_many_arguments)]
pub(crate) fn integrate_period(
    lp: &ClosedLoop,
    step: usize,
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
    let flow_ctx = Ctx::new(flow_space.clone(), order, ctx.cutoff);
    // Each segment is checked as it is computed (the period stops at the first that fails).
    let mut unsafe_at: Result<Option<String>> = Ok(None);
    let fp = reach_from_checked(ode, init, &flow_space, &settings, &mut |seg, models| {
        unsafe_at = segment_unsafe(lp, seg, models, &flow_ctx, |c| c.applies_on(step, seg.t0, seg.t1, period));
        matches!(unsafe_at, Ok(None))
    })?;
    if let Some(reason) = unsafe_at? {
        return Ok(Err(reason));
    }
    if let Some(f) = &fp.failure {
        return Ok(Err(f.to_string()));
    }
    let next = fp.final_state[..n].iter().map(|t| {
        let mut t = shift_vars(t, &flow_space, &ctx.space, -1)?;
        t.sweep(ctx);
        Ok(t)
    });
    Ok(Ok(next.collect::<Result<_>>()?))
}

/// Why a safety condition that `applies` on a flowpipe segment fails there (over the states,
/// the segment's first variables), if one does.
pub(crate) fn unsafe_segment<'a>(
    lp: &ClosedLoop,
    segments: impl IntoIterator<Item = &'a Segment>,
    applies: impl Fn(&Condition, &Segment) -> bool,
) -> Result<Option<String>> {
    let n = lp.state_names.len();
    for seg in segments {
        for c in lp.safe.iter().filter(|c| applies(c, seg)) {
            let margin = c.margin.eval(&Intervals, &seg.bounds[..n])?;
            if c.cmp.decide(margin[0]) != Some(true) {
                return Ok(Some(format!("'{}' could not be proved over t in [{:.4}, {:.4}] of the period", c.label, seg.t0, seg.t1)));
            }
        }
    }
    Ok(None)
}

/// Why a safety condition that `applies` fails on a flowpipe segment, if one does: decided on the
/// segment's box first, and where that fails on its Taylor models over the cell's variables and
/// time (`models`, built once), which keep how the states move together.
pub(crate) fn segment_unsafe(
    lp: &ClosedLoop,
    seg: &Segment,
    models: &dyn Fn() -> Vec<TaylorModel>,
    ctx: &Ctx,
    applies: impl Fn(&Condition) -> bool,
) -> Result<Option<String>> {
    let n = lp.state_names.len();
    let mut over_cell: Option<Vec<TaylorModel>> = None;
    for c in lp.safe.iter().filter(|c| applies(c)) {
        if c.cmp.decide(c.margin.eval(&Intervals, &seg.bounds[..n])?[0]) == Some(true) {
            continue;
        }
        let models = over_cell.get_or_insert_with(models);
        let margin = c.margin.eval(&TaylorModels { ctx }, &models[..n])?;
        if c.cmp.decide(taylor::bound::range(&margin[0], &ctx.space)) != Some(true) {
            return Ok(Some(format!("'{}' could not be proved over t in [{:.4}, {:.4}] of the period", c.label, seg.t0, seg.t1)));
        }
    }
    Ok(None)
}

/// Number of `where` conditions and min/max choices (clip) of the plant that are undecided on
/// the set this step: each is a place where Verisig would branch and we take the hull.
pub(crate) fn count_undecided(plant: &Program, values: &[TaylorModel], ctx: &Ctx) -> usize {
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

pub(crate) fn describe(names: &[String], b: &[Interval]) -> String {
    names.iter().zip(b).map(|(n, i)| format!("{n} in [{:.6}, {:.6}]", i.lo(), i.hi())).collect::<Vec<_>>().join(", ")
}
