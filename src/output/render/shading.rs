//! BTF shading: the measured directions a view/light pair falls between,
//! and the local frame and sample of each texel.

use super::*;
use crate::math;

/// Measured directions of one kind (views or lights) as unit vectors in
/// sample axes, for nearest-direction interpolation.
pub(crate) struct Directions {
    pub(crate) dirs: Vec<Vec3>,
    pub(crate) cos_max: f32,
    sin_max: f32,
}

impl Directions {
    pub(super) fn new(angles: &[Angles]) -> Directions {
        let dirs: Vec<Vec3> = angles
            .iter()
            .map(|a| crate::generate::direction(a.theta, a.phi).into())
            .collect();
        let theta_max = angles
            .iter()
            .map(|a| a.theta)
            .fold(0f32, f32::max)
            .clamp(0.0, 90.0)
            .to_radians();
        Directions {
            dirs,
            cos_max: math::cos(theta_max),
            sin_max: math::sin(theta_max),
        }
    }

    /// `d` (unit, sample axes) with θ clamped to the measured range, φ kept.
    pub(super) fn clamp(&self, d: Vec3) -> Vec3 {
        if d.z >= self.cos_max {
            return d;
        }
        let h = (d.x * d.x + d.y * d.y).sqrt();
        if h < 1e-12 {
            return Vec3::new(self.sin_max, 0.0, self.cos_max);
        }
        Vec3::new(self.sin_max * d.x / h, self.sin_max * d.y / h, self.cos_max)
    }

    /// The (up to) 3 measured directions nearest to the unit `d` by angle
    /// and their normalised weights: `(index, weight)`, count. The weights
    /// are 1/α_k − 1/α_4 (α_4 the angle to the fourth nearest), so a
    /// direction's weight falls to zero as it stops being among the three
    /// nearest: the interpolation is continuous as the view or light turns
    /// over the surface (plain inverse-angle weights over the three nearest
    /// step where the third changes, a faint line across the render). With
    /// three directions or fewer, plain inverse-angle weights.
    pub(super) fn nearest(&self, d: Vec3) -> ([(u32, f32); 3], usize) {
        // a degenerate frame can only give a non-finite direction: take the pole
        let d = if d.is_finite() { d } else { Vec3::Z };
        let mut best = [(f32::NEG_INFINITY, u32::MAX); 4];
        for (j, m) in self.dirs.iter().enumerate() {
            let c = d.dot(*m);
            if c > best[3].0 {
                let mut k = 3;
                while k > 0 && c > best[k - 1].0 {
                    best[k] = best[k - 1];
                    k -= 1;
                }
                best[k] = (c, j as u32);
            }
        }
        let angle = |k: usize| {
            let chord = d.distance(self.dirs[best[k].1 as usize]);
            2.0 * math::asin((0.5 * chord).min(1.0))
        };
        let count = self.dirs.len().min(3);
        let cut = if self.dirs.len() > 3 {
            1.0 / angle(3).max(EXACT_HIT)
        } else {
            0.0
        };
        let mut out = [(0u32, 0f32); 3];
        let mut total = 0f32;
        for k in 0..count {
            let a = angle(k);
            if a < EXACT_HIT {
                return ([(best[k].1, 1.0), (0, 0.0), (0, 0.0)], 1);
            }
            let w = (1.0 / a - cut).max(0.0);
            out[k] = (best[k].1, w);
            total += w;
        }
        if !(total > 0.0) {
            // the four nearest are equally far (a symmetric point): equal weights
            for o in out.iter_mut().take(count) {
                o.1 = 1.0 / count as f32;
            }
            return (out, count);
        }
        for o in out.iter_mut().take(count) {
            o.1 /= total;
        }
        (out, count)
    }
}

/// One sample's factorization as the shading needs it. Its g vectors are
/// only ever dotted with its own p (a texel's value is Σ_i g_i p_i in its
/// own sample's basis).
pub(crate) struct Basis {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) terms: usize,
    /// Where this sample's terms start in the per-pixel scratch buffer.
    pub(super) offset: usize,
    /// `[y][x][i]`.
    pub(crate) geometry: Vec<f32>,
    /// `[pair][rgb][i]`, the pairs shared by every sample.
    pub(crate) appearance: Vec<f32>,
}

/// The BTF data a pixel needs.
pub(crate) struct BtfShading {
    /// Every sample the surface draws from, in [`Quilt::samples`] order.
    pub(crate) samples: Vec<Basis>,
    /// Σ terms over the samples: the scratch buffer's length.
    pub(super) total_terms: usize,
    pub(crate) views: Directions,
    pub(crate) lights: Directions,
    pub(super) n_lights: usize,
    /// Per texel: sample coordinate, Jacobian, sample index, covered.
    pub(crate) tiles: AtlasTiles<BtfTile>,
    /// Per corner: ∂P/∂X, ∂P/∂Y (3D per atlas texel) averaged over its
    /// wedge ([`corner_maps`]), `None` if degenerate.
    pub(crate) corner_maps: Vec<Option<[[f32; 3]; 2]>>,
}

pub(crate) enum Shading {
    /// Dilated atlas colour texture.
    Colour(AtlasTiles<ColourTile>),
    Btf(Box<BtfShading>),
}
