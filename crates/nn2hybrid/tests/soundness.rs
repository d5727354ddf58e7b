//! Sampling soundness and tightness of network bounds: random sigmoid, tanh, ReLU and mixed
//! networks of several widths and depths; every float forward pass from inside the box must lie
//! inside the bounds of every method.
use nn2hybrid::propagate::{self, Models, Settings};
use nn2hybrid::{verisig, Activation, LayerArrays, Network, NetworkError};
use taylor::{Ctx, Interval, Space, TaylorModel};

/// Deterministic uniform numbers in [0, 1).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / ((1u64 << 53) as f64)
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// A random network; `acts` cycles per layer, `mixed` draws one activation per neuron.
fn random_network(rng: &mut Rng, widths: &[usize], acts: &[Activation], mixed: bool, gain: f64) -> Network {
    let layers = widths
        .windows(2)
        .enumerate()
        .map(|(l, w)| {
            let (n_in, n_out) = (w[0], w[1]);
            let scale = gain / (n_in as f64).sqrt();
            let activations = if mixed {
                (0..n_out).map(|_| acts[(rng.next() * acts.len() as f64) as usize % acts.len()]).collect()
            } else {
                vec![acts[l % acts.len()]]
            };
            LayerArrays {
                n_out,
                n_in,
                weight: (0..n_out * n_in).map(|_| rng.range(-scale, scale)).collect(),
                bias: (0..n_out).map(|_| rng.range(-0.5, 0.5)).collect(),
                activations,
            }
        })
        .collect();
    let n = *widths.last().unwrap();
    Network::new(layers, Some((0..n).map(|_| rng.range(0.5, 2.0)).collect()), Some(vec![0.1; n])).unwrap()
}

fn random_box(rng: &mut Rng, n: usize, radius: f64) -> Vec<Interval> {
    (0..n)
        .map(|_| {
            let c = rng.range(-1.0, 1.0);
            Interval::new(c - radius, c + radius).unwrap()
        })
        .collect()
}

/// Float outputs at `count` random points of the box (corners included).
fn samples(rng: &mut Rng, net: &Network, bx: &[Interval], count: usize) -> Vec<Vec<f64>> {
    (0..count)
        .map(|k| {
            let x: Vec<f64> = bx
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    if k < 2 {
                        if (k + i) % 2 == 0 {
                            b.lo()
                        } else {
                            b.hi()
                        }
                    } else {
                        rng.range(b.lo(), b.hi())
                    }
                })
                .collect();
            net.eval(&x).unwrap()
        })
        .collect()
}

fn assert_encloses(label: &str, bounds: &[Interval], points: &[Vec<f64>]) {
    for y in points {
        for (j, (b, v)) in bounds.iter().zip(y).enumerate() {
            assert!(b.contains(*v), "{label}: output {j} = {v} outside {b}");
        }
    }
}

/// Sampled range width of each output.
fn sampled_widths(points: &[Vec<f64>]) -> Vec<f64> {
    (0..points[0].len())
        .map(|j| {
            let (lo, hi) = points.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), y| (lo.min(y[j]), hi.max(y[j])));
            hi - lo
        })
        .collect()
}

const SIGMOID: Activation = Activation::Sigmoid;
const TANH: Activation = Activation::Tanh;
const RELU: Activation = Activation::Relu;
const IDENTITY: Activation = Activation::Identity;

#[test]
fn direct_and_interval_bounds_contain_samples() {
    let mut rng = Rng(1);
    let shapes: [&[usize]; 5] = [&[2, 8, 1], &[3, 16, 16, 2], &[2, 50, 600, 3], &[4, 20, 20, 20, 20, 1], &[6, 32, 8]];
    let kinds: [(&[Activation], bool); 5] =
        [(&[SIGMOID], false), (&[TANH], false), (&[RELU], false), (&[SIGMOID, TANH, RELU, IDENTITY], true), (&[TANH, RELU], false)];
    for shape in shapes {
        for (acts, mixed) in kinds {
            for radius in [1e-6, 1e-3, 0.05, 0.5] {
                let net = random_network(&mut rng, shape, acts, mixed, 2.0);
                let bx = random_box(&mut rng, shape[0], radius);
                let points = samples(&mut rng, &net, &bx, 2000);
                let label = format!("{shape:?} {acts:?} mixed={mixed} radius {radius}");
                for order in [3, 5] {
                    let s = Settings { order, max_vars: 3, ..Settings::default() };
                    assert_encloses(&format!("{label} taylor order {order}"), &propagate::bounds(&net, &bx, &s).unwrap(), &points);
                }
                let s = Settings { symbolic: false, ..Settings::default() };
                assert_encloses(&format!("{label} taylor without symbols"), &propagate::bounds(&net, &bx, &s).unwrap(), &points);
                assert_encloses(&format!("{label} interval"), &propagate::interval_bounds(&net, &bx).unwrap(), &points);
            }
        }
    }
}

