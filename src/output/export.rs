//! `export`: artifacts out to other tools.
//!
//! - A geometry image (`.gim`) goes out as its mesh with atlas UVs and the
//!   chart map as the texture; a decorated mesh (`.quilt`) with its baked
//!   atlas texture. Formats: OBJ + MTL + PNG, or one binary glTF 2.0 file
//!   (`mesh.glb`, the texture embedded).
//! - A decorated mesh's *surface BTF* for other renderers: per atlas texel the
//!   sample coordinate and frame (`synthesis.exr`, and which sample when the
//!   surface draws from several), and each sample as its factorization
//!   (`geometry_maps.exr`, `appearance.csv`, …; `geometry_maps_K.exr`,
//!   `appearance_K.csv`, … for sample K ≥ 1), described by a `FORMAT.md`
//!   written beside them.
//!
//! Every export is all-or-nothing: the files are written into a hidden
//! staging folder inside the output folder and renamed into place only when
//! all of them are complete, so an error leaves no new file behind (and an
//! output folder the export created is removed again).

use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::artifact::gim::Gim;
use crate::artifact::svd::SvdArtifact;
use std::sync::Mutex;

use crate::container::{BoundedCache, Container, MemoryBudget};
use crate::io::imageio;
use crate::mesh::io::write_obj;
use crate::mesh::Mesh;
use crate::output::show::{show, ShowWhat};
use crate::output::{bake, BAND_ROWS};
use crate::quilt::{Quilt, NO_PATCH};
use crate::{Error, Result};

use serde::Serialize;

/// A mesh file format for `export --format`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum MeshFormat {
    /// `mesh.obj` + `mesh.mtl` + the texture as PNG.
    #[default]
    Obj,
    /// `mesh.glb`: binary glTF 2.0 with the texture embedded.
    #[value(alias = "glb")]
    Gltf,
}

impl FromStr for MeshFormat {
    type Err = Error;
    /// The names clap accepts: `obj`, `gltf` (or `glb`).
    fn from_str(s: &str) -> Result<Self> {
        <Self as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| Error::Config(format!("--format '{s}': expected obj or gltf")))
    }
}

/// What [`export`] writes.
#[derive(Clone, Debug, Default)]
pub struct ExportOptions {
    /// The mesh with its texture, in this format, into this folder.
    pub mesh: Option<(MeshFormat, PathBuf)>,
    /// The surface BTF of a `.quilt` into this folder.
    pub btf: Option<PathBuf>,
    /// The sample of a `.quilt` (default: the path recorded in it).
    pub sample: Option<PathBuf>,
    pub budget: MemoryBudget,
}

/// Exports a `.gim` or a `.quilt` as `opts` asks; returns the files written.
/// Nothing is written unless everything succeeds.
pub fn export(file: &Path, opts: &ExportOptions) -> Result<Vec<PathBuf>> {
    if opts.mesh.is_none() && opts.btf.is_none() {
        return Err(Error::Config(
            "nothing to export: give -o DIR (with --format obj|gltf) and/or --btf DIR".into(),
        ));
    }
    let kind = Container::open(file, opts.budget)?.metadata().kind.clone();
    let source = if kind == crate::quilt::KIND {
        let quilt = Quilt::open(file, opts.budget)?;
        // `--sample` stands in for the tiling's sample only: the others
        // must be where the quilt says
        for (k, path) in quilt.samples.iter().enumerate().skip(1) {
            if !path.exists() {
                return Err(Error::input(
                    file,
                    format!("its sample {} (painted in, 'sample_{k}') is gone", path.display()),
                ));
            }
        }
        let gim = quilt.open_gim(None, opts.budget)?;
        Source::Quilt {
            path: file,
            quilt,
            gim,
        }
    } else if kind == crate::artifact::gim::KIND {
        if opts.btf.is_some() {
            return Err(Error::input(
                file,
                "a geometry image has no surface BTF: --btf needs a decorated mesh (.quilt, from `tile`)",
            ));
        }
        Source::Gim(Gim::open(file, opts.budget)?)
    } else {
        return Err(Error::input(
            file,
            format!("a '{kind}' artifact: export takes a .gim or a .quilt"),
        ));
    };
    // the surface BTF's inputs first: their checks are cheap
    let btf = match (&opts.btf, &source) {
        (Some(dir), Source::Quilt { path, quilt, .. }) => {
            if quilt.container().array("jacobian").is_err() {
                return Err(Error::input(
                    path,
                    "has no per-texel sample frame (array 'jacobian'): it was tiled by an older btfquilt; run `tile` again",
                ));
            }
            Some((
                dir,
                super::open_samples(quilt, opts.sample.as_deref(), opts.budget)?,
            ))
        }
        _ => None,
    };
    // everything that can fail happens before anything is renamed into place
    let mut stages = Vec::new();
    if let Some((format, dir)) = &opts.mesh {
        let mut stage = Stage::new(dir)?;
        stage_mesh(&source, *format, opts, &mut stage)?;
        stages.push(stage);
    }
    if let (Some((dir, samples)), Source::Quilt { path, quilt, .. }) = (&btf, &source) {
        let mut stage = Stage::new(dir)?;
        let mut paths = quilt.samples.clone();
        if let Some(first) = &opts.sample {
            paths[0] = first.clone();
        }
        let svds: Vec<&SvdArtifact> = samples.iter().map(|s| &s.svd).collect();
        stage_surface_btf(path, quilt, &svds, &paths, &mut stage)?;
        stages.push(stage);
    }
    // no published file may land on an input (the artifact, its geometry
    // image or samples): checked for all before any is renamed
    let mut inputs: Vec<(String, PathBuf)> = match &source {
        Source::Quilt { quilt, .. } => quilt.input_files(),
        Source::Gim(gim) => vec![("the geometry image".into(), gim.container().path().to_path_buf())],
    };
    if let Some(p) = &opts.sample {
        inputs.push(("the sample".into(), p.clone()));
    }
    let inputs: Vec<(&str, &Path)> = inputs.iter().map(|(r, p)| (r.as_str(), p.as_path())).collect();
    for stage in &stages {
        for name in &stage.publish {
            crate::io::staging::check_output(&stage.dir.join(name), &inputs)?;
        }
    }
    let mut written = Vec::new();
    for stage in stages {
        written.extend(stage.commit()?);
    }
    Ok(written)
}

