//! `paint`: graphcut texture painting (the paper's section IV; docs/design.md
//! section 7): imperfections — cracks, dirt, scratches — from a sample's
//! foreground S_f put into a region F the user marks on a decorated
//! surface, merged seamlessly with the background.
//!
//! The constraint function m0 is 1 on F and falls linearly to 0 over a
//! transition zone of `transition` texels (hops on the dense mesh) outside
//! F. Every texel with m0 > 0 is then re-synthesized by the quilting loop
//! with the constrained graphcut: the data term D_p(σ) = |m_σ(p) − m0(p)|
//! (m_σ the sample's foreground mask at the texel's sample coordinate) on
//! the t-links, the quilting smoothness term on the n-links, one min-cut per
//! fitting (the optimal swap move between the old values A and the new patch
//! B), and patch matching jointly on features and constraint values.
//!
//! Regions come as an atlas-space mask PNG, per-vertex weights on the input
//! mesh (PLY `quality`/`weight`, or vertex colours as painted in Blender),
//! or JSON strokes `[{"point": [x, y, z], "radius": r}, …]` (geodesic disks
//! on the dense mesh). Verbatim copy places the foreground at a surface
//! point (`--preview` writes the direct projection without a graphcut).
//!
//! Painting writes a new `.quilt` (the old one stays: undo is free) whose
//! `paint_log` parameter records the base quilt and every stroke, so a
//! painted surface can be replayed ([`replay`]).

use std::collections::{BinaryHeap, VecDeque};
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::artifact::gim::{Gim, EMPTY};
use crate::container::Param;
use crate::progress::Progress;
pub use crate::quilt::Projection;
use crate::quilt::{same_file, sample_at_density, sample_role, Quilt, SizedSample, Synthesis, TileConfig};
use crate::{Error, Result};

/// A verbatim copy: where and how the foreground goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Verbatim {
    /// A point on (or near) the surface; the nearest dense vertex is used.
    pub at: [f32; 3],
    /// Turn of the sample against the field direction, in degrees.
    pub angle: f64,
}

/// Options of [`paint`].
#[derive(Clone, Debug)]
pub struct PaintConfig {
    /// The sample to paint with: the one the surface was tiled with, or any
    /// other with the same direction set (a colour image on a colour
    /// surface, a BTF measured like the surface's). Default: the sample of
    /// the last stroke (the tiling's for a surface not yet painted).
    pub sample: Option<PathBuf>,
    /// The sample's foreground mask m_P (a PNG the sample's size); default:
    /// the one recorded in the quilt, when it belongs to that sample.
    pub sample_mask: Option<PathBuf>,
    /// The target region F: a mask PNG (atlas space), a PLY/OBJ with vertex
    /// weights or colours, or JSON strokes.
    pub region: Option<PathBuf>,
    /// Width of the transition zone in texels.
    pub transition: usize,
    /// Verbatim copy instead of a region.
    pub verbatim: Option<Verbatim>,
    /// Verbatim only: write the direct projection to this image.
    pub preview: Option<PathBuf>,
    /// Quilting options (seed, radius, T_c, constraint weight, memory).
    pub tile: TileConfig,
}

impl Default for PaintConfig {
    fn default() -> Self {
        PaintConfig {
            sample: None,
            sample_mask: None,
            region: None,
            transition: 8,
            verbatim: None,
            preview: None,
            tile: TileConfig::default(),
        }
    }
}

impl PaintConfig {
    /// Checks the numbers a user gives: the quilting options
    /// ([`TileConfig::validate`]) and a verbatim copy's point and angle.
    pub fn validate(&self) -> Result<()> {
        self.tile.validate()?;
        if let Some(v) = &self.verbatim {
            check_verbatim(v)?;
        }
        Ok(())
    }
}

/// What [`paint`] did.
#[derive(Clone, Debug, Default)]
pub struct PaintReport {
    /// Texels in F (m0 = 1).
    pub region_texels: usize,
    /// Texels in F plus the transition zone (m0 > 0).
    pub zone_texels: usize,
    /// Patches fitted.
    pub patches: usize,
    /// Texels that took a new patch.
    pub repainted: usize,
    pub seconds: f64,
    /// Verbatim preview: the direct projection alone (after opening the
    /// artifacts), in seconds.
    pub projection_seconds: f64,
}

impl std::fmt::Display for PaintReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "region {} texels ({} with the transition zone), {} patches, {} texels repainted, {:.2} s",
            self.region_texels, self.zone_texels, self.patches, self.repainted, self.seconds
        )
    }
}

/// Paints `quilt_path` into a new artifact `out` (see the module docs); with
/// `cfg.preview` set, only the preview is written, as by [`preview`].
pub fn paint(
    quilt_path: &Path,
    out: &Path,
    cfg: &PaintConfig,
    progress: &dyn Progress,
) -> Result<PaintReport> {
    run(quilt_path, out, cfg, progress)
}

