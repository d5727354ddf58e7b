//! The engine's own tests: loops whose runs are simulated in plain floats.
use crate::outcome::{CellOutcome, Verdict};
use crate::problem::{ClosedLoop, Component, Condition, Plant, Stage};
use crate::settings::{CellSettings, Method};
use crate::solve::verify_cell;
use nn2hybrid::network::{Activation, LayerArrays};
use nn2hybrid::propagate::Settings as NnSettings;
use nn2hybrid::Network;
use std::sync::Arc;
use taylor::expr::Intervals;
use taylor::parser::parse_expr;
use taylor::Expr;
use taylor::{Cmp, Interval, Program};

/// x+ = x + 0.1 v, v+ = v + 0.1 u, u = tanh(-g x - g v) over `steps` steps, safe while x <= 2.
fn feedback_loop(gain: f64, steps: usize) -> (ClosedLoop, Network) {
    let net = Network::new(
        vec![LayerArrays { n_out: 1, n_in: 2, weight: vec![-gain, -gain], bias: vec![0.0], activations: vec![Activation::Tanh] }],
        None,
        None,
    )
    .unwrap();
    let names: Vec<String> = ["x", "v", "u"].iter().map(|s| s.to_string()).collect();
    let plant = Program::compile(&[parse_expr("x + 0.1*v").unwrap(), parse_expr("v + 0.1*u").unwrap()], &names).unwrap();
    let safe = Program::compile(&[parse_expr("x - 2").unwrap()], &names[..2]).unwrap();
    let lp = ClosedLoop {
        state_names: names[..2].to_vec(),
        stages: vec![Stage { component: Component::Network(Arc::new(net.clone())), inputs: vec![0, 1] }],
        plant: Plant::Discrete(Arc::new(plant)),
        safe: vec![Condition { margin: Arc::new(safe), cmp: Cmp::Le, label: "x <= 2".into(), window: None }],
        goal: None,
        goal_within: false,
        steps,
    };
    lp.validate().unwrap();
    (lp, net)
}

fn loop_settings(state_symbols: bool) -> CellSettings {
    CellSettings {
        order: 4,
        cutoff: 1e-12,
        method: Method::Taylor,
        nn: NnSettings { order: 4, ..NnSettings::default() },
        timeout: None,
        blow_up_width: 1e6,
        max_splits: 0,
        max_redone: None,
        rebox: false,
        state_symbols,
        progress: None,
    }
}

/// Float runs from a grid of the cell stay in every step's box.
fn assert_runs_inside(out: &CellOutcome, net: &Network, cell: &[Interval], steps: usize) {
    for a in 0..=10 {
        for b in 0..=10 {
            let at = |iv: Interval, k: usize| (iv.lo() + 0.1 * k as f64 * iv.width()).min(iv.hi());
            let (mut x, mut v) = (at(cell[0], a), at(cell[1], b));
            for step in 0..=steps {
                let bx = &out.boxes[step];
                assert!(bx[0].contains(x) && bx[1].contains(v), "step {step}: ({x}, {v}) outside {bx:?}");
                let u = net.eval(&[x, v]).unwrap()[0];
                (x, v) = (x + 0.1 * v, v + 0.1 * u);
            }
        }
    }
}

/// The float run of a plant whose update reads only the states (evaluated at points, each step's
/// midpoint the next state) lies in every step's box.
fn assert_float_run_inside(boxes: &[Vec<Interval>], plant: &Program, mut state: Vec<f64>) {
    for (step, bx) in boxes.iter().enumerate() {
        assert!(bx.iter().zip(&state).all(|(iv, &x)| iv.contains(x)), "step {step}: {state:?} outside {bx:?}");
        let point: Vec<Interval> = state.iter().map(|&x| Interval::point(x)).collect();
        state = plant.eval(&Intervals, &point).unwrap().iter().map(|iv| iv.mid()).collect();
    }
}

#[test]
fn discrete_loop_encloses_simulations() {
    let (lp, net) = feedback_loop(1.0, 40);
    let cell = [Interval::new(0.5, 0.7).unwrap(), Interval::new(-0.1, 0.1).unwrap()];
    for state_symbols in [false, true] {
        let out = verify_cell(&lp, &cell, &loop_settings(state_symbols));
        assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
        assert_runs_inside(&out, &net, &cell, 40);
    }
}

