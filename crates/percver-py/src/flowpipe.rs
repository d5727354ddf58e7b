//! `percver._core.flowpipe` and `hybrid_reach`: ODE and hybrid-automaton reachability, the GIL
//! released while integrating.
use crate::closed_loop::{automaton, JumpArg, ModeArg};
use crate::error::IntoPy;
use crate::expr::{to_intervals, PyExpr};
use numpy::{PyArray2, PyArray3, ToPyArray};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;
use taylor::bound::Bounder;
use taylor::flowpipe::normalise_initial_point;
use taylor::hybrid::{self, Limits, Run};
use taylor::{reach, Flowpipe, Interval, Ode, OrderPolicy, Precondition, Settings, Space, StepSize, TaylorModel};

#[pyclass(name = "FlowpipeResult", module = "percver._core", frozen)]
/// The flowpipe and the initial box its final models are normalised over.
pub struct PyFlowpipe(pub Flowpipe, pub Vec<Interval>);

/// Step: a float (fixed) or (min, max) (adaptive). Order: an int or (min, max).
#[derive(FromPyObject)]
pub enum StepArg {
    Fixed(f64),
    Adaptive((f64, f64)),
}

#[derive(FromPyObject)]
pub enum OrderArg {
    Fixed(usize),
    Adaptive((usize, usize)),
}

fn step_size(step: StepArg) -> StepSize {
    match step {
        StepArg::Fixed(h) => StepSize::Fixed(h),
        StepArg::Adaptive((min, max)) => StepSize::Adaptive { min, max },
    }
}

fn order_policy(order: OrderArg) -> OrderPolicy {
    match order {
        OrderArg::Fixed(k) => OrderPolicy::Fixed(k),
        OrderArg::Adaptive((min, max)) => OrderPolicy::Adaptive { min, max },
    }
}

#[pyfunction]
#[pyo3(signature = (names, rhs, init, t_end, step, order, cutoff=1e-10, remainder=None, precondition="identity", refinements=30, symbolic_queue=100, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn flowpipe(
    py: Python<'_>,
    names: Vec<String>,
    rhs: Vec<PyExpr>,
    init: Vec<(f64, f64)>,
    t_end: f64,
    step: StepArg,
    order: OrderArg,
    cutoff: f64,
    remainder: Option<Vec<f64>>,
    precondition: &str,
    refinements: usize,
    symbolic_queue: usize,
    progress: Option<PyObject>,
) -> PyResult<PyFlowpipe> {
    let ode = Ode::new(names.clone(), rhs.into_iter().map(|e| e.0).collect()).py_err()?;
    let init = to_intervals(&init, &names)?;
    let precondition = match precondition.to_ascii_lowercase().as_str() {
        "identity" => Precondition::Identity,
        "qr" => Precondition::Qr,
        other => {
            return Err(crate::error::to_py(taylor::TaylorError::input(format!("unknown precondition '{other}' (use 'identity' or 'qr')"))))
        }
    };
    let settings = Settings {
        step: step_size(step),
        order: order_policy(order),
        t_end,
        cutoff,
        remainder_estimate: remainder.unwrap_or_else(|| vec![1e-4; names.len()]),
        precondition,
        refinements,
        symbolic_queue,
    };
    let mut interrupted: Option<PyErr> = None;
    let result = py.allow_threads(|| {
        let mut observer = |t: f64| -> bool {
            Python::with_gil(|py| {
                if let Err(e) = py.check_signals() {
                    interrupted = Some(e);
                    return false;
                }
                if let Some(cb) = &progress {
                    if let Err(e) = cb.call1(py, (t,)) {
                        interrupted = Some(e);
                        return false;
                    }
                }
                true
            })
        };
        reach(&ode, &init, &settings, &mut observer)
    });
    if let Some(e) = interrupted {
        return Err(e);
    }
    Ok(PyFlowpipe(result.py_err()?, init))
}

