//! Placement (section III-B, step 4): the candidate translations and
//! rotations from FFT matching, and the seeded choice among near-minimal ones.

use super::coarse::{self, Coarse};
use super::config::TileConfig;
use super::flatten::{rotation_index, WorkImage};
use super::matching;
use super::matching::{Image, MatchConfig, Matcher};
use super::occurrence::{Costs, Occurrence};
use super::sample::{Sample, WholeCopy};
use crate::math;
use crate::Result;
use std::sync::atomic::{AtomicU64, Ordering};

/// Placements tried by a refinement are at least this many pixels apart.
pub(super) const REFINE_SPACING: i32 = 4;

/// The matches of the work image against the sample at the work image's
/// rotation whose placement puts the seed and 95 % of the work image on
/// the sample.
pub(super) fn covering_candidates(
    sample: &Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    cfg: &TileConfig,
    reference: f64,
    occurrence: Option<&mut Occurrence>,
) -> Result<(usize, Vec<matching::Placement>)> {
    let weight = (cfg.constraint_weight * reference).powi(2);
    let penalty = occurrence.map(|o| (o, cfg.occurrence_weight * reference * reference));
    let (rotation, candidates) = match_candidates(sample, matcher, work, weight, penalty, cfg)?;
    let turn = Turn::new(sample, rotation);
    let covering = candidates
        .into_iter()
        .filter(|p| {
            let (dx, dy) = (p.dx as f64, p.dy as f64);
            if !inside_sample(sample, turn.to_sample(dx, dy, work.coords[0])) {
                return false;
            }
            let (on, probed) = probes_on_sample(sample, turn, dx, dy, &work.coords);
            on as f64 >= 0.95 * probed as f64
        })
        .collect();
    Ok((rotation, covering))
}

/// Up to `count` placements of finite cost, cheapest first, each at least
/// `spacing` pixels (Chebyshev) from those already picked; ties in cost keep
/// the order given, so the pick is deterministic.
pub(super) fn distinct_best(
    placements: &[matching::Placement],
    count: usize,
    spacing: i32,
) -> Vec<matching::Placement> {
    let mut order: Vec<&matching::Placement> = placements.iter().filter(|p| p.cost.is_finite()).collect();
    order.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut picks: Vec<matching::Placement> = Vec::with_capacity(count);
    for p in order {
        if picks.len() == count {
            break;
        }
        if picks
            .iter()
            .all(|q| (q.dx - p.dx).abs().max((q.dy - p.dy).abs()) >= spacing)
        {
            picks.push(*p);
        }
    }
    picks
}

/// A placement of the rotated sample over the work image.
pub(super) struct PlacementChoice {
    pub(super) rotation: usize,
    pub(super) dx: f64,
    pub(super) dy: f64,
}

/// One rotated copy's map between work-image coordinates and unrotated
/// sample coordinates, its rotation's sine and cosine taken once.
#[derive(Clone, Copy)]
pub(super) struct Turn {
    /// sin θ and cos θ of the copy's rotation θ.
    pub(super) s: f64,
    pub(super) c: f64,
    /// The sample's centre, which the copies turn about.
    cen: [f64; 2],
}

impl Turn {
    pub(super) fn new(sample: &Sample, rotation: usize) -> Turn {
        let theta = rotation as f64 * std::f64::consts::TAU / sample.rotations as f64;
        let (s, c) = math::sin_cos(theta);
        let cen = [
            (sample.width as f64 - 1.0) / 2.0,
            (sample.height as f64 - 1.0) / 2.0,
        ];
        Turn { s, c, cen }
    }

    /// Work coordinate `w` through placement (`dx`, `dy`) of this copy, in
    /// unrotated sample coordinates (the inverse of the rotated copy's
    /// construction).
    #[inline]
    pub(super) fn to_sample(self, dx: f64, dy: f64, w: [f64; 2]) -> [f64; 2] {
        let (s, c, cen) = (self.s, self.c, self.cen);
        let q = [w[0] - dx - cen[0], w[1] - dy - cen[1]];
        [c * q[0] + s * q[1] + cen[0], -s * q[0] + c * q[1] + cen[1]]
    }

