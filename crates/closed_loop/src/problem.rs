//! The problem: a closed loop of stages (networks or expressions) and a plant, and the property
//! its runs must satisfy. Everything is checked once ([`ClosedLoop::validate`]) before any work.
use crate::error::{ReachError, Result};
use nn2hybrid::Network;
use std::sync::Arc;
use taylor::flowpipe::{Ode, Settings as FlowSettings};
use taylor::hybrid::Automaton;
use taylor::{Cmp, Program};

#[derive(Clone, Debug)]
pub enum Component {
    Network(Arc<Network>),
    Expr(Arc<Program>),
}

/// A stage reads signals at `inputs` (indices into the environment: the state first, then
/// the outputs of earlier stages in order) and appends its outputs to the environment.
#[derive(Clone, Debug)]
pub struct Stage {
    pub component: Component,
    pub inputs: Vec<usize>,
}

impl Stage {
    fn n_out(&self) -> usize {
        match &self.component {
            Component::Network(n) => n.n_out(),
            Component::Expr(p) => p.outputs.len(),
        }
    }
}

/// `margin cmp 0` must hold; `margin` is a program over the state.
#[derive(Clone, Debug)]
pub struct Condition {
    pub margin: Arc<Program>,
    pub cmp: Cmp,
    pub label: String,
    /// A safety condition's window in steps, `[lo, hi]` (fractional for times between steps):
    /// it is checked at the steps in it and, for a continuous plant, on every flowpipe segment
    /// whose time span meets it. None: always.
    pub window: Option<(f64, f64)>,
}

impl Condition {
    /// Whether the condition applies somewhere in steps `[from, to]` (a step, or the span of a
    /// flowpipe segment). Decided with a margin of 1e-9 steps towards applying: checking a
    /// condition where it need not hold is only stricter, missing one where it must is unsound.
    pub fn applies(&self, from: f64, to: f64) -> bool {
        self.window.is_none_or(|(lo, hi)| to >= lo - 1e-9 && from <= hi + 1e-9)
    }

    /// Whether the condition applies on the flowpipe segment [t0, t1] of period `step`: where
    /// the segment's span meets the window, except only at the period's end or start, whose
    /// states are checked at the steps themselves (else a window from step 5 would also hold
    /// the whole last segment before it to the condition).
    pub fn applies_on(&self, step: usize, t0: f64, t1: f64, period: f64) -> bool {
        let Some((lo, hi)) = self.window else { return true };
        let k = step as f64;
        // The period's last segment ends at or an ulp past its end (taylor::flowpipe).
        let only_end = t1 >= period && lo == k + 1.0;
        let only_start = t0 == 0.0 && hi == k;
        self.applies(k + t0 / period, k + t1 / period) && !only_end && !only_start
    }
}

/// How the state moves from one control step to the next.
#[derive(Clone, Debug)]
pub enum Plant {
    /// Inputs: the whole environment; outputs: the next state, in state order.
    Discrete(Arc<Program>),
    /// x' = f(x, u) over one control period with u held: the ODE's variables are the states
    /// followed by the inputs (whose right-hand sides are 0); `inputs` are their environment
    /// indices. Safety is checked on every flowpipe segment of the period.
    Continuous { ode: Arc<Ode>, inputs: Vec<usize>, period: f64, flow: FlowSettings },
    /// Each control period runs the hybrid automaton from mode `start` until it exits (the jumps
    /// that return control to the controller), its variables the states followed by the held
    /// inputs; every exit state is a successor. Safety is checked on every flowpipe segment.
    Hybrid { automaton: Arc<Automaton>, start: usize, inputs: Vec<usize>, flow: FlowSettings, max_time: f64, max_jumps: usize },
}

impl Plant {
    /// A continuous plant integrated with fixed steps of `step` over each period, each step's
    /// remainder first estimated at `remainder` per variable (the cell's Taylor order is used).
    pub fn continuous(ode: Ode, inputs: Vec<usize>, period: f64, step: f64, remainder: f64) -> Plant {
        let flow = FlowSettings { t_end: period, ..flow_settings(ode.dim(), step, remainder) };
        Plant::Continuous { ode: Arc::new(ode), inputs, period, flow }
    }

