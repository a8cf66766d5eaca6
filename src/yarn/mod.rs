//! Yarn-level curves: the reference yarn-level simulator and the stitch-pattern
//! generator arrive with later issues; for now, analytic example swatches.

pub mod analytic;
