//! Rasterizing the packed charts into the geometry image, tile by tile, and
//! zippering the chart boundaries (see the [module docs](super)).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::atlas::charts::{build_charts, Chart, ChartConfig};
use crate::atlas::pack::{closest_on_triangle, pack, Shape, COVER_RADIUS};
use crate::container::{codec, ArrayId, ArraySpec, ContainerWriter, DType, Element, Param};
use crate::field::{self, FieldKey};
use crate::mesh::io::{self, LoadOptions};
use crate::mesh::repair::RepairReport;
use crate::mesh::{unit_or, Mesh, NO_FACE};
use crate::progress::Progress;
use crate::{Error, Result};

pub use crate::artifact::gim::{TexelId, EMPTY, KIND, MAX_LINK, MAX_RESOLUTION, TILE};

/// Options of [`build_gim`].
#[derive(Clone, Debug)]
pub struct AtlasConfig {
    /// Atlas edge R in texels.
    pub resolution: usize,
    /// Minimum empty texels between charts.
    pub gutter: usize,
    pub charts: ChartConfig,
    pub load: LoadOptions,
    /// Vector-field keys (JSON); `None` for the default field.
    pub field_keys: Option<PathBuf>,
    /// Where the default field turns: its smoothness weighs each face by
    /// its exposure ([`crate::mesh::exposure`]) to this power, so the field
    /// turns, and its singularities sit, where the surface is seen least
    /// (in creases, under the chin, between the legs). 0 (the default)
    /// weighs every face alike. At 2, Spot's field has 6 singularities
    /// instead of 12 and their summed exposure falls from 8.9 to 4.7; on
    /// nine shared meshes no field gains a singularity, four change little
    /// (docs/measurements.md, "Field singularities"). Not the default: the
    /// field turns more sharply where it is hidden, and on Spot tiled with
    /// large bricks more courses end at seams. Keys ignore it.
    pub field_exposure: f64,
    pub level: i32,
}

impl Default for AtlasConfig {
    fn default() -> Self {
        AtlasConfig {
            resolution: 1024,
            gutter: 2,
            charts: ChartConfig::default(),
            load: LoadOptions::default(),
            field_keys: None,
            field_exposure: 0.0,
            level: crate::container::DEFAULT_ZSTD_LEVEL,
        }
    }
}

impl AtlasConfig {
    /// Checks the numbers a user gives, naming the command-line flag and the
    /// value: the atlas edge, the weld tolerance and the chart-splitting
    /// thresholds ([`build_gim`] refuses the same values).
    pub fn validate(&self) -> Result<()> {
        let r = self.resolution;
        if !(16..=MAX_RESOLUTION).contains(&r) {
            return Err(Error::Config(format!(
                "--resolution {r}: must be between 16 and {MAX_RESOLUTION}"
            )));
        }
        let w = self.load.weld_tolerance;
        if !(w.is_finite() && (0.0..=0.5).contains(&w)) {
            return Err(Error::Config(format!(
                "--weld {w}: must be a finite number in 0..=0.5 (a fraction of the median edge length; \
                 0 welds exact duplicates only)"
            )));
        }
        let at_least_one = |flag: &str, v: f32| {
            if v.is_finite() && v >= 1.0 {
                Ok(())
            } else {
                Err(Error::Config(format!("{flag} {v}: must be a finite number ≥ 1")))
            }
        };
        let e = self.field_exposure;
        if !(e.is_finite() && (0.0..=MAX_FIELD_EXPOSURE).contains(&e)) {
            return Err(Error::Config(format!(
                "--field-exposure {e}: must be a finite number in 0..={MAX_FIELD_EXPOSURE} \
                 (the power of each face's exposure weighing the field's turning; 0 weighs all alike)"
            )));
        }
        at_least_one("--max-stretch", self.charts.max_stretch)?;
        at_least_one("--max-area-distortion", self.charts.max_area_distortion)?;
        at_least_one("--max-linf-stretch", self.charts.max_linf_stretch)
    }
}

/// The largest `--field-exposure`: a face seen from nowhere still weighs
/// [`MIN_TURNING_WEIGHT`], and past this power the weights of all but the
/// most exposed faces vanish against it.
pub const MAX_FIELD_EXPOSURE: f64 = 8.0;