/// Only the verbatim copy's preview (`cfg.preview` and `cfg.verbatim`
/// must be set): no quilt is written. For many previews of one surface,
/// open a [`PreviewSession`] once instead.
pub fn preview(quilt_path: &Path, cfg: &PaintConfig, progress: &dyn Progress) -> Result<PaintReport> {
    let start = Instant::now();
    let (Some(out), Some(v)) = (&cfg.preview, cfg.verbatim) else {
        return Err(Error::Config(
            "a preview needs --verbatim and --preview IMAGE".into(),
        ));
    };
    check_paint_output(&Quilt::open(quilt_path, cfg.tile.memory)?, cfg, out)?;
    let mut session = PreviewSession::open(quilt_path, cfg, progress)?;
    let t = Instant::now();
    let taken = session.preview(v, out, progress)?;
    Ok(PaintReport {
        region_texels: taken,
        zone_texels: taken,
        projection_seconds: t.elapsed().as_secs_f64(),
        seconds: start.elapsed().as_secs_f64(),
        ..PaintReport::default()
    })
}

/// A decorated surface and a sample opened once for interactive verbatim
/// previews (§IV's fast preview): each [`PreviewSession::preview`] is only
/// the direct projection of the foreground at a point (no graphcut, no
/// re-reading of the artifacts), about 30 ms on Spot at 1024².
pub struct PreviewSession {
    syn: Synthesis,
    _tmp: SizedSample,
}

impl PreviewSession {
    /// Opens `quilt_path` with the sample and foreground mask of `cfg` (their
    /// defaults as for [`paint`]; `cfg.region`, `cfg.verbatim` and
    /// `cfg.preview` are not used).
    pub fn open(quilt_path: &Path, cfg: &PaintConfig, progress: &dyn Progress) -> Result<PreviewSession> {
        let base = Quilt::open(quilt_path, cfg.tile.memory)?;
        // a stroke resolves the sample and mask defaults; its place is
        // given per preview
        let stroke = Stroke::from_config(
            &PaintConfig {
                region: None,
                preview: None,
                verbatim: Some(cfg.verbatim.unwrap_or(Verbatim {
                    at: [0.0; 3],
                    angle: 0.0,
                })),
                ..cfg.clone()
            },
            &base,
            quilt_path,
        )?;
        let (syn, _, tmp) = open_synthesis(&base, &stroke, quilt_path, progress)?;
        Ok(PreviewSession { syn, _tmp: tmp })
    }

    /// Writes the direct projection of the foreground placed as `v` (the
    /// atlas box of the work patch, foreground pasted over the surface's
    /// colours) to `out`; returns the foreground texels it covers.
    pub fn preview(&mut self, v: Verbatim, out: &Path, progress: &dyn Progress) -> Result<usize> {
        let (taken, projection) = self.project(v, progress)?;
        crate::io::imageio::write_png(out, &projection.image, crate::io::imageio::PngDepth::Eight)?;
        Ok(taken)
    }

    /// The direct projection of the foreground placed as `v`, in memory:
    /// the foreground texels it covers and the atlas box ([`Projection`]).
    pub fn project(&mut self, v: Verbatim, progress: &dyn Progress) -> Result<(usize, Projection)> {
        let (centre, extent) = foreground_extent(&self.syn);
        let vertex = verbatim_vertex(&self.syn, &v)?;
        let radius = (extent * 1.15).ceil() as usize + 4;
        let (taken, projection) =
            self.syn
                .verbatim(vertex, radius, v.angle.to_radians(), centre, true, progress)?;
        Ok((taken, projection.expect("a preview returns its projection")))
    }
}

/// Opens the synthesis for a stroke on `base`: its geometry image, the
/// stroke's sample (factorized into a temporary directory if it is an
/// image; rotated copies only for a region stroke, whose matching needs
/// them) and foreground mask, and the surface's state.
fn open_synthesis(
    base: &Quilt,
    stroke: &Stroke,
    beside: &Path,
    progress: &dyn Progress,
) -> Result<(Synthesis, Gim, SizedSample)> {
    let start = Instant::now();
    let cfg = TileConfig {
        sample_mask: Some(stroke.sample_mask.clone()),
        ..stroke.tile.clone()
    };
    let gim = base.open_gim(None, cfg.memory)?;
    let matching = stroke.verbatim.is_none();
    let sized = sample_at_density(
        &stroke.sample,
        gim.texel_size,
        cfg.sample_size(),
        matching,
        progress,
    )?;
    let trace = |what: &str| crate::progress::trace(progress, start, what);
    trace("factorized");
    let mut syn = Synthesis::open(&gim, &stroke.sample, &sized.svd, beside, &cfg, matching)?;
    syn.set_scale(&sized);
    trace("opened");
    syn.set_mask(&stroke.sample_mask)?;
    syn.load(base, progress)?;
    syn.painting = true;
    trace("loaded");
    Ok((syn, gim, sized))
}

/// [`paint`]: applies the stroke of `cfg` and writes `out`.
fn run(quilt_path: &Path, out: &Path, cfg: &PaintConfig, progress: &dyn Progress) -> Result<PaintReport> {
    if cfg.preview.is_some() {
        return Err(Error::Config(
            "--preview writes only the preview: give no output quilt".into(),
        ));
    }
    let base = Quilt::open(quilt_path, cfg.tile.memory)?;
    check_paint_output(&base, cfg, out)?;
    let log = match base.container().metadata().param("paint_log") {
        Some(Param::Text(s)) => PaintLog::parse(s, quilt_path, &base.samples[0])?.resolved_in(quilt_path),
        _ => PaintLog {
            base: quilt_path.to_path_buf(),
            base_hash: base.container().content_hash(),
            strokes: Vec::new(),
        },
    };
    let stroke = Stroke::from_config(cfg, &base, quilt_path)?;
    apply_stroke(&base, &stroke, out, &log, progress)
}

