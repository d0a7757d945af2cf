//! The `.gim` artifact: a multi-chart geometry image, the dense mesh M_d
//! (section III-A). Per atlas texel, in 64×64 tiles: the chart, the original
//! face and barycentrics, the 3D position, normal and tangent frame; plus
//! the mesh with its atlas UVs, the vector field, and the zipper links and
//! triangles that join the charts. The writer is [`crate::atlas::build_gim`];
//! [`DenseGraph`] derives M_d's neighbourhoods on demand.

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::container::{Container, DType, Element, MemoryBudget, Param};
use crate::mesh::Mesh;
use crate::{Error, Result};

/// The artifact kind of a geometry image.
pub const KIND: &str = "gim";
/// Edge of the atlas tiles (chunks).
pub const TILE: usize = 64;
/// Chart id of an empty texel.
pub const EMPTY: u32 = u32::MAX;
/// Longest zipper link, in texel sizes.
pub const MAX_LINK: f64 = 2.5;

/// A dense vertex: the atlas texel `y · R + x`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TexelId(pub u32);

/// Largest atlas resolution `atlas` writes and readers accept.
pub const MAX_RESOLUTION: usize = 32768;

/// A geometry image opened for reading.
pub struct Gim {
    container: Container,
    pub resolution: usize,
    pub charts: usize,
    pub texel_size: f64,
    /// Vertices and faces of the stored mesh (the row counts of its arrays).
    vertices: u64,
    faces: u64,
}

impl Gim {
    /// Opens a `.gim`, checking its kind, its parameters against the shapes
    /// of its arrays, and (as each is read, see [`Gim::read`]) the indices
    /// its arrays hold against the counts they index.
    pub fn open(path: &Path, budget: MemoryBudget) -> Result<Gim> {
        let container = Container::open_kind(path, KIND, budget)?;
        let m = container.metadata();
        let int = |k: &str| match m.param(k) {
            Some(Param::Int(v)) if *v > 0 => Ok(*v as usize),
            _ => Err(Error::input(path, format!("metadata parameter '{k}' is missing"))),
        };
        let texel_size = match m.param("texel_size") {
            Some(Param::Float(v)) => *v,
            _ => return Err(Error::input(path, "metadata parameter 'texel_size' is missing")),
        };
        let (resolution, charts) = (int("resolution")?, int("charts")?);
        let r = resolution as u64;
        let why = format!("parameter 'resolution' is {resolution}");
        for (name, dtype, channels) in [
            ("chart", DType::U32, 1),
            ("face", DType::U32, 1),
            ("bary", DType::F32, 2),
            ("position", DType::F32, 3),
            ("normal", DType::F32, 3),
            ("tangent", DType::F32, 3),
        ] {
            let shape = if channels == 1 {
                vec![r, r]
            } else {
                vec![r, r, channels]
            };
            container.array_shaped(name, dtype, &shape, &why)?;
        }
        if resolution > MAX_RESOLUTION {
            return Err(Error::input(
                path,
                format!("parameter 'resolution' is {resolution}, more than the {MAX_RESOLUTION} an atlas may have"),
            ));
        }
        // per-row arrays: their row counts are the mesh's vertex and face counts
        let rows = |name: &str, dtype: DType, cols: u64| -> Result<u64> {
            let spec = container.spec(container.array(name)?);
            if spec.dtype != dtype || spec.shape.len() != 2 || spec.shape[1] != cols {
                return Err(Error::input(
                    path,
                    format!(
                        "array '{name}' is {} {}, expected N×{cols} {}",
                        crate::container::dims(&spec.shape),
                        spec.dtype.name(),
                        dtype.name()
                    ),
                ));
            }
            Ok(spec.shape[0])
        };
        let vertices = rows("mesh_positions", DType::F32, 3)?;
        let faces = rows("mesh_triangles", DType::U32, 3)?;
        let faces_why = format!("array 'mesh_triangles' has {faces} faces");
        for (name, dtype, shape) in [
            ("corner_uv", DType::F32, [faces * 3, 2]),
            ("face_chart", DType::U32, [faces, 1]),
            ("face_field", DType::F32, [faces, 3]),
        ] {
            if container.array(name).is_ok() {
                container.array_shaped(name, dtype, &shape, &faces_why)?;
            }
        }
        rows("zipper_links", DType::U32, 2)?;
        rows("zipper_triangles", DType::U32, 3)?;
        Ok(Gim {
            resolution,
            charts,
            texel_size,
            vertices,
            faces,
            container,
        })
    }

