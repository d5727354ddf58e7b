//! `percver._core.ClosedLoop` and `verify_cells`: closed-loop cells verified in parallel with
//! the GIL released; each finished cell is handed to a Python callback (journal, progress).
use crate::error::{network_to_py, IntoPy};
use crate::expr::{compile, PyExpr};
use crate::network::PyNetwork;
use nn2hybrid::closed_loop::{self, CellOutcome, CellSettings, ClosedLoop, Component, Condition, Method, Plant, Stage, Verdict};
use nn2hybrid::propagate::Settings as NnSettings;
use nn2hybrid::NetworkError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::{Arc, Mutex};
use taylor::{Cmp, Interval};

#[pyclass(name = "ClosedLoop", module = "percver._core", frozen)]
pub struct PyClosedLoop(pub ClosedLoop);

/// A discrete plant: next-state expressions over the environment's names. A continuous plant:
/// (right-hand sides, ODE variable names = states then inputs, input indices in the
/// environment, control period, integration step, remainder estimate).
#[derive(FromPyObject)]
pub enum PlantArg {
    Discrete(Vec<PyExpr>),
    Continuous((Vec<PyExpr>, Vec<String>, Vec<usize>, f64, f64, f64)),
}

/// A stage's component: a network, or expressions over named inputs.
#[derive(FromPyObject)]
pub enum ComponentArg<'py> {
    Network(PyRef<'py, PyNetwork>),
    Expr((Vec<PyExpr>, Vec<String>)),
}

fn input_error(message: String) -> PyErr {
    network_to_py(NetworkError::input(message))
}

fn cmp(op: &str) -> PyResult<Cmp> {
    Ok(match op {
        "<" => Cmp::Lt,
        "<=" => Cmp::Le,
        ">" => Cmp::Gt,
        ">=" => Cmp::Ge,
        _ => return Err(input_error(format!("unknown comparison '{op}'"))),
    })
}

fn condition(state: &[String], (margin, op, label): (PyExpr, String, String)) -> PyResult<Condition> {
    Ok(Condition { margin: Arc::new(compile(&[margin], state)?), cmp: cmp(&op)?, label })
}

#[pymethods]
impl PyClosedLoop {
    /// `stages`: (component, indices of its inputs in the environment = state ++ stage outputs);
    /// `plant`: next-state expressions over `env_names`; conditions: (margin, op, label) meaning
    /// `margin op 0` over the state.
    #[new]
    #[pyo3(signature = (state_names, stages, env_names, plant, safe, goal, goal_within, steps))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        state_names: Vec<String>,
        stages: Vec<(ComponentArg<'_>, Vec<usize>)>,
        env_names: Vec<String>,
        plant: PlantArg,
        safe: Vec<(PyExpr, String, String)>,
        goal: Option<(PyExpr, String, String)>,
        goal_within: bool,
        steps: usize,
    ) -> PyResult<Self> {
        let mut built = Vec::with_capacity(stages.len());
        for (component, inputs) in stages {
            let component = match component {
                ComponentArg::Network(n) => Component::Network(n.0.clone()),
                ComponentArg::Expr((exprs, names)) => Component::Expr(Arc::new(compile(&exprs, &names)?)),
            };
            built.push(Stage { component, inputs });
        }
        let plant = match plant {
            PlantArg::Discrete(update) => Plant::Discrete(Arc::new(compile(&update, &env_names)?)),
            PlantArg::Continuous((rhs, names, inputs, period, step, remainder)) => {
                let ode = taylor::Ode::new(names.clone(), rhs.into_iter().map(|e| e.0).collect()).py_err()?;
                let flow = taylor::Settings {
                    step: taylor::StepSize::Fixed(step),
                    order: taylor::OrderPolicy::Fixed(1),
                    t_end: period,
                    cutoff: 1e-12,
                    remainder_estimate: vec![remainder; names.len()],
                    precondition: taylor::Precondition::Identity,
                    refinements: 30,
                    symbolic_queue: 100,
                };
                Plant::Continuous { ode: Arc::new(ode), inputs, period, flow }
            }
        };
        let lp = ClosedLoop {
            plant,
            safe: safe.into_iter().map(|c| condition(&state_names, c)).collect::<PyResult<_>>()?,
            goal: goal.map(|c| condition(&state_names, c)).transpose()?,
            state_names,
            stages: built,
            goal_within,
            steps,
        };
        lp.validate().py_err()?;
        Ok(PyClosedLoop(lp))
    }
}

