//! `percver._core.Expr` and its evaluators (floats, intervals, Taylor models).
use crate::error::{to_py, IntoPy};
use numpy::{PyArray2, PyReadonlyArray2, ToPyArray};
use pyo3::prelude::*;
use pyo3::types::PyAnyMethods;
use taylor::expr::{FloatBatch, Intervals, TaylorModels};
use taylor::{BinOp, Cmp, Ctx, Expr, Func, Interval, Program, Space, TaylorError, TaylorModel};

#[pyclass(name = "Expr", module = "percver._core", frozen)]
#[derive(Clone)]
pub struct PyExpr(pub Expr);

/// A comparison `lhs cmp rhs`, the argument of `where` and of properties.
#[pyclass(name = "Condition", module = "percver._core", frozen)]
#[derive(Clone)]
pub struct PyCondition {
    pub lhs: Expr,
    pub cmp: Cmp,
    pub rhs: Expr,
}

pub fn function(name: &str) -> PyResult<Func> {
    Func::from_name(name).ok_or_else(|| to_py(TaylorError::input(format!("unknown function '{name}'"))))
}

/// A number entering an expression: an infinite or NaN one makes bounds and float evaluation
/// disagree (x * inf is bounded as [0, inf] but evaluates to NaN at x = 0), so it is refused.
fn finite(value: f64, what: &str) -> PyResult<f64> {
    if value.is_finite() {
        return Ok(value);
    }
    Err(to_py(TaylorError::input(format!("{what} {value} is not a finite number; expressions take finite numbers only"))))
}

/// Accepts an Expr or a number.
fn operand(value: &Bound<'_, PyAny>) -> PyResult<Expr> {
    if let Ok(e) = value.extract::<PyExpr>() {
        return Ok(e.0);
    }
    if let Ok(v) = value.extract::<f64>() {
        return Ok(Expr::constant(finite(v, "constant")?));
    }
    Err(pyo3::exceptions::PyTypeError::new_err(format!("expected an expression or a number, got {}", value.get_type().name()?)))
}

fn cond(lhs: &Expr, cmp: Cmp, rhs: &Bound<'_, PyAny>) -> PyResult<PyCondition> {
    Ok(PyCondition { lhs: lhs.clone(), cmp, rhs: operand(rhs)? })
}