    /// Checks the indices a `u32` array holds against what they index, so
    /// that no reader can index out of range with them: mesh triangles
    /// against the vertex count, texel faces (of covered texels) against the
    /// face count, texel charts and face charts against the chart count,
    /// zipper links and triangles against the texel count.
    fn check_indices(&self, name: &str, values: &[u32]) -> Result<()> {
        let texels = (self.resolution * self.resolution) as u64;
        let charts = self.charts as u64;
        let (bound, what, empty_ok) = match name {
            "mesh_triangles" => (self.vertices, "vertices", false),
            "face_chart" => (charts, "charts", false),
            "chart" => (charts, "charts", true),
            "zipper_links" | "zipper_triangles" => (texels, "texels", false),
            "face" => {
                // empty texels hold NO_FACE; covered ones a face
                let chart: Vec<u32> = self.container.read_array(self.container.array("chart")?)?;
                self.check_indices("chart", &chart)?;
                let bad = values
                    .iter()
                    .zip(&chart)
                    .position(|(&f, &c)| c != EMPTY && f as u64 >= self.faces);
                return match bad {
                    None => Ok(()),
                    Some(t) => Err(Error::input(
                        self.container.path(),
                        format!(
                            "array 'face' holds face {} at covered texel {t}, but the mesh has {} faces",
                            values[t], self.faces
                        ),
                    )),
                };
            }
            _ => return Ok(()),
        };
        match values
            .iter()
            .position(|&v| v as u64 >= bound && !(empty_ok && v == EMPTY))
        {
            None => Ok(()),
            Some(i) => Err(Error::input(
                self.container.path(),
                format!(
                    "array '{name}' holds index {} at element {i}, but there are {bound} {what}",
                    values[i]
                ),
            )),
        }
    }

    /// The container underneath.
    pub fn container(&self) -> &Container {
        &self.container
    }

    /// A whole named array; an index array's values are checked against
    /// what they index (an error names the file and array).
    pub fn read<T: Element>(&self, name: &str) -> Result<Vec<T>> {
        let v: Vec<T> = self.container.read_array(self.container.array(name)?)?;
        if T::DTYPE == DType::U32 {
            self.check_indices(name, bytemuck::cast_slice(&v))?;
        }
        Ok(v)
    }

    /// The chart and face planes of the atlas region `(x0, y0, w, h)`
    /// (row-major), their indices checked like [`Gim::read`] checks them.
    pub fn chart_face_region(
        &self,
        x0: usize,
        y0: usize,
        w: usize,
        h: usize,
    ) -> Result<(Vec<u32>, Vec<u32>)> {
        let c = &self.container;
        let (o, e) = ([y0 as u64, x0 as u64], [h as u64, w as u64]);
        let chart: Vec<u32> = c.read_region(c.array("chart")?, &o, &e)?;
        let face: Vec<u32> = c.read_region(c.array("face")?, &o, &e)?;
        let charts = self.charts as u64;
        for (i, (&ch, &f)) in chart.iter().zip(&face).enumerate() {
            let texel = (y0 + i / w) * self.resolution + x0 + i % w;
            if ch != EMPTY && ch as u64 >= charts {
                return Err(Error::input(
                    c.path(),
                    format!(
                        "array 'chart' holds index {ch} at element {texel}, but there are {charts} charts"
                    ),
                ));
            }
            if ch != EMPTY && f as u64 >= self.faces {
                return Err(Error::input(
                    c.path(),
                    format!(
                        "array 'face' holds face {f} at covered texel {texel}, but the mesh has {} faces",
                        self.faces
                    ),
                ));
            }
        }
        Ok((chart, face))
    }

    /// The per-texel surface of the atlas region `(x0, y0, w, h)`, each
    /// plane row-major: chart, face, position (3 per texel), normal (3).
    /// Chart and face indices are checked ([`Gim::chart_face_region`]).
    pub fn texel_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<TexelRegion> {
        let c = &self.container;
        let (o3, e3) = ([y0 as u64, x0 as u64, 0], [h as u64, w as u64, 3]);
        let (chart, face) = self.chart_face_region(x0, y0, w, h)?;
        Ok(TexelRegion {
            chart,
            face,
            position: c.read_region(c.array("position")?, &o3, &e3)?,
            normal: c.read_region(c.array("normal")?, &o3, &e3)?,
        })
    }

