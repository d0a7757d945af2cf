//! `export`: artifacts out to other tools.
//!
//! - A geometry image (`.gim`) goes out as its mesh with atlas UVs and the
//!   chart map as the texture; a decorated mesh (`.quilt`) with its baked
//!   atlas texture. Formats: OBJ + MTL + PNG, or one binary glTF 2.0 file
//!   (`mesh.glb`, the texture embedded).
//! - A decorated mesh's *surface BTF* for other renderers: per atlas texel the
//!   sample coordinate and frame (`synthesis.exr`, and which sample when the
//!   surface draws from several), and each sample as its factorization
//!   (`geometry_maps.exr`, `appearance.csv`, …; `geometry_maps_K.exr`,
//!   `appearance_K.csv`, … for sample K ≥ 1), described by a `FORMAT.md`
//!   written beside them.
//!
//! Every export is all-or-nothing: the files are written into a hidden
//! staging folder inside the output folder and renamed into place only when
//! all of them are complete, so an error leaves no new file behind (and an
//! output folder the export created is removed again).

use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::artifact::gim::Gim;
use crate::artifact::svd::SvdArtifact;
use std::sync::Mutex;

use crate::container::{BoundedCache, Container, MemoryBudget};
use crate::io::imageio;
use crate::mesh::io::write_obj;
use crate::mesh::Mesh;
use crate::output::show::{show, ShowWhat};
use crate::output::{bake, BAND_ROWS};
use crate::quilt::{Quilt, NO_PATCH};
use crate::{Error, Result};

use serde::Serialize;

mod gltf;
mod split;
mod surface_btf;
pub use gltf::*;
pub use split::*;
pub use surface_btf::*;

/// A mesh file format for `export --format`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum MeshFormat {
    /// `mesh.obj` + `mesh.mtl` + the texture as PNG.
    #[default]
    Obj,
    /// `mesh.glb`: binary glTF 2.0 with the texture embedded.
    #[value(alias = "glb")]
    Gltf,
}

impl FromStr for MeshFormat {
    type Err = Error;
    /// The names clap accepts: `obj`, `gltf` (or `glb`).
    fn from_str(s: &str) -> Result<Self> {
        <Self as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| Error::Config(format!("--format '{s}': expected obj or gltf")))
    }
}

/// What [`export`] writes.
#[derive(Clone, Debug, Default)]
pub struct ExportOptions {
    /// The mesh with its texture, in this format, into this folder.
    pub mesh: Option<(MeshFormat, PathBuf)>,
    /// The surface BTF of a `.quilt` into this folder.
    pub btf: Option<PathBuf>,
    /// The sample of a `.quilt` (default: the path recorded in it).
    pub sample: Option<PathBuf>,
    pub budget: MemoryBudget,
}

