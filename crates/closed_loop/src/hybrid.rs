//! A hybrid plant over one control period: the automaton ([`taylor::hybrid`]) run from the
//! state and the held inputs in the cell's flowpipe space, safety checked on every segment of
//! every branch, the exit states mapped back into the cell's space as the step's successors.
use crate::error::Result;
use crate::step::{shift_vars, unsafe_segment};
use taylor::flowpipe::Settings as FlowSettings;
use taylor::hybrid::{run, Automaton, Limits};
use taylor::{Ctx, Space, TaylorModel};

/// Branches one period follows at once before it aggregates them: the exits are aggregated to the
/// cell's fork budget anyway, and branches kept apart until then keep their jump times apart.
pub(crate) const BRANCHES: usize = 64;

/// At most `limits.max_exits` successors (more exit states are aggregated, counted in `hulls`);
/// Ok(Err(reason)) when a flowpipe, a safety check or the automaton's limits fail.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_period(
    lp: &crate::ClosedLoop,
    step: usize,
    automaton: &Automaton,
    start: usize,
    flow: &FlowSettings,
    limits: Limits,
    state: &[TaylorModel],
    held: &[TaylorModel],
    ctx: &Ctx,
    hulls: &mut usize,
) -> Result<std::result::Result<Vec<Vec<TaylorModel>>, String>> {
    let n = state.len();
    let order = ctx.order;
    let space = Space::get(1 + automaton.names.len().max(ctx.space.nvars), order, 1)?;
    let init: Vec<TaylorModel> = state.iter().chain(held).map(|t| shift_vars(t, &ctx.space, &space, 1)).collect::<Result<_>>()?;
    let settings = FlowSettings { order: taylor::OrderPolicy::Fixed(order), ..flow.clone() };
    let reached = run(automaton, start, init, &space, &settings, &limits)?;
    for (mode, segment) in &reached.segments {
        // A period's length varies with its mode sequence: a condition with a time window is
        // checked on the whole period that meets the window (stronger, so still sound).
        if let Some(reason) = unsafe_segment(lp, [segment], |c, _| c.applies(step as f64, step as f64 + 1.0))? {
            return Ok(Err(format!("{reason} (mode '{}')", automaton.modes[*mode].name)));
        }
    }
    if let Some(reason) = reached.failure {
        return Ok(Err(reason));
    }
    *hulls += reached.aggregations;
    let back = |exit: &Vec<TaylorModel>| -> Result<Vec<TaylorModel>> {
        exit[..n]
            .iter()
            .map(|t| {
                let mut t = shift_vars(t, &space, &ctx.space, -1)?;
                t.sweep(ctx);
                Ok(t)
            })
            .collect()
    };
    Ok(Ok(reached.exits.iter().map(back).collect::<Result<_>>()?))
}