/// Refuses `out` when it is the surface, a file it depends on, or a file
/// the stroke reads.
fn check_paint_output(base: &Quilt, cfg: &PaintConfig, out: &Path) -> Result<()> {
    base.check_output(out)?;
    let mut inputs = Vec::new();
    if let Some(p) = &cfg.sample {
        inputs.push(("the sample to paint with", p.as_path()));
    }
    if let Some(p) = &cfg.sample_mask {
        inputs.push(("the sample's foreground mask", p.as_path()));
    }
    if let Some(p) = &cfg.region {
        inputs.push(("the target region", p.as_path()));
    }
    crate::io::staging::check_output(out, &inputs)
}

/// Replays the paint log of `painted` onto its recorded base quilt, writing
/// the result to `out` (byte-identical to `painted` when nothing changed).
pub fn replay(painted: &Path, out: &Path, progress: &dyn Progress) -> Result<PaintReport> {
    let q = Quilt::open(painted, crate::container::MemoryBudget::default())?;
    let Some(Param::Text(text)) = q.container().metadata().param("paint_log") else {
        return Err(Error::input(painted, "has no paint log (it was not painted)"));
    };
    let log = PaintLog::parse(text, painted, &q.samples[0])?.resolved_in(painted);
    q.check_output(out)?;
    let base = Quilt::open(&log.base, crate::container::MemoryBudget::default())?;
    base.check_output(out)?;
    if base.container().content_hash() != log.base_hash {
        return Err(Error::input(
            &log.base,
            format!("changed since {} was painted from it", painted.display()),
        ));
    }
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let mut current = log.base.clone();
    let mut done = PaintLog {
        strokes: Vec::new(),
        ..log.clone()
    };
    let mut report = PaintReport::default();
    for (k, stroke) in log.strokes.iter().enumerate() {
        let last = k + 1 == log.strokes.len();
        let target = if last {
            out.to_path_buf()
        } else {
            dir.path().join(format!("step{k}.quilt"))
        };
        let q = Quilt::open(&current, stroke.tile.memory)?;
        report = apply_stroke(&q, stroke, &target, &done, progress)?;
        done.strokes.push(stroke.clone());
        current = target;
    }
    Ok(report)
}

/// One recorded stroke: everything needed to apply it again.
#[derive(Clone, Debug, PartialEq)]
struct Stroke {
    sample: PathBuf,
    sample_mask: PathBuf,
    region: Option<PathBuf>,
    verbatim: Option<Verbatim>,
    transition: usize,
    /// The quilting options: the paint log records the seed, the patch
    /// radius, T_c and the constraint weight; the rest are
    /// [`TileConfig::default`]'s, so a replay quilts exactly the same.
    tile: TileConfig,
}

impl Stroke {
    fn from_config(cfg: &PaintConfig, base: &Quilt, quilt_path: &Path) -> Result<Stroke> {
        let masked = base.samples.get(base.mask_sample()).unwrap_or(&base.samples[0]);
        let sample = cfg.sample.clone().unwrap_or_else(|| masked.clone());
        if !sample.exists() {
            return Err(Error::input(&sample, "does not exist (the sample to paint with)"));
        }
        let recorded = match &base.sample_mask {
            Some(p) if same_file(masked, &sample) => {
                base.verify("sample_mask", p)?;
                Some(p.clone())
            }
            _ => None,
        };
        let sample_mask = match (&cfg.sample_mask, recorded) {
            (Some(p), _) => p.clone(),
            (None, Some(p)) => p,
            _ => {
                return Err(Error::Config(format!(
                    "give --sample-mask: {} records no foreground mask for the sample {}",
                    quilt_path.display(),
                    sample.display()
                )))
            }
        };
        match (&cfg.region, &cfg.verbatim) {
            (None, None) => return Err(Error::Config("give --region or --verbatim".into())),
            (Some(_), Some(_)) => {
                return Err(Error::Config(
                    "give either --region or --verbatim, not both".into(),
                ))
            }
            _ => {}
        }
        if cfg.preview.is_some() && cfg.verbatim.is_none() {
            return Err(Error::Config("--preview needs --verbatim".into()));
        }
        if let Some(v) = &cfg.verbatim {
            check_verbatim(v)?;
        }
        cfg.tile.validate()?;
        let t = &cfg.tile;
        // painting with the tiling's sample keeps its recorded width
        let (sample_width, sample_pixel) = match (t.sample_width, t.sample_pixel) {
            (None, None) => (recorded_span(base, &sample), None),
            given => given,
        };
        Ok(Stroke {
            tile: Stroke::tiling(
                t.seed,
                t.patch_radius,
                t.seam_threshold,
                t.constraint_weight,
                sample_width,
                sample_pixel,
                t.memory,
            ),
            sample,
            sample_mask,
            region: cfg.region.clone(),
            verbatim: cfg.verbatim,
            transition: cfg.transition,
        })
    }