#[test]
fn state_symbols_stop_the_wrapping_of_a_stiff_feedback() {
    // A stiff controller feeds v's error back into v every step: as intervals the error adds
    // its magnitude each time; as symbols the correction cancels it.
    let steps = 60;
    let (lp, net) = feedback_loop(4.0, steps);
    let cell = [Interval::new(0.5, 0.52).unwrap(), Interval::new(-0.01, 0.01).unwrap()];
    let width = |state_symbols: bool| {
        let out = verify_cell(&lp, &cell, &loop_settings(state_symbols));
        assert_runs_inside(&out, &net, &cell, out.steps_done);
        out.boxes.last().map(|b| b[1].width()).unwrap_or(f64::INFINITY)
    };
    let (intervals, symbols) = (width(false), width(true));
    assert!(symbols < 0.5 * intervals, "symbols {symbols} against intervals {intervals}");
}

/// A one-state loop without stages, x+ = `update`, goal x >= 1 at some step up to `steps`.
fn reach_loop(update: &str, steps: usize) -> ClosedLoop {
    let names = vec!["x".to_string()];
    ClosedLoop {
        state_names: names.clone(),
        stages: vec![],
        plant: Plant::Discrete(Arc::new(Program::compile(&[parse_expr(update).unwrap()], &names).unwrap())),
        safe: vec![],
        goal: Some(Condition {
            margin: Arc::new(Program::compile(&[parse_expr("x - 1").unwrap()], &names).unwrap()),
            cmp: Cmp::Ge,
            label: "x >= 1".into(),
            window: None,
        }),
        goal_within: true,
        steps,
    }
}

/// Every one of 1,001 float runs from `x0` meets x >= 1 at some step up to `steps`: what a
/// "verified" from the cover claims.
fn all_runs_arrive(update: impl Fn(f64) -> f64, x0: (f64, f64), steps: usize) -> bool {
    (0..=1000).all(|i| {
        let mut x = x0.0 + (x0.1 - x0.0) * i as f64 / 1000.0;
        (0..=steps).any(|_| {
            let arrived = x >= 1.0;
            x = update(x);
            arrived
        })
    })
}

fn reach_verdict(update: &str, x0: (f64, f64), steps: usize) -> CellOutcome {
    let settings = CellSettings {
        order: 3,
        cutoff: 1e-12,
        method: Method::Taylor,
        nn: NnSettings::default(),
        timeout: None,
        blow_up_width: 1e6,
        max_splits: 0,
        max_redone: None,
        rebox: false,
        state_symbols: true,
        progress: None,
    };
    verify_cell(&reach_loop(update, steps), &[Interval::new(x0.0, x0.1).unwrap()], &settings)
}

#[test]
fn parts_arriving_at_different_steps_verify_without_splits() {
    // x+ = 2.2 - x: x0 >= 1 is in the goal at step 0, x0 < 1 at step 1; neither step holds
    // the whole set, and the set never arrives at once (without splits, this cell was lost).
    let out = reach_verdict("2.2 - x", (0.5, 1.5), 4);
    assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
    assert!(all_runs_arrive(|x| 2.2 - x, (0.5, 1.5), 4));
    // x+ = x: the part below 1 never arrives, so no cover may be claimed.
    let out = reach_verdict("x", (0.5, 1.5), 4);
    assert_eq!(out.verdict, Verdict::Unknown, "{:?}", out.reason);
    // x+ = 0.9 x + 0.2, x_k = 2 - 0.9^k (2 - x0): the runs from 0.5 arrive at step 4, those
    // from 0.95 at step 1, the others in between.
    let out = reach_verdict("0.9*x + 0.2", (0.5, 1.5), 10);
    assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
    assert!(all_runs_arrive(|x| 0.9 * x + 0.2, (0.5, 1.5), 10));
    let out = reach_verdict("0.9*x + 0.2", (0.5, 1.5), 3);
    assert_ne!(out.verdict, Verdict::Verified, "runs from 0.5 are at 0.907 after 3 steps");
    assert!(!all_runs_arrive(|x| 0.9 * x + 0.2, (0.5, 1.5), 3));
}