    /// The placement (dx, dy) that puts work coordinate `w` on unrotated
    /// sample point `at` (the inverse of [`Turn::to_sample`]).
    pub(super) fn placing(self, w: [f64; 2], at: [f64; 2]) -> [f64; 2] {
        let (s, c, mid) = (self.s, self.c, self.cen);
        let d = [at[0] - mid[0], at[1] - mid[1]];
        // q = R(θ) d
        let q = [c * d[0] - s * d[1], s * d[0] + c * d[1]];
        [w[0] - mid[0] - q[0], w[1] - mid[1] - q[1]]
    }
}

/// Locked courses: `placement` moved across the sample's rows so that the
/// sample row at the seed shows the course phase the work image asks there
/// ([`WorkImage::course_phase`]): by under half a course, or a course more
/// either way where that keeps more of the patch on the sample; the rows
/// of the other vertices are then within the spacing of the sample's
/// courses of theirs ([`super::courses::Courses::lock_rows`] puts them
/// exactly). `None` when the work image is free or the sample has no
/// courses.
pub(super) fn lock_courses(
    sample: &Sample,
    work: &WorkImage,
    placement: &PlacementChoice,
) -> Option<PlacementChoice> {
    let target = *work.course_phase.first()?;
    let courses = sample.courses.as_ref()?;
    let turn = Turn::new(sample, placement.rotation);
    let row = turn.to_sample(placement.dx, placement.dy, work.coords[0])[1];
    // moving the placement by δ (−sin θ, cos θ) moves every row by −δ;
    // of the shifts by under half a course and a course either way, the
    // one that keeps most of the patch on the sample, the smallest of equals
    let period = courses.period();
    let least = crate::field::wrap_angle(courses.phase(row) - target) * period / std::f64::consts::TAU;
    let shifted = |delta: f64| (placement.dx - turn.s * delta, placement.dy + turn.c * delta);
    let on_sample = |delta: f64| {
        let (dx, dy) = shifted(delta);
        probes_on_sample(sample, turn, dx, dy, &work.coords).0
    };
    let mut best = (on_sample(least), least);
    for delta in [least - period, least + period] {
        let n = on_sample(delta);
        if n > best.0 || (n == best.0 && delta.abs() < best.1.abs()) {
            best = (n, delta);
        }
    }
    let (dx, dy) = shifted(best.1);
    Some(PlacementChoice {
        rotation: placement.rotation,
        dx,
        dy,
    })
}

/// Where `placement` puts the work-image vertices `coords` on the sample
/// (unrotated sample coordinates), each row then moved to its course phase
/// where the work image has one (`course_phase`: locked courses,
/// [`super::courses::Courses::lock_rows`]).
pub(super) fn placed_on_sample(
    sample: &Sample,
    placement: &PlacementChoice,
    coords: &[[f64; 2]],
    course_phase: &[f64],
) -> Vec<[f64; 2]> {
    let turn = Turn::new(sample, placement.rotation);
    let mut placed: Vec<[f64; 2]> = coords
        .iter()
        .map(|&w| turn.to_sample(placement.dx, placement.dy, w))
        .collect();
    if let (false, Some(courses)) = (course_phase.is_empty(), &sample.courses) {
        courses.lock_rows(&mut placed, course_phase);
    }
    placed
}

/// The stride of the work-image vertices probed when judging how much of
/// a patch a placement puts on the sample: every 1/400th.
fn probe_step(coords: &[[f64; 2]]) -> usize {
    (coords.len() / 400).max(1)
}

/// How many of the probed vertices of `coords` (every [`probe_step`]th)
/// placement (`dx`, `dy`) of `turn`'s copy puts on the sample, and how
/// many were probed.
fn probes_on_sample(sample: &Sample, turn: Turn, dx: f64, dy: f64, coords: &[[f64; 2]]) -> (usize, usize) {
    let probed = coords.iter().step_by(probe_step(coords));
    let count = probed.len();
    let on = probed
        .filter(|&&w| inside_sample(sample, turn.to_sample(dx, dy, w)))
        .count();
    (on, count)
}

pub(super) fn inside_sample(sample: &Sample, c: [f64; 2]) -> bool {
    sample.tileable
        || (c[0] >= 0.0
            && c[1] >= 0.0
            && c[0] <= sample.width as f64 - 1.0
            && c[1] <= sample.height as f64 - 1.0)
}