#[test]
fn verisig_bounds_contain_samples_and_agree_with_direct() {
    let mut rng = Rng(2);
    let shapes: [&[usize]; 3] = [&[2, 8, 1], &[3, 16, 16, 2], &[2, 30, 5]];
    for shape in shapes {
        for (acts, mixed) in [(&[SIGMOID][..], false), (&[TANH][..], false), (&[SIGMOID, TANH, RELU, IDENTITY][..], true)] {
            for radius in [1e-4, 0.05] {
                let net = random_network(&mut rng, shape, acts, mixed, 1.5);
                let bx = random_box(&mut rng, shape[0], radius);
                let points = samples(&mut rng, &net, &bx, 2000);
                let s = Settings { order: 4, ..Settings::default() };
                let v = verisig::bounds(&net, &bx, &s).unwrap();
                let label = format!("{shape:?} {acts:?} radius {radius}");
                assert_encloses(&format!("{label} verisig"), &v, &points);
                // The two methods enclose the same function: they must overlap.
                let d = propagate::bounds(&net, &bx, &s).unwrap();
                for (a, b) in v.iter().zip(&d) {
                    assert!(!a.intersect(b).is_empty(), "{label}: verisig {a} and direct {b} are disjoint");
                }
            }
        }
    }
}

#[test]
fn direct_bounds_are_tight_on_small_boxes() {
    let mut rng = Rng(3);
    for (shape, acts) in [(&[2usize, 16, 16, 1][..], &[SIGMOID][..]), (&[3, 20, 20, 2], &[TANH]), (&[2, 50, 100, 4], &[TANH, SIGMOID])] {
        let net = random_network(&mut rng, shape, acts, false, 2.0);
        let bx = random_box(&mut rng, shape[0], 1e-2);
        let points = samples(&mut rng, &net, &bx, 4000);
        let bounds = propagate::bounds(&net, &bx, &Settings::default()).unwrap();
        for (b, w) in bounds.iter().zip(sampled_widths(&points)) {
            assert!(b.width() <= 1.5 * w + 1e-9, "{shape:?}: bound width {} vs sampled {w}", b.width());
        }
    }
}

#[test]
fn narrow_layers_and_truncated_activations_stay_sound() {
    // An image chain's shape: wide layers make a symbol per neuron, narrow ones box all but the
    // largest (`narrow_symbols`), and the later layers' activations drop degrees against the
    // errors their inputs carry (inputs with remainders, as in a closed loop).
    let mut rng = Rng(12);
    for (shape, acts) in [(&[3usize, 40, 400, 12, 400, 2][..], &[TANH, SIGMOID][..]), (&[2, 300, 8, 300, 8, 1], &[SIGMOID])] {
        for radius in [1e-3, 0.02, 0.2] {
            let net = random_network(&mut rng, shape, acts, false, 2.0);
            let bx = random_box(&mut rng, shape[0], radius);
            let points = samples(&mut rng, &net, &bx, 3000);
            let label = format!("{shape:?} radius {radius}");
            let mut widths = vec![];
            for keep in [None, Settings::default().narrow_symbols, Some(4), Some(0)] {
                let s = Settings { order: 4, symbol_min: 0.0, narrow_symbols: keep, ..Settings::default() };
                let bounds = propagate::bounds(&net, &bx, &s).unwrap();
                assert_encloses(&format!("{label} keep {keep:?}"), &bounds, &points);
                widths.push(bounds[0].width());
            }
            // Boxing beyond the default's largest symbols costs little (measured: at most 16% here).
            assert!(widths[1] <= 1.25 * widths[0], "{label}: widths {widths:?}");
            // Inputs with remainders: the activations' degrees drop, sampled anywhere inside.
            let ctx = Ctx::new(Space::get(shape[0], 4, 0).unwrap(), 4, 1e-15);
            let inputs: Vec<TaylorModel> = bx
                .iter()
                .enumerate()
                .map(|(v, b)| {
                    let mut x = TaylorModel::affine(&ctx, b.mid(), v, 0.8 * b.radius());
                    x.rem = Interval::new(-0.2 * b.radius(), 0.2 * b.radius()).unwrap();
                    x
                })
                .collect();
            let out = propagate::propagate_taylor_models(&net, &inputs, &ctx, &Settings { order: 4, ..Settings::default() }).unwrap();
            for _ in 0..3000 {
                let a: Vec<f64> = (0..shape[0]).map(|_| rng.range(-1.0, 1.0)).collect();
                let x: Vec<f64> =
                    bx.iter().zip(&a).map(|(b, a)| b.mid() + 0.8 * b.radius() * a + rng.range(-0.2, 0.2) * b.radius()).collect();
                let truth = net.eval(&x).unwrap();
                let at: Vec<Interval> = a.iter().map(|&a| Interval::point(a)).collect();
                for (j, model) in out.iter().enumerate() {
                    let value = model.eval_interval(&ctx.space, &at);
                    assert!(value.contains(truth[j]), "{label}: output {j}: {value} misses {}", truth[j]);
                }
            }
        }
    }
}

