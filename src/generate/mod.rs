//! Deterministic synthetic BTF generation: procedural mesostructure
//! ([`material`]) and height-field ray-marched rendering ([`render`]).

pub mod material;
pub mod render;

pub use material::{Family, Imperfection, MaterialParams, Mesostructure};
pub use render::{direction, BlockRenderer};
mod stream;
pub use stream::{generate_btf, mask_path, GenerateConfig, GenerateReport};
