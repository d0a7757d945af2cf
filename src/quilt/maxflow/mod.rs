//! Minimum s–t cut / maximum flow by the Boykov–Kolmogorov algorithm.
//!
//! Written from the algorithm description in Y. Boykov, V. Kolmogorov, "An
//! Experimental Comparison of Min-Cut/Max-Flow Algorithms for Energy
//! Minimization in Vision", IEEE PAMI 26(9), 2004: two search trees `S` and
//! `T` are grown from the terminals (growth stage, FIFO queue of active
//! nodes); when they touch, flow is pushed along the found s→t path
//! (augmentation stage) and the nodes below saturated tree edges become
//! orphans, which then look for a new parent in their own tree or are freed
//! (adoption stage). Origin checks in the adoption stage use the paper's
//! timestamp/distance marks, and the growth stage uses the same marks to keep
//! the trees shallow.
//!
//! This is the solver behind graphcut texture synthesis (Kwatra et al. 2003):
//! pixel grids with 4-neighbour edges, terminal links on the overlap borders,
//! and "seam nodes" on old seams.
//!
//! # Layout
//!
//! Everything is a flat array indexed by `u32`. Arcs are stored in pairs: arc
//! `2k` and arc `2k + 1` are each other's reverse (`rev = a ^ 1`), so an arc
//! only stores its head and its residual capacity; its tail is the head of its
//! reverse. Per-node adjacency is a CSR index built once when solving. The
//! two terminal links of a node are folded into one signed residual `tr_cap`
//! (positive: residual capacity from the source, negative: to the sink), as in
//! the paper's t-link formulation.
//!
//! # Floating point
//!
//! Capacities are `f64`. A residual capacity `≤ eps` counts as saturated,
//! where `eps = 1e-12 · (largest edge capacity)`; if the graph has no positive
//! edge capacity the largest finite terminal capacity is used instead. Terminal
//! capacities are deliberately left out of the scale when there are edges, so
//! that "infinite-ish" terminal capacities (1e9, 1e30, even `f64::INFINITY`)
//! used to tie border pixels to a terminal do not wash out the seam costs. The
//! flow value and the cut capacity therefore agree up to about `eps` per
//! saturated arc.

/// Parent sentinel: the node is free (in no tree).
const NONE: u32 = u32::MAX;
/// Parent sentinel: the node's parent is its terminal.
const TERMINAL: u32 = u32::MAX - 1;
/// Parent sentinel: the node lost its parent and waits for adoption.
const ORPHAN: u32 = u32::MAX - 2;
/// Largest number of arcs (and nodes): indices must stay below the sentinels.
const MAX_INDEX: usize = (u32::MAX - 3) as usize;

/// Tree tags.
const FREE: u8 = 0;
const TREE_S: u8 = 1;
const TREE_T: u8 = 2;

/// A flow network with two terminals, built incrementally, solved once.
///
/// Nodes are `0..node_count()`. Capacities must be non-negative; edge
/// capacities must be finite, terminal capacities may be `f64::INFINITY` as
/// long as no s→t path consists of infinite capacities only (the flow would be
/// infinite; the solver still terminates but the result is unspecified).
/// Negative or NaN capacities are a programmer error: they trip a
/// `debug_assert!` and are clamped to zero in release builds.
///
/// # Panics
///
/// Programmer errors panic: a node index out of range, more than about
/// 4·10⁹ nodes or arcs, adding nodes/edges/t-links after [`Graph::maxflow`],
/// and asking for a [`Graph::segment`] before [`Graph::maxflow`].
#[derive(Clone, Debug, Default)]
pub struct Graph {
    /// Signed terminal residual per node: `> 0` from the source, `< 0` to the sink.
    tr_cap: Vec<f64>,
    /// Head node of each arc; the tail of arc `a` is `head[a ^ 1]`.
    head: Vec<u32>,
    /// Residual capacity of each arc.
    r_cap: Vec<f64>,
    /// The constant part of the flow (from combining t-links) plus, after
    /// solving, the augmented flow.
    flow: f64,
    /// Tree tag per node after solving (empty before).
    tree: Vec<u8>,
    /// Per node: `FREE`, or the terminal it is tied to ([`Graph::fix`]);
    /// empty while no node is fixed.
    fixed: Vec<u8>,
    solved: bool,
}

