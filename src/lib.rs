//! btfquilt: decorate triangle meshes with textures and bidirectional texture
//! functions (BTFs), as a streaming pipeline over disk-backed tiles.
//!
//! Every stage is a function from typed artifacts on disk (see [`container`])
//! plus a config struct and a [`progress::Progress`] sink to a new artifact on
//! disk. The only `unsafe` code is the memory map in `container::mmap`.
#![deny(unsafe_code)]

pub mod atlas;
pub mod bake;
pub mod btf;
pub mod container;
pub mod demo;
pub mod error;
pub mod evaluate;
pub mod export;
pub mod factorize;
pub mod field;
pub mod generate;
pub mod gim;
pub mod imageio;
pub mod ingest;
pub mod matching;
pub mod maxflow;
pub mod mesh;
pub mod naming;
pub mod paint;
pub mod progress;
pub mod quilt;
pub mod render;
mod rng;
pub mod show;
pub mod staging;

pub use error::{Error, Result};