/// The least weight of a face's turning (exposure 0): the field stays
/// smooth in hidden places too.
const MIN_TURNING_WEIGHT: f64 = 0.05;

/// What [`build_gim`] made.
#[derive(Clone, Debug)]
pub struct AtlasReport {
    pub repair: RepairReport,
    pub charts: usize,
    /// Area-weighted L2 texture stretch over all charts (Sander et al. 2001).
    pub l2_stretch: f64,
    /// Worst L∞ stretch of any chart.
    pub linf_stretch: f64,
    /// Covered texels / R².
    pub utilization: f64,
    pub texels: usize,
    /// Texels whose centre lies inside two triangles or more (a chart
    /// folded over itself or overlapping another); 0 for a valid atlas.
    pub overlapping_texels: usize,
    pub zipper_links: usize,
    pub zipper_triangles: usize,
    /// The vector field's singular vertices (indices into the repaired
    /// mesh, positions in the mesh's units): there the sample's lines meet
    /// at an angle ([`field::singularities`]).
    pub singularities: Vec<field::Singularity>,
    /// Surface length of one texel.
    pub texel_size: f64,
    pub seconds: f64,
    /// (stage, seconds)
    pub stages: Vec<(&'static str, f64)>,
}

impl std::fmt::Display for AtlasReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} charts, stretch L2 {:.3} L∞ {:.3}, utilization {:.1}%, {} dense vertices ({} covered twice), {} zipper links, {} zipper triangles, {} field singularities ({} of index +1, {} of −1{}; summed exposure {:.2}), texel {:.3e} units, {:.2} s (",
            self.charts,
            self.l2_stretch,
            self.linf_stretch,
            100.0 * self.utilization,
            self.texels,
            self.overlapping_texels,
            self.zipper_links,
            self.zipper_triangles,
            self.singularities.len(),
            self.singularities.iter().filter(|s| s.index == 1).count(),
            self.singularities.iter().filter(|s| s.index == -1).count(),
            if self.singularities.iter().any(|s| s.index.abs() > 1) {
                ", others higher"
            } else {
                ""
            },
            self.singularities.iter().map(|s| s.exposure as f64).sum::<f64>(),
            self.texel_size,
            self.seconds
        )?;
        for (i, (s, t)) in self.stages.iter().enumerate() {
            write!(f, "{}{s} {t:.2}", if i > 0 { ", " } else { "" })?;
        }
        write!(f, ")")
    }
}

/// Per-face data the rasterizer needs.
struct FaceRaster<'a> {
    mesh: &'a Mesh,
    face_chart: Vec<u32>,
    /// Texel-space corners of each face.
    corner_texel: Vec<[[f64; 2]; 3]>,
    vertex_normals: Vec<[f32; 3]>,
    field: Vec<[f32; 3]>,
    resolution: usize,
    /// Maps the (possibly rescaled, see [`Mesh::normalize_extreme_scale`])
    /// mesh positions back to the user's units; 1.0 for ordinary meshes.
    unscale: f64,
}

/// The best triangle found for one texel.
#[derive(Clone, Copy)]
struct Cover {
    dist: f64,
    face: u32,
    bary: [f64; 3],
}

const NO_COVER: Cover = Cover {
    dist: f64::INFINITY,
    face: NO_FACE,
    bary: [0.0; 3],
};

/// One rasterized tile plus a one-texel margin.
struct TileRaster {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    /// (w + 2) × (h + 2) covers, margin included.
    cover: Vec<Cover>,
    /// Per texel of the tile (w × h), how many triangles hold its centre
    /// strictly inside (saturating): above one where charts overlap.
    inside: Vec<u8>,
}

impl TileRaster {
    fn at(&self, x: isize, y: isize) -> &Cover {
        // x, y relative to the tile origin, -1..=w
        &self.cover[((y + 1) as usize) * (self.w + 2) + (x + 1) as usize]
    }
}

/// A boundary texel, for zippering.
#[derive(Clone, Copy, Debug)]
struct BoundaryTexel {
    texel: u32,
    chart: u32,
    face: u32,
    position: [f32; 3],
}

