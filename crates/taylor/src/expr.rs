//! Expressions: one definition of a function, evaluated on floats, intervals and Taylor models.
//!
//! An [`Expr`] is an immutable DAG (children shared through `Arc`). Before evaluation it is
//! compiled into a [`Program`]: a topologically ordered list of operations over slots, with
//! shared sub-expressions computed once and variable names resolved to input positions.
//! The same program runs on every [`Algebra`], which is what keeps simulation (floats) and
//! verification (sets) from drifting apart.
use crate::error::{Result, TaylorError};
use crate::functions::{div_tm, powf_tm, Func};
use crate::interval::Interval;
use crate::tm::{Ctx, TaylorModel};
use std::collections::HashMap;
use std::fmt;
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Min,
    Max,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Cmp {
    Lt,
    Le,
    Gt,
    Ge,
}

impl Cmp {
    /// Does `lhs - rhs` with value `d` satisfy the comparison?
    pub fn holds(&self, d: f64) -> bool {
        match self {
            Cmp::Lt => d < 0.0,
            Cmp::Le => d <= 0.0,
            Cmp::Gt => d > 0.0,
            Cmp::Ge => d >= 0.0,
        }
    }
    /// Decide the comparison for every value of `lhs - rhs` in `d`, or None if it depends.
    pub fn decide(&self, d: Interval) -> Option<bool> {
        match self {
            Cmp::Lt if d.hi() < 0.0 => Some(true),
            Cmp::Lt if d.lo() >= 0.0 => Some(false),
            Cmp::Le if d.hi() <= 0.0 => Some(true),
            Cmp::Le if d.lo() > 0.0 => Some(false),
            Cmp::Gt if d.lo() > 0.0 => Some(true),
            Cmp::Gt if d.hi() <= 0.0 => Some(false),
            Cmp::Ge if d.lo() >= 0.0 => Some(true),
            Cmp::Ge if d.hi() < 0.0 => Some(false),
            _ => None,
        }
    }
    pub fn symbol(&self) -> &'static str {
        match self {
            Cmp::Lt => "<",
            Cmp::Le => "<=",
            Cmp::Gt => ">",
            Cmp::Ge => ">=",
        }
    }
}

#[derive(Debug)]
pub enum Node {
    Const(f64),
    /// A constant known only to an interval (uncertain parameter), as in Flow*'s `[a, b]`. `id`
    /// is its identity: two parameters with the same range are different quantities, and a
    /// simulation draws each one's value by id ([`FloatBatch::parameters`]).
    Uncertain {
        range: Interval,
        id: u64,
    },
    Var(String),
    Neg(Expr),
    Binary(BinOp, Expr, Expr),
    PowI(Expr, i32),
    PowF(Expr, f64),
    Func(Func, Expr),
    /// `where(lhs cmp rhs, then, otherwise)`: piecewise definitions (limits, walls, modes).
    Where {
        lhs: Expr,
        cmp: Cmp,
        rhs: Expr,
        then: Expr,
        otherwise: Expr,
    },
}

#[derive(Clone, Debug)]
pub struct Expr(pub Arc<Node>);

/// Fresh parameter ids: a counter from a random start, so expressions pickled in one process and
/// built in another do not confuse their parameters.
fn next_parameter_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::OnceLock;
    static NEXT: OnceLock<AtomicU64> = OnceLock::new();
    let next = NEXT.get_or_init(|| {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u32(std::process::id());
        AtomicU64::new(h.finish() >> 1)
    });
    next.fetch_add(1, Ordering::Relaxed)
}

impl Expr {
    fn new(n: Node) -> Expr {
        Expr(Arc::new(n))
    }
    pub fn constant(c: f64) -> Expr {
        Expr::new(Node::Const(c))
    }
    /// A new uncertain parameter: a quantity of its own, whatever its range.
    pub fn uncertain(iv: Interval) -> Expr {
        Expr::parameter(iv, next_parameter_id())
    }
    /// The parameter `id` (a pickled or parsed expression's own parameter, kept by identity).
    pub fn parameter(range: Interval, id: u64) -> Expr {
        Expr::new(Node::Uncertain { range, id })
    }
    pub fn var(name: &str) -> Expr {
        Expr::new(Node::Var(name.to_string()))
    }
    pub fn neg(&self) -> Expr {
        Expr::new(Node::Neg(self.clone()))
    }
    pub fn binary(op: BinOp, a: &Expr, b: &Expr) -> Expr {
        Expr::new(Node::Binary(op, a.clone(), b.clone()))
    }
    pub fn powi(&self, n: i32) -> Expr {
        Expr::new(Node::PowI(self.clone(), n))
    }
    pub fn powf(&self, r: f64) -> Expr {
        if r == r.trunc() && r.abs() < 1e9 {
            return self.powi(r as i32);
        }
        Expr::new(Node::PowF(self.clone(), r))
    }
    pub fn func(f: Func, a: &Expr) -> Expr {
        Expr::new(Node::Func(f, a.clone()))
    }
    pub fn select(lhs: &Expr, cmp: Cmp, rhs: &Expr, then: &Expr, otherwise: &Expr) -> Expr {
        Expr::new(Node::Where { lhs: lhs.clone(), cmp, rhs: rhs.clone(), then: then.clone(), otherwise: otherwise.clone() })
    }
    /// min(max(x, lo), hi)
    pub fn clip(&self, lo: &Expr, hi: &Expr) -> Expr {
        Expr::binary(BinOp::Min, &Expr::binary(BinOp::Max, self, lo), hi)
    }

    /// Every distinct node (shared ones once), parents before children, left to right.
    fn nodes(&self) -> Vec<Expr> {
        let mut out = Vec::new();
        let mut stack = vec![self.clone()];
        let mut visited = std::collections::HashSet::new();
        while let Some(e) = stack.pop() {
            if !visited.insert(Arc::as_ptr(&e.0) as usize) {
                continue;
            }
            match &*e.0 {
                Node::Const(_) | Node::Uncertain { .. } | Node::Var(_) => {}
                Node::Neg(a) | Node::PowI(a, _) | Node::PowF(a, _) | Node::Func(_, a) => stack.push(a.clone()),
                Node::Binary(_, a, b) => {
                    stack.push(b.clone());
                    stack.push(a.clone());
                }
                Node::Where { lhs, rhs, then, otherwise, .. } => {
                    for x in [otherwise, then, rhs, lhs] {
                        stack.push(x.clone());
                    }
                }
            }
            out.push(e);
        }
        out
    }

    /// The uncertain parameters used, by id with their ranges, in order of first appearance.
    pub fn parameters(&self) -> Vec<(u64, Interval)> {
        let mut out: Vec<(u64, Interval)> = Vec::new();
        for e in self.nodes() {
            if let Node::Uncertain { range, id } = &*e.0 {
                if !out.iter().any(|(k, _)| k == id) {
                    out.push((*id, *range));
                }
            }
        }
        out
    }

