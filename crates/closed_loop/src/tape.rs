//! Tapes: pieces in the same state replay each other's steps, and the states whose errors are
//! kept as symbols or summed along the run.
use crate::problem::{ClosedLoop, Plant};
use crate::settings::{CellSettings, Method};
use taylor::expr::Op;
use taylor::TaylorModel;

/// The states whose errors become symbols: with the Taylor method (no rebox), every state whose
/// error can feed back, i.e. that a stage or another state's update (or right-hand side) reads.
/// Parameters a discrete plant copies (a noise level) stay exact, and a sum that only adds to
/// itself (a reward) cannot wrap: symbols for them would only enlarge every model. A continuous
/// plant's flowpipe carries the symbols as variables of its own (constant over the period),
/// so a controller's correction of an earlier error cancels it there too.
pub(crate) fn symbol_states(lp: &ClosedLoop, settings: &CellSettings) -> Vec<usize> {
    if !settings.state_symbols || settings.method != Method::Taylor || settings.rebox {
        return vec![];
    }
    let states = 0..lp.state_names.len();
    match &lp.plant {
        Plant::Discrete(plant) => {
            let deps = plant.dependencies();
            states
                .filter(|&i| {
                    let copied = matches!(plant.ops[plant.outputs[i]], Op::Input(j) if j == i);
                    !copied && steers(lp, &deps, i)
                })
                .collect()
        }
        Plant::Continuous { ode, .. } => {
            let deps = ode.program.dependencies();
            states.filter(|&i| steers(lp, &deps, i)).collect()
        }
        // Jumps and guards are decided on the state's models over the cell's variables only.
        Plant::Hybrid { .. } => vec![],
    }
}

/// Whether state `i` steers the loop: a stage reads it, or another state's update does (`deps`:
/// the plant's dependencies per output; the plant reads the environment, the states first).
pub(crate) fn steers(lp: &ClosedLoop, deps: &[Vec<bool>], i: usize) -> bool {
    lp.stages.iter().any(|s| s.inputs.contains(&i)) || (0..lp.state_names.len()).any(|j| j != i && deps[j][i])
}

/// The states that are sums along the run (a reward, a step counter) of a discrete plant:
/// updated as s + g or s - g with g not reading s, and steering nothing. Pieces replay each
/// other's steps through them ([`Tape`]). None with `rebox`, whose boxes drop what a sum's model
/// says about each point of the domain.
pub(crate) fn sums(lp: &ClosedLoop, settings: &CellSettings) -> Vec<usize> {
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
pub(crate) struct Tape {
    /// The states other than the sums where the tape starts.
    pub(crate) start: Vec<TaylorModel>,
    /// The state after each step from there; a sum as what it added since the start.
    pub(crate) steps: Vec<Vec<TaylorModel>>,
}

impl Tape {
    /// Whether the tape's start encloses `start` (the same polynomials, remainders no narrower):
    /// its steps then enclose the successors of every state `start` holds.
    pub(crate) fn encloses(&self, start: &[TaylorModel]) -> bool {
        self.start.iter().zip(start).all(|(t, s)| t.coef == s.coef && t.rem.contains_interval(&s.rem))
    }
}

/// A piece on a tape: it replays the steps the tape has and records those it computes beyond.
pub(crate) struct OnTape<'a> {
    pub(crate) tape: &'a mut Tape,
    pub(crate) sums: &'a [usize],
    /// The piece's step where the tape starts, and its sums there.
    pub(crate) from: usize,
    pub(crate) base: Vec<TaylorModel>,
}

impl OnTape<'_> {
    /// The state after step `step` when the tape has it.
    pub(crate) fn replay(&self, step: usize) -> Option<Vec<TaylorModel>> {
        let mut state = self.tape.steps.get(step - self.from)?.clone();
        for (&i, base) in self.sums.iter().zip(&self.base) {
            state[i] = base.add(&state[i]);
        }
        Some(state)
    }

    /// Keeps the state the piece computed after step `step` when it extends the tape.
    pub(crate) fn record(&mut self, step: usize, state: &[TaylorModel]) {
        if step - self.from == self.tape.steps.len() {
            let mut added = state.to_vec();
            for (&i, base) in self.sums.iter().zip(&self.base) {
                added[i] = state[i].sub(base);
            }
            self.tape.steps.push(added);
        }
    }
}
