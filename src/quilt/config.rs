//! The quilting stage's options ([`TileConfig`], every default and its
//! validation), its report ([`TileReport`]) and the tuning constants of seam
//! refinement.

use std::path::PathBuf;

use crate::container::MemoryBudget;
use crate::{Error, Result};

/// Options of [`tile`](super::tile).
#[derive(Clone, Debug, PartialEq)]
pub struct TileConfig {
    /// Work-patch radius r_w in BFS hops; `None` = 32 per 512 texels of
    /// atlas, at most a quarter of the sample's smaller side.
    pub patch_radius: Option<usize>,
    /// Smallest radius of the hierarchical search.
    pub min_radius: usize,
    /// Accept a fitting if its mean seam cost ≤ this × the sample's mean
    /// neighbour difference (T_c). A seam edge's cost sums two differences
    /// (‖A(s)−B(s)‖ + ‖A(t)−B(t)‖), so 2 is a seam as strong as the
    /// sample's own edges; 3 (the default) keeps patches large, which on
    /// Spot gave fewer broken structures than 2, whose many small patches
    /// multiply the seams (and is 5–7× faster).
    pub seam_threshold: f64,
    /// The seeded choice of a placement draws from those costing at most
    /// (1 + tolerance) × the best, after the occurrence penalty. 0 (the
    /// default) takes the best (the seed breaks ties and picks the first
    /// work patch): with the occurrence penalty spreading the sample's use,
    /// 400² flat-square quilts of eight samples came out more coherent and
    /// more complete than at 0.1 (docs/measurements.md, "Coherence and
    /// completeness in 2D").
    pub tolerance: f64,
    /// Weight of the occurrence penalty in matching: a placement costs this
    /// × (the sample's neighbour difference)² × the mean use, relative to
    /// the sample's mean use, of the sample pixels it covers, so work
    /// patches spread over the sample's whole variety instead of returning
    /// to the region that matches best (Kaspar et al. 2015). 0 turns it off.
    /// Default 0.5: against 1, on eleven 400² flat-square quilts the
    /// coherence's 95th percentile (geometric mean) fell from 0.0337 to
    /// 0.0330 and completeness rose from 0.0117 to 0.0122 (23 → 24 % of
    /// the sample never used); on Spot and Bob at 1024² with the wall, the
    /// plaster and the wood the 95th percentile fell by 0–14 % with 1–5
    /// points more of the sample never used (docs/measurements.md,
    /// "Refinement where features end by default").
    pub occurrence_weight: f64,
    /// Weight of the structure channel (each sample pixel's distance to the
    /// nearest strong edge of the sample, 0..1; see `src/quilt/structure.rs`)
    /// in matching, the cut cost and seam refinement, in sample neighbour
    /// differences: a cut between a texel on an edge and one as far from
    /// any edge as the sample's features are apart costs this many more.
    /// 0 (the default) turns it off: colour only. On six 2D samples it
    /// changed no figure for the better at 0.5, 1 or 2 (coherence's 95th
    /// percentile 2–5 % worse), and on Spot at 1024² with the brick wall at
    /// twice its size offset courses remained at patch seams: they come
    /// from the field turning between patches, which a cut cost cannot
    /// undo.
    pub structure_weight: f64,
    /// Feature alignment: before the cut, each new patch is bent by up to
    /// this share of its radius so that its features meet the old texels
    /// of the overlap (Wu & Yu 2004; `src/quilt/align.rs`), where a rigid
    /// placement can line its courses up with only one of the patches
    /// around it. 0 keeps patches rigid; the default, 0.09, is the share
    /// that left fewest broken courses on Spot (docs/measurements.md,
    /// "Feature alignment").
    pub feature_align: f64,
    /// Matching may turn the sample up to this many rotation steps (5° for
    /// 72 rotated copies) away from the work patch's mean field direction
    /// where the field turns inside the patch: a climb from the direction
    /// the sample already has around the patch picks the copy (ranked on a
    /// 4× coarser match), so a patch follows its neighbours' courses. 0
    /// keeps the field's nearest copy. A constant field (a flat square) is
    /// unaffected. Default 2: on Spot and Bob at 1024² with the brick wall
    /// at the size of a 4096² close-up, structure broken at seams
    /// (`evaluate`'s `continuation`) fell by 28–29 % against 1 step where
    /// the field turns by a step (the climb at 1: 19–26 %, at 4: 31–32 %),
    /// with no more time. Following the neighbours, courses drift from the
    /// field by up to this many steps: on Bob's body about 10° at 2 and
    /// 20° at 4 (docs/measurements.md, "Structure across seams").
    pub field_turn: usize,
    /// How a sample whose features run in rows (brick courses, lines of
    /// text) lays its courses. [`CourseMode::Free`] (the default): each
    /// work patch places the sample where it matches best, its courses
    /// following the field patch by patch; they may step where patches
    /// meet at an angle. [`CourseMode::Locked`]: every work image is bent
    /// so that its rows follow the smoothest stripe pattern along the
    /// field (Knöppel et al. 2015, [`crate::field::StripePattern`]) and
    /// every patch's rows are locked to its phase, so courses run on
    /// across every seam and end only where the pattern ends them (its
    /// `evaluate --forced-ends`). Matching then keeps the field's rotation
    /// (`field_turn` is not used), and the courses' spacing varies with
    /// the pattern's (on Spot ±25 % at the 5th and 95th percentiles;
    /// coherence's 95th percentile +15–43 % with the brick wall). The
    /// courses are found on the original sample, as `evaluate` finds
    /// them. Locked needs a sample with courses and memory for the
    /// pattern's solve (about 140 MiB on Spot, within `memory` less the
    /// rotated copies' quarter).
    pub courses: CourseMode,
    /// Maximum area distortion of a flattened work patch (T_d).
    pub max_distortion: f64,
    pub seed: u64,
    pub memory: MemoryBudget,
    pub level: i32,
    /// The sample's foreground mask m_P (a PNG the sample's size): with it,
    /// tiling keeps the foreground out (m0 = 0 everywhere, §IV).
    pub sample_mask: Option<PathBuf>,
    /// Weight of the constraint: the data term |m_σ(p) − m0(p)| costs this
    /// many sample neighbour differences per texel in the graphcut, and the
    /// matching adds (this × neighbour difference)² · |m0 − m_P|². It must
    /// outweigh the feature difference between the old background and the
    /// foreground that replaces it (on a flat square with a brick sample,
    /// 2 filled 17 % of F, 4 filled 62 %, 8 filled 79 %, 16 at least 95 %).
    pub constraint_weight: f64,
    /// Seam refinement after the surface is covered (the synthesis's `refine` step):
    /// seams whose step exceeds this × the sample's neighbour difference
    /// get one more work patch of radius r_w each; `None` turns it off. The
    /// default 2: on Spot at 1024² with the 192² brick crop it took the seam
    /// ratio from 0.91 to 0.80 (50 refinements kept) in 3 s more.
    pub refine: Option<f64>,
    /// Seam refinement fits this many distinct good placements per seam
    /// (graphcut each, the cheapest cut kept). Default 1, the cheapest
    /// match: on Spot at 1024² with the brick wall, back to back, seam ratio
    /// 0.684 (1 placement), 0.667 (2), 0.658 (4); each extra placement costs
    /// a graphcut per refined seam (there 2-3 s more per placement).
    pub refine_placements: usize,
    /// Seam refinement also looks where a feature ends at a seam (a mortar
    /// line or a strand that one patch, continued one texel across, would
    /// carry on but the other does not show: a continuation differing by
    /// more than [`BROKEN_CONTINUATION`] × the sample's neighbour
    /// difference), whatever the colour step there, and fits this many
    /// placements at such seams: the cut that ends fewest features at the
    /// patch's seams is kept ([`ends`](super::ends), [`ENDS_DEARER`]); 0
    /// turns it off. Default 4 (with [`TileConfig::refine_passes`] 2): on
    /// Spot and Bob at 1024² with the brick wall, the plaster and the wood
    /// (seeds 1 and 2, against 0, occurrence weight 1) broken
    /// continuations fell by 18–38 % and the coherence's 95th percentile
    /// moved by −10 % to +1 %, for 1.9× the time of 0 on Spot with the
    /// wall (10.5 s against 5.4 s; docs/measurements.md, "Refinement where
    /// features end by default").
    pub refine_broken: usize,
    /// Passes of seam refinement where features end: with
    /// [`TileConfig::refine_broken`] ≥ 1, after the first refinement this
    /// many − 1 more passes visit the seams where features still end (the
    /// refinements kept make new seams), stopping early when a pass keeps
    /// no patch; with `refine_broken` 0 there is one pass whatever this
    /// says. Default 2. On Spot at 1024² with the brick wall at the size
    /// of a 4096² close-up and `refine_broken` 4, the second, third and
    /// fourth passes kept 104, 44 and 20 patches (seed 1);
    /// docs/measurements.md, "Structure across seams".
    pub refine_passes: usize,
    /// Work patches per round of the quilting loop (section III-B's loop,
    /// computed a round at a time, [`rounds`](super::rounds)): the most constrained texel
    /// and up to this − 1 more of the most constrained ones whose atlas
    /// tiles the round does not hold yet, computed at once and accepted in
    /// order. 1 is the paper's one patch at a time. It is part of the
    /// recipe, like the seed: the quilt depends on it, never on the thread
    /// count. Default 4: on Spot 4096² from the brick wall, 2 threads, the
    /// quilting loop took 35 s instead of about 70 s, mean seam cost 1.154
    /// either way; 8 took 31 s at 1.179.
    pub round: usize,
    /// The sample's size on the surface: how many mesh units its width
    /// spans. The sample (its geometry maps, rotated copies and mask) is
    /// resampled to the atlas's texel density, so the texture keeps its
    /// size in the world whatever the atlas resolution. `None`: one sample
    /// pixel per atlas texel ([`TileReport::sample_width`] says what width
    /// that is).
    pub sample_width: Option<f64>,
    /// The sample's size on the surface per pixel: mesh units one sample
    /// pixel spans (the width is this times the sample's width in pixels).
    /// At most one of `sample_width` and `sample_pixel`.
    pub sample_pixel: Option<f64>,
    /// Matching goes coarse to fine for samples (after resampling) longer
    /// than this many pixels a side ([`coarse`](super::coarse)): it matches copies
    /// box-averaged to at most this size, then costs the placements around
    /// the best coarse ones exactly. 0 always matches at full resolution.
    /// Default 512: samples up to 512² (the 192² wall and the 128² BTFs at
    /// any atlas size without `--sample-width`) are matched exactly as
    /// before.
    pub coarse_above: usize,
    /// Matching reads only this many leading geometry-map terms of a BTF
    /// sample (plus the structure channel when it is on); the cut cost,
    /// seam refinement and every output keep all of them. The terms are
    /// g_i = σ_i u_i in decreasing σ_i, so the leading ones carry most of
    /// the variation, and the placement search, whose transforms grow with
    /// the terms, costs a fraction. 0 (or at least the sample's terms)
    /// reads every term.
    pub match_terms: usize,
}