    /// The quilting options of a stroke: the recorded ones over
    /// [`TileConfig::default`] (the memory budget does not change the
    /// result; the foreground mask is the stroke's `sample_mask`).
    fn tiling(
        seed: u64,
        patch_radius: Option<usize>,
        seam_threshold: f64,
        constraint_weight: f64,
        sample_width: Option<f64>,
        sample_pixel: Option<f64>,
        memory: crate::container::MemoryBudget,
    ) -> TileConfig {
        TileConfig {
            seed,
            patch_radius,
            seam_threshold,
            constraint_weight,
            sample_width,
            sample_pixel,
            memory,
            ..TileConfig::default()
        }
    }

    /// The stroke as the paint log records it.
    fn to_record(&self) -> StrokeRecord {
        let text = |p: &Path| p.display().to_string();
        StrokeRecord {
            sample: Some(text(&self.sample)),
            sample_mask: text(&self.sample_mask),
            region: self.region.as_deref().map(text),
            verbatim: self.verbatim.map(|v| VerbatimRecord {
                at: v.at,
                angle: v.angle,
            }),
            transition: self.transition,
            seed: self.tile.seed,
            patch_radius: self.tile.patch_radius,
            seam_threshold: self.tile.seam_threshold,
            constraint_weight: self.tile.constraint_weight,
            sample_width: self.tile.sample_width,
            sample_pixel: self.tile.sample_pixel,
        }
    }

    /// `base_sample`: the sample of logs written before strokes recorded
    /// theirs (the tiling's, the only one they could use).
    fn from_record(r: StrokeRecord, base_sample: &Path) -> Stroke {
        Stroke {
            tile: Stroke::tiling(
                r.seed,
                r.patch_radius,
                r.seam_threshold,
                r.constraint_weight,
                r.sample_width,
                r.sample_pixel,
                crate::container::MemoryBudget::default(),
            ),
            sample: r.sample.map_or_else(|| base_sample.to_path_buf(), PathBuf::from),
            sample_mask: PathBuf::from(r.sample_mask),
            region: r.region.map(PathBuf::from),
            verbatim: r.verbatim.map(|v| Verbatim {
                at: v.at,
                angle: v.angle,
            }),
            transition: r.transition,
        }
    }
}

/// The width (mesh units) the surface `base` records for `sample`, if it
/// draws from that sample and was given one: painting with the tiling's
/// sample keeps its size on the surface.
fn recorded_span(base: &Quilt, sample: &Path) -> Option<f64> {
    let k = base.samples.iter().position(|p| same_file(p, sample))?;
    match base
        .container()
        .metadata()
        .param(&format!("{}_span", sample_role(k)))
    {
        Some(Param::Float(v)) => Some(*v),
        _ => None,
    }
}

/// A stroke in the paint log's JSON. The fields are written in this order;
/// `sample` is absent from logs written before strokes recorded it.
#[derive(serde::Serialize, serde::Deserialize)]
struct StrokeRecord {
    #[serde(default)]
    sample: Option<String>,
    sample_mask: String,
    #[serde(default)]
    region: Option<String>,
    #[serde(default)]
    verbatim: Option<VerbatimRecord>,
    transition: usize,
    seed: u64,
    #[serde(default)]
    patch_radius: Option<usize>,
    seam_threshold: f64,
    constraint_weight: f64,
    /// Mesh units the sample's width spans; absent: one pixel per texel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sample_width: Option<f64>,
    /// Mesh units one sample pixel spans (instead of `sample_width`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sample_pixel: Option<f64>,
}

/// A verbatim copy in the paint log's JSON.
#[derive(serde::Serialize, serde::Deserialize)]
struct VerbatimRecord {
    at: [f32; 3],
    angle: f64,
}

/// The paint log's JSON: its base, the base's content hash (16 hex digits)
/// and the strokes.
#[derive(serde::Serialize, serde::Deserialize)]
struct LogRecord {
    base: String,
    base_hash: String,
    strokes: Vec<StrokeRecord>,
}

/// The paint log's JSON layout, as logs have always been written (they are
/// stored in `.quilt` files and replayed): `", "` and `": "` between items,
/// numbers as Rust prints them (`3`, not `3.0`), and control characters
/// other than a line feed as `\u00XX`.
struct LogFormatter;

impl serde_json::ser::Formatter for LogFormatter {
    fn begin_array_value<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        if first {
            Ok(())
        } else {
            w.write_all(b", ")
        }
    }

    fn begin_object_key<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        self.begin_array_value(w, first)
    }

    fn begin_object_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b": ")
    }

    fn write_f32<W: ?Sized + std::io::Write>(&mut self, w: &mut W, v: f32) -> std::io::Result<()> {
        write!(w, "{v}")
    }

    fn write_f64<W: ?Sized + std::io::Write>(&mut self, w: &mut W, v: f64) -> std::io::Result<()> {
        write!(w, "{v}")
    }

    fn write_char_escape<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        escape: serde_json::ser::CharEscape,
    ) -> std::io::Result<()> {
        use serde_json::ser::CharEscape as E;
        match escape {
            E::Quote => w.write_all(b"\\\""),
            E::ReverseSolidus => w.write_all(b"\\\\"),
            E::Solidus => w.write_all(b"/"),
            E::LineFeed => w.write_all(b"\\n"),
            E::Backspace => write!(w, "\\u{:04x}", 0x08),
            E::FormFeed => write!(w, "\\u{:04x}", 0x0c),
            E::CarriageReturn => write!(w, "\\u{:04x}", 0x0d),
            E::Tab => write!(w, "\\u{:04x}", 0x09),
            E::AsciiControl(c) => write!(w, "\\u{c:04x}"),
        }
    }
}