/// Writes `DIR/mesh.obj`, `DIR/mesh.mtl` and `DIR/charts.png` (the chart map
/// as the texture, so a viewer shows the atlas). OBJ texture coordinates are
/// y-up: `vt u (1 - v)` for atlas uv (u, v) with v down. Returns the OBJ path.
pub fn export_gim_obj(gim: &Gim, dir: &Path) -> Result<PathBuf> {
    let mut stage = Stage::new(dir)?;
    stage_gim_mesh(gim, MeshFormat::Obj, &mut stage)?;
    stage.commit()?;
    Ok(dir.join("mesh.obj"))
}

/// Writes a decorated mesh: `DIR/mesh.obj`, `DIR/mesh.mtl` and
/// `DIR/atlas.png` (the baked preview colour, gutter dilated). Returns the
/// OBJ path.
pub fn export_quilt_obj(quilt_path: &Path, dir: &Path, budget: MemoryBudget) -> Result<PathBuf> {
    let opts = ExportOptions {
        mesh: Some((MeshFormat::Obj, dir.to_path_buf())),
        budget,
        ..ExportOptions::default()
    };
    export(quilt_path, &opts)?;
    Ok(dir.join("mesh.obj"))
}

enum Source<'a> {
    Gim(Gim),
    Quilt { path: &'a Path, quilt: Quilt, gim: Gim },
}

fn stage_mesh(source: &Source, format: MeshFormat, opts: &ExportOptions, stage: &mut Stage) -> Result<()> {
    match source {
        Source::Gim(gim) => stage_gim_mesh(gim, format, stage),
        Source::Quilt { path, gim, .. } => {
            // the baked atlas: a published file for OBJ, embedded for glTF
            let png = match format {
                MeshFormat::Obj => stage.publish("atlas.png"),
                MeshFormat::Gltf => stage.scratch("atlas.png"),
            };
            bake::bake(path, opts.sample.as_deref(), &png, opts.budget)?;
            stage_textured(gim, format, &png, "atlas.png", stage)
        }
    }
}

fn stage_gim_mesh(gim: &Gim, format: MeshFormat, stage: &mut Stage) -> Result<()> {
    let png = match format {
        MeshFormat::Obj => stage.publish("charts.png"),
        MeshFormat::Gltf => stage.scratch("charts.png"),
    };
    show(gim, ShowWhat::Charts, &png)?;
    stage_textured(gim, format, &png, "charts.png", stage)
}

/// The mesh of `gim` with atlas UVs and the texture at `png` (named
/// `texture` in the MTL).
fn stage_textured(gim: &Gim, format: MeshFormat, png: &Path, texture: &str, stage: &mut Stage) -> Result<()> {
    let mesh = gim.mesh()?;
    let corner_uv = gim.corner_uv()?;
    match format {
        MeshFormat::Obj => {
            // OBJ texture coordinates are y-up
            let uv: Vec<[f32; 2]> = corner_uv.iter().map(|&[u, v]| [u, 1.0 - v]).collect();
            write_mtl(&stage.publish("mesh.mtl"), "atlas", texture)?;
            write_obj(
                &stage.publish("mesh.obj"),
                &mesh,
                Some(&uv),
                Some(("mesh.mtl", "atlas")),
            )
        }
        MeshFormat::Gltf => {
            let image = std::fs::read(png).map_err(|e| Error::io(png, e))?;
            let out = stage.publish("mesh.glb");
            let split = split_by_uv(&mesh, &corner_uv)
                .map_err(|reason| Error::input(gim.container().path(), reason))?;
            let glb = glb_bytes(&split, &image).map_err(|reason| Error::input(&out, reason))?;
            imageio::write_atomic(&out, |w| w.write_all(&glb).map_err(|e| Error::io(&out, e)))
        }
    }
}

/// Writes a one-material MTL file with a diffuse texture.
pub fn write_mtl(path: &Path, material: &str, texture: &str) -> Result<()> {
    imageio::write_atomic(path, |w| {
        write!(
            w,
            "newmtl {material}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {texture}\n"
        )
        .map_err(|e| Error::io(path, e))
    })
}

/// Files written into a hidden folder inside the destination, renamed into
/// the destination by [`Stage::commit`]; dropped uncommitted, the staging
/// folder is removed, and so is the destination if this stage created it and
/// it is still empty.
struct Stage {
    dir: PathBuf,
    created: bool,
    tmp: Option<tempfile::TempDir>,
    publish: Vec<String>,
}

impl Stage {
    fn new(dir: &Path) -> Result<Stage> {
        let created = !dir.exists();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let tmp = crate::io::staging::staging_dir_in(dir, "export");
        let tmp = match tmp {
            Ok(t) => t,
            Err(e) => {
                if created {
                    let _ = std::fs::remove_dir(dir);
                }
                return Err(e);
            }
        };
        Ok(Stage {
            dir: dir.to_path_buf(),
            created,
            tmp: Some(tmp),
            publish: Vec::new(),
        })
    }

    fn staging(&self) -> &Path {
        self.tmp.as_ref().expect("an uncommitted stage").path()
    }

    /// A path for a file that will be renamed to `DIR/name` on commit.
    fn publish(&mut self, name: &str) -> PathBuf {
        if !self.publish.iter().any(|n| n == name) {
            self.publish.push(name.to_string());
        }
        self.staging().join(name)
    }

