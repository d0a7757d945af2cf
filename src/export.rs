//! `export`: artifacts out to other tools. A geometry image goes out as its
//! mesh with atlas UVs (OBJ + MTL) and the chart map as the texture; a
//! decorated mesh (`.quilt`) with its baked atlas texture.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::gim::Gim;
use crate::imageio;
use crate::mesh::io::write_obj;
use crate::show::{show, ShowWhat};
use crate::{Error, Result};

/// Writes `DIR/mesh.obj`, `DIR/mesh.mtl` and `DIR/charts.png` (the chart map
/// as the texture, so a viewer shows the atlas). OBJ texture coordinates are
/// y-up: `vt u (1 - v)` for atlas uv (u, v) with v down. Returns the OBJ path.
pub fn export_gim_obj(gim: &Gim, dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    show(gim, ShowWhat::Charts, &dir.join("charts.png"))?;
    write_textured_obj(gim, dir, "charts.png")
}

/// Writes a decorated mesh: `DIR/mesh.obj`, `DIR/mesh.mtl` and
/// `DIR/atlas.png` (the baked preview colour, gutter dilated). Returns the
/// OBJ path.
pub fn export_quilt_obj(
    quilt_path: &Path,
    dir: &Path,
    budget: crate::container::MemoryBudget,
) -> Result<PathBuf> {
    let quilt = crate::quilt::Quilt::open(quilt_path, budget)?;
    let gim = Gim::open(&quilt.gim, budget)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::bake::bake(quilt_path, None, &dir.join("atlas.png"), budget)?;
    write_textured_obj(&gim, dir, "atlas.png")
}

/// The mesh of `gim` with atlas UVs (y up: `vt u (1 - v)`) and a material
/// whose diffuse texture is `texture` (a file in `dir`).
fn write_textured_obj(gim: &Gim, dir: &Path, texture: &str) -> Result<PathBuf> {
    let mesh = gim.mesh()?;
    let uv: Vec<[f32; 2]> = gim.corner_uv()?.into_iter().map(|[u, v]| [u, 1.0 - v]).collect();
    write_mtl(&dir.join("mesh.mtl"), "atlas", texture)?;
    let obj = dir.join("mesh.obj");
    write_obj(&obj, &mesh, Some(&uv), Some(("mesh.mtl", "atlas")))?;
    Ok(obj)
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
