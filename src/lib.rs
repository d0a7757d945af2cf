//! btfquilt: decorate triangle meshes with textures and bidirectional texture
//! functions (BTFs) by graphcut quilting and graphcut texture painting, after
//! Zhou et al., *Decorating Surfaces with Bidirectional Texture Functions*
//! (TVCG 2005), as a streaming pipeline over disk-backed tiles.
//!
//! Every stage is a function from typed artifacts on disk (see [`container`])
//! plus a config struct and a [`progress::Progress`] sink to a new artifact on
//! disk; the command-line tool calls the same functions. The only `unsafe`
//! code is the memory map in `container::mmap`.
//!
//! | stage | function | writes |
//! |---|---|---|
//! | mesh → dense mesh (multi-chart geometry image) | [`atlas::build_gim`] | `.gim` |
//! | BTF or colour image → geometry maps | [`factorize::factorize`] | `.svd` |
//! | graphcut quilting | [`quilt::tile`] | `.quilt` |
//! | graphcut texture painting | [`paint::paint`], [`paint::replay`] | `.quilt` |
//! | atlas texture | [`output::bake::bake`] | PNG / EXR |
//! | picture | [`output::render::render`] | PNG / EXR |
//! | OBJ, glTF, surface BTF | [`output::export::export`] | files in a folder |
//!
//! # Example
//!
//! Tile Spot with the brick wall and bake the atlas texture (the crate's
//! `examples/01_tile_a_mesh.rs` runs the same):
//!
//! ```no_run
//! use btfquilt::container::MemoryBudget;
//! use btfquilt::atlas::{self, AtlasConfig};
//! use btfquilt::progress::Silent;
//! use btfquilt::quilt::{self, TileConfig};
//! use std::path::Path;
//!
//! fn main() -> btfquilt::Result<()> {
//!     let cfg = AtlasConfig { resolution: 512, ..Default::default() };
//!     atlas::build_gim(Path::new("data/spot_5.8k.obj"), Path::new("spot.gim"), &cfg, &Silent)?;
//!
//!     let report = quilt::tile(
//!         Path::new("spot.gim"),
//!         Path::new("data/brick_wall.png"),
//!         Path::new("spot.quilt"),
//!         &TileConfig { seed: 1, ..Default::default() },
//!         &Silent,
//!     )?;
//!     println!("{report}");
//!
//!     btfquilt::output::bake::bake(Path::new("spot.quilt"), None, Path::new("spot_atlas.png"), MemoryBudget::default())?;
//!     Ok(())
//! }
//! ```
//!
//! The design, with the algorithms of each stage, is in `docs/design.md`.
#![deny(unsafe_code)]

pub mod artifact;
pub mod atlas;
pub mod batch;

pub mod container;
pub mod demo;
mod dense;
pub mod error;
pub mod factorize;
pub mod field;
pub mod generate;

pub mod ingest;
pub mod io;
mod math;
pub mod mesh;
pub mod output;
pub mod paint;
pub mod progress;
pub mod quilt;
mod rng;
mod sparse;
pub mod studio;

pub use error::{Error, Result};

/// Locks a mutex; a holder that panicked does not poison it for good.
pub(crate) fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The README's code, compiled as doc tests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