    /// The 3D positions of the atlas region `(x0, y0, w, h)`, row-major, three
    /// values a texel.
    pub fn position_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Vec<f32>> {
        let c = &self.container;
        c.read_region(
            c.array("position")?,
            &[y0 as u64, x0 as u64, 0],
            &[h as u64, w as u64, 3],
        )
    }

    /// The repaired input mesh.
    pub fn mesh(&self) -> Result<Mesh> {
        let p: Vec<f32> = self.read("mesh_positions")?;
        let t: Vec<u32> = self.read("mesh_triangles")?;
        Ok(Mesh {
            positions: p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            triangles: t.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            ..Mesh::default()
        })
    }

    /// The vector field: a unit tangent per face of [`Gim::mesh`].
    pub fn face_field(&self) -> Result<Vec<[f32; 3]>> {
        let f: Vec<f32> = self.read("face_field")?;
        Ok(f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    }

    /// Atlas uv (0..1, y down) of every face corner.
    pub fn corner_uv(&self) -> Result<Vec<[f32; 2]>> {
        Ok(self
            .read::<f32>("corner_uv")?
            .chunks_exact(2)
            .map(|c| [c[0], c[1]])
            .collect())
    }

    /// Zipper links between texels.
    pub fn zipper_links(&self) -> Result<Vec<[u32; 2]>> {
        Ok(self
            .read::<u32>("zipper_links")?
            .chunks_exact(2)
            .map(|c| [c[0], c[1]])
            .collect())
    }

    /// Zipper triangles between texels.
    pub fn zipper_triangles(&self) -> Result<Vec<[u32; 3]>> {
        Ok(self
            .read::<u32>("zipper_triangles")?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect())
    }

    /// The dense mesh's graph: grid neighbours within a chart plus zipper links.
    pub fn graph(&self) -> Result<DenseGraph> {
        let chart: Vec<u32> = self.read("chart")?;
        let links = self.zipper_links()?;
        Ok(DenseGraph::new(self.resolution, chart, &links))
    }
}

/// The per-texel surface of an atlas region ([`Gim::texel_region`]).
pub struct TexelRegion {
    pub chart: Vec<u32>,
    pub face: Vec<u32>,
    pub position: Vec<f32>,
    pub normal: Vec<f32>,
}

/// The zipper links of the dense mesh M_d as adjacency lists (CSR): each
/// texel on a chart border to its partners in other charts.
pub struct ZipperLinks {
    start: Vec<u32>,
    to: Vec<u32>,
    index: Vec<u32>,
    /// Where each run of [`BUCKET`] texel ids starts in `index` (one more
    /// entry at the end): most texels have no link, and most runs none.
    bucket: Vec<u32>,
}

/// Texel ids per bucket of [`ZipperLinks::bucket`] (as a shift).
const BUCKET: u32 = 8;

impl ZipperLinks {
    /// Both directions of every link.
    pub fn new(links: &[[u32; 2]]) -> ZipperLinks {
        let mut pairs: Vec<(u32, u32)> = links.iter().flat_map(|&[a, b]| [(a, b), (b, a)]).collect();
        pairs.sort_unstable();
        let mut start = Vec::new();
        let mut index = Vec::new();
        let mut to = Vec::with_capacity(pairs.len());
        for (i, &(a, b)) in pairs.iter().enumerate() {
            if index.last() != Some(&a) {
                start.push(i as u32);
                index.push(a);
            }
            to.push(b);
        }
        let buckets = index.last().map_or(0, |&t| (t >> BUCKET) as usize + 1);
        let bucket = (0..=buckets)
            .map(|b| index.partition_point(|&t| ((t >> BUCKET) as usize) < b) as u32)
            .collect();
        ZipperLinks {
            start,
            to,
            index,
            bucket,
        }
    }