#[test]
fn a_set_that_left_the_goal_is_not_a_violation() {
    // x+ = 0: the runs from x0 >= 1 reached the goal at step 0, so failing at the horizon is
    // not a violation of the whole set; from [0.2, 0.5] it is.
    let out = reach_verdict("0*x", (0.5, 1.5), 2);
    assert_eq!(out.verdict, Verdict::Unknown, "{:?}", out.reason);
    let out = reach_verdict("0*x", (0.2, 0.5), 2);
    assert_eq!(out.verdict, Verdict::Violated, "{:?}", out.reason);
}

/// A sum that only adds to itself (a reward) is not an error-symbol state, but its updates
/// carry the symbols of the states it sums. Renewing the symbols each step must not leave it
/// with terms in the old symbols: read as the new ones they cancelled against the next
/// step's terms, and runs of this rotating loop at order 1 left the sum's box by 1.7e-3.
#[test]
fn a_sum_of_renewed_errors_encloses_simulations() {
    let names: Vec<String> = ["x", "y", "s"].iter().map(|s| s.to_string()).collect();
    let exprs = ["0.8*y + x*y", "-0.8*x + x*y", "s + x"].map(|e| parse_expr(e).unwrap());
    let plant = Program::compile(&exprs, &names).unwrap();
    let steps = 25;
    let lp = ClosedLoop {
        state_names: names,
        stages: vec![],
        plant: Plant::Discrete(Arc::new(plant.clone())),
        safe: vec![],
        goal: None,
        goal_within: false,
        steps,
    };
    let cell = [Interval::new(0.3, 0.4).unwrap(), Interval::new(0.1, 0.2).unwrap(), Interval::point(0.0)];
    let out = verify_cell(&lp, &cell, &CellSettings { order: 1, cutoff: 0.0, ..loop_settings(true) });
    assert_eq!(out.steps_done, steps);
    for a in 0..=60 {
        for b in 0..=60 {
            assert_float_run_inside(&out.boxes, &plant, vec![0.3 + 0.1 * a as f64 / 60.0, 0.1 + 0.1 * b as f64 / 60.0, 0.0]);
        }
    }
}

/// Runs that hit a wall x = 0 at different steps stop there (x = v = 0) and climb out the
/// same way: the pieces forked off at each hit replay the first one's steps ([`Tape`]) with
/// their own sums s (of x, which only these pieces have large: the other piece carries the
/// runs as if there were no wall). Float runs stay in every step's box, s included.
#[test]
fn pieces_that_hit_a_wall_at_different_steps_replay_one_climb_inside_the_simulations() {
    let names: Vec<String> = ["x", "v", "s"].iter().map(|s| s.to_string()).collect();
    let (x, s) = (Expr::var("x"), Expr::var("s"));
    let v1 = parse_expr("v + 0.03 - 0.02*x").unwrap();
    let y = Expr::binary(taylor::BinOp::Add, &x, &v1);
    let zero = Expr::constant(0.0);
    let at_wall = |then: &Expr, otherwise: &Expr| Expr::select(&y, Cmp::Le, &zero, then, otherwise);
    let sum = Expr::binary(taylor::BinOp::Add, &s, &x);
    let plant = Program::compile(&[at_wall(&zero, &y), at_wall(&zero, &v1), sum], &names).unwrap();
    let steps = 30;
    let lp = ClosedLoop {
        state_names: names,
        stages: vec![],
        plant: Plant::Discrete(Arc::new(plant.clone())),
        safe: vec![],
        goal: None,
        goal_within: false,
        steps,
    };
    let cell = [Interval::new(0.5, 1.2).unwrap(), Interval::point(-0.3), Interval::point(0.0)];
    let out = verify_cell(&lp, &cell, &CellSettings { max_splits: 16, ..loop_settings(false) });
    assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
    assert!(out.replayed >= steps / 2, "{} steps replayed", out.replayed);
    // Forks go on from the step where they fork: nothing is computed again.
    assert!(out.branches > 0 && out.steps_redone == 0, "{} branches, {} steps redone", out.branches, out.steps_redone);
    for a in 0..=1000 {
        assert_float_run_inside(&out.boxes, &plant, vec![0.5 + 0.7 * a as f64 / 1000.0, -0.3, 0.0]);
    }
}