/// Exports a `.gim` or a `.quilt` as `opts` asks; returns the files written.
/// Nothing is written unless everything succeeds.
pub fn export(file: &Path, opts: &ExportOptions) -> Result<Vec<PathBuf>> {
    if opts.mesh.is_none() && opts.btf.is_none() {
        return Err(Error::Config(
            "nothing to export: give -o DIR (with --format obj|gltf) and/or --btf DIR".into(),
        ));
    }
    let kind = Container::open(file, MemoryBudget(0))?.metadata().kind.clone();
    let source = if kind == crate::quilt::KIND {
        // the quilt's and the geometry image's decoded chunks share what the
        // program and the surface BTF's held bands leave (`bake` divides the
        // whole budget again: it runs before either cache fills)
        let bands = match &opts.btf {
            Some(_) => held_bytes(Quilt::open(file, MemoryBudget(0))?.resolution),
            None => 0,
        };
        let held = super::PROGRAM_BYTES + bands;
        let [quilt_budget, gim_budget] = opts.budget.less(held).split([1, 1]);
        let quilt = Quilt::open(file, quilt_budget)?;
        // `--sample` stands in for the tiling's sample only: the others
        // must be where the quilt says
        for (k, path) in quilt.samples.iter().enumerate().skip(1) {
            if !path.exists() {
                return Err(Error::input(
                    file,
                    format!("its sample {} (painted in, 'sample_{k}') is gone", path.display()),
                ));
            }
        }
        let gim = quilt.open_gim(None, gim_budget)?;
        Source::Quilt {
            path: file,
            quilt,
            gim,
        }
    } else if kind == crate::artifact::gim::KIND {
        if opts.btf.is_some() {
            return Err(Error::input(
                file,
                "a geometry image has no surface BTF: --btf needs a decorated mesh (.quilt, from `tile`)",
            ));
        }
        Source::Gim(Gim::open(file, opts.budget)?)
    } else {
        return Err(Error::input(
            file,
            format!("a '{kind}' artifact: export takes a .gim or a .quilt"),
        ));
    };
    // the surface BTF's inputs first: their checks are cheap
    let btf = match (&opts.btf, &source) {
        (Some(dir), Source::Quilt { path, quilt, .. }) => {
            if quilt.container().array("jacobian").is_err() {
                return Err(Error::input(
                    path,
                    "has no per-texel sample frame (array 'jacobian'): it was tiled by an older btfquilt; run `tile` again",
                ));
            }
            Some((
                dir,
                super::open_samples(quilt, opts.sample.as_deref(), [opts.budget; 2])?,
            ))
        }
        _ => None,
    };
    // everything that can fail happens before anything is renamed into place
    let mut stages = Vec::new();
    if let Some((format, dir)) = &opts.mesh {
        let mut stage = Stage::new(dir)?;
        stage_mesh(&source, *format, opts, &mut stage)?;
        stages.push(stage);
    }
    if let (Some((dir, samples)), Source::Quilt { path, quilt, .. }) = (&btf, &source) {
        let mut stage = Stage::new(dir)?;
        let mut paths = quilt.samples.clone();
        if let Some(first) = &opts.sample {
            paths[0] = first.clone();
        }
        let svds: Vec<&SvdArtifact> = samples.iter().map(|s| &s.svd).collect();
        stage_surface_btf(path, quilt, &svds, &paths, &mut stage)?;
        stages.push(stage);
    }
    // no published file may land on an input (the artifact, its geometry
    // image or samples): checked for all before any is renamed
    let mut inputs: Vec<(String, PathBuf)> = match &source {
        Source::Quilt { quilt, .. } => quilt.input_files(),
        Source::Gim(gim) => vec![("the geometry image".into(), gim.container().path().to_path_buf())],
    };
    if let Some(p) = &opts.sample {
        inputs.push(("the sample".into(), p.clone()));
    }
    let inputs: Vec<(&str, &Path)> = inputs.iter().map(|(r, p)| (r.as_str(), p.as_path())).collect();
    for stage in &stages {
        for name in &stage.publish {
            crate::io::staging::check_output(&stage.dir.join(name), &inputs)?;
        }
    }
    let mut written = Vec::new();
    for stage in stages {
        written.extend(stage.commit()?);
    }
    Ok(written)
}

/// Writes `DIR/mesh.obj`, `DIR/mesh.mtl` and `DIR/charts.png` (the chart map
/// as the texture, so a viewer shows the atlas). OBJ texture coordinates are
/// y-up: `vt u (1 - v)` for atlas uv (u, v) with v down. Returns the OBJ path.
pub fn export_gim_obj(gim: &Gim, dir: &Path) -> Result<PathBuf> {
    let mut stage = Stage::new(dir)?;
    stage_gim_mesh(gim, MeshFormat::Obj, &mut stage)?;
    stage.commit()?;
    Ok(dir.join("mesh.obj"))
}

/// Writes a decorated mesh: `DIR/mesh.obj`, `DIR/mesh.mtl` and
/// `DIR/atlas.png` (the baked preview colour, gutter dilated). Returns the
/// OBJ path.
pub fn export_quilt_obj(quilt_path: &Path, dir: &Path, budget: MemoryBudget) -> Result<PathBuf> {
    let opts = ExportOptions {
        mesh: Some((MeshFormat::Obj, dir.to_path_buf())),
        budget,
        ..ExportOptions::default()
    };
    export(quilt_path, &opts)?;
    Ok(dir.join("mesh.obj"))
}

enum Source<'a> {
    Gim(Gim),
    Quilt { path: &'a Path, quilt: Quilt, gim: Gim },
}

fn stage_mesh(source: &Source, format: MeshFormat, opts: &ExportOptions, stage: &mut Stage) -> Result<()> {
    match source {
        Source::Gim(gim) => stage_gim_mesh(gim, format, stage),
        Source::Quilt { path, gim, .. } => {
            // the baked atlas: a published file for OBJ, embedded for glTF
            let png = match format {
                MeshFormat::Obj => stage.publish("atlas.png"),
                MeshFormat::Gltf => stage.scratch("atlas.png"),
            };
            bake::bake(path, opts.sample.as_deref(), &png, opts.budget)?;
            stage_textured(gim, format, &png, "atlas.png", stage)
        }
    }
}

