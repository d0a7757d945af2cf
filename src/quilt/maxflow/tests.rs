use super::*;

fn lcg(state: &mut u64) -> u64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    *state >> 33
}

/// Checks, on the residual state left by a solve, that the flow respects
/// capacities, is conserved at every node, has the reported value, and that
/// the source side is closed under residual arcs (so the cut is minimum).
fn check_residual(g: &Graph, caps: &[f64], tw: &[(f64, f64)]) {
    let n = g.node_count();
    let tol = 1e-9 * (1.0 + g.flow.abs());
    let mut excess = vec![0.0f64; n];
    for k in 0..caps.len() / 2 {
        let (a, b) = (g.head[2 * k + 1] as usize, g.head[2 * k] as usize);
        // Net flow a -> b.
        let f = caps[2 * k] - g.r_cap[2 * k];
        assert!((caps[2 * k] + caps[2 * k + 1] - g.r_cap[2 * k] - g.r_cap[2 * k + 1]).abs() <= tol);
        assert!(g.r_cap[2 * k] >= 0.0 && g.r_cap[2 * k + 1] >= 0.0);
        excess[a] -= f;
        excess[b] += f;
    }
    let mut from_s = 0.0;
    for i in 0..n {
        // Flow from the terminals into i: (s - t) originally, minus what is left.
        let (s, t) = tw[i];
        let m = s.min(t);
        let net_in = (s - m) - (t - m) - g.tr_cap[i];
        from_s += (s - m) - g.tr_cap[i].max(0.0);
        assert!((excess[i] + net_in).abs() <= tol, "conservation at {i}");
    }
    let constant: f64 = tw.iter().map(|&(s, t)| s.min(t)).sum();
    assert!(
        (constant + from_s - g.flow).abs() <= tol,
        "{} vs {}",
        constant + from_s,
        g.flow
    );
    // Closure: no residual arc leaves the source side, no residual t-link enters the sink side.
    for a in 0..g.head.len() {
        let (u, v) = (g.head[a ^ 1], g.head[a]);
        if g.segment(u) == Segment::Source && g.segment(v) == Segment::Sink {
            assert!(g.r_cap[a] <= 1e-9, "residual arc {a} crosses the cut");
        }
    }
    for i in 0..n {
        if g.segment(i as u32) == Segment::Sink {
            assert!(
                g.tr_cap[i] <= 1e-9,
                "node {i} has residual from the source but is Sink"
            );
        } else {
            assert!(
                g.tr_cap[i] >= -1e-9,
                "node {i} has residual to the sink but is Source"
            );
        }
    }
}

#[test]
fn residual_state_is_a_maximum_flow() {
    let mut seed = 7u64;
    for round in 0..400 {
        let n = 1 + (lcg(&mut seed) % 60) as usize;
        let m = (lcg(&mut seed) % (4 * n as u64 + 1)) as usize;
        let mut g = Graph::new(n, m);
        let mut tw = vec![(0.0, 0.0); n];
        for (i, w) in tw.iter_mut().enumerate() {
            let r = lcg(&mut seed) % 4;
            let v = (lcg(&mut seed) % 1000) as f64 / 100.0;
            *w = match r {
                0 => (v, 0.0),
                1 => (0.0, v),
                2 => (v, (lcg(&mut seed) % 1000) as f64 / 100.0),
                _ => (0.0, 0.0),
            };
            g.add_tweights(i as u32, w.0, w.1);
        }
        let mut caps = Vec::new();
        for _ in 0..m {
            let a = (lcg(&mut seed) % n as u64) as u32;
            let b = (lcg(&mut seed) % n as u64) as u32;
            let c = (lcg(&mut seed) % 1000) as f64 / 37.0;
            let r = if round % 2 == 0 {
                (lcg(&mut seed) % 1000) as f64 / 37.0
            } else {
                0.0
            };
            g.add_edge(a, b, c, r);
            caps.push(c);
            caps.push(r);
        }
        g.maxflow();
        check_residual(&g, &caps, &tw);
    }
}

/// The growth-stage reparenting relies on: along every tree edge j -> parent
/// k, `ts[k] > ts[j]` or (`ts[k] == ts[j]` and `dist[k] < dist[j]`). Check it
/// after every stage on random graphs.
#[test]
fn tree_marks_are_monotone_towards_the_root() {
    let mut seed = 99u64;
    for _ in 0..200 {
        let n = 2 + (lcg(&mut seed) % 40) as usize;
        let mut g = Graph::new(n, 3 * n);
        for i in 0..n {
            let v = (lcg(&mut seed) % 20) as f64;
            match lcg(&mut seed) % 3 {
                0 => g.add_tweights(i as u32, v, 0.0),
                1 => g.add_tweights(i as u32, 0.0, v),
                _ => {}
            }
        }
        for _ in 0..3 * n {
            let a = (lcg(&mut seed) % n as u64) as u32;
            let b = (lcg(&mut seed) % n as u64) as u32;
            g.add_edge(a, b, (lcg(&mut seed) % 10) as f64, (lcg(&mut seed) % 10) as f64);
        }
        let scale = g.scale();
        let mut s = Solver::new(&mut g, scale);
        for i in 0..n {
            let c = s.tr_cap[i];
            let t = if c > s.eps {
                TREE_S
            } else if c < -s.eps {
                TREE_T
            } else {
                continue;
            };
            s.tree[i] = t;
            s.parent[i] = TERMINAL;
            s.dist[i] = 1;
            s.activate(i as u32);
        }
        let check = |s: &Solver| {
            for j in 0..n {
                let pa = s.parent[j];
                assert_ne!(pa, ORPHAN);
                assert_eq!(pa == NONE, s.tree[j] == FREE);
                if pa < ORPHAN {
                    let k = s.head[pa as usize] as usize;
                    assert_eq!(s.tree[k], s.tree[j]);
                    assert!(s.ts[k] > s.ts[j] || (s.ts[k] == s.ts[j] && s.dist[k] < s.dist[j]));
                }
            }
        };
        while let Some(mid) = s.grow() {
            check(&s);
            s.time += 1;
            s.augment(mid);
            s.adopt();
            check(&s);
        }
    }
}
