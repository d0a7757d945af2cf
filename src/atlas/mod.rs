//! `atlas`: from a mesh to the dense mesh M_d, a multi-chart geometry image
//! (the paper's "GIM-based sampling", docs/design.md section 5).
//!
//! The mesh is cut into charts and parameterised ([`charts`]), packed at
//! one texel density into R×R ([`pack`]), and rasterized tile by tile:
//! every covered atlas texel becomes a dense vertex with its chart, original
//! face, barycentrics, 3D position, normal and tangent frame (tangent from the
//! vector field). Coverage is conservative (texel centres within 0.75 texel
//! of a chart triangle), so each chart's texels form a connected grid whose
//! border runs along the chart's boundary. Chart boundaries are then
//! zippered: each boundary texel links to the nearest boundary texel across
//! the seam (in 3D, among nearby faces), which makes M_d one connected graph
//! per surface component; strips of triangles stitch the zippers so work
//! patches that cross charts can be flattened.
//!
//! The artifact stores the atlas arrays in 64×64 tiles, plus the mesh with
//! its atlas UVs, the field and the zipper links and triangles.

mod arap;
pub mod charts;
pub mod lscm;
mod overlap;
pub mod pack;
pub mod raster;

pub use raster::{build_gim, AtlasConfig, AtlasReport};
