//! The BTF artifact: RGB values f(x, v, l) for W×H texels and every pair of a
//! view-direction list and a light-direction list (docs/design.md sections 2-3).
//!
//! Arrays:
//! - `view_dirs`, `light_dirs`: f32 `[n, 2]`, (θ, φ) in degrees;
//! - `rgb`: f16 `[H, W, P, 3]`, linear radiance, `P = n_views · n_lights`,
//!   pair `p = v · n_lights + l`; chunked as texel tiles × direction bands
//!   (`[tile, tile, band, 3]`), so both "every direction of one texel tile"
//!   and "one direction's full image" are read with bounded memory.

use std::ops::Range;
use std::path::Path;

use half::f16;
use half::slice::HalfFloatSliceExt;

use crate::container::{
    ArrayId, ArraySpec, Container, ContainerWriter, DType, EncodedChunk, MemoryBudget, Param,
};
pub use crate::io::naming::Angles;
use crate::{Error, Result};

/// The artifact kind string of a BTF.
pub const KIND: &str = "btf";
/// Default texel tile edge of the `rgb` chunks.
pub const DEFAULT_TILE: usize = 16;

/// The paper's direction grid: 12 azimuths φ ∈ {0, 30, …, 330}° × 8 polar
/// angles θ ∈ {5, 15, …, 75}°, sorted by θ then φ (96 directions).
pub fn default_grid() -> Vec<Angles> {
    grid(12, 8, 75.0)
}

/// A grid of `n_phi` azimuths × `n_theta` polar angles, θ evenly spaced with
/// half-step offsets up to `theta_max` (θ_k = (k + ½)·θ_max/(n_θ − ½)).
pub fn grid(n_phi: usize, n_theta: usize, theta_max: f32) -> Vec<Angles> {
    let step = if n_theta > 1 {
        theta_max / (n_theta as f32 - 0.5)
    } else {
        0.0
    };
    let mut out = Vec::with_capacity(n_phi * n_theta);
    for t in 0..n_theta {
        let theta = if n_theta > 1 { (t as f32 + 0.5) * step } else { 0.0 };
        for p in 0..n_phi {
            out.push(Angles {
                theta,
                phi: 360.0 * p as f32 / n_phi as f32,
            });
        }
    }
    out
}

/// Parses a grid spec like `12x8` (φ × θ) into [`grid`] up to 75°.
pub fn parse_grid(spec: &str) -> Result<Vec<Angles>> {
    let bad = || Error::Config(format!("direction grid '{spec}': expected PHIxTHETA like 12x8"));
    let (a, b) = spec.split_once(['x', 'X']).ok_or_else(bad)?;
    let n_phi: usize = a.trim().parse().map_err(|_| bad())?;
    let n_theta: usize = b.trim().parse().map_err(|_| bad())?;
    if n_phi == 0 || n_theta == 0 || n_phi * n_theta > 100_000 {
        return Err(bad());
    }
    Ok(grid(n_phi, n_theta, 75.0))
}

/// Shape and chunking of a BTF.
#[derive(Clone, Debug, PartialEq)]
pub struct BtfLayout {
    pub width: usize,
    pub height: usize,
    pub views: Vec<Angles>,
    pub lights: Vec<Angles>,
    /// Texel tile edge.
    pub tile: usize,
    /// Direction pairs per chunk.
    pub band: usize,
}

impl BtfLayout {
    /// A layout with the default tile and one view's lights per band.
    pub fn new(width: usize, height: usize, views: Vec<Angles>, lights: Vec<Angles>) -> BtfLayout {
        let band = lights.len().clamp(1, 256);
        BtfLayout {
            width,
            height,
            views,
            lights,
            tile: DEFAULT_TILE,
            band,
        }
    }

    /// Number of (view, light) pairs.
    pub fn pairs(&self) -> usize {
        self.views.len() * self.lights.len()
    }

    /// Pair index of (view index, light index).
    pub fn pair(&self, view: usize, light: usize) -> usize {
        view * self.lights.len() + light
    }

    /// Tiles across and down.
    pub fn tiles(&self) -> (usize, usize) {
        (self.width.div_ceil(self.tile), self.height.div_ceil(self.tile))
    }

    /// Number of direction bands.
    pub fn bands(&self) -> usize {
        self.pairs().div_ceil(self.band)
    }

    /// Raw size of the `rgb` array in bytes (f16).
    pub fn raw_bytes(&self) -> u64 {
        (self.width * self.height * self.pairs() * 3 * 2) as u64
    }

    /// The `rgb` array spec.
    pub fn rgb_spec(&self) -> ArraySpec {
        let t = self.tile as u64;
        ArraySpec::new(
            "rgb",
            DType::F16,
            &[self.height as u64, self.width as u64, self.pairs() as u64, 3],
            &[t, t, self.band as u64, 3],
        )
        .expect("rgb spec is well-formed")
    }