/// A cell whose parts stop at different steps: a fork at step 0 (x >= 0.5 or not), then the
/// part run first violates the step-20 window x <= -5 while the other waits at step 1. The
/// boxes are complete up to step 1 only; deepest_step says where the cell gave up. Before
/// step 20 the window does not apply, so nothing stops the parts earlier.
#[test]
fn deepest_step_is_where_a_part_gave_up() {
    let names = vec!["x".to_string()];
    let (x, half) = (Expr::var("x"), Expr::constant(0.5));
    let update = Expr::select(&x, Cmp::Ge, &half, &parse_expr("x + 0.1").unwrap(), &parse_expr("x - 0.1").unwrap());
    let plant = Program::compile(&[update], &names).unwrap();
    let margin = Arc::new(Program::compile(&[parse_expr("x + 5").unwrap()], &names).unwrap());
    let late = Condition { margin, cmp: Cmp::Le, label: "x <= -5 at step 20".into(), window: Some((20.0, 20.0)) };
    let lp = ClosedLoop {
        state_names: names,
        stages: vec![],
        plant: Plant::Discrete(Arc::new(plant)),
        safe: vec![late],
        goal: None,
        goal_within: false,
        steps: 20,
    };
    let out = verify_cell(&lp, &[Interval::new(0.0, 1.0).unwrap()], &CellSettings { max_splits: 1, ..loop_settings(false) });
    assert_eq!(out.verdict, Verdict::Unknown, "{:?}", out.reason);
    assert!(out.reason.as_deref().unwrap_or("").starts_with("step 20:"), "{:?}", out.reason);
    assert_eq!((out.steps_done, out.boxes.len(), out.deepest_step), (1, 2, 20));
}

/// The cell of the test above with its splits' restarts bounded: at half a run it gives up at
/// the first split, unknown, naming the variable it would have split (a, as the verified run's
/// first split), without computing a step again; at ten runs it verifies as without the bound.
#[test]
fn max_redone_gives_a_cell_up_before_a_split_that_would_compute_too_many_steps_again() {
    let (lp, _) = truncated_cubic();
    let cell = [Interval::new(-1.0, 1.0).unwrap(), Interval::new(-1.0, 1.0).unwrap(), Interval::point(0.0)];
    let settings = CellSettings { order: 2, max_splits: 3, ..loop_settings(false) };
    let out = verify_cell(&lp, &cell, &CellSettings { max_redone: Some(0.5), ..settings.clone() });
    assert_eq!((out.verdict, out.branches, out.steps_redone, out.split), (Verdict::Unknown, 0, 0, Some(0)), "{:?}", out.reason);
    assert!(out.reason.as_deref().unwrap_or("").contains("past max_redone"), "{:?}", out.reason);
    let out = verify_cell(&lp, &cell, &CellSettings { max_redone: Some(10.0), ..settings });
    assert_eq!((out.verdict, out.branches), (Verdict::Verified, 3), "{:?}", out.reason);
}

/// x' = y, y' = -x from around (1, 0) for one period of pi (half a turn); safe while
/// 0.5 x^2 + y^2 <= `limit`. The runs from the corners (1.1, +-0.1) reach 1.22 (their whole 1.1^2 + 0.1^2) near a quarter turn
/// and are back at 0.615 at the period's end, so only the segments can tell a limit below it.
fn half_turn(limit: f64) -> ClosedLoop {
    use taylor::flowpipe::Ode;
    let names: Vec<String> = ["x", "y"].iter().map(|s| s.to_string()).collect();
    let ode = Ode::new(names.clone(), vec![parse_expr("y").unwrap(), parse_expr("-x").unwrap()]).unwrap();
    let margin = Program::compile(&[parse_expr(&format!("0.5*x^2 + y^2 - {limit}")).unwrap()], &names).unwrap();
    let lp = ClosedLoop {
        state_names: names,
        stages: vec![],
        plant: Plant::continuous(ode, vec![], std::f64::consts::PI, std::f64::consts::PI / 10.0, 1e-4),
        safe: vec![Condition { margin: Arc::new(margin), cmp: Cmp::Le, label: format!("0.5 x^2 + y^2 <= {limit}"), window: None }],
        goal: None,
        goal_within: false,
        steps: 1,
    };
    lp.validate().unwrap();
    lp
}