impl FaceRaster<'_> {
    fn chart_of(&self, c: &Cover) -> u32 {
        if c.face == NO_FACE {
            EMPTY
        } else {
            self.face_chart[c.face as usize]
        }
    }

    fn rasterize(&self, tx: usize, ty: usize, bucket: &[u32]) -> TileRaster {
        let r = self.resolution;
        let (x0, y0) = (tx * TILE, ty * TILE);
        let (w, h) = (TILE.min(r - x0), TILE.min(r - y0));
        let mut cover = vec![NO_COVER; (w + 2) * (h + 2)];
        let mut inside = vec![0u8; w * h];
        // region in absolute texels: [x0 - 1, x0 + w + 1)
        let (rx0, ry0) = (x0 as isize - 1, y0 as isize - 1);
        let (rx1, ry1) = ((x0 + w + 1) as isize, (y0 + h + 1) as isize);
        for &f in bucket {
            let p = &self.corner_texel[f as usize];
            let lo_x = p.iter().map(|c| c[0]).fold(f64::INFINITY, f64::min) - COVER_RADIUS - 0.5;
            let hi_x = p.iter().map(|c| c[0]).fold(f64::NEG_INFINITY, f64::max) + COVER_RADIUS - 0.5;
            let lo_y = p.iter().map(|c| c[1]).fold(f64::INFINITY, f64::min) - COVER_RADIUS - 0.5;
            let hi_y = p.iter().map(|c| c[1]).fold(f64::NEG_INFINITY, f64::max) + COVER_RADIUS - 0.5;
            let xa = (lo_x.ceil() as isize).max(rx0).max(0);
            let xb = (hi_x.floor() as isize + 1).min(rx1).min(r as isize);
            let ya = (lo_y.ceil() as isize).max(ry0).max(0);
            let yb = (hi_y.floor() as isize + 1).min(ry1).min(r as isize);
            for y in ya..yb {
                for x in xa..xb {
                    let q = [x as f64 + 0.5, y as f64 + 0.5];
                    let Some((dist, bary)) = closest_on_triangle(p, q) else {
                        continue;
                    };
                    if dist > COVER_RADIUS {
                        continue;
                    }
                    let core = (x as usize).wrapping_sub(x0) < w && (y as usize).wrapping_sub(y0) < h;
                    if core && bary.iter().all(|&l| l > 0.0) {
                        let n = &mut inside[(y as usize - y0) * w + x as usize - x0];
                        *n = n.saturating_add(1);
                    }
                    let slot = &mut cover[((y - ry0) as usize) * (w + 2) + (x - rx0) as usize];
                    if dist < slot.dist - 1e-12 || (dist <= slot.dist + 1e-12 && f < slot.face) {
                        *slot = Cover { dist, face: f, bary };
                    }
                }
            }
        }
        TileRaster {
            x0,
            y0,
            w,
            h,
            cover,
            inside,
        }
    }

    /// The attributes of a covered texel: position, normal, tangent.
    fn attributes(&self, c: &Cover) -> ([f32; 3], [f32; 3], [f32; 3]) {
        let t = self.mesh.triangles[c.face as usize];
        let mut pos = DVec3::ZERO;
        let mut nrm = Vec3::ZERO;
        for k in 0..3 {
            let p = Vec3::from(self.mesh.positions[t[k] as usize]);
            let n = Vec3::from(self.vertex_normals[t[k] as usize]);
            pos += c.bary[k] * p.as_dvec3();
            nrm += c.bary[k] as f32 * n;
        }
        let mut n = unit_or(nrm, Vec3::ZERO);
        if n.length_squared() < 0.5 {
            n = self.mesh.face_normal(c.face as usize).into();
        }
        let f = Vec3::from(self.field[c.face as usize]);
        let mut t = unit_or(f - f.dot(n) * n, Vec3::ZERO);
        if t.length_squared() < 0.5 {
            let other = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
            t = unit_or(n.cross(other), Vec3::ZERO);
        }
        (pos.as_vec3().to_array(), n.to_array(), t.to_array())
    }
}

/// The atlas arrays of one tile, ready to encode.
struct TileArrays {
    chart: Vec<u32>,
    face: Vec<u32>,
    bary: Vec<f32>,
    position: Vec<f32>,
    normal: Vec<f32>,
    tangent: Vec<f32>,
    boundary: Vec<BoundaryTexel>,
    covered: usize,
    /// Texels whose centre lies inside two triangles or more.
    overlapping: usize,
}