#[test]
fn splitting_stays_sound_and_tightens_wide_boxes() {
    let mut rng = Rng(4);
    let net = random_network(&mut rng, &[2, 30, 30, 1], &[TANH], false, 3.0);
    let bx = vec![Interval::new(-1.0, 1.0).unwrap(), Interval::new(0.2, 0.2001).unwrap()];
    let points = samples(&mut rng, &net, &bx, 5000);
    let whole = propagate::bounds(&net, &bx, &Settings::default()).unwrap();
    let split = propagate::bounds(&net, &bx, &Settings { splits: vec![(0, 6)], ..Settings::default() }).unwrap();
    assert_encloses("whole", &whole, &points);
    assert_encloses("split", &split, &points);
    assert!(split[0].width() < whole[0].width(), "split {} vs whole {}", split[0], whole[0]);
}

#[test]
fn many_inputs_become_symbols() {
    // 40 inputs: 4 are polynomial variables, the rest enter as error symbols.
    let mut rng = Rng(5);
    let net = random_network(&mut rng, &[40, 20, 3], &[SIGMOID, TANH], false, 1.0);
    let bx = random_box(&mut rng, 40, 0.02);
    let points = samples(&mut rng, &net, &bx, 2000);
    assert_encloses("40 inputs", &propagate::bounds(&net, &bx, &Settings::default()).unwrap(), &points);
    let models = Models::from_box(&bx, &Settings::default(), false).unwrap();
    assert_eq!(models.variables.len(), 4);
    assert_eq!(models.symbols(), 36);
}

#[test]
fn taylor_model_inputs_compose() {
    // Inputs that are themselves Taylor models of a state (x, y) in [-1, 1]^2, as in a closed loop.
    let mut rng = Rng(6);
    let net = random_network(&mut rng, &[2, 16, 16, 1], &[SIGMOID], false, 2.0);
    let ctx = Ctx::new(Space::get(2, 5, 0).unwrap(), 5, 1e-15);
    let x = TaylorModel::affine(&ctx, 0.3, 0, 0.1);
    let y = TaylorModel::var(&ctx, 1).scale(0.05).add(&x.square(&ctx).scale(0.5));
    let out = propagate::propagate_taylor_models(&net, &[x, y], &ctx, &Settings::default()).unwrap();
    for _ in 0..2000 {
        let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let (xv, yv) = (0.3 + 0.1 * a, 0.05 * b + 0.5 * (0.3 + 0.1 * a).powi(2));
        let truth = net.eval(&[xv, yv]).unwrap()[0];
        let e = out[0].eval_interval(&ctx.space, &[Interval::point(a), Interval::point(b)]);
        assert!(e.contains(truth), "{e} misses {truth}");
    }
}