    /// The expression with the variables named in `map` replaced by expressions. Shared nodes
    /// stay shared (each distinct node is rebuilt once) and parameters keep their identity, so a
    /// model written in terms of other signals becomes one over the states without copies.
    pub fn substitute(&self, map: &HashMap<String, Expr>) -> Expr {
        // Post-order without recursion: a network written as an expression is thousands deep.
        let mut done: HashMap<usize, Expr> = HashMap::new();
        let mut stack = vec![(self.clone(), false)];
        let key = |e: &Expr| Arc::as_ptr(&e.0) as usize;
        while let Some((e, expanded)) = stack.pop() {
            if done.contains_key(&key(&e)) {
                continue;
            }
            let children = children_of(&e);
            if !expanded && children.iter().any(|c| !done.contains_key(&key(c))) {
                stack.push((e.clone(), true));
                stack.extend(children.into_iter().map(|c| (c.clone(), false)));
                continue;
            }
            let new = |c: &Expr| done[&key(c)].clone();
            let unchanged = |cs: &[&Expr]| cs.iter().all(|c| Arc::ptr_eq(&done[&key(c)].0, &c.0));
            let rebuilt = match &*e.0 {
                Node::Var(_) | Node::Const(_) | Node::Uncertain { .. } => map_leaf(&e, map),
                _ if unchanged(&children_of(&e)) => e.clone(),
                Node::Neg(a) => new(a).neg(),
                Node::PowI(a, n) => new(a).powi(*n),
                Node::PowF(a, r) => Expr::new(Node::PowF(new(a), *r)),
                Node::Func(f, a) => Expr::func(*f, &new(a)),
                Node::Binary(op, a, b) => Expr::binary(*op, &new(a), &new(b)),
                Node::Where { lhs, cmp, rhs, then, otherwise } => Expr::select(&new(lhs), *cmp, &new(rhs), &new(then), &new(otherwise)),
            };
            done.insert(key(&e), rebuilt);
        }
        return done[&key(self)].clone();

        fn children_of(e: &Expr) -> Vec<&Expr> {
            match &*e.0 {
                Node::Const(_) | Node::Uncertain { .. } | Node::Var(_) => vec![],
                Node::Neg(a) | Node::PowI(a, _) | Node::PowF(a, _) | Node::Func(_, a) => vec![a],
                Node::Binary(_, a, b) => vec![a, b],
                Node::Where { lhs, rhs, then, otherwise, .. } => vec![lhs, rhs, then, otherwise],
            }
        }
        fn map_leaf(e: &Expr, map: &HashMap<String, Expr>) -> Expr {
            match &*e.0 {
                Node::Var(n) => map.get(n).cloned().unwrap_or_else(|| e.clone()),
                _ => e.clone(),
            }
        }
    }

    /// Names of the variables used, in order of first appearance.
    pub fn variables(&self) -> Vec<String> {
        let mut seen = std::collections::HashSet::new();
        let mut out: Vec<String> = Vec::new();
        for e in self.nodes() {
            if let Node::Var(n) = &*e.0 {
                if seen.insert(n.clone()) {
                    out.push(n.clone());
                }
            }
        }
        out
    }
}

impl Expr {
    /// The expression as text, cut after about `limit` characters: a DAG with shared
    /// subexpressions can print exponentially long.
    pub fn describe(&self, limit: usize) -> String {
        struct Bounded {
            text: String,
            limit: usize,
        }
        impl fmt::Write for Bounded {
            fn write_str(&mut self, s: &str) -> fmt::Result {
                if self.text.len() + s.len() > self.limit {
                    return Err(fmt::Error);
                }
                self.text.push_str(s);
                Ok(())
            }
        }
        let mut out = Bounded { text: String::new(), limit };
        if fmt::write(&mut out, format_args!("{self}")).is_err() {
            out.text.push_str(" ...");
        }
        out.text
    }

    /// A hash of the expression's structure, linear in the number of distinct nodes (each shared
    /// node is hashed once), stable across runs: for journals' problem fingerprints.
    pub fn structural_hash(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        // Parameters hash by their order of first appearance, not their random ids: `a + a` and
        // `a + b` are different problems, and the hash is the same in every process.
        fn go(e: &Expr, memo: &mut HashMap<usize, u64>, params: &mut HashMap<u64, usize>) -> u64 {
            let key = Arc::as_ptr(&e.0) as usize;
            if let Some(&h) = memo.get(&key) {
                return h;
            }
            let mut s = std::collections::hash_map::DefaultHasher::new();
            let mut go = |e: &Expr| go(e, memo, params);
            match &*e.0 {
                Node::Const(c) => (0u8, c.to_bits()).hash(&mut s),
                Node::Uncertain { range, id } => {
                    let fresh = params.len();
                    let ordinal = *params.entry(*id).or_insert(fresh);
                    (1u8, range.lo().to_bits(), range.hi().to_bits(), ordinal).hash(&mut s)
                }
                Node::Var(n) => (2u8, n).hash(&mut s),
                Node::Neg(a) => (3u8, go(a)).hash(&mut s),
                Node::Binary(op, a, b) => (4u8, *op as u8, go(a), go(b)).hash(&mut s),
                Node::PowI(a, n) => (5u8, go(a), n).hash(&mut s),
                Node::PowF(a, r) => (6u8, go(a), r.to_bits()).hash(&mut s),
                Node::Func(f, a) => (7u8, *f as u8, go(a)).hash(&mut s),
                Node::Where { lhs, cmp, rhs, then, otherwise } => (8u8, *cmp as u8, go(lhs), go(rhs), go(then), go(otherwise)).hash(&mut s),
            }
            let h = s.finish();
            memo.insert(key, h);
            h
        }
        go(self, &mut HashMap::new(), &mut HashMap::new())
    }
}

impl fmt::Display for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &*self.0 {
            Node::Const(c) => write!(f, "{c:?}"),
            Node::Uncertain { range, .. } => write!(f, "[{:?}, {:?}]", range.lo(), range.hi()),
            Node::Var(n) => write!(f, "{n}"),
            Node::Neg(a) => write!(f, "(-{a})"),
            Node::Binary(op, a, b) => match op {
                BinOp::Add => write!(f, "({a} + {b})"),
                BinOp::Sub => write!(f, "({a} - {b})"),
                BinOp::Mul => write!(f, "({a} * {b})"),
                BinOp::Div => write!(f, "({a} / {b})"),
                BinOp::Min => write!(f, "min({a}, {b})"),
                BinOp::Max => write!(f, "max({a}, {b})"),
            },
            Node::PowI(a, n) => write!(f, "({a}^{n})"),
            Node::PowF(a, r) => write!(f, "({a}^{r:?})"),
            Node::Func(func, a) => write!(f, "{}({a})", func.name()),
            Node::Where { lhs, cmp, rhs, then, otherwise } => {
                write!(f, "where({lhs} {} {rhs}, {then}, {otherwise})", cmp.symbol())
            }
        }
    }
}

