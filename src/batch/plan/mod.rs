//! A batch plan (`plan.toml`): the inputs, the product of parameters, and
//! the outputs wanted; expanded into content-addressed jobs and the shared
//! stages they need.
//!
//! ```toml
//! [[mesh]]
//! path = "meshes/spot.obj"      # relative to the plan's folder
//! [[sample]]
//! path = "samples/wall.png"     # a colour image, a .btf or a .svd
//! mask = "samples/wall.mask.png" # optional: its foreground, kept out of the tiling
//! [atlas]
//! resolutions = [512, 1024]
//! [tile]
//! seeds = [1, 2, 3]
//! sample_widths = [0.5, 1.0]    # mesh units; omitted: one sample pixel per texel
//! [render]
//! cameras = ["auto"]
//! lights = ["0.4,0.8,0.6", "-0.6,0.3,0.7"]
//! [outputs]
//! bake = true
//! render = true
//! gltf = true
//! btf = false
//! ```
//!
//! A job is one decorated surface: mesh × resolution × sample × seed ×
//! sample width, with every render (camera × light) and export the plan
//! asks for. Its key hashes its inputs' content hashes and every parameter
//! that reaches its outputs ([`JobSpec`]), so the same job always gets the
//! same folder and any change to what it depends on gives a new one.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::atlas::AtlasConfig;
use crate::factorize::FactorizeConfig;
use crate::output::render::{Camera, Light, RenderConfig};
use crate::quilt::{CourseMode, TileConfig};
use crate::{Error, Result};

mod file;
mod shard;
pub use file::*;
pub use shard::*;

/// Version of the job description: part of every key, raised whenever a
/// job's outputs would change for the same description.
const SPEC_VERSION: u32 = 1;

/// A 128-bit content key, written as 32 hexadecimal digits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Key(pub u128);

impl Key {
    /// The key of a serializable description (its JSON text, which serde
    /// writes in field order with exact numbers).
    pub fn of<T: Serialize>(value: &T) -> Key {
        let text = serde_json::to_vec(value).expect("plain data serializes");
        Key(xxhash_rust::xxh3::xxh3_128(&text))
    }

    /// Parses 32 hexadecimal digits.
    pub fn parse(s: &str) -> Option<Key> {
        (s.len() == 32)
            .then(|| u128::from_str_radix(s, 16).ok())
            .flatten()
            .map(Key)
    }
}

impl std::fmt::Display for Key {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:032x}", self.0)
    }
}

impl Serialize for Key {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

// ---------------------------------------------------------------- the plan

/// An input file of the plan, with its content identity.
#[derive(Clone, Debug)]
pub struct Input {
    /// The name listings show (the plan's `name`, else the file stem).
    pub name: String,
    /// The file, resolved against the plan's folder.
    pub path: PathBuf,
    /// Its identity: length and content hash (a container's own content
    /// hash, else xxh3 of the bytes).
    pub id: InputId,
}

/// What identifies an input's content, and the name of its copy in the
/// output folder's `inputs/`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct InputId {
    /// `inputs/HASH-BYTES.EXT`, the copy every artifact of the batch refers to.
    pub file: String,
    pub bytes: u64,
    pub hash: String,
}

/// A sample of the plan and its optional foreground mask.
#[derive(Clone, Debug)]
pub struct SampleInput {
    pub input: Input,
    pub mask: Option<Input>,
}

impl SampleInput {
    /// Whether the sample is already a factorization.
    pub fn is_svd(&self) -> bool {
        has_ext(&self.input.path, "svd")
    }
}

/// A render of each job: a camera (`None`: framing the mesh) and one
/// directional light.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RenderSpec {
    pub file: String,
    /// eye, target, up, fov; absent: a three-quarter view framing the mesh.
    pub camera: Option<[f32; 10]>,
    /// Towards the light, and its intensity.
    pub light: [f32; 4],
}

impl RenderSpec {
    /// The render's configuration.
    pub fn config(&self, plan: &Plan) -> RenderConfig {
        let c = self.camera;
        RenderConfig {
            camera: c.map(|c| Camera {
                eye: [c[0], c[1], c[2]],
                target: [c[3], c[4], c[5]],
                up: [c[6], c[7], c[8]],
                fov: c[9],
            }),
            lights: vec![Light::Directional {
                direction: [self.light[0], self.light[1], self.light[2]],
                intensity: self.light[3],
            }],
            width: plan.render.width,
            height: plan.render.height,
            exposure: plan.render.exposure,
        }
    }
}