fn tile_arrays(fr: &FaceRaster, t: &TileRaster) -> TileArrays {
    let n = t.w * t.h;
    let mut a = TileArrays {
        chart: vec![EMPTY; n],
        face: vec![NO_FACE; n],
        bary: vec![0.0; n * 2],
        position: vec![0.0; n * 3],
        normal: vec![0.0; n * 3],
        tangent: vec![0.0; n * 3],
        boundary: Vec::new(),
        covered: 0,
        overlapping: t.inside.iter().filter(|&&n| n > 1).count(),
    };
    for y in 0..t.h {
        for x in 0..t.w {
            let c = t.at(x as isize, y as isize);
            let chart = fr.chart_of(c);
            if chart == EMPTY {
                continue;
            }
            let i = y * t.w + x;
            a.covered += 1;
            a.chart[i] = chart;
            a.face[i] = c.face;
            a.bary[i * 2] = c.bary[1] as f32;
            a.bary[i * 2 + 1] = c.bary[2] as f32;
            let (p, nrm, tan) = fr.attributes(c);
            let user = if fr.unscale == 1.0 {
                p
            } else {
                p.map(|x| (x as f64 * fr.unscale) as f32)
            };
            a.position[i * 3..i * 3 + 3].copy_from_slice(&user);
            a.normal[i * 3..i * 3 + 3].copy_from_slice(&nrm);
            a.tangent[i * 3..i * 3 + 3].copy_from_slice(&tan);
            let (xi, yi) = (x as isize, y as isize);
            let on_border = [(-1, 0), (1, 0), (0, -1), (0, 1)]
                .iter()
                .any(|&(dx, dy)| fr.chart_of(t.at(xi + dx, yi + dy)) != chart);
            if on_border {
                a.boundary.push(BoundaryTexel {
                    texel: ((t.y0 + y) * fr.resolution + t.x0 + x) as u32,
                    chart,
                    face: c.face,
                    position: p,
                });
            }
        }
    }
    a
}

