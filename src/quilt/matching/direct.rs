//! Matching by direct sums: the brute-force reference of the FFT costs,
//! exact costs of a few placements around coarse ones (hierarchical
//! matching), and owned sample copies.

use super::*;

/// Brute-force reference: the cost of one placement by direct sums, with the
/// same acceptance rule as [`Matcher::cost_map`] (cost +∞ if rejected).
pub fn brute_force_cost(
    work: &Work,
    sample: &Sample,
    cfg: &MatchConfig,
    dx: i32,
    dy: i32,
) -> Result<Placement> {
    let lay = Layout::new(work, sample, cfg)?;
    Ok(brute(work, sample, cfg, &lay, dx, dy))
}

fn brute(work: &Work, sample: &Sample, cfg: &MatchConfig, lay: &Layout, dx: i32, dy: i32) -> Placement {
    let (wi, si) = (&work.image, &sample.image);
    let w = if work.constraint.is_some() {
        cfg.constraint_weight
    } else {
        0.0
    };
    let (mut ssd, mut overlap) = (0.0f64, 0.0f64);
    for y in 0..wi.height as i32 {
        let sy = y - dy;
        if sy < 0 || sy >= si.height as i32 {
            continue;
        }
        for x in 0..wi.width as i32 {
            let sx = x - dx;
            if sx < 0 || sx >= si.width as i32 {
                continue;
            }
            let (p, s) = (
                (y * wi.width as i32 + x) as usize,
                (sy * si.width as i32 + sx) as usize,
            );
            let mv = work.known[p] as f64 * sample.valid[s] as f64;
            let n = lay.n;
            let mut d = sq_diff(&wi.data[p * n..(p + 1) * n], &si.data[s * n..(s + 1) * n]);
            if let (Some(a), Some(b)) = (&work.constraint, &sample.constraint) {
                let k = lay.nc;
                d += w * sq_diff(&a.data[p * k..(p + 1) * k], &b.data[s * k..(s + 1) * k]);
            }
            ssd += mv * d;
            overlap += mv;
        }
    }
    let mass: f64 = work.known.iter().map(|&m| m as f64).sum();
    let max_valid = sample.valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
    scored(dx, dy, ssd, overlap, cfg.min_overlap, 1e-9 * mass * max_valid)
}

/// Σ (a − b)² in f64.
fn sq_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum()
}

/// The placement (dx, dy) with its direct sums: cost SSD / overlap, or +∞
/// where [`accept`] rejects the overlap.
fn scored(dx: i32, dy: i32, ssd: f64, overlap: f64, min_overlap: f64, tol: f64) -> Placement {
    let cost = if accept(overlap, min_overlap, tol) {
        ssd / overlap
    } else {
        f64::INFINITY
    };
    Placement {
        dx,
        dy,
        cost,
        overlap,
    }
}

/// Brute-force [`CostMap`] over the same placements as [`Matcher::cost_map`].
pub fn brute_force_map(work: &Work, sample: &Sample, cfg: &MatchConfig) -> Result<CostMap> {
    let lay = Layout::new(work, sample, cfg)?;
    let columns = (lay.dx.1 - lay.dx.0 + 1) as usize;
    let rows = (lay.dy.1 - lay.dy.0 + 1) as usize;
    let all: Vec<Placement> = (0..rows * columns)
        .into_par_iter()
        .map(|i| {
            let (dx, dy) = (lay.dx.0 + (i % columns) as i32, lay.dy.0 + (i / columns) as i32);
            brute(work, sample, cfg, &lay, dx, dy)
        })
        .collect();
    Ok(CostMap {
        dx0: lay.dx.0,
        dy0: lay.dy.0,
        columns,
        rows,
        cost: all.iter().map(|p| p.cost).collect(),
        overlap: all.iter().map(|p| p.overlap).collect(),
    })
}

/// The placements [`Matcher::cost_map`] considers for a `work`-sized image
/// over a `sample`-sized one: the (dx, dy) ranges, inclusive.
pub fn placement_range(work: [usize; 2], sample: [usize; 2], span: Span) -> [(i32, i32); 2] {
    [axis(work[0], sample[0], span).0, axis(work[1], sample[1], span).0]
}

