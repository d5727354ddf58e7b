//! `percver._core.Interval`: outward-rounded interval arithmetic, mostly for tests and users
//! who want rigorous scalar bounds.
use crate::error::IntoPy;
use pyo3::prelude::*;
use taylor::Interval;

#[pyclass(name = "Interval", module = "percver._core", frozen)]
#[derive(Clone, Copy)]
pub struct PyInterval(pub Interval);

#[pymethods]
impl PyInterval {
    #[new]
    #[pyo3(signature = (lo, hi=None))]
    fn new(lo: f64, hi: Option<f64>) -> PyResult<Self> {
        Ok(PyInterval(Interval::new(lo, hi.unwrap_or(lo)).py_err()?))
    }
    #[getter]
    fn lo(&self) -> f64 {
        self.0.lo()
    }
    #[getter]
    fn hi(&self) -> f64 {
        self.0.hi()
    }
    fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    fn contains(&self, x: f64) -> bool {
        self.0.contains(x)
    }
    fn __add__(&self, o: &Self) -> Self {
        PyInterval(self.0 + o.0)
    }
    fn __sub__(&self, o: &Self) -> Self {
        PyInterval(self.0 - o.0)
    }
    fn __mul__(&self, o: &Self) -> Self {
        PyInterval(self.0 * o.0)
    }
    fn __truediv__(&self, o: &Self) -> PyResult<Self> {
        Ok(PyInterval(self.0 * o.0.recip().py_err()?))
    }
    fn __neg__(&self) -> Self {
        PyInterval(-self.0)
    }
    /// Division that returns the whole line for a divisor containing zero instead of raising.
    fn div_extended(&self, o: &Self) -> Self {
        PyInterval(self.0.div_extended(&o.0))
    }
    fn hull(&self, o: &Self) -> Self {
        PyInterval(self.0.hull(&o.0))
    }
    fn intersect(&self, o: &Self) -> Self {
        PyInterval(self.0.intersect(&o.0))
    }
    fn sqr(&self) -> Self {
        PyInterval(self.0.sqr())
    }
    fn powi(&self, n: i32) -> PyResult<Self> {
        Ok(PyInterval(self.0.powi(n).py_err()?))
    }
    fn powf(&self, r: f64) -> PyResult<Self> {
        Ok(PyInterval(self.0.powf(r).py_err()?))
    }
    /// Applies an elementary function by name: exp log sqrt sin cos tan atan tanh sigmoid abs.
    fn apply(&self, name: &str) -> PyResult<Self> {
        let f = crate::expr::function(name)?;
        Ok(PyInterval(f.eval_interval(self.0).py_err()?))
    }
    fn __repr__(&self) -> String {
        format!("Interval({:?}, {:?})", self.0.lo(), self.0.hi())
    }
}
