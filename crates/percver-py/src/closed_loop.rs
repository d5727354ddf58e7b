//! `percver._core.ClosedLoop`, `CellSettings` and `verify_cells` (crate `closed_loop`): cells
//! verified in parallel with the GIL released; each finished cell is handed to a Python callback
//! (journal, progress) as a `CellOutcome`.
use crate::error::{reach_to_py, IntoPy};
use crate::expr::{compile, PyExpr};
use crate::network::PyNetwork;
use closed_loop::{CellOutcome, CellSettings, ClosedLoop, Component, Condition, Method, Plant, ReachError, Stage, Verdict};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use taylor::hybrid::{Automaton, Constraint, Jump, Mode, Target};
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
    Hybrid(HybridArg),
}

/// A hybrid plant: (variable names = states then inputs, modes, jumps, start mode index, input
/// indices in the environment, time bound per period, integration step, remainder estimate,
/// most jumps per period). A mode: (name, right-hand sides, invariant); a jump: (source index,
/// target index or None for "back to the controller", guard, reset of every variable or None,
/// urgent); a constraint: (margin, op) meaning `margin op 0`.
type HybridArg = (Vec<String>, Vec<ModeArg>, Vec<JumpArg>, usize, Vec<usize>, f64, f64, f64, usize);
pub type ModeArg = (String, Vec<PyExpr>, Vec<(PyExpr, String)>);
pub type JumpArg = (usize, Option<usize>, Vec<(PyExpr, String)>, Option<Vec<PyExpr>>, bool);

pub fn automaton(names: Vec<String>, modes: Vec<ModeArg>, jumps: Vec<JumpArg>) -> PyResult<Automaton> {
    let constraints = |list: Vec<(PyExpr, String)>| -> PyResult<Vec<Constraint>> {
        list.into_iter().map(|(margin, op)| Ok(Constraint { margin: Arc::new(compile(&[margin], &names)?), cmp: cmp(&op)? })).collect()
    };
    let modes = modes
        .into_iter()
        .map(|(name, rhs, invariant)| {
            let ode = taylor::Ode::new(names.clone(), rhs.into_iter().map(|e| e.0).collect()).py_err()?;
            Ok(Mode { name, ode, invariant: constraints(invariant)? })
        })
        .collect::<PyResult<_>>()?;
    let jumps = jumps
        .into_iter()
        .map(|(source, target, guard, reset, urgent)| {
            Ok(Jump {
                source,
                target: target.map_or(Target::Exit, Target::Mode),
                guard: constraints(guard)?,
                reset: reset.map(|r| compile(&r, &names).map(Arc::new)).transpose()?,
                urgent,
            })
        })
        .collect::<PyResult<_>>()?;
    let automaton = Automaton { names: names.clone(), modes, jumps };
    automaton.validate().py_err()?;
    Ok(automaton)
}

/// A stage's component: a network, or expressions over named inputs.
#[derive(FromPyObject)]
pub enum ComponentArg<'py> {
    Network(PyRef<'py, PyNetwork>),
    Expr((Vec<PyExpr>, Vec<String>)),
}