/// The exact cost of each of `placements` by direct sums over the work
/// image's known pixels, with the acceptance rule of [`Matcher::cost_map`]
/// (cost +∞ where rejected): the fine step of coarse-to-fine matching,
/// where only a few placements around the coarse minima are wanted. Each
/// placement is summed in pixel order on one thread, so the result does
/// not depend on the thread count.
pub fn direct_costs(
    work: &Work,
    sample: &Sample,
    cfg: &MatchConfig,
    placements: &[(i32, i32)],
) -> Result<Vec<Placement>> {
    let max_valid = sample.valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
    direct_costs_in(work, sample, [0, 0], max_valid, cfg, placements)
}

/// The bounding box `[x0, y0, x1, y1]` (inclusive) of the work image's
/// known pixels; `None` if none is known.
pub fn known_box(work: &Work) -> Option<[i64; 4]> {
    let w = work.image.width;
    work.known
        .iter()
        .enumerate()
        .filter(|&(_, &m)| m > 0.0)
        .fold(None, |b: Option<[i64; 4]>, (p, _)| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            Some(b.map_or([x, y, x, y], |b| {
                [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)]
            }))
        })
}

/// The sample pixels the known pixels (`known`, [`known_box`]) land on at
/// any of `placements`, as the smallest rectangle `(x, y, w, h)` of a
/// `size` sample holding them; a pixel of the sample where none lands.
pub fn footprint(
    known: Option<[i64; 4]>,
    placements: &[(i32, i32)],
    size: [usize; 2],
) -> (usize, usize, usize, usize) {
    let clip = |v: i64, n: usize| v.clamp(0, n as i64 - 1);
    let mut rect: Option<[i64; 4]> = None;
    if let Some([x0, y0, x1, y1]) = known {
        for &(dx, dy) in placements {
            let (dx, dy) = (dx as i64, dy as i64);
            let (a0, a1, b0, b1) = (x0 - dx, x1 - dx, y0 - dy, y1 - dy);
            if a1 < 0 || b1 < 0 || a0 >= size[0] as i64 || b0 >= size[1] as i64 {
                continue;
            }
            let r = [
                clip(a0, size[0]),
                clip(b0, size[1]),
                clip(a1, size[0]),
                clip(b1, size[1]),
            ];
            rect = Some(rect.map_or(r, |q| {
                [q[0].min(r[0]), q[1].min(r[1]), q[2].max(r[2]), q[3].max(r[3])]
            }));
        }
    }
    let [x0, y0, x1, y1] = rect.unwrap_or([0; 4]);
    (
        x0 as usize,
        y0 as usize,
        (x1 - x0 + 1) as usize,
        (y1 - y0 + 1) as usize,
    )
}