/// How the courses of a sample whose features run in rows are laid
/// (`tile --courses`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum CourseMode {
    /// Each patch places its courses where it matches best.
    #[default]
    Free,
    /// Every patch's courses follow one stripe pattern over the surface.
    Locked,
}

impl Default for TileConfig {
    fn default() -> Self {
        TileConfig {
            patch_radius: None,
            min_radius: 4,
            seam_threshold: 3.0,
            tolerance: 0.0,
            occurrence_weight: 0.5,
            structure_weight: 0.0,
            feature_align: 0.09,
            field_turn: 2,
            courses: CourseMode::Free,
            max_distortion: 4.0,
            seed: 1,
            memory: MemoryBudget::default(),
            level: crate::container::DEFAULT_ZSTD_LEVEL,
            sample_mask: None,
            constraint_weight: 16.0,
            refine: Some(2.0),
            refine_placements: REFINE_PLACEMENTS,
            refine_broken: 4,
            refine_passes: 2,
            round: 4,
            sample_width: None,
            sample_pixel: None,
            coarse_above: 512,
            match_terms: 0,
        }
    }
}

/// The sample's size on the surface, as a user gives it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SampleSize {
    /// Mesh units the sample's width spans.
    Width(f64),
    /// Mesh units one sample pixel spans.
    Pixel(f64),
}