#[test]
fn input_remainders_stay_correlated_across_neurons() {
    // One input seen by two tanh neurons whose difference is the output: the input's remainder
    // (a closed loop's earlier errors) cancels when it is one symbol, not two intervals.
    let net = Network::new(
        vec![
            LayerArrays { n_out: 2, n_in: 1, weight: vec![3.0, 3.0], bias: vec![0.1, 0.1], activations: vec![TANH] },
            LayerArrays { n_out: 1, n_in: 2, weight: vec![1.0, -1.0], bias: vec![0.0], activations: vec![IDENTITY] },
        ],
        None,
        None,
    )
    .unwrap();
    let ctx = Ctx::new(Space::get(1, 5, 0).unwrap(), 5, 1e-15);
    // A narrow polynomial part and a wider remainder, as in a closed loop after many steps.
    let mut x = TaylorModel::affine(&ctx, 0.2, 0, 0.001);
    x.rem = Interval::new(-0.01, 0.02).unwrap();
    let out = propagate::propagate_taylor_models(&net, &[x.clone()], &ctx, &Settings::default()).unwrap();
    let bound = out[0].bound(&ctx.space);
    // As two independent intervals: 2 x 3 x tanh' x 0.03 >= 0.08 (tanh' >= 0.48 on [0.6, 0.8]).
    assert!(bound.width() < 0.008, "{bound}");
    let mut rng = Rng(11);
    for _ in 0..2000 {
        let (a, e) = (rng.range(-1.0, 1.0), rng.range(-0.01, 0.02));
        let xv = 0.2 + 0.001 * a + e;
        let truth = net.eval(&[xv]).unwrap()[0];
        let value = out[0].eval_interval(&ctx.space, &[Interval::point(a)]);
        assert!(value.contains(truth), "{value} misses {truth}");
    }
    // Sampled inputs anywhere in their remainders, through a random sigmoid network.
    let net = random_network(&mut rng, &[2, 16, 16, 2], &[SIGMOID, TANH], false, 2.0);
    let ctx = Ctx::new(Space::get(2, 5, 0).unwrap(), 5, 1e-15);
    let mut x = TaylorModel::affine(&ctx, 0.3, 0, 0.1);
    x.rem = Interval::new(-0.02, 0.005).unwrap();
    let mut y = TaylorModel::var(&ctx, 1).scale(0.05).add(&x.square(&ctx).scale(0.5));
    y.rem = Interval::new(-1e-3, 3e-3).unwrap();
    let out = propagate::propagate_taylor_models(&net, &[x.clone(), y.clone()], &ctx, &Settings::default()).unwrap();
    for _ in 0..4000 {
        let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let (ex, ey) = (rng.range(-0.02, 0.005), rng.range(-1e-3, 3e-3));
        let xv = 0.3 + 0.1 * a;
        let truth = net.eval(&[xv + ex, 0.05 * b + 0.5 * xv * xv + ey]).unwrap();
        for (j, model) in out.iter().enumerate() {
            let value = model.eval_interval(&ctx.space, &[Interval::point(a), Interval::point(b)]);
            assert!(value.contains(truth[j]), "output {j}: {value} misses {}", truth[j]);
        }
    }
}

#[test]
fn verisig_keeps_a_closed_loops_own_time_variable_apart() {
    // Variable 0 ranges over [0, 1] (a closed loop's normalised time): the Verisig ODEs must get
    // a fresh time variable, not integrate over this one.
    let mut rng = Rng(9);
    let net = random_network(&mut rng, &[2, 8, 1], &[TANH], false, 1.5);
    let ctx = Ctx::new(Space::get(2, 4, 0b01).unwrap(), 4, 1e-15);
    let x = TaylorModel::var(&ctx, 0).scale(0.2).add_constant(0.1);
    let y = TaylorModel::var(&ctx, 1).scale(0.05);
    let s = Settings { order: 4, ..Settings::default() };
    let out = verisig::propagate(&net, &Models::from_taylor_models(&[x, y], &ctx).unwrap(), &s).unwrap();
    assert_eq!(out.time_var(), Some(2));
    let bounds = out.bounds();
    for _ in 0..2000 {
        let (t, b) = (rng.next(), rng.range(-1.0, 1.0));
        let truth = net.eval(&[0.1 + 0.2 * t, 0.05 * b]).unwrap()[0];
        assert!(bounds[0].contains(truth), "{} misses {truth}", bounds[0]);
    }
}