/// The side of the minimum cut a node ends up on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Segment {
    /// Reachable from the source in the final residual graph.
    Source,
    /// Everything else (including nodes reached by neither search tree).
    Sink,
}

impl Graph {
    /// A graph with `nodes` nodes (indices `0..nodes`) and room for
    /// `edges_hint` calls to [`Graph::add_edge`] without reallocating.
    pub fn new(nodes: usize, edges_hint: usize) -> Graph {
        assert!(nodes <= MAX_INDEX, "maxflow::Graph: too many nodes ({nodes})");
        Graph {
            tr_cap: vec![0.0; nodes],
            head: Vec::with_capacity(2 * edges_hint),
            r_cap: Vec::with_capacity(2 * edges_hint),
            flow: 0.0,
            tree: Vec::new(),
            fixed: Vec::new(),
            solved: false,
        }
    }

    /// Adds a node without terminal links and returns its index.
    pub fn add_node(&mut self) -> u32 {
        assert!(!self.solved, "maxflow::Graph::add_node after maxflow");
        let i = self.tr_cap.len();
        assert!(i < MAX_INDEX, "maxflow::Graph: too many nodes");
        self.tr_cap.push(0.0);
        i as u32
    }

    /// The number of nodes (terminals not counted).
    pub fn node_count(&self) -> usize {
        self.tr_cap.len()
    }

    /// Terminal capacities: adds `source` to the s→node capacity and `sink` to
    /// node→t (both ≥ 0). They are combined as in the paper: the smaller of the
    /// two (after adding to what the node already has) is subtracted from both
    /// and added to the flow constant, leaving one signed residual per node.
    /// May be called several times for the same node.
    pub fn add_tweights(&mut self, node: u32, source: f64, sink: f64) {
        assert!(!self.solved, "maxflow::Graph::add_tweights after maxflow");
        debug_assert!(
            (node as usize) < self.tr_cap.len(),
            "maxflow: node {node} out of range"
        );
        debug_assert!(
            source >= 0.0 && sink >= 0.0,
            "maxflow: negative or NaN t-link ({source}, {sink})"
        );
        // `max` also maps NaN to 0.
        let (mut s, mut t) = (source.max(0.0), sink.max(0.0));
        let d = self.tr_cap[node as usize];
        if d > 0.0 {
            s += d;
        } else {
            t -= d;
        }
        let m = s.min(t);
        self.flow += m;
        // `s - t` directly (not `(s - m) - (t - m)`), which is also right when one side is infinite.
        self.tr_cap[node as usize] = if s == t { 0.0 } else { s - t };
    }

    /// Ties `node` to one side of the cut, as an infinite t-link to that
    /// terminal would, but cheaper: [`Graph::maxflow`] merges fixed nodes
    /// into their terminals (an edge to a fixed node becomes a t-link of
    /// the other end) and searches the free nodes alone. The flow and the
    /// segmentation equal those with the infinite t-link, up to the order
    /// of floating-point sums. The node's finite t-links still count: the
    /// one to the other terminal is cut.
    pub fn fix(&mut self, node: u32, side: Segment) {
        assert!(!self.solved, "maxflow::Graph::fix after maxflow");
        let n = self.tr_cap.len();
        assert!(
            (node as usize) < n,
            "maxflow: node {node} out of range ({n} nodes)"
        );
        self.fixed.resize(n, FREE);
        self.fixed[node as usize] = match side {
            Segment::Source => TREE_S,
            Segment::Sink => TREE_T,
        };
    }

