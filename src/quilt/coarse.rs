//! Coarse-to-fine matching for large samples. Entire-patch matching
//! ([`super::matching`]) transforms images the sample's size: a sample
//! resampled to 768² or more costs FFT buffers of 50–120 MB per work patch
//! and most of the matching time. Above [`TileConfig::coarse_above`]
//! pixels a side, the work image and the rotated sample are box-averaged by
//! a factor f (weighted by the known and validity weights), matched whole at
//! that scale, and the best coarse placements are then costed exactly, at
//! full resolution, in a window of ±(f − 1) pixels around each
//! ([`matching::direct_costs`]). The result has the form of a full match: a
//! cost map whose finite entries are exact full-resolution costs.
//!
//! [`TileConfig::coarse_above`]: super::TileConfig::coarse_above

use super::matching::{self, CostMap, Image, MatchConfig, Matcher};

/// Coarse placements refined at full resolution.
const COARSE_CANDIDATES: usize = 16;

/// The downsampling factor for a sample `side` pixels long with the limit
/// `above` (1: match at full resolution; `above` 0 never downsamples).
pub(super) fn factor(side: usize, above: usize) -> usize {
    if above == 0 || side <= above {
        1
    } else {
        side.div_ceil(above)
    }
}

/// A box-averaged image: per coarse pixel the weight-averaged features and
/// constraint, and the mean weight.
pub(super) struct Coarse {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) features: Vec<f32>,
    pub(super) weight: Vec<f32>,
    pub(super) constraint: Vec<f32>,
}

impl Coarse {
    /// Averages f×f blocks of a `width × height` image of `channels`
    /// features (`[y][x][c]`), with per-pixel `weight` and optional
    /// constraint channels (`constraint_channels` per pixel, or empty).
    pub(super) fn new(
        image: &Image,
        weight: &[f32],
        constraint: &[f32],
        constraint_channels: usize,
        f: usize,
    ) -> Coarse {
        let (w, h, n, k) = (image.width, image.height, image.channels, constraint_channels);
        let (cw, ch) = (w.div_ceil(f), h.div_ceil(f));
        let mut features = vec![0f32; cw * ch * n];
        let mut out_weight = vec![0f32; cw * ch];
        let mut out_constraint = vec![0f32; if constraint.is_empty() { 0 } else { cw * ch * k }];
        let mut sum = vec![0f64; n + k];
        for cy in 0..ch {
            for cx in 0..cw {
                sum.fill(0.0);
                let mut mass = 0.0f64;
                for y in cy * f..((cy + 1) * f).min(h) {
                    for x in cx * f..((cx + 1) * f).min(w) {
                        let p = y * w + x;
                        let m = weight[p] as f64;
                        if m == 0.0 {
                            continue;
                        }
                        mass += m;
                        for (c, s) in sum[..n].iter_mut().enumerate() {
                            *s += m * image.data[p * n + c] as f64;
                        }
                        if !constraint.is_empty() {
                            for (c, s) in sum[n..].iter_mut().enumerate() {
                                *s += m * constraint[p * k + c] as f64;
                            }
                        }
                    }
                }
                let q = cy * cw + cx;
                out_weight[q] = (mass / (f * f) as f64) as f32;
                if mass > 0.0 {
                    for c in 0..n {
                        features[q * n + c] = (sum[c] / mass) as f32;
                    }
                    if !constraint.is_empty() {
                        for c in 0..k {
                            out_constraint[q * k + c] = (sum[n + c] / mass) as f32;
                        }
                    }
                }
            }
        }
        Coarse {
            width: cw,
            height: ch,
            features,
            weight: out_weight,
            constraint: out_constraint,
        }
    }

    /// Borrows the features as an [`Image`].
    pub(super) fn image(&self, channels: usize) -> Image<'_> {
        Image {
            width: self.width,
            height: self.height,
            channels,
            data: &self.features,
        }
    }

    /// Borrows the constraint channels as an [`Image`], if there are any.
    pub(super) fn constraint_image(&self, channels: usize) -> Option<Image<'_>> {
        (!self.constraint.is_empty()).then(|| Image {
            width: self.width,
            height: self.height,
            channels,
            data: &self.constraint,
        })
    }
}