#[test]
fn chained_models_match_the_composed_network() {
    let mut rng = Rng(7);
    let first = random_network(&mut rng, &[2, 12, 3], &[TANH], false, 2.0);
    let second = random_network(&mut rng, &[3, 12, 1], &[SIGMOID], false, 2.0);
    let bx = random_box(&mut rng, 2, 0.05);
    let s = Settings::default();
    let middle = propagate::propagate(&first, &Models::from_box(&bx, &s, false).unwrap(), &s).unwrap();
    let out = propagate::propagate(&second, &middle, &s).unwrap().bounds();
    let points: Vec<Vec<f64>> = (0..3000)
        .map(|_| {
            let x: Vec<f64> = bx.iter().map(|b| rng.range(b.lo(), b.hi())).collect();
            second.eval(&first.eval(&x).unwrap()).unwrap()
        })
        .collect();
    assert_encloses("chained models", &out, &points);
    let via_verisig = verisig::propagate(&second, &middle, &Settings { order: 4, ..s }).unwrap().bounds();
    assert_encloses("chained into verisig", &via_verisig, &points);
}

#[test]
fn bad_inputs_are_errors() {
    let mut rng = Rng(8);
    let net = random_network(&mut rng, &[2, 4, 1], &[TANH], false, 1.0);
    let one = [Interval::new(0.0, 1.0).unwrap()];
    let two = [Interval::new(0.0, 1.0).unwrap(), Interval::new(0.0, 0.5).unwrap()];
    let err = propagate::bounds(&net, &one, &Settings::default()).unwrap_err();
    assert_eq!(err.to_string(), "the network takes 2 inputs but the box has 1 intervals");
    assert!(propagate::interval_bounds(&net, &one).is_err());
    assert!(verisig::bounds(&net, &one, &Settings::default()).is_err());
    let unbounded = [Interval::ENTIRE, Interval::new(0.0, 1.0).unwrap()];
    assert!(matches!(propagate::bounds(&net, &unbounded, &Settings::default()), Err(NetworkError::Input(_))));
    assert!(propagate::interval_bounds(&net, &unbounded).is_err());
    let bad_order = Settings { order: 0, ..Settings::default() };
    assert!(propagate::bounds(&net, &two, &bad_order).unwrap_err().to_string().contains("order must be between"));
    let bad_split = Settings { splits: vec![(5, 2)], ..Settings::default() };
    assert!(propagate::bounds(&net, &two, &bad_split).unwrap_err().to_string().contains("cannot split input 5"));
    let models = Models::from_box(&one, &Settings::default(), false).unwrap();
    let err = propagate::propagate(&net, &models, &Settings::default()).err().expect("wrong input count");
    assert!(err.to_string().contains("takes 2 inputs but 1"));
}

/// ReLU ranges by back-substitution: on ReLU networks (and ReLU layers after a smooth one, where
/// back-substitution starts anew) over wide boxes, the bounds with it contain every sample, lie
/// inside the bounds without it (up to 0.1% of their width: the zonotope relaxation is not
/// monotone in the ranges it starts from, as a tighter range changes the chord's slope), and are
/// tighter in total.
#[test]
fn back_substitution_is_sound_and_never_looser() {
    let mut rng = Rng(21);
    let off = Settings { back_substitution: false, ..Settings::default() };
    let cases: [(&[usize], &[Activation], bool); 6] = [
        (&[3, 30, 30, 2], &[RELU], false),
        (&[4, 20, 20, 20, 20, 1], &[RELU], false),
        (&[12, 40, 40, 10, 3], &[RELU], false),
        (&[3, 16, 24, 24, 2], &[TANH, RELU, RELU], false),
        (&[4, 24, 24, 2], &[RELU, IDENTITY], true),
        (&[2, 60, 2], &[RELU], false),
    ];
    let (mut with_total, mut without_total) = (0.0, 0.0);
    for (shape, acts, mixed) in cases {
        for radius in [0.1, 0.5, 1.0] {
            let net = random_network(&mut rng, shape, acts, mixed, 2.0);
            let bx = random_box(&mut rng, shape[0], radius);
            let points = samples(&mut rng, &net, &bx, 5000);
            let with = propagate::bounds(&net, &bx, &Settings::default()).unwrap();
            let without = propagate::bounds(&net, &bx, &off).unwrap();
            assert_encloses(&format!("{shape:?} radius {radius} back-substituted"), &with, &points);
            assert_encloses(&format!("{shape:?} radius {radius} without"), &without, &points);
            for (a, b) in with.iter().zip(&without) {
                // Tighter ranges change the chord slopes, so an end may move out by a hair.
                let slack = 1e-3 * b.width();
                assert!(a.lo() >= b.lo() - slack && a.hi() <= b.hi() + slack, "{shape:?} radius {radius}: {a} not inside {b}");
                with_total += a.width();
                without_total += b.width();
            }
        }
    }
    assert!(with_total < 0.9 * without_total, "back-substitution must tighten: {with_total} vs {without_total}");
}