fn stage_gim_mesh(gim: &Gim, format: MeshFormat, stage: &mut Stage) -> Result<()> {
    let png = match format {
        MeshFormat::Obj => stage.publish("charts.png"),
        MeshFormat::Gltf => stage.scratch("charts.png"),
    };
    show(gim, ShowWhat::Charts, &png)?;
    stage_textured(gim, format, &png, "charts.png", stage)
}

/// The mesh of `gim` with atlas UVs and the texture at `png` (named
/// `texture` in the MTL).
fn stage_textured(gim: &Gim, format: MeshFormat, png: &Path, texture: &str, stage: &mut Stage) -> Result<()> {
    let mesh = gim.mesh()?;
    let corner_uv = gim.corner_uv()?;
    match format {
        MeshFormat::Obj => {
            // OBJ texture coordinates are y-up
            let uv: Vec<[f32; 2]> = corner_uv.iter().map(|&[u, v]| [u, 1.0 - v]).collect();
            write_mtl(&stage.publish("mesh.mtl"), "atlas", texture)?;
            write_obj(
                &stage.publish("mesh.obj"),
                &mesh,
                Some(&uv),
                Some(("mesh.mtl", "atlas")),
            )
        }
        MeshFormat::Gltf => {
            let image = std::fs::read(png).map_err(|e| Error::io(png, e))?;
            let out = stage.publish("mesh.glb");
            let split = split_by_uv(&mesh, &corner_uv)
                .map_err(|reason| Error::input(gim.container().path(), reason))?;
            let glb = glb_bytes(&split, &image).map_err(|reason| Error::input(&out, reason))?;
            imageio::write_atomic(&out, |w| w.write_all(&glb).map_err(|e| Error::io(&out, e)))
        }
    }
}

/// Writes a one-material MTL file with a diffuse texture.
pub fn write_mtl(path: &Path, material: &str, texture: &str) -> Result<()> {
    imageio::write_atomic(path, |w| {
        write!(
            w,
            "newmtl {material}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {texture}\n"
        )
        .map_err(|e| Error::io(path, e))
    })
}

/// Files written into a hidden folder inside the destination, renamed into
/// the destination by [`Stage::commit`]; dropped uncommitted, the staging
/// folder is removed, and so is the destination if this stage created it and
/// it is still empty.
struct Stage {
    dir: PathBuf,
    created: bool,
    tmp: Option<tempfile::TempDir>,
    publish: Vec<String>,
}

impl Stage {
    fn new(dir: &Path) -> Result<Stage> {
        let created = !dir.exists();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let tmp = crate::io::staging::staging_dir_in(dir, "export");
        let tmp = match tmp {
            Ok(t) => t,
            Err(e) => {
                if created {
                    let _ = std::fs::remove_dir(dir);
                }
                return Err(e);
            }
        };
        Ok(Stage {
            dir: dir.to_path_buf(),
            created,
            tmp: Some(tmp),
            publish: Vec::new(),
        })
    }

    fn staging(&self) -> &Path {
        self.tmp.as_ref().expect("an uncommitted stage").path()
    }

    /// A path for a file that will be renamed to `DIR/name` on commit.
    fn publish(&mut self, name: &str) -> PathBuf {
        if !self.publish.iter().any(|n| n == name) {
            self.publish.push(name.to_string());
        }
        self.staging().join(name)
    }

    /// A path for an intermediate file, removed with the staging folder.
    fn scratch(&self, name: &str) -> PathBuf {
        self.staging().join(format!("scratch-{name}"))
    }

    /// Renames the published files into the destination; returns their paths.
    fn commit(mut self) -> Result<Vec<PathBuf>> {
        let mut out = Vec::new();
        for name in &self.publish {
            let from = self.staging().join(name);
            let to = self.dir.join(name);
            std::fs::rename(&from, &to).map_err(|e| Error::io(&to, e))?;
            out.push(to);
        }
        self.created = false;
        Ok(out)
    }
}

impl Drop for Stage {
    fn drop(&mut self) {
        if let Some(tmp) = self.tmp.take() {
            let _ = tmp.close();
        }
        if self.created {
            // only if empty: never removes anything else
            let _ = std::fs::remove_dir(&self.dir);
        }
    }
}

#[cfg(test)]
mod tests;
