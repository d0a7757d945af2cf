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
use crate::math;
use crate::mesh::io::{self, LoadOptions};
use crate::mesh::repair::RepairReport;
use crate::mesh::{unit_or, Mesh, NO_FACE};
use crate::progress::Progress;
use crate::{Error, Result};

mod faces;
mod zipper;
use faces::{tile_arrays, BoundaryTexel, FaceRaster};
use zipper::{zipper_links, zipper_triangles};

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
            .map(|&e| math::powf(e as f64, cfg.field_exposure).max(MIN_TURNING_WEIGHT))
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