#[test]
fn a_relation_between_states_is_proved_on_the_segments_models_and_only_if_it_holds() {
    let cell = [Interval::new(0.9, 1.1).unwrap(), Interval::new(-0.1, 0.1).unwrap()];
    // The most the corner runs reach, sampled over the half turn.
    let peak = (0..=1000)
        .flat_map(|k| [(1.1, 0.1), (1.1, -0.1), (0.9, 0.1)].map(|(x, y): (f64, f64)| (k, x, y)))
        .map(|(k, x0, y0)| {
            let t = std::f64::consts::PI * k as f64 / 1000.0;
            let (x, y) = (x0 * t.cos() + y0 * t.sin(), -x0 * t.sin() + y0 * t.cos());
            0.5 * x * x + y * y
        })
        .fold(0.0, f64::max);
    assert!((peak - 1.22).abs() < 1e-3, "{peak}");
    // The boxes of the segments near the quarter turn (x up to 0.43 where |y| reaches 1.1)
    // fail even 1.5; the relation between x and y proves 1.3.
    let out = verify_cell(&half_turn(1.3), &cell, &loop_settings(false));
    assert_eq!(out.verdict, Verdict::Verified, "{:?}", out.reason);
    // Runs cross 1.2 inside the period only, never at its ends: not verified.
    let out = verify_cell(&half_turn(1.2), &cell, &loop_settings(false));
    assert_eq!(out.verdict, Verdict::Unknown, "{:?}", out.reason);
    assert!(out.reason.as_deref().unwrap_or("").contains("could not be proved over t"), "{:?}", out.reason);
}

/// x+ = x + 2 a - 0.3 b^2 + 0.3 b^3 (a, b constant) at order 2: b^3's truncation, 0.3 a step,
/// is the whole overestimate (runs reach 2 a step at most, the bound 2.3), and x's relative error
/// stays at 12% from step 1 on. Halving a leaves the truncation as it is in the half with a near
/// 1; halving b divides it by 8.
fn truncated_cubic() -> (ClosedLoop, Program) {
    let names: Vec<String> = ["a", "b", "x"].iter().map(|s| s.to_string()).collect();
    let updates = ["a", "b", "x + 2*a - 0.3*b^2 + 0.3*b^3"].map(|e| parse_expr(e).unwrap());
    let plant = Program::compile(&updates, &names).unwrap();
    let safe = Program::compile(&[parse_expr("x - 21").unwrap()], &names).unwrap();
    let lp = ClosedLoop {
        state_names: names,
        stages: vec![],
        plant: Plant::Discrete(Arc::new(plant.clone())),
        safe: vec![Condition { margin: Arc::new(safe), cmp: Cmp::Le, label: "x <= 21".into(), window: None }],
        goal: None,
        goal_within: false,
        steps: 10,
    };
    lp.validate().unwrap();
    (lp, plant)
}

/// A lost piece whose error is truncation from step 1 on is split at step 0, so the halves make
/// the smaller truncation of their own: the cell verifies after three splits (two along a, the
/// largest spread, then b). Split where its error stopped changing (step 9), every half would
/// carry the nine steps' truncation and none would verify. Float runs from a grid of the cell
/// stay in every step's box.
#[test]
fn a_piece_lost_to_truncation_is_split_before_it_and_encloses_the_simulations() {
    let (lp, plant) = truncated_cubic();
    let cell = [Interval::new(-1.0, 1.0).unwrap(), Interval::new(-1.0, 1.0).unwrap(), Interval::point(0.0)];
    let settings = CellSettings { order: 2, ..loop_settings(false) };
    assert_eq!(verify_cell(&lp, &cell, &settings).verdict, Verdict::Unknown);
    let out = verify_cell(&lp, &cell, &CellSettings { max_splits: 3, ..settings });
    assert_eq!((out.verdict, out.branches), (Verdict::Verified, 3), "{:?}", out.reason);
    assert_eq!(out.steps_done, 10);
    // Each split restarted at step 0 what its piece had run (a run of its own), and a verified
    // cell names the state it split most.
    assert!(out.steps_redone >= 3, "{} steps redone", out.steps_redone);
    assert_eq!(out.split, Some(0));
    for i in 0..=40 {
        for j in 0..=40 {
            assert_float_run_inside(&out.boxes, &plant, vec![-1.0 + i as f64 / 20.0, -1.0 + j as f64 / 20.0, 0.0]);
        }
    }
}
