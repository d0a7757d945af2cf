//! Dilation: filling uncovered texels from covered neighbours, so lookups
//! near chart borders never see the empty background.

use super::*;

/// Fills empty texels from their filled neighbours, ring by ring, so
/// mipmapping never blends in the background; what is still empty after
/// `passes` rings gets the mean colour of the covered texels.
pub fn dilate(img: &mut RgbImage, covered: &[bool], passes: usize) {
    let mut mean = CoveredMean::default();
    mean.add(&img.data, covered);
    dilate_with(img, covered, passes, mean.colour());
}

/// The mean colour of covered texels, summed in texel order (so a sum over
/// bands in order equals the sum over the whole image, bit for bit).
#[derive(Clone, Copy, Debug, Default)]
pub struct CoveredMean {
    sum: [f64; 3],
    n: usize,
}

impl CoveredMean {
    /// Adds the covered texels of RGB `data`.
    pub fn add(&mut self, data: &[f32], covered: &[bool]) {
        for (t, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
            for k in 0..3 {
                self.sum[k] += data[t * 3 + k] as f64;
            }
            self.n += 1;
        }
    }

    /// The mean (0 when nothing is covered).
    pub fn colour(&self) -> [f32; 3] {
        self.sum.map(|s| (s / self.n.max(1) as f64) as f32)
    }
}

/// [`dilate`], with `fill` for what is still empty after `passes` rings.
pub fn dilate_with(img: &mut RgbImage, covered: &[bool], passes: usize, fill: [f32; 3]) {
    let (w, h) = (img.width, img.height);
    let mut filled = covered.to_vec();
    for _ in 0..passes {
        let mut next = filled.clone();
        let mut any = false;
        for y in 0..h {
            for x in 0..w {
                let t = y * w + x;
                if filled[t] {
                    continue;
                }
                let (mut s, mut c) = ([0f32; 3], 0);
                for (dx, dy) in [
                    (-1i32, 0i32),
                    (1, 0),
                    (0, -1),
                    (0, 1),
                    (-1, -1),
                    (1, -1),
                    (-1, 1),
                    (1, 1),
                ] {
                    let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i32 || ny >= h as i32 {
                        continue;
                    }
                    let n = ny as usize * w + nx as usize;
                    if filled[n] {
                        for k in 0..3 {
                            s[k] += img.data[n * 3 + k];
                        }
                        c += 1;
                    }
                }
                if c > 0 {
                    for k in 0..3 {
                        img.data[t * 3 + k] = s[k] / c as f32;
                    }
                    next[t] = true;
                    any = true;
                }
            }
        }
        filled = next;
        if !any {
            break;
        }
    }
    for t in 0..w * h {
        if !filled[t] {
            img.data[t * 3..t * 3 + 3].copy_from_slice(&fill);
        }
    }
}