/// A parsed, checked plan.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The plan file.
    pub path: PathBuf,
    pub meshes: Vec<Input>,
    pub samples: Vec<SampleInput>,
    pub resolutions: Vec<usize>,
    pub gutter: usize,
    pub terms: Option<usize>,
    pub seeds: Vec<u64>,
    /// `None`: one sample pixel per texel.
    pub sample_widths: Vec<Option<f64>>,
    /// The tiling's options besides seed, size and mask.
    pub tile: TileParams,
    /// Size and exposure of every render ([`RenderConfig`]'s, cameras and
    /// lights taken from `renders`).
    pub render: RenderConfig,
    pub renders: Vec<RenderSpec>,
    pub outputs: Outputs,
}

/// The tiling options a plan may set, as they enter a job's key.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TileParams {
    pub seam_threshold: f64,
    pub occurrence_weight: f64,
    pub tolerance: f64,
    pub structure_weight: f64,
    /// Left out of the key at 0 (rigid patches), so a job with rigid
    /// patches keeps the key it had before the option existed: its outputs
    /// are the same.
    #[serde(skip_serializing_if = "is_zero")]
    pub feature_align: f64,
    pub field_turn: usize,
    pub refine: Option<f64>,
    /// Left out of the key at 0 (off) and 1, as `feature_align` at 0.
    #[serde(skip_serializing_if = "is_zero_count")]
    pub refine_broken: usize,
    #[serde(skip_serializing_if = "is_one")]
    pub refine_passes: usize,
    /// Left out of the key when free, as `feature_align` at 0.
    #[serde(skip_serializing_if = "is_free")]
    pub courses: CourseMode,
    /// Left out of the key at 0 (every term), as `feature_align` at 0.
    #[serde(skip_serializing_if = "is_zero_count")]
    pub match_terms: usize,
}

fn is_free(v: &CourseMode) -> bool {
    *v == CourseMode::Free
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_zero_count(v: &usize) -> bool {
    *v == 0
}

fn is_one(v: &usize) -> bool {
    *v == 1
}

/// A stage whose artifact several jobs share, computed once into
/// `shared/`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SharedStage {
    /// The geometry image of mesh `mesh` at `resolution`.
    Atlas {
        mesh: usize,
        resolution: usize,
        key: Key,
    },
    /// The factorization of sample `sample`.
    Factorize { sample: usize, key: Key },
}

impl SharedStage {
    /// The stage's key.
    pub fn key(&self) -> Key {
        match self {
            SharedStage::Atlas { key, .. } | SharedStage::Factorize { key, .. } => *key,
        }
    }

    /// Its artifact, relative to the output folder.
    pub fn file(&self) -> String {
        match self {
            SharedStage::Atlas { key, .. } => format!("shared/atlas-{key}.gim"),
            SharedStage::Factorize { key, .. } => format!("shared/sample-{key}.svd"),
        }
    }
}

/// Everything a job's outputs depend on: its key is the hash of this.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JobSpec {
    pub version: u32,
    pub btfquilt: &'static str,
    pub mesh: InputId,
    pub resolution: usize,
    pub gutter: usize,
    pub sample: InputId,
    pub mask: Option<InputId>,
    /// Terms of the sample's factorization (`None`: the default; unused
    /// for a `.svd` sample).
    pub terms: Option<usize>,
    pub seed: u64,
    pub sample_width: Option<f64>,
    pub tile: TileParams,
    pub render_size: [usize; 2],
    pub exposure: f32,
    pub renders: Vec<RenderSpec>,
    pub outputs: Outputs,
}

/// One job of the plan.
#[derive(Clone, Debug)]
pub struct Job {
    pub key: Key,
    pub mesh: usize,
    pub sample: usize,
    pub resolution: usize,
    pub seed: u64,
    pub sample_width: Option<f64>,
    /// Its geometry image (shared).
    pub atlas: SharedStage,
    /// Its sample's factorization (shared), unless the sample is a `.svd`.
    pub factorization: Option<SharedStage>,
    pub spec: JobSpec,
}

