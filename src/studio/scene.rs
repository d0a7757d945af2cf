//! What the studio's viewer draws, built from the same [`Scene`] the CPU
//! renderer shades with, so the browser's picture is the renderer's: the
//! mesh per corner, the atlas's per-texel shading data (the dilated preview
//! colour, or the BTF lookup's sample coordinates and Jacobians), and each
//! sample's factorization (geometry maps g_i and appearance functions p_i,
//! section II-B) laid out as WebGL2 textures. All arrays are little-endian
//! `f32`.

use std::io::{Seek, Write};
use std::path::Path;
use std::sync::Arc;

use serde::Serialize;

use crate::container::MemoryBudget;
use crate::output::render::{Camera, Scene, Shading};
use crate::{Error, Result};

/// Floats per corner in [`Payload::mesh`]: position, normal, atlas uv,
/// ∂P/∂X, ∂P/∂Y and whether the face's frame is valid.
pub const CORNER_FLOATS: usize = 15;
/// Width of the appearance texture in RGBA texels.
pub const APPEARANCE_WIDTH: usize = 2048;

/// One sample's part of [`Payload::basis`].
#[derive(Clone, Debug, Serialize)]
pub struct SampleLayout {
    pub width: usize,
    pub height: usize,
    pub terms: usize,
    /// RGBA layers its g vector takes (⌈terms / 4⌉).
    pub layers: usize,
    /// First layer in the geometry texture array.
    pub first_layer: usize,
    /// First RGBA texel in the appearance texture: pair `q`, channel `c`,
    /// layer `l` is texel `first_texel + (q·3 + c)·layers + l`.
    pub first_texel: usize,
}

/// The viewer's description of a scene (`GET /api/scene`).
#[derive(Clone, Debug, Serialize)]
pub struct SceneInfo {
    pub resolution: usize,
    pub btf: bool,
    /// Factor from the user's units to the positions in [`Payload::mesh`].
    pub unit: f32,
    pub corners: usize,
    /// The renderer's default camera, in the user's units.
    pub camera: CameraJson,
    pub samples: Vec<SampleLayout>,
    /// Geometry texture array size: the largest sample, and its layers.
    pub geometry_size: [usize; 3],
    /// Appearance texture height (its width is [`APPEARANCE_WIDTH`]).
    pub appearance_rows: usize,
    /// Measured view and light directions (unit vectors, sample axes).
    pub views: Vec<[f32; 3]>,
    pub lights: Vec<[f32; 3]>,
    /// cos θ of the largest measured view and light θ.
    pub view_cos_max: f32,
    pub light_cos_max: f32,
}

/// A pinhole camera as JSON.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct CameraJson {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    pub fov: f32,
}

impl From<Camera> for CameraJson {
    fn from(c: Camera) -> Self {
        CameraJson {
            eye: c.eye,
            target: c.target,
            up: c.up,
            fov: c.fov,
        }
    }
}

/// Everything the viewer downloads for one version of the surface.
pub struct Payload {
    pub info: SceneInfo,
    /// Per corner [`CORNER_FLOATS`] floats.
    pub mesh: Arc<Vec<u8>>,
    /// Colour: r² RGBA (dilated linear preview colour, alpha 1). BTF: r²
    /// RGBA (sample x, sample y, sample index, covered) then r² RGBA
    /// (the Jacobian ∂s/∂X, ∂s/∂Y as the renderer reads it). 16 or 32
    /// bytes an atlas texel: kept in a file, not in memory.
    pub texels: Arc<TexelFile>,
    /// BTF only: the geometry texture array (layer, y, x, RGBA; each sample
    /// at its first layer, padded to the largest sample), then the
    /// appearance texture (rows of [`APPEARANCE_WIDTH`] RGBA texels).
    pub basis: Arc<Vec<u8>>,
}

/// [`Payload::texels`]: a hidden file, removed when dropped.
pub struct TexelFile {
    file: tempfile::NamedTempFile,
    len: usize,
}

impl TexelFile {
    /// Bytes in the file.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the file is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// A reader of the file from its start (its own handle).
    pub fn reader(&self) -> Result<std::fs::File> {
        self.file.reopen().map_err(|e| Error::io(self.file.path(), e))
    }
}

/// Writes `f32`s to a file from a byte offset, counting the bytes.
struct Floats<'a> {
    out: std::io::BufWriter<std::fs::File>,
    path: &'a Path,
    len: usize,
}

