//! Render a decorated mesh under two lights and export it as binary glTF.
//!
//! ```sh
//! cargo run --release --example 01_tile_a_mesh   # makes the quilt this reads
//! cargo run --release --example 02_render_and_export
//! ```

use btfquilt::container::MemoryBudget;
use btfquilt::output::export::{self, ExportOptions, MeshFormat};
use btfquilt::output::render::{self, Light, RenderConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::temp_dir().join("btfquilt-example-01");
    let quilt_path = out.join("spot.quilt");
    if !quilt_path.exists() {
        eprintln!("run `cargo run --release --example 01_tile_a_mesh` first");
        std::process::exit(1);
    }

    // A three-quarter view (the default camera frames the mesh) lit from the
    // front and from the side. Directions point towards the light.
    let cfg = RenderConfig {
        lights: vec![
            Light::directional([0.3, 0.5, 1.0]),
            Light::directional([1.0, 0.0, 0.0]),
        ],
        width: 640,
        height: 480,
        ..Default::default()
    };
    let png = out.join("spot_render.png");
    render::render(&quilt_path, &cfg, &png, MemoryBudget::default())?;
    println!("wrote {}", png.display());

    // mesh.glb: the mesh with its atlas uvs and the baked atlas as base colour.
    let opts = ExportOptions {
        mesh: Some((MeshFormat::Gltf, out.join("gltf"))),
        btf: None,
        sample: None,
        budget: MemoryBudget::default(),
    };
    for path in export::export(&quilt_path, &opts)? {
        println!("wrote {}", path.display());
    }
    Ok(())
}
