//! The `.quilt` artifact: a decorated surface (section III). Per atlas texel
//! of its geometry image: the sample coordinate, the rotation, the patch id,
//! the seam flags, the Jacobian of the texture mapping and, for a painted
//! surface, which sample the texel draws from; plus the files it depends on
//! (relative paths, lengths and content hashes), once painted, the paint
//! log and, with locked courses, the stripe pattern they follow. The
//! writer is the quilting stage ([`crate::quilt::tile`]).

use std::path::{Path, PathBuf};

use crate::artifact::gim::Gim;
use crate::container::{Container, DType, MemoryBudget, Param};
use crate::{Error, Result};

/// The artifact kind of a decorated surface.
pub const KIND: &str = "quilt";
/// Patch id of an unsynthesized texel.
pub const NO_PATCH: u32 = u32::MAX;

/// One file a decorated surface depends on, as its quilt records it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Dependency {
    /// What it is: `gim`, `sample`, `sample_K` (painted in) or `sample_mask`.
    pub role: String,
    /// Where it is: the recorded path, resolved against the quilt's folder.
    pub path: PathBuf,
    /// Its recorded length in bytes.
    pub bytes: u64,
    /// Its recorded content hash ([`crate::container::file_identity`]).
    pub hash: u64,
}

impl Dependency {
    /// What the role means, for messages.
    pub(crate) fn what(&self) -> String {
        match self.role.as_str() {
            "gim" => "the geometry image".into(),
            "sample" => "the sample".into(),
            "sample_mask" => "the sample's foreground mask".into(),
            r => format!("the sample painted in as '{r}'"),
        }
    }
}

/// The seam flags of a texel ([`Quilt::seams`]): a seam to the +x
/// neighbour in the atlas.
pub const SEAM_X: u8 = 1;
/// A seam to the +y neighbour in the atlas.
pub const SEAM_Y: u8 = 2;
/// A seam across one of the texel's zipper links (to another chart).
pub const SEAM_ZIPPER: u8 = 4;

/// The per-texel state of an atlas region ([`Quilt::texel_region`]).
pub struct QuiltRegion {
    pub coord: Vec<[f32; 2]>,
    pub jacobian: Vec<[f32; 4]>,
    pub patch: Vec<u32>,
    pub rotation: Vec<u8>,
    pub sample: Vec<u8>,
}

/// A decorated surface opened for reading.
pub struct Quilt {
    container: Container,
    pub resolution: usize,
    pub gim: PathBuf,
    /// Every sample its texels draw from: the one it was tiled with first,
    /// then each other sample painted in (see [`Quilt::sample_index`]).
    pub samples: Vec<PathBuf>,
    /// The foreground mask of the last stroke's (or the tiling's) sample, if
    /// one was given.
    pub sample_mask: Option<PathBuf>,
    /// The files it depends on, with what they held when it was written.
    pub dependencies: Vec<Dependency>,
}

