//! Solving: cells verified in parallel, each a worklist of pieces that advance, fork, split or
//! stop ([`run`]).
use crate::error::{ReachError, Result};
use crate::outcome::{CellOutcome, Verdict};
use crate::problem::ClosedLoop;
use crate::settings::CellSettings;
use crate::split::{precise, restrict_half, split_variable, End, Piece};
use crate::step::{advance, box_models};
use crate::tape::{sums, symbol_states, OnTape, Tape};
use rayon::prelude::*;
use std::time::Instant;
use taylor::error_symbols::ErrorSymbols;
use taylor::{Interval, TaylorModel};

/// Runs one cell: the initial box `cell` (one interval per state variable).
pub fn verify_cell(lp: &ClosedLoop, cell: &[Interval], settings: &CellSettings) -> CellOutcome {
    let started = Instant::now();
    let mut out = CellOutcome {
        verdict: Verdict::Unknown,
        reason: None,
        steps_done: 0,
        deepest_step: 0,
        boxes: Vec::new(),
        seconds: 0.0,
        nn_seconds: 0.0,
        branches: 0,
        steps_redone: 0,
        replayed: 0,
        split: None,
    };
    if let Err(e) = run(lp, cell, settings, &mut out, started) {
        out.verdict = Verdict::Unknown;
        out.reason = Some(e.to_string());
    }
    out.seconds = started.elapsed().as_secs_f64();
    out
}

pub(crate) fn run(lp: &ClosedLoop, cell: &[Interval], settings: &CellSettings, out: &mut CellOutcome, started: Instant) -> Result<()> {
    let n = lp.state_names.len();
    if cell.len() != n {
        return Err(ReachError::input(format!("cell has {} intervals for {n} state variables", cell.len())));
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
            let start: Vec<TaylorModel> =
                piece.state.iter().enumerate().filter(|(i, _)| !sums.contains(i)).map(|(_, m)| m.clone()).collect();
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
                let arrival =
                    piece.arrival.take().filter(|a| precise(std::slice::from_ref(&a.margin), &symbols.domain.space, &|m| m.rem.width()));
                let (history, v) = match arrival {
                    Some(arrival) => {
                        let v = split_variable(&[std::slice::from_ref(&arrival.margin)], &symbols.domain.space, symbols.nvars());
                        (vec![(arrival.step, arrival.state)], v)
                    }
                    None => {
                        let before = piece.history.iter().filter(|(s, _)| *s < step.max(1)).count().max(1);
                        let at = piece.history[..before]
                            .iter()
                            .rposition(|(_, st)| precise(st, &space, &|m| symbols.error_width(m)))
                            .unwrap_or(0);
                        // The split state first; the later ones when it shows no dependence yet.
                        let later: Vec<&[TaylorModel]> =
                            piece.history[at..].iter().map(|(_, st)| &st[..]).chain([&piece.state[..]]).collect();
                        let v = split_variable(&later, &space, symbols.nvars());
                        piece.history.truncate(at + 1);
                        (piece.history, v)
                    }
                };
                let from = history.last().expect("non-empty").0;
                let redone = out.steps_redone + step.saturating_sub(from);
                let within = settings.max_redone.is_none_or(|runs| redone as f64 <= runs * out.deepest_step.max(1) as f64);
                match v.filter(|_| splits < settings.max_splits && within) {
                    Some(v) => {
                        out.steps_redone = redone;
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
                        out.reason = Some(match (splits, within) {
                            (_, false) => format!("{reason} (after {splits} splits; the next would compute steps again past max_redone)"),
                            (0, true) => reason,
                            _ => format!("{reason} (after {splits} splits)"),
                        });
                        break;
                    }
                }
            }
        }
    }
    out.branches = splits + hulls;
    if out.split.is_none() {
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
        .map_err(|e| ReachError::input(format!("could not start worker threads: {e}")))?;
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
