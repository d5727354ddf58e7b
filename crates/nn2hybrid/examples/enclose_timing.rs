use nn2hybrid::activation::{enclose, Smooth};
use taylor::Interval;
fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let cases: Vec<(f64, f64)> = if args.len() == 2 { vec![(args[0], args[1])] } else { vec![(-0.01, 0.02), (0.3, 1.1), (-0.75, 0.75), (-3.0, -1.5), (2.0, 3.5), (-4.0, 4.0), (-10.0, -8.5)] };
    let reps = if args.len() == 2 { 200000 } else { 2000 };
    for &(lo, hi) in &cases {
        for f in [Smooth::Sigmoid, Smooth::Tanh] {
            let r = Interval::new(lo, hi).unwrap();
            let t = std::time::Instant::now();
            let mut e = None;
            for _ in 0..reps { e = Some(enclose(f, r, 4)); }
            let e = e.unwrap();
            println!("{f:?} [{lo},{hi}] {:.2} us err {:e}", t.elapsed().as_secs_f64() * 1e6 / reps as f64, e.err);
        }
    }
}
