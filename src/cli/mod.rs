//! Command-line interface: clap definitions and the glue from arguments to the
//! library. Only this module and `main` know about processes and terminals.

mod args;
mod asset;
mod bake;
mod bench;
mod budget;
mod card;
mod command_line;
mod commands;
mod console;
pub mod exit;
mod fabric_test;
mod fit;
pub mod guard;
mod parse;
mod pattern;
mod run;
mod simulate;
mod train;
mod watch;
mod yarn_material;
mod yls;

pub use command_line::{Cli, Command};
pub use console::wants_json;
pub use exit::{error_message, exit_code_for, ExitCode};

use bench::BenchTarget;

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    crate::io::set_max_memory(cli.max_memory.unwrap_or_else(guard::default_max_memory));
    guard::check(&cli)?;
    match cli.command {
        Command::Inspect(a) => commands::inspect(&a),
        Command::Convert(a) => commands::convert(&a),
        Command::Embed(a) => asset::embed(&a),
        Command::Shapefit(a) => asset::shapefit(&a),
        Command::Export(a) => asset::export(&a),
        Command::Fit(a) => fit::fit(&a),
        Command::Validate(a) => fit::validate(&a),
        Command::FitDamping(a) => fit::fit_damping(&a),
        Command::Simulate(a) => simulate::simulate(&a),
        Command::Bake(a) => bake::bake(&a),
        Command::Run(a) => run::run(&a),
        Command::Watch(a) => watch::watch(&a, cli.max_memory),
        Command::Bench(a) => match a.target {
            BenchTarget::Io(b) => bench::io(&b),
            BenchTarget::Embed(b) => bench::embed(&b),
            BenchTarget::Sim(b) => bench::sim(&b),
            BenchTarget::Yls(b) => bench::yls(&b),
        },
        Command::Pattern(a) => pattern::pattern(&a),
        Command::Yls(a) => yls::yls(&a),
        Command::Train(a) => train::train(&a),
        Command::Card(a) => card::card(&a),
        Command::FabricTest(k) => fabric_test::fabric_test(&k),
        Command::Demo(a) => commands::demo(&a),
        Command::Completions { shell } => {
            use clap::CommandFactory;
            clap_complete::generate(
                shell,
                &mut Cli::command(),
                "knitvox",
                &mut std::io::stdout(),
            );
            Ok(ExitCode::Success)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::bench::BenchArgs;
    use super::parse::parse_tile;
    use super::*;
    use crate::io::WriteOptions;
    use clap::Parser;

    #[test]
    fn cli_definition_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }

    /// Defaults written as text in clap attributes are the library's.
    #[test]
    fn textual_defaults_are_the_librarys() {
        let cli = Cli::try_parse_from(["knitvox", "bench", "sim"]).unwrap();
        let Command::Bench(BenchArgs {
            target: BenchTarget::Sim(b),
        }) = cli.command
        else {
            panic!("not bench sim")
        };
        assert_eq!(b.dt, crate::sim::pd::PdParams::default().dt);
        assert_eq!(
            b.backend,
            crate::pipeline::sim_scene::BackendChoice::default()
        );
        assert_eq!(
            b.solver,
            crate::pipeline::sim_scene::SolverChoice::default()
        );
        let cli = Cli::try_parse_from(["knitvox", "convert", "a.ply", "b.ply"]).unwrap();
        let Command::Convert(c) = cli.command else {
            panic!("not convert")
        };
        assert_eq!(c.write_options(), WriteOptions::default());
        let cli = Cli::try_parse_from(["knitvox", "export", "a.vtkhdf", "-o", "out"]).unwrap();
        let Command::Export(e) = cli.command else {
            panic!("not export")
        };
        let w = WriteOptions::default();
        assert_eq!((e.out_units, e.out_up_axis), (w.units, w.up_axis));
        let cli = Cli::try_parse_from([
            "knitvox",
            "simulate",
            "a.vtkhdf",
            "--character",
            "c.glb",
            "--frames",
            "1",
            "-o",
            "o.vtkhdf",
        ])
        .unwrap();
        let Command::Simulate(a) = cli.command else {
            panic!("not simulate")
        };
        let scene = simulate::scene_of(&a).unwrap();
        let c = scene.character.unwrap();
        let d = crate::pipeline::sim_scene::CharacterSection::default();
        assert_eq!((c.scale, c.pin_distance), (d.scale, d.pin_distance));
        assert_eq!(
            scene.simulation,
            crate::pipeline::sim_scene::SimulationSection::default()
        );
    }

    #[test]
    fn tile_parsing() {
        assert_eq!(parse_tile("3x4"), Ok([3, 4]));
        assert_eq!(parse_tile("2X2"), Ok([2, 2]));
        assert!(parse_tile("0x3").is_err());
        assert!(parse_tile("3").is_err());
        assert!(parse_tile("99999999999999999999x1").is_err());
    }
}