/// The same through Taylor-model inputs (a closed loop's state: polynomials with nonnegative
/// monomials, remainders that become symbols): every float forward pass of a point of the
/// inputs' models lies inside the output models, with and without back-substitution, and the
/// output ranges with it are no wider (0.1% slack, as above) and narrower in total.
#[test]
fn back_substituted_models_enclose_taylor_model_inputs() {
    let mut rng = Rng(22);
    let (mut with_total, mut without_total) = (0.0, 0.0);
    let ctx = Ctx::new(Space::get(2, 5, 0).unwrap(), 5, 1e-15);
    for (shape, acts) in [(&[2usize, 40, 40, 2][..], &[RELU][..]), (&[2, 20, 20, 20, 1], &[RELU]), (&[2, 16, 30, 2], &[SIGMOID, RELU])] {
        let net = random_network(&mut rng, shape, acts, false, 2.0);
        let mut x = TaylorModel::affine(&ctx, 0.3, 0, 0.6);
        x.rem = Interval::new(-0.05, 0.02).unwrap();
        let mut y = TaylorModel::var(&ctx, 1).scale(0.4).add(&x.square(&ctx).scale(0.5));
        y.rem = Interval::new(-1e-2, 3e-2).unwrap();
        let run = |back_substitution| {
            let s = Settings { back_substitution, ..Settings::default() };
            propagate::propagate_taylor_models(&net, &[x.clone(), y.clone()], &ctx, &s).unwrap()
        };
        let (with, without) = (run(true), run(false));
        for (a, b) in with.iter().zip(&without) {
            let (ra, rb) = (a.bound(&ctx.space), b.bound(&ctx.space));
            assert!(ra.width() <= rb.width() * (1.0 + 1e-3), "{shape:?}: {ra} wider than {rb}");
            with_total += ra.width();
            without_total += rb.width();
        }
        for _ in 0..4000 {
            let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            let (ex, ey) = (rng.range(-0.05, 0.02), rng.range(-1e-2, 3e-2));
            let xv = 0.3 + 0.6 * a;
            let truth = net.eval(&[xv + ex, 0.4 * b + 0.5 * xv * xv + ey]).unwrap();
            for out in [&with, &without] {
                for (j, model) in out.iter().enumerate() {
                    let value = model.eval_interval(&ctx.space, &[Interval::point(a), Interval::point(b)]);
                    assert!(value.contains(truth[j]), "{shape:?} output {j}: {value} misses {}", truth[j]);
                }
            }
        }
    }
    assert!(with_total < 0.95 * without_total, "back-substitution must tighten the models: {with_total} vs {without_total}");
}

/// Optimised lower slopes (alpha-CROWN): sound on ReLU networks over wide boxes, never looser
/// than the adaptive slopes (0.1% slack, as above), and tighter in total.
#[test]
fn optimised_slopes_are_sound_and_tighter() {
    let mut rng = Rng(23);
    let adaptive = Settings::default();
    let optimised = Settings { alpha_steps: 20, ..Settings::default() };
    let (mut with_total, mut without_total) = (0.0, 0.0);
    for shape in [&[3usize, 30, 30, 2][..], &[4, 20, 20, 20, 20, 1], &[12, 40, 40, 10, 3]] {
        for radius in [0.5, 1.0] {
            let net = random_network(&mut rng, shape, &[RELU], false, 2.0);
            let bx = random_box(&mut rng, shape[0], radius);
            let points = samples(&mut rng, &net, &bx, 5000);
            let with = propagate::bounds(&net, &bx, &optimised).unwrap();
            let without = propagate::bounds(&net, &bx, &adaptive).unwrap();
            assert_encloses(&format!("{shape:?} radius {radius} optimised"), &with, &points);
            for (a, b) in with.iter().zip(&without) {
                let slack = 1e-3 * b.width();
                assert!(a.lo() >= b.lo() - slack && a.hi() <= b.hi() + slack, "{shape:?} radius {radius}: {a} not inside {b}");
                with_total += a.width();
                without_total += b.width();
            }
        }
    }
    assert!(with_total < 0.95 * without_total, "optimised slopes must tighten: {with_total} vs {without_total}");
}
