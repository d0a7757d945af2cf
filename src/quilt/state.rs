//! The synthesis state over atlas texels (struct-of-arrays), the dense
//! surface it lives on, work patches P(v) and their breadth-first traversal
//! (section III-B, step 2).

use super::sample::Sample;
use crate::artifact::gim::{Gim, EMPTY};
use crate::artifact::quilt::NO_PATCH;
use crate::Result;

/// No foreign feature vector (a texel of the active sample).
pub(super) const NO_FOREIGN: u32 = u32::MAX;

/// Per-texel synthesis state (struct of arrays over the atlas).
pub(super) struct State {
    pub(super) r: usize,
    pub(super) n: usize,
    pub(super) chart: Vec<u32>,
    pub(super) synthesized: Vec<bool>,
    pub(super) coord: Vec<[f32; 2]>,
    /// Sample-space offset per +x and per +y atlas step (columns of the local
    /// Jacobian), to continue an old patch one texel into its neighbour.
    pub(super) jacobian: Vec<[f32; 4]>,
    pub(super) rotation: Vec<u8>,
    pub(super) patch: Vec<u32>,
    /// Index of the sample each texel draws from ([`Quilt::samples`](crate::quilt::Quilt::samples)).
    pub(super) source: Vec<u8>,
    /// The sample new patches come from.
    pub(super) active: u8,
    /// Texels of other samples than the active one (painting with a new
    /// sample): index into `foreign_features` (`NO_FOREIGN` for texels of
    /// the active sample, whose geometry-map vectors are looked up in it
    /// at their coordinate when needed, not stored).
    pub(super) foreign: Vec<u32>,
    /// Their geometry-map vectors projected into the active sample's basis
    /// (see [`Synthesis::load`](super::synthesis::Synthesis::load)), `n` per entry.
    pub(super) foreign_features: Vec<f32>,
    /// m_σ(p): the sample's foreground mask at each texel's coordinate
    /// (when the sample has a mask).
    pub(super) mask: Vec<f32>,
    /// m0(p): the constraint function (1 on the painted region F, falling
    /// to 0 over the transition zone, 0 elsewhere), when constrained.
    pub(super) target: Option<Vec<f32>>,
    /// The id the next accepted patch gets.
    pub(super) next_patch: u32,
    /// Synthesized-neighbour counts of unsynthesized texels (the
    /// "most constrained" priority), bucketed.
    pub(super) count: Vec<u8>,
    pub(super) buckets: Vec<std::collections::BTreeSet<u32>>,
    pub(super) remaining: usize,
}

impl State {
    pub(super) fn new(chart: Vec<u32>, n: usize, r: usize) -> State {
        let texels = chart.len();
        let mut buckets = vec![std::collections::BTreeSet::new(); 16];
        let mut remaining = 0;
        for (t, &c) in chart.iter().enumerate() {
            if c != EMPTY {
                buckets[0].insert(t as u32);
                remaining += 1;
            }
        }
        State {
            r,
            n,
            synthesized: vec![false; texels],
            coord: vec![[0.0; 2]; texels],
            jacobian: vec![[0.0; 4]; texels],
            rotation: vec![0; texels],
            patch: vec![NO_PATCH; texels],
            source: vec![0; texels],
            active: 0,
            foreign: vec![NO_FOREIGN; texels],
            foreign_features: Vec::new(),
            mask: vec![0.0; texels],
            target: None,
            next_patch: 0,
            count: vec![0; texels],
            buckets,
            remaining,
            chart,
        }
    }

    /// The most constrained unsynthesized texel (lowest id among equals).
    pub(super) fn most_constrained(&self) -> Option<u32> {
        self.buckets.iter().rev().find_map(|b| b.first().copied())
    }