/// One step of a compiled program; operands are slot indices.
#[derive(Clone, Debug)]
pub enum Op {
    Const(f64),
    Uncertain { range: Interval, id: u64 },
    Input(usize),
    Neg(usize),
    Binary(BinOp, usize, usize),
    PowI(usize, i32),
    PowF(usize, f64),
    Func(Func, usize),
    Where { lhs: usize, cmp: Cmp, rhs: usize, then: usize, otherwise: usize },
}

impl Op {
    /// What the operation computes, as a hashable key: kind, operand slots and constants (bits).
    fn identity(&self) -> (u8, u8, [u64; 5]) {
        let u = |x: usize| x as u64;
        match *self {
            Op::Const(c) => (0, 0, [c.to_bits(), 0, 0, 0, 0]),
            Op::Uncertain { range, id } => (1, 0, [range.lo().to_bits(), range.hi().to_bits(), id, 0, 0]),
            Op::Input(i) => (2, 0, [u(i), 0, 0, 0, 0]),
            Op::Neg(a) => (3, 0, [u(a), 0, 0, 0, 0]),
            Op::Binary(op, a, b) => (4, op as u8, [u(a), u(b), 0, 0, 0]),
            Op::PowI(a, n) => (5, 0, [u(a), n as u64, 0, 0, 0]),
            Op::PowF(a, r) => (6, 0, [u(a), r.to_bits(), 0, 0, 0]),
            Op::Func(f, a) => (7, f as u8, [u(a), 0, 0, 0, 0]),
            Op::Where { lhs, cmp, rhs, then, otherwise } => (8, cmp as u8, [u(lhs), u(rhs), u(then), u(otherwise), 0]),
        }
    }
}

/// Slots already emitted, by expression node and by what they compute.
#[derive(Default)]
struct Slots {
    by_node: HashMap<usize, usize>,
    by_op: HashMap<(u8, u8, [u64; 5]), usize>,
}

/// Expressions compiled against an ordered list of input names.
#[derive(Clone, Debug)]
pub struct Program {
    pub inputs: Vec<String>,
    pub ops: Vec<Op>,
    pub outputs: Vec<usize>,
}

impl Program {
    /// A name listed twice in `inputs` is read at its first place: in a loop's environment a
    /// later one is a copy (a fused network carries states it passes on as identity neurons, whose
    /// models gain rounding at every step; the state itself is exact).
    ///
    /// Structurally equal operations share one slot (the same operation on the same slots is the
    /// same quantity at every point; a parameter is equal only to itself, by id). A slot is
    /// therefore what a quantity *is*, which is what [`Forking`] keys its decisions by.
    pub fn compile(outputs: &[Expr], inputs: &[String]) -> Result<Program> {
        let mut positions: HashMap<&str, usize> = HashMap::with_capacity(inputs.len());
        for (i, n) in inputs.iter().enumerate() {
            positions.entry(n.as_str()).or_insert(i);
        }
        let mut program = Program { inputs: inputs.to_vec(), ops: Vec::new(), outputs: Vec::new() };
        let mut slots = Slots::default();
        for e in outputs {
            let s = program.emit(e, &positions, &mut slots)?;
            program.outputs.push(s);
        }
        Ok(program)
    }

    fn emit(&mut self, e: &Expr, positions: &HashMap<&str, usize>, slots: &mut Slots) -> Result<usize> {
        let key = Arc::as_ptr(&e.0) as usize;
        if let Some(&s) = slots.by_node.get(&key) {
            return Ok(s);
        }
        let op = match &*e.0 {
            Node::Const(c) => Op::Const(*c),
            Node::Uncertain { range, id } => Op::Uncertain { range: *range, id: *id },
            Node::Var(n) => match positions.get(n.as_str()) {
                Some(&i) => Op::Input(i),
                None => {
                    return Err(TaylorError::input(format!(
                        "unknown variable '{n}' (known: {}); declare it as a state, input or parameter",
                        self.inputs.join(", ")
                    )))
                }
            },
            Node::Neg(a) => Op::Neg(self.emit(a, positions, slots)?),
            Node::Binary(op, a, b) => {
                let (a, b) = (self.emit(a, positions, slots)?, self.emit(b, positions, slots)?);
                Op::Binary(*op, a, b)
            }
            Node::PowI(a, n) => Op::PowI(self.emit(a, positions, slots)?, *n),
            Node::PowF(a, r) => Op::PowF(self.emit(a, positions, slots)?, *r),
            Node::Func(f, a) => Op::Func(*f, self.emit(a, positions, slots)?),
            Node::Where { lhs, cmp, rhs, then, otherwise } => Op::Where {
                lhs: self.emit(lhs, positions, slots)?,
                cmp: *cmp,
                rhs: self.emit(rhs, positions, slots)?,
                then: self.emit(then, positions, slots)?,
                otherwise: self.emit(otherwise, positions, slots)?,
            },
        };
        let slot = *slots.by_op.entry(op.identity()).or_insert_with(|| {
            self.ops.push(op);
            self.ops.len() - 1
        });
        slots.by_node.insert(key, slot);
        Ok(slot)
    }

    /// Runs the program on one algebra; returns one value per output.
    pub fn eval<A: Algebra>(&self, alg: &A, inputs: &[A::Value]) -> Result<Vec<A::Value>> {
        let values = self.eval_all(alg, inputs)?;
        Ok(self.outputs_of(&values))
    }

    /// Per output, whether it depends on each input (syntactically).
    pub fn dependencies(&self) -> Vec<Vec<bool>> {
        let deps = self.slot_dependencies();
        self.outputs.iter().map(|&s| deps[s].clone()).collect()
    }

    /// Per slot (op), whether its value depends on each input (syntactically).
    pub fn slot_dependencies(&self) -> Vec<Vec<bool>> {
        let n = self.inputs.len();
        let mut deps: Vec<Vec<bool>> = Vec::with_capacity(self.ops.len());
        for op in &self.ops {
            let mut d = vec![false; n];
            let operands: Vec<usize> = match *op {
                Op::Const(_) | Op::Uncertain { .. } => vec![],
                Op::Input(k) => {
                    d[k] = true;
                    vec![]
                }
                Op::Neg(a) | Op::PowI(a, _) | Op::PowF(a, _) | Op::Func(_, a) => vec![a],
                Op::Binary(_, a, b) => vec![a, b],
                Op::Where { lhs, rhs, then, otherwise, .. } => vec![lhs, rhs, then, otherwise],
            };
            for a in operands {
                d.iter_mut().zip(&deps[a]).for_each(|(x, &y)| *x |= y);
            }
            deps.push(d);
        }
        deps
    }