impl Quilt {
    /// Opens a `.quilt`.
    pub fn open(path: &Path, budget: MemoryBudget) -> Result<Quilt> {
        let container = Container::open_kind(path, KIND, budget)?;
        let m = container.metadata();
        let mut dependencies = Vec::new();
        let mut dependency = |role: &str| -> Result<PathBuf> {
            let Some(Param::Text(s)) = m.param(role) else {
                return Err(Error::input(
                    path,
                    format!("metadata parameter '{role}' is missing"),
                ));
            };
            let resolved = crate::io::staging::resolve_in_folder_of(path, Path::new(s));
            let bytes = match m.param(&format!("{role}_bytes")) {
                Some(Param::Int(b)) if *b >= 0 => *b as u64,
                _ => {
                    return Err(Error::input(
                        path,
                        format!(
                            "records no size and content hash for its {role} {}: it was written by an older btfquilt; tile it again",
                            resolved.display()
                        ),
                    ))
                }
            };
            let hash = m
                .inputs
                .iter()
                .find(|i| i.name == role)
                .map(|i| i.hash)
                .ok_or_else(|| Error::input(path, format!("records no content hash for its {role}")))?;
            dependencies.push(Dependency {
                role: role.to_string(),
                path: resolved.clone(),
                bytes,
                hash,
            });
            Ok(resolved)
        };
        let resolution = match m.param("resolution") {
            Some(Param::Int(v)) if *v > 0 => *v as usize,
            _ => return Err(Error::input(path, "metadata parameter 'resolution' is missing")),
        };
        // the arrays must match the resolution everything sizes itself by
        let why = format!("parameter 'resolution' is {resolution}");
        let r = resolution as u64;
        for (name, dtype, channels, required) in [
            ("coord", DType::F32, 2, true),
            ("jacobian", DType::F32, 4, false),
            ("rotation", DType::U8, 1, false),
            ("patch", DType::U32, 1, false),
            ("sample", DType::U8, 1, false),
            ("seam", DType::U8, 1, false),
            ("region", DType::F32, 1, false),
        ] {
            if required || container.array(name).is_ok() {
                let shape = if channels == 1 {
                    vec![r, r]
                } else {
                    vec![r, r, channels]
                };
                container.array_shaped(name, dtype, &shape, &why)?;
            }
        }
        if resolution > crate::artifact::gim::MAX_RESOLUTION {
            return Err(Error::input(
                path,
                format!(
                    "parameter 'resolution' is {resolution}, more than the {} an atlas may have",
                    crate::artifact::gim::MAX_RESOLUTION
                ),
            ));
        }
        let gim = dependency("gim")?;
        let sample = dependency("sample")?;
        let count = match m.param("sample_count") {
            None => 1,
            Some(Param::Int(v)) if (1..=MAX_SAMPLES as i64).contains(v) => *v as usize,
            Some(_) => {
                return Err(Error::input(
                    path,
                    "metadata parameter 'sample_count' is out of range",
                ))
            }
        };
        let mut samples = vec![sample];
        for k in 1..count {
            samples.push(dependency(&sample_role(k))?);
        }
        let sample_mask = match m.param("sample_mask") {
            Some(_) => Some(dependency("sample_mask")?),
            None => None,
        };
        Ok(Quilt {
            resolution,
            gim,
            samples,
            sample_mask,
            dependencies,
            container,
        })
    }

    /// The recorded dependency of `role`, if the quilt has one.
    pub fn dependency(&self, role: &str) -> Option<&Dependency> {
        self.dependencies.iter().find(|d| d.role == role)
    }

    /// Checks that the file at `at` (the recorded path, or one the user
    /// gave in its place) is the one the quilt was made from: same length,
    /// same content hash. The error names the quilt and the file.
    pub fn verify(&self, role: &str, at: &Path) -> Result<()> {
        let Some(d) = self.dependency(role) else {
            return Err(Error::input(
                self.container.path(),
                format!("has no '{role}' dependency"),
            ));
        };
        if !at.exists() {
            return Err(Error::input(
                self.container.path(),
                format!("{} {} is gone: put it back", d.what(), at.display()),
            ));
        }
        let (bytes, hash) = crate::container::file_identity(at)?;
        if (bytes, hash) != (d.bytes, d.hash) {
            return Err(Error::input(
                at,
                format!(
                    "is not {} that {} was made from (recorded {} bytes, content {:016x}; found {} bytes, content {:016x}): \
                     put the original back, or decorate again",
                    d.what(),
                    self.container.path().display(),
                    d.bytes,
                    d.hash,
                    bytes,
                    hash
                ),
            ));
        }
        Ok(())
    }

    /// Opens the geometry image (`at`, or the recorded one), after checking
    /// it is the one the quilt was made from.
    pub fn open_gim(&self, at: Option<&Path>, budget: MemoryBudget) -> Result<Gim> {
        let path = at.unwrap_or(&self.gim);
        self.verify("gim", path)?;
        Gim::open(path, budget)
    }

    /// Refuses `out` when it is the quilt or one of the files it depends on.
    pub fn check_output(&self, out: &Path) -> Result<()> {
        let files = self.input_files();
        let inputs: Vec<(&str, &Path)> = files.iter().map(|(r, p)| (r.as_str(), p.as_path())).collect();
        crate::io::staging::check_output(out, &inputs)
    }

    /// Every file the quilt depends on, with its role for messages: what an
    /// output must never overwrite.
    pub fn input_files(&self) -> Vec<(String, PathBuf)> {
        self.dependencies
            .iter()
            .map(|d| (d.what(), d.path.clone()))
            .chain(std::iter::once((
                "the decorated surface".to_string(),
                self.container.path().to_path_buf(),
            )))
            .collect()
    }

