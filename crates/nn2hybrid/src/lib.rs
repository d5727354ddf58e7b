//! `nn2hybrid`: feed-forward networks as sound set maps.
//!
//! [`network`] holds the IR; [`propagate`] bounds a network over a box or over Taylor models
//! directly (matrix products on coefficient matrices, polynomial activation enclosures from
//! [`activation`], ReLU ranges tightened by back-substitution in `crown`, layers that read one
//! input alone over that input's range in [`prefix`]); [`verisig`] does the same through the Verisig translation (each sigmoid or
//! tanh neuron an ODE over fictitious time) and serves as a cross-check.
pub mod activation;
pub mod crown;
pub mod error;
pub mod network;
pub mod prefix;
pub mod propagate;
pub mod verisig;

pub use error::{NetworkError, Result};
pub use network::{Activation, Layer, LayerArrays, Network};