/// The coarse matching's config: the same options with the minimum
/// overlap scaled to coarse pixels (weights are block means, so an overlap
/// of A full pixels is about A / f² coarse ones) and `candidates` kept.
fn coarse_config(cfg: &MatchConfig, f: usize) -> MatchConfig {
    MatchConfig {
        min_overlap: (cfg.min_overlap / (f * f) as f64).max(f64::MIN_POSITIVE),
        candidates: COARSE_CANDIDATES,
        tolerance: f64::INFINITY,
        ..*cfg
    }
}

/// The full-resolution placements to cost around the best `coarse` ones
/// (coarse placement c ↦ f·c, then ±(f − 1) a side), inside `range` (the
/// full match's placements), each once: a cluster per coarse placement,
/// without those of an earlier one, each in (dy, dx) order.
fn fine_windows(coarse: &[matching::Placement], f: usize, range: [(i32, i32); 2]) -> Vec<Vec<(i32, i32)>> {
    let r = f as i32 - 1;
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for p in coarse {
        let (cx, cy) = (p.dx * f as i32, p.dy * f as i32);
        let mut cluster = Vec::new();
        for dy in (cy - r).max(range[1].0)..=(cy + r).min(range[1].1) {
            for dx in (cx - r).max(range[0].0)..=(cx + r).min(range[0].1) {
                if seen.insert((dx, dy)) {
                    cluster.push((dx, dy));
                }
            }
        }
        if !cluster.is_empty() {
            out.push(cluster);
        }
    }
    out
}

/// A rectangle of the full-resolution sample: maps, validity and
/// constraint channels (empty without), `[y][x]…` over the rectangle.
pub(super) struct Window {
    pub(super) maps: Vec<f32>,
    pub(super) valid: Vec<f32>,
    pub(super) constraint: Vec<f32>,
}

/// The full-resolution sample of the exact step, read by rectangles
/// `(x, y, w, h)`: a large rotated copy is never needed whole.
pub(super) struct Fine<'a> {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) channels: usize,
    /// Constraint channels per pixel (0: none).
    pub(super) constraint_channels: usize,
    /// The whole sample's largest validity ([`matching::direct_costs_in`]).
    pub(super) max_valid: f64,
    pub(super) read: &'a dyn Fn((usize, usize, usize, usize)) -> crate::Result<Window>,
}

/// Coarse-to-fine match of `work` against `fine` at factor `f > 1`, given
/// their box-averaged copies: the coarse cost map (passed to `penalize`
/// with its placement step f, as the occurrence penalty must see it), the
/// best coarse placements, and the exact costs around them, each window
/// costed against the rectangle of the sample it reads.
#[allow(clippy::too_many_arguments)]
pub(super) fn match_coarse_to_fine(
    matcher: &mut Matcher,
    work: &matching::Work,
    fine: &Fine,
    coarse_work: &matching::Work,
    coarse_sample: &matching::Sample,
    cfg: &MatchConfig,
    f: usize,
    penalize: &mut dyn FnMut(&mut CostMap, i32),
) -> crate::Result<Vec<matching::Placement>> {
    let ccfg = coarse_config(cfg, f);
    let mut map = matcher.cost_map(coarse_work, coarse_sample, &ccfg)?;
    penalize(&mut map, f as i32);
    let best = map.best(ccfg.candidates, ccfg.tolerance);
    let size = [fine.width, fine.height];
    let range = matching::placement_range([work.image.width, work.image.height], size, cfg.span);
    let known = matching::known_box(work);
    let mut placements = Vec::new();
    for cluster in fine_windows(&best, f, range) {
        let rect = matching::footprint(known, &cluster, size);
        let window = (fine.read)(rect)?;
        let image = |channels, data| Image {
            width: rect.2,
            height: rect.3,
            channels,
            data,
        };
        let sample = matching::Sample {
            image: image(fine.channels, &window.maps),
            valid: &window.valid,
            constraint: (fine.constraint_channels > 0)
                .then(|| image(fine.constraint_channels, &window.constraint)),
            key: 0,
        };
        let origin = [rect.0, rect.1];
        placements.extend(matching::direct_costs_in(
            work,
            &sample,
            origin,
            fine.max_valid,
            cfg,
            &cluster,
        )?);
    }
    Ok(placements)
}

