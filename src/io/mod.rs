//! Files that are not containers: images (PNG, JPEG, TIFF, EXR) with
//! bilinear lookup and bounded decoding ([`imageio`]), staged writes that
//! are renamed into place when complete and the output-equals-input check
//! ([`staging`]), and the names and CSV manifests of exported direction
//! images ([`naming`]).

pub mod imageio;
pub mod naming;
pub mod staging;
