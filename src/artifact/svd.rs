//! The `.svd` artifact: a factorized sample (section II-B). Arrays: the n
//! geometry maps g_i (and their rotated copies with validity masks) over the
//! sample's texels, the eigen point appearance functions p_i over the
//! direction pairs, the view and light directions, and a preview image. The
//! writer is [`crate::factorize::factorize`].

use std::path::Path;

use half::f16;

use crate::artifact::btf::{Angles, Btf};
use crate::container::{Container, DType, MemoryBudget, Param};
use crate::io::imageio::{self, is_image_path, RgbImage};
use crate::{Error, Result};

/// The artifact kind of a factorized sample.
pub const KIND: &str = "svd";

/// A factorization opened for reading.
pub struct SvdArtifact {
    container: Container,
    pub width: usize,
    pub height: usize,
    pub terms: usize,
    pub views: Vec<Angles>,
    pub lights: Vec<Angles>,
    pub rotations: usize,
}

impl SvdArtifact {
    /// Whether the sample was factorized `--tileable` (its lookups wrap
    /// round its borders).
    pub fn tileable(&self) -> bool {
        matches!(self.container().metadata().param("tileable"), Some(Param::Int(1)))
    }

    /// Opens a `.svd`, checking its kind and arrays.
    pub fn open(path: &Path, budget: MemoryBudget) -> Result<SvdArtifact> {
        let container = Container::open_kind(path, KIND, budget)?;
        let int = |name: &str| match container.metadata().param(name) {
            Some(Param::Int(v)) if *v >= 0 => Ok(*v as usize),
            _ => Err(Error::input(
                path,
                format!("metadata parameter '{name}' is missing"),
            )),
        };
        let (width, height, terms, rotations) =
            (int("width")?, int("height")?, int("terms")?, int("rotations")?);
        let dirs = |name: &str| crate::artifact::btf::read_directions(&container, path, name);
        let (views, lights) = (dirs("view_dirs")?, dirs("light_dirs")?);
        let g = container.spec(container.array("geometry_maps")?);
        let p = container.spec(container.array("appearance")?);
        if g.shape != [height as u64, width as u64, terms as u64]
            || p.shape != [(views.len() * lights.len()) as u64, 3, terms as u64]
        {
            return Err(Error::input(
                path,
                "geometry_maps/appearance shapes disagree with the metadata",
            ));
        }
        let (h, w, n, r) = (height as u64, width as u64, terms as u64, rotations as u64);
        let why = format!("parameters width {width}, height {height}, terms {terms}, rotations {rotations}");
        container.array_shaped("singular_values", DType::F32, &[n], &why)?;
        container.array_shaped("preview", DType::F32, &[h, w, 3], &why)?;
        if rotations > 0 {
            container.array_shaped("rotated_maps", DType::F16, &[r, h, w, n], &why)?;
            container.array_shaped("rotated_valid", DType::U8, &[r, h, w], &why)?;
        }
        Ok(SvdArtifact {
            container,
            width,
            height,
            terms,
            views,
            lights,
            rotations,
        })
    }

    /// The container underneath.
    pub fn container(&self) -> &Container {
        &self.container
    }

    /// Geometry maps g_i(x) = σ_i u_i(x): `[y][x][i]`.
    pub fn geometry_maps(&self) -> Result<Vec<f32>> {
        self.container.read_array(self.container.array("geometry_maps")?)
    }

    /// Appearance functions p_i: `[pair][rgb][i]`.
    pub fn appearance(&self) -> Result<Vec<f32>> {
        self.container.read_array(self.container.array("appearance")?)
    }

    /// Singular values σ_i.
    pub fn singular_values(&self) -> Result<Vec<f32>> {
        self.container
            .read_array(self.container.array("singular_values")?)
    }

    /// The preview colour (front-parallel view, head-on light): `[y][x][rgb]`.
    pub fn preview(&self) -> Result<RgbImage> {
        Ok(RgbImage {
            width: self.width,
            height: self.height,
            data: self.container.read_array(self.container.array("preview")?)?,
        })
    }

    /// The mean luminance of each row of the preview colour (Rec. 709
    /// weights), read 64 rows at a time.
    pub fn preview_row_means(&self) -> Result<Vec<f64>> {
        let array = self.container.array("preview")?;
        let (w, h) = (self.width as u64, self.height as u64);
        let mut means = Vec::with_capacity(self.height);
        for y0 in (0..h).step_by(64) {
            let rows = 64.min(h - y0);
            let band: Vec<f32> = self.container.read_region(array, &[y0, 0, 0], &[rows, w, 3])?;
            means.extend(
                band.chunks_exact(3 * w as usize)
                    .map(crate::io::imageio::row_luminance),
            );
        }
        Ok(means)
    }

    /// Rotated copy `r` (r·360°/R): maps `[y][x][i]` and validity `[y][x]`.
    pub fn rotated(&self, r: usize) -> Result<(Vec<f16>, Vec<u8>)> {
        self.rotated_rect(r, (0, 0, self.width, self.height))
    }