impl<'a> Floats<'a> {
    /// A writer of its own (an offset of its own) into `file` at `offset`.
    fn at(file: &'a tempfile::NamedTempFile, offset: u64) -> Result<Floats<'a>> {
        let path = file.path();
        let mut handle = file.reopen().map_err(|e| Error::io(path, e))?;
        handle
            .seek(std::io::SeekFrom::Start(offset))
            .map_err(|e| Error::io(path, e))?;
        Ok(Floats {
            out: std::io::BufWriter::with_capacity(1 << 20, handle),
            path,
            len: 0,
        })
    }

    fn push(&mut self, v: f32) -> Result<()> {
        self.out
            .write_all(&v.to_le_bytes())
            .map_err(|e| Error::io(self.path, e))?;
        self.len += 4;
        Ok(())
    }

    /// Flushes; the bytes written.
    fn finish(mut self) -> Result<usize> {
        self.out.flush().map_err(|e| Error::io(self.path, e))?;
        Ok(self.len)
    }
}

fn push(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

impl Payload {
    /// Opens `quilt` as the renderer does and lays out its data; the
    /// texels go to `texels`, a new file ([`TexelFile`]).
    pub fn build(quilt: &Path, budget: MemoryBudget, texels: tempfile::NamedTempFile) -> Result<Payload> {
        let scene = Scene::open(quilt, budget)?;
        Payload::from_scene(&scene, texels)
    }

    fn from_scene(scene: &Scene, texel_file: tempfile::NamedTempFile) -> Result<Payload> {
        let r = scene.resolution;
        let faces = scene.mesh.triangles.len();
        let corner_maps = match &scene.shading {
            Shading::Btf(b) => Some(&b.corner_maps),
            Shading::Colour(_) => None,
        };
        let mut mesh = Vec::with_capacity(faces * 3 * CORNER_FLOATS * 4);
        for (f, tri) in scene.mesh.triangles.iter().enumerate() {
            let maps = corner_maps.map(|m| &m[f * 3..f * 3 + 3]);
            let valid = maps.is_some_and(|m| m.iter().all(Option::is_some));
            for (k, &v) in tri.iter().enumerate() {
                let p = scene.mesh.positions[v as usize];
                let n = scene.normals[v as usize];
                let uv = scene.corner_uv[f * 3 + k];
                let d = maps.and_then(|m| m[k]).unwrap_or([[0.0; 3]; 2]);
                for x in p.into_iter().chain(n).chain(uv).chain(d[0]).chain(d[1]) {
                    push(&mut mesh, x);
                }
                push(&mut mesh, if valid { 1.0 } else { 0.0 });
            }
        }
        let mut texels = Floats::at(&texel_file, 0)?;
        // a BTF's Jacobians, after the other r² RGBA texels
        let mut jacobians = None;
        let mut basis = Vec::new();
        let mut samples = Vec::new();
        let (mut geometry_size, mut appearance_rows) = ([0; 3], 0);
        let (mut views, mut lights, mut view_cos_max, mut light_cos_max) = (Vec::new(), Vec::new(), 1.0, 1.0);
        match &scene.shading {
            Shading::Colour(tiles) => {
                let mut view = tiles.view();
                for t in 0..r * r {
                    let c = view
                        .with(t, |tile, i| [tile.0[i * 3], tile.0[i * 3 + 1], tile.0[i * 3 + 2]])
                        .unwrap_or([0.0; 3]);
                    for x in c.into_iter().chain([1.0]) {
                        texels.push(x)?;
                    }
                }
            }
            Shading::Btf(btf) => {
                let jac = jacobians.insert(Floats::at(&texel_file, (r * r * 16) as u64)?);
                let mut view = btf.tiles.view();
                for t in 0..r * r {
                    let (c, j, s, cov) = view
                        .with(t, |tile, i| {
                            (tile.coord[i], tile.jacobian[i], tile.sample[i], tile.covered[i])
                        })
                        .unwrap_or(([0.0; 2], [1.0, 0.0, 0.0, 1.0], 0, false));
                    for x in [c[0], c[1], s as f32, if cov { 1.0 } else { 0.0 }] {
                        texels.push(x)?;
                    }
                    for x in j {
                        jac.push(x)?;
                    }
                }
                let (w, h) = btf
                    .samples
                    .iter()
                    .fold((0, 0), |(w, h), b| (w.max(b.width), h.max(b.height)));
                let mut layer = 0;
                let mut texel = 0;
                for b in &btf.samples {
                    let layers = b.terms.div_ceil(4);
                    samples.push(SampleLayout {
                        width: b.width,
                        height: b.height,
                        terms: b.terms,
                        layers,
                        first_layer: layer,
                        first_texel: texel,
                    });
                    layer += layers;
                    texel += b.appearance.len() / b.terms * layers;
                }
                geometry_size = [w, h, layer];
                basis.reserve(w * h * layer * 16 + texel.div_ceil(APPEARANCE_WIDTH) * APPEARANCE_WIDTH * 16);
                for b in &btf.samples {
                    for l in 0..b.terms.div_ceil(4) {
                        for y in 0..h {
                            for x in 0..w {
                                for c in 0..4 {
                                    let i = l * 4 + c;
                                    let v = if x < b.width && y < b.height && i < b.terms {
                                        b.geometry[(y * b.width + x) * b.terms + i]
                                    } else {
                                        0.0
                                    };
                                    push(&mut basis, v);
                                }
                            }
                        }
                    }
                }
                for b in &btf.samples {
                    let layers = b.terms.div_ceil(4);
                    for row in b.appearance.chunks_exact(b.terms) {
                        for l in 0..layers {
                            for c in 0..4 {
                                push(&mut basis, row.get(l * 4 + c).copied().unwrap_or(0.0));
                            }
                        }
                    }
                }
                appearance_rows = texel.div_ceil(APPEARANCE_WIDTH).max(1);
                basis.resize(w * h * layer * 16 + appearance_rows * APPEARANCE_WIDTH * 16, 0);
                views = btf.views.dirs.iter().map(|d| d.to_array()).collect();
                lights = btf.lights.dirs.iter().map(|d| d.to_array()).collect();
                view_cos_max = btf.views.cos_max;
                light_cos_max = btf.lights.cos_max;
            }
        }
        let info = SceneInfo {
            resolution: r,
            btf: scene.is_btf(),
            unit: scene.unit,
            corners: faces * 3,
            camera: scene.default_camera().into(),
            samples,
            geometry_size,
            appearance_rows,
            views,
            lights,
            view_cos_max,
            light_cos_max,
        };
        let len = texels.finish()? + jacobians.map_or(Ok(0), Floats::finish)?;
        Ok(Payload {
            info,
            mesh: Arc::new(mesh),
            texels: Arc::new(TexelFile {
                file: texel_file,
                len,
            }),
            basis: Arc::new(basis),
        })
    }
}
