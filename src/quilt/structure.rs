//! The structure channel: a feature channel that sees structure, not only
//! colour, for matching, the graphcut's cut cost and seam refinement (the
//! feature distance of Lefebvre & Hoppe 2006, "Appearance-space texture
//! synthesis"; the feature maps of Wu & Yu 2004). Two brick bodies
//! offset by part of a brick are grey against grey, so a colour-only cut
//! runs through them; their distances to the nearest mortar line differ, so
//! a cut there costs.
//!
//! The channel is the distance from each sample pixel to the nearest
//! feature pixel (the strongest geometry-map gradients), clamped at the
//! sample's own feature spacing and scaled to 0..1.

/// Pixels whose gradient is at least this quantile of the sample's
/// gradients are features.
const FEATURE_QUANTILE: f64 = 0.85;

/// Distances are clamped at this quantile of all distances (the sample's
/// feature spacing), then scaled to 0..1.
const SPACING_QUANTILE: f64 = 0.9;

/// The structure channel of `n`-term geometry maps `width × height`
/// (`[y][x]`, 0..1; all 0 when the sample has no edges).
pub(super) fn structure_channel(maps: &[f32], width: usize, height: usize, n: usize) -> Vec<f32> {
    let (w, h) = (width, height);
    let at = |x: usize, y: usize| &maps[(y * w + x) * n..(y * w + x + 1) * n];
    let sq = |a: &[f32], b: &[f32]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(p, q)| {
                let d = (*p - *q) as f64;
                d * d
            })
            .sum()
    };
    // central differences in feature space (one-sided at the border)
    let grad: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let gx = sq(at((x + 1).min(w - 1), y), at(x.saturating_sub(1), y));
            let gy = sq(at(x, (y + 1).min(h - 1)), at(x, y.saturating_sub(1)));
            (gx + gy).sqrt()
        })
        .collect();
    let threshold = quantile(&grad, FEATURE_QUANTILE);
    if threshold <= 0.0 {
        return vec![0.0; w * h];
    }
    let feature: Vec<bool> = grad.iter().map(|&g| g >= threshold).collect();
    let d2 = squared_distance(&feature, w, h);
    let dist: Vec<f64> = d2.iter().map(|&d| d.sqrt()).collect();
    let spacing = quantile(&dist, SPACING_QUANTILE).max(1.0);
    dist.iter().map(|&d| (d.min(spacing) / spacing) as f32).collect()
}

/// The `q` quantile (nearest rank) of `values`.
fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    let k = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// Exact squared Euclidean distance from every pixel to the nearest `true`
/// pixel (Felzenszwalb & Huttenlocher 2012: the lower envelope of parabolas,
/// by columns then rows); `f64::INFINITY` everywhere without one.
pub(super) fn squared_distance(feature: &[bool], w: usize, h: usize) -> Vec<f64> {
    const FAR: f64 = 1e20;
    let mut grid: Vec<f64> = feature.iter().map(|&f| if f { 0.0 } else { FAR }).collect();
    let (mut f, mut d) = (vec![0f64; w.max(h)], vec![0f64; w.max(h)]);
    let (mut v, mut z) = (vec![0usize; w.max(h)], vec![0f64; w.max(h) + 1]);
    for x in 0..w {
        for y in 0..h {
            f[y] = grid[y * w + x];
        }
        envelope(&f[..h], &mut d[..h], &mut v, &mut z);
        for y in 0..h {
            grid[y * w + x] = d[y];
        }
    }
    for y in 0..h {
        f[..w].copy_from_slice(&grid[y * w..(y + 1) * w]);
        envelope(&f[..w], &mut d[..w], &mut v, &mut z);
        grid[y * w..(y + 1) * w].copy_from_slice(&d[..w]);
    }
    if !feature.iter().any(|&f| f) {
        grid.fill(f64::INFINITY);
    }
    grid
}

/// The 1D distance transform d(p) = min_q (p − q)² + f(q).
fn envelope(f: &[f64], d: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let cross = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * q as f64 - 2.0 * p as f64)
    };
    for q in 1..n {
        let mut s = cross(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = cross(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (p, out) in d.iter_mut().enumerate() {
        while z[k + 1] < p as f64 {
            k += 1;
        }
        let q = v[k];
        *out = (p as f64 - q as f64).powi(2) + f[q];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn squared_distances_match_brute_force() {
        let (w, h) = (23, 17);
        for seed in 0..20u64 {
            let feature: Vec<bool> = (0..w * h)
                .map(|i| crate::rng::mix64(seed * 1000 + i as u64) % 29 == 0)
                .collect();
            let got = squared_distance(&feature, w, h);
            for i in 0..w * h {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let want = (0..w * h)
                    .filter(|&j| feature[j])
                    .map(|j| ((j % w) as f64 - x).powi(2) + ((j / w) as f64 - y).powi(2))
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(got[i], want, "seed {seed} pixel {i}");
            }
        }
    }

    #[test]
    fn the_channel_is_zero_on_lines_and_grows_between_them() {
        // vertical bright lines every 12 px on a flat ground (one on either
        // border), 3 terms
        let (w, h, n) = (49, 20, 3);
        let maps: Vec<f32> = (0..w * h)
            .flat_map(|i| {
                let v = if (i % w) % 12 == 0 { 1.0 } else { 0.2 };
                [v, 0.5 * v, 0.0]
            })
            .collect();
        let s = structure_channel(&maps, w, h, n);
        let row = &s[5 * w..6 * w];
        // the gradient lies on the pixels either side of a line (a central
        // difference is zero on the line itself, one pixel from them)
        assert_eq!((row[11], row[13]), (0.0, 0.0));
        assert!(row[12] > 0.0 && row[12] == row[14], "{row:?}");
        // growing towards the middle between two lines, where it tops at 1
        assert!((13..16).all(|x| row[x] < row[x + 1]), "{row:?}");
        assert!((16..18).all(|x| row[x] <= row[x + 1]), "{row:?}");
        assert_eq!(row[18], 1.0);
        // the same along every row: the lines are vertical
        assert!((0..h).all(|y| s[y * w..(y + 1) * w] == *row));
    }

    #[test]
    fn a_flat_sample_has_a_flat_channel() {
        let maps = vec![0.3f32; 16 * 16 * 2];
        assert!(structure_channel(&maps, 16, 16, 2).iter().all(|&v| v == 0.0));
        assert!(squared_distance(&[false; 9], 3, 3)
            .iter()
            .all(|d| d.is_infinite()));
    }
}
