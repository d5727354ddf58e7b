//! `percver._core.Network`: the network IR and its sound bounds; the GIL is released while
//! propagating (rayon works across neurons and pieces meanwhile).
use crate::error::IntoPy;
use nn2hybrid::propagate::{self, Models, Settings};
use nn2hybrid::{verisig, Activation, LayerArrays, Network, NetworkError};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;
use taylor::Interval;

#[pyclass(name = "Network", module = "percver._core", frozen)]
pub struct PyNetwork(pub Arc<Network>);

/// Taylor models of a network's outputs (or inputs), ready to be propagated further.
#[pyclass(name = "NetworkModels", module = "percver._core", frozen)]
pub struct PyNetworkModels(pub Models);

/// Propagation input: a box as (lo, hi) pairs, or models from an earlier propagation.
#[derive(FromPyObject)]
pub enum Input<'py> {
    Models(PyRef<'py, PyNetworkModels>),
    Box(Vec<(f64, f64)>),
}

fn to_box(pairs: &[(f64, f64)]) -> PyResult<Vec<Interval>> {
    pairs
        .iter()
        .enumerate()
        .map(|(i, &(lo, hi))| Interval::new(lo, hi).map_err(|e| NetworkError::input(format!("input {i}: {e}"))).py_err())
        .collect()
}

fn pairs(bounds: &[Interval]) -> Vec<(f64, f64)> {
    bounds.iter().map(|b| (b.lo(), b.hi())).collect()
}

/// The propagation keywords of `bounds` and `models`, one list for both: each one left out
/// takes `Settings::default()`'s value (the one source of the defaults).
fn settings(options: Option<&Bound<'_, PyDict>>, splits: Vec<(usize, usize)>) -> PyResult<Settings> {
    let mut s = Settings { splits, ..Settings::default() };
    for (key, value) in options.into_iter().flat_map(|d| d.iter()) {
        match key.extract::<String>()?.as_str() {
            "order" => s.order = value.extract()?,
            "cutoff" => s.cutoff = value.extract()?,
            "symbolic" => s.symbolic = value.extract()?,
            "max_vars" => s.max_vars = value.extract()?,
            "max_symbols" => s.max_symbols = value.extract()?,
            "back_substitution" => s.back_substitution = value.extract()?,
            "alpha_steps" => s.alpha_steps = value.extract()?,
            other => {
                return Err(NetworkError::input(format!(
                    "unknown keyword '{other}'; use order, cutoff, symbolic, max_vars, max_symbols, back_substitution or alpha_steps"
                )))
                .py_err()
            }
        }
    }
    s.validate().py_err()?;
    Ok(s)
}

fn unknown_method(method: &str, allowed: &str) -> PyErr {
    crate::error::network_to_py(NetworkError::input(format!("unknown method '{method}'; use {allowed}")))
}

#[pymethods]
impl PyNetwork {
    /// `layers`: (weight n_out x n_in, bias, activations: one name per neuron or one per layer).
    #[new]
    #[pyo3(signature = (layers, scale=None, offset=None))]
    fn new(
        layers: Vec<(PyReadonlyArray2<'_, f64>, PyReadonlyArray1<'_, f64>, Vec<String>)>,
        scale: Option<Vec<f64>>,
        offset: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        let mut arrays = Vec::with_capacity(layers.len());
        for (index, (weight, bias, names)) in layers.iter().enumerate() {
            let w = weight.as_array();
            let activations = names
                .iter()
                .map(|n| {
                    Activation::from_name(n).ok_or_else(|| NetworkError::Shape {
                        layer: index + 1,
                        field: "activations",
                        problem: format!("name the unknown activation '{n}'; use sigmoid, tanh, relu or identity"),
                    })
                })
                .collect::<Result<Vec<_>, _>>()
                .py_err()?;
            arrays.push(LayerArrays {
                n_out: w.nrows(),
                n_in: w.ncols(),
                weight: w.iter().copied().collect(),
                bias: bias.as_array().to_vec(),
                activations,
            });
        }
        Ok(PyNetwork(Arc::new(Network::new(arrays, scale, offset).py_err()?)))
    }

