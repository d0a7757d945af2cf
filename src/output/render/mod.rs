//! `render`: a software rasterizer that shows a decorated mesh from a pinhole
//! camera under directional and point lights, to PNG (8-bit sRGB) or EXR
//! (linear).
//!
//! Two passes:
//! 1. a G-buffer is rasterized sequentially (z-buffer; per pixel the nearest
//!    face and its perspective-correct barycentrics);
//! 2. rows are shaded in parallel with rayon. Every pixel depends only on its
//!    own G-buffer entry, so the image is byte-identical for any thread count.
//!
//! Shading depends on the quilt's samples:
//! - a colour image (one view × one light): the baked preview colour (gutter
//!   dilated, bilinear in the atlas) × `0.18 + 0.82 Σ_k E_k max(n·l_k, 0)`;
//! - a BTF (more than one direction pair): per pixel, the nearest covered
//!   atlas texel gives the sample coordinate (carried to the pixel's exact
//!   atlas position through the texel's Jacobian) and the local frame: the
//!   interpolated vertex normal n, the sample's +x axis on the surface (the
//!   atlas step J⁻¹·(1,0) through the face's atlas→3D map, orthonormalised
//!   against n) and the sample's +y axis ± n × x, the sign taken from the
//!   mapped J⁻¹·(0,1) so a mirrored mapping stays consistent. View and light
//!   are expressed there as (θ, φ) in the generator's convention
//!   ([`crate::generate::direction`]: `(sinθ cosφ, sinθ sinφ, cosθ)` in
//!   sample axes, x right, y down the image, z the normal: φ = 0° is image +x
//!   and φ = 90° image +y, downwards). Each of view and light is interpolated
//!   from its 3 nearest measured directions by angle (normalised weights
//!   1/α_k − 1/α_4, α the angular distance and α_4 the fourth nearest's, so
//!   the blend is continuous as directions turn; an exact hit takes weight
//!   1), so the value is
//!   `Σ_v Σ_l w_v w_l E Σ_i g_i(x) p_i(v, l)`, with the geometry maps looked
//!   up bilinearly (clamped at the sample's border). Directions beyond the
//!   measured θ range are clamped to it; a light below the horizon (n·l ≤ 0)
//!   adds nothing, and one between the last measured θ and the horizon is
//!   faded by `cos θ_l / cos θ_max` so the terminator is continuous. The
//!   measured values are images under the light and already contain the
//!   `cos θ_l` foreshortening (the generator shades `albedo·max(n·l, 0)`), so
//!   it is not applied again.
//!
//! A surface may draw from several samples (one direction set, checked by
//! [`crate::output::open_samples`]); each texel looks up its own: the colour
//! path reads each texel's sample's preview, and the BTF path blends the
//! geometry vectors of the four texels per sample (a g vector is only
//! meaningful in its own sample's basis) and sums, over the samples present,
//! `Σ_i g_i p_i` with each sample's own appearance functions.
//!
//! Point lights fall off with the inverse square of the distance, normalised
//! to their intensity at the distance of the mesh's bounding-box centre.

use std::path::{Path, PathBuf};

use glam::Vec3;
use rayon::prelude::*;

use crate::artifact::btf::Angles;
use crate::container::MemoryBudget;
use crate::io::imageio::{self, PngDepth, RgbImage};
use crate::io::imageio::{bilinear_with, CoveredMean};
use crate::mesh::{unit_or, Mesh};
use crate::output::texels::{btf_tiles, colour_tiles, AtlasTiles, BtfTile, ColourTile, TileView};
use crate::output::{colour_rows, open_samples, BAND_ROWS};
use crate::quilt::Quilt;
use crate::{Error, Result};

mod camera;
mod scene;
mod shading;
pub use camera::*;
pub use scene::*;
pub(crate) use shading::*;

/// Background colour (linear RGB) where no surface is seen.
pub const BACKGROUND: [f32; 3] = [0.02, 0.02, 0.025];
/// The direction (towards the light) of the default directional light.
pub const DEFAULT_LIGHT: [f32; 3] = [0.4, 0.8, 0.6];
/// Largest image edge in pixels.
pub const MAX_EDGE: usize = 16384;
/// Most frames [`render_frames`] writes.
pub const MAX_FRAMES: usize = 100_000;
/// Below this angle (radians) a direction counts as a measured one.
const EXACT_HIT: f32 = 1e-4;
/// Rings of neighbours searched for a covered texel around an empty one.
const TEXEL_SEARCH: isize = 3;

/// Rings of gutter the colour texture is dilated by (so bilinear lookups at
/// chart borders never blend in the background).
const TEXTURE_DILATION: usize = 4;

/// One render thread's lookups into the scene's shading tiles.
enum Lookup<'a> {
    Colour(TileView<'a, ColourTile>),
    Btf(TileView<'a, BtfTile>),
}

/// What to render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderConfig {
    /// `None`: a three-quarter view framing the mesh ([`Camera::framing`]).
    pub camera: Option<Camera>,
    /// Summed; may be empty (the colour path then shows its ambient term).
    pub lights: Vec<Light>,
    pub width: usize,
    pub height: usize,
    /// Exposure in stops: values are multiplied by `2^exposure`.
    pub exposure: f32,
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            camera: None,
            lights: vec![Light::default()],
            width: 800,
            height: 600,
            exposure: 0.0,
        }
    }
}

