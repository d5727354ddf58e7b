//! Maps Rust errors to the exception classes of `percver.errors` (defined in Python so that
//! pure-Python modules raise the same types).
use pyo3::prelude::*;
use pyo3::types::PyAnyMethods;
use taylor::TaylorError;

/// Builds an instance of `percver.errors.<class>` with `message`.
pub fn percver_error(py: Python<'_>, class: &str, message: String) -> PyErr {
    match py.import("percver.errors").and_then(|m| m.getattr(class)) {
        Ok(cls) => match cls.call1((message.clone(),)) {
            Ok(instance) => PyErr::from_value(instance),
            Err(e) => e,
        },
        Err(_) => pyo3::exceptions::PyValueError::new_err(message),
    }
}

pub fn to_py(error: TaylorError) -> PyErr {
    Python::with_gil(|py| {
        let class = match &error {
            TaylorError::Input(_) => "InputError",
            TaylorError::Domain { .. } => "DomainError",
            TaylorError::Parse { .. } => "ParseError",
            TaylorError::BlowUp { .. } => "BlowUpError",
        };
        percver_error(py, class, error.to_string())
    })
}

/// `?`-friendly conversion for core results.
pub trait IntoPy<T> {
    fn py_err(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for Result<T, TaylorError> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}

/// Network errors: shapes and values of the arrays are format errors, bad boxes or settings
/// input errors, a Verisig neuron that cannot be integrated a blow-up.
pub fn network_to_py(error: nn2hybrid::NetworkError) -> PyErr {
    use nn2hybrid::NetworkError;
    let class = match &error {
        NetworkError::Taylor(e) => return to_py(e.clone()),
        NetworkError::Shape { .. } | NetworkError::NonFinite { .. } => "NetworkFormatError",
        NetworkError::Input(_) => "InputError",
        NetworkError::Integration { .. } => "BlowUpError",
    };
    Python::with_gil(|py| percver_error(py, class, error.to_string()))
}

impl<T> IntoPy<T> for Result<T, nn2hybrid::NetworkError> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(network_to_py)
    }
}

/// Closed-loop errors: a malformed loop or cell is an input error; the rest are the networks' or
/// the Taylor models' own.
pub fn reach_to_py(error: closed_loop::ReachError) -> PyErr {
    use closed_loop::ReachError;
    match error {
        ReachError::Input(m) => Python::with_gil(|py| percver_error(py, "InputError", m)),
        ReachError::Network(e) => network_to_py(e),
        ReachError::Taylor(e) => to_py(e),
    }
}

impl<T> IntoPy<T> for Result<T, closed_loop::ReachError> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(reach_to_py)
    }
}
