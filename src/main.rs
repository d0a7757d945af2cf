//! The `btfquilt` command line: parses arguments and calls the library.

use std::path::PathBuf;
use std::sync::Mutex;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use btfquilt::btf::{self, Angles, Btf};
use btfquilt::container::{Container, MemoryBudget};
use btfquilt::factorize::{self, FactorizeConfig, SvdArtifact};
use btfquilt::generate::{self, Family, GenerateConfig, Imperfection};
use btfquilt::gim::{self, AtlasConfig, Gim};
use btfquilt::ingest::{self, ImageFormat, IngestConfig};
use btfquilt::mesh::io::LoadOptions;
use btfquilt::progress::Progress;
use btfquilt::quilt::{self, TileConfig};
use btfquilt::{bake, evaluate, export, render, show};

/// Prints a line to stdout; a closed pipe (`btfquilt evaluate … | head`) is
/// not an error.
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}

#[derive(Parser)]
#[command(
    name = "btfquilt",
    version,
    about = "Decorate meshes with textures and BTFs by graphcut quilting"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Options shared by the stages that process data.
#[derive(Args, Clone)]
struct Resources {
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Memory budget for decoded tiles, e.g. 512MiB or 2GiB.
    #[arg(long, global = true, default_value = "1GiB")]
    memory: String,
    /// Hide progress bars.
    #[arg(long, short, global = true)]
    quiet: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Print an artifact's metadata, arrays, chunking and compression.
    Info {
        file: PathBuf,
        /// Also decode every chunk and check its checksum.
        #[arg(long)]
        verify: bool,
    },
    /// Generate a synthetic BTF (procedural mesostructure, ray-marched).
    GenerateBtf {
        /// bricks, weave, cracked or pebbles.
        #[arg(long, default_value = "bricks")]
        family: String,
        /// none, cracks, stains or scratches (its mask is written beside the output as *.mask.png).
        #[arg(long, default_value = "none")]
        imperfection: String,
        /// Texels per side (width = height).
        #[arg(long, default_value_t = 128)]
        size: usize,
        /// View directions as PHIxTHETA.
        #[arg(long, default_value = "12x8")]
        views: String,
        /// Light directions as PHIxTHETA.
        #[arg(long, default_value = "12x8")]
        lights: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
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
        #[arg(long, allow_hyphen_values = true)]
        view: Option<String>,
        /// Light direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true)]
        light: Option<String>,
        /// Output image (.png or .exr).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Write every image into this folder, named the way `ingest` reads.
        #[arg(long)]
        all: Option<PathBuf>,
        /// Format for --all: exr (exact f16) or png (16-bit sRGB).
        #[arg(long, default_value = "exr")]
        format: String,
        #[command(flatten)]
        res: Resources,
    },
    /// Factorize a BTF (or a colour image) into geometry maps and appearance functions (randomized SVD).
    Factorize {
        /// A .btf, or a colour image (PNG/JPEG/TIFF/EXR) taken as a one-direction BTF.
        input: PathBuf,
        /// Number of terms n (default 40, or fewer if the matrix is smaller).
        #[arg(long)]
        terms: Option<usize>,
        /// Oversampling p of the randomized SVD.
        #[arg(long, default_value_t = 10)]
        oversampling: usize,
        /// Power iterations q of the randomized SVD.
        #[arg(long, default_value_t = 2)]
        power_iterations: usize,
        /// Rotated copies of the geometry maps (5° steps for 72).
        #[arg(long, default_value_t = 72)]
        rotations: usize,
        /// The sample wraps around: rotated copies sample it toroidally.
        #[arg(long)]
        tileable: bool,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Render one direction pair from a factorization and print its PSNR against the original.
    Reconstruct {
        file: PathBuf,
        /// View direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true)]
        view: String,
        /// Light direction θ,φ in degrees.
        #[arg(long, allow_hyphen_values = true)]
        light: String,
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
        #[arg(long, default_value_t = 1024)]
        resolution: usize,
        /// Minimum empty texels between charts.
        #[arg(long, default_value_t = 2)]
        gutter: usize,
        /// Vector-field keys: JSON [{"face": 12, "dir": [1, 0, 0]}, …].
        #[arg(long)]
        field: Option<PathBuf>,
        /// Weld vertices closer than this fraction of the median edge length (0..=0.5; 0: exact duplicates only).
        #[arg(long, default_value_t = 1e-6)]
        weld: f32,
        /// Split a chart whose L2 texture stretch exceeds this (≥ 1; lower: more
        /// charts, more even texel density).
        #[arg(long)]
        max_stretch: Option<f32>,
        /// Split a chart when over 5 % of its area has a texel density off the
        /// chart's mean by more than this factor (≥ 1; default 1.5).
        #[arg(long)]
        max_area_distortion: Option<f32>,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        res: Resources,
    },
    /// Debug picture of a geometry image: charts, normals or field.
    Show {
        file: PathBuf,
        #[arg(long, default_value = "charts")]
        what: String,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Export for other tools: a .gim or a .quilt as a textured mesh (OBJ or glTF), and a .quilt's surface BTF.
    Export {
        file: PathBuf,
        /// Mesh format for -o: obj (mesh.obj + mesh.mtl + PNG) or gltf (mesh.glb, texture embedded). Default obj.
        #[arg(long)]
        format: Option<String>,
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
        /// Work-patch radius r_w in texels (default 32 per 512 of atlas, at most a quarter of the sample).
        #[arg(long)]
        patch_radius: Option<usize>,
        /// T_c: accept a patch if its mean seam cost ≤ this × the sample's neighbour difference.
        #[arg(long, default_value_t = 3.0)]
        seam_threshold: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The sample's foreground mask (PNG, the sample's size): keep the
        /// foreground (cracks, stains…) out of the tiling.
        #[arg(long)]
        sample_mask: Option<PathBuf>,
        /// Seam refinement once covered: seams stepping more than this × the
        /// sample's neighbour difference get another work patch; 0 turns it off.
        #[arg(long, default_value_t = 2.0)]
        refine: f64,
        /// Seam refinement fits this many distinct good placements per seam and
        /// keeps the cheapest cut (1: only the best match; more: lower seams,
        /// longer runs).
        #[arg(long, default_value_t = quilt::REFINE_PLACEMENTS)]
        refine_placements: usize,
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
        #[arg(long, default_value_t = 8)]
        transition: usize,
        /// Copy the foreground verbatim at --at (instead of a region).
        #[arg(long)]
        verbatim: bool,
        /// Verbatim: the surface point x,y,z.
        #[arg(long, allow_hyphen_values = true)]
        at: Option<String>,
        /// Verbatim: the turn of the sample against the field, in degrees.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        angle: f64,
        /// Verbatim: write the direct projection (no graphcut) to this image.
        #[arg(long)]
        preview: Option<PathBuf>,
        /// Work-patch radius r_w in texels (default 32 per 512 of atlas, at most a quarter of the sample).
        #[arg(long)]
        patch_radius: Option<usize>,
        /// Weight of the constraint (data term per texel, in sample neighbour differences).
        #[arg(long, default_value_t = 16.0)]
        constraint_weight: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(short, long)]
        output: Option<PathBuf>,
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
    },
    /// Print quality figures of a decorated surface as JSON.
    Evaluate {
        file: PathBuf,
        #[arg(long)]
        gim: Option<PathBuf>,
        #[arg(long)]
        sample: Option<PathBuf>,
    },
    /// Render a decorated mesh to an image: BTF shading per view and light
    /// direction for BTF samples, preview colour × Lambert for colour samples.
    Render {
        file: PathBuf,
        /// eye,target,up,fov (10 numbers); default: a three-quarter view framing the mesh.
        #[arg(long, allow_hyphen_values = true)]
        camera: Option<String>,
        /// Directional light x,y,z[,intensity] (towards the light, world space); repeatable.
        /// Default when no light is given: 0.4,0.8,0.6.
        #[arg(long, allow_hyphen_values = true)]
        light: Vec<String>,
        /// Point light x,y,z[,intensity] (world space; inverse-square falloff,
        /// intensity at the distance of the mesh's bounding-box centre); repeatable.
        #[arg(long = "point-light", allow_hyphen_values = true)]
        point_light: Vec<String>,
        /// Write N frames OUTPUT-STEM_000 … with the first light (the first --light,
        /// else the first --point-light) circling the camera's view axis.
        #[arg(long = "orbit-light")]
        orbit_light: Option<usize>,
        /// Exposure in stops (values × 2^EXPOSURE).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        exposure: f32,
        #[arg(long, default_value_t = 800)]
        width: usize,
        #[arg(long, default_value_t = 600)]
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

/// Progress bars on stderr.
struct Bars {
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl Bars {
    fn new(quiet: bool) -> Bars {
        Bars {
            quiet,
            bar: Mutex::new(None),
        }
    }
}

impl Progress for Bars {
    fn begin(&self, stage: &str, total: u64) {
        if self.quiet {
            return;
        }
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template("{prefix:>10} [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        bar.set_prefix(stage.to_string());
        *self.bar.lock().unwrap() = Some(bar);
    }
    fn advance(&self, n: u64) {
        if let Some(b) = &*self.bar.lock().unwrap() {
            b.inc(n);
        }
    }
    fn end(&self) {
        if let Some(b) = self.bar.lock().unwrap().take() {
            b.finish_and_clear();
        }
    }
    fn note(&self, line: &str) {
        match &*self.bar.lock().unwrap() {
            // a hidden bar (stderr not a terminal) drops println
            Some(b) if !b.is_hidden() => b.println(line),
            _ => eprintln!("{line}"),
        }
    }
}

fn parse_angles(s: &str, what: &str) -> Result<Angles> {
    let (t, p) = s
        .split_once(',')
        .with_context(|| format!("--{what} '{s}': expected θ,φ in degrees"))?;
    let theta: f32 = t
        .trim()
        .parse()
        .with_context(|| format!("--{what} '{s}': θ is not a number"))?;
    let phi: f32 = p
        .trim()
        .parse()
        .with_context(|| format!("--{what} '{s}': φ is not a number"))?;
    if !(theta.is_finite() && phi.is_finite()) {
        bail!("--{what} '{s}': θ and φ must be finite numbers of degrees");
    }
    Ok(Angles { theta, phi })
}

/// The most worker threads `--threads` may ask for, per core: beyond a few
/// per core, threads only add scheduling and memory cost.
const MAX_THREADS_PER_CORE: usize = 4;

impl Resources {
    fn apply(&self) -> Result<(MemoryBudget, Bars)> {
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
        Ok((MemoryBudget::parse(&self.memory)?, Bars::new(self.quiet)))
    }
}

fn main() {
    let result = run(Cli::parse());
    for r in btfquilt::staging::take_removed_partials() {
        eprintln!(
            "note: removed {} ({}), a partial output left by process {} that no longer runs",
            r.path.display(),
            btfquilt::container::human_bytes(r.bytes),
            r.pid
        );
    }
    if let Err(e) = result {
        eprintln!("error: {}", error_chain(&e));
        std::process::exit(1);
    }
}

/// The error and its causes, `: `-separated, each said once (a cause whose
/// text its parent already ends with, such as an OS error the library's
/// message quotes, is not repeated).
fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info { file, verify } => {
            let c = Container::open(&file, MemoryBudget::default())?;
            say!("{}", c.describe().trim_end());
            if c.metadata().kind == btf::KIND {
                let b = Btf::open(&file, MemoryBudget::default())?;
                let l = b.layout();
                say!(
                    "btf:       {}×{} texels, {} views × {} lights = {} pairs, tile {}, band {}",
                    l.width,
                    l.height,
                    l.views.len(),
                    l.lights.len(),
                    l.pairs(),
                    l.tile,
                    l.band
                );
            }
            if verify {
                c.verify()?;
                say!("verify:    every chunk decodes and matches its checksum");
            }
        }
        Command::GenerateBtf {
            family,
            imperfection,
            size,
            views,
            lights,
            seed,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let cfg = GenerateConfig {
                family: Family::parse(&family).with_context(|| {
                    format!("--family '{family}': expected bricks, weave, cracked or pebbles")
                })?,
                imperfection: Imperfection::parse(&imperfection).with_context(|| {
                    format!("--imperfection '{imperfection}': expected none, cracks, stains or scratches")
                })?,
                width: size,
                height: size,
                views: btf::parse_grid(&views)?,
                lights: btf::parse_grid(&lights)?,
                seed,
                memory,
                ..GenerateConfig::default()
            };
            let report = generate::generate_btf(&cfg, &output, &bars)?;
            say!("wrote {} ({})", output.display(), report);
        }
        Command::Ingest { input, output, res } => {
            let (memory, bars) = res.apply()?;
            let cfg = IngestConfig {
                memory,
                ..IngestConfig::default()
            };
            let r = ingest::ingest(&input, &output, &cfg, &bars)?;
            say!(
                "wrote {}: {}×{} texels, {} views × {} lights",
                output.display(),
                r.width,
                r.height,
                r.views,
                r.lights
            );
        }
        Command::ExportBtf {
            file,
            view,
            light,
            output,
            all,
            format,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let b = Btf::open(&file, memory)?;
            match (all, output) {
                (Some(dir), None) => {
                    let n = ingest::export_all(&b, &dir, ImageFormat::parse(&format)?, memory, &bars)?;
                    say!("wrote {n} images and manifest.csv into {}", dir.display());
                }
                (None, Some(out)) => {
                    btfquilt::staging::check_output(&out, &[("the BTF", file.as_path())])?;
                    let view =
                        parse_angles(view.as_deref().context("--view θ,φ is required with -o")?, "view")?;
                    let light = parse_angles(
                        light.as_deref().context("--light θ,φ is required with -o")?,
                        "light",
                    )?;
                    let img = ingest::pair_image(&b, view, light)?;
                    btfquilt::imageio::write_rgb(&out, &img)?;
                    say!("wrote {}", out.display());
                }
                _ => bail!("give either -o IMAGE (with --view and --light) or --all DIR"),
            }
        }
        Command::Factorize {
            input,
            terms,
            oversampling,
            power_iterations,
            rotations,
            tileable,
            seed,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let cfg = FactorizeConfig {
                terms,
                oversampling,
                power_iterations,
                rotations,
                tileable,
                seed,
                memory,
                ..FactorizeConfig::default()
            };
            let report = factorize::factorize(&input, &output, &cfg, &bars)?;
            say!("wrote {}: {report}", output.display());
        }
        Command::Reconstruct {
            file,
            view,
            light,
            original,
            output,
            res,
        } => {
            let (memory, _) = res.apply()?;
            let mut inputs = vec![("the factorization", file.as_path())];
            if let Some(o) = &original {
                inputs.push(("the original", o.as_path()));
            }
            btfquilt::staging::check_output(&output, &inputs)?;
            let svd = SvdArtifact::open(&file, memory)?;
            let pair = svd.find_pair(parse_angles(&view, "view")?, parse_angles(&light, "light")?)?;
            let img = svd.reconstruct_pair(pair)?;
            btfquilt::imageio::write_rgb(&output, &img)?;
            say!("wrote {}", output.display());
            match svd.original_pair(pair, original.as_deref(), memory)? {
                Some(orig) => say!("PSNR {:.2} dB against the original", factorize::psnr(&orig, &img)),
                None => say!("PSNR: the original is not available (give --original FILE)"),
            }
        }
        Command::Atlas {
            mesh,
            resolution,
            gutter,
            field,
            weld,
            max_stretch,
            max_area_distortion,
            output,
            res,
        } => {
            let (_, bars) = res.apply()?;
            let mut cfg = AtlasConfig {
                resolution,
                gutter,
                field_keys: field,
                load: LoadOptions { weld_tolerance: weld },
                ..AtlasConfig::default()
            };
            if let Some(s) = max_stretch {
                cfg.charts.max_stretch = s;
            }
            if let Some(a) = max_area_distortion {
                cfg.charts.max_area_distortion = a;
            }
            let report = gim::build_gim(&mesh, &output, &cfg, &bars)?;
            say!("{}: {}", mesh.display(), report.repair);
            say!("wrote {}: {report}", output.display());
        }
        Command::Show { file, what, output } => {
            let g = Gim::open(&file, MemoryBudget::default())?;
            show::show(&g, what.parse()?, &output)?;
            say!("wrote {}", output.display());
        }
        Command::Export {
            file,
            format,
            output,
            btf,
            sample,
            res,
        } => {
            let (memory, _) = res.apply()?;
            if output.is_none() && format.is_some() {
                bail!("--format needs -o DIR (the folder for the mesh)");
            }
            let format: export::MeshFormat = format.as_deref().unwrap_or("obj").parse()?;
            let opts = export::ExportOptions {
                mesh: output.map(|dir| (format, dir)),
                btf,
                sample,
                budget: memory,
            };
            for path in export::export(&file, &opts)? {
                say!("wrote {}", path.display());
            }
        }
        Command::Tile {
            gim,
            sample,
            patch_radius,
            seam_threshold,
            seed,
            sample_mask,
            refine,
            refine_placements,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let cfg = TileConfig {
                patch_radius,
                seam_threshold,
                seed,
                memory,
                sample_mask,
                refine: (refine != 0.0).then_some(refine),
                refine_placements,
                ..TileConfig::default()
            };
            let report = quilt::tile(&gim, &sample, &output, &cfg, &bars)?;
            say!("wrote {}: {report}", output.display());
        }
        Command::Paint {
            file,
            sample,
            sample_mask,
            region,
            transition,
            verbatim,
            at,
            angle,
            preview,
            patch_radius,
            constraint_weight,
            seed,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let verbatim = if verbatim {
                let at = at.ok_or_else(|| anyhow::anyhow!("--verbatim needs --at x,y,z"))?;
                let v: Vec<f32> = at
                    .split(',')
                    .map(|c| c.trim().parse::<f32>())
                    .collect::<std::result::Result<_, _>>()
                    .ok()
                    .filter(|v: &Vec<f32>| v.len() == 3 && v.iter().all(|c| c.is_finite()))
                    .ok_or_else(|| anyhow::anyhow!("--at '{at}': expected x,y,z (three finite numbers)"))?;
                Some(btfquilt::paint::Verbatim {
                    at: [v[0], v[1], v[2]],
                    angle,
                })
            } else {
                if at.is_some() {
                    anyhow::bail!("--at is for --verbatim");
                }
                None
            };
            if output.is_none() && preview.is_none() {
                anyhow::bail!("give -o OUTPUT.quilt (or --preview IMAGE with --verbatim)");
            }
            let cfg = btfquilt::paint::PaintConfig {
                sample,
                sample_mask,
                region,
                transition,
                verbatim,
                preview: preview.clone(),
                tile: TileConfig {
                    patch_radius,
                    constraint_weight,
                    seed,
                    memory,
                    ..TileConfig::default()
                },
            };
            if let Some(p) = &preview {
                let t = std::time::Instant::now();
                let report = btfquilt::paint::preview(&file, &cfg, &bars)?;
                say!(
                    "wrote {} ({} foreground texels; projection {:.1} ms, {:.0} ms with opening the artifacts)",
                    p.display(),
                    report.region_texels,
                    report.projection_seconds * 1e3,
                    t.elapsed().as_secs_f64() * 1e3
                );
            }
            if let Some(out) = output {
                let cfg = btfquilt::paint::PaintConfig { preview: None, ..cfg };
                let report = btfquilt::paint::paint(&file, &out, &cfg, &bars)?;
                say!("wrote {}: {report}", out.display());
            }
        }
        Command::Replay { file, output, res } => {
            let (_, bars) = res.apply()?;
            let report = btfquilt::paint::replay(&file, &output, &bars)?;
            say!("wrote {}: {report}", output.display());
        }
        Command::Bake { file, sample, output } => {
            bake::bake(&file, sample.as_deref(), &output, MemoryBudget::default())?;
            say!("wrote {}", output.display());
        }
        Command::Evaluate { file, gim, sample } => {
            say!(
                "{}",
                evaluate::evaluate(&file, gim.as_deref(), sample.as_deref(), MemoryBudget::default())?
            );
        }
        Command::Render {
            file,
            camera,
            light,
            point_light,
            orbit_light,
            exposure,
            width,
            height,
            output,
            res,
        } => {
            let (memory, _bars) = res.apply()?;
            let camera = camera.as_deref().map(render::Camera::parse).transpose()?;
            let mut lights = light
                .iter()
                .map(|s| render::Light::parse_directional(s))
                .collect::<Result<Vec<_>, _>>()?;
            for s in &point_light {
                lights.push(render::Light::parse_point(s)?);
            }
            if lights.is_empty() {
                lights.push(render::Light::default());
            }
            let cfg = render::RenderConfig {
                camera,
                lights,
                width,
                height,
                exposure,
            };
            match orbit_light {
                Some(frames) => {
                    for p in render::render_frames(&file, &cfg, frames, &output, memory)? {
                        say!("wrote {}", p.display());
                    }
                }
                None => {
                    render::render(&file, &cfg, &output, memory)?;
                    say!("wrote {}", output.display());
                }
            }
        }
        Command::Demo { output, res } => {
            let (memory, bars) = res.apply()?;
            let report = btfquilt::demo::run(&output, memory, &bars)?;
            say!("{report}");
        }
    }
    Ok(())
}