    /// The outputs among the values of every slot.
    pub fn outputs_of<T: Clone>(&self, values: &[T]) -> Vec<T> {
        self.outputs.iter().map(|&s| values[s].clone()).collect()
    }

    /// Per slot, whether its value is nonnegative by its form, whatever the inputs: an even
    /// power, a square `x * x`, |x|, sqrt, exp, sigmoid, a nonnegative constant, and sums,
    /// products, quotients, powers, minima and `where`s of such (a maximum needs one). Sets
    /// enclosing such a value may dip below 0 (`0 + 0` rounded down, a square's Taylor model
    /// bounded term by term) where the value cannot: a function defined only from 0 on (sqrt,
    /// a fractional power) gets the enclosure's nonnegative part ([`Algebra::func_nonneg`]).
    pub fn nonnegative_slots(&self) -> Vec<bool> {
        let mut out: Vec<bool> = Vec::with_capacity(self.ops.len());
        for op in &self.ops {
            let nonneg = match *op {
                Op::Const(c) => c >= 0.0,
                Op::Uncertain { range, .. } => range.lo() >= 0.0,
                Op::Input(_) | Op::Neg(_) => false,
                Op::PowI(a, n) => n % 2 == 0 || out[a],
                Op::PowF(..) => true, // defined only where its base is >= 0, and then >= 0
                Op::Func(f, a) => matches!(f, Func::Abs | Func::Sqrt | Func::Exp | Func::Sigmoid) || (f == Func::Recip && out[a]),
                Op::Binary(BinOp::Mul, a, b) if a == b => true,
                Op::Binary(BinOp::Add | BinOp::Mul | BinOp::Div | BinOp::Min, a, b) => out[a] && out[b],
                Op::Binary(BinOp::Max, a, b) => out[a] || out[b],
                Op::Binary(BinOp::Sub, ..) => false,
                Op::Where { then, otherwise, .. } => out[then] && out[otherwise],
            };
            out.push(nonneg);
        }
        out
    }

    /// The value of every slot (for callers that inspect intermediate results, such as the
    /// conditions of `where`).
    pub fn eval_all<A: Algebra>(&self, alg: &A, inputs: &[A::Value]) -> Result<Vec<A::Value>> {
        if inputs.len() != self.inputs.len() {
            return Err(TaylorError::input(format!(
                "expected {} inputs ({}), got {}",
                self.inputs.len(),
                self.inputs.join(", "),
                inputs.len()
            )));
        }
        // A slot may fail (a domain error) without failing the program: only a use of it does.
        // So a `where` whose condition is decided ignores the other branch even if that one is
        // undefined on the set (a ray's formula for a wall it does not hit).
        let mut v: Vec<Result<A::Value>> = Vec::with_capacity(self.ops.len());
        fn get<T>(v: &[Result<T>], i: usize) -> Result<&T> {
            v[i].as_ref().map_err(|e| e.clone())
        }
        let nonneg = self.nonnegative_slots();
        let known = |a: usize| nonneg[a];
        for op in &self.ops {
            let value = match op {
                Op::Const(c) => Ok(alg.constant(*c)),
                Op::Uncertain { range, id } => Ok(alg.uncertain(*range, *id)),
                Op::Input(i) => Ok(inputs[*i].clone()),
                Op::Neg(a) => get(&v, *a).map(|x| alg.neg(x)),
                Op::Binary(op, a, b) => get(&v, *a).and_then(|x| alg.binary(*op, x, get(&v, *b)?)),
                Op::PowI(a, n) => get(&v, *a).and_then(|x| alg.powi(x, *n)),
                Op::PowF(a, r) if known(*a) => get(&v, *a).and_then(|x| alg.powf_nonneg(x, *r)),
                Op::PowF(a, r) => get(&v, *a).and_then(|x| alg.powf(x, *r)),
                Op::Func(f, a) if known(*a) => get(&v, *a).and_then(|x| alg.func_nonneg(*f, x)),
                Op::Func(f, a) => get(&v, *a).and_then(|x| alg.func(*f, x)),
                Op::Where { lhs, cmp, rhs, then, otherwise } => (|| {
                    let (l, r) = (get(&v, *lhs)?, get(&v, *rhs)?);
                    match alg.decide_at(Question { lhs: *lhs, cmp: *cmp, rhs: *rhs }, l, r) {
                        Some(true) => get(&v, *then).cloned(),
                        Some(false) => get(&v, *otherwise).cloned(),
                        None => alg.select(l, *cmp, r, get(&v, *then)?, get(&v, *otherwise)?),
                    }
                })(),
            };
            v.push(if known(v.len()) { value.map(|x| alg.nonneg(x)) } else { value });
        }
        for &o in &self.outputs {
            v[o].clone()?;
        }
        Ok(v.into_iter().map(|x| x.unwrap_or_else(|_| alg.constant(f64::NAN))).collect())
    }
}

/// A condition of a compiled program: `slot lhs cmp slot rhs`. Two `where`s with the same
/// question ask it of the same quantities, so every point answers them alike.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Question {
    pub lhs: usize,
    pub cmp: Cmp,
    pub rhs: usize,
}

/// A number system the expression language can be evaluated in.
pub trait Algebra {
    type Value: Clone;
    fn constant(&self, c: f64) -> Self::Value;
    /// The value of parameter `id`, known to lie in `range`.
    fn uncertain(&self, range: Interval, id: u64) -> Self::Value;
    fn neg(&self, a: &Self::Value) -> Self::Value;
    fn binary(&self, op: BinOp, a: &Self::Value, b: &Self::Value) -> Result<Self::Value>;
    fn powi(&self, a: &Self::Value, n: i32) -> Result<Self::Value>;
    fn powf(&self, a: &Self::Value, r: f64) -> Result<Self::Value>;
    fn func(&self, f: Func, a: &Self::Value) -> Result<Self::Value>;
    /// A value nonnegative by its form ([`Program::nonnegative_slots`]): a set algebra may drop
    /// the part of its enclosure below 0 (intervals do; a Taylor model cannot).
    fn nonneg(&self, a: Self::Value) -> Self::Value {
        a
    }
    /// `f(a)` and `a^r` for an `a` nonnegative by its form: a set algebra may drop the part of
    /// `a`'s enclosure below 0.
    fn func_nonneg(&self, f: Func, a: &Self::Value) -> Result<Self::Value> {
        self.func(f, a)
    }
    fn powf_nonneg(&self, a: &Self::Value, r: f64) -> Result<Self::Value> {
        self.powf(a, r)
    }
    /// Whether `lhs cmp rhs` holds everywhere (Some(true)), nowhere (Some(false)), or either.
    fn decide(&self, lhs: &Self::Value, cmp: Cmp, rhs: &Self::Value) -> Option<bool>;
    /// Decides the condition a program asks at `question`; an algebra that follows a plan
    /// remembers its answers by question ([`Forking`]), the others decide on the values.
    fn decide_at(&self, question: Question, lhs: &Self::Value, rhs: &Self::Value) -> Option<bool> {
        self.decide(lhs, question.cmp, rhs)
    }
    /// `then` where `lhs cmp rhs` holds, `otherwise` elsewhere; sets take the hull when the
    /// comparison is undecided (callers that need branching decide the condition first).
    fn select(&self, lhs: &Self::Value, cmp: Cmp, rhs: &Self::Value, then: &Self::Value, otherwise: &Self::Value) -> Result<Self::Value>;
}

