//! Boykov–Kolmogorov max-flow (`btfquilt::quilt::maxflow`) against a brute-force
//! oracle on tiny graphs and against `ac_library`'s Dinic on larger ones.

use ac_library::MfGraph;
use btfquilt::quilt::maxflow::{Graph, Segment};
use proptest::prelude::*;

/// A graph description that can be fed to both solvers and used to evaluate cuts.
#[derive(Clone, Debug, Default)]
struct Spec {
    n: usize,
    /// (node, source cap, sink cap); several entries per node allowed.
    tlinks: Vec<(u32, f64, f64)>,
    /// (a, b, cap a->b, cap b->a)
    edges: Vec<(u32, u32, f64, f64)>,
}

impl Spec {
    fn build(&self) -> Graph {
        let mut g = Graph::new(self.n, self.edges.len());
        for &(i, s, t) in &self.tlinks {
            g.add_tweights(i, s, t);
        }
        for &(a, b, c, r) in &self.edges {
            g.add_edge(a, b, c, r);
        }
        g
    }

    /// Capacity of the cut where `source_side[i]` says node i is with s.
    fn cut_value(&self, source_side: &[bool]) -> f64 {
        let mut v = 0.0;
        for &(i, s, t) in &self.tlinks {
            v += if source_side[i as usize] { t } else { s };
        }
        for &(a, b, c, r) in &self.edges {
            match (source_side[a as usize], source_side[b as usize]) {
                (true, false) => v += c,
                (false, true) => v += r,
                _ => {}
            }
        }
        v
    }

    fn brute_force_min_cut(&self) -> f64 {
        assert!(self.n <= 16);
        let mut best = f64::INFINITY;
        let mut side = vec![false; self.n];
        for mask in 0u32..(1 << self.n) {
            for (i, s) in side.iter_mut().enumerate() {
                *s = mask >> i & 1 == 1;
            }
            best = best.min(self.cut_value(&side));
        }
        best
    }

    /// Dinic on capacities multiplied by `scale` and rounded; returns the flow and
    /// Dinic's source side.
    fn dinic(&self, scale: f64) -> (i64, Vec<bool>) {
        let (s, t) = (self.n, self.n + 1);
        let mut mf = MfGraph::<i64>::new(self.n + 2);
        let q = |c: f64| (c * scale).round() as i64;
        for &(i, cs, ct) in &self.tlinks {
            if q(cs) > 0 {
                mf.add_edge(s, i as usize, q(cs));
            }
            if q(ct) > 0 {
                mf.add_edge(i as usize, t, q(ct));
            }
        }
        for &(a, b, c, r) in &self.edges {
            if a == b {
                continue;
            }
            if q(c) > 0 {
                mf.add_edge(a as usize, b as usize, q(c));
            }
            if q(r) > 0 {
                mf.add_edge(b as usize, a as usize, q(r));
            }
        }
        let f = mf.flow(s, t);
        let side = mf.min_cut(s)[..self.n].to_vec();
        (f, side)
    }

    /// Number of arcs and t-links crossing a cut (each carries at most one rounding error).
    fn crossing(&self, side: &[bool]) -> usize {
        let t = self.tlinks.len();
        let e = self
            .edges
            .iter()
            .filter(|&&(a, b, _, _)| side[a as usize] != side[b as usize])
            .count();
        t + e
    }
}

fn segmentation(g: &Graph) -> Vec<bool> {
    (0..g.node_count() as u32)
        .map(|i| g.segment(i) == Segment::Source)
        .collect()
}

/// A small deterministic generator (64-bit LCG, high bits).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn unit(&mut self) -> f64 {
        self.next() as f64 / (1u64 << 31) as f64
    }
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * (1.0 + a.abs().max(b.abs()))
}

/// Solve with BK and check the returned segmentation is a cut of capacity == flow.
fn solve_checked(spec: &Spec, rel: f64) -> (f64, Vec<bool>) {
    let mut g = spec.build();
    let f = g.maxflow();
    assert_eq!(g.maxflow(), f, "second call must return the same value");
    let side = segmentation(&g);
    let cut = spec.cut_value(&side);
    assert!(close(cut, f, rel), "cut {cut} != flow {f}");
    (f, side)
}