impl RenderConfig {
    /// Checks sizes and numbers before any file is opened.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_EDGE).contains(&self.width) || !(1..=MAX_EDGE).contains(&self.height) {
            return Err(Error::Config(format!(
                "--width {} --height {}: each must be 1..={MAX_EDGE} pixels",
                self.width, self.height
            )));
        }
        if !self.exposure.is_finite() || self.exposure.abs() > 64.0 {
            return Err(Error::Config(format!(
                "--exposure {}: expected stops in -64..=64",
                self.exposure
            )));
        }
        if let Some(c) = &self.camera {
            c.check().map_err(|why| {
                Error::Config(format!(
                    "--camera {},{},{},{},{},{},{},{},{},{}: {why}",
                    c.eye[0],
                    c.eye[1],
                    c.eye[2],
                    c.target[0],
                    c.target[1],
                    c.target[2],
                    c.up[0],
                    c.up[1],
                    c.up[2],
                    c.fov
                ))
            })?;
        }
        for l in &self.lights {
            let ok = match *l {
                Light::Directional { direction, intensity } => {
                    direction.iter().all(|v| v.is_finite())
                        && Vec3::from(direction).length_squared() > 1e-12
                        && intensity.is_finite()
                        && intensity >= 0.0
                }
                Light::Point { position, intensity } => {
                    position.iter().all(|v| v.is_finite()) && intensity.is_finite() && intensity >= 0.0
                }
            };
            if !ok {
                return Err(Error::Config(format!(
                    "light {l:?}: needs a finite nonzero direction or position and an intensity ≥ 0"
                )));
            }
        }
        Ok(())
    }
}

/// Refuses output names other than `.png` / `.exr` and missing folders
/// before any work is done.
fn check_output(out: &Path) -> Result<()> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    if !matches!(ext.as_deref(), Some("png") | Some("exr")) {
        return Err(Error::input(out, "can only write .png or .exr images"));
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            return Err(Error::input(out, "its folder does not exist"));
        }
    }
    Ok(())
}

/// Writes `.png` as 8-bit sRGB, `.exr` as linear f16 (both atomically:
/// temporary file + rename, see [`imageio::write_atomic`]).
fn write(out: &Path, img: &RgbImage) -> Result<()> {
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        imageio::write_png(out, img, PngDepth::Eight)
    } else {
        imageio::write_rgb(out, img)
    }
}

/// Renders the decorated mesh of `quilt_path` to `out` (`.png` or `.exr`).
pub fn render(quilt_path: &Path, cfg: &RenderConfig, out: &Path, budget: MemoryBudget) -> Result<()> {
    render_views(quilt_path, &[(cfg.clone(), out.to_path_buf())], budget)
}

/// Renders the decorated mesh of `quilt_path` once per `(config, output)`
/// pair, opening it once: the same files as [`render`] for each pair. All
/// configurations and outputs are checked before anything is drawn; on an
/// error the pictures already written are removed.
pub fn render_views(
    quilt_path: &Path,
    views: &[(RenderConfig, PathBuf)],
    budget: MemoryBudget,
) -> Result<()> {
    for (cfg, out) in views {
        cfg.validate()?;
        check_output(out)?;
    }
    let quilt = Quilt::open(quilt_path, budget)?;
    for (_, out) in views {
        quilt.check_output(out)?;
    }
    drop(quilt);
    let scene = Scene::open(quilt_path, budget)?;
    for (k, (cfg, out)) in views.iter().enumerate() {
        if let Err(e) = scene.render_image(cfg).and_then(|img| write(out, &img)) {
            for (_, p) in &views[..k] {
                let _ = std::fs::remove_file(p);
            }
            return Err(e);
        }
    }
    Ok(())
}

/// The paths [`render_frames`] writes: `STEM_000.EXT … STEM_{N-1}.EXT`
/// beside `out` (more digits when N > 1000, so the names sort).
pub fn frame_paths(out: &Path, frames: usize) -> Vec<PathBuf> {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let ext = out
        .extension()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let digits = frames.saturating_sub(1).to_string().len().max(3);
    (0..frames)
        .map(|k| out.with_file_name(format!("{stem}_{k:0digits$}.{ext}")))
        .collect()
}

/// Renders `frames` images with the first light of `cfg` turned about the
/// camera's view axis in equal steps (frame k by k·360°/frames, frame 0 as
/// given), to [`frame_paths`]`(out, frames)`, which it returns. On an error
/// the frames already written are removed.
pub fn render_frames(
    quilt_path: &Path,
    cfg: &RenderConfig,
    frames: usize,
    out: &Path,
    budget: MemoryBudget,
) -> Result<Vec<PathBuf>> {
    if !(1..=MAX_FRAMES).contains(&frames) {
        return Err(Error::Config(format!(
            "--orbit-light {frames}: expected 1..={MAX_FRAMES} frames"
        )));
    }
    if cfg.lights.is_empty() {
        return Err(Error::Config("--orbit-light: there is no light to move".into()));
    }
    cfg.validate()?;
    check_output(out)?;
    let scene = Scene::open(quilt_path, budget)?;
    let camera = cfg.camera.unwrap_or_else(|| scene.default_camera());
    let paths = frame_paths(out, frames);
    let quilt = Quilt::open(quilt_path, budget)?;
    for p in &paths {
        quilt.check_output(p)?;
    }
    for (k, path) in paths.iter().enumerate() {
        let mut c = cfg.clone();
        c.camera = Some(camera);
        let angle = std::f32::consts::TAU * k as f32 / frames as f32;
        c.lights[0] = cfg.lights[0].orbit(&camera, angle);
        if let Err(e) = scene.render_image(&c).and_then(|img| write(path, &img)) {
            for p in &paths[..k] {
                let _ = std::fs::remove_file(p);
            }
            return Err(e);
        }
    }
    Ok(paths)
}

#[cfg(test)]
mod tests;