/// A [`Fine`] reader of a whole sample held in memory: its maps, validity
/// and constraint channels (empty without) cut to each rectangle.
pub(super) fn cut<'a>(
    sample: &'a matching::Sample<'a>,
) -> impl Fn((usize, usize, usize, usize)) -> crate::Result<Window> + 'a {
    move |(x0, y0, w, h)| {
        let (sw, n) = (sample.image.width, sample.image.channels);
        let k = sample.constraint.as_ref().map_or(0, |c| c.channels);
        let mut window = Window {
            maps: Vec::with_capacity(w * h * n),
            valid: Vec::with_capacity(w * h),
            constraint: Vec::with_capacity(w * h * k),
        };
        for y in y0..y0 + h {
            let row = y * sw + x0;
            window
                .maps
                .extend_from_slice(&sample.image.data[row * n..(row + w) * n]);
            window.valid.extend_from_slice(&sample.valid[row..row + w]);
            if let Some(c) = &sample.constraint {
                window
                    .constraint
                    .extend_from_slice(&c.data[row * k..(row + w) * k]);
            }
        }
        Ok(window)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factors_cover_the_limit() {
        assert_eq!(factor(768, 0), 1);
        assert_eq!(factor(512, 512), 1);
        assert_eq!(factor(513, 512), 2);
        assert_eq!(factor(1200, 512), 3);
        for side in [1usize, 100, 511, 777, 1500, 4000] {
            let f = factor(side, 384);
            assert!(side.div_ceil(f) <= 384, "side {side} factor {f}");
            assert!(
                f == 1 || side.div_ceil(f - 1) > 384,
                "side {side}: factor {f} not the smallest"
            );
        }
    }

    #[test]
    fn block_means_weigh_by_the_weights() {
        // 3×2 image, one channel, f = 2: blocks {0,1,3,4} and {2,5}
        let data = [1.0f32, 3.0, 5.0, 7.0, 9.0, 11.0];
        let weight = [1.0f32, 0.0, 1.0, 1.0, 0.5, 0.0];
        let image = Image {
            width: 3,
            height: 2,
            channels: 1,
            data: &data,
        };
        let c = Coarse::new(&image, &weight, &[], 0, 2);
        assert_eq!((c.width, c.height), (2, 1));
        // (1·1 + 1·7 + 0.5·9) / 2.5 = 5, weight 2.5 / 4
        assert!((c.features[0] - 5.0).abs() < 1e-6);
        assert!((c.weight[0] - 0.625).abs() < 1e-6);
        // only pixel 2 has weight: its value; weight 1 / 4
        assert!((c.features[1] - 5.0).abs() < 1e-6);
        assert!((c.weight[1] - 0.25).abs() < 1e-6);
    }

    #[test]
    fn windows_stay_in_range_and_are_distinct() {
        let p = |dx, dy| matching::Placement {
            dx,
            dy,
            cost: 0.0,
            overlap: 1.0,
        };
        let clusters = fine_windows(&[p(0, 0), p(1, 0), p(-3, -3)], 3, [(-8, 3), (-8, 0)]);
        for c in &clusters {
            assert!(c.windows(2).all(|a| (a[0].1, a[0].0) < (a[1].1, a[1].0)), "{c:?}");
        }
        let w: Vec<(i32, i32)> = clusters.concat();
        let mut distinct = w.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(w.len(), distinct.len());
        // (1, 0) keeps only its placements right of (0, 0)'s: x 3
        assert_eq!(clusters[1], [(3, -2), (3, -1), (3, 0)]);
        assert!(w
            .iter()
            .all(|&(x, y)| (-8..=3).contains(&x) && (-8..=0).contains(&y)));
        // (0,0) → x −2..2, (1,0) → 1..5 clipped to 3: x −2..3, y −2..0
        assert_eq!(w.iter().filter(|&&(_, y)| y == 0).count(), 6);
        // (−3,−3) → centre (−9,−9): x −11..−7 → −8..−7, y −8..−7
        assert!(w.contains(&(-8, -8)) && w.contains(&(-7, -7)));
        assert_eq!(w.len(), 6 * 3 + 4);
    }

    /// A smooth sample (sums of sines), a work image cut from it at an
    /// offset that is no multiple of f and known on an L-shaped band: the
    /// coarse-to-fine match finds the offset at cost 0, as the full match
    /// does, and its finite costs are the full match's.
    #[test]
    fn a_planted_offset_is_found_exactly() {
        let (sw, sh, ww, wh, n) = (150usize, 120usize, 40usize, 30usize, 3usize);
        let value = |x: usize, y: usize, c: usize| {
            let (x, y, c) = (x as f32, y as f32, c as f32);
            (0.11 * x + 0.7 * c).sin() + (0.07 * y - 0.3 * c).cos() + 0.5 * (0.05 * (x + 2.0 * y) + c).sin()
        };
        let sdata: Vec<f32> = (0..sw * sh * n)
            .map(|i| value(i / n % sw, i / n / sw, i % n))
            .collect();
        let valid = vec![1f32; sw * sh];
        for (ox, oy) in [(37usize, 22usize), (91, 64), (5, 80)] {
            let wdata: Vec<f32> = (0..ww * wh * n)
                .map(|i| value(i / n % ww + ox, i / n / ww + oy, i % n))
                .collect();
            let known: Vec<f32> = (0..ww * wh)
                .map(|i| if i % ww < 12 || i / ww < 9 { 1.0 } else { 0.0 })
                .collect();
            let work = matching::Work {
                image: Image::new(ww, wh, n, &wdata).unwrap(),
                known: &known,
                constraint: None,
            };
            let sample = matching::Sample {
                image: Image::new(sw, sh, n, &sdata).unwrap(),
                valid: &valid,
                constraint: None,
                key: 1,
            };
            let f = 3;
            let cw = Coarse::new(&work.image, &known, &[], 0, f);
            let cs = Coarse::new(&sample.image, &valid, &[], 0, f);
            let coarse_work = matching::Work {
                image: cw.image(n),
                known: &cw.weight,
                constraint: None,
            };
            let coarse_sample = matching::Sample {
                image: cs.image(n),
                valid: &cs.weight,
                constraint: None,
                key: 2,
            };
            let cfg = MatchConfig {
                min_overlap: 0.5 * known.iter().sum::<f32>() as f64,
                candidates: 8,
                tolerance: f64::INFINITY,
                ..MatchConfig::default()
            };
            let mut matcher = Matcher::new();
            let mut steps = Vec::new();
            let read = cut(&sample);
            let fine = Fine {
                width: sw,
                height: sh,
                channels: n,
                constraint_channels: 0,
                max_valid: 1.0,
                read: &read,
            };
            let placements = match_coarse_to_fine(
                &mut matcher,
                &work,
                &fine,
                &coarse_work,
                &coarse_sample,
                &cfg,
                f,
                &mut |_, step| steps.push(step),
            )
            .unwrap();
            assert_eq!(steps, [3]);
            let at: Vec<(i32, i32)> = placements.iter().map(|p| (p.dx, p.dy)).collect();
            let whole = matching::direct_costs(&work, &sample, &cfg, &at).unwrap();
            assert_eq!(placements, whole, "the windows cost as the whole sample does");
            let best = matching::best_of(placements.clone(), cfg.candidates, cfg.tolerance);
            assert_eq!((best[0].dx, best[0].dy), (-(ox as i32), -(oy as i32)), "{best:?}");
            assert!(best[0].cost < 1e-9, "{:?}", best[0]);
            let full = matcher.cost_map(&work, &sample, &cfg).unwrap();
            assert_eq!(full.best(1, 0.0)[0].dx, best[0].dx);
            let mut finite = 0;
            for p in placements.iter().filter(|p| p.cost.is_finite()) {
                let (cost, overlap) = full.get(p.dx, p.dy).unwrap();
                assert!(
                    (p.cost - cost).abs() <= 1e-6 * cost.abs() + 1e-9,
                    "{p:?} vs {cost}"
                );
                assert!((p.overlap - overlap).abs() <= 1e-9 * overlap);
                finite += 1;
            }
            // at least the window of the best coarse placement
            assert!(finite >= (2 * f - 1) * (2 * f - 1), "{finite}");
        }
    }
}