/// Places the sample over the work image (Kwatra et al.: the new patch must
/// cover the work patch): among the best matches, those that put the seed
/// and at least 95 % of the patch's vertices on the sample; a seeded choice
/// among the near-minimal ones; the sample centred on the seed if none does.
pub(super) fn place_covering(
    sample: &Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    cfg: &TileConfig,
    reference: f64,
    occurrence: Option<&mut Occurrence>,
    counter: u64,
) -> Result<PlacementChoice> {
    let (rotation, covering) = covering_candidates(sample, matcher, work, cfg, reference, occurrence)?;
    Ok(choose_placement(sample, work, cfg, counter, rotation, &covering))
}

/// A seeded choice among the near-minimal `covering` matches
/// ([`matching::choose`]), or, when there is none, a seeded spot on the
/// sample (one that best agrees with the constraint when the work image has
/// one).
pub(super) fn choose_placement(
    sample: &Sample,
    work: &WorkImage,
    cfg: &TileConfig,
    counter: u64,
    rotation: usize,
    covering: &[matching::Placement],
) -> PlacementChoice {
    let step = probe_step(&work.coords);
    if let Some(p) = matching::choose(covering, cfg.tolerance, cfg.seed, counter) {
        return PlacementChoice {
            rotation,
            dx: p.dx as f64,
            dy: p.dy as f64,
        };
    }
    // nothing known yet, or no match covers the patch: a seeded spot that
    // covers the seed's neighbourhood (the sample centre ± a margin)
    let (sw, sh) = (sample.width as f64, sample.height as f64);
    let turn = Turn::new(sample, rotation);
    let mid = [(sw - 1.0) / 2.0, (sh - 1.0) / 2.0];
    // the seed at unrotated sample point `cen`
    let place = |cen: [f64; 2]| {
        let [dx, dy] = turn.placing(work.coords[0], cen);
        PlacementChoice {
            rotation,
            dx: dx.round(),
            dy: dy.round(),
        }
    };
    let h = crate::rng::mix64(cfg.seed ^ crate::rng::mix64(counter + 1));
    let jitter = |bits: u64, span: f64| ((bits & 0xffff) as f64 / 65535.0 - 0.5) * span;
    if !work.constraint.is_empty() && sample.mask.is_some() {
        // constrained: among seeded spots anywhere on the sample, the one
        // whose foreground best agrees with m0 over the patch (outside the
        // sample counts as a full mismatch), the first of equals
        let probe: Vec<usize> = (0..work.coords.len()).step_by(step).collect();
        let mut best = (f64::INFINITY, place([mid[0], mid[1]]));
        for k in 0..64u64 {
            let b = crate::rng::mix64(h ^ crate::rng::mix64(k + 1));
            let choice = place([mid[0] + jitter(b, 0.9 * sw), mid[1] + jitter(b >> 16, 0.9 * sh)]);
            let cost: f64 = probe
                .iter()
                .map(|&i| {
                    let w = work.coords[i];
                    let m0 = work.constraint[(w[1].round() as usize).min(work.height - 1) * work.width
                        + (w[0].round() as usize).min(work.width - 1)];
                    let cs = turn.to_sample(choice.dx, choice.dy, w);
                    if inside_sample(sample, cs) {
                        (sample.mask_at(cs) - m0).abs() as f64
                    } else {
                        1.0
                    }
                })
                .sum();
            if cost < best.0 {
                best = (cost, choice);
            }
        }
        return best.1;
    }
    let margin = 0.25;
    place([
        (sw - 1.0) / 2.0 + jitter(h, margin * sw),
        (sh - 1.0) / 2.0 + jitter(h >> 16, margin * sh),
    ])
}

