//! The command line's arguments: subcommands, shared option groups and
//! value parsers. Defaults come from the library's config types.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};

use btfquilt::artifact::btf::{self, Angles};
use btfquilt::atlas::AtlasConfig;
use btfquilt::batch;
use btfquilt::container::MemoryBudget;
use btfquilt::factorize::FactorizeConfig;
use btfquilt::generate::{Family, GenerateConfig, Imperfection};
use btfquilt::ingest::ImageFormat;
use btfquilt::output::evaluate;
use btfquilt::output::export::MeshFormat;
use btfquilt::output::render::{Camera, Light, RenderConfig};
use btfquilt::output::show::ShowWhat;
use btfquilt::paint::PaintConfig;
use btfquilt::quilt::{CourseMode, TileConfig};
use btfquilt::studio::ServeConfig;

use super::bars::Bars;

#[derive(Parser)]
#[command(
    name = "btfquilt",
    version,
    about = "Decorate meshes with textures and BTFs by graphcut quilting"
)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(super) command: Command,
}

/// Quilting options shared by `tile` and `paint` (defaults from [`TileConfig`]).
#[derive(Args, Clone)]
pub(super) struct Quilting {
    /// Work-patch radius r_w in texels (default 32 per 512 of atlas, at most a quarter of the sample).
    #[arg(long)]
    pub(super) patch_radius: Option<usize>,
    /// T_c: accept a patch if its mean seam cost ≤ this × the sample's neighbour difference.
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().seam_threshold)]
    pub(super) seam_threshold: f64,
    /// Weight of the constraint (data term per texel, in sample neighbour differences).
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().constraint_weight)]
    pub(super) constraint_weight: f64,
    #[arg(long, default_value_t = TileConfig::default().seed)]
    pub(super) seed: u64,
    /// The sample's size on the surface: mesh units its width spans (it is
    /// resampled to the atlas's texel density). Default: one sample pixel per
    /// texel; painting keeps the tiling's size (its sample at the tiling's
    /// width, another at the tiling sample's pixel size).
    #[arg(long, allow_negative_numbers = true)]
    pub(super) sample_width: Option<f64>,
    /// The sample's size on the surface per pixel: mesh units one sample
    /// pixel spans (instead of --sample-width).
    #[arg(long, allow_negative_numbers = true, conflicts_with = "sample_width")]
    pub(super) sample_pixel: Option<f64>,
}

impl Quilting {
    /// These options over [`TileConfig::default`].
    pub(super) fn tile_config(&self, memory: MemoryBudget) -> TileConfig {
        TileConfig {
            patch_radius: self.patch_radius,
            seam_threshold: self.seam_threshold,
            constraint_weight: self.constraint_weight,
            seed: self.seed,
            sample_width: self.sample_width,
            sample_pixel: self.sample_pixel,
            memory,
            ..TileConfig::default()
        }
    }
}

