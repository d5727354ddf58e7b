//! Closed-loop reachability of discrete-time perception-control loops, cell by cell.
//!
//! A loop is: state x (plant states and noise parameters, which have zero dynamics), a chain of
//! stages (networks or expressions) computing named signals from the state and earlier
//! signals, and a plant map x+ = f(x, signals). The state of one cell is a vector of Taylor
//! models over the cell's normalised box, so the dependency between the state and everything
//! computed from it survives from step to step (no boxing in between); networks are applied
//! to Taylor models directly ([`nn2hybrid::propagate`]) or through the Verisig translation
//! ([`nn2hybrid::verisig`]). Piecewise plant definitions (`where`, `clip`) take the hull of both
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
//! an earlier piece replays that piece's steps instead of computing them ([`tape`]).
//!
//! The modules, in the order a cell meets them: [`problem`] (the loop and its property),
//! [`settings`], [`solve`] (cells in parallel; a cell's worklist of pieces), [`step`] (one piece
//! step by step; [`hybrid`] for plants with modes and jumps), [`split`] (where a lost piece is split; arrivals at a goal), [`tape`] (replayed
//! steps, summed and symbolic states), [`outcome`].
pub mod error;
mod hybrid;
pub mod outcome;
pub mod problem;
pub mod settings;
pub mod solve;
pub mod split;
pub mod step;
pub mod tape;
#[cfg(test)]
mod tests;

pub use error::{ReachError, Result};
pub use outcome::{CellOutcome, Verdict};
pub use problem::{ClosedLoop, Component, Condition, Plant, Stage};
pub use settings::{CellSettings, Method};
pub use solve::{verify_cell, verify_cells};