/// Plain floats, batched: each value is a column of `n` samples.
pub struct FloatBatch {
    pub n: usize,
    /// Per parameter id, its value in each sample; a parameter not listed takes its midpoint.
    pub parameters: HashMap<u64, Vec<f64>>,
}

impl FloatBatch {
    /// `n` samples, every parameter at its midpoint.
    pub fn new(n: usize) -> FloatBatch {
        FloatBatch { n, parameters: HashMap::new() }
    }

    fn map2(a: &[f64], b: &[f64], f: impl Fn(f64, f64) -> f64) -> Vec<f64> {
        a.iter().zip(b).map(|(&x, &y)| f(x, y)).collect()
    }
}

impl Algebra for FloatBatch {
    type Value = Vec<f64>;
    fn constant(&self, c: f64) -> Vec<f64> {
        vec![c; self.n]
    }
    /// The samples' drawn values of the parameter, or its midpoint in every sample.
    fn uncertain(&self, range: Interval, id: u64) -> Vec<f64> {
        match self.parameters.get(&id) {
            Some(values) => values.clone(),
            None => vec![range.mid(); self.n],
        }
    }
    fn neg(&self, a: &Vec<f64>) -> Vec<f64> {
        a.iter().map(|x| -x).collect()
    }
    fn binary(&self, op: BinOp, a: &Vec<f64>, b: &Vec<f64>) -> Result<Vec<f64>> {
        Ok(match op {
            BinOp::Add => Self::map2(a, b, |x, y| x + y),
            BinOp::Sub => Self::map2(a, b, |x, y| x - y),
            BinOp::Mul => Self::map2(a, b, |x, y| x * y),
            BinOp::Div => Self::map2(a, b, |x, y| x / y),
            BinOp::Min => Self::map2(a, b, f64::min),
            BinOp::Max => Self::map2(a, b, f64::max),
        })
    }
    fn powi(&self, a: &Vec<f64>, n: i32) -> Result<Vec<f64>> {
        Ok(a.iter().map(|x| x.powi(n)).collect())
    }
    fn powf(&self, a: &Vec<f64>, r: f64) -> Result<Vec<f64>> {
        Ok(a.iter().map(|x| x.powf(r)).collect())
    }
    fn func(&self, f: Func, a: &Vec<f64>) -> Result<Vec<f64>> {
        Ok(a.iter().map(|&x| f.eval_f64(x)).collect())
    }
    /// Samples decide one by one, in `select`.
    fn decide(&self, _l: &Vec<f64>, _cmp: Cmp, _r: &Vec<f64>) -> Option<bool> {
        None
    }
    fn select(&self, l: &Vec<f64>, cmp: Cmp, r: &Vec<f64>, t: &Vec<f64>, o: &Vec<f64>) -> Result<Vec<f64>> {
        Ok((0..self.n).map(|i| if cmp.holds(l[i] - r[i]) { t[i] } else { o[i] }).collect())
    }
}

/// Interval arithmetic (outward rounded); domain violations are errors.
pub struct Intervals;

impl Algebra for Intervals {
    type Value = Interval;
    fn constant(&self, c: f64) -> Interval {
        Interval::point(c)
    }
    fn uncertain(&self, range: Interval, _id: u64) -> Interval {
        range
    }
    fn neg(&self, a: &Interval) -> Interval {
        -*a
    }
    fn binary(&self, op: BinOp, a: &Interval, b: &Interval) -> Result<Interval> {
        Ok(match op {
            BinOp::Add => *a + *b,
            BinOp::Sub => *a - *b,
            BinOp::Mul => *a * *b,
            BinOp::Div => *a * b.recip()?,
            BinOp::Min => a.min(b),
            BinOp::Max => a.max(b),
        })
    }
    fn powi(&self, a: &Interval, n: i32) -> Result<Interval> {
        a.powi(n)
    }
    fn powf(&self, a: &Interval, r: f64) -> Result<Interval> {
        a.powf(r)
    }
    fn func(&self, f: Func, a: &Interval) -> Result<Interval> {
        f.eval_interval(*a)
    }
    fn nonneg(&self, a: Interval) -> Interval {
        a.nonnegative_part()
    }
    fn func_nonneg(&self, f: Func, a: &Interval) -> Result<Interval> {
        f.eval_interval(a.nonnegative_part())
    }
    fn powf_nonneg(&self, a: &Interval, r: f64) -> Result<Interval> {
        a.nonnegative_part().powf(r)
    }
    fn decide(&self, l: &Interval, cmp: Cmp, r: &Interval) -> Option<bool> {
        cmp.decide(*l - *r)
    }
    fn select(&self, l: &Interval, cmp: Cmp, r: &Interval, t: &Interval, o: &Interval) -> Result<Interval> {
        Ok(match cmp.decide(*l - *r) {
            Some(true) => *t,
            Some(false) => *o,
            None => t.hull(o),
        })
    }
}

/// Taylor-model arithmetic at the context's order and cutoff.
pub struct TaylorModels<'a> {
    pub ctx: &'a Ctx,
}

impl TaylorModels<'_> {
    /// An enclosure of a value that is `a` or `b` and lies in `range`: `a` or `b` plus everything
    /// the other may differ from it by, or the plain interval `range` when that is narrower
    /// (e.g. `clip` at a bound the set straddles: the model of v is wider than [lo, hi]).
    fn hull(&self, a: &TaylorModel, b: &TaylorModel, range: Interval) -> TaylorModel {
        let space = &self.ctx.space;
        let widen = |base: &TaylorModel, other: &TaylorModel| {
            let diff = other.sub(base).bound(space);
            let mut t = base.clone();
            t.rem = base.rem.hull(&(base.rem + diff));
            t
        };
        let (from_a, from_b) = (widen(a, b), widen(b, a));
        let (wa, wb) = (from_a.bound(space).width(), from_b.bound(space).width());
        let best = if wb < wa { from_b } else { from_a };
        if range.width() < best.bound(space).width() {
            TaylorModel::from_interval(range)
        } else {
            best
        }
    }
}