/// `tile`'s own options (defaults from [`TileConfig`]).
#[derive(Args, Clone)]
pub(super) struct Tiling {
    /// The sample's foreground mask (PNG, the sample's size): keep the
    /// foreground (cracks, stains…) out of the tiling.
    #[arg(long)]
    sample_mask: Option<PathBuf>,
    /// Seam refinement once covered: seams stepping more than this × the
    /// sample's neighbour difference get another work patch; 0 turns it off.
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().refine.unwrap_or(0.0))]
    refine: f64,
    /// Seam refinement fits this many distinct good placements per seam and
    /// keeps the cheapest cut (1: only the best match; more: lower seams,
    /// longer runs).
    #[arg(long, default_value_t = TileConfig::default().refine_placements)]
    refine_placements: usize,
    /// Seam refinement also visits seams where a feature ends (a mortar
    /// line or strand one side would carry on), whatever their colour
    /// step, fits this many placements there and keeps the one that ends
    /// fewest features; 0: off (one pass, whatever --refine-passes says).
    #[arg(long, default_value_t = TileConfig::default().refine_broken)]
    refine_broken: usize,
    /// With --refine-broken: passes over the seams where features still
    /// end (each refinement makes new seams); stops early when a pass
    /// changes nothing.
    #[arg(long, default_value_t = TileConfig::default().refine_passes)]
    refine_passes: usize,
    /// Work patches computed at once per round of the quilting loop (1: one
    /// at a time, as in the paper). Part of the recipe like the seed: the
    /// output depends on it, never on --threads.
    #[arg(long, default_value_t = TileConfig::default().round)]
    round: usize,
    /// Penalise sample regions in proportion to how often the surface
    /// already shows them (0 turns it off; higher: more of the sample's
    /// variety, at some cost in seam quality).
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().occurrence_weight)]
    occurrence_weight: f64,
    /// Choose among placements costing at most (1 + this) × the best one,
    /// by the seed (0: the best; higher: more variety, weaker seams).
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().tolerance)]
    tolerance: f64,
    /// Weight of the structure channel (distance to the sample's edges) in
    /// matching and seams, in sample neighbour differences (0: colour only).
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().structure_weight)]
    structure_weight: f64,
    /// Bend each new patch by up to this share of its radius so that its features
    /// meet the old texels of the overlap before the cut (0: rigid patches)
    #[arg(long, allow_negative_numbers = true, default_value_t = TileConfig::default().feature_align)]
    feature_align: f64,
    /// Let matching turn the sample up to this many rotation steps (5°) off the
    /// field's mean direction where the field turns inside a work patch (0: never).
    #[arg(long, default_value_t = TileConfig::default().field_turn)]
    field_turn: usize,
    /// For a sample whose features run in rows: `free` places each patch's
    /// courses where it matches best; `locked` bends every patch so its
    /// courses follow one stripe pattern along the field, unbroken across
    /// seams (ends only where the field forces them; see `evaluate
    /// --forced-ends`).
    #[arg(long, value_enum, ignore_case = true, default_value_t = TileConfig::default().courses)]
    courses: CourseMode,
    /// Match samples longer than this many pixels a side (after resampling)
    /// coarse to fine: on copies averaged down to at most this size, then
    /// exactly around the best coarse placements (0: always at full
    /// resolution). Part of the recipe like the seed.
    #[arg(long, default_value_t = TileConfig::default().coarse_above)]
    coarse_above: usize,
    /// Match on this many leading geometry-map terms of a BTF sample; the
    /// seams' cut cost and every output keep all of them (0: every term).
    /// Part of the recipe like the seed.
    #[arg(long, default_value_t = TileConfig::default().match_terms)]
    match_terms: usize,
}

impl Tiling {
    /// These options over `base`.
    pub(super) fn tile_config(self, base: TileConfig) -> TileConfig {
        TileConfig {
            sample_mask: self.sample_mask,
            refine: (self.refine != 0.0).then_some(self.refine),
            refine_placements: self.refine_placements,
            refine_broken: self.refine_broken,
            refine_passes: self.refine_passes,
            round: self.round,
            occurrence_weight: self.occurrence_weight,
            tolerance: self.tolerance,
            structure_weight: self.structure_weight,
            feature_align: self.feature_align,
            field_turn: self.field_turn,
            courses: self.courses,
            coarse_above: self.coarse_above,
            match_terms: self.match_terms,
            ..base
        }
    }
}

/// The options of `generate-btf` that describe the BTF.
#[derive(Args)]
pub(super) struct Generating {
    /// The material family.
    #[arg(long, value_enum, ignore_case = true, default_value_t = GenerateConfig::default().family)]
    family: Family,
    /// The imperfection layer (its mask is written beside the output as *.mask.png).
    #[arg(long, value_enum, ignore_case = true, default_value_t = GenerateConfig::default().imperfection)]
    imperfection: Imperfection,
    /// Texels per side (width = height).
    #[arg(long, default_value_t = GenerateConfig::default().width)]
    size: usize,
    /// View directions as PHIxTHETA.
    #[arg(long, value_parser = parse_grid, default_value_t = Grid(GenerateConfig::default().views))]
    views: Grid,
    /// Light directions as PHIxTHETA.
    #[arg(long, value_parser = parse_grid, default_value_t = Grid(GenerateConfig::default().lights))]
    lights: Grid,
    #[arg(long, default_value_t = GenerateConfig::default().seed)]
    seed: u64,
}