/// The rotation for the work image's field direction and the best matches
/// of that rotated copy (up to 64, cheapest first); jointly on features and
/// on the constraint (m0 against the rotated foreground mask, weighted by
/// `constraint_weight`) when the work image carries one (§IV); with
/// `penalty` (an occurrence map and its weight), plus the occurrence
/// penalty of each placement ([`Occurrence::penalize`]). Where the field
/// turns inside the patch ([`WorkImage::field_spread`]), the copy may turn
/// up to `field_turn` steps from the field's ([`choose_rotation`]): a patch
/// then follows its neighbours' courses rather than the field's mean
/// direction. Large samples are matched coarse to fine
/// ([`super::coarse`], `cfg.coarse_above`).
pub(super) fn match_candidates(
    sample: &Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    constraint_weight: f64,
    mut penalty: Option<(&mut Occurrence, f64)>,
    cfg: &TileConfig,
) -> Result<(usize, Vec<matching::Placement>)> {
    // locked courses keep the copy at the rows' direction (the work image's angle)
    let field_turn = if work.course_phase.is_empty() {
        cfg.field_turn
    } else {
        0
    };
    let f = coarse::factor(sample.width.max(sample.height), cfg.coarse_above);
    let rotations = sample.rotations;
    let rot = rotation_index(work.angle, rotations);
    let known_count: f64 = work.known.iter().map(|&k| k as f64).sum();
    if known_count == 0.0 {
        return Ok((rot, Vec::new()));
    }
    let r = match turn_limit(work, field_turn) {
        0 => rot,
        limit => choose_rotation(sample, matcher, work, penalty.as_mut(), rot, limit, f)?,
    };
    let p = penalty.as_mut().map(|(o, w)| (&mut **o, *w));
    let c = match_at_rotation(sample, matcher, work, constraint_weight, p, r, known_count, f)?;
    Ok((r, c))
}

/// How many rotation steps matching may turn the sample away from the
/// field's: `field_turn` where the field turns inside the patch at all, 0
/// where it is constant (a flat square keeps the field's copy).
fn turn_limit(work: &WorkImage, field_turn: usize) -> i64 {
    if work.field_spread > 0.0 {
        field_turn as i64
    } else {
        0
    }
}

/// Rotations are ranked on a match this many times coarser than the
/// placement's own ([`choose_rotation`]).
const RANK_FACTOR: usize = 4;

/// The rotated copy a work patch is matched with, within `limit` steps of
/// the field's copy `rot`: a climb over the copies, from the one nearest
/// the direction the sample already has around the patch
/// ([`WorkImage::neighbour_angle`]; the field's where nothing is known) to
/// a neighbouring step while that costs less. Each copy is ranked by its
/// best placement matched [`RANK_FACTOR`] × coarser (block means,
/// [`Coarse`]) with the occurrence penalty; only the chosen copy is then
/// matched in full. Following the neighbours' courses where the field
/// turns keeps structure continuous across seams (a course turned by one
/// 5° step drifts by a course height over a few course lengths).
fn choose_rotation(
    sample: &Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    mut penalty: Option<&mut (&mut Occurrence, f64)>,
    rot: usize,
    limit: i64,
    f: usize,
) -> Result<usize> {
    let rotations = sample.rotations as i64;
    // signed steps from the field's copy
    let offset = |r: usize| {
        let d = (r as i64 - rot as i64).rem_euclid(rotations);
        if d > rotations / 2 {
            d - rotations
        } else {
            d
        }
    };
    let start = work.neighbour_angle.map_or(0, |a| {
        offset(rotation_index(a, sample.rotations)).clamp(-limit, limit)
    });
    let fr = RANK_FACTOR * f;
    let n = sample.match_channels();
    let features = sample.match_features(&work.features);
    let image = Image {
        width: work.width,
        height: work.height,
        channels: n,
        data: &features,
    };
    let cwork = Coarse::new(&image, &work.known, &[], 1, fr);
    let known: f64 = cwork.weight.iter().map(|&k| k as f64).sum();
    let mc = MatchConfig {
        min_overlap: (0.5 * known).max(1.0),
        candidates: 1,
        tolerance: f64::INFINITY,
        ..MatchConfig::default()
    };
    // every copy is matched against the same coarse work image: its
    // spectra are computed once
    static WORK_KEYS: AtomicU64 = AtomicU64::new(0);
    let work_key = WORK_KEYS.fetch_add(1, Ordering::Relaxed);
    let (cw, ch) = (sample.width.div_ceil(fr), sample.height.div_ceil(fr));
    let mut rank = |d: i64| -> Result<f64> {
        let r = (rot as i64 + d).rem_euclid(rotations) as usize;
        let copy = sample.coarse_rotation(r, fr)?;
        let coarse_work = matching::Work {
            image: cwork.image(n),
            known: &cwork.weight,
            constraint: None,
        };
        let coarse_sample = matching::Sample {
            image: Image {
                width: cw,
                height: ch,
                channels: n,
                data: &copy.0,
            },
            valid: &copy.1,
            constraint: None,
            key: r as u64 | (fr as u64) << 40,
        };
        let mut map = matcher.cost_map_for(&coarse_work, Some(work_key), &coarse_sample, &mc)?;
        penalize(
            penalty.as_deref_mut(),
            sample,
            work,
            Costs::Map(&mut map),
            r,
            fr as i32,
        );
        Ok(map
            .cost
            .iter()
            .copied()
            .filter(|c| c.is_finite())
            .fold(f64::INFINITY, f64::min))
    };
    let (mut best, mut cost) = (start, rank(start)?);
    let mut dir = 0;
    for d in [-1, 1] {
        if (start + d).abs() <= limit {
            let c = rank(start + d)?;
            if c < cost {
                (best, cost, dir) = (start + d, c, d);
            }
        }
    }
    while dir != 0 && (best + dir).abs() <= limit {
        let c = rank(best + dir)?;
        if c >= cost {
            break;
        }
        (best, cost) = (best + dir, c);
    }
    Ok((rot as i64 + best).rem_euclid(rotations) as usize)
}