impl Algebra for TaylorModels<'_> {
    type Value = TaylorModel;
    fn constant(&self, c: f64) -> TaylorModel {
        TaylorModel::constant(c)
    }
    fn uncertain(&self, range: Interval, _id: u64) -> TaylorModel {
        TaylorModel::from_interval(range)
    }
    fn neg(&self, a: &TaylorModel) -> TaylorModel {
        a.neg()
    }
    fn binary(&self, op: BinOp, a: &TaylorModel, b: &TaylorModel) -> Result<TaylorModel> {
        let space = &self.ctx.space;
        Ok(match op {
            BinOp::Add => a.add(b),
            BinOp::Sub => a.sub(b),
            BinOp::Mul => a.mul(b, self.ctx),
            BinOp::Div => div_tm(a, b, self.ctx)?,
            BinOp::Min | BinOp::Max => {
                let d = a.sub(b).bound(space);
                let a_smaller = if d.hi() <= 0.0 {
                    Some(true)
                } else if d.lo() >= 0.0 {
                    Some(false)
                } else {
                    None
                };
                match (a_smaller, op == BinOp::Min) {
                    (Some(s), true) => {
                        if s {
                            a.clone()
                        } else {
                            b.clone()
                        }
                    }
                    (Some(s), false) => {
                        if s {
                            b.clone()
                        } else {
                            a.clone()
                        }
                    }
                    (None, min) => {
                        let (ra, rb) = (a.bound(space), b.bound(space));
                        let range = if min { ra.min(&rb) } else { ra.max(&rb) };
                        self.hull(a, b, range)
                    }
                }
            }
        })
    }
    fn powi(&self, a: &TaylorModel, n: i32) -> Result<TaylorModel> {
        if n >= 0 {
            Ok(a.powi(n as u32, self.ctx))
        } else {
            Func::Recip.eval_tm(&a.powi((-n) as u32, self.ctx), self.ctx)
        }
    }
    fn powf(&self, a: &TaylorModel, r: f64) -> Result<TaylorModel> {
        powf_tm(a, r, self.ctx)
    }
    fn func(&self, f: Func, a: &TaylorModel) -> Result<TaylorModel> {
        f.eval_tm(a, self.ctx)
    }
    /// Expanded as usual where the model's bound is nonnegative and the expansion exists (sqrt
    /// has none around 0); else the interval image of the bound's nonnegative part, as a
    /// constant model (sound: every value of `a` is in that part).
    fn func_nonneg(&self, f: Func, a: &TaylorModel) -> Result<TaylorModel> {
        let range = a.bound(&self.ctx.space);
        match self.func(f, a) {
            Ok(m) if range.lo() >= 0.0 => Ok(m),
            _ => Ok(TaylorModel::from_interval(f.eval_interval(range.nonnegative_part())?)),
        }
    }
    fn powf_nonneg(&self, a: &TaylorModel, r: f64) -> Result<TaylorModel> {
        let range = a.bound(&self.ctx.space);
        match self.powf(a, r) {
            Ok(m) if range.lo() >= 0.0 => Ok(m),
            _ => Ok(TaylorModel::from_interval(range.nonnegative_part().powf(r)?)),
        }
    }
    fn decide(&self, l: &TaylorModel, cmp: Cmp, r: &TaylorModel) -> Option<bool> {
        cmp.decide(l.sub(r).bound(&self.ctx.space))
    }
    fn select(&self, l: &TaylorModel, cmp: Cmp, r: &TaylorModel, t: &TaylorModel, o: &TaylorModel) -> Result<TaylorModel> {
        Ok(match cmp.decide(l.sub(r).bound(&self.ctx.space)) {
            Some(true) => t.clone(),
            Some(false) => o.clone(),
            None => self.hull(t, o, t.bound(&self.ctx.space).hull(&o.bound(&self.ctx.space))),
        })
    }
}

/// Taylor-model arithmetic that follows a plan through undecided conditions: the k-th
/// undecided question met takes branch `plan[k]` (and evaluates only that branch), questions
/// beyond the plan take the hull. Evaluating every plan a condition tree allows, each branch
/// assumed on the whole set, covers every point: a point's own path through the conditions is
/// one of the plans. `beyond` reports whether a question past the plan was undecided.
/// A question asked again (two `where`s on one guard, say p' <= -1.2 for both p and v) takes the
/// answer it got before: a point answers one question once, so the plans that mix answers cover
/// no point and are not made. Questions are told apart by what they ask ([`Question`]: the
/// compiled slots of their operands), never by their models: two different quantities can
/// have equal models (sin(1000 x) and sin(1000 y) on a wide set are both [-1, 1]).
pub struct Forking<'a> {
    pub tm: TaylorModels<'a>,
    pub plan: &'a [bool],
    seen: std::cell::Cell<usize>,
    beyond: std::cell::Cell<bool>,
    taken: std::cell::RefCell<HashMap<Question, bool>>,
}

impl<'a> Forking<'a> {
    pub fn new(ctx: &'a crate::tm::Ctx, plan: &'a [bool]) -> Self {
        Forking {
            tm: TaylorModels { ctx },
            plan,
            seen: std::cell::Cell::new(0),
            beyond: std::cell::Cell::new(false),
            taken: std::cell::RefCell::new(HashMap::new()),
        }
    }
    /// Whether an undecided condition was met after the plan ran out.
    pub fn beyond(&self) -> bool {
        self.beyond.get()
    }
}

