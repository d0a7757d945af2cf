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
use crate::container::{MemoryBudget, Param};
use crate::progress::Progress;
pub use crate::quilt::Projection;
use crate::quilt::{
    foreign_sample_bytes, same_file, sample_at_density, sample_pixel_size, CourseMode, Quilt, SizedSample,
    StoredPattern, Synthesis, TileConfig,
};
use crate::{Error, Result};

mod log;
mod region;
use log::{PaintLog, StrokeRecord, VerbatimRecord};
use region::{check_verbatim, constraint_function, foreground_extent, read_region, verbatim_vertex};

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
    /// How a stroke lays the courses of a sample whose features run in
    /// rows. `None` (the default): as the surface was tiled — locked to its
    /// stripe pattern when it was tiled with [`CourseMode::Locked`] and the
    /// stroke paints with the tiling's sample at its width, or with a
    /// sample whose courses lie within 5 % of the pattern's spacing on the
    /// surface (a verbatim copy also only along the field, at angle 0);
    /// free otherwise. [`CourseMode::Locked`] is refused where that does
    /// not hold.
    pub courses: Option<CourseMode>,
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
            courses: None,
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
    /// The stroke's courses were locked to the surface's stripe pattern.
    pub locked_courses: bool,
}

impl std::fmt::Display for PaintReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "region {} texels ({} with the transition zone), {} patches, {} texels repainted, {:.2} s",
            self.region_texels, self.zone_texels, self.patches, self.repainted, self.seconds
        )?;
        if self.locked_courses {
            write!(f, "; courses locked to the surface's stripe pattern")?;
        }
        Ok(())
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
    check_paint_output(&Quilt::open(quilt_path, reading(cfg.tile.memory))?, cfg, out)?;
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
        let base = Quilt::open(quilt_path, reading(cfg.tile.memory))?;
        // a stroke resolves the sample and mask defaults; its place and
        // turn are given per preview (courses resolved as for a copy along
        // the field, which a locked surface locks)
        let stroke = Stroke::from_config(
            &PaintConfig {
                region: None,
                preview: None,
                verbatim: Some(Verbatim {
                    at: cfg.verbatim.map_or([0.0; 3], |v| v.at),
                    angle: 0.0,
                }),
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
    // the other samples the surface draws from keep their maps and
    // previews while the stroke runs (a sample that cannot be read counts
    // nothing here: loading names it if the surface still shows it)
    let others: u64 = (base.samples.iter())
        .filter(|p| !same_file(p, &stroke.sample))
        .map(|p| foreign_sample_bytes(p).unwrap_or(0))
        .sum();
    let cfg = TileConfig {
        sample_mask: Some(stroke.sample_mask.clone()),
        // what reading the base surface and the other samples leave
        memory: stroke_budgets(stroke.tile.memory)[1].less(others),
        ..stroke.tile.clone()
    };
    // (the synthesis reads the surface by tiles through a reader of its
    // own; this one reads the region's planes in bands)
    let gim = base.open_gim(None, MemoryBudget(1 << 20))?;
    let matching = stroke.verbatim.is_none();
    let sized = sample_at_density(
        &stroke.sample,
        gim.texel_size,
        cfg.sample_size(),
        matching,
        cfg.memory,
        progress,
    )?;
    let trace = |what: &str| crate::progress::trace(progress, start, what);
    trace("factorized");
    // a locked stroke locks to the pattern the surface stores, if it does
    let stored = base.stripe_pattern()?.map(|(period, psi)| StoredPattern {
        file: base.container().path().to_path_buf(),
        period,
        psi,
        free_unless_fit: stroke.free_unless_fit,
    });
    let mut syn = Synthesis::open(
        &gim,
        &stroke.sample,
        &sized,
        beside,
        &cfg,
        matching,
        stored.as_ref().filter(|_| cfg.courses == CourseMode::Locked),
    )?;
    syn.set_scale(&sized);
    trace("opened");
    syn.set_mask(&stroke.sample_mask)?;
    syn.load(base, progress)?;
    syn.painting = true;
    // a painted surface keeps the base's courses and their pattern,
    // whatever the stroke's
    syn.base_locked_courses = base.locked_courses();
    syn.kept_pattern = stored;
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
    let base = Quilt::open(quilt_path, reading(cfg.tile.memory))?;
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

/// `--memory` split between caching the base surface's decoded chunks
/// while a stroke loads it tile by tile (an eighth) and the stroke's
/// synthesis (the rest).
fn stroke_budgets(memory: MemoryBudget) -> [MemoryBudget; 2] {
    memory.split([1, 7])
}

/// The first share of [`stroke_budgets`]: the base surface's reads.
fn reading(memory: MemoryBudget) -> MemoryBudget {
    stroke_budgets(memory)[0]
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
/// the result to `out` (byte-identical to `painted` when nothing changed),
/// each stroke within `memory` (which does not change the result).
pub fn replay(
    painted: &Path,
    out: &Path,
    memory: MemoryBudget,
    progress: &dyn Progress,
) -> Result<PaintReport> {
    let q = Quilt::open(painted, MemoryBudget(1 << 20))?;
    let Some(Param::Text(text)) = q.container().metadata().param("paint_log") else {
        return Err(Error::input(painted, "has no paint log (it was not painted)"));
    };
    let log = PaintLog::parse(text, painted, &q.samples[0])?.resolved_in(painted);
    q.check_output(out)?;
    let base = Quilt::open(&log.base, MemoryBudget(1 << 20))?;
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
        let q = Quilt::open(&current, reading(memory))?;
        let within = Stroke {
            tile: TileConfig {
                memory,
                ..stroke.tile.clone()
            },
            ..stroke.clone()
        };
        report = apply_stroke(&q, &within, &target, &done, progress)?;
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
    /// Locked courses ([`PaintConfig::courses`] left to the surface) with
    /// another sample than the tiling's: laid free if its courses do not
    /// fit the surface's pattern. The log records what the stroke did.
    free_unless_fit: bool,
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
        let (sample_width, sample_pixel) = match (t.sample_width, t.sample_pixel) {
            (None, None) => (default_width(base, &sample)?, None),
            given => given,
        };
        let (courses, free_unless_fit) =
            stroke_courses(cfg, base, quilt_path, &sample, (sample_width, sample_pixel))?;
        Ok(Stroke {
            tile: Stroke::tiling(&TileConfig {
                sample_width,
                sample_pixel,
                courses,
                ..t.clone()
            }),
            sample,
            sample_mask,
            free_unless_fit,
            region: cfg.region.clone(),
            verbatim: cfg.verbatim,
            transition: cfg.transition,
        })
    }

    /// The quilting options of a stroke: those of `given` the paint log
    /// records, and its memory budget (which does not change the result),
    /// over [`TileConfig::default`] (the foreground mask is the stroke's
    /// `sample_mask`).
    fn tiling(given: &TileConfig) -> TileConfig {
        TileConfig {
            seed: given.seed,
            patch_radius: given.patch_radius,
            seam_threshold: given.seam_threshold,
            constraint_weight: given.constraint_weight,
            sample_width: given.sample_width,
            sample_pixel: given.sample_pixel,
            courses: given.courses,
            memory: given.memory,
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
            locked_courses: self.tile.courses == CourseMode::Locked,
        }
    }

    /// `base_sample`: the sample of logs written before strokes recorded
    /// theirs (the tiling's, the only one they could use).
    fn from_record(r: StrokeRecord, base_sample: &Path) -> Stroke {
        Stroke {
            tile: Stroke::tiling(&TileConfig {
                seed: r.seed,
                patch_radius: r.patch_radius,
                seam_threshold: r.seam_threshold,
                constraint_weight: r.constraint_weight,
                sample_width: r.sample_width,
                sample_pixel: r.sample_pixel,
                courses: if r.locked_courses {
                    CourseMode::Locked
                } else {
                    CourseMode::Free
                },
                ..TileConfig::default()
            }),
            sample: r.sample.map_or_else(|| base_sample.to_path_buf(), PathBuf::from),
            sample_mask: PathBuf::from(r.sample_mask),
            region: r.region.map(PathBuf::from),
            verbatim: r.verbatim.map(|v| Verbatim {
                at: v.at,
                angle: v.angle,
            }),
            transition: r.transition,
            free_unless_fit: false,
        }
    }
}

/// How a stroke of `cfg` with `sample` at `size` (its width or pixel in
/// mesh units) lays its courses on `base` ([`PaintConfig::courses`]), and
/// whether a lock that does not fit may fall back to free. Locked only on
/// a surface tiled locked, and a verbatim copy only when it is not turned
/// from the field (`--angle 0`): with the tiling's sample at the tiling's
/// width (the surface's own pattern), or with any sample whose courses fit
/// the pattern the surface stores (judged when the sample is open,
/// [`crate::quilt::PATTERN_FIT`]).
fn stroke_courses(
    cfg: &PaintConfig,
    base: &Quilt,
    quilt_path: &Path,
    sample: &Path,
    size: (Option<f64>, Option<f64>),
) -> Result<(CourseMode, bool)> {
    let tiling = &base.samples[0];
    let turned = cfg.verbatim.is_some_and(|v| v.angle != 0.0);
    let own = same_file(tiling, sample) && size == (recorded_span(base, tiling), None);
    let lockable = base.locked_courses() && !turned && (own || base.stores_stripe_pattern());
    match cfg.courses {
        None if lockable => Ok((CourseMode::Locked, !own)),
        None | Some(CourseMode::Free) => Ok((CourseMode::Free, false)),
        Some(CourseMode::Locked) if lockable => Ok((CourseMode::Locked, false)),
        Some(CourseMode::Locked) if !base.locked_courses() => Err(Error::input(
            quilt_path,
            "was not tiled with --courses locked: it has no stripe pattern to lock a stroke's courses to",
        )),
        Some(CourseMode::Locked) if turned => Err(Error::Config(
            "a verbatim copy turned from the field (--angle) keeps its own rows: give --angle 0 to lock its \
             courses, or --courses free"
                .into(),
        )),
        Some(CourseMode::Locked) => Err(Error::input(
            quilt_path,
            format!(
                "stores no stripe pattern: --courses locked paints on it only with the tiling's sample {} \
                 at its width (leave out --sample-width and --sample-pixel), or use --courses free",
                tiling.display()
            ),
        )),
    }
}

/// The width (mesh units) the surface `base` records for `sample`, if it
/// draws from that sample and was given one: painting with the tiling's
/// sample keeps its size on the surface.
fn recorded_span(base: &Quilt, sample: &Path) -> Option<f64> {
    let k = base.samples.iter().position(|p| same_file(p, sample))?;
    base.sample_span(k)
}

/// The width a stroke's sample takes when none is given: a sample the
/// surface already draws from keeps its recorded width; another sample
/// takes the tiling sample's pixel size (a twin of the same size its
/// width), so both show at one scale. `None` (one pixel per texel) where
/// the tiling was given no width.
fn default_width(base: &Quilt, sample: &Path) -> Result<Option<f64>> {
    if base.samples.iter().any(|p| same_file(p, sample)) {
        return Ok(recorded_span(base, sample));
    }
    let Some(span) = base.sample_span(0) else {
        return Ok(None);
    };
    let [tiling_width, _] = sample_pixel_size(base.sample_file(0)?)?;
    let [width, _] = sample_pixel_size(sample)?;
    Ok(Some(if width == tiling_width {
        span
    } else {
        span / tiling_width as f64 * width as f64
    }))
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
    // what the stroke did: a sample whose courses do not fit is laid free
    let mut stroke = stroke.clone();
    if !syn.locks_courses() {
        stroke.tile.courses = CourseMode::Free;
    }
    let mut report = PaintReport {
        locked_courses: syn.locks_courses(),
        ..PaintReport::default()
    };
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