#[pymethods]
impl PyExpr {
    #[staticmethod]
    fn var(name: &str) -> PyResult<Self> {
        if name.is_empty() || !name.chars().all(|c| c.is_alphanumeric() || c == '_') {
            return Err(to_py(TaylorError::input(format!("'{name}' is not a valid variable name (letters, digits, _)"))));
        }
        Ok(PyExpr(Expr::var(name)))
    }
    #[staticmethod]
    fn constant(value: f64) -> PyResult<Self> {
        Ok(PyExpr(Expr::constant(finite(value, "constant")?)))
    }
    /// A constant known only to lie in [lo, hi].
    #[staticmethod]
    fn uncertain(lo: f64, hi: f64) -> PyResult<Self> {
        let (lo, hi) = (finite(lo, "uncertain lower bound")?, finite(hi, "uncertain upper bound")?);
        Ok(PyExpr(Expr::uncertain(Interval::new(lo, hi).py_err()?)))
    }
    #[staticmethod]
    fn parse(text: &str) -> PyResult<Self> {
        Ok(PyExpr(taylor::parser::parse_expr(text).py_err()?))
    }
    #[staticmethod]
    fn apply(name: &str, arg: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::func(function(name)?, &operand(arg)?)))
    }
    #[staticmethod]
    fn select(condition: &PyCondition, then: &Bound<'_, PyAny>, otherwise: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::select(&condition.lhs, condition.cmp, &condition.rhs, &operand(then)?, &operand(otherwise)?)))
    }
    #[staticmethod]
    fn minimum(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Min, &operand(a)?, &operand(b)?)))
    }
    #[staticmethod]
    fn maximum(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Max, &operand(a)?, &operand(b)?)))
    }
    fn variables(&self) -> Vec<String> {
        self.0.variables()
    }
    /// The variable's name if this expression is a bare variable.
    fn name(&self) -> Option<String> {
        match &*self.0 .0 {
            taylor::expr::Node::Var(n) => Some(n.clone()),
            _ => None,
        }
    }
    fn __add__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Add, &self.0, &operand(o)?)))
    }
    fn __radd__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Add, &operand(o)?, &self.0)))
    }
    fn __sub__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Sub, &self.0, &operand(o)?)))
    }
    fn __rsub__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Sub, &operand(o)?, &self.0)))
    }
    fn __mul__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Mul, &self.0, &operand(o)?)))
    }
    fn __rmul__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Mul, &operand(o)?, &self.0)))
    }
    fn __truediv__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Div, &self.0, &operand(o)?)))
    }
    fn __rtruediv__(&self, o: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(PyExpr(Expr::binary(BinOp::Div, &operand(o)?, &self.0)))
    }
    fn __pow__(&self, exponent: f64, modulo: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        if modulo.is_some() || !exponent.is_finite() {
            return Err(to_py(TaylorError::input("powers need a finite constant exponent and no modulus")));
        }
        Ok(PyExpr(self.0.powf(exponent)))
    }
    fn __neg__(&self) -> Self {
        PyExpr(self.0.neg())
    }
    fn __pos__(&self) -> Self {
        self.clone()
    }
    fn __lt__(&self, o: &Bound<'_, PyAny>) -> PyResult<PyCondition> {
        cond(&self.0, Cmp::Lt, o)
    }
    fn __le__(&self, o: &Bound<'_, PyAny>) -> PyResult<PyCondition> {
        cond(&self.0, Cmp::Le, o)
    }
    fn __gt__(&self, o: &Bound<'_, PyAny>) -> PyResult<PyCondition> {
        cond(&self.0, Cmp::Gt, o)
    }
    fn __ge__(&self, o: &Bound<'_, PyAny>) -> PyResult<PyCondition> {
        cond(&self.0, Cmp::Ge, o)
    }
    fn __hash__(slf: &Bound<'_, Self>) -> isize {
        slf.as_ptr() as isize
    }
    /// The expression with the variables named in `mapping` replaced (shared nodes stay shared,
    /// parameters keep their identity).
    fn substitute(&self, mapping: std::collections::HashMap<String, Bound<'_, PyAny>>) -> PyResult<Self> {
        let map = mapping.into_iter().map(|(name, value)| Ok((name, operand(&value)?))).collect::<PyResult<_>>()?;
        Ok(PyExpr(self.0.substitute(&map)))
    }
    /// Structural hash (each shared node once): for fingerprints of large expression DAGs.
    fn structural_hash(&self) -> u64 {
        self.0.structural_hash()
    }
    /// The uncertain parameters the expression reads, as (id, lo, hi), each once: simulations
    /// draw values for them by id (`eval_float(..., parameters={id: values})`).
    fn parameters(&self) -> Vec<(u64, f64, f64)> {
        self.0.parameters().into_iter().map(|(id, r)| (id, r.lo(), r.hi())).collect()
    }
    fn __repr__(&self) -> String {
        self.0.describe(2000)
    }
    /// Pickling (Dask, process pools): the DAG as a node list, each shared node once.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (Vec<FlatNode>,))> {
        Ok((slf.get_type().getattr("_from_nodes")?, (flatten(&slf.get().0),)))
    }
    #[staticmethod]
    fn _from_nodes(nodes: Vec<FlatNode>) -> PyResult<Self> {
        unflatten(&nodes).map(PyExpr)
    }
}

/// One DAG node for pickling: (kind, operator/function index, numbers, child indices, name).
type FlatNode = (u8, u8, Vec<f64>, Vec<usize>, String);
const BINOPS: [BinOp; 6] = [BinOp::Add, BinOp::Sub, BinOp::Mul, BinOp::Div, BinOp::Min, BinOp::Max];
const CMPS: [Cmp; 4] = [Cmp::Lt, Cmp::Le, Cmp::Gt, Cmp::Ge];
const FUNCS: [Func; 11] =
    [Func::Exp, Func::Log, Func::Sqrt, Func::Sin, Func::Cos, Func::Tan, Func::Atan, Func::Tanh, Func::Sigmoid, Func::Recip, Func::Abs];