fn input_error(message: String) -> PyErr {
    reach_to_py(ReachError::input(message))
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

/// A condition (margin, op, label) and its window in steps (None: always).
type ConditionArg = (PyExpr, String, String, Option<(f64, f64)>);

fn condition(state: &[String], (margin, op, label, window): ConditionArg) -> PyResult<Condition> {
    Ok(Condition { margin: Arc::new(compile(&[margin], state)?), cmp: cmp(&op)?, label, window })
}

/// The deepest step of the cells running with it (`verify_cells(progress=...)`), readable while
/// they run: a progress bar shows how far a long cell has got.
#[pyclass(name = "StepCounter", module = "percver._core", frozen)]
pub struct PyStepCounter(Arc<AtomicUsize>);

#[pymethods]
impl PyStepCounter {
    #[new]
    fn new() -> Self {
        PyStepCounter(Arc::new(AtomicUsize::new(0)))
    }
    fn get(&self) -> usize {
        self.0.load(Ordering::Relaxed)
    }
    fn reset(&self) {
        self.0.store(0, Ordering::Relaxed)
    }
}

#[pymethods]
impl PyClosedLoop {
    /// `stages`: (component, indices of its inputs in the environment = state ++ stage outputs);
    /// `plant`: next-state expressions over `env_names`; conditions: (margin, op, label, window)
    /// meaning `margin op 0` over the state, at the steps in the window (None: always).
    #[new]
    #[pyo3(signature = (state_names, stages, env_names, plant, safe, goal, goal_within, steps))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        state_names: Vec<String>,
        stages: Vec<(ComponentArg<'_>, Vec<usize>)>,
        env_names: Vec<String>,
        plant: PlantArg,
        safe: Vec<ConditionArg>,
        goal: Option<ConditionArg>,
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
                let ode = taylor::Ode::new(names, rhs.into_iter().map(|e| e.0).collect()).py_err()?;
                Plant::continuous(ode, inputs, period, step, remainder)
            }
            PlantArg::Hybrid((names, modes, jumps, start, inputs, max_time, step, remainder, max_jumps)) => {
                Plant::hybrid(automaton(names, modes, jumps)?, start, inputs, max_time, step, remainder, max_jumps)
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

/// What verifying a cell found (`closed_loop::CellOutcome`), with the boxes as (lo, hi) pairs.
/// Picklable: outcomes come back from executor workers as they are.
#[pyclass(name = "CellOutcome", module = "percver._core", frozen, get_all)]
#[derive(Clone)]
pub struct PyCellOutcome {
    /// "verified", "unknown" or "violated".
    verdict: String,
    reason: Option<String>,
    steps_done: usize,
    deepest_step: usize,
    boxes: Vec<Vec<(f64, f64)>>,
    seconds: f64,
    nn_seconds: f64,
    branches: usize,
    steps_redone: usize,
    split: Option<usize>,
}

fn verdict_name(v: Verdict) -> &'static str {
    match v {
        Verdict::Verified => "verified",
        Verdict::Unknown => "unknown",
        Verdict::Violated => "violated",
    }
}

impl From<&CellOutcome> for PyCellOutcome {
    fn from(o: &CellOutcome) -> Self {
        PyCellOutcome {
            verdict: verdict_name(o.verdict).to_string(),
            reason: o.reason.clone(),
            steps_done: o.steps_done,
            deepest_step: o.deepest_step,
            boxes: o.boxes.iter().map(|b| b.iter().map(|i| (i.lo(), i.hi())).collect()).collect(),
            seconds: o.seconds,
            nn_seconds: o.nn_seconds,
            branches: o.branches,
            steps_redone: o.steps_redone,
            split: o.split,
        }
    }
}

/// The constructor's arguments, the fields in their order (and what `__reduce__` gives back).
type OutcomeArgs = (String, Option<String>, usize, usize, Vec<Vec<(f64, f64)>>, f64, f64, usize, usize, Option<usize>);

#[pymethods]
impl PyCellOutcome {
    /// `CellOutcome(verdict, reason, steps_done, deepest_step, boxes, seconds, nn_seconds, branches, steps_redone, split)`.
    #[new]
    #[pyo3(signature = (*args))]
    fn new(args: OutcomeArgs) -> PyResult<Self> {
        let (verdict, reason, steps_done, deepest_step, boxes, seconds, nn_seconds, branches, steps_redone, split) = args;
        if ![Verdict::Verified, Verdict::Unknown, Verdict::Violated].iter().any(|&v| verdict_name(v) == verdict) {
            return Err(input_error(format!("a cell's verdict is 'verified', 'unknown' or 'violated', not '{verdict}'")));
        }
        Ok(PyCellOutcome { verdict, reason, steps_done, deepest_step, boxes, seconds, nn_seconds, branches, steps_redone, split })
    }
    fn __repr__(&self) -> String {
        format!(
            "CellOutcome(verdict='{}', reason={:?}, steps_done={}, deepest_step={}, {} boxes, seconds={}, nn_seconds={}, branches={}, steps_redone={}, split={:?})",
            self.verdict,
            self.reason,
            self.steps_done,
            self.deepest_step,
            self.boxes.len(),
            self.seconds,
            self.nn_seconds,
            self.branches,
            self.steps_redone,
            self.split
        )
    }
    /// Pickling (Dask, process pools): the constructor's arguments.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> (Bound<'py, pyo3::types::PyType>, OutcomeArgs) {
        let o = slf.get().clone();
        (
            slf.get_type(),
            (o.verdict, o.reason, o.steps_done, o.deepest_step, o.boxes, o.seconds, o.nn_seconds, o.branches, o.steps_redone, o.split),
        )
    }
}

/// How each cell is verified; every keyword left out takes the engine's default (Rust's
/// `CellSettings::default()`, the one source of them).
#[pyclass(name = "CellSettings", module = "percver._core", frozen)]
#[derive(Clone)]
pub struct PyCellSettings(pub CellSettings);

#[pymethods]
impl PyCellSettings {
    #[new]
    #[pyo3(signature = (*, order=None, cutoff=None, method=None, timeout=None, nn_order=None, blow_up_width=None, max_splits=None, max_redone=None, rebox=None, state_symbols=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        order: Option<usize>,
        cutoff: Option<f64>,
        method: Option<&str>,
        timeout: Option<f64>,
        nn_order: Option<usize>,
        blow_up_width: Option<f64>,
        max_splits: Option<usize>,
        max_redone: Option<f64>,
        rebox: Option<bool>,
        state_symbols: Option<bool>,
    ) -> PyResult<Self> {
        let d = CellSettings::default();
        let settings = CellSettings {
            order: order.unwrap_or(d.order),
            cutoff: cutoff.unwrap_or(d.cutoff),
            method: method.map(Method::from_name).transpose().py_err()?.unwrap_or(d.method),
            timeout: timeout.or(d.timeout),
            blow_up_width: blow_up_width.unwrap_or(d.blow_up_width),
            max_splits: max_splits.unwrap_or(d.max_splits),
            max_redone: max_redone.or(d.max_redone),
            rebox: rebox.unwrap_or(d.rebox),
            state_symbols: state_symbols.unwrap_or(d.state_symbols),
            nn: d.nn,
            progress: None,
        };
        Ok(PyCellSettings(settings.with_network_order(nn_order).py_err()?))
    }
    #[getter]
    fn order(&self) -> usize {
        self.0.order
    }
    #[getter]
    fn cutoff(&self) -> f64 {
        self.0.cutoff
    }
    #[getter]
    fn method(&self) -> &'static str {
        self.0.method.name()
    }
    #[getter]
    fn timeout(&self) -> Option<f64> {
        self.0.timeout
    }
    #[getter]
    fn nn_order(&self) -> usize {
        self.0.nn.order
    }
    #[getter]
    fn blow_up_width(&self) -> f64 {
        self.0.blow_up_width
    }
    #[getter]
    fn max_splits(&self) -> usize {
        self.0.max_splits
    }
    #[getter]
    fn max_redone(&self) -> Option<f64> {
        self.0.max_redone
    }
    #[getter]
    fn rebox(&self) -> bool {
        self.0.rebox
    }
    #[getter]
    fn state_symbols(&self) -> bool {
        self.0.state_symbols
    }
    fn __repr__(&self) -> String {
        let s = &self.0;
        format!(
            "CellSettings(order={}, cutoff={:e}, method='{}', timeout={}, nn_order={}, blow_up_width={:e}, max_splits={}, max_redone={}, rebox={}, state_symbols={})",
            s.order,
            s.cutoff,
            s.method.name(),
            py_optional(s.timeout),
            s.nn.order,
            s.blow_up_width,
            s.max_splits,
            py_optional(s.max_redone),
            s.rebox,
            s.state_symbols
        )
    }
    /// Pickling (Dask, process pools): the keywords that rebuild it.
    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyAny>,))> {
        let s = &slf.get().0;
        let py = slf.py();
        let kwargs = PyDict::new(py);
        kwargs.set_item("order", s.order)?;
        kwargs.set_item("cutoff", s.cutoff)?;
        kwargs.set_item("method", s.method.name())?;
        kwargs.set_item("timeout", s.timeout)?;
        kwargs.set_item("nn_order", s.nn.order)?;
        kwargs.set_item("blow_up_width", s.blow_up_width)?;
        kwargs.set_item("max_splits", s.max_splits)?;
        kwargs.set_item("max_redone", s.max_redone)?;
        kwargs.set_item("rebox", s.rebox)?;
        kwargs.set_item("state_symbols", s.state_symbols)?;
        let rebuild = py.import("percver._core")?.getattr("_cell_settings")?;
        Ok((rebuild, (kwargs.into_any(),)))
    }
}