    /// Rows of the rotated copies' chunks: a rectangle read in bands of
    /// whole chunk rows decodes each chunk once.
    pub fn rotated_band_rows(&self) -> Result<usize> {
        let id = self.container.array("rotated_maps")?;
        Ok(self.container.spec(id).chunk_shape[1].max(1) as usize)
    }

    /// The rectangle `(x, y, w, h)` of rotated copy `r`, decoding only the
    /// chunks it touches.
    pub fn rotated_rect(&self, r: usize, rect: (usize, usize, usize, usize)) -> Result<(Vec<f16>, Vec<u8>)> {
        if r >= self.rotations {
            return Err(Error::Config(format!("rotation {r} of {}", self.rotations)));
        }
        let (x, y, w, h) = (rect.0 as u64, rect.1 as u64, rect.2 as u64, rect.3 as u64);
        let maps = self.container.read_region(
            self.container.array("rotated_maps")?,
            &[r as u64, y, x, 0],
            &[1, h, w, self.terms as u64],
        )?;
        let valid = self.container.read_region(
            self.container.array("rotated_valid")?,
            &[r as u64, y, x],
            &[1, h, w],
        )?;
        Ok((maps, valid))
    }

    /// Index of a (view, light) pair.
    pub fn find_pair(&self, view: Angles, light: Angles) -> Result<usize> {
        let find = |d: &[Angles], a: Angles, what: &str| {
            d.iter()
                .position(|x| crate::artifact::btf::same_direction(*x, a))
                .ok_or_else(|| {
                    Error::input(
                        self.container.path(),
                        format!("has no {what} direction θ {} φ {}", a.theta, a.phi),
                    )
                })
        };
        Ok(find(&self.views, view, "view")? * self.lights.len() + find(&self.lights, light, "light")?)
    }

    /// Reconstructs one direction pair: Σ_i g_i(x) p_i(pair, c).
    pub fn reconstruct_pair(&self, pair: usize) -> Result<RgbImage> {
        let g = self.geometry_maps()?;
        let n = self.terms as u64;
        let p: Vec<f32> = self.container.read_region(
            self.container.array("appearance")?,
            &[pair as u64, 0, 0],
            &[1, 3, n],
        )?;
        let (n, p) = (self.terms, &p);
        let data = g
            .chunks_exact(n)
            .flat_map(|gx| {
                (0..3).map(move |c| {
                    gx.iter()
                        .zip(&p[c * n..(c + 1) * n])
                        .map(|(a, b)| a * b)
                        .sum::<f32>()
                })
            })
            .collect();
        Ok(RgbImage {
            width: self.width,
            height: self.height,
            data,
        })
    }

    /// The original image of a pair, from the source the `.svd` was made of
    /// (or `original` if given); `None` if the source is gone or changed.
    pub fn original_pair(
        &self,
        pair: usize,
        original: Option<&Path>,
        budget: MemoryBudget,
    ) -> Result<Option<RgbImage>> {
        let meta = self.container.metadata();
        let recorded = meta.inputs.first().map(|i| i.hash);
        let source = match (original, meta.param("source")) {
            (Some(p), _) => p.to_path_buf(),
            (None, Some(Param::Text(s))) => {
                // recorded relative to the factorization's folder
                crate::io::staging::resolve_in_folder_of(self.container.path(), Path::new(s))
            }
            _ => return Ok(None),
        };
        if !source.exists() {
            return Ok(None);
        }
        if is_image_path(&source) {
            return imageio::read_rgb_within(&source, budget.bytes()).map(Some);
        }
        let btf = Btf::open(&source, budget)?;
        if original.is_none() && Some(btf.container().content_hash()) != recorded {
            return Ok(None);
        }
        let l = btf.layout();
        Ok(Some(RgbImage {
            width: l.width,
            height: l.height,
            data: btf.read_pair_images(pair..pair + 1)?,
        }))
    }
}

/// Errors unless `b` was measured over the same view and light directions
/// as `a` (painting and rendering mix their values per texel).
pub fn same_directions(a: &SvdArtifact, b: &SvdArtifact) -> Result<()> {
    let same = |x: &[crate::artifact::btf::Angles], y: &[crate::artifact::btf::Angles]| {
        x.len() == y.len()
            && x.iter()
                .zip(y)
                .all(|(p, q)| crate::artifact::btf::same_direction(*p, *q))
    };
    if same(&a.views, &b.views) && same(&a.lights, &b.lights) {
        Ok(())
    } else {
        Err(Error::input(
            b.container().path(),
            format!(
                "has {}×{} view/light directions, not the {}×{} of {}: samples on one surface must share \
                 their direction set (colour images with colour images)",
                b.views.len(),
                b.lights.len(),
                a.views.len(),
                a.lights.len(),
                a.container().path().display()
            ),
        ))
    }
}