/// Builds the geometry image of the mesh at `mesh_path` into `out`.
pub fn build_gim(
    mesh_path: &Path,
    out: &Path,
    cfg: &AtlasConfig,
    progress: &dyn Progress,
) -> Result<AtlasReport> {
    let start = Instant::now();
    let mut stages = Vec::new();
    let mut lap = {
        let mut t = Instant::now();
        move |name: &'static str, stages: &mut Vec<(&'static str, f64)>| {
            stages.push((name, t.elapsed().as_secs_f64()));
            t = Instant::now();
        }
    };
    let r = cfg.resolution;
    if !(16..=MAX_RESOLUTION).contains(&r) {
        return Err(Error::Config(format!(
            "--resolution {r}: must be between 16 and {MAX_RESOLUTION}"
        )));
    }
    let mut inputs = vec![("the input mesh", mesh_path)];
    if let Some(keys) = &cfg.field_keys {
        inputs.push(("the vector-field keys", keys.as_path()));
    }
    crate::io::staging::check_output(out, &inputs)?;
    let (mut mesh, repair) = io::load(mesh_path, &cfg.load)?;
    // A mesh of extreme size is worked on rescaled by a power of two (exact),
    // and its positions written back in the user's units.
    let unscale = mesh.normalize_extreme_scale();
    let topology = mesh.topology();
    let keys: Vec<FieldKey> = match &cfg.field_keys {
        Some(p) => field::read_keys(p, mesh.triangles.len())?,
        None => Vec::new(),
    };
    lap("load", &mut stages);
    let charts = build_charts(&mesh, &topology, &cfg.charts)?;
    lap("charts", &mut stages);
    let extents: Vec<[f64; 2]> = charts
        .iter()
        .map(|c| {
            let mx =
                c.uv.iter()
                    .fold([0f64; 2], |m, p| [m[0].max(p[0] as f64), m[1].max(p[1] as f64)]);
            [mx[0].max(1e-9), mx[1].max(1e-9)]
        })
        .collect();
    let shapes: Vec<Shape> = charts
        .iter()
        .zip(&extents)
        .map(|(c, &extent)| Shape {
            uv: &c.uv,
            triangles: &c.triangles,
            extent,
        })
        .collect();
    let packing = pack(&shapes, r, cfg.gutter, cfg.charts.compact);
    if packing.scale <= 0.0 {
        return Err(Error::input(
            mesh_path,
            format!("its {} charts do not fit a {r}² atlas", charts.len()),
        ));
    }
    let nf = mesh.triangles.len();
    let mut face_chart = vec![EMPTY; nf];
    let mut corner_texel = vec![[[0f64; 2]; 3]; nf];
    // (the charts' uv are right-handed; atlas rows run down, so `place`
    // flips v within each chart's box — else every chart, and everything
    // quilted into it, would show mirrored on the surface)
    for (ci, c) in charts.iter().enumerate() {
        for (k, &f) in c.faces.iter().enumerate() {
            face_chart[f as usize] = ci as u32;
            for j in 0..3 {
                let uv = c.uv[c.triangles[k][j] as usize];
                corner_texel[f as usize][j] = packing.place(ci, extents[ci], uv);
            }
        }
    }
    if let Some(f) = face_chart.iter().position(|&c| c == EMPTY) {
        return Err(Error::Config(format!(
            "internal: face {f} was not assigned to a chart"
        )));
    }
    let exposure = crate::mesh::exposure::face_exposure(&mesh);
    let turning: Option<Vec<f64>> = (cfg.field_exposure > 0.0).then(|| {
        exposure
            .iter()
            .map(|&e| (e as f64).powf(cfg.field_exposure).max(MIN_TURNING_WEIGHT))
            .collect()
    });
    let field = field::face_field(&mesh, &topology, &keys, turning.as_deref());
    let mut singularities = field::singularities(&mesh, &topology, &field);
    let mut around = vec![(0f32, 0u32); mesh.positions.len()];
    for (t, &e) in mesh.triangles.iter().zip(&exposure) {
        for &v in t {
            around[v as usize].0 += e;
            around[v as usize].1 += 1;
        }
    }
    for s in &mut singularities {
        let (sum, count) = around[s.vertex as usize];
        s.exposure = sum / count.max(1) as f32;
        // in the user's units (see `FaceRaster::unscale`)
        if unscale != 1.0 {
            s.position = s.position.map(|x| (x as f64 * unscale) as f32);
        }
    }
    lap("pack+field", &mut stages);

    let fr = FaceRaster {
        mesh: &mesh,
        face_chart,
        corner_texel,
        vertex_normals: mesh.vertex_normals(),
        field,
        resolution: r,
        unscale,
    };
    // bucket faces by the tiles their dilated texel bounding box touches
    let nt = r.div_ceil(TILE);
    let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); nt * nt];
    for (f, p) in fr.corner_texel.iter().enumerate() {
        let lo = |k: usize| p.iter().map(|c| c[k]).fold(f64::INFINITY, f64::min) - COVER_RADIUS - 1.5;
        let hi = |k: usize| p.iter().map(|c| c[k]).fold(f64::NEG_INFINITY, f64::max) + COVER_RADIUS + 1.5;
        let t0 = |v: f64| ((v.max(0.0) as usize) / TILE).min(nt - 1);
        for ty in t0(lo(1))..=t0(hi(1)) {
            for tx in t0(lo(0))..=t0(hi(0)) {
                buckets[ty * nt + tx].push(f as u32);
            }
        }
    }

    let mut w = ContainerWriter::create(out, KIND)?;
    w.set_level(cfg.level);
    let (ru, tu) = (r as u64, TILE as u64);
    let arr = |w: &mut ContainerWriter, name: &str, dtype: DType, c: u64| -> Result<ArrayId> {
        let (shape, chunk) = if c == 1 {
            (vec![ru, ru], vec![tu, tu])
        } else {
            (vec![ru, ru, c], vec![tu, tu, c])
        };
        w.add_array(ArraySpec::new(name, dtype, &shape, &chunk)?)
    };
    let ids = [
        arr(&mut w, "chart", DType::U32, 1)?,
        arr(&mut w, "face", DType::U32, 1)?,
        arr(&mut w, "bary", DType::F32, 2)?,
        arr(&mut w, "position", DType::F32, 3)?,
        arr(&mut w, "normal", DType::F32, 3)?,
        arr(&mut w, "tangent", DType::F32, 3)?,
    ];
    progress.begin("atlas", (nt * nt) as u64);
    let level = cfg.level;
    let mut boundary = Vec::new();
    let mut covered = 0usize;
    let mut overlapping = 0usize;
    let tiles: Vec<usize> = (0..nt * nt).collect();
    for batch in tiles.chunks(16) {
        let done: Vec<(Vec<codec::EncodedChunk>, Vec<BoundaryTexel>, usize, usize)> = batch
            .par_iter()
            .map(|&t| {
                let raster = fr.rasterize(t % nt, t / nt, &buckets[t]);
                let a = tile_arrays(&fr, &raster);
                let enc = vec![
                    codec::encode(&a.chart, level),
                    codec::encode(&a.face, level),
                    codec::encode(&a.bary, level),
                    codec::encode(&a.position, level),
                    codec::encode(&a.normal, level),
                    codec::encode(&a.tangent, level),
                ];
                (enc, a.boundary, a.covered, a.overlapping)
            })
            .collect();
        for (&t, (enc, b, n, o)) in batch.iter().zip(done) {
            for (id, e) in ids.iter().zip(enc) {
                w.write_encoded(*id, t as u64, e)?;
            }
            boundary.extend(b);
            covered += n;
            overlapping += o;
        }
        progress.advance(batch.len() as u64);
    }
    progress.end();
    lap("rasterize", &mut stages);

    let texel_size = 1.0 / packing.scale;
    let links = zipper_links(&mesh, &boundary, texel_size, r);
    let zip_tris = zipper_triangles(&links, &boundary, r);
    lap("zipper", &mut stages);

    // stretch figures, area-weighted over charts
    let areas: Vec<f64> = charts
        .iter()
        .map(|c| c.faces.iter().map(|&f| mesh.face_area(f as usize) as f64).sum())
        .collect();
    let total_area: f64 = areas.iter().sum::<f64>().max(1e-30);
    let l2 = (charts
        .iter()
        .zip(&areas)
        .map(|(c, a)| a * (c.l2_stretch as f64).powi(2))
        .sum::<f64>()
        / total_area)
        .sqrt();
    let linf = charts.iter().map(|c| c.linf_stretch as f64).fold(0.0, f64::max);
    let utilization = covered as f64 / (r * r) as f64;

    // the zipper above worked in the rescaled units; the file and the
    // report speak the user's
    let texel_size = texel_size * unscale;
    write_mesh_arrays(&mut w, &mesh, &fr, &charts, &links, &zip_tris)?;
    // inputs are named relative to the geometry image's folder, so its bytes
    // do not depend on the working directory it was made from
    let source = crate::io::staging::relative_to_folder_of(out, mesh_path);
    w.add_input(&source, hash_file(mesh_path)?);
    if let Some(p) = &cfg.field_keys {
        w.add_input(&crate::io::staging::relative_to_folder_of(out, p), hash_file(p)?);
    }
    w.set_param("source", Param::Text(source));
    w.set_param("resolution", Param::Int(r as i64));
    w.set_param("gutter", Param::Int(cfg.gutter as i64));
    w.set_param("charts", Param::Int(charts.len() as i64));
    w.set_param("texel_size", Param::Float(texel_size));
    w.set_param("l2_stretch", Param::Float(l2));
    w.set_param("linf_stretch", Param::Float(linf));
    w.set_param("utilization", Param::Float(utilization));
    w.set_param("dense_vertices", Param::Int(covered as i64));
    w.set_param("repair", Param::Text(repair.to_string()));
    w.set_param(
        "field",
        Param::Text(if keys.is_empty() && cfg.field_exposure > 0.0 {
            format!("default, turning weighed by exposure^{}", cfg.field_exposure)
        } else if keys.is_empty() {
            "default".into()
        } else {
            format!("{} keys", keys.len())
        }),
    );
    w.finish()?;
    lap("write", &mut stages);
    Ok(AtlasReport {
        repair,
        charts: charts.len(),
        l2_stretch: l2,
        linf_stretch: linf,
        utilization,
        texels: covered,
        overlapping_texels: overlapping,
        zipper_links: links.len(),
        singularities,
        zipper_triangles: zip_tris.len(),
        texel_size,
        seconds: start.elapsed().as_secs_f64(),
        stages,
    })
}