    /// Linear chunk index of (tile x, tile y, band).
    pub fn chunk(&self, tx: usize, ty: usize, band: usize) -> u64 {
        let (ntx, _) = self.tiles();
        (((ty * ntx + tx) * self.bands()) + band) as u64
    }

    fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::Config("a BTF needs at least one texel".into()));
        }
        if self.views.is_empty() || self.lights.is_empty() {
            return Err(Error::Config(
                "a BTF needs at least one view and one light direction".into(),
            ));
        }
        if self.tile == 0 || self.band == 0 {
            return Err(Error::Config("tile and band must be positive".into()));
        }
        for (what, dirs) in [("view", &self.views), ("light", &self.lights)] {
            for (i, a) in dirs.iter().enumerate() {
                if !(0.0..=90.0).contains(&a.theta) || !(0.0..360.0).contains(&a.phi) {
                    return Err(Error::Config(format!(
                        "{what} direction {i} (θ {}, φ {}) is outside θ∈[0,90], φ∈[0,360)",
                        a.theta, a.phi
                    )));
                }
                if dirs[..i].iter().any(|b| same_direction(*a, *b)) {
                    return Err(Error::Config(format!(
                        "{what} direction {i} (θ {}, φ {}) is listed twice",
                        a.theta, a.phi
                    )));
                }
            }
        }
        Ok(())
    }
}

/// Whether two angle pairs name the same direction (the pole θ = 0 has one φ).
pub fn same_direction(a: Angles, b: Angles) -> bool {
    (a.theta - b.theta).abs() < 1e-3 && (a.theta.abs() < 1e-3 || (a.phi - b.phi).abs() < 1e-3)
}

fn dirs_to_f32(d: &[Angles]) -> Vec<f32> {
    d.iter().flat_map(|a| [a.theta, a.phi]).collect()
}

/// Streams a BTF artifact to disk, one `rgb` chunk at a time.
pub struct BtfWriter {
    writer: ContainerWriter,
    rgb: ArrayId,
    layout: BtfLayout,
}

impl BtfWriter {
    /// Starts a BTF at `path` (written to a temporary file until [`finish`](Self::finish)).
    pub fn create(path: &Path, layout: BtfLayout) -> Result<BtfWriter> {
        layout.validate()?;
        let mut writer = ContainerWriter::create(path, KIND)?;
        writer.set_param("width", Param::Int(layout.width as i64));
        writer.set_param("height", Param::Int(layout.height as i64));
        writer.set_param("views", Param::Int(layout.views.len() as i64));
        writer.set_param("lights", Param::Int(layout.lights.len() as i64));
        writer.set_param("color_space", Param::Text("linear".into()));
        for (name, dirs) in [("view_dirs", &layout.views), ("light_dirs", &layout.lights)] {
            let n = dirs.len() as u64;
            let id = writer.add_array(ArraySpec::new(name, DType::F32, &[n, 2], &[n, 2])?)?;
            writer.write_array(id, &dirs_to_f32(dirs))?;
        }
        let rgb = writer.add_array(layout.rgb_spec())?;
        Ok(BtfWriter { writer, rgb, layout })
    }

    /// The layout being written.
    pub fn layout(&self) -> &BtfLayout {
        &self.layout
    }

    /// The underlying container writer (seed, params, input hashes).
    pub fn container(&mut self) -> &mut ContainerWriter {
        &mut self.writer
    }

    /// Writes the chunk of tile (tx, ty) and band `band`, already encoded; its
    /// elements are `[tile_h][tile_w][band_len][3]` f16.
    pub fn write_encoded(&mut self, tx: usize, ty: usize, band: usize, chunk: EncodedChunk) -> Result<()> {
        let c = self.layout.chunk(tx, ty, band);
        self.writer.write_encoded(self.rgb, c, chunk)
    }

    /// Writes the chunk of tile (tx, ty) and band `band`.
    pub fn write_tile_band(&mut self, tx: usize, ty: usize, band: usize, values: &[f16]) -> Result<()> {
        let c = self.layout.chunk(tx, ty, band);
        self.writer.write_chunk(self.rgb, c, values)
    }

    /// Completes the file and renames it into place.
    pub fn finish(self) -> Result<()> {
        self.writer.finish()
    }
}

/// A BTF artifact opened for reading.
pub struct Btf {
    container: Container,
    layout: BtfLayout,
    rgb: ArrayId,
}

/// The directions array `name` (f32 [n, 2] of θ, φ) of an artifact at `path`.
pub(crate) fn read_directions(container: &Container, path: &Path, name: &str) -> Result<Vec<Angles>> {
    let id = container.array(name)?;
    let spec = container.spec(id);
    if spec.dtype != DType::F32 || spec.shape.len() != 2 || spec.shape[1] != 2 {
        return Err(Error::input(path, format!("array '{name}' must be f32 [n, 2]")));
    }
    let v: Vec<f32> = container.read_array(id)?;
    Ok(v.chunks_exact(2)
        .map(|a| Angles {
            theta: a[0],
            phi: a[1],
        })
        .collect())
}