    /// The container underneath.
    pub fn container(&self) -> &Container {
        &self.container
    }

    /// Per texel sample coordinates (unrotated sample pixels).
    pub fn coords(&self) -> Result<Vec<[f32; 2]>> {
        let v: Vec<f32> = self.container.read_array(self.container.array("coord")?)?;
        Ok(v.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
    }

    /// Per texel patch ids ([`NO_PATCH`] where empty).
    pub fn patches(&self) -> Result<Vec<u32>> {
        self.container.read_array(self.container.array("patch")?)
    }

    /// Per texel sample offset per atlas step: `[dx/dX, dy/dX, dx/dY, dy/dY]`
    /// (sample pixels per atlas texel along +X, then along +Y; y down in
    /// both), the local frame that maps the sample onto the surface.
    pub fn jacobians(&self) -> Result<Vec<[f32; 4]>> {
        let v: Vec<f32> = self.container.read_array(self.container.array("jacobian")?)?;
        Ok(v.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect())
    }

    /// Per texel rotation index.
    pub fn rotations(&self) -> Result<Vec<u8>> {
        self.container.read_array(self.container.array("rotation")?)
    }

    /// Per texel seam flags ([`SEAM_X`], [`SEAM_Y`], [`SEAM_ZIPPER`]): where
    /// the patches meet.
    pub fn seams(&self) -> Result<Vec<u8>> {
        self.container.read_array(self.container.array("seam")?)
    }

    /// Per texel index into [`Quilt::samples`] (all 0 for a surface that
    /// draws from one sample, which stores no such array).
    pub fn sample_index(&self) -> Result<Vec<u8>> {
        let texels = self.resolution * self.resolution;
        let Ok(id) = self.container.array("sample") else {
            return Ok(vec![0; texels]);
        };
        let v: Vec<u8> = self.container.read_array(id)?;
        if v.len() != texels || v.iter().any(|&k| k as usize >= self.samples.len()) {
            return Err(Error::input(
                self.container.path(),
                format!(
                    "its sample indices do not match its {} samples",
                    self.samples.len()
                ),
            ));
        }
        Ok(v)
    }

    /// The per-texel state of the atlas region `(x0, y0, w, h)`, each plane
    /// row-major (sample indices checked against the samples, all 0 for a
    /// surface of one sample).
    pub fn texel_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<QuiltRegion> {
        let jacobian = self
            .jacobian_region(x0, y0, w, h)?
            .ok_or_else(|| Error::input(self.container.path(), "it stores no 'jacobian' array"))?;
        Ok(QuiltRegion {
            coord: self.coord_region(x0, y0, w, h)?,
            jacobian,
            patch: self.patch_region(x0, y0, w, h)?,
            rotation: self.rotation_region(x0, y0, w, h)?,
            sample: self.sample_region(x0, y0, w, h)?,
        })
    }

    /// The sample coordinates of the atlas region `(x0, y0, w, h)`, row-major.
    pub fn coord_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Vec<[f32; 2]>> {
        let c = &self.container;
        let v: Vec<f32> = c.read_region(
            c.array("coord")?,
            &[y0 as u64, x0 as u64, 0],
            &[h as u64, w as u64, 2],
        )?;
        Ok(v.chunks_exact(2).map(|v| [v[0], v[1]]).collect())
    }

    /// The stored Jacobians of the atlas region `(x0, y0, w, h)`, row-major
    /// (`None` for a quilt that stores none).
    pub fn jacobian_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Option<Vec<[f32; 4]>>> {
        let c = &self.container;
        let Ok(id) = c.array("jacobian") else {
            return Ok(None);
        };
        let v: Vec<f32> = c.read_region(id, &[y0 as u64, x0 as u64, 0], &[h as u64, w as u64, 4])?;
        Ok(Some(
            v.chunks_exact(4).map(|v| [v[0], v[1], v[2], v[3]]).collect(),
        ))
    }

    /// The patch ids of the atlas region `(x0, y0, w, h)`, row-major.
    pub fn patch_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Vec<u32>> {
        let c = &self.container;
        c.read_region(c.array("patch")?, &[y0 as u64, x0 as u64], &[h as u64, w as u64])
    }

    /// The rotation indices of the atlas region `(x0, y0, w, h)`, row-major.
    pub fn rotation_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Vec<u8>> {
        let c = &self.container;
        c.read_region(
            c.array("rotation")?,
            &[y0 as u64, x0 as u64],
            &[h as u64, w as u64],
        )
    }

    /// The constraint function m0 of the last stroke (§IV) over the atlas
    /// region `(x0, y0, w, h)`, row-major (`None` for a surface that was not
    /// painted).
    pub fn constraint_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Option<Vec<f32>>> {
        let c = &self.container;
        let Ok(id) = c.array("region") else {
            return Ok(None);
        };
        Ok(Some(c.read_region(
            id,
            &[y0 as u64, x0 as u64],
            &[h as u64, w as u64],
        )?))
    }

    /// The sample indices of the atlas region `(x0, y0, w, h)`, row-major,
    /// checked against the samples (all 0 for a surface of one sample).
    pub fn sample_region(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Vec<u8>> {
        let c = &self.container;
        let sample = match c.array("sample") {
            Ok(id) => c.read_region(id, &[y0 as u64, x0 as u64], &[h as u64, w as u64])?,
            Err(_) => vec![0u8; w * h],
        };
        if sample.iter().any(|&k| k as usize >= self.samples.len()) {
            return Err(Error::input(
                c.path(),
                format!(
                    "its sample indices do not match its {} samples",
                    self.samples.len()
                ),
            ));
        }
        Ok(sample)
    }

    /// Whether the surface was tiled with locked courses (`tile --courses
    /// locked`): its courses follow the stripe pattern of its atlas's field
    /// at the tiling sample's course period, and painting with that sample
    /// locks its strokes to the same pattern.
    pub fn locked_courses(&self) -> bool {
        matches!(self.container.metadata().param("courses"), Some(Param::Text(s)) if s == "locked")
    }

    /// The stripe pattern a surface tiled or painted with locked courses
    /// stores: its row spacing (mesh units) and ψ per vertex of its
    /// subdivided mesh ([`crate::field::StripePattern::from_psi`]); `None`
    /// when the quilt holds none.
    pub fn stripe_pattern(&self) -> Result<Option<(f64, Vec<f32>)>> {
        let Some((period, id)) = self.stored_stripe_pattern() else {
            return Ok(None);
        };
        Ok(Some((period, self.container.read_array(id)?)))
    }

    /// Whether the quilt stores a stripe pattern ([`Quilt::stripe_pattern`]),
    /// without reading it.
    pub fn stores_stripe_pattern(&self) -> bool {
        self.stored_stripe_pattern().is_some()
    }

    fn stored_stripe_pattern(&self) -> Option<(f64, crate::container::ArrayId)> {
        let c = &self.container;
        match (c.metadata().param("stripe_period"), c.array("stripe_psi")) {
            (Some(Param::Float(period)), Ok(id)) => Some((*period, id)),
            _ => None,
        }
    }

    /// Sample `k`'s file ([`Quilt::samples`] order), after checking it is
    /// the one the quilt was made from ([`Quilt::verify`]).
    pub fn sample_file(&self, k: usize) -> Result<&Path> {
        self.verify(&sample_role(k), &self.samples[k])?;
        Ok(&self.samples[k])
    }

    /// The width (mesh units) sample `k` ([`Quilt::samples`] order) was
    /// given on the surface (`--sample-width` or `--sample-pixel`); `None`
    /// when it was given none (one sample pixel per texel).
    pub fn sample_span(&self, k: usize) -> Option<f64> {
        match self
            .container
            .metadata()
            .param(&format!("{}_span", sample_role(k)))
        {
            Some(Param::Float(v)) => Some(*v),
            _ => None,
        }
    }

    /// Which sample the recorded `sample_mask` belongs to (the last painted
    /// stroke's sample; 0 for a tiling).
    pub fn mask_sample(&self) -> usize {
        match self.container.metadata().param("mask_sample") {
            Some(Param::Int(v)) if *v >= 0 => *v as usize,
            _ => 0,
        }
    }
}

/// The role under which a quilt records sample `k`: `sample` for the
/// tiling's, `sample_K` for one painted in.
pub(crate) fn sample_role(k: usize) -> String {
    if k == 0 {
        "sample".to_string()
    } else {
        format!("sample_{k}")
    }
}

/// How many samples one surface may draw from (the tiling's and those
/// painted in), so a texel's sample index fits a byte.
pub const MAX_SAMPLES: usize = 255;