impl PaintLog {
    /// The log with every path it records made relative to the folder of
    /// the quilt `out` that will store it, so a painted surface and its
    /// inputs can move together and be replayed from any working directory.
    fn relative_to(&self, out: &Path) -> PaintLog {
        let rel = |p: &Path| PathBuf::from(crate::io::staging::relative_to_folder_of(out, p));
        PaintLog {
            base: rel(&self.base),
            base_hash: self.base_hash,
            strokes: self
                .strokes
                .iter()
                .map(|s| Stroke {
                    sample: rel(&s.sample),
                    sample_mask: rel(&s.sample_mask),
                    region: s.region.as_deref().map(rel),
                    ..s.clone()
                })
                .collect(),
        }
    }

    /// The log read from the quilt `file`, its paths resolved against that
    /// quilt's folder.
    fn resolved_in(self, file: &Path) -> PaintLog {
        let abs = |p: &Path| crate::io::staging::resolve_in_folder_of(file, p);
        PaintLog {
            base: abs(&self.base),
            base_hash: self.base_hash,
            strokes: self
                .strokes
                .into_iter()
                .map(|s| Stroke {
                    sample: abs(&s.sample),
                    sample_mask: abs(&s.sample_mask),
                    region: s.region.as_deref().map(abs),
                    ..s
                })
                .collect(),
        }
    }
}

/// The paint log stored in a painted quilt: its base and its strokes.
#[derive(Clone, Debug)]
struct PaintLog {
    base: PathBuf,
    base_hash: u64,
    strokes: Vec<Stroke>,
}

impl PaintLog {
    fn to_json(&self) -> Result<String> {
        let record = LogRecord {
            base: self.base.display().to_string(),
            base_hash: format!("{:016x}", self.base_hash),
            strokes: self.strokes.iter().map(Stroke::to_record).collect(),
        };
        let mut out = Vec::new();
        let mut ser = serde_json::Serializer::with_formatter(&mut out, LogFormatter);
        serde::Serialize::serialize(&record, &mut ser)
            .map_err(|e| Error::Config(format!("cannot write the paint log: {e}")))?;
        String::from_utf8(out).map_err(|e| Error::Config(format!("cannot write the paint log: {e}")))
    }

    fn parse(text: &str, file: &Path, base_sample: &Path) -> Result<PaintLog> {
        let bad = |why: String| Error::input(file, format!("has a malformed paint log: {why}"));
        let record: LogRecord = serde_json::from_str(text).map_err(|e| bad(e.to_string()))?;
        let base_hash = u64::from_str_radix(&record.base_hash, 16)
            .map_err(|e| bad(format!("base_hash \"{}\": {e}", record.base_hash)))?;
        Ok(PaintLog {
            base: PathBuf::from(record.base),
            base_hash,
            strokes: record
                .strokes
                .into_iter()
                .map(|s| Stroke::from_record(s, base_sample))
                .collect(),
        })
    }
}

/// Applies one stroke to `base`, writing `out` with `log` + the stroke.
fn apply_stroke(
    base: &Quilt,
    stroke: &Stroke,
    out: &Path,
    log: &PaintLog,
    progress: &dyn Progress,
) -> Result<PaintReport> {
    let start = Instant::now();
    let trace = |what: &str| crate::progress::trace(progress, start, what);
    let (mut syn, gim, _tmp) = open_synthesis(base, stroke, out, progress)?;
    let mut report = PaintReport::default();
    if let Some(v) = stroke.verbatim {
        let (centre, extent) = foreground_extent(&syn);
        let vertex = verbatim_vertex(&syn, &v)?;
        let radius = (extent * 1.15).ceil() as usize + 4;
        let (taken, _) = syn.verbatim(vertex, radius, v.angle.to_radians(), centre, false, progress)?;
        report.repainted = taken;
        report.patches = 1;
        (report.region_texels, report.zone_texels) = syn.target_summary();
    } else {
        let region_path = stroke.region.as_deref().expect("checked: a region or verbatim");
        let region = read_region(&syn, &gim, region_path)?;
        let zone = constraint_function(&syn, &region, stroke.transition);
        report.region_texels = region.len();
        report.zone_texels = zone.len();
        if report.region_texels == 0 {
            return Err(Error::input(region_path, "marks no texel of the surface"));
        }
        syn.set_target_zone(&zone);
        trace("region");
        // every texel of the zone is re-synthesized once, as the seed or
        // inside (not on the rim of) a work patch; seeds deepest in F first
        // (highest m0, then lowest id), so the first patch lays the feature
        // where it must be and later ones continue it
        let mut order = zone;
        order.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let order: Vec<u32> = order.into_iter().map(|(t, _)| t).collect();
        let radius0 = syn.radius0();
        progress.begin("paint", report.zone_texels as u64);
        syn.paint_seeds(&order, radius0, &|n| progress.advance(n as u64), progress)?;
        progress.end();
        trace("painted");
        report.patches = syn.report.patches;
        report.repainted = syn.changed_patches(base)?;
    }
    let mut log = log.clone();
    log.strokes.push(stroke.clone());
    syn.write(
        out,
        &gim,
        &base.gim,
        Some(&log.relative_to(out).to_json()?),
        start,
    )?;
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// The foreground's centroid (sample pixels) and its largest distance from
/// it.
fn foreground_extent(syn: &Synthesis) -> ([f64; 2], f64) {
    let (w, mask) = syn.sample_mask();
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0usize);
    for (i, &m) in mask.iter().enumerate() {
        if m >= 0.5 {
            sx += (i % w) as f64;
            sy += (i / w) as f64;
            n += 1;
        }
    }
    let c = [sx / n.max(1) as f64, sy / n.max(1) as f64];
    let extent = mask
        .iter()
        .enumerate()
        .filter(|(_, &m)| m >= 0.5)
        .map(|(i, _)| (((i % w) as f64 - c[0]).powi(2) + ((i / w) as f64 - c[1]).powi(2)).sqrt())
        .fold(0.0, f64::max);
    (c, extent)
}