impl Job {
    /// Its folder, relative to the output folder.
    pub fn dir(&self) -> String {
        format!("jobs/{}", self.key)
    }

    /// The sample file the tiling reads, relative to the output folder.
    pub fn sample_file(&self) -> String {
        match &self.factorization {
            Some(f) => f.file(),
            None => self.spec.sample.file.clone(),
        }
    }

    /// A one-line description for listings.
    pub fn describe(&self, plan: &Plan) -> String {
        let width = match self.sample_width {
            Some(w) => format!("width {w}"),
            None => "1 px/texel".into(),
        };
        format!(
            "{} {}² × {} seed {} {}",
            plan.meshes[self.mesh].name,
            self.resolution,
            plan.samples[self.sample].input.name,
            self.seed,
            width
        )
    }
}

fn has_ext(path: &Path, ext: &str) -> bool {
    path.extension()
        .is_some_and(|e| e.to_string_lossy().eq_ignore_ascii_case(ext))
}

/// The identity of an input named in the plan.
fn input(plan: &Path, what: &str, path: &Path, name: Option<String>) -> Result<Input> {
    let resolved = crate::io::staging::resolve_in_folder_of(plan, path);
    if !resolved.is_file() {
        return Err(Error::input(
            plan,
            format!(
                "{what} '{}': {} is not a file",
                path.display(),
                resolved.display()
            ),
        ));
    }
    let (bytes, hash) = crate::container::file_identity(&resolved)
        .map_err(|e| Error::input(plan, format!("{what} '{}': {e}", path.display())))?;
    let ext = resolved
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy().to_ascii_lowercase()))
        .unwrap_or_default();
    let name = name.unwrap_or_else(|| {
        resolved
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    });
    Ok(Input {
        name,
        path: resolved,
        id: InputId {
            file: format!("inputs/{hash:016x}-{bytes}{ext}"),
            bytes,
            hash: format!("{hash:016x}"),
        },
    })
}

