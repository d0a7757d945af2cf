//! Tile a mesh with a colour photo and bake the result into an atlas texture.
//!
//! ```sh
//! cargo run --release --example 01_tile_a_mesh
//! ```
//!
//! The three stages are the CLI's `atlas`, `tile` and `bake`; each reads
//! artifacts from disk and writes a new one.

use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, TileConfig};
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Outputs go to a folder of their own under the system's temp folder.
    let out = std::env::temp_dir().join("btfquilt-example-01");
    std::fs::create_dir_all(&out)?;
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");

    // 1. The dense mesh: Spot cut into charts, packed into a 256² atlas; one
    //    dense vertex per covered texel, with its frame from the vector field.
    let gim_path = out.join("spot.gim");
    let atlas_cfg = AtlasConfig {
        resolution: 256,
        ..Default::default()
    };
    let atlas = atlas::build_gim(&data.join("spot_5.8k.obj"), &gim_path, &atlas_cfg, &Silent)?;
    println!("atlas: {atlas}");

    // 2. Graphcut quilting of the 192² brick wall over the dense mesh. The
    //    quilt stores a sample coordinate per texel, not colours.
    let quilt_path = out.join("spot.quilt");
    let tile_cfg = TileConfig {
        seed: 7,
        ..Default::default()
    };
    let tiled = quilt::tile(
        &gim_path,
        &data.join("brick_wall.png"),
        &quilt_path,
        &tile_cfg,
        &Silent,
    )?;
    println!("tile: {tiled}");

    // 3. Look the colours up and write the atlas texture (gutters dilated).
    let png = out.join("spot_atlas.png");
    btfquilt::output::bake::bake(&quilt_path, None, &png, MemoryBudget::default())?;
    println!("wrote {}", png.display());
    Ok(())
}
