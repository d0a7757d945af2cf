//! A chart candidate as a set of faces with local adjacency: growing, splitting
//! and the disk and cone tests (§ segmentation in the parent module).

use super::*;

/// A set of faces with adjacency in local indices ([`NONE`] across the
/// patch border).
pub(super) struct Patch {
    pub(super) faces: Vec<u32>,
    adj: Vec<[u32; 3]>,
}

impl Patch {
    pub(super) fn whole(ctx: &Ctx) -> Patch {
        let adj = ctx
            .adj
            .iter()
            .map(|a| a.map(|g| if g == NO_FACE { NONE } else { g }))
            .collect();
        Patch {
            faces: (0..ctx.adj.len() as u32).collect(),
            adj,
        }
    }

    /// `faces` must be sorted ascending.
    pub(super) fn new(ctx: &Ctx, faces: Vec<u32>) -> Patch {
        let adj = faces
            .iter()
            .map(|&f| {
                ctx.adj[f as usize].map(|g| {
                    if g == NO_FACE {
                        NONE
                    } else {
                        faces.binary_search(&g).map_or(NONE, |i| i as u32)
                    }
                })
            })
            .collect();
        Patch { faces, adj }
    }

    pub(super) fn len(&self) -> usize {
        self.faces.len()
    }

    pub(super) fn weight(&self, ctx: &Ctx, f: u32, i: usize) -> f64 {
        ctx.weight[self.faces[f as usize] as usize][i]
    }

    /// Grows one region per seed simultaneously (Dijkstra over the dual graph
    /// with the priority geodesic distance × (1 + k (1 − n·N)), N the region's
    /// current mean normal). With a cone limit a face joins only if n·N ≥ cos
    /// of the limit; faces nobody can take stay [`NONE`].
    pub(super) fn grow(&self, ctx: &Ctx, seeds: &[u32], cone: Option<f64>) -> Vec<u32> {
        let mut label = vec![NONE; self.len()];
        let mut sum = vec![DVec3::ZERO; seeds.len()];
        let mut mean = vec![DVec3::ZERO; seeds.len()];
        let mut heap = BinaryHeap::new();
        for (r, &s) in seeds.iter().enumerate() {
            heap.push(Reverse((0u64, s, r as u32, 0u64)));
        }
        while let Some(Reverse((_, f, r, d))) = heap.pop() {
            if label[f as usize] != NONE {
                continue;
            }
            let g = self.faces[f as usize] as usize;
            let n = ctx.normal[g];
            let ru = r as usize;
            if let Some(c) = cone {
                // faces without a normal (zero area) fit anywhere
                if sum[ru] != DVec3::ZERO && n != DVec3::ZERO && n.dot(mean[ru]) < c {
                    continue;
                }
            }
            label[f as usize] = r;
            let a = ctx.area[g].max(1e-300);
            sum[ru] += a * n;
            mean[ru] = dunit_or(sum[ru], DVec3::ZERO);
            let d = f64::from_bits(d);
            for i in 0..3 {
                let h = self.adj[f as usize][i];
                if h == NONE || label[h as usize] != NONE {
                    continue;
                }
                let dh = d + self.weight(ctx, f, i);
                let nh = ctx.normal[self.faces[h as usize] as usize];
                let prio = dh * (1.0 + NORMAL_PENALTY * (1.0 - nh.dot(mean[ru])));
                heap.push(Reverse((key(prio), h, r, dh.to_bits())));
            }
        }
        label
    }

    /// Connected components of equal-label faces: (component per face,
    /// count), components numbered in order of their smallest face.
    fn components(&self, label: &[u32]) -> (Vec<u32>, usize) {
        let mut comp = vec![NONE; self.len()];
        let mut count = 0u32;
        let mut stack = Vec::new();
        for s in 0..self.len() {
            if comp[s] != NONE {
                continue;
            }
            comp[s] = count;
            stack.push(s as u32);
            while let Some(f) = stack.pop() {
                for &h in &self.adj[f as usize] {
                    if h != NONE && comp[h as usize] == NONE && label[h as usize] == label[f as usize] {
                        comp[h as usize] = count;
                        stack.push(h);
                    }
                }
            }
            count += 1;
        }
        (comp, count as usize)
    }

