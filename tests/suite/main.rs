//! btfquilt's integration tests, as one test binary: each module is one area
//! (run one with `cargo test --release --test suite -- btf::`). Tests run as
//! parallel threads of one process, so none of them changes process-wide
//! state (environment variables, the current directory, rayon's global
//! pool); a test that needs such a change runs it in a child process.

#[path = "../common/mod.rs"]
mod common;

mod batch;
mod btf;
mod cli;
mod container;
mod courses;
mod export;
mod factorize;
mod gim;
mod lscm;
mod machine;
mod matching;
mod maxflow;
mod mesh;
mod multisample;
mod paint;
mod quilt;
mod render;
mod robustness;
mod studio;