    #[getter]
    fn n_in(&self) -> usize {
        self.0.n_in()
    }

    #[getter]
    fn n_out(&self) -> usize {
        self.0.n_out()
    }

    /// Sound output bounds over a box (or over earlier models) by "taylor", "verisig" or "interval";
    /// `leaves` > 1 refines a box's Taylor bounds by branch and bound on the input.
    #[pyo3(signature = (input, method="taylor", *, splits=vec![], leaves=1, **options))]
    fn bounds(
        &self,
        py: Python<'_>,
        input: Input<'_>,
        method: &str,
        splits: Vec<(usize, usize)>,
        leaves: usize,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Vec<(f64, f64)>> {
        let net = self.0.clone();
        let s = settings(options, splits)?;
        let result = match input {
            Input::Box(b) => {
                let b = to_box(&b)?;
                match method {
                    "taylor" => py.allow_threads(|| propagate::refined_bounds(&net, &b, &s, leaves)),
                    "verisig" => py.allow_threads(|| verisig::bounds(&net, &b, &s)),
                    "interval" => propagate::interval_bounds(&net, &b),
                    other => return Err(unknown_method(other, "'taylor', 'verisig' or 'interval'")),
                }
            }
            Input::Models(m) => {
                let models = m.0.clone();
                match method {
                    "taylor" => py.allow_threads(|| propagate::propagate(&net, &models, &s).map(|r| r.bounds())),
                    "verisig" => py.allow_threads(|| verisig::propagate(&net, &models, &s).map(|r| r.bounds())),
                    other => return Err(unknown_method(other, "'taylor' or 'verisig' for Taylor-model inputs")),
                }
            }
        };
        Ok(pairs(&result.py_err()?))
    }

    /// The output Taylor models over a box (or over earlier models), to propagate further.
    #[pyo3(signature = (input, method="taylor", **options))]
    fn models(&self, py: Python<'_>, input: Input<'_>, method: &str, options: Option<&Bound<'_, PyDict>>) -> PyResult<PyNetworkModels> {
        let net = self.0.clone();
        let s = settings(options, vec![])?;
        let verisig = match method {
            "taylor" => false,
            "verisig" => true,
            other => return Err(unknown_method(other, "'taylor' or 'verisig'")),
        };
        let start = match input {
            Input::Box(b) => Models::from_box(&to_box(&b)?, &s, verisig).py_err()?,
            Input::Models(m) => m.0.clone(),
        };
        let out = py.allow_threads(|| if verisig { verisig::propagate(&net, &start, &s) } else { propagate::propagate(&net, &start, &s) });
        Ok(PyNetworkModels(out.py_err()?))
    }
}

#[pymethods]
impl PyNetworkModels {
    fn __len__(&self) -> usize {
        self.0.n()
    }
    /// Range of each model (polynomial by the linear dominated bounder, plus symbols and remainder).
    fn bounds(&self) -> Vec<(f64, f64)> {
        pairs(&self.0.bounds())
    }
    /// Each model's interval remainder, the error symbols' range included.
    fn remainders(&self) -> Vec<(f64, f64)> {
        self.0.to_taylor_models().iter().map(|t| (t.rem.lo(), t.rem.hi())).collect()
    }
    /// Error symbols shared between the models (activation errors kept for cancellation).
    #[getter]
    fn symbols(&self) -> usize {
        self.0.symbols()
    }
    /// (input index, variable, centre, radius): input = centre + radius * x_variable, x in [-1, 1].
    #[getter]
    fn variables(&self) -> Vec<(usize, usize, f64, f64)> {
        self.0.variables.clone()
    }
    #[getter]
    fn order(&self) -> usize {
        self.0.ctx.order
    }
}