fn hash_file(path: &Path) -> Result<u64> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    Ok(xxhash_rust::xxh3::xxh3_64(&bytes))
}

fn write_flat<T: Element>(
    w: &mut ContainerWriter,
    name: &str,
    dtype: DType,
    rows: usize,
    cols: usize,
    v: &[T],
) -> Result<()> {
    let chunk_rows = 65536u64.min(rows.max(1) as u64);
    let id = w.add_array(ArraySpec::new(
        name,
        dtype,
        &[rows as u64, cols as u64],
        &[chunk_rows, cols as u64],
    )?)?;
    w.write_array(id, v)
}

fn write_mesh_arrays(
    w: &mut ContainerWriter,
    mesh: &Mesh,
    fr: &FaceRaster,
    charts: &[Chart],
    links: &[[u32; 2]],
    zip_tris: &[[u32; 3]],
) -> Result<()> {
    let (nv, nf, r) = (mesh.positions.len(), mesh.triangles.len(), fr.resolution as f64);
    write_flat(
        w,
        "mesh_positions",
        DType::F32,
        nv,
        3,
        &mesh
            .positions
            .iter()
            .flatten()
            .map(|&c| {
                if fr.unscale == 1.0 {
                    c
                } else {
                    (c as f64 * fr.unscale) as f32
                }
            })
            .collect::<Vec<f32>>(),
    )?;
    write_flat(
        w,
        "mesh_triangles",
        DType::U32,
        nf,
        3,
        &mesh.triangles.iter().flatten().copied().collect::<Vec<u32>>(),
    )?;
    let uv: Vec<f32> = fr
        .corner_texel
        .iter()
        .flatten()
        .flat_map(|c| [(c[0] / r) as f32, (c[1] / r) as f32])
        .collect();
    write_flat(w, "corner_uv", DType::F32, nf * 3, 2, &uv)?;
    write_flat(w, "face_chart", DType::U32, nf, 1, &fr.face_chart)?;
    write_flat(
        w,
        "face_field",
        DType::F32,
        nf,
        3,
        &fr.field.iter().flatten().copied().collect::<Vec<f32>>(),
    )?;
    let stretch: Vec<f32> = charts
        .iter()
        .flat_map(|c| [c.l2_stretch, c.linf_stretch])
        .collect();
    write_flat(w, "chart_stretch", DType::F32, charts.len(), 2, &stretch)?;
    write_flat(
        w,
        "zipper_links",
        DType::U32,
        links.len(),
        2,
        &links.iter().flatten().copied().collect::<Vec<u32>>(),
    )?;
    write_flat(
        w,
        "zipper_triangles",
        DType::U32,
        zip_tris.len(),
        3,
        &zip_tris.iter().flatten().copied().collect::<Vec<u32>>(),
    )
}

