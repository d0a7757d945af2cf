//! `tile`: graphcut quilting on the dense mesh (Zhou et al., section III-B;
//! Kwatra et al. 2003), for colour samples and BTFs alike (both enter as a
//! `.svd`: patch costs use the n-term geometry-map vectors).
//!
//! The loop (the paper's Fig. 4):
//! 1. pick the most constrained unsynthesized dense vertex v (most
//!    synthesized neighbours; the first one from the seed);
//! 2. work patch P(v): breadth-first traversal of M_d from v to depth r_w;
//! 3. work image I(v): inside one chart, the chart's sub-image (no
//!    resampling); across charts, P(v) flattened — the charts' own LSCM
//!    layouts aligned over the zipper links and their seams closed by a
//!    membrane (area distortion ≤ T_d, else the rigid field-based
//!    unfolding) — and resampled at one texel per pixel, a pixel known where
//!    its triangle's three vertices are synthesized;
//! 4. entire-patch matching of the sample rotated to the work image's mean
//!    field direction (one of the 72 rotated copies) by FFT; a seeded choice
//!    among near-minimal placements;
//! 5. patch fitting: a graphcut over P(v)'s vertices between the old values A
//!    and the new B, edge weight ‖A(s)−B(s)‖ + ‖A(t)−B(t)‖, with a seam node on
//!    every old seam so later patches can remove earlier seams;
//! 6. accept if the mean seam cost is below T_c (relative to the sample's own
//!    neighbour differences), else shrink r_w by 0.8 and retry, down to 4;
//! 7. record for each vertex taken: sample coordinate, rotation, patch id.
//!
//! State is struct-of-arrays over atlas texels. The loop is sequential, so the
//! result depends only on the inputs and the seed.

use std::path::Path;
use std::time::Instant;

use crate::artifact::gim::Gim;
use crate::container::MemoryBudget;
use crate::progress::Progress;
use crate::{Error, Result};

mod align;
mod coarse;
mod config;
pub mod courses;
mod ends;
mod fit;
mod flatten;
pub mod matching;
pub mod maxflow;
mod occurrence;
mod pager;
mod placement;
mod rounds;
mod sample;
mod state;
mod streamed;
mod structure;
mod synthesis;
mod worker;

pub use crate::artifact::quilt::{
    Dependency, Quilt, KIND, MAX_SAMPLES, NO_PATCH, SEAM_X, SEAM_Y, SEAM_ZIPPER,
};
pub use config::{
    CourseMode, SampleSize, TileConfig, TileReport, BROKEN_CONTINUATION, ENDS_DEARER, REFINE_PLACEMENTS,
};
pub(crate) use sample::*;
use synthesis::write_quilt;
pub use synthesis::Projection;
pub(crate) use synthesis::*;

/// Decorates the geometry image `gim_path` with the sample (`.svd`, or a
/// colour image factorized on the fly) into the `.quilt` artifact `out`.
/// With `cfg.sample_mask` (the sample's foreground mask), the constrained
/// graphcut keeps the foreground out of the background (m0 = 0 everywhere).
pub fn tile(
    gim_path: &Path,
    sample_path: &Path,
    out: &Path,
    cfg: &TileConfig,
    progress: &dyn Progress,
) -> Result<TileReport> {
    tile_refining_by(gim_path, sample_path, out, cfg, synthesis::REFINE_ROUND, progress)
}

/// [`tile`], seam refinement taking up to `refine_round` patches per round
/// (the quilt is the same for any).
pub(crate) fn tile_refining_by(
    gim_path: &Path,
    sample_path: &Path,
    out: &Path,
    cfg: &TileConfig,
    refine_round: usize,
    progress: &dyn Progress,
) -> Result<TileReport> {
    let start = Instant::now();
    cfg.validate()?;
    let mut inputs = vec![("the geometry image", gim_path), ("the sample", sample_path)];
    if let Some(mask) = &cfg.sample_mask {
        inputs.push(("the sample's foreground mask", mask.as_path()));
    }
    crate::io::staging::check_output(out, &inputs)?;
    // (the surface is read by tiles through a reader of its own)
    let gim = Gim::open(gim_path, MemoryBudget(1 << 20))?;
    let sized = sample_at_density(
        sample_path,
        gim.texel_size,
        cfg.sample_size(),
        true,
        cfg.memory,
        progress,
    )?;
    let mut syn = Synthesis::open(&gim, sample_path, &sized, out, cfg, true, None)?;
    syn.refine_round = refine_round;
    syn.set_scale(&sized);
    syn.set_structure(cfg.structure_weight);
    if let Some(mask) = &cfg.sample_mask {
        syn.set_mask(mask)?;
        syn.constrain_to_background();
    }
    syn.report.coarse_factor = coarse::factor(syn.sample.width.max(syn.sample.height), cfg.coarse_above);
    let radius0 = syn.radius0();
    progress.begin("tile", syn.state.remaining as u64);
    // the first vertex: a seeded choice among all dense vertices
    let first = {
        let vertices = syn.surface.vertices();
        if vertices == 0 {
            return Err(Error::input(gim_path, "has no dense vertices"));
        }
        syn.surface
            .nth_vertex((crate::rng::mix64(cfg.seed) % vertices as u64) as usize)
    };
    syn.synthesize(first, radius0, progress)?;
    progress.end();
    if let Some(step) = cfg.refine {
        syn.refine(radius0.max(cfg.min_radius), step, cfg.refine_broken, progress)?;
        // more passes over the seams where features still end (a kept
        // refinement makes new seams), until one keeps nothing
        if cfg.refine_broken > 0 {
            for _ in 1..cfg.refine_passes {
                if syn.refine(
                    radius0.max(cfg.min_radius),
                    f64::INFINITY,
                    cfg.refine_broken,
                    progress,
                )? == 0
                {
                    break;
                }
            }
        }
    }
    syn.finish_report(start);
    let report = syn.report.clone();
    write_quilt(out, cfg, &gim, gim_path, &syn, None, &report)?;
    Ok(report)
}