impl SampleSize {
    /// The flag and value, as a message names them (`--sample-width 2`).
    pub fn flag(self) -> String {
        match self {
            SampleSize::Width(w) => format!("--sample-width {w}"),
            SampleSize::Pixel(p) => format!("--sample-pixel {p}"),
        }
    }

    /// Mesh units the width of a sample `pixels` wide spans.
    pub fn width_units(self, pixels: usize) -> f64 {
        match self {
            SampleSize::Width(w) => w,
            SampleSize::Pixel(p) => p * pixels as f64,
        }
    }
}

impl TileConfig {
    /// The sample's size on the surface, if one is given.
    pub fn sample_size(&self) -> Option<SampleSize> {
        self.sample_width
            .map(SampleSize::Width)
            .or(self.sample_pixel.map(SampleSize::Pixel))
    }

    /// Checks the numbers a user gives (each must be finite and in range),
    /// naming the command-line flag and the value.
    pub fn validate(&self) -> Result<()> {
        let check = |flag: &str, v: f64, ok: bool, want: &str| {
            if v.is_finite() && ok {
                Ok(())
            } else {
                Err(Error::Config(format!("{flag} {v}: must be {want}")))
            }
        };
        check(
            "--seam-threshold",
            self.seam_threshold,
            self.seam_threshold > 0.0,
            "a finite number > 0 (a mean seam cost in sample neighbour differences)",
        )?;
        check(
            "--occurrence-weight",
            self.occurrence_weight,
            self.occurrence_weight >= 0.0,
            "a finite number ≥ 0 (0 turns the occurrence penalty off)",
        )?;
        check(
            "--tolerance",
            self.tolerance,
            self.tolerance >= 0.0,
            "a finite number ≥ 0 (a share of the best placement's cost)",
        )?;
        check(
            "--structure-weight",
            self.structure_weight,
            self.structure_weight >= 0.0,
            "a finite number ≥ 0 (sample neighbour differences; 0 turns the structure channel off)",
        )?;
        check(
            "--feature-align",
            self.feature_align,
            (0.0..=0.5).contains(&self.feature_align),
            "a number from 0 to 0.5 (a share of the work patch's radius; 0 keeps patches rigid)",
        )?;
        check(
            "--constraint-weight",
            self.constraint_weight,
            self.constraint_weight >= 0.0,
            "a finite number ≥ 0 (sample neighbour differences per texel)",
        )?;
        if let Some(r) = self.refine {
            check(
                "--refine",
                r,
                r > 0.0,
                "a finite number > 0 (a seam step in sample neighbour differences), or 0 for none",
            )?;
        }
        if let Some(w) = self.sample_width {
            check(
                "--sample-width",
                w,
                w > 0.0,
                "a finite number > 0 (mesh units spanned by the sample's width)",
            )?;
        }
        if let Some(p) = self.sample_pixel {
            check(
                "--sample-pixel",
                p,
                p > 0.0,
                "a finite number > 0 (mesh units spanned by one sample pixel)",
            )?;
            if self.sample_width.is_some() {
                return Err(Error::Config(
                    "--sample-width and --sample-pixel both give the sample's size; give one".into(),
                ));
            }
        }
        if self.field_turn > 36 {
            return Err(Error::Config(format!(
                "--field-turn {}: must be 0 to 36 (rotation steps of 5° off the field, at most a half turn)",
                self.field_turn
            )));
        }
        if self.refine_placements == 0 {
            return Err(Error::Config("--refine-placements must be at least 1".into()));
        }
        if self.refine_passes == 0 {
            return Err(Error::Config(
                "--refine-passes 0: must be at least 1 (passes of seam refinement)".into(),
            ));
        }
        if self.round == 0 {
            return Err(Error::Config(
                "--round must be at least 1 (work patches per round)".into(),
            ));
        }
        crate::container::check_level(self.level)
    }
}