    /// An edge pair between two nodes: capacity `cap` from `a` to `b` and
    /// `rev_cap` from `b` to `a` (both ≥ 0, finite). Parallel edges add up;
    /// self-loops are allowed and have no effect.
    pub fn add_edge(&mut self, a: u32, b: u32, cap: f64, rev_cap: f64) {
        assert!(!self.solved, "maxflow::Graph::add_edge after maxflow");
        let n = self.tr_cap.len();
        assert!(
            (a as usize) < n && (b as usize) < n,
            "maxflow: edge ({a}, {b}) out of range ({n} nodes)"
        );
        debug_assert!(
            cap >= 0.0 && rev_cap >= 0.0 && cap.is_finite() && rev_cap.is_finite(),
            "maxflow: bad edge capacity ({cap}, {rev_cap})"
        );
        assert!(self.head.len() + 2 <= MAX_INDEX, "maxflow::Graph: too many arcs");
        let clamp = |c: f64| if c.is_finite() { c.max(0.0) } else { 0.0 };
        // arc 2k: a -> b, arc 2k+1: b -> a
        self.head.push(b);
        self.r_cap.push(clamp(cap));
        self.head.push(a);
        self.r_cap.push(clamp(rev_cap));
    }

    /// Runs Boykov–Kolmogorov; returns the max-flow value, including the
    /// constant part from [`Graph::add_tweights`]. Calling it again returns the
    /// same value without further work.
    pub fn maxflow(&mut self) -> f64 {
        if !self.solved {
            self.solved = true;
            let scale = self.scale();
            if self.fixed.iter().any(|&f| f != FREE) {
                self.fixed.resize(self.tr_cap.len(), FREE);
                let (mut free, index) = self.contract();
                free.tree = Solver::new(&mut free, scale).run();
                let mut tree = std::mem::take(&mut self.fixed);
                for (i, t) in tree.iter_mut().enumerate() {
                    if *t == FREE {
                        *t = free.tree[index[i] as usize];
                    }
                }
                self.flow = free.flow;
                self.tree = tree;
            } else {
                let tree = Solver::new(self, scale).run();
                self.tree = tree;
            }
        }
        self.flow
    }

    /// The capacity that sets the solver's saturation tolerance: the largest
    /// edge capacity, or without edges the largest finite terminal one.
    fn scale(&self) -> f64 {
        let max_edge = self.r_cap.iter().fold(0.0f64, |acc, &c| acc.max(c));
        if max_edge > 0.0 {
            max_edge
        } else {
            self.tr_cap
                .iter()
                .filter(|c| c.is_finite())
                .fold(0.0f64, |acc, &c| acc.max(c.abs()))
        }
    }

    /// The graph over the free nodes alone (in order), with the fixed ones
    /// merged into their terminals, and each node's index in it. Consumes
    /// this graph's arcs.
    fn contract(&mut self) -> (Graph, Vec<u32>) {
        let mut index = vec![NONE; self.tr_cap.len()];
        let mut free = Graph::default();
        free.flow = self.flow;
        for (i, &f) in self.fixed.iter().enumerate() {
            let c = self.tr_cap[i];
            match f {
                FREE => {
                    index[i] = free.tr_cap.len() as u32;
                    free.tr_cap.push(c);
                }
                // the t-link to the other terminal is cut
                TREE_S => free.flow += (-c).max(0.0),
                _ => free.flow += c.max(0.0),
            }
        }
        let (head, r_cap) = (std::mem::take(&mut self.head), std::mem::take(&mut self.r_cap));
        for k in 0..head.len() / 2 {
            // arc 2k: a -> b, arc 2k + 1: b -> a
            let (a, b) = (head[2 * k + 1] as usize, head[2 * k] as usize);
            let (ab, ba) = (r_cap[2 * k], r_cap[2 * k + 1]);
            match (self.fixed[a], self.fixed[b]) {
                (FREE, FREE) => free.add_edge(index[a], index[b], ab, ba),
                (FREE, side) => tie(&mut free, index[a], side, ab, ba),
                (side, FREE) => tie(&mut free, index[b], side, ba, ab),
                (TREE_S, TREE_T) => free.flow += ab,
                (TREE_T, TREE_S) => free.flow += ba,
                _ => {}
            }
        }
        (free, index)
    }

