//! Errors of closed-loop verification. Each variant maps to one Python exception class of
//! `percver.errors` (see `crates/percver-py/src/error.rs`).
use nn2hybrid::NetworkError;
use taylor::TaylorError;
use thiserror::Error;

#[derive(Debug, Clone, Error, PartialEq)]
pub enum ReachError {
    /// A malformed loop, cell or setting: wiring, widths, periods.
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Network(#[from] NetworkError),
    #[error(transparent)]
    Taylor(#[from] TaylorError),
}

pub type Result<T> = std::result::Result<T, ReachError>;

impl ReachError {
    pub fn input(message: impl Into<String>) -> Self {
        ReachError::Input(message.into())
    }
}
