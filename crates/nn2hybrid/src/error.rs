//! Errors of network construction and set propagation. Each variant maps to one Python
//! exception class of `percver.errors` (see `crates/percver-py/src/error.rs`).
use taylor::TaylorError;
use thiserror::Error;

#[derive(Debug, Clone, Error, PartialEq)]
pub enum NetworkError {
    /// An array of the network has the wrong size. Layers are numbered from 1, as in Verisig files.
    #[error("layer {layer}: {field} {problem}")]
    Shape { layer: usize, field: &'static str, problem: String },
    /// A weight, bias or output-map entry is NaN or infinite.
    #[error("layer {layer}: {field} has the non-finite value {value} at index {index}; every weight must be a finite number")]
    NonFinite { layer: usize, field: &'static str, index: usize, value: f64 },
    /// A malformed argument of propagation: box, settings, input models.
    #[error("{0}")]
    Input(String),
    /// The Verisig translation could not integrate a neuron's ODE over t in [0, 1].
    #[error("Verisig translation, layer {layer} neuron {neuron}: {reason}; split the input box (pieces=) or use the direct method")]
    Integration { layer: usize, neuron: usize, reason: String },
    #[error(transparent)]
    Taylor(#[from] TaylorError),
}

pub type Result<T> = std::result::Result<T, NetworkError>;

impl NetworkError {
    pub fn input(message: impl Into<String>) -> Self {
        NetworkError::Input(message.into())
    }
}