#[pymethods]
impl PyFlowpipe {
    #[getter]
    fn names(&self) -> Vec<String> {
        self.0.names.clone()
    }
    /// (S, 2) array of segment start and end times.
    #[getter]
    fn times<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let s = &self.0.segments;
        numpy::ndarray::Array2::from_shape_fn((s.len(), 2), |(i, j)| if j == 0 { s[i].t0 } else { s[i].t1 }).to_pyarray(py)
    }
    /// (S, n, 2) array: the box of each segment, lower and upper bounds per variable.
    #[getter]
    fn boxes<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        let s = &self.0.segments;
        let n = self.0.names.len();
        numpy::ndarray::Array3::from_shape_fn((s.len(), n, 2), |(i, v, j)| {
            let b = s[i].bounds[v];
            if j == 0 {
                b.lo()
            } else {
                b.hi()
            }
        })
        .to_pyarray(py)
    }
    #[getter]
    fn final_box(&self) -> Vec<(f64, f64)> {
        self.0.final_box.iter().map(|b| (b.lo(), b.hi())).collect()
    }
    #[getter]
    fn time_reached(&self) -> f64 {
        self.0.time_reached
    }
    /// Why integration stopped early (None when it reached the horizon).
    #[getter]
    fn failure(&self) -> Option<String> {
        self.0.failure.as_ref().map(|e| e.to_string())
    }
    #[getter]
    fn orders(&self) -> Vec<usize> {
        self.0.segments.iter().map(|s| s.order).collect()
    }
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.0.stats;
        let d = PyDict::new(py);
        d.set_item("steps", s.steps)?;
        d.set_item("rejected_steps", s.rejected_steps)?;
        d.set_item("seconds", s.seconds)?;
        d.set_item("picard_seconds", s.picard_seconds)?;
        d.set_item("validation_seconds", s.validation_seconds)?;
        d.set_item("composition_seconds", s.composition_seconds)?;
        Ok(d)
    }
    /// The final state's Taylor models over the normalised initial set z in [-1, 1]^n
    /// (x0_i = c_i + r_i z_i): per variable, ([(exponents of z_1..z_n, coefficient)], (rem lo, hi)).
    fn final_models(&self) -> Vec<(Vec<(Vec<u8>, f64)>, (f64, f64))> {
        let fp = &self.0;
        let n = fp.names.len();
        fp.final_state
            .iter()
            .map(|m| {
                let terms = m
                    .coef
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| **c != 0.0)
                    .map(|(i, &c)| (fp.space.exponents(i)[1..=n].to_vec(), c))
                    .collect();
                (terms, (m.rem.lo(), m.rem.hi()))
            })
            .collect()
    }
    /// (c_i, r_i) of the map x0_i = c_i + r_i z_i from the normalised initial set.
    fn initial_map(&self) -> Vec<(f64, f64)> {
        self.1
            .iter()
            .map(|iv| {
                if iv.lo() == iv.hi() {
                    (iv.lo(), 0.0)
                } else {
                    let m = iv.mid();
                    (m, (iv.hi() - m).max(m - iv.lo()).next_up())
                }
            })
            .collect()
    }
    /// The final box with a chosen bounder: "dominated", "interval", "subdivision" (split
    /// pieces per variable) or "bernstein".
    #[pyo3(signature = (bounder="dominated", split=4))]
    fn final_bound(&self, py: Python<'_>, bounder: &str, split: usize) -> PyResult<Vec<(f64, f64)>> {
        let b = match bounder.to_ascii_lowercase().as_str() {
            "dominated" | "ldb" => Bounder::Dominated,
            "interval" => Bounder::Interval,
            "subdivision" => Bounder::Subdivision(split),
            "bernstein" => Bounder::Bernstein,
            other => {
                return Err(crate::error::to_py(taylor::TaylorError::input(format!(
                    "unknown bounder '{other}' (use 'dominated', 'interval', 'subdivision' or 'bernstein')"
                ))))
            }
        };
        let boxes = py.allow_threads(|| self.0.final_bound(b)).py_err()?;
        Ok(boxes.iter().map(|i| (i.lo(), i.hi())).collect())
    }
    /// Rigorous enclosures of the final state reached from each initial point (N x n), as
    /// (N, n, 2) bounds: the final models evaluated in interval arithmetic at the point.
    fn final_enclose<'py>(&self, py: Python<'py>, points: Vec<Vec<f64>>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let fp = &self.0;
        let n = fp.names.len();
        let mut out = numpy::ndarray::Array3::<f64>::zeros((points.len(), n, 2));
        for (p, x) in points.iter().enumerate() {
            let Some(z) = normalise_initial_point(&self.1, x) else {
                return Err(crate::error::to_py(taylor::TaylorError::input(format!(
                    "initial point {x:?} is not in the initial box (one value per state variable, each inside its interval)"
                ))));
            };
            let mut args = vec![Interval::ZERO; fp.space.nvars];
            args[1..=n].copy_from_slice(&z);
            for (v, m) in fp.final_state.iter().enumerate() {
                let e = m.eval_interval(&fp.space, &args);
                out[[p, v, 0]] = e.lo();
                out[[p, v, 1]] = e.hi();
            }
        }
        Ok(out.to_pyarray(py))
    }
}

