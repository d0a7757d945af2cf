pub mod charts;
pub mod lscm;
pub mod pack;
