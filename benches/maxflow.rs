//! Boykov–Kolmogorov max-flow on graphcut seam problems.
//!
//! A w×h pixel grid with 4-neighbour edges of random float smoothness weight
//! (seeded LCG), the left border tied to the source and the right border to
//! the sink with a large capacity, and random t-links on 2% of the pixels.
//! `solve/*` times `maxflow()` alone (graph built in the untimed setup);
//! `build_solve/*` times construction plus solve, as the synthesis loop does;
//! `dinic_build_solve/*` is ac-library's Dinic on the same graph (×1e6, rounded) for scale.

use btfquilt::quilt::maxflow::Graph;
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};

struct Lcg(u64);

impl Lcg {
    fn unit(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// (tlinks, edges) of the seam problem, so building can be timed separately.
type Problem = (Vec<(u32, f64, f64)>, Vec<(u32, u32, f64)>);

fn problem(w: usize, h: usize, seed: u64) -> Problem {
    let mut rng = Lcg(seed);
    let id = |x: usize, y: usize| (y * w + x) as u32;
    let mut tlinks = Vec::new();
    let mut edges = Vec::with_capacity(2 * w * h);
    for y in 0..h {
        tlinks.push((id(0, y), 1e9, 0.0));
        tlinks.push((id(w - 1, y), 0.0, 1e9));
        for x in 0..w {
            if x + 1 < w {
                edges.push((id(x, y), id(x + 1, y), rng.unit() * 2.0 + 1e-3));
            }
            if y + 1 < h {
                edges.push((id(x, y), id(x, y + 1), rng.unit() * 2.0 + 1e-3));
            }
            if rng.unit() < 0.02 {
                tlinks.push((id(x, y), rng.unit() * 4.0, rng.unit() * 4.0));
            }
        }
    }
    (tlinks, edges)
}

fn build(n: usize, p: &Problem) -> Graph {
    let mut g = Graph::new(n, p.1.len());
    for &(i, s, t) in &p.0 {
        g.add_tweights(i, s, t);
    }
    for &(a, b, c) in &p.1 {
        g.add_edge(a, b, c, c);
    }
    g
}

fn dinic(n: usize, p: &Problem) -> i64 {
    let q = |c: f64| (c * 1e6).round() as i64;
    let mut g = ac_library::MfGraph::<i64>::new(n + 2);
    for &(i, s, t) in &p.0 {
        g.add_edge(n, i as usize, q(s));
        g.add_edge(i as usize, n + 1, q(t));
    }
    for &(a, b, c) in &p.1 {
        g.add_edge(a as usize, b as usize, q(c));
        g.add_edge(b as usize, a as usize, q(c));
    }
    g.flow(n, n + 1)
}

fn benches(c: &mut Criterion) {
    for size in [64usize, 256] {
        let n = size * size;
        let p = problem(size, size, 0x5eed + size as u64);
        let flow = build(n, &p).maxflow();
        eprintln!(
            "maxflow {size}x{size}: {n} nodes, {} edges, flow {flow:.6}",
            p.1.len()
        );
        c.bench_function(&format!("maxflow/solve/{size}x{size}"), |b| {
            b.iter_batched(|| build(n, &p), |mut g| g.maxflow(), BatchSize::LargeInput)
        });
        c.bench_function(&format!("maxflow/build_solve/{size}x{size}"), |b| {
            b.iter(|| build(n, &p).maxflow())
        });
        // For scale: ac-library's Dinic on the capacities ×1e6, rounded.
        c.bench_function(&format!("maxflow/dinic_build_solve/{size}x{size}"), |b| {
            b.iter(|| dinic(n, &p))
        });
    }
}

criterion_group!(maxflow, benches);
criterion_main!(maxflow);