fn random_float_spec(rng: &mut Lcg, n: usize) -> Spec {
    let mut spec = Spec { n, ..Spec::default() };
    for i in 0..n as u32 {
        match rng.below(5) {
            0 => spec.tlinks.push((i, rng.unit() * 3.0, 0.0)),
            1 => spec.tlinks.push((i, 0.0, rng.unit() * 3.0)),
            2 => spec.tlinks.push((i, rng.unit() * 3.0, rng.unit() * 3.0)),
            3 => {
                spec.tlinks.push((i, rng.unit(), 0.0));
                spec.tlinks.push((i, 0.0, rng.unit()));
            }
            _ => {}
        }
    }
    let m = rng.below(3 * n as u64 + 1) as usize;
    for _ in 0..m {
        let a = rng.below(n as u64) as u32;
        let b = rng.below(n as u64) as u32;
        let c = if rng.below(4) == 0 { 0.0 } else { rng.unit() * 2.0 };
        let r = if rng.below(3) == 0 { 0.0 } else { rng.unit() * 2.0 };
        spec.edges.push((a, b, c, r));
    }
    spec
}

#[test]
fn brute_force_tiny_graphs() {
    let mut rng = Lcg(1);
    for _ in 0..3000 {
        let n = 1 + rng.below(10) as usize;
        let spec = random_float_spec(&mut rng, n);
        let (f, _) = solve_checked(&spec, 1e-9);
        let best = spec.brute_force_min_cut();
        assert!(close(f, best, 1e-9), "flow {f} vs brute force {best}: {spec:?}");
    }
}

fn int_spec(rng: &mut Lcg, n: usize, max_cap: u64) -> Spec {
    let mut spec = Spec { n, ..Spec::default() };
    for i in 0..n as u32 {
        let r = rng.below(10);
        if r < 2 {
            spec.tlinks.push((i, (1 + rng.below(max_cap)) as f64, 0.0));
        } else if r < 4 {
            spec.tlinks.push((i, 0.0, (1 + rng.below(max_cap)) as f64));
        } else if r == 4 {
            spec.tlinks
                .push((i, rng.below(max_cap) as f64, rng.below(max_cap) as f64));
        }
    }
    let m = rng.below(4 * n as u64) as usize + n / 2;
    for _ in 0..m {
        let a = rng.below(n as u64) as u32;
        let b = rng.below(n as u64) as u32;
        let c = rng.below(max_cap) as f64;
        let r = if rng.below(2) == 0 {
            0.0
        } else {
            rng.below(max_cap) as f64
        };
        spec.edges.push((a, b, c, r));
    }
    spec
}

#[test]
fn matches_dinic_on_random_integer_graphs() {
    let mut rng = Lcg(2024);
    for round in 0..300 {
        let n = 2 + rng.below(299) as usize;
        let max_cap = [2, 10, 1000, 1_000_000][round % 4];
        let spec = int_spec(&mut rng, n, max_cap);
        let (f, side) = solve_checked(&spec, 0.0);
        let (d, _) = spec.dinic(1.0);
        // Integer capacities: every partial sum is exact in f64.
        assert_eq!(f, d as f64, "round {round}: BK {f} vs Dinic {d}");
        assert_eq!(spec.cut_value(&side), f);
    }
}

/// A graphcut seam problem on a w×h grid: left column tied to the source and
/// right column to the sink with a large capacity, float smoothness weights.
fn grid_spec(rng: &mut Lcg, w: usize, h: usize, big: f64, tlink_fraction: f64) -> Spec {
    let id = |x: usize, y: usize| (y * w + x) as u32;
    let mut spec = Spec {
        n: w * h,
        ..Spec::default()
    };
    for y in 0..h {
        spec.tlinks.push((id(0, y), big, 0.0));
        spec.tlinks.push((id(w - 1, y), 0.0, big));
    }
    for y in 0..h {
        for x in 0..w {
            if x + 1 < w {
                let c = rng.unit() * 2.0 + 1e-3;
                spec.edges.push((id(x, y), id(x + 1, y), c, c));
            }
            if y + 1 < h {
                let c = rng.unit() * 2.0 + 1e-3;
                spec.edges.push((id(x, y), id(x, y + 1), c, c));
            }
            if tlink_fraction > 0.0 && rng.unit() < tlink_fraction {
                let s = rng.unit() * 4.0;
                let t = rng.unit() * 4.0;
                spec.tlinks.push((id(x, y), s, t));
            }
        }
    }
    spec
}

