//! The typed artifacts the stages pass to each other, each a container
//! ([`crate::container`]) of a known kind with named arrays and parameters:
//! a measured or generated BTF ([`btf`]), a factorized sample ([`svd`]), a
//! geometry image ([`gim`]) and a decorated surface ([`quilt`]). Readers
//! check an artifact's kind and arrays when they open it; each stage writes
//! the artifact it makes.

pub mod btf;
pub mod gim;
pub mod quilt;
pub mod svd;
