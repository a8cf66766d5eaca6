//! Orchestration: stages that combine io and the solvers. Later issues add the
//! job manifest, stage caching and resume.

pub mod asset;
pub mod demo;
pub mod fabric_test;
pub mod inspect;
pub mod pattern;
pub mod sim_scene;
pub mod simulate;
pub mod yls;
pub mod yls_scene;