/// BK on float capacities vs Dinic on `round(c · 1e6)`: the two optima differ by
/// at most half a unit per link crossing either optimal cut.
fn compare_scaled(spec: &Spec) {
    let scale = 1e6;
    let (f, side) = solve_checked(spec, 1e-9);
    let (d, dside) = spec.dinic(scale);
    let tol = 0.5 / scale * spec.crossing(&side).max(spec.crossing(&dside)) as f64 + 1e-9 * f;
    let d = d as f64 / scale;
    assert!((f - d).abs() <= tol, "BK {f} vs Dinic {d} (tol {tol})");
    // Weak duality with Dinic's cut evaluated in floats.
    assert!(f <= spec.cut_value(&dside) * (1.0 + 1e-12) + 1e-9);
}

#[test]
fn grid_64x64_seam_problems_match_dinic() {
    let mut rng = Lcg(77);
    for k in 0..6 {
        let frac = if k % 2 == 0 { 0.0 } else { 0.02 };
        let spec = grid_spec(&mut rng, 64, 64, 1e6, frac);
        compare_scaled(&spec);
    }
}

#[test]
fn grid_with_infinite_terminals() {
    // f64::INFINITY on the border t-links must behave like a hard constraint.
    let mut rng = Lcg(5);
    let spec = grid_spec(&mut rng, 32, 24, f64::INFINITY, 0.0);
    let mut g = spec.build();
    let f = g.maxflow();
    let side = segmentation(&g);
    for y in 0..24 {
        assert!(side[y * 32]);
        assert!(!side[y * 32 + 31]);
    }
    let finite = Spec {
        tlinks: spec
            .tlinks
            .iter()
            .map(|&(i, s, t)| (i, s.min(1e6), t.min(1e6)))
            .collect(),
        ..spec.clone()
    };
    let (f2, _) = solve_checked(&finite, 1e-9);
    assert!(close(f, f2, 1e-9), "{f} vs {f2}");
}

/// Kwatra-style seam nodes: some neighbouring pixel pairs are joined through an
/// extra node m (a–m, m–b, and m→sink with the old seam cost).
#[test]
fn seam_nodes_match_dinic() {
    let mut rng = Lcg(31337);
    for _ in 0..8 {
        let (w, h) = (40, 30);
        let mut spec = grid_spec(&mut rng, w, h, 1e6, 0.0);
        let mut edges = Vec::new();
        for &(a, b, c, r) in &spec.edges {
            if rng.below(4) == 0 {
                let m = spec.n as u32;
                spec.n += 1;
                let c1 = rng.unit() * 2.0;
                let c2 = rng.unit() * 2.0;
                edges.push((a, m, c1, c1));
                edges.push((m, b, c2, c2));
                spec.tlinks.push((m, 0.0, c + r * rng.unit()));
            } else {
                edges.push((a, b, c, r));
            }
        }
        spec.edges = edges;
        compare_scaled(&spec);
        let ints = Spec {
            tlinks: spec
                .tlinks
                .iter()
                .map(|&(i, s, t)| (i, (s * 100.0).round(), (t * 100.0).round()))
                .collect(),
            edges: spec
                .edges
                .iter()
                .map(|&(a, b, c, r)| (a, b, (c * 100.0).round(), (r * 100.0).round()))
                .collect(),
            n: spec.n,
        };
        let (f, _) = solve_checked(&ints, 0.0);
        assert_eq!(f, ints.dinic(1.0).0 as f64);
    }
}

