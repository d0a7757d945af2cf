//! Packing charts into the R×R atlas at one uniform texel density.
//!
//! Charts arrive in surface units (uv area = 3D area). The packer finds the
//! largest scale s (texels per surface unit) at which shelf packing of the
//! charts' bounding rectangles, each padded so neighbouring charts keep at
//! least `gutter` empty texels between their (half-texel dilated) coverage,
//! fits in R×R, by bisection on s.

/// Where each chart goes.
#[derive(Clone, Debug, PartialEq)]
pub struct Packing {
    /// Texels per surface unit, the same for every chart.
    pub scale: f64,
    /// Per chart, the texel position of its uv origin.
    pub offsets: Vec<[f64; 2]>,
}

/// Texels kept free around each chart: half the gutter plus the coverage
/// dilation of the rasterizer (under one texel).
fn padding(gutter: usize) -> f64 {
    gutter as f64 / 2.0 + 1.0
}

/// Shelf-packs rectangles of `extents · scale` (plus padding) into
/// `resolution`²; the offsets, or `None` if they do not fit.
fn shelf(
    extents: &[[f64; 2]],
    order: &[usize],
    scale: f64,
    resolution: usize,
    gutter: usize,
) -> Option<Vec<[f64; 2]>> {
    let pad = padding(gutter);
    let r = resolution as f64;
    let mut offsets = vec![[0.0; 2]; extents.len()];
    let (mut x, mut y, mut shelf_h) = (0.0f64, 0.0f64, 0.0f64);
    for &c in order {
        let w = (extents[c][0] * scale + 2.0 * pad).ceil();
        let h = (extents[c][1] * scale + 2.0 * pad).ceil();
        if w > r || h > r {
            return None;
        }
        if x + w > r {
            x = 0.0;
            y += shelf_h;
            shelf_h = 0.0;
        }
        if y + h > r {
            return None;
        }
        offsets[c] = [x + pad, y + pad];
        x += w;
        shelf_h = shelf_h.max(h);
    }
    Some(offsets)
}

/// Packs charts with the given uv extents (surface units, each starting at
/// 0) into `resolution`² with at least `gutter` texels between charts.
pub fn pack(extents: &[[f64; 2]], resolution: usize, gutter: usize) -> Packing {
    // tallest first (ties by index), so shelves fill evenly
    let mut order: Vec<usize> = (0..extents.len()).collect();
    order.sort_by(|&a, &b| extents[b][1].total_cmp(&extents[a][1]).then(a.cmp(&b)));
    let area: f64 = extents.iter().map(|e| e[0] * e[1]).sum::<f64>().max(1e-30);
    // upper bound: the charts' total area cannot exceed the atlas
    let mut hi = resolution as f64 / area.sqrt();
    let mut lo = 0.0;
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if shelf(extents, &order, mid, resolution, gutter).is_some() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let offsets =
        shelf(extents, &order, lo, resolution, gutter).unwrap_or_else(|| vec![[0.0; 2]; extents.len()]);
    Packing { scale: lo, offsets }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_charts_do_not_overlap_and_fill_the_atlas() {
        let extents: Vec<[f64; 2]> = (0..30)
            .map(|i| [1.0 + (i * 7 % 5) as f64, 0.5 + (i * 3 % 4) as f64])
            .collect();
        let (r, gutter) = (512usize, 2usize);
        let p = pack(&extents, r, gutter);
        assert!(p.scale > 0.0);
        let rects: Vec<[f64; 4]> = extents
            .iter()
            .zip(&p.offsets)
            .map(|(e, o)| [o[0], o[1], o[0] + e[0] * p.scale, o[1] + e[1] * p.scale])
            .collect();
        for (i, a) in rects.iter().enumerate() {
            assert!(a[0] >= 1.0 && a[1] >= 1.0 && a[2] <= r as f64 - 1.0 && a[3] <= r as f64 - 1.0);
            for b in &rects[i + 1..] {
                // separated by at least gutter + 2 texels along some axis
                let gap_x = (b[0] - a[2]).max(a[0] - b[2]);
                let gap_y = (b[1] - a[3]).max(a[1] - b[3]);
                assert!(gap_x.max(gap_y) >= gutter as f64 + 2.0 - 1e-9, "{a:?} {b:?}");
            }
        }
        // a slightly larger scale no longer fits: the bisection is tight
        let used: f64 = rects.iter().map(|r| (r[2] - r[0]) * (r[3] - r[1])).sum();
        assert!(
            used / (r * r) as f64 > 0.4,
            "utilisation {}",
            used / (r * r) as f64
        );
    }
}