    /// Calls `f` for every zipper partner of texel `t`.
    #[inline]
    pub fn for_each(&self, t: u32, mut f: impl FnMut(u32)) {
        let b = (t >> BUCKET) as usize;
        let Some(&[lo, hi]) = self.bucket.get(b..b + 2) else {
            return;
        };
        let run = &self.index[lo as usize..hi as usize];
        if let Ok(k) = run.binary_search(&t).map(|k| k + lo as usize) {
            let s = self.start[k] as usize;
            let e = self.start.get(k + 1).map_or(self.to.len(), |&v| v as usize);
            for &n in &self.to[s..e] {
                f(n);
            }
        }
    }
}

/// Adjacency of the dense mesh M_d: each covered texel's 4-neighbours of the
/// same chart, plus its zipper partners.
pub struct DenseGraph {
    pub resolution: usize,
    pub chart: Vec<u32>,
    zippers: ZipperLinks,
}

impl DenseGraph {
    /// Builds the graph from the chart map and zipper links.
    pub fn new(resolution: usize, chart: Vec<u32>, links: &[[u32; 2]]) -> DenseGraph {
        DenseGraph {
            resolution,
            chart,
            zippers: ZipperLinks::new(links),
        }
    }

    /// Whether a texel is a dense vertex.
    pub fn covered(&self, t: u32) -> bool {
        self.chart[t as usize] != EMPTY
    }

    /// Calls `f` for every neighbour of texel `t`; `f`'s second argument says
    /// whether the edge is a zipper link.
    pub fn for_each_neighbour(&self, t: u32, mut f: impl FnMut(u32, bool)) {
        let r = self.resolution;
        let (x, y) = (t as usize % r, t as usize / r);
        let c = self.chart[t as usize];
        if c == EMPTY {
            return;
        }
        let mut grid = |nx: usize, ny: usize| {
            let n = (ny * r + nx) as u32;
            if self.chart[n as usize] == c {
                f(n, false);
            }
        };
        if x > 0 {
            grid(x - 1, y);
        }
        if x + 1 < r {
            grid(x + 1, y);
        }
        if y > 0 {
            grid(x, y - 1);
        }
        if y + 1 < r {
            grid(x, y + 1);
        }
        self.zippers.for_each(t, |n| f(n, true));
    }

    /// Breadth-first hop distances from `source` (u32::MAX where unreached).
    pub fn bfs(&self, source: u32, max_hops: u32) -> Vec<u32> {
        let mut dist = vec![u32::MAX; self.chart.len()];
        let mut queue = std::collections::VecDeque::new();
        dist[source as usize] = 0;
        queue.push_back(source);
        while let Some(t) = queue.pop_front() {
            let d = dist[t as usize];
            if d >= max_hops {
                continue;
            }
            self.for_each_neighbour(t, |n, _| {
                if dist[n as usize] == u32::MAX {
                    dist[n as usize] = d + 1;
                    queue.push_back(n);
                }
            });
        }
        dist
    }