/// The dense vertex nearest to a 3D point (lowest id among equals),
/// computed in f64 so that far points compare correctly. Refuses, with the
/// reason, a point that is not finite or that lies farther from the surface
/// than the surface's own size (its bounding-box diagonal): such a point was
/// meant for another mesh or other units, and its "nearest vertex" would be
/// an arbitrary one.
fn nearest_vertex(syn: &Synthesis, p: [f64; 3]) -> std::result::Result<u32, String> {
    let show = |p: [f64; 3]| format!("({}, {}, {})", short(p[0]), short(p[1]), short(p[2]));
    if !p.iter().all(|c| c.is_finite()) {
        return Err(format!("point {} is not a finite position", show(p)));
    }
    let r = syn.resolution();
    let mut best: Option<(f64, u32)> = None;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for t in 0..(r * r) as u32 {
        if syn.chart(t) == EMPTY {
            continue;
        }
        let q = syn.position(t).map(|c| c as f64);
        if !q.iter().all(|c| c.is_finite()) {
            continue;
        }
        for k in 0..3 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
        let d = (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f64>();
        if best.map_or(true, |(b, _)| d < b) {
            best = Some((d, t));
        }
    }
    let Some((d2, t)) = best else {
        return Err("the surface has no dense vertex to place it on".into());
    };
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let d = d2.sqrt();
    if !d.is_finite() || d > diag {
        return Err(format!(
            "point {} is {} from the surface, farther than the surface's size \
             (bounding-box diagonal {}): give a point on or near the mesh, in its units",
            show(p),
            short(d),
            short(diag)
        ));
    }
    Ok(t)
}

/// A number for a message: 4 decimals in ordinary ranges, else scientific.
fn short(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-3..1e6).contains(&x.abs()) {
        format!("{x:.3e}")
    } else {
        format!("{}", (x * 1e4).round() / 1e4)
    }
}

/// Checks a verbatim copy's numbers: a finite point and a finite angle.
fn check_verbatim(v: &Verbatim) -> Result<()> {
    if !v.at.iter().all(|c| c.is_finite()) {
        return Err(Error::Config(format!(
            "--at {},{},{}: each coordinate must be a finite number",
            v.at[0], v.at[1], v.at[2]
        )));
    }
    if !v.angle.is_finite() {
        return Err(Error::Config(format!(
            "--angle {}: must be a finite number of degrees",
            v.angle
        )));
    }
    Ok(())
}

/// The dense vertex for a verbatim copy at `v.at`.
fn verbatim_vertex(syn: &Synthesis, v: &Verbatim) -> Result<u32> {
    check_verbatim(v)?;
    nearest_vertex(syn, v.at.map(|c| c as f64)).map_err(|why| Error::Config(format!("--at: {why}")))
}

/// Checks stroke `k` of the strokes file `path` after parsing: a finite
/// point and a finite radius > 0; the error names the file and the stroke.
fn check_stroke(path: &Path, k: usize, point: [f64; 3], radius: f64) -> Result<()> {
    if !point.iter().all(|c| c.is_finite()) {
        return Err(Error::input(
            path,
            format!(
                "stroke {k}: \"point\" [{}, {}, {}] is not a finite position",
                point[0], point[1], point[2]
            ),
        ));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(Error::input(
            path,
            format!("stroke {k}: \"radius\" {radius} must be a finite number > 0"),
        ));
    }
    Ok(())
}

/// The region F (its texels, ascending), from a mask PNG, a mesh with
/// vertex paint, or JSON strokes (by extension).
fn read_region(syn: &Synthesis, gim: &Gim, path: &Path) -> Result<Vec<u32>> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let r = syn.resolution();
    let texels = |marked: Vec<bool>| -> Vec<u32> {
        (0..marked.len() as u32).filter(|&t| marked[t as usize]).collect()
    };
    match ext.as_str() {
        _ if crate::io::imageio::is_image_path(path) => {
            let mask =
                crate::io::imageio::read_sized_mask(path, r, r, "a region mask must be the atlas size")?;
            Ok((0..mask.len() as u32)
                .filter(|&t| mask[t as usize] >= 0.5 && syn.chart(t) != EMPTY)
                .collect())
        }
        "ply" | "obj" => Ok(texels(vertex_paint_region(
            gim,
            &gim.read::<u32>("chart")?,
            path,
        )?)),
        "json" => strokes_region(syn, path),
        _ => Err(Error::input(
            path,
            "is not a region: give a mask .png, a .ply/.obj with vertex paint, or .json strokes",
        )),
    }
}

