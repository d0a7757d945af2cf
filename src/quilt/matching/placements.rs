//! The result of a match: every placement's cost ([`CostMap`]) and the
//! choice among the best ones.

/// A placement: sample pixel (x − dx, y − dy) lands on work pixel (x, y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub dx: i32,
    pub dy: i32,
    /// SSD / overlap (features + w · constraint).
    pub cost: f64,
    /// Σ M V over the overlap.
    pub overlap: f64,
}

impl Placement {
    /// Deterministic order: cost, then dy, then dx.
    fn order(&self, other: &Placement) -> std::cmp::Ordering {
        self.cost
            .total_cmp(&other.cost)
            .then(self.dy.cmp(&other.dy))
            .then(self.dx.cmp(&other.dx))
    }
}

/// Cost and overlap of every placement, `[dy − dy0][dx − dx0]`. The cost is
/// +∞ where the overlap is below the minimum.
#[derive(Clone, Debug, PartialEq)]
pub struct CostMap {
    pub dx0: i32,
    pub dy0: i32,
    /// Number of dx values.
    pub columns: usize,
    /// Number of dy values.
    pub rows: usize,
    pub cost: Vec<f64>,
    pub overlap: Vec<f64>,
}

impl CostMap {
    /// (cost, overlap) of placement (dx, dy), if it is in the map.
    pub fn get(&self, dx: i32, dy: i32) -> Option<(f64, f64)> {
        let (c, r) = (dx - self.dx0, dy - self.dy0);
        if c < 0 || r < 0 || c as usize >= self.columns || r as usize >= self.rows {
            return None;
        }
        let i = r as usize * self.columns + c as usize;
        Some((self.cost[i], self.overlap[i]))
    }

    /// All placements with a finite cost, unordered.
    pub fn placements(&self) -> impl Iterator<Item = Placement> + '_ {
        (0..self.rows * self.columns)
            .filter(|&i| self.cost[i].is_finite())
            .map(|i| Placement {
                dx: self.dx0 + (i % self.columns) as i32,
                dy: self.dy0 + (i / self.columns) as i32,
                cost: self.cost[i],
                overlap: self.overlap[i],
            })
    }

    /// The best placements in (cost, dy, dx) order: at most `candidates`
    /// (0 = all) of those with cost ≤ (1 + tolerance) · best.
    pub fn best(&self, candidates: usize, tolerance: f64) -> Vec<Placement> {
        best_of(self.placements().collect(), candidates, tolerance)
    }
}

/// [`CostMap::best`] of a list of distinct placements (in any order; those
/// of cost +∞ are left out).
pub fn best_of(mut all: Vec<Placement>, candidates: usize, tolerance: f64) -> Vec<Placement> {
    all.retain(|p| p.cost.is_finite());
    if candidates > 0 && candidates < all.len() {
        all.select_nth_unstable_by(candidates - 1, Placement::order);
        all.truncate(candidates);
    }
    all.sort_unstable_by(Placement::order);
    if let Some(best) = all.first().map(|p| p.cost) {
        let limit = near_limit(best, tolerance);
        all.retain(|p| p.cost <= limit);
    }
    all
}

/// The near-minimal bound: cost ≤ best + tolerance · |best| (all when the
/// tolerance is infinite).
pub(in crate::quilt) fn near_limit(best: f64, tolerance: f64) -> f64 {
    if tolerance == f64::INFINITY {
        f64::INFINITY
    } else {
        best + tolerance.max(0.0) * best.abs()
    }
}

/// Seeded choice among near-minimal placements (Kwatra et al.: a random pick
/// among good matches avoids visible repetition): uniform among the entries
/// of `placements` with cost ≤ (1 + tolerance) · min cost, in slice order,
/// indexed by a hash of (seed, counter). A pure function; `None` if no
/// placement has a finite cost.
pub fn choose(placements: &[Placement], tolerance: f64, seed: u64, counter: u64) -> Option<Placement> {
    let best = placements
        .iter()
        .map(|p| p.cost)
        .filter(|c| c.is_finite())
        .min_by(f64::total_cmp)?;
    let limit = near_limit(best, tolerance);
    let near = |p: &&Placement| p.cost.is_finite() && p.cost <= limit;
    let count = placements.iter().filter(near).count() as u64;
    let h = crate::rng::mix64(crate::rng::derive(seed, counter));
    let pick = ((h as u128 * count as u128) >> 64) as usize;
    placements.iter().filter(near).nth(pick).copied()
}