    /// After [`Graph::maxflow`]: which side of the minimum cut the node is on.
    ///
    /// `Source` exactly for the nodes in the final source tree, i.e. those
    /// reachable from the source in the residual graph; nodes in the sink tree
    /// and nodes reached by neither tree are `Sink`. This is the minimum cut
    /// with the smallest source side.
    pub fn segment(&self, node: u32) -> Segment {
        assert!(self.solved, "maxflow::Graph::segment before maxflow");
        if self.tree[node as usize] == TREE_S {
            Segment::Source
        } else {
            Segment::Sink
        }
    }
}

/// An edge between free `node` and a node fixed to `side`, with capacity
/// `out` from `node` and `back` into it, as a t-link of `node`: to the sink
/// (`out`) or from the source (`back`).
fn tie(g: &mut Graph, node: u32, side: u8, out: f64, back: f64) {
    if side == TREE_T {
        g.add_tweights(node, 0.0, out);
    } else {
        g.add_tweights(node, back, 0.0);
    }
}

/// The working state of one solve. Borrows the graph's residuals and owns the
/// per-node search state; only the tree tags survive the solve.
struct Solver<'g> {
    head: &'g [u32],
    r_cap: &'g mut [f64],
    tr_cap: &'g mut [f64],
    flow: &'g mut f64,
    /// CSR: the arcs leaving node `i` are `adj[adj_start[i]..adj_start[i + 1]]`.
    adj_start: Vec<u32>,
    adj: Vec<u32>,
    /// Arc from the node to its tree parent, or `NONE` / `TERMINAL` / `ORPHAN`.
    parent: Vec<u32>,
    tree: Vec<u8>,
    /// Timestamp and distance-to-terminal marks (valid when `ts == time`).
    ts: Vec<u32>,
    dist: Vec<u32>,
    in_queue: Vec<bool>,
    /// FIFO of active nodes; freed nodes are dropped lazily when they reach the front.
    active: std::collections::VecDeque<u32>,
    /// Orphans of the current adoption stage (FIFO via `orphan_next`).
    orphans: Vec<u32>,
    /// The augmenting path of [`Solver::augment`]: (node, parent arc).
    path: Vec<(u32, u32)>,
    time: u32,
    eps: f64,
}