#[pyclass(name = "HybridRun", module = "percver._core", frozen)]
/// A hybrid automaton's reach set: its segments per mode and its states at the horizon, over
/// the automaton's variables and the clock `time` (the last).
pub struct PyHybridRun(pub Run, pub Arc<Space>, pub Vec<String>);

/// The reach set of the automaton (names, modes, jumps: as for a hybrid plant) from the box
/// `init` in mode `start`, up to `t_end` and `max_jumps` jumps, Flow*'s way; with
/// `box_at_jumps` the state is boxed at every jump.
#[pyfunction]
#[pyo3(signature = (names, modes, jumps, start, init, t_end, step, order, cutoff, remainder, max_jumps, max_branches, box_at_jumps))]
#[allow(clippy::too_many_arguments)]
pub fn hybrid_reach(
    py: Python<'_>,
    names: Vec<String>,
    modes: Vec<ModeArg>,
    jumps: Vec<JumpArg>,
    start: usize,
    init: Vec<(f64, f64)>,
    t_end: f64,
    step: StepArg,
    order: OrderArg,
    cutoff: f64,
    remainder: Vec<f64>,
    max_jumps: usize,
    max_branches: usize,
    box_at_jumps: bool,
) -> PyResult<PyHybridRun> {
    let aut = automaton(names.clone(), modes, jumps)?;
    let init = to_intervals(&init, &names)?;
    let flow = Settings {
        step: step_size(step),
        order: order_policy(order),
        t_end: 0.0,
        cutoff,
        remainder_estimate: remainder,
        precondition: Precondition::Identity,
        refinements: 30,
        symbolic_queue: 100,
    };
    let limits = Limits {
        max_time: t_end,
        max_jumps,
        max_branches,
        max_exits: usize::MAX,
        contract: vec![],
        drop_past_max_jumps: true,
        box_at_jumps,
    };
    let (run, space) = py.allow_threads(|| hybrid::reach(&aut, start, &init, t_end, &flow, &limits)).py_err()?;
    Ok(PyHybridRun(run, space, names.into_iter().chain([hybrid::TIME.to_string()]).collect()))
}

#[pymethods]
impl PyHybridRun {
    /// The variables of every box: the automaton's, then the clock.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.2.clone()
    }
    /// Per segment: (mode index, t0, t1, [(lo, hi) per variable]).
    fn segments(&self) -> Vec<(usize, f64, f64, Vec<(f64, f64)>)> {
        self.0.segments.iter().map(|(m, s)| (*m, s.t0, s.t1, s.bounds.iter().map(|b| (b.lo(), b.hi())).collect())).collect()
    }
    /// Per state at the horizon: (mode index, [(lo, hi) per variable]).
    fn finals(&self) -> Vec<(usize, Vec<(f64, f64)>)> {
        let bounds = |state: &Vec<TaylorModel>| state.iter().map(|t| taylor::bound::range(t, &self.1)).map(|b| (b.lo(), b.hi())).collect();
        self.0.exit_modes.iter().zip(&self.0.exits).map(|(m, state)| (*m, bounds(state))).collect()
    }
    #[getter]
    fn failure(&self) -> Option<String> {
        self.0.failure.clone()
    }
    #[getter]
    fn aggregations(&self) -> usize {
        self.0.aggregations
    }
}