/// Faces within two vertex-rings of `f` (sorted).
fn two_ring(mesh: &Mesh, vertex_faces: &[Vec<u32>], f: u32) -> Vec<u32> {
    let mut ring: Vec<u32> = mesh.triangles[f as usize]
        .iter()
        .flat_map(|&v| vertex_faces[v as usize].iter().copied())
        .collect();
    ring.sort_unstable();
    ring.dedup();
    let mut two: Vec<u32> = ring
        .iter()
        .flat_map(|&g| {
            mesh.triangles[g as usize]
                .iter()
                .flat_map(|&v| vertex_faces[v as usize].iter().copied())
        })
        .collect();
    two.sort_unstable();
    two.dedup();
    two
}

/// Links each boundary texel to the nearest boundary texel across its seam:
/// of another chart (or of its own chart but far away in the atlas), within
/// [`MAX_LINK`] texel sizes in 3D, on a face within two vertex-rings. Sorted,
/// deduplicated pairs (lower texel id first).
fn zipper_links(mesh: &Mesh, boundary: &[BoundaryTexel], texel: f64, r: usize) -> Vec<[u32; 2]> {
    let mut vertex_faces = vec![Vec::new(); mesh.positions.len()];
    for (f, t) in mesh.triangles.iter().enumerate() {
        for &v in t {
            vertex_faces[v as usize].push(f as u32);
        }
    }
    let cell = MAX_LINK * texel;
    let key = |p: [f32; 3]| -> [i64; 3] {
        [
            (p[0] as f64 / cell).floor() as i64,
            (p[1] as f64 / cell).floor() as i64,
            (p[2] as f64 / cell).floor() as i64,
        ]
    };
    let mut grid: Vec<([i64; 3], u32)> = boundary
        .iter()
        .enumerate()
        .map(|(i, b)| (key(b.position), i as u32))
        .collect();
    grid.sort_unstable();
    // the 2-rings of the boundary faces, computed once per face
    let mut faces: Vec<u32> = boundary.iter().map(|b| b.face).collect();
    faces.sort_unstable();
    faces.dedup();
    let rings: BTreeMap<u32, Vec<u32>> = faces
        .par_iter()
        .map(|&f| (f, two_ring(mesh, &vertex_faces, f)))
        .collect();
    let mut links: Vec<[u32; 2]> = boundary
        .par_iter()
        .filter_map(|a| {
            let k = key(a.position);
            let ring = &rings[&a.face];
            let (ax, ay) = ((a.texel as usize % r) as i64, (a.texel as usize / r) as i64);
            let mut best: Option<(f64, u32)> = None;
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let c = [k[0] + dx, k[1] + dy, k[2] + dz];
                        let lo = grid.partition_point(|e| e.0 < c);
                        for e in grid[lo..].iter().take_while(|e| e.0 == c) {
                            let b = &boundary[e.1 as usize];
                            if b.texel == a.texel {
                                continue;
                            }
                            if b.chart == a.chart {
                                let (bx, by) = ((b.texel as usize % r) as i64, (b.texel as usize / r) as i64);
                                if (ax - bx).abs().max((ay - by).abs()) <= 3 {
                                    continue;
                                }
                            }
                            let d = Vec3::from(a.position) - Vec3::from(b.position);
                            let d = (d.length_squared() as f64).sqrt();
                            if d > MAX_LINK * texel || ring.binary_search(&b.face).is_err() {
                                continue;
                            }
                            if best.map_or(true, |(bd, bt)| d < bd || (d == bd && b.texel < bt)) {
                                best = Some((d, b.texel));
                            }
                        }
                    }
                }
            }
            best.map(|(_, t)| [a.texel.min(t), a.texel.max(t)])
        })
        .collect();
    links.sort_unstable();
    links.dedup();
    links
}