fn outcome_dict<'py>(py: Python<'py>, o: &CellOutcome) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item(
        "verdict",
        match o.verdict {
            Verdict::Verified => "verified",
            Verdict::Unknown => "unknown",
            Verdict::Violated => "violated",
        },
    )?;
    d.set_item("reason", o.reason.clone())?;
    d.set_item("steps_done", o.steps_done)?;
    let boxes: Vec<Vec<(f64, f64)>> = o.boxes.iter().map(|b| b.iter().map(|i| (i.lo(), i.hi())).collect()).collect();
    d.set_item("boxes", boxes)?;
    d.set_item("seconds", o.seconds)?;
    d.set_item("nn_seconds", o.nn_seconds)?;
    d.set_item("branches", o.branches)?;
    d.set_item("split", o.split)?;
    Ok(d)
}

/// Runs `cells` (lists of (lo, hi) per state variable); `done(index, outcome: dict) -> bool`
/// is called as each cell finishes; returning False (or raising) stops starting new cells.
#[pyfunction]
#[pyo3(signature = (problem, cells, done, order=5, cutoff=1e-12, method="taylor", timeout=None, workers=None, nn_order=None, blow_up_width=1e6, max_splits=16, rebox=false, state_symbols=false))]
#[allow(clippy::too_many_arguments)]
pub fn verify_cells(
    py: Python<'_>,
    problem: &PyClosedLoop,
    cells: Vec<Vec<(f64, f64)>>,
    done: PyObject,
    order: usize,
    cutoff: f64,
    method: &str,
    timeout: Option<f64>,
    workers: Option<usize>,
    nn_order: Option<usize>,
    blow_up_width: f64,
    max_splits: usize,
    rebox: bool,
    state_symbols: bool,
) -> PyResult<()> {
    let method = match method {
        "taylor" => Method::Taylor,
        "verisig" => Method::Verisig,
        other => return Err(input_error(format!("unknown method '{other}'; use 'taylor' or 'verisig'"))),
    };
    let n = problem.0.state_names.len();
    let boxes: Vec<Vec<Interval>> = cells
        .iter()
        .enumerate()
        .map(|(k, c)| {
            if c.len() != n {
                return Err(input_error(format!("cell {k} has {} intervals for {n} state variables", c.len())));
            }
            c.iter()
                .zip(&problem.0.state_names)
                .map(|(&(lo, hi), name)| Interval::new(lo, hi).map_err(|e| input_error(format!("cell {k}, '{name}': {e}"))))
                .collect()
        })
        .collect::<PyResult<_>>()?;
    let nn = NnSettings { order: nn_order.unwrap_or(order), cutoff, ..NnSettings::default() };
    nn.validate().py_err()?;
    let settings = CellSettings { order, cutoff, method, nn, timeout, blow_up_width, max_splits, rebox, state_symbols };
    let failure: Mutex<Option<PyErr>> = Mutex::new(None);
    let callback = |i: usize, o: &CellOutcome| -> bool {
        Python::with_gil(|py| {
            let result = outcome_dict(py, o).and_then(|d| done.call1(py, (i, d))).and_then(|r| r.is_truthy(py).map(|t| t || r.is_none(py)));
            match result {
                Ok(go_on) => go_on,
                Err(e) => {
                    failure.lock().unwrap_or_else(|p| p.into_inner()).get_or_insert(e);
                    false
                }
            }
        })
    };
    let result = py.allow_threads(|| closed_loop::verify_cells(&problem.0, &boxes, &settings, workers, &callback));
    if let Some(e) = failure.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(e);
    }
    result.py_err()?;
    Ok(())
}