    /// For every connected component of equal-label faces, the face farthest
    /// (dual geodesic distance) from the component's border, or its first
    /// face if it has no border. Returns (label, face) in component order.
    pub(super) fn centres(&self, ctx: &Ctx, label: &[u32]) -> Vec<(u32, u32)> {
        let (comp, count) = self.components(label);
        let mut d = vec![f64::INFINITY; self.len()];
        let mut heap = BinaryHeap::new();
        for f in 0..self.len() {
            for i in 0..3 {
                let h = self.adj[f][i];
                if h == NONE || label[h as usize] != label[f] {
                    // half the dual edge: distance to the border edge
                    let w = if h == NONE {
                        0.0
                    } else {
                        0.5 * self.weight(ctx, f as u32, i)
                    };
                    if w < d[f] {
                        d[f] = w;
                    }
                }
            }
            if d[f].is_finite() {
                heap.push(Reverse((key(d[f]), f as u32)));
            }
        }
        while let Some(Reverse((k, f))) = heap.pop() {
            if k != key(d[f as usize]) {
                continue;
            }
            for i in 0..3 {
                let h = self.adj[f as usize][i];
                if h == NONE || label[h as usize] != label[f as usize] {
                    continue;
                }
                let dh = d[f as usize] + self.weight(ctx, f, i);
                if dh < d[h as usize] {
                    d[h as usize] = dh;
                    heap.push(Reverse((key(dh), h)));
                }
            }
        }
        let mut best: Vec<Option<(f64, u32)>> = vec![None; count];
        for f in 0..self.len() {
            let c = comp[f] as usize;
            let df = if d[f].is_finite() { d[f] } else { -1.0 };
            if best[c].map_or(true, |(bd, _)| df > bd) {
                best[c] = Some((df, f as u32));
            }
        }
        best.into_iter()
            .map(|b| b.expect("component has a face").1)
            .map(|f| (label[f as usize], f))
            .collect()
    }

    /// The face farthest from `s` (dual geodesic distance within the patch).
    fn farthest_from(&self, ctx: &Ctx, s: u32) -> u32 {
        let mut d = vec![f64::INFINITY; self.len()];
        d[s as usize] = 0.0;
        let mut heap = BinaryHeap::new();
        heap.push(Reverse((0u64, s)));
        let mut far = (0.0, s);
        while let Some(Reverse((k, f))) = heap.pop() {
            let df = d[f as usize];
            if k != key(df) {
                continue;
            }
            if df > far.0 {
                far = (df, f);
            }
            for i in 0..3 {
                let h = self.adj[f as usize][i];
                if h == NONE {
                    continue;
                }
                let dh = df + self.weight(ctx, f, i);
                if dh < d[h as usize] {
                    d[h as usize] = dh;
                    heap.push(Reverse((key(dh), h)));
                }
            }
        }
        far.1
    }

    /// Whether the patch is a topological disk: connected, every vertex on
    /// at most one border fan (no pinch), and Euler characteristic 1.
    pub(super) fn is_disk(&self, ctx: &Ctx) -> bool {
        let (_, count) = self.components(&vec![0; self.len()]);
        if count != 1 {
            return false;
        }
        let mut verts: Vec<u32> = Vec::with_capacity(self.len() * 3);
        let mut border: Vec<u32> = Vec::new();
        let mut interior_half = 0usize;
        for (f, &g) in self.faces.iter().enumerate() {
            let t = ctx.mesh.triangles[g as usize];
            verts.extend_from_slice(&t);
            for i in 0..3 {
                if self.adj[f][i] == NONE {
                    border.push(t[i]);
                    border.push(t[(i + 1) % 3]);
                } else {
                    interior_half += 1;
                }
            }
        }
        if border.is_empty() {
            return false;
        }
        verts.sort_unstable();
        verts.dedup();
        border.sort_unstable();
        // a vertex on more than two border edges is a pinch
        if border.windows(3).any(|w| w[0] == w[2]) {
            return false;
        }
        let e = interior_half / 2 + border.len() / 2;
        verts.len() as i64 - e as i64 + self.len() as i64 == 1
    }