    /// A path for an intermediate file, removed with the staging folder.
    fn scratch(&self, name: &str) -> PathBuf {
        self.staging().join(format!("scratch-{name}"))
    }

    /// Renames the published files into the destination; returns their paths.
    fn commit(mut self) -> Result<Vec<PathBuf>> {
        let mut out = Vec::new();
        for name in &self.publish {
            let from = self.staging().join(name);
            let to = self.dir.join(name);
            std::fs::rename(&from, &to).map_err(|e| Error::io(&to, e))?;
            out.push(to);
        }
        self.created = false;
        Ok(out)
    }
}

impl Drop for Stage {
    fn drop(&mut self) {
        if let Some(tmp) = self.tmp.take() {
            let _ = tmp.close();
        }
        if self.created {
            // only if empty: never removes anything else
            let _ = std::fs::remove_dir(&self.dir);
        }
    }
}

// ---------------------------------------------------------------- glTF ----

/// A mesh as glTF wants it: one uv per vertex, so mesh vertices whose corners
/// carry different atlas uvs (chart seams) are split.
#[derive(Clone, Debug, PartialEq)]
pub struct SplitMesh {
    pub positions: Vec<[f32; 3]>,
    /// Unit normals (area-weighted smooth normals of the input mesh, so both
    /// copies of a split vertex have the same one).
    pub normals: Vec<[f32; 3]>,
    /// Atlas uv, origin top left, v down (glTF's and the atlas's convention).
    pub uvs: Vec<[f32; 2]>,
    pub triangles: Vec<[u32; 3]>,
    /// The input vertex of each output vertex.
    pub source: Vec<u32>,
}

/// Splits `mesh`'s vertices wherever its corners have different uvs; output
/// vertices are numbered in order of first use (triangle by triangle, corner
/// by corner), so the result is deterministic.
pub fn split_by_uv(mesh: &Mesh, corner_uv: &[[f32; 2]]) -> std::result::Result<SplitMesh, String> {
    let (nv, nf) = (mesh.positions.len(), mesh.triangles.len());
    if nf == 0 {
        return Err("the mesh has no triangles".into());
    }
    if corner_uv.len() != 3 * nf {
        return Err(format!("{} corner uvs for {nf} triangles", corner_uv.len()));
    }
    if let Some(p) = mesh
        .positions
        .iter()
        .position(|p| p.iter().any(|c| !c.is_finite()))
    {
        return Err(format!("vertex {p} is not finite"));
    }
    if let Some(i) = corner_uv.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(format!("corner uv {i} is not finite"));
    }
    let normals = mesh.vertex_normals();
    let mut map: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut out = SplitMesh {
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        triangles: Vec::with_capacity(nf),
        source: Vec::new(),
    };
    for (f, tri) in mesh.triangles.iter().enumerate() {
        let mut t = [0u32; 3];
        for k in 0..3 {
            let v = tri[k];
            if v as usize >= nv {
                return Err(format!("triangle {f} refers to vertex {v} of {nv}"));
            }
            // +0.0 folds -0.0 into 0.0, so equal uvs have equal bits
            let uv = [corner_uv[3 * f + k][0] + 0.0, corner_uv[3 * f + k][1] + 0.0];
            let key = (v, uv[0].to_bits(), uv[1].to_bits());
            let next = out.positions.len() as u32;
            let id = *map.entry(key).or_insert(next);
            if id == next {
                out.positions.push(mesh.positions[v as usize]);
                out.normals.push(unit_normal(mesh, &normals, v as usize, f));
                out.uvs.push(uv);
                out.source.push(v);
            }
            t[k] = id;
        }
        out.triangles.push(t);
    }
    Ok(out)
}

