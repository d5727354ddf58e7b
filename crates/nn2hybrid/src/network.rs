//! The network IR: dense layers `h <- act(W h + b)` with one activation per neuron, then an
//! optional output map `y <- scale * h + offset`.
//!
//! Activations are per neuron (not per layer) so that a chain of networks can carry inputs of
//! later stages past earlier ones as identity neurons (Python's `Network.passthrough`): one
//! layer then mixes, say, 50 tanh neurons with 2 identity neurons. Python parses the files;
//! this IR only receives arrays and validates them.
use crate::error::{NetworkError, Result};
use crate::prefix::Prefix;
use nalgebra::DMatrix;
use std::sync::{Arc, OnceLock};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Activation {
    Sigmoid,
    Tanh,
    Relu,
    Identity,
}

impl Activation {
    pub fn from_name(name: &str) -> Option<Activation> {
        Some(match name.to_ascii_lowercase().as_str() {
            "sigmoid" => Activation::Sigmoid,
            "tanh" => Activation::Tanh,
            "relu" => Activation::Relu,
            "identity" | "linear" | "affine" => Activation::Identity,
            _ => return None,
        })
    }

    pub fn name(&self) -> &'static str {
        match self {
            Activation::Sigmoid => "sigmoid",
            Activation::Tanh => "tanh",
            Activation::Relu => "relu",
            Activation::Identity => "identity",
        }
    }

    /// Float evaluation (the reference that sampling tests compare against).
    pub fn eval(&self, x: f64) -> f64 {
        match self {
            Activation::Sigmoid => {
                // exp of a non-positive argument only: no overflow on either tail.
                let e = (-x.abs()).exp();
                if x >= 0.0 {
                    1.0 / (1.0 + e)
                } else {
                    e / (1.0 + e)
                }
            }
            Activation::Tanh => x.tanh(),
            Activation::Relu => x.max(0.0),
            Activation::Identity => x,
        }
    }
}

/// The arrays of one layer as Python hands them over: `weight` row-major `n_out x n_in`.
#[derive(Clone, Debug)]
pub struct LayerArrays {
    pub n_out: usize,
    pub n_in: usize,
    pub weight: Vec<f64>,
    pub bias: Vec<f64>,
    /// One per neuron, or a single entry for the whole layer.
    pub activations: Vec<Activation>,
}

#[derive(Clone, Debug)]
pub struct Layer {
    /// W transposed (`n_in x n_out`, column-major): column i is neuron i's weight row, the
    /// layout that the coefficient-matrix product of [`crate::propagate`] needs.
    pub weight_t: DMatrix<f64>,
    pub bias: Vec<f64>,
    pub activations: Vec<Activation>,
}

impl Layer {
    pub fn n_in(&self) -> usize {
        self.weight_t.nrows()
    }
    pub fn n_out(&self) -> usize {
        self.weight_t.ncols()
    }
    pub fn weight(&self, neuron: usize, input: usize) -> f64 {
        self.weight_t[(input, neuron)]
    }
    /// Whether the activation is the identity for every neuron (no work in set propagation).
    pub fn is_affine(&self) -> bool {
        self.activations.iter().all(|a| *a == Activation::Identity)
    }
}

#[derive(Clone, Debug)]
pub struct Network {
    layers: Vec<Layer>,
    scale: Option<Vec<f64>>,
    offset: Option<Vec<f64>>,
    /// Its one-input prefix ([`crate::prefix`]), found on first use: a closed loop propagates
    /// the same network at every step.
    prefix: OnceLock<Option<Arc<Prefix>>>,
}

fn check_finite(values: &[f64], layer: usize, field: &'static str) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(NetworkError::NonFinite { layer, field, index, value: values[index] }),
        None => Ok(()),
    }
}

impl Network {
    /// Validates shapes (consecutive layers must fit), finiteness and the output map.
    pub fn new(layers: Vec<LayerArrays>, scale: Option<Vec<f64>>, offset: Option<Vec<f64>>) -> Result<Network> {
        if layers.is_empty() {
            return Err(NetworkError::input("a network needs at least one layer"));
        }
        let mut built: Vec<Layer> = Vec::with_capacity(layers.len());
        for (i, a) in layers.into_iter().enumerate() {
            let index = i + 1;
            let shape = |field: &'static str, problem: String| Err(NetworkError::Shape { layer: index, field, problem });
            if a.n_out == 0 || a.n_in == 0 {
                return shape("weight", format!("is {} x {}; a layer needs at least one input and one neuron", a.n_out, a.n_in));
            }
            if a.weight.len() != a.n_out * a.n_in {
                return shape("weight", format!("has {} entries but should be n_out x n_in = {} x {}", a.weight.len(), a.n_out, a.n_in));
            }
            if a.bias.len() != a.n_out {
                return shape("bias", format!("has {} entries but the weight has {} rows (weight is n_out x n_in)", a.bias.len(), a.n_out));
            }
            if let Some(prev) = built.last() {
                if prev.n_out() != a.n_in {
                    return shape("weight", format!("has {} columns but layer {} has {} outputs", a.n_in, index - 1, prev.n_out()));
                }
            }
            let activations = match a.activations.len() {
                1 => vec![a.activations[0]; a.n_out],
                n if n == a.n_out => a.activations,
                n => {
                    return shape(
                        "activations",
                        format!("lists {n} activations for {} neurons; give one per neuron or one for the layer", a.n_out),
                    )
                }
            };
            check_finite(&a.weight, index, "weight")?;
            check_finite(&a.bias, index, "bias")?;
            // Row-major n_out x n_in is column-major n_in x n_out: W transposed.
            let weight_t = DMatrix::from_vec(a.n_in, a.n_out, a.weight);
            built.push(Layer { weight_t, bias: a.bias, activations });
        }
        let n_out = built.last().map_or(0, |l| l.n_out());
        let last = built.len();
        for (field, map) in [("output scale", &scale), ("output offset", &offset)] {
            if let Some(values) = map {
                if values.len() != n_out {
                    return Err(NetworkError::Shape {
                        layer: last,
                        field,
                        problem: format!("has {} entries for {n_out} outputs", values.len()),
                    });
                }
                check_finite(values, last, field)?;
            }
        }
        Ok(Network { layers: built, scale, offset, prefix: OnceLock::new() })
    }