/// [`direct_costs`] against a window of a larger sample: `window` holds the
/// sample's pixels from `origin` (x, y) on, and `max_valid` is the whole
/// sample's largest validity (the acceptance rule's tolerance scales with
/// it). The costs are the whole sample's as long as the window holds the
/// placements' [`footprint`]: a known pixel that lands outside the window
/// lands outside the sample.
pub fn direct_costs_in(
    work: &Work,
    window: &Sample,
    origin: [usize; 2],
    max_valid: f64,
    cfg: &MatchConfig,
    placements: &[(i32, i32)],
) -> Result<Vec<Placement>> {
    let sample = window;
    let (ox, oy) = (origin[0] as i32, origin[1] as i32);
    // (a placement (dx, dy) of the sample is (dx + ox, dy + oy) of the window)
    let shifted: Vec<(i32, i32)> = placements.iter().map(|&(dx, dy)| (dx + ox, dy + oy)).collect();
    let placements = &shifted[..];
    let lay = Layout::new(work, sample, cfg)?;
    let (wi, si) = (&work.image, &sample.image);
    let (n, nc) = (lay.n, lay.nc);
    // the known pixels, struct of arrays: weight, features (and constraint)
    // gathered, and the sample index each lands on at placement (0, 0)
    let known: Vec<usize> = (0..wi.pixels()).filter(|&p| work.known[p] > 0.0).collect();
    let weight: Vec<f64> = known.iter().map(|&p| work.known[p] as f64).collect();
    // (in f64 already: the same differences as converting in the loop)
    let features: Vec<f64> = known
        .iter()
        .flat_map(|&p| &wi.data[p * n..(p + 1) * n])
        .map(|&v| v as f64)
        .collect();
    let constraint: Vec<f64> = match &work.constraint {
        Some(c) => known
            .iter()
            .flat_map(|&p| &c.data[p * nc..(p + 1) * nc])
            .map(|&v| v as f64)
            .collect(),
        None => Vec::new(),
    };
    let xy: Vec<[i64; 2]> = known
        .iter()
        .map(|&p| [(p % wi.width) as i64, (p / wi.width) as i64])
        .collect();
    let at_origin: Vec<i64> = xy.iter().map(|&[x, y]| y * si.width as i64 + x).collect();
    // the known pixels' bounding box, to tell placements wholly inside
    let bbox = known_box(work);
    let mass: f64 = work.known.iter().map(|&m| m as f64).sum();
    let tol = 1e-9 * mass * max_valid;
    let w = if work.constraint.is_some() {
        cfg.constraint_weight
    } else {
        0.0
    };
    let pixels = Known {
        xy: &xy,
        weight: &weight,
        features: &features,
        constraint: &constraint,
        at_origin: &at_origin,
    };
    let group_costs = |group: &[(i32, i32)]| -> Vec<Placement> {
        let mut inside = [false; DIRECT_GROUP];
        let mut shift = [0i64; DIRECT_GROUP];
        for (j, &(dx, dy)) in group.iter().enumerate() {
            // (x1 − dx ≥ x0 − dx ≥ 0 once the first two hold)
            inside[j] = bbox.is_some_and(|[x0, y0, x1, y1]| {
                x0 - dx as i64 >= 0
                    && y0 - dy as i64 >= 0
                    && x1 - (dx as i64) < si.width as i64
                    && y1 - (dy as i64) < si.height as i64
            });
            shift[j] = dy as i64 * si.width as i64 + dx as i64;
        }
        // colour samples (three channels) get the sum unrolled
        let (ssd, overlap) = if n == 3 {
            pixels.pass(sample, group, &inside, &shift, w, sq_diff3)
        } else {
            pixels.pass(sample, group, &inside, &shift, w, sq_diff_f64)
        };
        group
            .iter()
            .enumerate()
            .map(|(j, &(dx, dy))| scored(dx - ox, dy - oy, ssd[j], overlap[j], cfg.min_overlap, tol))
            .collect()
    };
    // placements in groups of neighbours (the list is in (dy, dx) order):
    // one pass over the known pixels serves a group, whose sample reads
    // lie close together; each placement still sums in pixel order
    Ok(placements
        .par_chunks(DIRECT_GROUP)
        .flat_map_iter(group_costs)
        .collect())
}

/// The work image's known pixels as [`direct_costs`] gathers them: (x, y),
/// weight, features and constraint (f64), and the sample index each lands
/// on at placement (0, 0).
struct Known<'a> {
    /// Each known pixel's (x, y) in the work image.
    xy: &'a [[i64; 2]],
    pub(super) weight: &'a [f64],
    pub(super) features: &'a [f64],
    pub(super) constraint: &'a [f64],
    at_origin: &'a [i64],
}