/// Adds the occurrence penalty (an occurrence map and its weight) to the
/// costs of `map`, placements of rotated copy `rot` over `work` matched at
/// `step` work pixels per cost-map step ([`Occurrence::penalize`]).
fn penalize(
    penalty: Option<&mut (&mut Occurrence, f64)>,
    sample: &Sample,
    work: &WorkImage,
    costs: Costs,
    rot: usize,
    step: i32,
) {
    if let Some((occurrence, weight)) = penalty {
        let turn = Turn::new(sample, rot);
        let to_unrotated = |p: [f64; 2]| turn.to_sample(0.0, 0.0, p);
        occurrence.penalize(costs, rot, to_unrotated, [work.width, work.height], *weight, step);
    }
}

/// The best placements (up to 64, cheapest first) of rotated copy `rot`
/// over the work image, matched at full resolution (`f` = 1) or coarse to
/// fine at factor `f`, with the occurrence penalty when given.
#[allow(clippy::too_many_arguments)]
fn match_at_rotation(
    sample: &Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    constraint_weight: f64,
    mut penalty: Option<(&mut Occurrence, f64)>,
    rot: usize,
    known_count: f64,
    f: usize,
) -> Result<Vec<matching::Placement>> {
    let (sw, sh, n) = (sample.width, sample.height, sample.match_channels());
    let constrained = !work.constraint.is_empty() && sample.mask.is_some();
    let mask = if constrained {
        sample.rotation_mask(rot)
    } else {
        None
    };
    let mask = mask.as_deref().map(|m| &m.0[..]);
    let mc = MatchConfig {
        min_overlap: (0.5 * known_count).max(1.0),
        candidates: 64,
        tolerance: f64::INFINITY,
        constraint_weight,
        ..MatchConfig::default()
    };
    let features = sample.match_features(&work.features);
    let work_image = Image {
        width: work.width,
        height: work.height,
        channels: n,
        data: &features,
    };
    let key = rot as u64 | (constrained as u64) << 32;
    if f == 1 && mask.is_none() {
        // a full match: the f32 copy, or the f16 one when memory has no
        // room for the f32 (the same costs)
        let work_in = matching::Work {
            image: work_image,
            known: &work.known,
            constraint: None,
        };
        let whole = sample.rotation_to_match(rot)?;
        let (data, valid): (&[f32], &[f32]) = match &whole {
            WholeCopy::F32(copy) => (&copy.0, &copy.1),
            WholeCopy::F16(_, valid) => (&[], valid),
        };
        let sample_in = matching::Sample {
            image: Image {
                width: sw,
                height: sh,
                channels: n,
                data,
            },
            valid,
            constraint: None,
            key,
        };
        let mut map = match &whole {
            WholeCopy::F32(_) => matcher.cost_map(&work_in, &sample_in, &mc)?,
            WholeCopy::F16(values, _) => matcher.cost_map_half(&work_in, None, &sample_in, values, &mc)?,
        };
        self::penalize(penalty.as_mut(), sample, work, Costs::Map(&mut map), rot, 1);
        return Ok(map.best(mc.candidates, mc.tolerance));
    }
    // the whole copy for a full match with the foreground mask, or for the
    // coarse mask (painting); coarse to fine reads the rectangles it costs
    let copy = if f == 1 || mask.is_some() {
        Some(sample.rotation(rot)?)
    } else {
        None
    };
    let work_in = matching::Work {
        image: work_image,
        known: &work.known,
        constraint: mask.map(|_| Image {
            width: work.width,
            height: work.height,
            channels: 1,
            data: &work.constraint,
        }),
    };
    let sample_in = copy.as_deref().map(|(maps, valid)| matching::Sample {
        image: Image {
            width: sw,
            height: sh,
            channels: n,
            data: maps,
        },
        valid,
        constraint: mask.map(|m| Image {
            width: sw,
            height: sh,
            channels: 1,
            data: m,
        }),
        key,
    });
    if f == 1 {
        let sample_in = sample_in.expect("the whole copy for a full match");
        let mut map = matcher.cost_map(&work_in, &sample_in, &mc)?;
        self::penalize(penalty.as_mut(), sample, work, Costs::Map(&mut map), rot, 1);
        return Ok(map.best(mc.candidates, mc.tolerance));
    }
    let ccopy = sample.coarse_rotation(rot, f)?;
    // (the features of the copy are block-averaged once, in the sample)
    let cmask = sample_in.as_ref().zip(mask).map(|(s, m)| {
        let no_features = Image {
            channels: 0,
            data: &[],
            ..s.image
        };
        Coarse::new(&no_features, s.valid, m, 1, f).constraint
    });
    let work_constraint: &[f32] = if mask.is_some() { &work.constraint } else { &[] };
    let cwork = Coarse::new(&work_in.image, &work.known, work_constraint, 1, f);
    let (cw, ch) = (sw.div_ceil(f), sh.div_ceil(f));
    let coarse_work = matching::Work {
        image: cwork.image(n),
        known: &cwork.weight,
        constraint: cwork.constraint_image(1),
    };
    let coarse_sample = matching::Sample {
        image: Image {
            width: cw,
            height: ch,
            channels: n,
            data: &ccopy.0,
        },
        valid: &ccopy.1,
        constraint: cmask.as_deref().map(|m| Image {
            width: cw,
            height: ch,
            channels: 1,
            data: m,
        }),
        key: key | (f as u64) << 40,
    };
    let from_copy = sample_in.as_ref().map(coarse::cut);
    let from_svd = |rect| {
        let (maps, valid) = sample.rotation_rect(rot, rect)?;
        Ok(coarse::Window {
            maps,
            valid,
            constraint: Vec::new(),
        })
    };
    let fine = coarse::Fine {
        width: sw,
        height: sh,
        channels: n,
        constraint_channels: mask.map_or(0, |_| 1),
        // (validity is 0 or 1: 1 if any coarse pixel has some)
        max_valid: if ccopy.1.iter().any(|&v| v > 0.0) {
            1.0
        } else {
            0.0
        },
        read: match &from_copy {
            Some(cut) => cut,
            None => &from_svd,
        },
    };
    let mut penalize = |map: &mut matching::CostMap, step: i32| {
        self::penalize(penalty.as_mut(), sample, work, Costs::Map(map), rot, step);
    };
    let mut placements = coarse::match_coarse_to_fine(
        matcher,
        &work_in,
        &fine,
        &coarse_work,
        &coarse_sample,
        &mc,
        f,
        &mut penalize,
    )?;
    self::penalize(
        penalty.as_mut(),
        sample,
        work,
        Costs::List(&mut placements),
        rot,
        1,
    );
    Ok(matching::best_of(placements, mc.candidates, mc.tolerance))
}

#[cfg(test)]
mod tests;