fn position<T: PartialEq>(all: &[T], x: &T) -> u8 {
    all.iter().position(|y| y == x).expect("every variant is listed") as u8
}

/// Nodes in post-order (children before parents), the root last.
fn flatten(root: &Expr) -> Vec<FlatNode> {
    use taylor::expr::Node;
    fn go(e: &Expr, memo: &mut std::collections::HashMap<usize, usize>, out: &mut Vec<FlatNode>) -> usize {
        let key = std::sync::Arc::as_ptr(&e.0) as usize;
        if let Some(&i) = memo.get(&key) {
            return i;
        }
        let node = match &*e.0 {
            Node::Const(c) => (0, 0, vec![*c], vec![], String::new()),
            Node::Uncertain { range, id } => (1, 0, vec![range.lo(), range.hi()], vec![], id.to_string()),
            Node::Var(n) => (2, 0, vec![], vec![], n.clone()),
            Node::Neg(a) => (3, 0, vec![], vec![go(a, memo, out)], String::new()),
            Node::Binary(op, a, b) => (4, position(&BINOPS, op), vec![], vec![go(a, memo, out), go(b, memo, out)], String::new()),
            Node::PowI(a, n) => (5, 0, vec![*n as f64], vec![go(a, memo, out)], String::new()),
            Node::PowF(a, r) => (6, 0, vec![*r], vec![go(a, memo, out)], String::new()),
            Node::Func(f, a) => (7, position(&FUNCS, f), vec![], vec![go(a, memo, out)], String::new()),
            Node::Where { lhs, cmp, rhs, then, otherwise } => {
                let args = [lhs, rhs, then, otherwise].map(|x| go(x, memo, out)).to_vec();
                (8, position(&CMPS, cmp), vec![], args, String::new())
            }
        };
        out.push(node);
        memo.insert(key, out.len() - 1);
        out.len() - 1
    }
    let mut out = Vec::new();
    go(root, &mut std::collections::HashMap::new(), &mut out);
    out
}

fn unflatten(nodes: &[FlatNode]) -> PyResult<Expr> {
    let bad = || to_py(TaylorError::input("corrupt pickled expression"));
    let mut built: Vec<Expr> = Vec::with_capacity(nodes.len());
    for (kind, sub, x, args, name) in nodes {
        let arg = |k: usize| args.get(k).and_then(|&i| built.get(i)).cloned().ok_or_else(bad);
        let num = |k: usize| x.get(k).copied().ok_or_else(bad);
        let e = match kind {
            0 => Expr::constant(num(0)?),
            1 => Expr::parameter(Interval::new(num(0)?, num(1)?).py_err()?, name.parse().map_err(|_| bad())?),
            2 => Expr::var(name),
            3 => arg(0)?.neg(),
            4 => Expr::binary(*BINOPS.get(*sub as usize).ok_or_else(bad)?, &arg(0)?, &arg(1)?),
            5 => arg(0)?.powi(num(0)? as i32),
            6 => arg(0)?.powf(num(0)?),
            7 => Expr::func(*FUNCS.get(*sub as usize).ok_or_else(bad)?, &arg(0)?),
            8 => Expr::select(&arg(0)?, *CMPS.get(*sub as usize).ok_or_else(bad)?, &arg(1)?, &arg(2)?, &arg(3)?),
            _ => return Err(bad()),
        };
        built.push(e);
    }
    built.pop().ok_or_else(bad)
}