impl Generating {
    /// The generator's configuration with these options and `memory`.
    pub(super) fn generate_config(self, memory: MemoryBudget) -> GenerateConfig {
        GenerateConfig {
            family: self.family,
            imperfection: self.imperfection,
            width: self.size,
            height: self.size,
            views: self.views.0,
            lights: self.lights.0,
            seed: self.seed,
            memory,
            ..GenerateConfig::default()
        }
    }
}

/// The options of `factorize` that shape the factorization.
#[derive(Args)]
pub(super) struct Factorizing {
    /// Number of terms n (default 40, or fewer if the matrix is smaller).
    #[arg(long)]
    terms: Option<usize>,
    /// Oversampling p of the randomized SVD.
    #[arg(long, default_value_t = FactorizeConfig::default().oversampling)]
    oversampling: usize,
    /// Power iterations q of the randomized SVD.
    #[arg(long, default_value_t = FactorizeConfig::default().power_iterations)]
    power_iterations: usize,
    /// Rotated copies of the geometry maps (5° steps for 72).
    #[arg(long, default_value_t = FactorizeConfig::default().rotations)]
    rotations: usize,
    /// The sample wraps around: rotated copies sample it toroidally.
    #[arg(long)]
    tileable: bool,
    #[arg(long, default_value_t = FactorizeConfig::default().seed)]
    seed: u64,
}

impl Factorizing {
    /// The factorization's configuration with these options and `memory`.
    pub(super) fn factorize_config(self, memory: MemoryBudget) -> FactorizeConfig {
        FactorizeConfig {
            terms: self.terms,
            oversampling: self.oversampling,
            power_iterations: self.power_iterations,
            rotations: self.rotations,
            tileable: self.tileable,
            seed: self.seed,
            memory,
            ..FactorizeConfig::default()
        }
    }
}

/// Options shared by the stages that process data.
#[derive(Args, Clone)]
pub(super) struct Resources {
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Memory budget for decoded tiles, e.g. 512MiB or 2GiB.
    #[arg(long, global = true, value_parser = parse_memory, default_value_t = Memory(MemoryBudget::default()))]
    memory: Memory,
    /// Hide progress bars.
    #[arg(long, short, global = true)]
    quiet: bool,
}