/// What [`tile`](super::tile) did.
#[derive(Clone, Debug, Default)]
pub struct TileReport {
    pub patches: usize,
    pub cross_chart_patches: usize,
    /// Accepted cross-chart patches whose work image is the rigid unfolding
    /// (the flattening exceeded T_d).
    pub unfolded_patches: usize,
    pub shrinks: usize,
    /// Seam refinements kept ([`TileConfig::refine`]).
    pub refined: usize,
    pub texels: usize,
    pub mean_seam_cost: f64,
    pub seconds: f64,
    pub matching_seconds: f64,
    pub graphcut_seconds: f64,
    /// Mesh units spanned by the sample's width on the surface.
    pub sample_width: f64,
    /// Sample pixels per atlas texel (1 unless resampled to a
    /// [`TileConfig::sample_width`]).
    pub sample_scale: f64,
    /// The atlas's 64×64 tiles, and how often one was read in (surface and
    /// state tiles counted apart; above twice the tiles when `--memory`
    /// made the loop evict some and read them again).
    pub atlas_tiles: usize,
    pub tiles_read: u64,
    /// Compressed bytes written to the scratch store by evictions.
    pub scratch_bytes: u64,
    /// Work patches (of the loop and of seam refinement) computed in rounds
    /// of several, and how many of them read outside their tiles and were
    /// computed again alone.
    pub concurrent_patches: usize,
    pub recomputed_patches: usize,
    /// Of those, the patches whose views of their tiles were made when a
    /// thread took them, not with the round (more of the round's patches
    /// than `--memory` holds in flight).
    pub late_views: usize,
    /// The factor matching averaged the sample down by before the exact
    /// step ([`TileConfig::coarse_above`]); 1 where it matched at full
    /// resolution.
    pub coarse_factor: usize,
    /// With locked courses ([`CourseMode::Locked`]): the course ends of
    /// the stripe pattern the courses follow, the only places a course
    /// ends.
    pub locked_course_ends: Option<usize>,
}

