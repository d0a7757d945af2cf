//! The typed artifacts the stages pass to each other, each a container
//! ([`crate::container`]) of a known kind with named arrays and parameters:
//! a measured or generated BTF ([`btf`]), a factorized sample ([`svd`]) and
//! a decorated surface ([`quilt`]). The geometry image is read by
//! [`crate::gim::Gim`].

pub mod btf;
pub mod quilt;
pub mod svd;