/// An optional number as Python writes it (None, or the number).
fn py_optional(v: Option<f64>) -> String {
    v.map_or_else(|| "None".to_string(), |v| v.to_string())
}

/// `CellSettings(**kwargs)` for unpickling.
#[pyfunction]
pub fn _cell_settings(kwargs: &Bound<'_, PyDict>) -> PyResult<PyCellSettings> {
    let get = |k: &str| kwargs.get_item(k).ok().flatten();
    PyCellSettings::new(
        get("order").map(|v| v.extract()).transpose()?,
        get("cutoff").map(|v| v.extract()).transpose()?,
        get("method").map(|v| v.extract::<String>()).transpose()?.as_deref(),
        get("timeout").and_then(|v| v.extract().ok()),
        get("nn_order").map(|v| v.extract()).transpose()?,
        get("blow_up_width").map(|v| v.extract()).transpose()?,
        get("max_splits").map(|v| v.extract()).transpose()?,
        get("max_redone").and_then(|v| v.extract().ok()),
        get("rebox").map(|v| v.extract()).transpose()?,
        get("state_symbols").map(|v| v.extract()).transpose()?,
    )
}

/// Runs `cells` (lists of (lo, hi) per state variable) with `settings` (the defaults when None);
/// `done(index, outcome: CellOutcome) -> bool` is called as each cell finishes; returning False (or
/// raising) stops starting new cells. `progress` is raised to the deepest step reached as they run.
#[pyfunction]
#[pyo3(signature = (problem, cells, done, settings=None, workers=None, progress=None))]
pub fn verify_cells(
    py: Python<'_>,
    problem: &PyClosedLoop,
    cells: Vec<Vec<(f64, f64)>>,
    done: PyObject,
    settings: Option<PyCellSettings>,
    workers: Option<usize>,
    progress: Option<PyRef<'_, PyStepCounter>>,
) -> PyResult<()> {
    let settings = CellSettings { progress: progress.map(|p| p.0.clone()), ..settings.map_or_else(CellSettings::default, |s| s.0) };
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
    let failure: Mutex<Option<PyErr>> = Mutex::new(None);
    let callback = |i: usize, o: &CellOutcome| -> bool {
        Python::with_gil(|py| {
            let result = done.call1(py, (i, PyCellOutcome::from(o))).and_then(|r| r.is_truthy(py).map(|t| t || r.is_none(py)));
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