impl std::fmt::Display for TileReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} texels in {} patches ({} across charts, {} of them unfolded, {} shrinks, {} seams refined), mean seam cost {:.4}, {:.1} s (matching {:.1} s, graphcut {:.1} s)",
            self.texels,
            self.patches,
            self.cross_chart_patches,
            self.unfolded_patches,
            self.shrinks,
            self.refined,
            self.mean_seam_cost,
            self.seconds,
            self.matching_seconds,
            self.graphcut_seconds
        )?;
        write!(
            f,
            "; the sample spans {:.4} mesh units ({:.3} sample pixels per texel){}; {} atlas tiles read {} times, {} evicted to scratch",
            self.sample_width,
            self.sample_scale,
            if self.coarse_factor > 1 {
                format!(", matched coarse to fine at 1/{}", self.coarse_factor)
            } else {
                String::new()
            },
            self.atlas_tiles,
            self.tiles_read,
            crate::container::human_bytes(self.scratch_bytes)
        )?;
        if let Some(ends) = self.locked_course_ends {
            write!(f, "; courses locked to a stripe pattern that ends {ends} of them")?;
        }
        Ok(())
    }
}

/// Refinement fits this many distinct placements per seam by default
/// ([`TileConfig::refine_placements`]).
pub const REFINE_PLACEMENTS: usize = 1;

/// A seam edge breaks a feature when one side's patch, continued one texel
/// across ([`State::continued`](super::state::State::continued)), differs from what the other side
/// shows by more than this × the sample's mean neighbour difference
/// ([`TileConfig::refine_broken`]). On the brick wall (linear RGB) mortar
/// against brick is about 13×, and half of its neighbour differences are
/// under 0.11×, 95 % under 6.5×.
pub const BROKEN_CONTINUATION: f64 = 4.0;

/// Seam refinement where features end ([`TileConfig::refine_broken`])
/// keeps a patch that ends fewer features than the seams it replaces if
/// its cut costs less than this × what they cost (any patch is kept whose
/// cut costs under 0.9× as much and ends no more features). 1: never a
/// stronger colour seam. On eleven 400² flat-square quilts (seeds 1–3,
/// `benches/quality_2d.py`) the coherence's 95th percentile (geometric
/// mean) was 0.0337 at 1, 0.0348 at 1.25 and 0.0355 at 1.5, against
/// 0.0340 without refinement where features end; on Spot and Bob at 1024²
/// with the wall, the plaster and the wood, 1.5 left 6–27 % fewer broken
/// continuations than 1 (docs/measurements.md, "Refinement where features
/// end by default").
pub const ENDS_DEARER: f64 = 1.0;