    /// Number of connected components among covered texels.
    pub fn components(&self) -> usize {
        let mut seen = vec![false; self.chart.len()];
        let mut count = 0;
        let mut stack = Vec::new();
        for s in 0..self.chart.len() as u32 {
            if seen[s as usize] || !self.covered(s) {
                continue;
            }
            count += 1;
            seen[s as usize] = true;
            stack.push(s);
            while let Some(t) = stack.pop() {
                self.for_each_neighbour(t, |n, _| {
                    if !seen[n as usize] {
                        seen[n as usize] = true;
                        stack.push(n);
                    }
                });
            }
        }
        count
    }
}

/// The atlas-space direction (texel axes, y down; unnormalised) of a 3D
/// tangent vector `v` on face `f`: least squares through the face's
/// parameterisation, `v ≈ (∂P/∂u) d_u + (∂P/∂v) d_v`. `None` for a face that
/// is degenerate in 3D or in the atlas.
pub fn atlas_direction(mesh: &Mesh, corner_uv: &[[f32; 2]], f: usize, v: [f64; 3]) -> Option<[f64; 2]> {
    let [p0, p1, p2] = mesh.corners(f).map(Vec3::from);
    let (e1, e2) = ((p1 - p0).as_dvec3(), (p2 - p0).as_dvec3());
    let (u0, u1, u2) = (corner_uv[f * 3], corner_uv[f * 3 + 1], corner_uv[f * 3 + 2]);
    let a = [(u1[0] - u0[0]) as f64, (u1[1] - u0[1]) as f64];
    let b = [(u2[0] - u0[0]) as f64, (u2[1] - u0[1]) as f64];
    let det = a[0] * b[1] - a[1] * b[0];
    if det.abs() < 1e-24 {
        return None;
    }
    // ∂P/∂u, ∂P/∂v from the inverse of [a b]
    let (i00, i01, i10, i11) = (b[1] / det, -b[0] / det, -a[1] / det, a[0] / det);
    let (du, dv) = (e1 * i00 + e2 * i10, e1 * i01 + e2 * i11);
    let v = DVec3::from(v);
    let (g00, g01, g11) = (du.dot(du), du.dot(dv), dv.dot(dv));
    let (h0, h1) = (du.dot(v), dv.dot(v));
    let gd = g00 * g11 - g01 * g01;
    if gd.abs() < 1e-300 {
        return None;
    }
    Some([(g11 * h0 - g01 * h1) / gd, (g00 * h1 - g01 * h0) / gd])
}

/// Grid triangles of the dense mesh inside charts: two per 2×2 block of one
/// chart, one where exactly three of the four texels are in one chart.
pub fn grid_triangles(chart: &[u32], r: usize) -> Vec<[u32; 3]> {
    let mut tris = Vec::new();
    for y in 0..r.saturating_sub(1) {
        for x in 0..r - 1 {
            tris.extend(block_triangles(chart, r, x, y));
        }
    }
    tris
}

/// The grid triangles of the 2×2 block whose top-left texel is (x, y)
/// (x + 1 < r, y + 1 < r).
pub fn block_triangles(chart: &[u32], r: usize, x: usize, y: usize) -> impl Iterator<Item = [u32; 3]> + '_ {
    block_triangles_by(|t| chart[t as usize], r, x, y)
}

/// [`block_triangles`] with the chart of a texel given by `ch`.
pub fn block_triangles_by(
    ch: impl Fn(u32) -> u32,
    r: usize,
    x: usize,
    y: usize,
) -> impl Iterator<Item = [u32; 3]> {
    let id = |dx: usize, dy: usize| ((y + dy) * r + x + dx) as u32;
    let (a, b, c, d) = (id(0, 0), id(1, 0), id(0, 1), id(1, 1));
    let same = |p: u32, q: u32| ch(p) != EMPTY && ch(p) == ch(q);
    let mut out: [Option<[u32; 3]>; 2] = [None, None];
    if same(a, b) && same(a, c) && same(a, d) {
        out = [Some([a, b, d]), Some([a, d, c])];
    } else if same(a, b) && same(b, d) && !same(a, c) {
        out[0] = Some([a, b, d]);
    } else if same(a, b) && same(a, c) && !same(a, d) {
        out[0] = Some([a, b, c]);
    } else if same(a, c) && same(c, d) && !same(a, b) {
        out[0] = Some([a, d, c]);
    } else if same(b, d) && same(c, d) && !same(a, d) {
        out[0] = Some([b, d, c]);
    }
    out.into_iter().flatten()
}

#[cfg(test)]
mod tests {
    use super::ZipperLinks;

    /// Every texel's partners, found through the buckets, are those of a
    /// search over all links, in the same order, around bucket edges too.
    #[test]
    fn zipper_partners_are_those_of_every_link() {
        let mut links: Vec<[u32; 2]> = Vec::new();
        let mut x = 12345u32;
        for _ in 0..2000 {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            let a = (x >> 8) % 70_000;
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            let b = (x >> 8) % 70_000;
            links.push([a, b]);
        }
        // ids at and around bucket edges, and the last id
        links.extend([[255, 256], [511, 0], [69_999, 256]]);
        let z = ZipperLinks::new(&links);
        let mut checked = 0;
        for t in 0..70_100u32 {
            let mut found = Vec::new();
            z.for_each(t, |n| found.push(n));
            let mut all: Vec<u32> = links
                .iter()
                .flat_map(|&[a, b]| [(a, b), (b, a)])
                .filter(|&(a, _)| a == t)
                .map(|(_, b)| b)
                .collect();
            all.sort_unstable();
            assert_eq!(found, all, "texel {t}");
            checked += !all.is_empty() as usize;
        }
        assert!(checked > 3000, "{checked}");
    }
}
