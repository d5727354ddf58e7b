use nn2hybrid::propagate::{bounds, Settings};
use nn2hybrid::{Activation, LayerArrays, Network};
use taylor::Interval;
fn main() {
    let data = std::fs::read("/tmp/exp/chain.bin").unwrap();
    let mut pos = 0;
    let mut rd = |n: usize| { let s = &data[pos..pos + n]; pos += n; s.to_vec() };
    let i64_ = |b: Vec<u8>| i64::from_le_bytes(b.try_into().unwrap()) as usize;
    let nl = i64_(rd(8));
    let mut layers = vec![];
    for _ in 0..nl {
        let (o, i) = (i64_(rd(8)), i64_(rd(8)));
        let f = |b: Vec<u8>| b.chunks(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect::<Vec<f64>>();
        let w = f(rd(8 * o * i));
        let b = f(rd(8 * o));
        let acts = rd(o).iter().map(|&a| [Activation::Sigmoid, Activation::Tanh, Activation::Relu, Activation::Identity][a as usize]).collect();
        layers.push(LayerArrays { n_out: o, n_in: i, weight: w, bias: b, activations: acts });
    }
    let net = Network::new(layers, None, None).unwrap();
    let bx = [Interval::new(-0.5, -0.49975).unwrap(), Interval::new(0.3, 2.0).unwrap(), Interval::new(0.0, 0.0).unwrap()];
    let args: Vec<String> = std::env::args().collect();
    let order: usize = args.get(1).map_or(4, |s| s.parse().unwrap());
    let pieces: usize = args.get(2).map_or(8, |s| s.parse().unwrap());
    let symbolic = args.get(3).map_or(true, |s| s == "1");
    let symbol_min: f64 = args.get(4).map_or(1e-4, |s| s.parse().unwrap());
    let max_symbols: usize = args.get(5).map_or(4096, |s| s.parse().unwrap());
    let s = Settings { order, splits: vec![(1, pieces)], symbolic, symbol_min, max_symbols, ..Settings::default() };
    let reps = 20;
    let mut best = f64::INFINITY;
    let mut out = vec![];
    for _ in 0..reps {
        let t = std::time::Instant::now();
        out = bounds(&net, &bx, &s).unwrap();
        best = best.min(t.elapsed().as_secs_f64());
    }
    println!("order {order} pieces {pieces} symbolic {symbolic}: {:.2} ms  {:?} width {:e}", best * 1e3, out[0], out[0].width());
}
