//! `export`: artifacts out to other tools. A geometry image goes out as its
//! mesh with atlas UVs (OBJ + MTL) and the chart map as the texture.

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
    let mesh = gim.mesh()?;
    let uv: Vec<[f32; 2]> = gim.corner_uv()?.into_iter().map(|[u, v]| [u, 1.0 - v]).collect();
    let texture = dir.join("charts.png");
    show(gim, ShowWhat::Charts, &texture)?;
    let mtl = dir.join("mesh.mtl");
    write_mtl(&mtl, "atlas", "charts.png")?;
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
