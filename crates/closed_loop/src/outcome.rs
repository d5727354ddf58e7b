//! What verifying a cell found: its verdict, why, and the reach boxes per step.
use taylor::Interval;

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
    /// Steps completed by the whole cell (the reach boxes cover steps 0..=steps_done): with
    /// splits, the pieces still waiting when the cell stopped hold it back.
    pub steps_done: usize,
    /// The deepest step any piece of the cell reached: where an unknown cell gave up, even
    /// when its boxes stop earlier.
    pub deepest_step: usize,
    /// State box per step, step 0 first.
    pub boxes: Vec<Vec<Interval>>,
    pub seconds: f64,
    pub nn_seconds: f64,
    pub branches: usize,
    /// Steps computed again because a lost piece was split at an earlier step (where its
    /// enclosure was last precise, or where part of it first reached the goal): the work that
    /// cells cut along the split variable ahead of the run would not have spent, unlike a fork
    /// or a split at the step where a piece was lost, whose parts go on from there.
    pub steps_redone: usize,
    /// Steps a piece replayed from another piece's tape instead of computing them ([`Tape`]).
    pub replayed: usize,
    /// The state the engine would have split next when it gave up (or split most often; for a
    /// verified cell, the one it split most often, if any): a caller that bisects the cell
    /// halves this one, not merely the widest.
    pub split: Option<usize>,
}