impl Algebra for Forking<'_> {
    type Value = TaylorModel;
    fn constant(&self, c: f64) -> TaylorModel {
        self.tm.constant(c)
    }
    fn uncertain(&self, range: Interval, id: u64) -> TaylorModel {
        self.tm.uncertain(range, id)
    }
    fn neg(&self, a: &TaylorModel) -> TaylorModel {
        self.tm.neg(a)
    }
    fn binary(&self, op: BinOp, a: &TaylorModel, b: &TaylorModel) -> Result<TaylorModel> {
        self.tm.binary(op, a, b)
    }
    fn powi(&self, a: &TaylorModel, n: i32) -> Result<TaylorModel> {
        self.tm.powi(a, n)
    }
    fn powf(&self, a: &TaylorModel, r: f64) -> Result<TaylorModel> {
        self.tm.powf(a, r)
    }
    fn func(&self, f: Func, a: &TaylorModel) -> Result<TaylorModel> {
        self.tm.func(f, a)
    }
    fn func_nonneg(&self, f: Func, a: &TaylorModel) -> Result<TaylorModel> {
        self.tm.func_nonneg(f, a)
    }
    fn powf_nonneg(&self, a: &TaylorModel, r: f64) -> Result<TaylorModel> {
        self.tm.powf_nonneg(a, r)
    }
    /// Without a question there is nothing to follow a plan by: decided or undecided.
    fn decide(&self, l: &TaylorModel, cmp: Cmp, r: &TaylorModel) -> Option<bool> {
        self.tm.decide(l, cmp, r)
    }
    fn decide_at(&self, question: Question, l: &TaylorModel, r: &TaylorModel) -> Option<bool> {
        let decided = self.tm.decide(l, question.cmp, r);
        if decided.is_some() {
            return decided;
        }
        if let Some(&b) = self.taken.borrow().get(&question) {
            return Some(b);
        }
        let k = self.seen.get();
        self.seen.set(k + 1);
        let forced = self.plan.get(k).copied();
        match forced {
            Some(b) => {
                self.taken.borrow_mut().insert(question, b);
            }
            None => self.beyond.set(true),
        }
        forced
    }
    fn select(&self, l: &TaylorModel, cmp: Cmp, r: &TaylorModel, t: &TaylorModel, o: &TaylorModel) -> Result<TaylorModel> {
        self.tm.select(l, cmp, r, t, o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::Space;

    fn vdp() -> (Expr, Expr) {
        let (x, y) = (Expr::var("x"), Expr::var("y"));
        let one = Expr::constant(1.0);
        let fy = Expr::binary(BinOp::Sub, &Expr::binary(BinOp::Mul, &Expr::binary(BinOp::Sub, &one, &x.powi(2)), &y), &x);
        (y, fy)
    }

    #[test]
    fn three_algebras_agree() {
        let (fx, fy) = vdp();
        let p = Program::compile(&[fx, fy], &["x".into(), "y".into()]).unwrap();
        let pts = [(0.3, -0.2), (1.0, 2.0), (-1.5, 0.7)];
        let xs: Vec<f64> = pts.iter().map(|p| p.0).collect();
        let ys: Vec<f64> = pts.iter().map(|p| p.1).collect();
        let floats = p.eval(&FloatBatch::new(3), &[xs, ys]).unwrap();
        let ctx = Ctx::new(Space::get(2, 4, 0).unwrap(), 4, 0.0);
        for (k, &(x, y)) in pts.iter().enumerate() {
            let iv = p.eval(&Intervals, &[Interval::point(x), Interval::point(y)]).unwrap();
            assert!(iv[1].contains(floats[1][k]));
            let tx = TaylorModel::affine(&ctx, x, 0, 0.0);
            let ty = TaylorModel::affine(&ctx, y, 1, 0.0);
            let tm = p.eval(&TaylorModels { ctx: &ctx }, &[tx, ty]).unwrap();
            assert!(tm[1].bound(&ctx.space).contains(floats[1][k]));
        }
    }

    #[test]
    fn substitution_keeps_sharing_and_parameters() {
        // e = s * s + k with s = sin(x + y), k an uncertain parameter; x := 2 t, y untouched.
        let (x, y, t) = (Expr::var("x"), Expr::var("y"), Expr::var("t"));
        let k = Expr::uncertain(Interval::new(1.0, 2.0).unwrap());
        let s = Expr::func(Func::Sin, &Expr::binary(BinOp::Add, &x, &y));
        let e = Expr::binary(BinOp::Add, &Expr::binary(BinOp::Mul, &s, &s), &k);
        let two_t = Expr::binary(BinOp::Mul, &Expr::constant(2.0), &t);
        let out = e.substitute(&HashMap::from([("x".to_string(), two_t)]));
        assert_eq!(out.variables(), vec!["t".to_string(), "y".to_string()]);
        assert_eq!(out.parameters(), e.parameters());
        // Shared: sin(2 t + y) is one node, so the program computes it once.
        let p = Program::compile(&[out], &["t".into(), "y".into()]).unwrap();
        let direct = Program::compile(&[e], &["x".into(), "y".into()]).unwrap();
        assert_eq!(p.ops.len(), direct.ops.len() + 2);
        let (tv, yv) = (vec![0.3, -1.1], vec![0.5, 2.0]);
        let xv: Vec<f64> = tv.iter().map(|t| 2.0 * t).collect();
        let batch = FloatBatch::new(2);
        assert_eq!(p.eval(&batch, &[tv, yv.clone()]).unwrap(), direct.eval(&batch, &[xv, yv]).unwrap());
        // A part that reads no replaced variable is the same node, not a copy.
        let z = Expr::func(Func::Exp, &y);
        let f = Expr::binary(BinOp::Add, &z, &x).substitute(&HashMap::from([("x".to_string(), t.clone())]));
        let Node::Binary(_, kept, _) = &*f.0 else { panic!("a sum stays a sum") };
        assert!(Arc::ptr_eq(&kept.0, &z.0));
    }

    #[test]
    fn shared_subexpressions_compile_once() {
        let x = Expr::var("x");
        let s = Expr::func(Func::Sin, &x);
        let e = Expr::binary(BinOp::Mul, &s, &s);
        let p = Program::compile(&[e], &["x".into()]).unwrap();
        assert_eq!(p.ops.len(), 3);
    }

    #[test]
    fn forking_takes_one_branch_per_repeated_condition() {
        // A wall: p' = where(x <= 0, 0, x), v' = where(x <= 0, 1, x) on x in [-1, 1]. Both
        // `where`s ask one question; each plan answers it once for both, and one fork (two plans)
        // covers every point: x <= 0 gives (0, 1), x > 0 gives (x, x).
        let x = Expr::var("x");
        let zero = Expr::constant(0.0);
        let p = Expr::select(&x, Cmp::Le, &zero, &zero, &x);
        let v = Expr::select(&x, Cmp::Le, &zero, &Expr::constant(1.0), &x);
        let prog = Program::compile(&[p, v], &["x".into()]).unwrap();
        let ctx = Ctx::new(Space::get(1, 3, 0).unwrap(), 3, 0.0);
        let input = [TaylorModel::var(&ctx, 0)];
        let unplanned = Forking::new(&ctx, &[]);
        prog.eval(&unplanned, &input).unwrap();
        assert!(unplanned.beyond());
        for (choice, expect) in [(true, [(0.0, 0.0), (1.0, 1.0)]), (false, [(-1.0, 1.0), (-1.0, 1.0)])] {
            let plan = [choice];
            let alg = Forking::new(&ctx, &plan);
            let out = prog.eval(&alg, &input).unwrap();
            assert!(!alg.beyond(), "the second where must reuse the first one's branch");
            for (m, (lo, hi)) in out.iter().zip(expect) {
                let b = m.bound(&ctx.space);
                assert!(b.lo() <= lo && b.hi() >= hi && b.width() <= hi - lo + 1e-12, "{b} against [{lo}, {hi}]");
            }
        }
    }

    /// Every plan `Forking` needs for `prog` on `input`, each run to its end.
    fn plans(prog: &Program, input: &[TaylorModel], ctx: &Ctx) -> Vec<Vec<bool>> {
        let (mut done, mut todo) = (Vec::new(), vec![Vec::new()]);
        while let Some(plan) = todo.pop() {
            let alg = Forking::new(ctx, &plan);
            prog.eval(&alg, input).unwrap();
            if alg.beyond() {
                todo.extend([false, true].map(|b| [plan.clone(), vec![b]].concat()));
            } else {
                done.push(plan);
            }
        }
        done
    }

    #[test]
    fn forking_tells_different_quantities_with_equal_models_apart() {
        // sin(1000 x) and sin(1000 y) on a wide box are both [-1, 1] (equal models), as are two
        // parameters of one range; each pair is two questions, so four plans, not two.
        let ctx = Ctx::new(Space::get(2, 3, 0).unwrap(), 3, 0.0);
        let (x, y) = (Expr::var("x"), Expr::var("y"));
        let k = Expr::constant(1000.0);
        let zero = Expr::constant(0.0);
        let (one, none) = (Expr::constant(1.0), Expr::constant(0.0));
        let sx = Expr::func(Func::Sin, &Expr::binary(BinOp::Mul, &k, &x));
        let sy = Expr::func(Func::Sin, &Expr::binary(BinOp::Mul, &k, &y));
        let range = Interval::new(-1.0, 1.0).unwrap();
        let (a, b) = (Expr::uncertain(range), Expr::uncertain(range));
        let input = [TaylorModel::affine(&ctx, 0.5, 0, 0.5), TaylorModel::affine(&ctx, 0.5, 1, 0.5)];
        for (p, q) in [(sx, sy), (a.clone(), b)] {
            let e =
                Expr::binary(BinOp::Add, &Expr::select(&p, Cmp::Le, &zero, &one, &none), &Expr::select(&q, Cmp::Le, &zero, &none, &one));
            let prog = Program::compile(&[e], &["x".into(), "y".into()]).unwrap();
            let mut found = plans(&prog, &input, &ctx);
            found.sort();
            assert_eq!(found, vec![vec![false, false], vec![false, true], vec![true, false], vec![true, true]]);
        }
        // One parameter asked twice (by two separately built conditions) is one question.
        let twice = Expr::binary(
            BinOp::Add,
            &Expr::select(&a, Cmp::Le, &Expr::constant(0.0), &one, &none),
            &Expr::select(&a, Cmp::Le, &Expr::constant(0.0), &none, &one),
        );
        let prog = Program::compile(&[twice], &["x".into(), "y".into()]).unwrap();
        assert_eq!(plans(&prog, &input, &ctx).len(), 2);
    }

    #[test]
    fn parameters_keep_their_identity() {
        let range = Interval::new(-1.0, 1.0).unwrap();
        let (a, b) = (Expr::uncertain(range), Expr::uncertain(range));
        let sum = Expr::binary(BinOp::Add, &a, &b);
        let ids: Vec<u64> = sum.parameters().iter().map(|p| p.0).collect();
        assert_eq!(ids.len(), 2);
        assert_ne!(ids[0], ids[1]);
        // Equal ranges, different quantities: not merged, and the hash tells a + a from a + b.
        let prog = Program::compile(std::slice::from_ref(&sum), &[]).unwrap();
        assert_eq!(prog.ops.len(), 3);
        assert_ne!(sum.structural_hash(), Expr::binary(BinOp::Add, &a, &a).structural_hash());
        // A simulation draws each by id.
        let mut batch = FloatBatch::new(2);
        batch.parameters.insert(ids[0], vec![0.25, -1.0]);
        batch.parameters.insert(ids[1], vec![0.5, 1.0]);
        assert_eq!(prog.eval(&batch, &[]).unwrap()[0], vec![0.75, 0.0]);
    }

    #[test]
    fn decided_where_ignores_an_undefined_branch() {
        // where(x >= 0, x, log(x)) on x in [1, 2]: log is fine; on [0.5, 1] too; the else
        // branch log(x - 2) is undefined there but never taken.
        let x = Expr::var("x");
        let bad = Expr::func(Func::Log, &Expr::binary(BinOp::Sub, &x, &Expr::constant(2.0)));
        let e = Expr::select(&x, Cmp::Ge, &Expr::constant(0.0), &x, &bad);
        let p = Program::compile(&[e], &["x".into()]).unwrap();
        let out = p.eval(&Intervals, &[Interval::new(0.5, 1.0).unwrap()]).unwrap();
        assert!(out[0].contains(0.5) && out[0].contains(1.0));
        // Undecided: both branches are needed and the error surfaces.
        assert!(p.eval(&Intervals, &[Interval::new(-0.5, 1.0).unwrap()]).is_err());
    }

    #[test]
    fn long_shared_expressions_print_bounded_and_hash_fast() {
        let mut e = Expr::var("x");
        for _ in 0..200 {
            e = Expr::binary(BinOp::Add, &e, &e); // 2^200 leaves when printed in full
        }
        assert!(e.describe(100).len() < 120);
        assert_eq!(e.structural_hash(), e.structural_hash());
        assert_ne!(e.structural_hash(), Expr::var("x").structural_hash());
    }

    #[test]
    fn a_name_given_twice_is_read_at_its_first_place() {
        let p = Program::compile(&[Expr::var("x")], &["x".into(), "y".into(), "x".into()]).unwrap();
        assert!(matches!(p.ops[p.outputs[0]], Op::Input(0)));
    }

    #[test]
    fn unknown_variable_is_named() {
        let e = Expr::binary(BinOp::Add, &Expr::var("x"), &Expr::var("z"));
        let err = Program::compile(&[e], &["x".into()]).unwrap_err();
        assert!(err.to_string().contains("'z'"));
    }

    #[test]
    fn where_is_sound_on_sets() {
        // clip(x, -1, 1) on a model of x in [-2, 0]: values in [-1, 0].
        let x = Expr::var("x");
        let e = x.clip(&Expr::constant(-1.0), &Expr::constant(1.0));
        let p = Program::compile(&[e], &["x".into()]).unwrap();
        let ctx = Ctx::new(Space::get(1, 3, 0).unwrap(), 3, 0.0);
        let tm = p.eval(&TaylorModels { ctx: &ctx }, &[TaylorModel::affine(&ctx, -1.0, 0, 1.0)]).unwrap();
        let b = tm[0].bound(&ctx.space);
        assert!(b.contains(-1.0) && b.contains(0.0));
        let iv = p.eval(&Intervals, &[Interval::new(-2.0, 0.0).unwrap()]).unwrap();
        assert!(iv[0].lo() >= -1.0 && iv[0].hi() <= 0.0);
    }
}