    /// The geometry-map vector of synthesized texel `t` in the active
    /// sample's basis, into `out` (`n` values).
    pub(super) fn feature_into(&self, sample: &Sample, t: u32, out: &mut [f32]) {
        let f = self.foreign[t as usize];
        if f != NO_FOREIGN {
            let f = f as usize * self.n;
            out.copy_from_slice(&self.foreign_features[f..f + self.n]);
            return;
        }
        let c = self.coord[t as usize];
        if !sample.lookup([c[0] as f64, c[1] as f64], out) {
            out.fill(0.0);
        }
    }
}

/// A work patch: its vertices (texels) and their BFS depth.
pub(crate) struct WorkPatch {
    pub(crate) texels: Vec<u32>,
    pub(crate) depth: Vec<u16>,
    /// Whether the traversal crossed a zipper (the patch spans charts).
    pub(super) crosses_charts: bool,
}

impl WorkPatch {
    /// The patch's bounding box in an `r`×`r` atlas: `(x0, y0, width,
    /// height)`.
    pub(super) fn atlas_box(&self, r: usize) -> (usize, usize, usize, usize) {
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

/// Reusable BFS buffers.
pub(super) struct Bfs {
    pub(super) stamp: Vec<u32>,
    pub(super) index: Vec<u32>,
    pub(super) epoch: u32,
}

impl Bfs {
    pub(super) fn patch(
        &mut self,
        graph: &crate::artifact::gim::DenseGraph,
        v: u32,
        radius: usize,
    ) -> WorkPatch {
        self.epoch += 1;
        let mut texels = vec![v];
        let mut depth = vec![0u16];
        self.stamp[v as usize] = self.epoch;
        self.index[v as usize] = 0;
        let mut crosses = false;
        let mut head = 0;
        while head < texels.len() {
            let (t, d) = (texels[head], depth[head]);
            head += 1;
            if d as usize >= radius {
                continue;
            }
            graph.for_each_neighbour(t, |n, zipper| {
                if self.stamp[n as usize] != self.epoch {
                    self.stamp[n as usize] = self.epoch;
                    self.index[n as usize] = texels.len() as u32;
                    texels.push(n);
                    depth.push(d + 1);
                    crosses |= zipper;
                }
            });
        }
        WorkPatch {
            texels,
            depth,
            crosses_charts: crosses,
        }
    }

    pub(super) fn contains(&self, t: u32) -> Option<usize> {
        (self.stamp[t as usize] == self.epoch).then(|| self.index[t as usize] as usize)
    }
}

/// Per face, the atlas-space angle of its field direction (radians, y down).
pub(super) fn face_angles(gim: &Gim) -> Result<Vec<f64>> {
    let mut mesh = gim.mesh()?;
    // angles do not depend on the scale; f32 products of extreme ones would overflow
    mesh.normalize_extreme_scale();
    let uv = gim.corner_uv()?;
    let field: Vec<f32> = gim.read("face_field")?;
    Ok((0..mesh.triangles.len())
        .map(|f| {
            let v = [
                field[f * 3] as f64,
                field[f * 3 + 1] as f64,
                field[f * 3 + 2] as f64,
            ];
            crate::artifact::gim::atlas_direction(&mesh, &uv, f, v).map_or(0.0, |d| d[1].atan2(d[0]))
        })
        .collect())
}

/// Everything the loop reads.
pub(super) struct Surface {
    pub(super) r: usize,
    pub(super) graph: crate::artifact::gim::DenseGraph,
    pub(super) face: Vec<u32>,
    /// Dense positions multiplied by `unit` (exactly: a power of two, 1 but
    /// for a mesh of extreme size, see [`crate::mesh::extreme_scale`]).
    pub(super) position: Vec<f32>,
    pub(super) unit: f32,
    pub(super) normal: Vec<f32>,
    pub(super) face_angle: Vec<f64>,
}

impl Surface {
    pub(super) fn texel_angle(&self, t: u32) -> f64 {
        self.face_angle[self.face[t as usize] as usize]
    }
}