#[pymethods]
impl PyCondition {
    /// The expression lhs - rhs whose sign the condition tests.
    fn margin(&self) -> PyExpr {
        PyExpr(Expr::binary(BinOp::Sub, &self.lhs, &self.rhs))
    }
    #[getter]
    fn op(&self) -> &'static str {
        self.cmp.symbol()
    }
    #[getter]
    fn lhs(&self) -> PyExpr {
        PyExpr(self.lhs.clone())
    }
    #[getter]
    fn rhs(&self) -> PyExpr {
        PyExpr(self.rhs.clone())
    }
    fn __bool__(&self) -> PyResult<bool> {
        Err(pyo3::exceptions::PyTypeError::new_err("a symbolic condition has no truth value; use it in pv.where(...) or as a property"))
    }
    fn __repr__(&self) -> String {
        format!("{} {} {}", self.lhs.describe(1000), self.cmp.symbol(), self.rhs.describe(1000))
    }
    /// Pickling: rebuilt as `operator.ge(lhs, rhs)` (and so on), which calls Expr's comparison.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (PyExpr, PyExpr))> {
        let name = match self.cmp {
            Cmp::Lt => "lt",
            Cmp::Le => "le",
            Cmp::Gt => "gt",
            Cmp::Ge => "ge",
        };
        Ok((py.import("operator")?.getattr(name)?, (PyExpr(self.lhs.clone()), PyExpr(self.rhs.clone()))))
    }
}

pub fn compile(exprs: &[PyExpr], names: &[String]) -> PyResult<Program> {
    let e: Vec<Expr> = exprs.iter().map(|e| e.0.clone()).collect();
    Program::compile(&e, names).py_err()
}

pub fn to_intervals(bounds: &[(f64, f64)], names: &[String]) -> PyResult<Vec<Interval>> {
    bounds
        .iter()
        .zip(names)
        .map(|(&(lo, hi), n)| Interval::new(lo, hi).map_err(|e| to_py(TaylorError::input(format!("bound of '{n}': {e}")))))
        .collect()
}

/// Float evaluation of `exprs` on the rows of `points` (N x len(names)) -> N x len(exprs).
/// `parameters` maps a parameter's id to its value in each row (others take their midpoint).
#[pyfunction]
#[pyo3(signature = (exprs, names, points, parameters=None))]
pub fn eval_float<'py>(
    py: Python<'py>,
    exprs: Vec<PyExpr>,
    names: Vec<String>,
    points: PyReadonlyArray2<'py, f64>,
    parameters: Option<std::collections::HashMap<u64, Vec<f64>>>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let program = compile(&exprs, &names)?;
    let a = points.as_array();
    if a.ncols() != names.len() {
        return Err(to_py(TaylorError::input(format!("points have {} columns for {} variables", a.ncols(), names.len()))));
    }
    let n = a.nrows();
    let mut batch = FloatBatch::new(n);
    for (id, values) in parameters.unwrap_or_default() {
        if values.len() != n {
            return Err(to_py(TaylorError::input(format!("parameter {id} has {} values for {n} points", values.len()))));
        }
        batch.parameters.insert(id, values);
    }
    let columns: Vec<Vec<f64>> = (0..a.ncols()).map(|j| a.column(j).to_vec()).collect();
    let out = py.allow_threads(|| program.eval(&batch, &columns)).py_err()?;
    let m = out.len();
    let arr = numpy::ndarray::Array2::from_shape_fn((n, m), |(i, j)| out[j][i]);
    Ok(arr.to_pyarray(py))
}

/// Interval evaluation over a box.
#[pyfunction]
pub fn eval_interval(exprs: Vec<PyExpr>, names: Vec<String>, bounds: Vec<(f64, f64)>) -> PyResult<Vec<(f64, f64)>> {
    let program = compile(&exprs, &names)?;
    let b = to_intervals(&bounds, &names)?;
    let out = program.eval(&Intervals, &b).py_err()?;
    Ok(out.iter().map(|i| (i.lo(), i.hi())).collect())
}

/// Taylor models of expressions over a box (each variable mapped affinely onto [-1, 1]).
#[pyclass(name = "TaylorModels", module = "percver._core", frozen)]
pub struct PyTaylorModels {
    models: Vec<TaylorModel>,
    space: std::sync::Arc<Space>,
    centre: Vec<f64>,
    radius: Vec<f64>,
}