    /// A hybrid plant integrated like [`Plant::continuous`]; a period fails if a run flows for
    /// longer than `max_time` or takes more than `max_jumps` jumps.
    pub fn hybrid(
        automaton: Automaton,
        start: usize,
        inputs: Vec<usize>,
        max_time: f64,
        step: f64,
        remainder: f64,
        max_jumps: usize,
    ) -> Plant {
        let flow = flow_settings(automaton.names.len(), step, remainder);
        Plant::Hybrid { automaton: Arc::new(automaton), start, inputs, flow, max_time, max_jumps }
    }
}

fn flow_settings(dim: usize, step: f64, remainder: f64) -> FlowSettings {
    FlowSettings {
        step: taylor::StepSize::Fixed(step),
        order: taylor::OrderPolicy::Fixed(1),
        t_end: 0.0,
        cutoff: 1e-12,
        remainder_estimate: vec![remainder; dim],
        precondition: taylor::Precondition::Identity,
        refinements: 30,
        symbolic_queue: 100,
    }
}

#[derive(Clone, Debug)]
pub struct ClosedLoop {
    pub state_names: Vec<String>,
    pub stages: Vec<Stage>,
    pub plant: Plant,
    /// Must hold at step 0 and after every step.
    pub safe: Vec<Condition>,
    /// Must hold after the last step, or at some step if `goal_within`.
    pub goal: Option<Condition>,
    pub goal_within: bool,
    pub steps: usize,
}

impl ClosedLoop {
    /// Checks indices and widths once, before any work.
    pub fn validate(&self) -> Result<()> {
        let n = self.state_names.len();
        if n == 0 {
            return Err(ReachError::input("the closed loop has no state variables"));
        }
        let mut env = n;
        for (k, stage) in self.stages.iter().enumerate() {
            if let Some(&bad) = stage.inputs.iter().find(|&&i| i >= env) {
                return Err(ReachError::input(format!("stage {}: input index {bad} is not computed before it", k + 1)));
            }
            let want = match &stage.component {
                Component::Network(net) => net.n_in(),
                Component::Expr(p) => p.inputs.len(),
            };
            if want != stage.inputs.len() {
                return Err(ReachError::input(format!(
                    "stage {}: the component takes {want} inputs but {} are wired to it",
                    k + 1,
                    stage.inputs.len()
                )));
            }
            env += stage.n_out();
        }
        match &self.plant {
            Plant::Discrete(p) if p.inputs.len() != env || p.outputs.len() != n => {
                return Err(ReachError::input(format!(
                    "the plant must read the {env} signals of the loop and define all {n} states, got {} inputs and {} outputs",
                    p.inputs.len(),
                    p.outputs.len()
                )));
            }
            Plant::Continuous { ode, inputs, period, .. } => {
                if ode.dim() != n + inputs.len() || inputs.iter().any(|&i| i >= env) {
                    return Err(ReachError::input(format!(
                        "the continuous plant's ODE must have the {n} states then the {} inputs as variables",
                        inputs.len()
                    )));
                }
                if !(*period > 0.0) {
                    return Err(ReachError::input(format!("the control period must be positive, got {period}")));
                }
            }
            Plant::Hybrid { automaton, start, inputs, max_time, .. } => {
                automaton.validate()?;
                if automaton.names.len() != n + inputs.len() || inputs.iter().any(|&i| i >= env) {
                    return Err(ReachError::input(format!(
                        "the hybrid plant's variables must be the {n} states then the {} inputs",
                        inputs.len()
                    )));
                }
                if *start >= automaton.modes.len() {
                    return Err(ReachError::input("the hybrid plant's start mode does not exist"));
                }
                if !(*max_time > 0.0) {
                    return Err(ReachError::input(format!("the hybrid plant's time bound per period must be positive, got {max_time}")));
                }
            }
            _ => {}
        }
        for c in self.safe.iter().chain(self.goal.iter()) {
            if c.margin.inputs.len() != n || c.margin.outputs.len() != 1 {
                return Err(ReachError::input(format!("property '{}' must be one expression over the state", c.label)));
            }
        }
        Ok(())
    }
}