/// Stitches zippers into triangle strips: for two boundary texels a, a' that
/// are grid neighbours in one chart and linked to b, b' across the seam, the
/// quad (a, a', b', b) becomes two triangles (one if b = b'). Oriented to
/// agree with the texels' normals is left to the reader; here triangles are
/// sorted triples, deduplicated.
fn zipper_triangles(links: &[[u32; 2]], boundary: &[BoundaryTexel], r: usize) -> Vec<[u32; 3]> {
    let chart_of: BTreeMap<u32, u32> = boundary.iter().map(|b| (b.texel, b.chart)).collect();
    let mut partners: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
    for &[a, b] in links {
        partners.entry(a).or_default().push(b);
        partners.entry(b).or_default().push(a);
    }
    let mut tris = Vec::new();
    for (&a, pa) in &partners {
        let (ax, ay) = (a as usize % r, a as usize / r);
        for (nx, ny) in [(ax + 1, ay), (ax, ay + 1)] {
            if nx >= r || ny >= r {
                continue;
            }
            let a2 = (ny * r + nx) as u32;
            if chart_of.get(&a2) != chart_of.get(&a) {
                continue;
            }
            let Some(pa2) = partners.get(&a2) else { continue };
            for &b in pa {
                for &b2 in pa2 {
                    if b == b2 {
                        tris.push(sorted3([a, a2, b]));
                    } else if chart_of.get(&b) == chart_of.get(&b2) {
                        let (bx, by) = (b as i64 % r as i64, b as i64 / r as i64);
                        let (cx, cy) = (b2 as i64 % r as i64, b2 as i64 / r as i64);
                        if (bx - cx).abs() + (by - cy).abs() == 1 {
                            tris.push(sorted3([a, a2, b2]));
                            tris.push(sorted3([a, b2, b]));
                        }
                    }
                }
            }
        }
    }
    tris.sort_unstable();
    tris.dedup();
    tris
}

fn sorted3(mut t: [u32; 3]) -> [u32; 3] {
    t.sort_unstable();
    t
}
