//! Errors of the validated-numerics core. Each variant maps to one Python exception class.
use thiserror::Error;

#[derive(Debug, Clone, Error, PartialEq)]
pub enum TaylorError {
    /// A malformed argument (empty or NaN interval, order 0, negative step, ...).
    #[error("{0}")]
    Input(String),
    /// A function applied outside its domain on a set that is not entirely inside it.
    #[error("{function} is undefined on {argument}: {hint}")]
    Domain { function: &'static str, argument: String, hint: &'static str },
    /// Text that does not parse; `position` is a byte offset into `source`.
    #[error("{message} at column {column} of '{source_text}'")]
    Parse { message: String, column: usize, source_text: String },
    /// The integrator could not enclose the flow any more.
    #[error("flowpipe could not be enclosed after t = {time_reached}: {reason}; try a smaller step, a higher order or a larger remainder estimate")]
    BlowUp { time_reached: f64, reason: String },
}

pub type Result<T> = std::result::Result<T, TaylorError>;

impl TaylorError {
    pub fn input(message: impl Into<String>) -> Self {
        TaylorError::Input(message.into())
    }
}