    /// Straightens the borders between the labels of the patch's faces: a
    /// face that meets its own region along at most one edge (the tip of a
    /// one-face-wide spike, a notch of a saw-toothed border, a lone face)
    /// moves to a region it meets along two edges, or, the tip of a spike
    /// between two regions, once to the one its normal is closer to — never
    /// across a crease (see [`CREASE_COS`]). A face meeting its own region
    /// along one edge is a leaf of it, so no region comes apart, and a
    /// region keeps its last face; each move to a region met along two
    /// edges shortens the border, so the sweeps end.
    pub(super) fn straighten(&self, ctx: &Ctx, label: &mut [u32]) {
        let mut tipped = vec![false; label.len()];
        // faces per label: a region's last face stays (a split stays a split)
        let labels = label
            .iter()
            .filter(|&&l| l != NONE)
            .max()
            .map_or(0, |&l| l as usize + 1);
        let mut count = vec![0usize; labels];
        for &l in label.iter().filter(|&&l| l != NONE) {
            count[l as usize] += 1;
        }
        loop {
            let mut moved = false;
            for f in 0..label.len() {
                let own = label[f];
                if own == NONE || count[own as usize] == 1 {
                    continue;
                }
                let mut others = [NONE; 3];
                let mut same = 0;
                for (i, &g) in self.adj[f].iter().enumerate() {
                    if g == NONE || label[g as usize] == NONE {
                        continue;
                    }
                    let l = label[g as usize];
                    if l == own {
                        same += 1;
                    } else {
                        others[i] = l;
                    }
                }
                if same > 1 {
                    continue;
                }
                // the least bend (cosine) from this face to a neighbour in `l`
                let normal = |f: u32| ctx.normal[self.faces[f as usize] as usize];
                let n = normal(f as u32);
                let bend = |l: u32| {
                    self.adj[f]
                        .iter()
                        .filter(|&&g| g != NONE && label[g as usize] == l)
                        .map(|&g| n.dot(normal(g)))
                        .fold(f64::INFINITY, f64::min)
                };
                let met = |l: u32| others.iter().filter(|&&m| m == l).count();
                let to = match others.iter().copied().find(|&l| l != NONE && met(l) >= 2) {
                    Some(l) => l,
                    None if same == 1 && !tipped[f] && others.iter().filter(|&&l| l != NONE).count() == 2 => {
                        // a spike's tip between two regions
                        let mut two = others.iter().copied().filter(|&l| l != NONE);
                        let (a, b) = (two.next().unwrap_or(NONE), two.next().unwrap_or(NONE));
                        tipped[f] = true;
                        if bend(b) > bend(a) {
                            b
                        } else {
                            a
                        }
                    }
                    None => continue,
                };
                // not across a crease: the face bends by less than
                // CREASE towards the region, or no more than towards its own
                if same == 0 || bend(to) >= CREASE_COS.min(bend(own)) {
                    count[own as usize] -= 1;
                    count[to as usize] += 1;
                    label[f] = to;
                    moved = true;
                }
            }
            if !moved {
                break;
            }
        }
    }

    /// Splits the patch in two by growing from the two faces farthest apart.
    pub(super) fn split_in_two(&self, ctx: &Ctx) -> Vec<Vec<u32>> {
        let a = self.farthest_from(ctx, 0);
        let mut b = self.farthest_from(ctx, a);
        if b == a {
            b = if a == 0 { 1 } else { 0 };
        }
        let mut label = self.grow(ctx, &[a, b], None);
        self.straighten(ctx, &mut label);
        let mut parts = vec![Vec::new(), Vec::new()];
        let mut rest = Vec::new();
        for (f, &l) in label.iter().enumerate() {
            match l {
                0 | 1 => parts[l as usize].push(self.faces[f]),
                _ => rest.push(self.faces[f]), // unreachable from both seeds
            }
        }
        if !rest.is_empty() {
            parts.push(rest);
        }
        parts
    }

    /// Faces grouped by component, in global ids.
    pub(super) fn split_components(&self) -> Vec<Vec<u32>> {
        let (comp, count) = self.components(&vec![0; self.len()]);
        let mut parts = vec![Vec::new(); count];
        for (f, &c) in comp.iter().enumerate() {
            parts[c as usize].push(self.faces[f]);
        }
        parts
    }
}
