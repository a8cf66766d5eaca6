//! Arguments shared by several commands.

use clap::Args;

use super::parse;
use crate::geom::{Units, UpAxis};
use crate::io::{ReadOptions, DEFAULT_RADIUS_M};

/// How to interpret input files.
#[derive(Debug, Clone, Args)]
pub struct ReadArgs {
    /// Unit of the input: mm, cm, m or metres per unit. Overrides what the file declares
    /// [default: the file's (glTF, HDF5, pyp: m); unitless bcc, obj, poly, ply: m, reported as assumed].
    #[arg(long, value_name = "mm|cm|m|SCALE")]
    pub units: Option<Units>,
    /// Up axis of the input. Overrides what the file declares
    /// [default: the file's (BCC header, glTF and HDF5 +Y, pyp +Z); others: y, reported as assumed].
    #[arg(long, value_name = "y|z")]
    pub up_axis: Option<UpAxis>,
    /// Repeat a periodic .pyp tile N x M times along its two periods.
    #[arg(long, value_name = "NxM", default_value = "1x1", value_parser = parse::parse_tile)]
    pub tile: [usize; 2],
    /// Polyline samples per span of BCC spline curves (C0, BS); 1 keeps the C0 control points.
    #[arg(long, value_name = "K", value_parser = parse::parse_spline_samples)]
    pub spline_samples: Option<usize>,
    /// Yarn radius in metres for files without one (or for all, with --override-radius).
    #[arg(long, value_name = "METRES", default_value_t = DEFAULT_RADIUS_M, value_parser = parse::parse_positive)]
    pub radius: f64,
    /// Use --radius even where the file gives radii.
    #[arg(long)]
    pub override_radius: bool,
}

impl ReadArgs {
    pub fn options(&self) -> ReadOptions {
        ReadOptions {
            units: self.units,
            up_axis: self.up_axis,
            spline_samples: self.spline_samples,
            tile: self.tile,
            radius: self.radius,
            override_radius: self.override_radius,
            ..ReadOptions::default()
        }
    }
}
