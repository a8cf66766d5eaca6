//! The command line: the top-level arguments and one subcommand per stage.

use clap::{Parser, Subcommand};

use super::bench::BenchArgs;
use super::commands::{ConvertArgs, DemoArgs, InspectArgs};
use super::{
    asset, bake, card, fabric_test, fit, parse, pattern, run, simulate, train, watch, yls,
};

/// knitvox: yarn-level knitwear to homogenized tetrahedral simulation, for render farms.
#[derive(Debug, Parser)]
#[command(name = "knitvox", version, about, long_about = None, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// Memory budget in bytes (suffixes K, M, G, T: 512M, 4G): the largest input file
    /// read whole, and the most a reader allocates for what a file declares
    /// (compressed HDF5, external glTF buffers, --tile) [default: an eighth of the
    /// physical memory, at most 2 GiB].
    #[arg(long, global = true, value_name = "BYTES", value_parser = parse::parse_bytes)]
    pub max_memory: Option<u64>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Summarise yarn files: format, curves, points, length, bbox, radius, units and axes.
    Inspect(InspectArgs),
    /// Convert a yarn file (or frame sequence) into another format, unit or up axis.
    Convert(ConvertArgs),
    /// Embed yarns in a voxel tet mesh and write a homogenized asset (.vtkhdf).
    Embed(asset::EmbedArgs),
    /// Shape-fit yarn frames (Y2V, VH Eq. 5-6) into an asset's time series.
    Shapefit(asset::ShapefitArgs),
    /// Export an asset's stored steps as per-frame yarn curves (V2Y).
    Export(asset::ExportArgs),
    /// Fit per-element materials (VH §6) of an asset to yarn-level training poses.
    Fit(fit::FitArgs),
    /// Compare an asset's homogenized motion with the yarn-level run of a yls scene.
    Validate(fit::ValidateArgs),
    /// Fit the homogenized damping of an asset on a dynamic yls scene (its yarn-level run) and write the asset with it.
    FitDamping(fit::FitDampingArgs),
    /// Bake a glTF character's animation into an HDF5 character cache (schemas/character-hdf5.md).
    Bake(bake::BakeArgs),
    /// Simulate a shot of an asset (scene file or character) and write frames (asset time series, yarn curves).
    Simulate(simulate::SimulateArgs),
    /// Run a job manifest's stages (embed, train, fit, shot, export), skipping cached ones (schemas/job.md).
    Run(run::RunArgs),
    /// Watch a folder: run the job manifests and yarn files dropped into ROOT/inbox (schemas/watch.md).
    Watch(watch::WatchArgs),
    /// Run a yarn-level scene (schemas/yls-scene.md) and write its frames (knitvox HDF5).
    Yls(yls::YlsArgs),
    /// Run one training pose (VH §8.6) quasi-statically on an asset's rest yarns (knitvox HDF5 frames for `fit`).
    Train(train::TrainArgs),
    /// Fit a material card on a swatch of a stitch pattern (docs/guides/cards.md): `embed --card` carries it onto garments.
    Card(card::CardArgs),
    /// Run a benchmark and print its figures (`--json` for machine-readable output).
    Bench(BenchArgs),
    /// Generate a stitch pattern (built-in or K/P grid) as yarn curves: a flat swatch or a tube.
    Pattern(pattern::PatternArgs),
    /// Fabric tests of Sperl 2022 §4 on a yarn swatch: stretch, bend (pear loop), hang.
    #[command(subcommand)]
    FabricTest(fabric_test::FabricTestKind),
    /// Run the built-in demo: convert, embed, shape-fit and simulate an example swatch, run a yarn-level stretch and a fabric test, and fit and validate a small rib's material (docs/guides/cli.md).
    Demo(DemoArgs),
    /// Print a shell completion script.
    Completions {
        /// The shell: bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
}
