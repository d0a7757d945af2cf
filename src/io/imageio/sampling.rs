//! Sampling images: bilinear lookups, box-filtered resampling and bilinear
//! lookups in masks (optionally tileable).

use super::*;

/// Read PNG (8/16-bit, grey/grey-alpha/RGB/RGBA), JPEG, TIFF, or OpenEXR into linear RGB.
///
/// PNG/JPEG/TIFF are decoded from sRGB with the exact transfer function
/// (a float TIFF is taken as already linear); EXR is read as is. Alpha is
/// Bilinear lookup in an RGB image at pixel coordinates (clamped).
pub fn bilinear(img: &RgbImage, x: f32, y: f32) -> [f32; 3] {
    let w = img.width;
    bilinear_with(img.width, img.height, x, y, |x, y| {
        let p = &img.data[(y * w + x) * 3..(y * w + x) * 3 + 3];
        [p[0], p[1], p[2]]
    })
}

/// [`bilinear`] over a `w`×`h` image whose pixel `(x, y)` is `px(x, y)`.
pub fn bilinear_with(
    w: usize,
    h: usize,
    x: f32,
    y: f32,
    mut px: impl FnMut(usize, usize) -> [f32; 3],
) -> [f32; 3] {
    let x = x.clamp(0.0, (w - 1) as f32);
    let y = y.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let (p00, p10, p01, p11) = (px(x0, y0), px(x1, y0), px(x0, y1), px(x1, y1));
    let mut out = [0f32; 3];
    for c in 0..3 {
        let top = p00[c] + (p10[c] - p00[c]) * fx;
        let bottom = p01[c] + (p11[c] - p01[c]) * fx;
        out[c] = top + (bottom - top) * fy;
    }
    out
}

/// Per output pixel of a 1-D resampling from `n` to `m` pixels: the source
/// pixels and their weights (summing to 1). Shrinking averages each output
/// pixel's footprint (a box filter, so no aliasing); enlarging interpolates
/// linearly between pixel centres.
fn resample_weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    let s = n as f64 / m as f64;
    (0..m)
        .map(|o| {
            if s > 1.0 {
                let (a, b) = (o as f64 * s, (o as f64 + 1.0) * s);
                let mut w = Vec::new();
                let mut i = a.floor() as usize;
                while (i as f64) < b && i < n {
                    let cover = (b.min(i as f64 + 1.0) - a.max(i as f64)) / s;
                    if cover > 0.0 {
                        w.push((i, cover as f32));
                    }
                    i += 1;
                }
                w
            } else {
                let x = ((o as f64 + 0.5) * s - 0.5).clamp(0.0, (n - 1) as f64);
                let i = x.floor() as usize;
                let f = (x - i as f64) as f32;
                if f > 0.0 && i + 1 < n {
                    vec![(i, 1.0 - f), (i + 1, f)]
                } else {
                    vec![(i, 1.0)]
                }
            }
        })
        .collect()
}

/// Resamples row-major `channels`-channel maps of `width`×`height` pixels to
/// `to_width`×`to_height` (separable: a box filter where it shrinks, linear
/// where it enlarges). Used to bring a sample to the atlas's texel density.
pub fn resample(
    maps: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    to_width: usize,
    to_height: usize,
) -> Vec<f32> {
    let (wx, wy) = (
        resample_weights(width, to_width),
        resample_weights(height, to_height),
    );
    let mut rows = vec![0f32; height * to_width * channels];
    for y in 0..height {
        for (x, taps) in wx.iter().enumerate() {
            let out = &mut rows[(y * to_width + x) * channels..(y * to_width + x + 1) * channels];
            for &(i, w) in taps {
                let src = &maps[(y * width + i) * channels..(y * width + i + 1) * channels];
                for (o, v) in out.iter_mut().zip(src) {
                    *o += w * v;
                }
            }
        }
    }
    let mut out = vec![0f32; to_height * to_width * channels];
    for (y, taps) in wy.iter().enumerate() {
        let dst = &mut out[y * to_width * channels..(y + 1) * to_width * channels];
        for &(i, w) in taps {
            let src = &rows[i * to_width * channels..(i + 1) * to_width * channels];
            for (o, v) in dst.iter_mut().zip(src) {
                *o += w * v;
            }
        }
    }
    out
}

/// A foreground mask value at sample coordinates `c` (pixel indices, `[y][x]`
/// storage), bilinear between pixel centres. A tileable sample wraps round
/// its borders; any other reads 0 outside `[0, width − 1] × [0, height − 1]`.
/// The one mask lookup of the synthesis and of `evaluate`'s painting
/// measures, so both count the same texels as foreground.
pub fn mask_bilinear(values: &[f32], width: usize, height: usize, c: [f64; 2], tileable: bool) -> f32 {
    let (w, h) = (width, height);
    if w == 0 || h == 0 || values.len() < w * h {
        return 0.0;
    }
    let (mut x, mut y) = (c[0], c[1]);
    if !(x.is_finite() && y.is_finite()) {
        return 0.0;
    }
    if tileable {
        x = x.rem_euclid(w as f64);
        y = y.rem_euclid(h as f64);
    } else if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return 0.0;
    }
    let (x0, y0) = ((x.floor() as usize).min(w - 1), (y.floor() as usize).min(h - 1));
    let (x1, y1) = if tileable {
        ((x0 + 1) % w, (y0 + 1) % h)
    } else {
        ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1))
    };
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let top = values[y0 * w + x0] + (values[y0 * w + x1] - values[y0 * w + x0]) * fx;
    let bottom = values[y1 * w + x0] + (values[y1 * w + x1] - values[y1 * w + x0]) * fx;
    top + (bottom - top) * fy
}