/// F from per-vertex paint on the input mesh: a vertex is in F when its
/// weight (PLY `quality`/`weight`/`value`) is ≥ ½, or, for vertex colours,
/// when its colour differs from the mesh's dominant (unpainted) colour by
/// ≥ ½ in some channel. Per texel the corner weights are interpolated with
/// the texel's barycentrics on its face.
fn vertex_paint_region(gim: &Gim, chart: &[u32], path: &Path) -> Result<Vec<bool>> {
    let (painted, _) = crate::mesh::io::load(path, &crate::mesh::io::LoadOptions::default())?;
    let weights: Vec<f32> = if let Some(w) = &painted.vertex_weights {
        w.clone()
    } else if let Some(c) = &painted.vertex_colors {
        let q = |c: &[f32; 3]| c.map(|v| (v * 15.0).round() as u8);
        let mut counts: std::collections::BTreeMap<[u8; 3], usize> = Default::default();
        for col in c {
            *counts.entry(q(col)).or_default() += 1;
        }
        let dominant = counts
            .iter()
            .max_by_key(|(k, n)| (**n, std::cmp::Reverse(**k)))
            .map(|(k, _)| k.map(|v| v as f32 / 15.0))
            .unwrap_or([0.0; 3]);
        c.iter()
            .map(|col| (0..3).map(|k| (col[k] - dominant[k]).abs()).fold(0f32, f32::max))
            .collect()
    } else {
        return Err(Error::input(
            path,
            "has no vertex paint (no quality/weight property and no vertex colours)",
        ));
    };
    let mesh = gim.mesh()?;
    // each mesh vertex's weight: the painted vertex at the same position
    // (both went through the same repair), else the nearest one
    let key = |p: [f32; 3]| p.map(|c| c.to_bits());
    let mut by_pos: std::collections::HashMap<[u32; 3], usize> = Default::default();
    for (i, &p) in painted.positions.iter().enumerate() {
        by_pos.entry(key(p)).or_insert(i);
    }
    let vertex_weight: Vec<f32> = mesh
        .positions
        .iter()
        .map(|&p| {
            let i = by_pos.get(&key(p)).copied().unwrap_or_else(|| {
                let d = |q: [f32; 3]| (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f32>();
                (0..painted.positions.len())
                    .min_by(|&a, &b| d(painted.positions[a]).total_cmp(&d(painted.positions[b])))
                    .unwrap_or(0)
            });
            weights.get(i).copied().unwrap_or(0.0)
        })
        .collect();
    if !vertex_weight.iter().any(|&w| w >= 0.5) {
        return Err(Error::input(path, "paints no vertex (no weight ≥ ½)"));
    }
    let face: Vec<u32> = gim.read("face")?;
    let bary: Vec<f32> = gim.read("bary")?;
    Ok((0..chart.len())
        .map(|t| {
            if chart[t] == EMPTY {
                return false;
            }
            let tri = mesh.triangles[face[t] as usize];
            let (b1, b2) = (bary[t * 2], bary[t * 2 + 1]);
            let w = (1.0 - b1 - b2) * vertex_weight[tri[0] as usize]
                + b1 * vertex_weight[tri[1] as usize]
                + b2 * vertex_weight[tri[2] as usize];
            w >= 0.5
        })
        .collect())
}

#[cfg(test)]
mod log_json_tests {
    use super::*;

    #[test]
    fn the_paint_log_keeps_its_text_and_reads_back() {
        let stroke = |region: Option<&str>, verbatim| Stroke {
            sample: PathBuf::from("dir/s.png"),
            sample_mask: PathBuf::from("m \"q\"\\\ttab\nline.png"),
            region: region.map(PathBuf::from),
            verbatim,
            transition: 8,
            tile: Stroke::tiling(
                u64::MAX,
                Some(5),
                3.0,
                0.1,
                None,
                None,
                crate::container::MemoryBudget::default(),
            ),
        };
        let log = PaintLog {
            base: PathBuf::from("q.quilt"),
            base_hash: 0xa2c2_693c_3c2e_8b45,
            strokes: vec![
                stroke(Some("st.json"), None),
                stroke(
                    None,
                    Some(Verbatim {
                        at: [0.3, -0.6, 0.0],
                        angle: 12.5,
                    }),
                ),
            ],
        };
        let text = log.to_json().unwrap();
        // the text logs have always had: ", " and ": ", numbers as Rust
        // prints them, control characters but the line feed as \u00XX
        let s1 = "{\"sample\": \"dir/s.png\", \"sample_mask\": \"m \\\"q\\\"\\\\\\u0009tab\\nline.png\", ";
        let tail = "\"transition\": 8, \"seed\": 18446744073709551615, \"patch_radius\": 5, \"seam_threshold\": 3, \"constraint_weight\": 0.1}";
        let want = format!(
            "{{\"base\": \"q.quilt\", \"base_hash\": \"a2c2693c3c2e8b45\", \"strokes\": [\
             {s1}\"region\": \"st.json\", \"verbatim\": null, {tail}, \
             {s1}\"region\": null, \"verbatim\": {{\"at\": [0.3, -0.6, 0], \"angle\": 12.5}}, {tail}]}}"
        );
        assert_eq!(text, want);
        let back = PaintLog::parse(&text, Path::new("p.quilt"), Path::new("base.png")).unwrap();
        assert_eq!(back.to_json().unwrap(), text);
        assert_eq!(back.base_hash, log.base_hash);
        assert_eq!(back.strokes[1].verbatim, log.strokes[1].verbatim);
        // a log without a stroke's sample (older logs) reads the base's
        let old = text.replacen("\"sample\": \"dir/s.png\", ", "", 1);
        let back = PaintLog::parse(&old, Path::new("p.quilt"), Path::new("base.png")).unwrap();
        assert_eq!(back.strokes[0].sample, PathBuf::from("base.png"));
        // malformed: named, with the position
        let e = PaintLog::parse("{\"base\": 1}", Path::new("p.quilt"), Path::new("b.png"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("p.quilt") && e.contains("malformed paint log") && e.contains("column"),
            "{e}"
        );
    }
}

/// One stroke of a strokes file.
#[derive(serde::Deserialize)]
struct StrokeSpec {
    point: [f64; 3],
    radius: f64,
}

/// F from JSON strokes `[{"point": [x, y, z], "radius": r}, …]`: the union
/// of geodesic disks on the dense mesh (Dijkstra over its edges with their
/// 3D lengths, from the vertex nearest each point).
fn strokes_region(syn: &Synthesis, path: &Path) -> Result<Vec<u32>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |why: &str| Error::input(path, format!("is not a stroke list ({why})"));
    let strokes: Vec<StrokeSpec> = serde_json::from_slice(&bytes)
        .map_err(|e| bad(&format!("[{{\"point\": [x, y, z], \"radius\": r}}, …]: {e}")))?;
    if strokes.is_empty() {
        return Err(bad("the list is empty"));
    }
    let r = syn.resolution();
    let mut region = std::collections::BTreeSet::new();
    // geodesic distance of the texels the current disk reached
    let mut dist: std::collections::HashMap<u32, f32> = Default::default();
    for (k, s) in strokes.iter().enumerate() {
        let (point, radius) = (s.point, s.radius);
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(bad(&format!("stroke {k} has no positive \"radius\"")));
        }
        check_stroke(path, k, point, radius)?;
        let source =
            nearest_vertex(syn, point).map_err(|why| Error::input(path, format!("stroke {k}: {why}")))?;
        // Dijkstra bounded by the radius
        dist.clear();
        dist.insert(source, 0.0);
        let mut heap = BinaryHeap::new();
        heap.push((std::cmp::Reverse(OrdF32(0.0)), source));
        while let Some((std::cmp::Reverse(OrdF32(d)), t)) = heap.pop() {
            if d > dist[&t] {
                continue;
            }
            region.insert(t);
            let p = syn.position(t);
            let mut relax = |nb: u32| {
                let q = syn.position(nb);
                let nd = d + ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                let old = dist.entry(nb).or_insert(f32::INFINITY);
                if nd <= radius as f32 && nd < *old {
                    *old = nd;
                    heap.push((std::cmp::Reverse(OrdF32(nd)), nb));
                }
            };
            syn.for_each_neighbour(t, |nb, _| relax(nb));
            // diagonal grid neighbours too, so the disk is round (8-neighbour
            // paths are within 8 % of the geodesic distance)
            let (x, y) = ((t as usize % r) as isize, (t as usize / r) as isize);
            for (dx, dy) in [(-1, -1), (1, -1), (-1, 1), (1, 1)] {
                let (nx, ny) = (x + dx, y + dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < r && (ny as usize) < r {
                    let nb = ny as usize * r + nx as usize;
                    if syn.chart(nb as u32) == syn.chart(t) {
                        relax(nb as u32);
                    }
                }
            }
        }
    }
    Ok(region.into_iter().collect())
}

/// A totally ordered f32 for the Dijkstra heap.
#[derive(Clone, Copy, PartialEq)]
struct OrdF32(f32);

impl Eq for OrdF32 {}

impl PartialOrd for OrdF32 {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for OrdF32 {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The constraint function m0 (§IV): 1 on F (`region`, its texels), falling
/// linearly to 0 over `transition` texels of hop distance outside F on the
/// dense mesh. Returns the zone where m0 > 0, `(texel, m0)` by texel.
fn constraint_function(syn: &Synthesis, region: &[u32], transition: usize) -> Vec<(u32, f32)> {
    let mut hops: std::collections::HashMap<u32, u32> = region.iter().map(|&t| (t, 0)).collect();
    let mut queue: VecDeque<u32> = region.iter().copied().collect();
    while let Some(t) = queue.pop_front() {
        let d = hops[&t];
        if d as usize >= transition {
            continue;
        }
        syn.for_each_neighbour(t, |nb, _| {
            if let std::collections::hash_map::Entry::Vacant(e) = hops.entry(nb) {
                e.insert(d + 1);
                queue.push_back(nb);
            }
        });
    }
    let mut zone: Vec<(u32, f32)> = hops
        .into_iter()
        .map(|(t, d)| (t, (1.0 - d as f32 / (transition as f32 + 1.0)).max(0.0)))
        .filter(|&(_, m)| m > 0.0)
        .collect();
    zone.sort_unstable_by_key(|e| e.0);
    zone
}