/// The smooth normal of vertex `v`, or the normal of face `f` (or +z) where
/// the smooth one vanishes; unit length in f32.
fn unit_normal(mesh: &Mesh, normals: &[[f32; 3]], v: usize, f: usize) -> [f32; 3] {
    let unit = |n: [f32; 3]| {
        let l = (n[0] as f64).hypot(n[1] as f64).hypot(n[2] as f64);
        (l > 1e-20 && l.is_finite()).then(|| n.map(|c| (c as f64 / l) as f32))
    };
    unit(normals[v])
        .or_else(|| {
            let [a, b, c] = mesh.triangles[f].map(|i| mesh.positions[i as usize]);
            let (e1, e2) = (
                [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
                [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
            );
            unit([
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ])
        })
        .unwrap_or([0.0, 0.0, 1.0])
}

const GLB_MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// serde_json's compact layout with numbers as Rust prints them (`1`, not
/// `1.0`; `-0`; never an exponent), as the glTF JSON has always been
/// written.
struct GltfFormatter;

impl serde_json::ser::Formatter for GltfFormatter {
    fn write_f64<W: ?Sized + Write>(&mut self, w: &mut W, v: f64) -> std::io::Result<()> {
        write!(w, "{v}")
    }
}

// The glTF document of `glb_bytes`: the fields in key order.

#[derive(Serialize)]
struct Gltf {
    asset: Asset,
    scene: u32,
    scenes: [Scene; 1],
    nodes: [Node; 1],
    meshes: [GltfMesh; 1],
    materials: [Material; 1],
    textures: [Texture; 1],
    images: [Image; 1],
    samplers: [Sampler; 1],
    accessors: [Accessor; 4],
    #[serde(rename = "bufferViews")]
    buffer_views: Vec<BufferView>,
    buffers: [Buffer; 1],
}

#[derive(Serialize)]
struct Asset {
    version: &'static str,
    generator: &'static str,
}

#[derive(Serialize)]
struct Scene {
    nodes: [u32; 1],
}

#[derive(Serialize)]
struct Node {
    mesh: u32,
    name: &'static str,
}

#[derive(Serialize)]
struct GltfMesh {
    name: &'static str,
    primitives: [Primitive; 1],
}

#[derive(Serialize)]
struct Primitive {
    attributes: Attributes,
    indices: u32,
    material: u32,
    mode: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
struct Attributes {
    position: u32,
    normal: u32,
    texcoord_0: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Material {
    name: &'static str,
    pbr_metallic_roughness: Pbr,
    double_sided: bool,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Pbr {
    base_color_texture: TextureRef,
    base_color_factor: [f64; 4],
    metallic_factor: f64,
    roughness_factor: f64,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct TextureRef {
    index: u32,
    tex_coord: u32,
}

#[derive(Serialize)]
struct Texture {
    sampler: u32,
    source: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Image {
    name: &'static str,
    buffer_view: usize,
    mime_type: &'static str,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Sampler {
    mag_filter: u32,
    min_filter: u32,
    wrap_s: u32,
    wrap_t: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Accessor {
    buffer_view: usize,
    byte_offset: usize,
    component_type: u32,
    count: usize,
    #[serde(rename = "type")]
    kind: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    min: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    max: Option<[f64; 3]>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct BufferView {
    buffer: u32,
    byte_offset: usize,
    byte_length: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    target: Option<u32>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Buffer {
    byte_length: usize,
}

/// A binary glTF 2.0 file: one node with one mesh (POSITION with min/max,
/// NORMAL, TEXCOORD_0, u32 indices, triangles), one material
/// (pbrMetallicRoughness with `png` as the sRGB base colour texture, metallic
/// 0, roughness 1, single sided), a sampler with trilinear filtering and
/// clamping, the PNG embedded through a bufferView. The JSON is serialized
/// from typed structs in a fixed key order, so the bytes depend only on the
/// inputs.
pub fn glb_bytes(mesh: &SplitMesh, png: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let n = mesh.positions.len();
    if n == 0 || mesh.triangles.is_empty() {
        return Err("an empty mesh".into());
    }
    if mesh.normals.len() != n || mesh.uvs.len() != n {
        return Err("positions, normals and uvs differ in count".into());
    }
    if mesh.triangles.iter().flatten().any(|&i| i as usize >= n) {
        return Err("an index is out of range".into());
    }
    if !png.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Err("the texture is not a PNG".into());
    }
    // the binary buffer: every view starts 4-byte aligned
    let mut bin: Vec<u8> = Vec::new();
    let mut views: Vec<(usize, usize, Option<u32>)> = Vec::new();
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>| {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        views.push((bin.len(), bytes.len(), target));
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    let flat = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
    let pos = view(&mut bin, &flat(mesh.positions.as_flattened()), Some(ARRAY_BUFFER));
    let nor = view(&mut bin, &flat(mesh.normals.as_flattened()), Some(ARRAY_BUFFER));
    let tex = view(&mut bin, &flat(mesh.uvs.as_flattened()), Some(ARRAY_BUFFER));
    let idx_bytes: Vec<u8> = mesh
        .triangles
        .as_flattened()
        .iter()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let idx = view(&mut bin, &idx_bytes, Some(ELEMENT_ARRAY_BUFFER));
    let img = view(&mut bin, png, None);
    let buffer_len = bin.len();

    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in &mesh.positions {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    // f32 → its exact f64 decimal, so a reader comparing as f32 or f64 agrees
    let wide = |v: [f32; 3]| v.map(|x| x as f64);
    let accessor = |view: usize, component_type: u32, count: usize, kind: &'static str| Accessor {
        buffer_view: view,
        byte_offset: 0,
        component_type,
        count,
        kind,
        min: None,
        max: None,
    };
    let doc = Gltf {
        asset: Asset {
            version: "2.0",
            generator: concat!("btfquilt ", env!("CARGO_PKG_VERSION")),
        },
        scene: 0,
        scenes: [Scene { nodes: [0] }],
        nodes: [Node {
            mesh: 0,
            name: "mesh",
        }],
        meshes: [GltfMesh {
            name: "mesh",
            primitives: [Primitive {
                attributes: Attributes {
                    position: 0,
                    normal: 1,
                    texcoord_0: 2,
                },
                indices: 3,
                material: 0,
                mode: 4, // triangles
            }],
        }],
        materials: [Material {
            name: "atlas",
            pbr_metallic_roughness: Pbr {
                base_color_texture: TextureRef {
                    index: 0,
                    tex_coord: 0,
                },
                base_color_factor: [1.0; 4],
                metallic_factor: 0.0,
                roughness_factor: 1.0,
            },
            double_sided: false,
        }],
        textures: [Texture {
            sampler: 0,
            source: 0,
        }],
        images: [Image {
            name: "atlas",
            buffer_view: img,
            mime_type: "image/png",
        }],
        // LINEAR magnification, LINEAR_MIPMAP_LINEAR minification, CLAMP_TO_EDGE
        samplers: [Sampler {
            mag_filter: 9729,
            min_filter: 9987,
            wrap_s: 33071,
            wrap_t: 33071,
        }],
        accessors: [
            Accessor {
                min: Some(wide(min)),
                max: Some(wide(max)),
                ..accessor(pos, FLOAT, n, "VEC3")
            },
            accessor(nor, FLOAT, n, "VEC3"),
            accessor(tex, FLOAT, n, "VEC2"),
            accessor(idx, UNSIGNED_INT, 3 * mesh.triangles.len(), "SCALAR"),
        ],
        buffer_views: views
            .iter()
            .map(|&(byte_offset, byte_length, target)| BufferView {
                buffer: 0,
                byte_offset,
                byte_length,
                target,
            })
            .collect(),
        buffers: [Buffer {
            byte_length: buffer_len,
        }],
    };
    let mut json = Vec::new();
    doc.serialize(&mut serde_json::Serializer::with_formatter(
        &mut json,
        GltfFormatter,
    ))
    .map_err(|e| format!("writing the glTF JSON: {e}"))?;

    // the GLB container: header, JSON chunk (space padded), BIN chunk (zero padded)
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let total32 = u32::try_from(total).map_err(|_| format!("{total} bytes: too large for a GLB file"))?;
    let mut out = Vec::with_capacity(total);
    for v in [GLB_MAGIC, 2, total32, json.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&json);
    for v in [bin.len() as u32, CHUNK_BIN] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&bin);
    debug_assert_eq!(out.len(), total);
    Ok(out)
}

// ------------------------------------------------------- surface BTF ----

/// Channel or column names `prefix00` … for `n` terms (at least two digits).
pub fn term_names(prefix: &str, n: usize) -> Vec<String> {
    let digits = n.saturating_sub(1).to_string().len().max(2);
    (0..n).map(|i| format!("{prefix}{i:0digits$}")).collect()
}

/// A value in the shortest decimal that reads back to the same f32.
fn num(v: f32) -> String {
    format!("{v:?}")
}

/// A sample's file name: `stem.ext` for sample 0, `stem_K.ext` for K ≥ 1.
pub fn sample_file(stem: &str, k: usize, ext: &str) -> String {
    if k == 0 {
        format!("{stem}.{ext}")
    } else {
        format!("{stem}_{k}.{ext}")
    }
}

/// Writes the surface BTF of a decorated mesh into the stage: `svds` and
/// `paths` are its samples in [`Quilt::samples`] order (sharing one direction
/// set, as [`open_samples`](super::open_samples) checks).
fn stage_surface_btf(
    quilt_path: &Path,
    quilt: &Quilt,
    svds: &[&SvdArtifact],
    paths: &[PathBuf],
    stage: &mut Stage,
) -> Result<()> {
    let r = quilt.resolution;
    let svd0 = svds[0];
    let (views, lights) = (&svd0.views, &svd0.lights);
    let several = svds.len() > 1;
    let samples: Vec<SampleFacts> = svds
        .iter()
        .zip(paths)
        .map(|(svd, path)| SampleFacts {
            path,
            w: svd.width,
            h: svd.height,
            n: svd.terms,
            tileable: svd.tileable(),
        })
        .collect();

    // synthesis.exr: per atlas texel the sample coordinate and frame (and,
    // with several samples, which one); a first pass over bands checks the
    // samples' extent, the second writes the bands the EXR writer asks for
    let mut covered = 0usize;
    let mut reach = vec![[0f32; 2]; svds.len()];
    for y0 in (0..r).step_by(BAND_ROWS) {
        let h = BAND_ROWS.min(r - y0);
        let coords = quilt.coord_region(0, y0, r, h)?;
        let patches = quilt.patch_region(0, y0, r, h)?;
        let index = quilt.sample_region(0, y0, r, h)?;
        for t in 0..r * h {
            if patches[t] == NO_PATCH {
                continue;
            }
            covered += 1;
            let ([x, y], k) = (coords[t], index[t] as usize);
            reach[k] = [reach[k][0].max(x.abs()), reach[k][1].max(y.abs())];
        }
    }
    for (k, s) in samples.iter().enumerate() {
        if !s.tileable && (reach[k][0] > s.w as f32 || reach[k][1] > s.h as f32) {
            let whose = if several {
                format!(" for its texels of sample {k}")
            } else {
                String::new()
            };
            return Err(Error::input(
                s.path,
                format!(
                    "is {}×{} but {} has sample coordinates up to ({}, {}){whose}: not the sample it was tiled with",
                    s.w,
                    s.h,
                    quilt_path.display(),
                    reach[k][0],
                    reach[k][1]
                ),
            ));
        }
    }
    let path = stage.publish("synthesis.exr");
    let names = ["u", "v", "angle", "dudX", "dvdX", "dudY", "dvdY", "sample"];
    if several {
        write_synthesis(quilt, &path, names)?;
    } else {
        write_synthesis(quilt, &path, std::array::from_fn::<_, 7, _>(|c| names[c]))?;
    }

    for (k, svd) in svds.iter().enumerate() {
        stage_factors(svd, k, views, lights, stage)?;
    }

    // directions.csv: both lists, with unit vectors in the sample frame
    let out = stage.publish("directions.csv");
    imageio::write_atomic(&out, |f| {
        let io = |e| Error::io(&out, e);
        writeln!(f, "set,index,theta,phi,x,y,z").map_err(io)?;
        for (set, list) in [("view", views), ("light", lights)] {
            for (i, a) in list.iter().enumerate() {
                let (st, ct) = (a.theta as f64).to_radians().sin_cos();
                let (sp, cp) = (a.phi as f64).to_radians().sin_cos();
                writeln!(
                    f,
                    "{set},{i},{},{},{},{},{}",
                    num(a.theta),
                    num(a.phi),
                    num((st * cp) as f32),
                    num((st * sp) as f32),
                    num(ct as f32)
                )
                .map_err(io)?;
            }
        }
        Ok(())
    })?;

    let facts = Facts {
        quilt: quilt_path,
        samples,
        r,
        views: views.len(),
        lights: lights.len(),
        covered,
    };
    let out = stage.publish("FORMAT.md");
    let text = format_md(&facts);
    imageio::write_atomic(&out, |f| {
        f.write_all(text.as_bytes()).map_err(|e| Error::io(&out, e))
    })
}

/// `synthesis.exr` of `quilt`: per covered texel its sample coordinate, the
/// frame's angle and Jacobian (and, with 8 channels, its sample index); NaN
/// elsewhere. Computed by bands of rows as the EXR writer asks for them, the
/// last four held.
fn write_synthesis<const N: usize>(quilt: &Quilt, path: &Path, names: [&str; N]) -> Result<()> {
    let r = quilt.resolution;
    let band = |y0: usize| -> Result<Vec<f32>> {
        let h = BAND_ROWS.min(r - y0);
        let coords = quilt.coord_region(0, y0, r, h)?;
        let patches = quilt.patch_region(0, y0, r, h)?;
        let index = quilt.sample_region(0, y0, r, h)?;
        let jac = quilt
            .jacobian_region(0, y0, r, h)?
            .ok_or_else(|| Error::input(quilt.container().path(), "it stores no 'jacobian' array"))?;
        let mut out = vec![f32::NAN; r * h * N];
        for t in 0..r * h {
            if patches[t] == NO_PATCH {
                continue;
            }
            let ([x, y], j) = (coords[t], jac[t]);
            let values = [
                x,
                y,
                j[1].atan2(j[0]).to_degrees(),
                j[0],
                j[1],
                j[2],
                j[3],
                index[t] as f32,
            ];
            out[t * N..(t + 1) * N].copy_from_slice(&values[..N]);
        }
        Ok(out)
    };
    let held = Mutex::new(BoundedCache::<usize, Vec<f32>>::new(MemoryBudget(
        (4 * BAND_ROWS * r * N * 4) as u64,
    )));
    imageio::write_exr_f32_fn(path, r, r, names, |x, y| {
        let mut cache = crate::lock(&held);
        let b = y / BAND_ROWS;
        if !cache.contains(&b) {
            let values = band(b * BAND_ROWS)?;
            let bytes = (values.len() * 4) as u64;
            cache.insert(b, values, bytes);
        }
        let values = cache.get(&b).expect("just inserted");
        let i = ((y - b * BAND_ROWS) * r + x) * N;
        Ok(std::array::from_fn(|c| values[i + c]))
    })
}

/// Writes sample `k`'s factorization: its geometry maps (one f32 channel
/// per term), its appearance table (one row per direction pair of the
/// shared `views` × `lights`) and its singular values, under
/// [`sample_file`] names.
fn stage_factors(
    svd: &SvdArtifact,
    k: usize,
    views: &[crate::artifact::btf::Angles],
    lights: &[crate::artifact::btf::Angles],
    stage: &mut Stage,
) -> Result<()> {
    let (w, h, n) = (svd.width, svd.height, svd.terms);
    let pairs = views.len() * lights.len();

    // geometry_maps.exr: the n maps of the sample, one f32 channel each
    let g = svd.geometry_maps()?;
    let gnames = term_names("g", n);
    let channels: Vec<(String, Vec<f32>)> = gnames
        .iter()
        .enumerate()
        .map(|(i, name)| (name.clone(), g.iter().skip(i).step_by(n).copied().collect()))
        .collect();
    drop(g);
    let out = stage.publish(&sample_file("geometry_maps", k, "exr"));
    imageio::write_exr_channels(&out, w, h, &channels, false)?;
    drop(channels);

    // appearance.csv: p_i(pair, c), one row per pair
    let p = svd.appearance()?;
    let out = stage.publish(&sample_file("appearance", k, "csv"));
    imageio::write_atomic(&out, |f| {
        let io = |e| Error::io(&out, e);
        let mut head = String::from("pair,view_theta,view_phi,light_theta,light_phi");
        for c in ["r", "g", "b"] {
            for name in term_names(c, n) {
                head.push(',');
                head += &name;
            }
        }
        writeln!(f, "{head}").map_err(io)?;
        let mut line = String::new();
        for (pair, row) in p.chunks_exact(3 * n).enumerate().take(pairs) {
            let (v, l) = (views[pair / lights.len()], lights[pair % lights.len()]);
            line.clear();
            let _ = write!(
                line,
                "{pair},{},{},{},{}",
                num(v.theta),
                num(v.phi),
                num(l.theta),
                num(l.phi)
            );
            for &x in row {
                line.push(',');
                line += &num(x);
            }
            writeln!(f, "{line}").map_err(io)?;
        }
        Ok(())
    })?;
    drop(p);

    let sigma = svd.singular_values()?;
    let out = stage.publish(&sample_file("singular_values", k, "csv"));
    imageio::write_atomic(&out, |f| {
        let io = |e| Error::io(&out, e);
        writeln!(f, "term,sigma").map_err(io)?;
        for (i, s) in sigma.iter().enumerate() {
            writeln!(f, "{i},{}", num(*s)).map_err(io)?;
        }
        Ok(())
    })
}

/// What FORMAT.md says about one sample.
struct SampleFacts<'a> {
    path: &'a Path,
    w: usize,
    h: usize,
    n: usize,
    tileable: bool,
}

struct Facts<'a> {
    quilt: &'a Path,
    /// In [`Quilt::samples`] order.
    samples: Vec<SampleFacts<'a>>,
    r: usize,
    views: usize,
    lights: usize,
    covered: usize,
}

/// The description written beside a surface BTF export.
fn format_md(f: &Facts) -> String {
    let s0 = &f.samples[0];
    let several = f.samples.len() > 1;
    let last = |c: &str| term_names(c, s0.n).pop().unwrap_or_default();
    let (gl, rl, bl) = (last("g"), last("r"), last("b"));
    let pairs = f.views * f.lights;
    let sample = if several {
        let paths: Vec<String> = f
            .samples
            .iter()
            .map(|s| format!("`{}`", s.path.display()))
            .collect();
        format!("samples {}", paths.join(", "))
    } else {
        format!("sample `{}`", s0.path.display())
    };
    let intro = if several {
        format!(
            "A decorated surface: every covered atlas texel of the mesh shows a point of\n\
             one of {count} BTF samples (channel `sample` of `synthesis.exr`), and each\n\
             sample is given as its own rank-n factorization. Here: atlas R×R = {r}×{r}\n\
             ({covered} of {texels} texels covered), {views} views × {lights} lights =\n\
             {pairs} direction pairs shared by all samples:\n\n{samples}\n",
            count = f.samples.len(),
            r = f.r,
            covered = f.covered,
            texels = f.r * f.r,
            samples = f
                .samples
                .iter()
                .enumerate()
                .map(|(k, s)| format!(
                    "- sample {k} (`{}`): W×H = {}×{}, n = {} terms",
                    s.path.display(),
                    s.w,
                    s.h,
                    s.n
                ))
                .collect::<Vec<_>>()
                .join("\n"),
            views = f.views,
            lights = f.lights,
        )
    } else {
        format!(
            "A decorated surface: every covered atlas texel of the mesh shows a point of\n\
             a BTF sample, and the sample is given as its rank-n factorization. Here:\n\
             atlas R×R = {r}×{r} ({covered} of {texels} texels covered), sample W×H =\n\
             {w}×{h}, n = {n} terms, {views} views × {lights} lights = {pairs} direction pairs.",
            r = f.r,
            covered = f.covered,
            texels = f.r * f.r,
            w = s0.w,
            h = s0.h,
            n = s0.n,
            views = f.views,
            lights = f.lights,
        )
    };
    let sample_channel = if several { ", `sample`" } else { "" };
    let mut more_files = String::new();
    for k in 1..f.samples.len() {
        let _ = writeln!(
            more_files,
            "| `{}`, `{}`, `{}` | sample {k}'s, laid out as sample 0's (its own W×H and n) |",
            sample_file("geometry_maps", k, "exr"),
            sample_file("appearance", k, "csv"),
            sample_file("singular_values", k, "csv"),
        );
    }
    let wrap = "coordinates may lie outside it and wrap (x mod W, y mod H, also for the +1 neighbour of the bilinear lookup)";
    let clamp =
        "coordinates lie in [0, W−1]×[0, H−1]; clamp the +1 neighbour of the bilinear lookup at the border";
    let edge = if !several {
        if s0.tileable {
            format!("the sample was factorized `--tileable`: {wrap}")
        } else {
            clamp.to_string()
        }
    } else {
        let tileable: Vec<String> = (0..f.samples.len())
            .filter(|&k| f.samples[k].tileable)
            .map(|k| k.to_string())
            .collect();
        if tileable.is_empty() {
            format!("in every sample {clamp}")
        } else {
            format!(
                "in a sample factorized `--tileable` (here: sample {}) {wrap}; in the others {clamp}",
                tileable.join(", ")
            )
        }
    };
    let sample_texel = if several {
        "\n\n`sample` = the index of the sample the texel shows (0, 1, …, a whole\n\
         number stored as f32): `u`, `v` and the Jacobian are in that sample's pixels."
    } else {
        ""
    };
    let reconstruct_several = if several {
        "\n\nWith several samples, take everything from the texel's own sample s\n\
         (channel `sample`): g_i from `geometry_maps.exr` for s = 0, else\n\
         `geometry_maps_s.exr`; p_i from `appearance.csv`, else `appearance_s.csv`;\n\
         n its number of terms. The g of one sample mean nothing in another's basis:\n\
         never mix one sample's g with another's p, nor blend g vectors of texels\n\
         from different samples; filter across such texels by blending their\n\
         values. The pairs (rows) are the same in every appearance table."
    } else {
        ""
    };
    format!(
        r#"# Surface BTF export

Written by btfquilt {version} from `{quilt}` ({sample}).

{intro}
The mesh with the same atlas uvs: `btfquilt export FILE --format gltf -o DIR`
(`mesh.glb`, `TEXCOORD_0`) or `--format obj` (OBJ's `vt` is y-up: 1 − v).

| file | contents |
|---|---|
| `synthesis.exr` | R×R, f32 channels `u`, `v`, `angle`, `dudX`, `dvdX`, `dudY`, `dvdY`{sample_channel} |
| `geometry_maps.exr` | W×H, f32 channels `g00` … `{gl}`: g_i = σ_i u_i |
| `appearance.csv` | one row per pair: `pair,view_theta,view_phi,light_theta,light_phi,r00..{rl},g00..{gl},b00..{bl}` |
| `directions.csv` | `set,index,theta,phi,x,y,z`: the view list, then the light list |
| `singular_values.csv` | `term,sigma`: σ_i (already folded into g_i; for information) |
{more_files}
CSV: a header row, comma separated, numbers in the shortest decimal that
reads back to the same f32. EXR: scanlines, ZIP compression, lossless f32;
channels are stored in name order, look them up by name.

## Coordinates

- Atlas texel (X, Y): column X, row Y, row 0 at the top. Its centre is uv
  ((X + 0.5)/R, (Y + 0.5)/R) in glTF's convention (origin top left, v down).
- Sample pixel coordinate (x, y): column x, row y, y down, *pixel centres at
  integers* (pixel (i, j) is the point (i, j), not (i + 0.5, j + 0.5)); {edge}.

## synthesis.exr

For a covered texel: `u`, `v` = the sample pixel coordinate (x, y) it shows
(in the unrotated sample); `dudX`, `dvdX` = the sample offset, in pixels, for
one texel step along atlas +X, `dudY`, `dvdY` along +Y (the Jacobian
J = [[dudX, dudY], [dvdX, dvdY]]); `angle` = atan2(dvdX, dudX) in degrees,
[−180, 180]: the direction in the sample that the atlas +X axis points to
(so the sample's +x axis lies at −angle from atlas +X when J is a rotation
and scale). **Empty texels** (the gutter between charts) are **NaN in every
channel**. Look texels up with nearest filtering: neighbouring texels may come
from different patches of the sample.{sample_texel}

## Reconstruction

The BTF value of covered texel (X, Y), direction pair `pair`, colour c ∈
{{r, g, b}}, linear (scene-referred, not sRGB):

    value = Σ_{{i<n}} g_i(u, v) · p_i(pair, c)

with (u, v) from `synthesis.exr` at (X, Y), g_i(u, v) bilinear in
`geometry_maps.exr` (x0 = ⌊u⌋, fx = u − x0, x1 = x0 + 1, likewise y; top =
g(x0,y0) + (g(x1,y0) − g(x0,y0))·fx, bottom the same on row y1, value = top +
(bottom − top)·fy), and p_i(pair, c) in row `pair` of `appearance.csv`,
column c followed by i zero-padded as in the header (`r07`: red, term 7). pair = view · {lights} + light,
both 0-based indices into `directions.csv`. The sum is linear, so summing the
sample first and interpolating afterwards gives the same value.{reconstruct_several}

## Directions and the frame

θ (from the surface normal) and φ (azimuth) are in degrees; `x,y,z` =
(sinθ cosφ, sinθ sinφ, cosθ) in the *sample frame*: x along sample +x
(columns), y along sample +y (rows, down the image), z the outward surface
normal. Directions point away from the surface (to the eye, to the light).

To shade a surface point with outward unit normal N: take the atlas tangents
T_X = ∂P/∂X and T_Y = ∂P/∂Y (position per texel; from a triangle's positions
and uvs, with X = R·u, Y = R·v), and J⁻¹ = [[a, b], [c, d]] from the texel's
Jacobian. The sample axes on the surface are e_x = a·T_X + c·T_Y and
e_y = b·T_X + d·T_Y; make them tangent (subtract their N component) and unit.
A unit world direction ω then has sample-frame components (ω·e_x, ω·e_y,
ω·N): θ = acos(ω·N), φ = atan2(ω·e_y, ω·e_x). Use the components as they are
even where (e_x, e_y, N) is left-handed (a mirrored chart). Take the nearest
listed view and light (or blend neighbours) to find `pair`.
"#,
        version = env!("CARGO_PKG_VERSION"),
        quilt = f.quilt.display(),
        sample = sample,
        intro = intro,
        sample_channel = sample_channel,
        more_files = more_files,
        gl = gl,
        rl = rl,
        bl = bl,
        edge = edge,
        lights = f.lights,
        sample_texel = sample_texel,
        reconstruct_several = reconstruct_several,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1×1 PNG (just the signature matters to `glb_bytes`).
    const PNG: &[u8] = b"\x89PNG\r\n\x1a\nnot really an image";

    fn json_chunk(glb: &[u8]) -> &str {
        let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
        std::str::from_utf8(&glb[20..20 + len]).unwrap()
    }

    /// The glTF JSON's exact text: key order, no whitespace, numbers as Rust
    /// prints them (`1`, `-0`, no exponents), as files have always been
    /// written.
    #[test]
    fn glb_json_text_is_pinned() {
        let mesh = SplitMesh {
            positions: vec![[-0.0, 0.1, -1e-7], [1.5, 2e20, -3.25], [0.0, 1e-30, 7.0]],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            uvs: vec![[0.0, 0.0], [1.0, 0.5], [0.25, 1.0]],
            triangles: vec![[0, 1, 2]],
            source: vec![0, 1, 2],
        };
        let glb = glb_bytes(&mesh, PNG).unwrap();
        let expected = concat!(
            r#"{"asset":{"version":"2.0","generator":"btfquilt "#,
            env!("CARGO_PKG_VERSION"),
            r#""},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0,"name":"mesh"}],"#,
            r#""meshes":[{"name":"mesh","primitives":[{"attributes":{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2},"#,
            r#""indices":3,"material":0,"mode":4}]}],"#,
            r#""materials":[{"name":"atlas","pbrMetallicRoughness":{"baseColorTexture":{"index":0,"texCoord":0},"#,
            r#""baseColorFactor":[1,1,1,1],"metallicFactor":0,"roughnessFactor":1},"doubleSided":false}],"#,
            r#""textures":[{"sampler":0,"source":0}],"images":[{"name":"atlas","bufferView":4,"mimeType":"image/png"}],"#,
            r#""samplers":[{"magFilter":9729,"minFilter":9987,"wrapS":33071,"wrapT":33071}],"#,
            r#""accessors":[{"bufferView":0,"byteOffset":0,"componentType":5126,"count":3,"type":"VEC3","#,
            r#""min":[-0,0.0000000000000000000000000000010000000031710769,-3.25],"max":[1.5,200000004008175470000,7]},"#,
            r#"{"bufferView":1,"byteOffset":0,"componentType":5126,"count":3,"type":"VEC3"},"#,
            r#"{"bufferView":2,"byteOffset":0,"componentType":5126,"count":3,"type":"VEC2"},"#,
            r#"{"bufferView":3,"byteOffset":0,"componentType":5125,"count":3,"type":"SCALAR"}],"#,
            r#""bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36,"target":34962},"#,
            r#"{"buffer":0,"byteOffset":36,"byteLength":36,"target":34962},"#,
            r#"{"buffer":0,"byteOffset":72,"byteLength":24,"target":34962},"#,
            r#"{"buffer":0,"byteOffset":96,"byteLength":12,"target":34963},"#,
            r#"{"buffer":0,"byteOffset":108,"byteLength":27}],"buffers":[{"byteLength":135}]}"#
        );
        let json = json_chunk(&glb);
        assert_eq!(json.trim_end_matches(' '), expected);
        // and it is JSON with the four accessors and five buffer views
        let v: serde_json::Value = serde_json::from_str(json).unwrap();
        assert_eq!(v["accessors"].as_array().map(Vec::len), Some(4));
        assert_eq!(v["bufferViews"].as_array().map(Vec::len), Some(5));
        assert_eq!(v["accessors"][0]["max"][1].as_f64(), Some(2e20f32 as f64));
    }
}