#[pyfunction]
#[pyo3(signature = (exprs, names, bounds, order=6, cutoff=0.0))]
pub fn taylor_models(
    py: Python<'_>,
    exprs: Vec<PyExpr>,
    names: Vec<String>,
    bounds: Vec<(f64, f64)>,
    order: usize,
    cutoff: f64,
) -> PyResult<PyTaylorModels> {
    let program = compile(&exprs, &names)?;
    let b = to_intervals(&bounds, &names)?;
    let space = Space::get(names.len(), order, 0).py_err()?;
    let ctx = Ctx::new(space.clone(), order, cutoff);
    let centre: Vec<f64> = b.iter().map(|i| i.mid()).collect();
    let radius: Vec<f64> = b.iter().zip(&centre).map(|(i, &m)| (i.hi() - m).max(m - i.lo()).next_up()).collect();
    let inputs: Vec<TaylorModel> = (0..names.len()).map(|v| TaylorModel::affine(&ctx, centre[v], v, radius[v])).collect();
    let models = py.allow_threads(|| program.eval(&TaylorModels { ctx: &ctx }, &inputs)).py_err()?;
    Ok(PyTaylorModels { models, space, centre, radius })
}

#[pymethods]
impl PyTaylorModels {
    /// Naive (monomial-wise) range bound of each model.
    fn bound(&self) -> Vec<(f64, f64)> {
        self.models.iter().map(|m| m.bound(&self.space)).map(|i| (i.lo(), i.hi())).collect()
    }
    /// Range bound refined by the linear dominated bounder.
    fn range(&self) -> Vec<(f64, f64)> {
        self.models.iter().map(|m| taylor::bound::range(m, &self.space)).map(|i| (i.lo(), i.hi())).collect()
    }
    fn remainders(&self) -> Vec<(f64, f64)> {
        self.models.iter().map(|m| (m.rem.lo(), m.rem.hi())).collect()
    }
    fn degree(&self) -> Vec<usize> {
        self.models.iter().map(|m| m.degree(&self.space)).collect()
    }
    /// Rigorous enclosures (lo, hi arrays, N x m) of the models at the given points of the box.
    fn enclose<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
        let a = points.as_array();
        let nv = self.centre.len();
        if a.ncols() != nv {
            return Err(to_py(TaylorError::input(format!("points have {} columns for {} variables", a.ncols(), nv))));
        }
        let (n, m) = (a.nrows(), self.models.len());
        let mut lo = numpy::ndarray::Array2::<f64>::zeros((n, m));
        let mut hi = lo.clone();
        for i in 0..n {
            for v in 0..nv {
                if !((a[(i, v)] - self.centre[v]).abs() <= self.radius[v]) {
                    return Err(to_py(TaylorError::input(format!("point {i} lies outside the box in variable {v}: {}", a[(i, v)]))));
                }
            }
            // Normalised coordinates as intervals: (x - c) / r, enclosed.
            let z: Vec<Interval> = (0..nv)
                .map(|v| {
                    ((Interval::point(a[(i, v)]) - Interval::point(self.centre[v]))
                        * Interval::point(self.radius[v]).recip().unwrap_or(Interval::ENTIRE))
                    .intersect(&Interval::SYMMETRIC)
                })
                .collect();
            for (j, model) in self.models.iter().enumerate() {
                let e = model.eval_interval(&self.space, &z);
                lo[(i, j)] = e.lo();
                hi[(i, j)] = e.hi();
            }
        }
        Ok((lo.to_pyarray(py), hi.to_pyarray(py)))
    }
}

/// Parses Flow*'s constraint syntax `lhs <= rhs` into a Condition.
#[pyfunction]
pub fn parse_condition(text: &str) -> PyResult<PyCondition> {
    let (lhs, cmp, rhs) = taylor::parser::parse_constraint(text).py_err()?;
    Ok(PyCondition { lhs, cmp, rhs })
}
