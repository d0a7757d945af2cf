//! The `.quilt` artifact: writing it (with its recorded dependencies) and
//! reading it back.

#[allow(unused_imports)]
use super::*;

/// Writes the synthesis state as a `.quilt`; `paint_log` (a JSON array of
/// strokes) when the surface was painted.
pub(super) fn write_quilt(
    out: &Path,
    cfg: &TileConfig,
    gim: &Gim,
    gim_path: &Path,
    syn: &Synthesis,
    paint_log: Option<&str>,
    report: &TileReport,
) -> Result<()> {
    let (sample, state) = (&syn.sample, &syn.state);
    let r = gim.resolution as u64;
    let t = TILE as u64;
    let mut w = ContainerWriter::create(out, KIND)?;
    w.set_level(cfg.level);
    w.set_seed(cfg.seed);
    record_dependency(&mut w, out, "gim", gim_path)?;
    let paths = &syn.sample_paths;
    record_dependency(&mut w, out, "sample", &paths[0])?;
    if paths.len() > 1 {
        w.set_param("sample_count", Param::Int(paths.len() as i64));
        for (k, p) in paths.iter().enumerate().skip(1) {
            record_dependency(&mut w, out, &format!("sample_{k}"), p)?;
        }
    }
    if let Some(mask) = &cfg.sample_mask {
        record_dependency(&mut w, out, "sample_mask", mask)?;
        if state.active > 0 {
            w.set_param("mask_sample", Param::Int(state.active as i64));
        }
    }
    if let Some(log) = paint_log {
        w.set_param("paint_log", Param::Text(log.to_string()));
    }
    w.set_param("resolution", Param::Int(r as i64));
    w.set_param("sample_width", Param::Int(sample.width as i64));
    w.set_param("sample_height", Param::Int(sample.height as i64));
    w.set_param("terms", Param::Int(sample.n as i64));
    w.set_param("rotations", Param::Int(sample.rotations as i64));
    w.set_param("patches", Param::Int(state.next_patch as i64));
    w.set_param("mean_seam_cost", Param::Float(report.mean_seam_cost));
    let coord: Vec<f32> = state.coord.iter().flatten().copied().collect();
    let id = w.add_array(ArraySpec::new("coord", DType::F32, &[r, r, 2], &[t, t, 2])?)?;
    w.write_array(id, &coord)?;
    let jacobian: Vec<f32> = state.jacobian.iter().flatten().copied().collect();
    let id = w.add_array(ArraySpec::new("jacobian", DType::F32, &[r, r, 4], &[t, t, 4])?)?;
    w.write_array(id, &jacobian)?;
    let id = w.add_array(ArraySpec::new("rotation", DType::U8, &[r, r], &[t, t])?)?;
    w.write_array(id, &state.rotation)?;
    let id = w.add_array(ArraySpec::new("patch", DType::U32, &[r, r], &[t, t])?)?;
    w.write_array(id, &state.patch)?;
    if paths.len() > 1 {
        let id = w.add_array(ArraySpec::new("sample", DType::U8, &[r, r], &[t, t])?)?;
        w.write_array(id, &state.source)?;
    }
    let seams = seam_flags(&state.patch, &state.chart, gim.resolution, &gim.zipper_links()?);
    let id = w.add_array(ArraySpec::new("seam", DType::U8, &[r, r], &[t, t])?)?;
    w.write_array(id, &seams)?;
    if let (Some(m0), Some(_)) = (&state.target, paint_log) {
        let id = w.add_array(ArraySpec::new("region", DType::F32, &[r, r], &[t, t])?)?;
        w.write_array(id, m0)?;
    }
    w.finish()
}

/// Records a file the quilt at `out` depends on under `role` (a parameter of
/// that name): its path relative to the quilt's folder (so the quilt and its
/// inputs can move together, and be read from any working directory), its
/// length (`ROLE_bytes`) and its content hash (an input of that name).
pub(super) fn record_dependency(w: &mut ContainerWriter, out: &Path, role: &str, path: &Path) -> Result<()> {
    let (bytes, hash) = crate::container::file_identity(path)?;
    w.add_input(role, hash);
    w.set_param(
        role,
        Param::Text(crate::io::staging::relative_to_folder_of(out, path)),
    );
    w.set_param(&format!("{role}_bytes"), Param::Int(bytes as i64));
    Ok(())
}

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
    pub(super) fn what(&self) -> String {
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

/// Per texel: which of its mesh edges the patches meet across (the seams
/// the graphcut left), as [`SEAM_X`] | [`SEAM_Y`] | [`SEAM_ZIPPER`].
pub(super) fn seam_flags(patch: &[u32], chart: &[u32], r: usize, zipper_links: &[[u32; 2]]) -> Vec<u8> {
    let mut flags = vec![0u8; r * r];
    let seam = |a: usize, b: usize| chart[a] == chart[b] && chart[a] != EMPTY && patch[a] != patch[b];
    for y in 0..r {
        for x in 0..r {
            let t = y * r + x;
            if x + 1 < r && seam(t, t + 1) {
                flags[t] |= SEAM_X;
            }
            if y + 1 < r && seam(t, t + r) {
                flags[t] |= SEAM_Y;
            }
        }
    }
    for &[a, b] in zipper_links {
        let (a, b) = (a as usize, b as usize);
        if patch[a] != patch[b] {
            flags[a] |= SEAM_ZIPPER;
            flags[b] |= SEAM_ZIPPER;
        }
    }
    flags
}

/// A decorated surface opened for reading.
pub struct Quilt {
    pub(super) container: Container,
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
        if resolution > crate::gim::MAX_RESOLUTION {
            return Err(Error::input(
                path,
                format!(
                    "parameter 'resolution' is {resolution}, more than the {} an atlas may have",
                    crate::gim::MAX_RESOLUTION
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
            samples.push(dependency(&format!("sample_{k}"))?);
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

    /// Which sample the recorded `sample_mask` belongs to (the last painted
    /// stroke's sample; 0 for a tiling).
    pub fn mask_sample(&self) -> usize {
        match self.container.metadata().param("mask_sample") {
            Some(Param::Int(v)) if *v >= 0 => *v as usize,
            _ => 0,
        }
    }
}

/// How many samples one surface may draw from (the tiling's and those
/// painted in), so a texel's sample index fits a byte.
pub const MAX_SAMPLES: usize = 255;