impl Known<'_> {
    /// Σ m·v·(feature distance + w · constraint distance) and Σ m·v of each
    /// placement of `group` (at most [`DIRECT_GROUP`]; `inside`: wholly
    /// inside the sample, `shift`: its sample index offset), each summed in
    /// pixel order, with `diff` the features' squared distance.
    fn pass(
        &self,
        sample: &Sample,
        group: &[(i32, i32)],
        inside: &[bool; DIRECT_GROUP],
        shift: &[i64; DIRECT_GROUP],
        w: f64,
        diff: impl Fn(&[f64], &[f32]) -> f64,
    ) -> ([f64; DIRECT_GROUP], [f64; DIRECT_GROUP]) {
        // (placements wholly inside need no bounds test: a loop without it)
        if inside[..group.len()].iter().all(|&i| i) {
            self.sums::<false>(sample, group, shift, w, diff)
        } else {
            self.sums::<true>(sample, group, shift, w, diff)
        }
    }

    /// [`Known::pass`], testing each placement's sample bounds if `BOUNDS`.
    #[inline(always)]
    fn sums<const BOUNDS: bool>(
        &self,
        sample: &Sample,
        group: &[(i32, i32)],
        shift: &[i64; DIRECT_GROUP],
        w: f64,
        diff: impl Fn(&[f64], &[f32]) -> f64,
    ) -> ([f64; DIRECT_GROUP], [f64; DIRECT_GROUP]) {
        let si = &sample.image;
        let (n, nc) = (si.channels, sample.constraint.as_ref().map_or(0, |c| c.channels));
        let (width, height) = (si.width as i64, si.height as i64);
        let mut ssd = [0.0f64; DIRECT_GROUP];
        let mut overlap = [0.0f64; DIRECT_GROUP];
        for (k, &[px, py]) in self.xy.iter().enumerate() {
            let a = &self.features[k * n..(k + 1) * n];
            let (origin, weight) = (self.at_origin[k], self.weight[k]);
            for (j, &(dx, dy)) in group.iter().enumerate() {
                if BOUNDS {
                    let (sx, sy) = (px - dx as i64, py - dy as i64);
                    if sx < 0 || sy < 0 || sx >= width || sy >= height {
                        continue;
                    }
                }
                let s = (origin - shift[j]) as usize;
                let mv = weight * sample.valid[s] as f64;
                if mv == 0.0 {
                    continue;
                }
                let mut d = diff(a, &si.data[s * n..(s + 1) * n]);
                if let Some(b) = &sample.constraint {
                    let c = &self.constraint[k * nc..(k + 1) * nc];
                    d += w * sq_diff_f64(c, &b.data[s * nc..(s + 1) * nc]);
                }
                ssd[j] += mv * d;
                overlap[j] += mv;
            }
        }
        (ssd, overlap)
    }
}

/// [`sq_diff`] with `a` converted to f64 already (the same sum).
#[inline]
fn sq_diff_f64(a: &[f64], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&a, &b)| (a - b as f64).powi(2)).sum()
}

/// [`sq_diff_f64`] of three channels.
#[inline(always)]
fn sq_diff3(a: &[f64], b: &[f32]) -> f64 {
    let (a, b): (&[f64; 3], &[f32; 3]) = (a.try_into().expect("3"), b.try_into().expect("3"));
    let d = [a[0] - b[0] as f64, a[1] - b[1] as f64, a[2] - b[2] as f64];
    -0.0 + d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// Placements [`direct_costs`] sums in one pass over the known pixels: the
/// ±1 window around a coarse placement of factor 2.
const DIRECT_GROUP: usize = 9;

/// An owned sample copy in f32: maps `[y][x][c]` and validity `[y][x]`.
#[derive(Clone, Debug)]
pub struct SampleCopy {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub maps: Vec<f32>,
    pub valid: Vec<f32>,
}

impl SampleCopy {
    /// Rotated copy `r` of a factorization's geometry maps.
    pub fn rotated(svd: &SvdArtifact, r: usize) -> Result<SampleCopy> {
        let (maps16, valid8) = svd.rotated(r)?;
        let mut maps = vec![0f32; maps16.len()];
        maps16.convert_to_f32_slice(&mut maps);
        Ok(SampleCopy {
            width: svd.width,
            height: svd.height,
            channels: svd.terms,
            maps,
            valid: valid_to_f32(&valid8),
        })
    }

    /// Borrows it as a [`Sample`] cached under `key` (e.g. the rotation
    /// index, combined with anything else that distinguishes the source).
    pub fn sample(&self, key: u64) -> Sample<'_> {
        Sample {
            image: Image {
                width: self.width,
                height: self.height,
                channels: self.channels,
                data: &self.maps,
            },
            valid: &self.valid,
            constraint: None,
            key,
        }
    }
}

/// A u8 validity mask as weights: non-zero → 1.
pub fn valid_to_f32(valid: &[u8]) -> Vec<f32> {
    valid.iter().map(|&v| if v != 0 { 1.0 } else { 0.0 }).collect()
}
