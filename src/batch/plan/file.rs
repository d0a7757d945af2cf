//! The plan file as written: its TOML sections and their defaults.

use super::*;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PlanFile {
    #[serde(default)]
    pub(super) mesh: Vec<MeshEntry>,
    #[serde(default)]
    pub(super) sample: Vec<SampleEntry>,
    #[serde(default)]
    pub(super) atlas: AtlasSection,
    #[serde(default)]
    pub(super) factorize: FactorizeSection,
    #[serde(default)]
    pub(super) tile: TileSection,
    #[serde(default)]
    pub(super) render: RenderSection,
    #[serde(default)]
    pub(super) outputs: Outputs,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MeshEntry {
    pub(super) path: PathBuf,
    pub(super) name: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SampleEntry {
    pub(super) path: PathBuf,
    pub(super) mask: Option<PathBuf>,
    pub(super) name: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AtlasSection {
    #[serde(default = "default_resolutions")]
    pub(super) resolutions: Vec<usize>,
    #[serde(default = "default_gutter")]
    pub(super) gutter: usize,
}

fn default_resolutions() -> Vec<usize> {
    vec![AtlasConfig::default().resolution]
}

fn default_gutter() -> usize {
    AtlasConfig::default().gutter
}

impl Default for AtlasSection {
    fn default() -> Self {
        AtlasSection {
            resolutions: default_resolutions(),
            gutter: default_gutter(),
        }
    }
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FactorizeSection {
    pub(super) terms: Option<usize>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TileSection {
    #[serde(default = "default_seeds")]
    pub(super) seeds: Vec<u64>,
    /// Absent or empty: one sample pixel per atlas texel.
    #[serde(default)]
    pub(super) sample_widths: Vec<f64>,
    pub(super) seam_threshold: Option<f64>,
    pub(super) occurrence_weight: Option<f64>,
    pub(super) tolerance: Option<f64>,
    pub(super) structure_weight: Option<f64>,
    pub(super) feature_align: Option<f64>,
    pub(super) field_turn: Option<usize>,
    /// 0 turns seam refinement off.
    pub(super) refine: Option<f64>,
    pub(super) refine_broken: Option<usize>,
    pub(super) refine_passes: Option<usize>,
    /// "free" or "locked", as `tile --courses`.
    pub(super) courses: Option<CourseMode>,
    /// As `tile --match-terms` (0: every term).
    pub(super) match_terms: Option<usize>,
}

fn default_seeds() -> Vec<u64> {
    vec![TileConfig::default().seed]
}

impl Default for TileSection {
    fn default() -> Self {
        TileSection {
            seeds: default_seeds(),
            sample_widths: Vec::new(),
            seam_threshold: None,
            occurrence_weight: None,
            tolerance: None,
            structure_weight: None,
            feature_align: None,
            field_turn: None,
            refine: None,
            refine_broken: None,
            refine_passes: None,
            courses: None,
            match_terms: None,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RenderSection {
    pub(super) width: Option<usize>,
    pub(super) height: Option<usize>,
    pub(super) exposure: Option<f32>,
    /// "auto" (a three-quarter view framing the mesh) or `render --camera`'s
    /// ten numbers.
    #[serde(default = "default_cameras")]
    pub(super) cameras: Vec<String>,
    /// `render --light`'s `x,y,z[,intensity]`: one render per light; absent:
    /// `render`'s default light.
    pub(super) lights: Option<Vec<String>>,
}

fn default_cameras() -> Vec<String> {
    vec!["auto".into()]
}

impl Default for RenderSection {
    fn default() -> Self {
        RenderSection {
            width: None,
            height: None,
            exposure: None,
            cameras: default_cameras(),
            lights: None,
        }
    }
}

/// The outputs a job writes besides its decorated surface
/// (`decorated.quilt`, always).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Outputs {
    /// The atlas texture, `baked.png`.
    #[serde(default = "yes")]
    pub bake: bool,
    /// One picture per camera and light, `render-cC-lL.png`.
    #[serde(default = "yes")]
    pub render: bool,
    /// The textured mesh as binary glTF, `gltf/mesh.glb`.
    #[serde(default)]
    pub gltf: bool,
    /// The surface BTF, `surface-btf/`.
    #[serde(default)]
    pub btf: bool,
}

fn yes() -> bool {
    true
}

impl Default for Outputs {
    fn default() -> Self {
        Outputs {
            bake: true,
            render: true,
            gltf: false,
            btf: false,
        }
    }
}