impl Btf {
    /// Opens a BTF, checking kind and array shapes.
    pub fn open(path: &Path, budget: MemoryBudget) -> Result<Btf> {
        let container = Container::open_kind(path, KIND, budget)?;
        let views = read_directions(&container, path, "view_dirs")?;
        let lights = read_directions(&container, path, "light_dirs")?;
        let rgb = container.array("rgb")?;
        let spec = container.spec(rgb).clone();
        let ok = spec.dtype == DType::F16
            && spec.shape.len() == 4
            && spec.shape[2] == (views.len() * lights.len()) as u64
            && spec.shape[3] == 3
            && spec.chunk_shape[0] == spec.chunk_shape[1]
            && spec.chunk_shape[3] == 3;
        if !ok {
            return Err(Error::input(
                path,
                format!(
                    "array 'rgb' has dtype {} shape {:?} chunks {:?}, expected f16 [H, W, {}, 3] in square tiles",
                    spec.dtype.name(),
                    spec.shape,
                    spec.chunk_shape,
                    views.len() * lights.len()
                ),
            ));
        }
        let layout = BtfLayout {
            width: spec.shape[1] as usize,
            height: spec.shape[0] as usize,
            views,
            lights,
            tile: spec.chunk_shape[0] as usize,
            band: spec.chunk_shape[2] as usize,
        };
        Ok(Btf {
            container,
            layout,
            rgb,
        })
    }

    /// The layout.
    pub fn layout(&self) -> &BtfLayout {
        &self.layout
    }

    /// The underlying container.
    pub fn container(&self) -> &Container {
        &self.container
    }

    /// Index of the pair whose view and light match the given angles
    /// (within 1e-3°); the error lists what the BTF has.
    pub fn find_pair(&self, view: Angles, light: Angles) -> Result<usize> {
        let find = |dirs: &[Angles], a: Angles, what: &str| {
            dirs.iter().position(|d| same_direction(*d, a)).ok_or_else(|| {
                Error::input(
                    self.container.path(),
                    format!(
                        "has no {what} direction θ {} φ {} (it has {} {what} directions, e.g. θ {} φ {})",
                        a.theta,
                        a.phi,
                        dirs.len(),
                        dirs[0].theta,
                        dirs[0].phi
                    ),
                )
            })
        };
        let v = find(&self.layout.views, view, "view")?;
        let l = find(&self.layout.lights, light, "light")?;
        Ok(self.layout.pair(v, l))
    }

    /// Values of a range of pairs for every texel, as f32 images:
    /// `[pair][y][x][rgb]`. Decodes only the bands the range touches.
    pub fn read_pair_images(&self, pairs: Range<usize>) -> Result<Vec<f32>> {
        let l = &self.layout;
        let k = pairs.len();
        let region: Vec<f16> = self.container.read_region(
            self.rgb,
            &[0, 0, pairs.start as u64, 0],
            &[l.height as u64, l.width as u64, k as u64, 3],
        )?;
        let mut values = vec![0f32; region.len()];
        region.convert_to_f32_slice(&mut values);
        let texels = l.width * l.height;
        let mut out = vec![0f32; k * texels * 3];
        for t in 0..texels {
            for p in 0..k {
                let (src, dst) = ((t * k + p) * 3, (p * texels + t) * 3);
                out[dst..dst + 3].copy_from_slice(&values[src..src + 3]);
            }
        }
        Ok(out)
    }

    /// One pair's values over a rectangle of texels (`x0`, `y0`, `w` × `h`)
    /// as f32: `[y][x][rgb]`. Decodes only the chunks it touches.
    pub fn read_pair_rect(
        &self,
        pair: usize,
        (x0, y0, w, h): (usize, usize, usize, usize),
    ) -> Result<Vec<f32>> {
        let region: Vec<f16> = self.container.read_region(
            self.rgb,
            &[y0 as u64, x0 as u64, pair as u64, 0],
            &[h as u64, w as u64, 1, 3],
        )?;
        let mut values = vec![0f32; region.len()];
        region.convert_to_f32_slice(&mut values);
        Ok(values)
    }

    /// Every direction pair of one texel tile: `[y][x][pair][rgb]` over the
    /// tile's clipped extent, with that extent (w, h).
    pub fn read_tile(&self, tx: usize, ty: usize) -> Result<(Vec<f16>, usize, usize)> {
        let l = &self.layout;
        let x0 = tx * l.tile;
        let y0 = ty * l.tile;
        let w = l.tile.min(l.width - x0);
        let h = l.tile.min(l.height - y0);
        let v = self.container.read_region(
            self.rgb,
            &[y0 as u64, x0 as u64, 0, 0],
            &[h as u64, w as u64, l.pairs() as u64, 3],
        )?;
        Ok((v, w, h))
    }
}