#[test]
fn degenerate_graphs() {
    // Empty graph.
    let mut g = Graph::new(0, 0);
    assert_eq!(g.node_count(), 0);
    assert_eq!(g.maxflow(), 0.0);

    // No edges: the flow is the sum of min(source, sink) per node.
    let mut g = Graph::new(4, 0);
    g.add_tweights(0, 3.0, 1.0);
    g.add_tweights(1, 1.0, 5.0);
    g.add_tweights(2, 2.0, 2.0);
    assert_eq!(g.maxflow(), 1.0 + 1.0 + 2.0);
    assert_eq!(g.segment(0), Segment::Source);
    assert_eq!(g.segment(1), Segment::Sink);
    assert_eq!(
        g.segment(2),
        Segment::Sink,
        "balanced t-links: unreached, Sink by convention"
    );
    assert_eq!(g.segment(3), Segment::Sink, "isolated node: Sink by convention");

    // All source.
    let mut g = Graph::new(3, 2);
    for i in 0..3 {
        g.add_tweights(i, 1.0, 0.0);
    }
    g.add_edge(0, 1, 1.0, 1.0);
    g.add_edge(1, 2, 1.0, 1.0);
    assert_eq!(g.maxflow(), 0.0);
    assert!((0..3).all(|i| g.segment(i) == Segment::Source));

    // All sink.
    let mut g = Graph::new(3, 2);
    for i in 0..3 {
        g.add_tweights(i, 0.0, 2.0);
    }
    g.add_edge(0, 1, 1.0, 1.0);
    g.add_edge(2, 1, 1.0, 0.0);
    assert_eq!(g.maxflow(), 0.0);
    assert!((0..3).all(|i| g.segment(i) == Segment::Sink));

    // Zero capacities everywhere.
    let mut g = Graph::new(3, 3);
    for i in 0..3 {
        g.add_tweights(i, 0.0, 0.0);
    }
    g.add_edge(0, 1, 0.0, 0.0);
    g.add_edge(1, 2, 0.0, 0.0);
    g.add_edge(2, 0, 0.0, 0.0);
    assert_eq!(g.maxflow(), 0.0);
    assert!((0..3).all(|i| g.segment(i) == Segment::Sink));

    // Zero-capacity path between a source node and a sink node.
    let mut g = Graph::new(2, 1);
    g.add_tweights(0, 5.0, 0.0);
    g.add_tweights(1, 0.0, 5.0);
    g.add_edge(0, 1, 0.0, 7.0);
    assert_eq!(g.maxflow(), 0.0);
    assert_eq!(g.segment(0), Segment::Source);
    assert_eq!(g.segment(1), Segment::Sink);

    // One node with both terminals, given in several calls.
    let mut g = Graph::new(1, 0);
    g.add_tweights(0, 2.0, 0.0);
    g.add_tweights(0, 0.0, 5.0);
    g.add_tweights(0, 1.0, 0.5);
    assert_eq!(g.maxflow(), 3.0);
    assert_eq!(g.segment(0), Segment::Sink);

    // add_node, self-loops and parallel edges.
    let mut g = Graph::new(0, 0);
    let a = g.add_node();
    let b = g.add_node();
    assert_eq!((a, b, g.node_count()), (0, 1, 2));
    g.add_tweights(a, 10.0, 0.0);
    g.add_tweights(b, 0.0, 10.0);
    g.add_edge(a, a, 100.0, 100.0);
    g.add_edge(a, b, 1.5, 0.0);
    g.add_edge(a, b, 2.0, 0.0);
    g.add_edge(b, a, 0.0, 0.25);
    assert_eq!(g.maxflow(), 3.75);
    assert_eq!(g.segment(a), Segment::Source);
    assert_eq!(g.segment(b), Segment::Sink);

    // A chain whose bottleneck is in the middle.
    let mut g = Graph::new(5, 4);
    g.add_tweights(0, 9.0, 0.0);
    g.add_tweights(4, 0.0, 9.0);
    for (i, c) in [4.0, 3.0, 0.5, 6.0].into_iter().enumerate() {
        g.add_edge(i as u32, i as u32 + 1, c, 0.0);
    }
    assert_eq!(g.maxflow(), 0.5);
    let side: Vec<_> = (0..5).map(|i| g.segment(i)).collect();
    use Segment::*;
    assert_eq!(side, [Source, Source, Source, Sink, Sink]);
}

#[test]
fn tiny_and_huge_capacities_mixed() {
    // Residuals up to eps = 1e-12 × (largest edge capacity) count as zero, so the
    // flow and the cut are exact up to eps per link.
    let mut rng = Lcg(9);
    for _ in 0..300 {
        let n = 1 + rng.below(9) as usize;
        let mut spec = random_float_spec(&mut rng, n);
        for e in spec.edges.iter_mut() {
            if rng.below(3) == 0 {
                e.2 *= 1e9;
            }
            if rng.below(3) == 0 {
                e.3 *= 1e-9;
            }
        }
        let max_edge = spec.edges.iter().fold(0.0f64, |m, e| m.max(e.2).max(e.3));
        let tol = 1e-12 * max_edge * (spec.edges.len() + spec.tlinks.len()) as f64 * 2.0 + 1e-12;
        let mut g = spec.build();
        let f = g.maxflow();
        let cut = spec.cut_value(&segmentation(&g));
        let best = spec.brute_force_min_cut();
        assert!(
            (f - best).abs() <= tol,
            "flow {f} vs brute force {best} (tol {tol})"
        );
        assert!((cut - f).abs() <= tol, "cut {cut} vs flow {f} (tol {tol})");
    }
}