impl Plan {
    /// Reads and checks the plan at `path`; every input it names must
    /// exist (their content is hashed here).
    pub fn load(path: &Path) -> Result<Plan> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Plan::parse(path, &text)
    }

    /// Parses plan `text` as if read from `path` (inputs resolve against
    /// its folder).
    pub fn parse(path: &Path, text: &str) -> Result<Plan> {
        let file: PlanFile =
            toml::from_str(text).map_err(|e| Error::input(path, format!("not a valid plan: {e}")))?;
        let bad = |reason: String| Error::input(path, reason);
        if file.mesh.is_empty() {
            return Err(bad("names no mesh: add [[mesh]] path = \"…\"".into()));
        }
        if file.sample.is_empty() {
            return Err(bad("names no sample: add [[sample]] path = \"…\"".into()));
        }
        let meshes = file
            .mesh
            .into_iter()
            .enumerate()
            .map(|(i, m)| input(path, &format!("mesh {}", i + 1), &m.path, m.name))
            .collect::<Result<Vec<_>>>()?;
        let mut samples = Vec::new();
        for (i, s) in file.sample.into_iter().enumerate() {
            let what = format!("sample {}", i + 1);
            let sample = input(path, &what, &s.path, s.name)?;
            let mask = match &s.mask {
                Some(m) => Some(input(path, &format!("{what}'s mask"), m, None)?),
                None => None,
            };
            samples.push(SampleInput { input: sample, mask });
        }
        for (what, list_empty) in [
            ("[atlas] resolutions", file.atlas.resolutions.is_empty()),
            ("[tile] seeds", file.tile.seeds.is_empty()),
            ("[render] cameras", file.render.cameras.is_empty()),
            (
                "[render] lights",
                file.render.lights.as_ref().is_some_and(|l| l.is_empty()),
            ),
        ] {
            if list_empty {
                return Err(bad(format!("{what} is empty: give at least one value")));
            }
        }
        for &r in &file.atlas.resolutions {
            AtlasConfig {
                resolution: r,
                gutter: file.atlas.gutter,
                ..AtlasConfig::default()
            }
            .validate()
            .map_err(|e| bad(format!("[atlas] resolutions: {e}")))?;
        }
        let factorize = FactorizeConfig {
            terms: file.factorize.terms,
            ..FactorizeConfig::default()
        };
        factorize
            .validate()
            .map_err(|e| bad(format!("[factorize] {e}")))?;
        let defaults = TileConfig::default();
        let t = &file.tile;
        let refine = match t.refine {
            Some(r) if r == 0.0 => None,
            Some(r) => Some(r),
            None => defaults.refine,
        };
        // refinement where features end is a part of seam refinement, and
        // its passes count only when it is on: what does nothing is left
        // at its off value, the same job with the same key
        let refine_broken = match refine {
            Some(_) => t.refine_broken.unwrap_or(defaults.refine_broken),
            None => 0,
        };
        let tile = TileParams {
            seam_threshold: t.seam_threshold.unwrap_or(defaults.seam_threshold),
            occurrence_weight: t.occurrence_weight.unwrap_or(defaults.occurrence_weight),
            tolerance: t.tolerance.unwrap_or(defaults.tolerance),
            structure_weight: t.structure_weight.unwrap_or(defaults.structure_weight),
            feature_align: t.feature_align.unwrap_or(defaults.feature_align),
            field_turn: t.field_turn.unwrap_or(defaults.field_turn),
            refine,
            refine_broken,
            refine_passes: if refine_broken == 0 {
                1
            } else {
                t.refine_passes.unwrap_or(defaults.refine_passes)
            },
            courses: t.courses.unwrap_or(defaults.courses),
            match_terms: t.match_terms.unwrap_or(defaults.match_terms),
        };
        let sample_widths: Vec<Option<f64>> = if t.sample_widths.is_empty() {
            vec![None]
        } else {
            t.sample_widths.iter().map(|&w| Some(w)).collect()
        };
        for &w in &sample_widths {
            let cfg = TileConfig {
                sample_width: w,
                ..tile_config(&tile, 1, None)
            };
            cfg.validate().map_err(|e| bad(format!("[tile] {e}")))?;
        }
        let r = &file.render;
        let base = RenderConfig::default();
        let render = RenderConfig {
            camera: None,
            lights: Vec::new(),
            width: r.width.unwrap_or(base.width),
            height: r.height.unwrap_or(base.height),
            exposure: r.exposure.unwrap_or(base.exposure),
        };
        render.validate().map_err(|e| bad(format!("[render] {e}")))?;
        let mut cameras = Vec::new();
        for c in &r.cameras {
            cameras.push(if c.trim() == "auto" {
                None
            } else {
                let c = Camera::parse(c).map_err(|e| bad(format!("[render] cameras: {e}")))?;
                let mut v = [0f32; 10];
                v[..3].copy_from_slice(&c.eye);
                v[3..6].copy_from_slice(&c.target);
                v[6..9].copy_from_slice(&c.up);
                v[9] = c.fov;
                Some(v)
            });
        }
        let mut lights = Vec::new();
        let light_texts = match &r.lights {
            Some(l) => l.clone(),
            None => {
                let Light::Directional { direction: d, .. } = Light::default() else {
                    unreachable!("the default light is directional")
                };
                vec![format!("{},{},{}", d[0], d[1], d[2])]
            }
        };
        for l in &light_texts {
            match Light::parse_directional(l).map_err(|e| bad(format!("[render] lights: {e}")))? {
                Light::Directional {
                    direction: d,
                    intensity,
                } => lights.push([d[0], d[1], d[2], intensity]),
                Light::Point { .. } => unreachable!("parse_directional gives a directional light"),
            }
        }
        let mut renders = Vec::new();
        if file.outputs.render {
            for (ci, &camera) in cameras.iter().enumerate() {
                for (li, &light) in lights.iter().enumerate() {
                    renders.push(RenderSpec {
                        file: format!("render-c{ci}-l{li}.png"),
                        camera,
                        light,
                    });
                }
            }
        }
        Ok(Plan {
            path: path.to_path_buf(),
            meshes,
            samples,
            resolutions: file.atlas.resolutions,
            gutter: file.atlas.gutter,
            terms: file.factorize.terms,
            seeds: file.tile.seeds,
            sample_widths,
            tile,
            render,
            renders,
            outputs: file.outputs,
        })
    }

    /// The geometry image of mesh `mesh` at `resolution`.
    pub fn atlas_stage(&self, mesh: usize, resolution: usize) -> SharedStage {
        #[derive(Serialize)]
        struct AtlasKey<'a> {
            stage: &'static str,
            version: u32,
            btfquilt: &'static str,
            mesh: &'a InputId,
            resolution: usize,
            gutter: usize,
        }
        let key = Key::of(&AtlasKey {
            stage: "atlas",
            version: SPEC_VERSION,
            btfquilt: env!("CARGO_PKG_VERSION"),
            mesh: &self.meshes[mesh].id,
            resolution,
            gutter: self.gutter,
        });
        SharedStage::Atlas {
            mesh,
            resolution,
            key,
        }
    }

    /// The factorization of sample `sample` (`None` for a `.svd`).
    pub fn factorize_stage(&self, sample: usize) -> Option<SharedStage> {
        #[derive(Serialize)]
        struct FactorizeKey<'a> {
            stage: &'static str,
            version: u32,
            btfquilt: &'static str,
            sample: &'a InputId,
            terms: Option<usize>,
        }
        if self.samples[sample].is_svd() {
            return None;
        }
        let key = Key::of(&FactorizeKey {
            stage: "factorize",
            version: SPEC_VERSION,
            btfquilt: env!("CARGO_PKG_VERSION"),
            sample: &self.samples[sample].input.id,
            terms: self.terms,
        });
        Some(SharedStage::Factorize { sample, key })
    }

    /// Every job, in shard order: grouped by geometry image and sample (so
    /// a shard's jobs share them), then by key.
    pub fn jobs(&self) -> Vec<Job> {
        let mut jobs = Vec::new();
        for (mi, mesh) in self.meshes.iter().enumerate() {
            for &resolution in &self.resolutions {
                let atlas = self.atlas_stage(mi, resolution);
                for (si, sample) in self.samples.iter().enumerate() {
                    let factorization = self.factorize_stage(si);
                    for &seed in &self.seeds {
                        for &sample_width in &self.sample_widths {
                            let spec = JobSpec {
                                version: SPEC_VERSION,
                                btfquilt: env!("CARGO_PKG_VERSION"),
                                mesh: mesh.id.clone(),
                                resolution,
                                gutter: self.gutter,
                                sample: sample.input.id.clone(),
                                mask: sample.mask.as_ref().map(|m| m.id.clone()),
                                terms: if sample.is_svd() { None } else { self.terms },
                                seed,
                                sample_width,
                                tile: self.tile.clone(),
                                render_size: [self.render.width, self.render.height],
                                exposure: self.render.exposure,
                                renders: self.renders.clone(),
                                outputs: self.outputs,
                            };
                            jobs.push(Job {
                                key: Key::of(&spec),
                                mesh: mi,
                                sample: si,
                                resolution,
                                seed,
                                sample_width,
                                atlas: atlas.clone(),
                                factorization: factorization.clone(),
                                spec,
                            });
                        }
                    }
                }
            }
        }
        jobs.sort_by_key(|j| (j.atlas.key(), j.factorization.as_ref().map(|f| f.key()), j.key));
        // the same description twice in a plan (a mesh listed twice) is one job
        jobs.dedup_by_key(|j| j.key);
        jobs
    }

    /// Every shared stage, by key.
    pub fn shared_stages(&self) -> Vec<SharedStage> {
        let mut stages: Vec<SharedStage> = Vec::new();
        for mi in 0..self.meshes.len() {
            for &r in &self.resolutions {
                stages.push(self.atlas_stage(mi, r));
            }
        }
        stages.extend((0..self.samples.len()).filter_map(|si| self.factorize_stage(si)));
        stages.sort_by_key(|s| s.key());
        stages.dedup_by_key(|s| s.key());
        stages
    }
}

/// The tiling configuration of a job (`memory` and `level` left at their
/// defaults: they change no output).
pub fn tile_config(p: &TileParams, seed: u64, sample_width: Option<f64>) -> TileConfig {
    TileConfig {
        seam_threshold: p.seam_threshold,
        occurrence_weight: p.occurrence_weight,
        tolerance: p.tolerance,
        structure_weight: p.structure_weight,
        feature_align: p.feature_align,
        field_turn: p.field_turn,
        refine: p.refine,
        refine_broken: p.refine_broken,
        refine_passes: p.refine_passes,
        courses: p.courses,
        match_terms: p.match_terms,
        seed,
        sample_width,
        ..TileConfig::default()
    }
}