#[derive(Subcommand)]
pub(super) enum Command {
    /// Print an artifact's metadata, arrays, chunking and compression.
    Info {
        file: PathBuf,
        /// Also decode every chunk and check its checksum.
        #[arg(long)]
        verify: bool,
        #[command(flatten)]
        res: Resources,
    },
    /// Generate a synthetic BTF (procedural mesostructure, ray-marched).
    GenerateBtf {
        #[command(flatten)]
        generating: Generating,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Build a BTF from a folder of Bonn/UTIA-named images or a CSV manifest.
    Ingest {
        /// Folder of `…_tlΘ_plΦ_tvΘ_pvΦ.png|exr` images, or a manifest.csv (file,theta_v,phi_v,theta_l,phi_l).
        input: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Write one image of a BTF (--view/--light), or all of them (--all DIR).
    ExportBtf {
        file: PathBuf,
        /// View direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_angles)]
        view: Option<Angles>,
        /// Light direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_angles)]
        light: Option<Angles>,
        /// Output image (.png or .exr).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Write every image into this folder, named the way `ingest` reads.
        #[arg(long)]
        all: Option<PathBuf>,
        /// Format for --all.
        #[arg(long, value_enum, ignore_case = true, default_value_t = ImageFormat::default())]
        format: ImageFormat,
        #[command(flatten)]
        res: Resources,
    },
    /// Factorize a BTF (or a colour image) into geometry maps and appearance functions (randomized SVD).
    Factorize {
        /// A .btf, or a colour image (PNG/JPEG/TIFF/EXR) taken as a one-direction BTF.
        input: PathBuf,
        #[command(flatten)]
        factorizing: Factorizing,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Render one direction pair from a factorization and print its PSNR against the original.
    Reconstruct {
        file: PathBuf,
        /// View direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_angles)]
        view: Angles,
        /// Light direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_angles)]
        light: Angles,
        /// The original BTF (default: the source recorded in the .svd, if unchanged).
        #[arg(long)]
        original: Option<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Build the dense mesh: atlas charts, packing and the multi-chart geometry image.
    Atlas {
        /// A triangle mesh (.obj or .ply).
        mesh: PathBuf,
        /// Atlas edge in texels.
        #[arg(long, default_value_t = AtlasConfig::default().resolution)]
        resolution: usize,
        /// Minimum empty texels between charts.
        #[arg(long, default_value_t = AtlasConfig::default().gutter)]
        gutter: usize,
        /// Vector-field keys: JSON [{"face": 12, "dir": [1, 0, 0]}, …].
        #[arg(long)]
        field: Option<PathBuf>,
        /// The default field turns where the surface is seen least: each
        /// face's turning weighs its exposure to this power (0..=8; 0: all
        /// faces alike). Moves singularities into creases and hidden places.
        #[arg(long, allow_negative_numbers = true, default_value_t = AtlasConfig::default().field_exposure)]
        field_exposure: f64,
        /// Weld vertices closer than this fraction of the median edge length (0..=0.5; 0: exact duplicates only).
        #[arg(long, allow_negative_numbers = true, default_value_t = AtlasConfig::default().load.weld_tolerance)]
        weld: f32,
        /// Split a chart whose L2 texture stretch exceeds this (≥ 1; lower: more
        /// charts, more even texel density).
        #[arg(long, allow_negative_numbers = true, default_value_t = AtlasConfig::default().charts.max_stretch)]
        max_stretch: f32,
        /// Split a chart when over 5 % of its area has a texel density off the
        /// chart's mean by more than this factor (≥ 1).
        #[arg(long, allow_negative_numbers = true, default_value_t = AtlasConfig::default().charts.max_area_distortion)]
        max_area_distortion: f32,
        /// Split a chart while one of its triangles stretches more than this
        /// in some direction (L∞ stretch, ≥ 1).
        #[arg(long, allow_negative_numbers = true, default_value_t = AtlasConfig::default().charts.max_linf_stretch)]
        max_linf_stretch: f32,
        /// A more compact atlas: stretched charts relaxed (ARAP) instead of
        /// split, and merged with relaxed maps; eighth turns in packing.
        /// Fewer charts and shorter seams; a different atlas.
        #[arg(long, default_value_t = AtlasConfig::default().charts.compact)]
        compact: bool,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Debug picture of a geometry image: charts, normals or field.
    Show {
        file: PathBuf,
        #[arg(long, value_enum, default_value_t = ShowWhat::default())]
        what: ShowWhat,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Export for other tools: a .gim or a .quilt as a textured mesh (OBJ or glTF), and a .quilt's surface BTF.
    Export {
        file: PathBuf,
        /// Mesh format for -o [default: obj].
        #[arg(long, value_enum)]
        format: Option<MeshFormat>,
        /// Output folder for the mesh.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Write a .quilt's surface BTF (synthesis.exr, geometry_maps.exr, appearance.csv, …, FORMAT.md) into this folder.
        #[arg(long)]
        btf: Option<PathBuf>,
        /// The sample of a .quilt (default: the path recorded in it).
        #[arg(long)]
        sample: Option<PathBuf>,
        #[command(flatten)]
        res: Resources,
    },
    /// Tile a geometry image with a sample by graphcut quilting.
    Tile {
        /// The dense mesh (from `atlas`).
        #[arg(long)]
        gim: PathBuf,
        /// A colour image or a factorization (.svd).
        #[arg(long)]
        sample: PathBuf,
        #[command(flatten)]
        quilting: Quilting,
        #[command(flatten)]
        tiling: Tiling,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Paint a sample's foreground (imperfections) into a region of a decorated surface
    /// by constrained graphcut, or copy it verbatim at a point; writes a new .quilt.
    Paint {
        /// The decorated surface (.quilt) to paint on; it is left unchanged.
        file: PathBuf,
        /// The sample to paint with (default: the last stroke's, or the tiling's): any sample with the surface's direction set.
        #[arg(long)]
        sample: Option<PathBuf>,
        /// The sample's foreground mask (PNG, the sample's size); default: the one the quilt records.
        #[arg(long)]
        sample_mask: Option<PathBuf>,
        /// Target region F: an atlas-space mask .png, a .ply/.obj with vertex paint, or .json strokes
        /// [{"point": [x, y, z], "radius": r}, …].
        #[arg(long)]
        region: Option<PathBuf>,
        /// Width of the transition zone outside F, in texels.
        #[arg(long, default_value_t = PaintConfig::default().transition)]
        transition: usize,
        /// Copy the foreground verbatim at --at (instead of a region).
        #[arg(long)]
        verbatim: bool,
        /// Verbatim: the surface point x,y,z.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_point)]
        at: Option<[f32; 3]>,
        /// Verbatim: the turn of the sample against the field, in degrees.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        angle: f64,
        /// Verbatim: write the direct projection (no graphcut) to this image.
        #[arg(long)]
        preview: Option<PathBuf>,
        /// The stroke's courses (a sample in rows): default as the surface was
        /// tiled — locked to its stripe pattern when tiled with `--courses
        /// locked` and painted with a sample whose courses fit it within 5 %
        /// (the tiling's at its width does; a verbatim copy only at --angle 0).
        #[arg(long, value_enum, ignore_case = true)]
        courses: Option<CourseMode>,
        #[command(flatten)]
        quilting: Quilting,
        #[arg(short, long)]
        output: Option<PathBuf>,
        #[command(flatten)]
        res: Resources,
    },
    /// Open a local web studio: view the surface (a BTF relit in real time), paint on it,
    /// undo, save and export glTF.
    Serve {
        /// The decorated surface (.quilt); it is never written.
        file: PathBuf,
        /// Port to listen on (0: any free port).
        #[arg(long, default_value_t = ServeConfig::default().port)]
        port: u16,
        /// Address to listen on; only the address and (for loopback) localhost are answered.
        #[arg(long, default_value_t = ServeConfig::default().bind)]
        bind: std::net::IpAddr,
        /// Threads answering requests.
        #[arg(long, default_value_t = ServeConfig::default().workers)]
        workers: usize,
        /// A further sample to paint with (repeatable).
        #[arg(long)]
        sample: Vec<PathBuf>,
        /// The foreground mask of each --sample, in the same order (all or none).
        #[arg(long)]
        sample_mask: Vec<PathBuf>,
        #[command(flatten)]
        res: Resources,
    },
    /// Run a batch plan (meshes × samples × seeds × sample widths, renders and
    /// exports) as content-addressed jobs: finished jobs are skipped, shared
    /// atlases and factorizations made once.
    Batch {
        /// The plan (TOML; see docs/batch.md).
        plan: PathBuf,
        /// Output folder: inputs/, shared/, jobs/KEY/, manifest.jsonl.
        #[arg(short, long)]
        output: PathBuf,
        /// Run shard I of N (0-based): a deterministic contiguous 1/N of the jobs.
        #[arg(long, value_parser = parse_shard, default_value = "0/1")]
        shard: batch::Shard,
        /// Run only this job (its 32-digit key, as --list prints it); repeatable.
        #[arg(long, value_parser = parse_key, conflicts_with_all = ["shard", "stages"])]
        job: Vec<batch::Key>,
        /// What to run: the jobs (with the shared artifacts they need) or only the
        /// shard's part of the shared stages.
        #[arg(long, value_enum, default_value_t = batch::BatchConfig::default().stages)]
        stages: batch::Stages,
        /// Print the shard's jobs (key, done or todo, what), or with --stages shared its
        /// shared artifacts, instead of running them.
        #[arg(long)]
        list: bool,
        /// With --list: one JSON object a line (key, status, folder, what).
        #[arg(long, requires = "list")]
        json: bool,
        /// Append the manifest lines here instead of OUTPUT/manifest.jsonl.
        #[arg(long)]
        manifest: Option<PathBuf>,
        /// Jobs run at once in this process (the quilting loop uses one core: give
        /// the number of cores); --memory is shared among them. Same outputs for any number.
        #[arg(long, default_value_t = batch::BatchConfig::default().workers)]
        workers: usize,
        #[command(flatten)]
        res: Resources,
    },
    /// Replay a painted surface's paint log onto its base quilt.
    Replay {
        file: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Bake a decorated surface's preview colour into an atlas texture (PNG/EXR).
    Bake {
        file: PathBuf,
        /// The sample (default: the path recorded in the quilt).
        #[arg(long)]
        sample: Option<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Print quality figures of a decorated surface as JSON.
    Evaluate {
        file: PathBuf,
        #[arg(long)]
        gim: Option<PathBuf>,
        #[arg(long)]
        sample: Option<PathBuf>,
        /// Output windows the coherence measures (each an exact search over
        /// the sample; more steady the 95th percentile)
        #[arg(long, default_value_t = evaluate::EvaluateConfig::default().windows)]
        windows: usize,
        /// For a sample whose features run in rows: also count the course
        /// ends of the smoothest stripe pattern along the atlas's field at
        /// the sample's course period (a stripe solve on the subdivided
        /// mesh; about a second and 140 MB on Spot).
        #[arg(long)]
        forced_ends: bool,
        #[command(flatten)]
        res: Resources,
    },
    /// Print how faithfully an image reproduces its sample as JSON: coherence
    /// (output windows to their nearest sample window) and completeness
    /// (sample windows to their nearest output window), exact nearest 5×5
    /// windows, unrotated.
    Compare {
        /// The synthesized image (e.g. a baked flat square, or another tool's output).
        image: PathBuf,
        #[arg(long)]
        sample: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Render a decorated mesh to an image: BTF shading per view and light
    /// direction for BTF samples, preview colour × Lambert for colour samples.
    Render {
        file: PathBuf,
        /// eye,target,up,fov (10 numbers); default: a three-quarter view framing the mesh.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_camera)]
        camera: Option<Camera>,
        /// Directional light x,y,z[,intensity] (towards the light, world space); repeatable.
        /// Default when no light is given: 0.4,0.8,0.6.
        #[arg(long, allow_hyphen_values = true, value_parser = parse_directional)]
        light: Vec<Light>,
        /// Point light x,y,z[,intensity] (world space; inverse-square falloff,
        /// intensity at the distance of the mesh's bounding-box centre); repeatable.
        #[arg(long = "point-light", allow_hyphen_values = true, value_parser = parse_point_light)]
        point_light: Vec<Light>,
        /// Write N frames OUTPUT-STEM_000 … with the first light (the first --light,
        /// else the first --point-light) circling the camera's view axis.
        #[arg(long = "orbit-light")]
        orbit_light: Option<usize>,
        /// Exposure in stops (values × 2^EXPOSURE).
        #[arg(long, default_value_t = RenderConfig::default().exposure, allow_hyphen_values = true)]
        exposure: f32,
        #[arg(long, default_value_t = RenderConfig::default().width)]
        width: usize,
        #[arg(long, default_value_t = RenderConfig::default().height)]
        height: usize,
        /// Output image: .png (8-bit sRGB) or .exr (linear).
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Run the pipeline on the embedded default data and write pictures.
    Demo {
        /// Output folder.
        #[arg(short, long, default_value = "demo-out")]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
}

/// A library message without the `--flag 'value': ` it starts with: clap's
/// error names the flag and the value already.
fn bare(e: impl std::fmt::Display, flag: &str, s: &str) -> String {
    let m = e.to_string();
    match m.strip_prefix(&format!("{flag} '{s}': ")) {
        Some(rest) => rest.to_string(),
        None => m,
    }
}

/// `--shard I/N`.
fn parse_shard(s: &str) -> std::result::Result<batch::Shard, String> {
    batch::Shard::parse(s).map_err(|e| bare(e, "--shard", s))
}

/// `--job KEY`: 32 hexadecimal digits.
fn parse_key(s: &str) -> std::result::Result<batch::Key, String> {
    batch::Key::parse(s)
        .ok_or_else(|| "expected a job key: 32 hexadecimal digits, as `batch --list` prints".into())
}

/// `--memory`: a size like 512MiB or 2GiB.
#[derive(Clone, Copy)]
struct Memory(pub(super) MemoryBudget);

impl std::fmt::Display for Memory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let b = self.0 .0;
        match [(30, "GiB"), (20, "MiB"), (10, "KiB")]
            .into_iter()
            .find(|&(shift, _)| b > 0 && b % (1u64 << shift) == 0)
        {
            Some((shift, unit)) => write!(f, "{}{unit}", b >> shift),
            None => write!(f, "{b}"),
        }
    }
}

fn parse_memory(s: &str) -> std::result::Result<Memory, String> {
    MemoryBudget::parse(s)
        .map(Memory)
        .map_err(|e| bare(e, "--memory", s))
}

/// `--views`/`--lights`: a direction grid PHIxTHETA.
#[derive(Clone)]
struct Grid(pub(super) Vec<Angles>);

impl std::fmt::Display for Grid {
    /// The grid as PHIxTHETA: its numbers of distinct φ and θ.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let distinct = |key: fn(&Angles) -> f32| {
            let mut v: Vec<u32> = self.0.iter().map(|a| key(a).to_bits()).collect();
            v.sort_unstable();
            v.dedup();
            v.len()
        };
        write!(f, "{}x{}", distinct(|a| a.phi), distinct(|a| a.theta))
    }
}

fn parse_grid(s: &str) -> std::result::Result<Grid, String> {
    btf::parse_grid(s).map(Grid).map_err(|e| e.to_string())
}

/// `--view`/`--light` θ,φ in degrees.
fn parse_angles(s: &str) -> std::result::Result<Angles, String> {
    let (t, p) = s.split_once(',').ok_or("expected θ,φ in degrees")?;
    let theta: f32 = t.trim().parse().map_err(|_| "θ is not a number")?;
    let phi: f32 = p.trim().parse().map_err(|_| "φ is not a number")?;
    if !(theta.is_finite() && phi.is_finite()) {
        return Err("θ and φ must be finite numbers of degrees".into());
    }
    Ok(Angles { theta, phi })
}

/// `paint --at x,y,z`.
fn parse_point(s: &str) -> std::result::Result<[f32; 3], String> {
    s.split(',')
        .map(|c| c.trim().parse::<f32>())
        .collect::<std::result::Result<Vec<f32>, _>>()
        .ok()
        .filter(|v| v.len() == 3 && v.iter().all(|c| c.is_finite()))
        .map(|v| [v[0], v[1], v[2]])
        .ok_or_else(|| "expected x,y,z (three finite numbers)".to_string())
}

/// `atlas` lists at most this many singularities, the most exposed first.
pub(super) const LISTED_SINGULARITIES: usize = 24;

fn parse_camera(s: &str) -> std::result::Result<Camera, String> {
    Camera::parse(s).map_err(|e| bare(e, "--camera", s))
}

fn parse_directional(s: &str) -> std::result::Result<Light, String> {
    Light::parse_directional(s).map_err(|e| bare(e, "--light", s))
}

fn parse_point_light(s: &str) -> std::result::Result<Light, String> {
    Light::parse_point(s).map_err(|e| bare(e, "--point-light", s))
}

/// The most worker threads `--threads` may ask for, per core: beyond a few
/// per core, threads only add scheduling and memory cost.
const MAX_THREADS_PER_CORE: usize = 4;

impl Resources {
    pub(super) fn apply(&self) -> Result<(MemoryBudget, Bars)> {
        if let Some(mut n) = self.threads {
            if n == 0 {
                bail!("--threads must be at least 1");
            }
            let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
            let cap = MAX_THREADS_PER_CORE * cores;
            if n > cap {
                eprintln!(
                    "note: --threads {n} capped at {cap} ({MAX_THREADS_PER_CORE} per core, {cores} cores); results do not depend on it"
                );
                n = cap;
            }
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build_global()
                .context("starting the thread pool")?;
        }
        Ok((self.memory.0, Bars::new(self.quiet)))
    }
}