#[cfg(debug_assertions)]
#[test]
#[should_panic]
fn negative_capacity_is_caught_in_debug() {
    let mut g = Graph::new(2, 1);
    g.add_edge(0, 1, -1.0, 0.0);
}

#[test]
#[should_panic]
fn out_of_range_edge_panics() {
    let mut g = Graph::new(2, 1);
    g.add_edge(0, 2, 1.0, 0.0);
}

#[test]
#[should_panic]
fn segment_before_maxflow_panics() {
    let g = Graph::new(2, 1);
    g.segment(0);
}

fn arb_spec() -> impl Strategy<Value = Spec> {
    (1usize..=8).prop_flat_map(|n| {
        let node = 0..n as u32;
        let cap = prop_oneof![Just(0.0), 0.0f64..4.0, (0u32..5).prop_map(f64::from)];
        (
            Just(n),
            prop::collection::vec((node.clone(), cap.clone(), cap.clone()), 0..2 * n),
            prop::collection::vec((node.clone(), node, cap.clone(), cap), 0..4 * n),
        )
            .prop_map(|(n, tlinks, edges)| Spec { n, tlinks, edges })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]
    #[test]
    fn proptest_matches_brute_force(spec in arb_spec()) {
        let mut g = spec.build();
        let f = g.maxflow();
        let side = segmentation(&g);
        let best = spec.brute_force_min_cut();
        prop_assert!(close(f, best, 1e-9), "flow {} vs brute force {}", f, best);
        prop_assert!(close(spec.cut_value(&side), f, 1e-9));
    }
}

/// Fixing a node to a side ([`Graph::fix`], which merges it into its
/// terminal before solving) gives the flow and the segmentation of the
/// same graph with an infinite t-link to that side. Integer capacities:
/// both flows are exact, and the smallest source side is unique.
#[test]
fn fixed_nodes_cut_as_infinite_terminal_links() {
    let mut rng = Lcg(99);
    for round in 0..400 {
        let n = 1 + rng.below(120) as usize;
        let spec = int_spec(&mut rng, n, [3, 100, 100_000][round % 3]);
        let share = rng.below(4); // none, a third, two thirds, all of the nodes
        let fixed: Vec<Option<Segment>> = (0..n)
            .map(|_| match rng.below(6) {
                k if k < 2 * share => Some(if rng.below(2) == 0 {
                    Segment::Source
                } else {
                    Segment::Sink
                }),
                _ => None,
            })
            .collect();
        let mut infinite = spec.clone();
        for (i, f) in fixed.iter().enumerate() {
            match f {
                Some(Segment::Source) => infinite.tlinks.push((i as u32, 1e30, 0.0)),
                Some(Segment::Sink) => infinite.tlinks.push((i as u32, 0.0, 1e30)),
                None => {}
            }
        }
        let (want, want_side) = solve_checked(&infinite, 0.0);
        let mut g = spec.build();
        for (i, f) in fixed.iter().enumerate() {
            if let Some(side) = f {
                g.fix(i as u32, *side);
            }
        }
        let got = g.maxflow();
        let side = segmentation(&g);
        assert_eq!(got, want, "round {round}: flow");
        assert_eq!(side, want_side, "round {round}: segmentation");
        for (i, f) in fixed.iter().enumerate() {
            if let Some(f) = f {
                assert_eq!(g.segment(i as u32), *f, "round {round}: node {i} left its side");
            }
        }
        // and the brute-force minimum over the cuts that keep the fixed sides
        if n <= 12 {
            let mut best = f64::INFINITY;
            for mask in 0u32..(1 << n) {
                let s: Vec<bool> = (0..n).map(|i| mask >> i & 1 == 1).collect();
                let keeps = fixed.iter().zip(&s).all(|(f, &s)| match f {
                    Some(Segment::Source) => s,
                    Some(Segment::Sink) => !s,
                    None => true,
                });
                if keeps {
                    best = best.min(spec.cut_value(&s));
                }
            }
            assert_eq!(got, best, "round {round}: brute force");
        }
    }
}