    pub fn layers(&self) -> &[Layer] {
        &self.layers
    }
    pub fn n_in(&self) -> usize {
        self.layers[0].n_in()
    }
    pub fn n_out(&self) -> usize {
        self.layers[self.layers.len() - 1].n_out()
    }
    pub fn scale(&self) -> Option<&[f64]> {
        self.scale.as_deref()
    }
    pub fn offset(&self) -> Option<&[f64]> {
        self.offset.as_deref()
    }

    /// The layers up to the first that mixes one input's nonlinear part with the other inputs,
    /// when they exist (see [`crate::prefix`]).
    pub(crate) fn prefix(&self) -> Option<&Prefix> {
        self.prefix.get_or_init(|| Prefix::find(self).map(Arc::new)).as_deref()
    }

    /// Float forward pass of one input (not rigorous: the sampling reference).
    pub fn eval(&self, x: &[f64]) -> Result<Vec<f64>> {
        if x.len() != self.n_in() {
            return Err(NetworkError::input(format!("the network takes {} inputs, got {}", self.n_in(), x.len())));
        }
        let mut h = x.to_vec();
        for layer in &self.layers {
            h = (0..layer.n_out())
                .map(|i| {
                    let column = layer.weight_t.column(i);
                    let z: f64 = column.iter().zip(&h).map(|(w, v)| w * v).sum::<f64>() + layer.bias[i];
                    layer.activations[i].eval(z)
                })
                .collect();
        }
        if let Some(s) = &self.scale {
            h.iter_mut().zip(s).for_each(|(v, s)| *v *= s);
        }
        if let Some(o) = &self.offset {
            h.iter_mut().zip(o).for_each(|(v, o)| *v += o);
        }
        Ok(h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(n_out: usize, n_in: usize, act: Activation) -> LayerArrays {
        LayerArrays { n_out, n_in, weight: vec![0.5; n_out * n_in], bias: vec![0.1; n_out], activations: vec![act] }
    }

    #[test]
    fn shapes_are_checked_with_layer_numbers() {
        let err = Network::new(vec![layer(3, 2, Activation::Tanh), layer(1, 4, Activation::Identity)], None, None).unwrap_err();
        assert_eq!(err.to_string(), "layer 2: weight has 4 columns but layer 1 has 3 outputs");
        let mut bad = layer(3, 2, Activation::Tanh);
        bad.bias.pop();
        assert!(Network::new(vec![bad], None, None).unwrap_err().to_string().contains("bias has 2 entries"));
        let mut acts = layer(3, 2, Activation::Tanh);
        acts.activations = vec![Activation::Tanh, Activation::Relu];
        assert!(Network::new(vec![acts], None, None).unwrap_err().to_string().contains("2 activations for 3 neurons"));
        assert!(Network::new(vec![layer(1, 2, Activation::Tanh)], Some(vec![1.0, 2.0]), None).is_err());
    }

    #[test]
    fn non_finite_values_are_located() {
        let mut l = layer(2, 2, Activation::Sigmoid);
        l.weight[3] = f64::NAN;
        let err = Network::new(vec![l], None, None).unwrap_err();
        assert!(matches!(err, NetworkError::NonFinite { layer: 1, field: "weight", index: 3, .. }), "{err}");
        assert!(Network::new(vec![layer(1, 1, Activation::Relu)], None, Some(vec![f64::INFINITY])).is_err());
    }

    #[test]
    fn forward_pass_uses_row_major_weights() {
        let l = LayerArrays {
            n_out: 2,
            n_in: 2,
            weight: vec![1.0, 2.0, 3.0, 4.0],
            bias: vec![0.0, 1.0],
            activations: vec![Activation::Identity, Activation::Relu],
        };
        let net = Network::new(vec![l], Some(vec![2.0, 1.0]), Some(vec![0.0, -1.0])).unwrap();
        assert_eq!(net.eval(&[1.0, -1.0]).unwrap(), vec![-2.0, -1.0]);
        assert_eq!(net.eval(&[1.0, 1.0]).unwrap(), vec![6.0, 7.0]);
        assert!(net.eval(&[1.0]).is_err());
    }
}
