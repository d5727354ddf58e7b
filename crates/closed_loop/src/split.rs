//! Splitting: the pieces a cell's domain is carried in, where a lost piece is split (the
//! variable, the step), and how much of a piece has reached a goal.
use taylor::{Cmp, Ctx, Space, TaylorModel};

/// A part of the cell's domain carried through the steps on its own. Its Taylor models are
/// over the whole normalised domain [-1, 1]^n; a split re-parameterises one variable to half
/// of its range (x = ±1/2 + x/2), which keeps every enclosure sound and lets the pieces
/// continue from where their parent was instead of restarting at step 0.
pub(crate) struct Piece {
    pub(crate) step: usize,
    pub(crate) state: Vec<TaylorModel>,
    /// The states of every step so far, oldest first: a lost piece is split at one of them.
    pub(crate) history: Vec<(usize, Vec<TaylorModel>)>,
    /// Where the goal first held on part of the piece: if the piece is lost later, it is split
    /// there so that the arrived part stops.
    pub(crate) arrival: Option<Arrival>,
    /// The goal's margin at every step since then at which it held on part of the piece. A
    /// point of the domain whose margin is positive at one of them has reached the goal; when
    /// that covers the domain the piece is done without a split ([`arrived`]).
    pub(crate) margins: Vec<(usize, TaylorModel)>,
}

impl Piece {
    pub(crate) fn new(
        step: usize,
        state: Vec<TaylorModel>,
        history: Vec<(usize, Vec<TaylorModel>)>,
        margins: Vec<(usize, TaylorModel)>,
    ) -> Piece {
        Piece { step, state, history, arrival: None, margins }
    }
}

/// Steps a piece may straddle the goal without more of its runs arriving before it is split
/// where it first straddled: parts that arrived would otherwise be carried past the goal (where
/// models may not hold) for long.
pub(crate) const ARRIVAL_PATIENCE: usize = 3;

#[derive(Clone)]
pub(crate) struct Arrival {
    pub(crate) step: usize,
    pub(crate) state: Vec<TaylorModel>,
    /// The goal's margin over the piece at that step.
    pub(crate) margin: TaylorModel,
    /// The last step at which the fraction of the piece's runs known to have arrived grew, and
    /// that fraction (see [`arrived`]).
    pub(crate) progress: usize,
    pub(crate) fraction: f64,
}

/// How one piece ended.
pub(crate) enum End {
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

/// Whether the polynomial parts carry the enclosures: every remainder is at most
/// [`PRECISE_REMAINDER`] of its model's range. Splitting a piece pays off from such a state; from
/// a later one the remainders, which splitting cannot shrink, are already large enough to grow on
/// their own: a controller's gain on a state (Mountain Car's u on v: 50-150) feeds them back each
/// step with no sign, so a remainder of a quarter of the range at step 70 is the whole range by
/// step 85 in both halves (measured: 1/4 left 10 of 10 hard composite cells unknown after 16
/// splits, 1/100 verified 8 of them; on the fixed probe's 30 composite cells, all verified either
/// way, 1/4 took 24 branches and 1/100 18). A later split state (a limit of 5%, or a multiple of
/// the piece's least relative error) saves the steps before it, but its halves inherit errors
/// that halving would have shrunk (truncation): it cost NAV splits and lost hard Mountain Car
/// cells that the restart from step 0 verifies (bench/README.md).
/// `error` is a model's width beyond its polynomial in the domain variables (its remainder, and
/// its error symbols' terms).
pub(crate) fn precise(models: &[TaylorModel], space: &Space, error: &dyn Fn(&TaylorModel) -> f64) -> bool {
    models.iter().all(|m| error(m) <= PRECISE_REMAINDER * m.bound(space).width())
}

pub(crate) const PRECISE_REMAINDER: f64 = 0.01;

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
pub(crate) fn split_variable(states: &[&[TaylorModel]], space: &Space, nvars: usize) -> Option<usize> {
    states
        .iter()
        .find_map(|state| best_variable(&moved(state, space), space, nvars))
        .or_else(|| best_variable(&states[0].iter().collect::<Vec<_>>(), space, nvars))
}

pub(crate) fn moved<'a>(state: &'a [TaylorModel], space: &Space) -> Vec<&'a TaylorModel> {
    state.iter().filter(|m| !own_variable(m, space)).collect()
}

pub(crate) fn best_variable(state: &[&TaylorModel], space: &Space, nvars: usize) -> Option<usize> {
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
pub(crate) fn own_variable(m: &TaylorModel, space: &Space) -> bool {
    let mut terms = m.coef.iter().enumerate().filter(|(k, &c)| c != 0.0 && space.exponents(*k).iter().any(|&e| e > 0));
    match (terms.next(), terms.next()) {
        (Some((k, &a)), None) => space.exponents(k).iter().sum::<u8>() == 1 && m.rem.width() <= 1e-9 * a.abs(),
        _ => false,
    }
}

/// Sub-boxes of the domain [`arrived`] may examine per call: each costs one re-expansion of
/// every margin (tens of microseconds for Mountain Car's 3-variable models).
pub(crate) const COVER_BUDGET: usize = 256;

/// The fraction of the normalised domain (by volume) whose points have a margin in `margins`
/// that satisfies `cmp`, i.e. whose runs reached the goal at one of those steps; 1 when every
/// run did. Bisects the domain; on each sub-box every margin is re-expanded (a rigorous
/// composition) and bounded. Sub-boxes that fail every margin, and those beyond
/// [`COVER_BUDGET`], count as not arrived.
pub(crate) fn arrived(margins: &[(usize, TaylorModel)], cmp: &Cmp, ctx: &Ctx) -> f64 {
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
pub(crate) fn restrict_half(state: &[TaylorModel], v: usize, half: f64, ctx: &Ctx) -> Vec<TaylorModel> {
    let args: Vec<TaylorModel> =
        (0..ctx.space.nvars).map(|w| if w == v { TaylorModel::affine(ctx, half, v, 0.5) } else { TaylorModel::var(ctx, w) }).collect();
    let reads_v = |m: &TaylorModel| m.coef.iter().enumerate().any(|(k, &c)| c != 0.0 && ctx.space.exponents(k)[v] > 0);
    state.iter().map(|m| if reads_v(m) { m.compose(&args, ctx) } else { m.clone() }).collect()
}
