//! Work patches (§III-B): texels within a hop radius of a centre, grown
//! breadth first over the dense graph.

use super::*;

/// A work patch: its vertices (texels) and their BFS depth.
pub(crate) struct WorkPatch {
    pub(crate) texels: Vec<u32>,
    pub(crate) depth: Vec<u16>,
    /// Whether the traversal crossed a zipper (the patch spans charts).
    pub(in crate::quilt) crosses_charts: bool,
    /// Where in `texels` the first texel reached across a zipper is
    /// (`texels.len()` if none): the patches of smaller radius at the same
    /// seed are prefixes of this traversal ([`Bfs::prefix`]).
    pub(in crate::quilt) first_zipper: usize,
}

impl WorkPatch {
    /// The patch's bounding box in an `r`×`r` atlas: `(x0, y0, width,
    /// height)`.
    pub(in crate::quilt) fn atlas_box(&self, r: usize) -> (usize, usize, usize, usize) {
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for &t in &self.texels {
            let (x, y) = (t as usize % r, t as usize / r);
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        (x0, y0, x1 - x0 + 1, y1 - y0 + 1)
    }
}

/// A multiplicative hash for texel ids (the map's keys are small integers).
#[derive(Default)]
pub(in crate::quilt) struct TexelHasher(u64);

impl Hasher for TexelHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u32(&mut self, v: u32) {
        self.0 = (v as u64 ^ 0x5555_5555).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// The last work patch's vertices by texel (sized by the patch, not the
/// atlas): a dense window of the atlas around the seed (a patch of radius
/// r lies within r texels of it inside its chart), a map for the texels
/// of other charts beyond it.
#[derive(Default)]
pub(in crate::quilt) struct Bfs {
    /// Local index per texel of the window (`u32::MAX`: not in the patch).
    window: Vec<u32>,
    /// The window's first column and row and its side.
    x0: i64,
    pub(super) y0: i64,
    side: usize,
    grid: Option<TileGrid>,
    /// Window slots set by the last patch, to clear.
    set: Vec<u32>,
    pub(super) index: HashMap<u32, u32, BuildHasherDefault<TexelHasher>>,
}

impl Bfs {
    /// Empties the index and centres its window of `radius` on `v`.
    fn window_around(&mut self, surface: &Surface, v: u32, radius: usize) {
        for &slot in &self.set {
            self.window[slot as usize] = u32::MAX;
        }
        self.set.clear();
        self.index.clear();
        let grid = surface.grid();
        let (x, y) = grid.xy(v);
        self.side = 2 * radius + 1;
        self.x0 = x as i64 - radius as i64;
        self.y0 = y as i64 - radius as i64;
        self.grid = Some(grid);
        if self.window.len() < self.side * self.side {
            self.window = vec![u32::MAX; self.side * self.side];
        }
    }

    /// The work patch of `radius` at `v`: a breadth-first traversal of the
    /// dense mesh, indexed for [`Bfs::contains`].
    pub(in crate::quilt) fn patch(&mut self, surface: &Surface, v: u32, radius: usize) -> WorkPatch {
        self.patch_unless(surface, v, radius, |_| false)
            .expect("never stopped")
    }

    /// [`Bfs::patch`], given up (`None`) at the first texel reached for
    /// which `stop` holds.
    pub(in crate::quilt) fn patch_unless(
        &mut self,
        surface: &Surface,
        v: u32,
        radius: usize,
        stop: impl Fn(u32) -> bool,
    ) -> Option<WorkPatch> {
        self.window_around(surface, v, radius);
        if stop(v) {
            return None;
        }
        let mut texels = vec![v];
        let mut depth = vec![0u16];
        self.insert(v, 0);
        let mut first_zipper = usize::MAX;
        let mut head = 0;
        let mut stopped = false;
        while head < texels.len() && !stopped {
            let (t, d) = (texels[head], depth[head]);
            head += 1;
            if d as usize >= radius {
                continue;
            }
            surface.for_each_neighbour(t, |n, zipper| {
                if self.contains(n).is_none() {
                    if zipper && first_zipper == usize::MAX {
                        first_zipper = texels.len();
                    }
                    self.insert(n, texels.len() as u32);
                    texels.push(n);
                    depth.push(d + 1);
                    stopped |= stop(n);
                }
            });
        }
        (!stopped).then(|| WorkPatch {
            crosses_charts: first_zipper != usize::MAX,
            first_zipper: first_zipper.min(texels.len()),
            texels,
            depth,
        })
    }

    /// [`Bfs::patch`] of `radius` at the seed of `ball`, a traversal of at
    /// least that radius from it, without traversing again: a breadth-first
    /// traversal lists its texels by depth, and those within `radius` come
    /// in the same order as a traversal stopped there.
    pub(in crate::quilt) fn prefix(
        &mut self,
        surface: &Surface,
        ball: &WorkPatch,
        radius: usize,
    ) -> WorkPatch {
        let v = ball.texels[0];
        self.window_around(surface, v, radius);
        let len = ball.depth.partition_point(|&d| d as usize <= radius);
        for (i, &t) in ball.texels[..len].iter().enumerate() {
            self.insert(t, i as u32);
        }
        WorkPatch {
            texels: ball.texels[..len].to_vec(),
            depth: ball.depth[..len].to_vec(),
            crosses_charts: ball.first_zipper < len,
            first_zipper: ball.first_zipper.min(len),
        }
    }

    /// The window slot of texel `t`, if it lies in the window.
    #[inline]
    fn slot(&self, t: u32) -> Option<usize> {
        let (x, y) = self.grid?.xy(t);
        let (dx, dy) = (x as i64 - self.x0, y as i64 - self.y0);
        let side = self.side as i64;
        (dx >= 0 && dy >= 0 && dx < side && dy < side).then(|| (dy * side + dx) as usize)
    }

    fn insert(&mut self, t: u32, i: u32) {
        match self.slot(t) {
            Some(slot) => {
                self.window[slot] = i;
                self.set.push(slot as u32);
            }
            None => {
                self.index.insert(t, i);
            }
        }
    }

    /// The local index of texel `t` in the last patch.
    #[inline]
    pub(in crate::quilt) fn contains(&self, t: u32) -> Option<usize> {
        match self.slot(t) {
            Some(slot) => Some(self.window[slot])
                .filter(|&i| i != u32::MAX)
                .map(|i| i as usize),
            None => self.index.get(&t).map(|&i| i as usize),
        }
    }
}