impl<'g> Solver<'g> {
    /// A solve of `g` where residuals `≤ 1e-12 · scale` count as saturated.
    fn new(g: &'g mut Graph, scale: f64) -> Solver<'g> {
        let n = g.tr_cap.len();
        let m = g.head.len();
        // CSR adjacency: out-degree counts, prefix sums, fill in arc order.
        let mut adj_start = vec![0u32; n + 1];
        for a in 0..m {
            adj_start[g.head[a ^ 1] as usize + 1] += 1;
        }
        for i in 0..n {
            adj_start[i + 1] += adj_start[i];
        }
        let mut fill: Vec<u32> = adj_start[..n].to_vec();
        let mut adj = vec![0u32; m];
        for a in 0..m {
            let tail = g.head[a ^ 1] as usize;
            adj[fill[tail] as usize] = a as u32;
            fill[tail] += 1;
        }
        drop(fill);
        let eps = 1e-12 * scale;

        Solver {
            head: &g.head,
            r_cap: &mut g.r_cap,
            tr_cap: &mut g.tr_cap,
            flow: &mut g.flow,
            adj_start,
            adj,
            parent: vec![NONE; n],
            tree: vec![FREE; n],
            ts: vec![0; n],
            dist: vec![0; n],
            in_queue: vec![false; n],
            active: std::collections::VecDeque::with_capacity(n),
            orphans: Vec::new(),
            path: Vec::new(),
            time: 0,
            eps,
        }
    }

    #[inline]
    fn activate(&mut self, i: u32) {
        if !self.in_queue[i as usize] {
            self.in_queue[i as usize] = true;
            self.active.push_back(i);
        }
    }

    #[inline]
    fn arcs(&self, i: u32) -> std::ops::Range<usize> {
        self.adj_start[i as usize] as usize..self.adj_start[i as usize + 1] as usize
    }

    fn run(mut self) -> Vec<u8> {
        let n = self.tr_cap.len();
        for i in 0..n {
            let c = self.tr_cap[i];
            let t = if c > self.eps {
                TREE_S
            } else if c < -self.eps {
                TREE_T
            } else {
                continue;
            };
            self.tree[i] = t;
            self.parent[i] = TERMINAL;
            self.dist[i] = 1;
            self.activate(i as u32);
        }
        while let Some(mid) = self.grow() {
            // A new timestamp per augmentation: marks from earlier stages are stale.
            self.time += 1;
            self.augment(mid);
            self.adopt();
        }
        self.tree
    }

    /// Growth stage. Returns the arc (tail in S, head in T) joining the trees,
    /// or `None` when no active node is left (the flow is maximum). The node
    /// that found the path stays at the front of the queue.
    fn grow(&mut self) -> Option<u32> {
        let eps = self.eps;
        while let Some(&p) = self.active.front() {
            let tp = self.tree[p as usize];
            if tp != FREE {
                for k in self.arcs(p) {
                    let a = self.adj[k];
                    // Residual capacity in the direction the tree grows.
                    let cap = if tp == TREE_S {
                        self.r_cap[a as usize]
                    } else {
                        self.r_cap[(a ^ 1) as usize]
                    };
                    if cap <= eps {
                        continue;
                    }
                    let q = self.head[a as usize] as usize;
                    let tq = self.tree[q];
                    if tq == FREE {
                        self.tree[q] = tp;
                        self.parent[q] = a ^ 1;
                        self.ts[q] = self.ts[p as usize];
                        self.dist[q] = self.dist[p as usize] + 1;
                        self.activate(q as u32);
                    } else if tq != tp {
                        return Some(if tp == TREE_S { a } else { a ^ 1 });
                    } else if self.ts[q] <= self.ts[p as usize] && self.dist[q] > self.dist[p as usize] {
                        // q is in p's tree but p is a fresher, closer way to the
                        // terminal: reparent q under p (cannot make a cycle, see
                        // `dist` invariant in the module tests).
                        self.parent[q] = a ^ 1;
                        self.ts[q] = self.ts[p as usize];
                        self.dist[q] = self.dist[p as usize] + 1;
                    }
                }
            }
            self.active.pop_front();
            self.in_queue[p as usize] = false;
        }
        None
    }

    /// Augmentation stage: push the bottleneck along the path through `mid`;
    /// nodes whose tree edge saturates become orphans.
    fn augment(&mut self, mid: u32) {
        let eps = self.eps;
        let head = self.head;
        let mid = mid as usize;
        let sp = head[mid ^ 1];
        let tq = head[mid];

        // Bottleneck, noting the path (node, parent arc) from `sp` up to the
        // source side's root, then from `tq` up to the sink side's root, so
        // that the push walks a list instead of the trees again.
        let mut f = self.r_cap[mid];
        let path = &mut self.path;
        path.clear();
        let mut i = sp as usize;
        loop {
            let pa = self.parent[i];
            if pa == TERMINAL {
                break;
            }
            // Flow goes parent -> i, on the reverse of the parent arc.
            f = f.min(self.r_cap[(pa ^ 1) as usize]);
            path.push((i as u32, pa));
            i = head[pa as usize] as usize;
        }
        let s_root = i;
        let s_len = path.len();
        f = f.min(self.tr_cap[i]);
        let mut i = tq as usize;
        loop {
            let pa = self.parent[i];
            if pa == TERMINAL {
                break;
            }
            f = f.min(self.r_cap[pa as usize]);
            path.push((i as u32, pa));
            i = head[pa as usize] as usize;
        }
        let t_root = i;
        f = f.min(-self.tr_cap[i]);

        // Push.
        self.r_cap[mid] -= f;
        self.r_cap[mid ^ 1] += f;
        for &(i, pa) in &self.path[..s_len] {
            let pa = pa as usize;
            self.r_cap[pa] += f;
            self.r_cap[pa ^ 1] -= f;
            if self.r_cap[pa ^ 1] <= eps {
                self.parent[i as usize] = ORPHAN;
                self.orphans.push(i);
            }
        }
        let i = s_root;
        self.tr_cap[i] -= f;
        if self.tr_cap[i] <= eps {
            self.parent[i] = ORPHAN;
            self.orphans.push(i as u32);
        }
        for &(i, pa) in &self.path[s_len..] {
            let pa = pa as usize;
            self.r_cap[pa] -= f;
            self.r_cap[pa ^ 1] += f;
            if self.r_cap[pa] <= eps {
                self.parent[i as usize] = ORPHAN;
                self.orphans.push(i);
            }
        }
        let i = t_root;
        self.tr_cap[i] += f;
        if self.tr_cap[i] >= -eps {
            self.parent[i] = ORPHAN;
            self.orphans.push(i as u32);
        }
        *self.flow += f;
    }

    /// Adoption stage: every orphan finds a new parent in its own tree whose
    /// origin is a terminal, or becomes free (its children become orphans and
    /// its tree neighbours that could regrow into it become active).
    fn adopt(&mut self) {
        let mut next = 0;
        while next < self.orphans.len() {
            let p = self.orphans[next];
            next += 1;
            self.adopt_one(p);
        }
        self.orphans.clear();
    }

    fn adopt_one(&mut self, p: u32) {
        let eps = self.eps;
        let time = self.time;
        let pi = p as usize;
        let tp = self.tree[pi];
        // Still (or again) linked to its terminal: never the case after a
        // t-link saturates, kept as a cheap safety net.
        if (tp == TREE_S && self.tr_cap[pi] > eps) || (tp == TREE_T && self.tr_cap[pi] < -eps) {
            self.parent[pi] = TERMINAL;
            self.ts[pi] = time;
            self.dist[pi] = 1;
            return;
        }
        let mut best = NONE;
        let mut best_d = u32::MAX;
        for k in self.arcs(p) {
            let a = self.adj[k] as usize;
            let q = self.head[a] as usize;
            if self.tree[q] != tp {
                continue;
            }
            // Residual from q towards p in the tree's direction.
            let cap = if tp == TREE_S {
                self.r_cap[a ^ 1]
            } else {
                self.r_cap[a]
            };
            if cap <= eps {
                continue;
            }
            // Origin check: walk up from q until a terminal, an orphan, or a
            // node already verified in this stage.
            let mut j = q;
            let mut d = 0u32;
            let valid = loop {
                if self.ts[j] == time {
                    d += self.dist[j];
                    break true;
                }
                let pa = self.parent[j];
                d += 1;
                if pa == TERMINAL {
                    self.ts[j] = time;
                    self.dist[j] = 1;
                    break true;
                }
                if pa == ORPHAN || pa == NONE {
                    break false;
                }
                j = self.head[pa as usize] as usize;
            };
            if valid {
                if d < best_d {
                    best = a as u32;
                    best_d = d;
                }
                // Stamp the verified path with exact distances.
                let mut j = q;
                while self.ts[j] != time {
                    self.ts[j] = time;
                    self.dist[j] = d;
                    d -= 1;
                    j = self.head[self.parent[j] as usize] as usize;
                }
            }
        }
        if best != NONE {
            self.parent[pi] = best;
            self.ts[pi] = time;
            self.dist[pi] = best_d + 1;
            return;
        }
        // No valid parent: p becomes free.
        for k in self.arcs(p) {
            let a = self.adj[k] as usize;
            let q = self.head[a] as usize;
            if self.tree[q] != tp || q == pi {
                continue;
            }
            let cap = if tp == TREE_S {
                self.r_cap[a ^ 1]
            } else {
                self.r_cap[a]
            };
            if cap > eps {
                self.activate(q as u32);
            }
            let pa = self.parent[q];
            if pa < ORPHAN && self.head[pa as usize] == p {
                self.parent[q] = ORPHAN;
                self.orphans.push(q as u32);
            }
        }
        self.tree[pi] = FREE;
        self.parent[pi] = NONE;
    }
}

#[cfg(test)]
mod tests;
