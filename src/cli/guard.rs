//! Guards applied to every command line before any work: no output may be
//! (or resolve to) one of the command's inputs, and `export --name` stays a
//! plain file name.

use std::path::Path;

use super::command_line::{Cli, Command};
use crate::io::overwrite;
use crate::pipeline::Error;

pub use super::budget::{default_max_memory, DEFAULT_MAX_MEMORY_CAP};

/// The command's input and output paths (outputs that are folders excluded).
fn io_paths(cli: &Cli) -> (Vec<&Path>, Vec<&Path>) {
    fn p(x: &Path) -> &Path {
        x
    }
    match &cli.command {
        Command::Convert(a) => (vec![p(&a.input)], vec![p(&a.output)]),
        Command::Embed(a) => (vec![p(&a.yarns)], vec![p(&a.output)]),
        // Without -o the asset is updated in place (documented); the frames
        // file must never be the output.
        Command::Shapefit(a) => (
            vec![p(&a.frames)],
            vec![a.output.as_deref().unwrap_or(&a.asset)],
        ),
        Command::Simulate(a) => {
            let mut ins = vec![p(&a.asset)];
            ins.extend(a.scene.as_deref());
            ins.extend(a.character.as_deref());
            let mut outs = vec![p(&a.output)];
            outs.extend(a.yarns_out.as_deref());
            (ins, outs)
        }
        Command::Yls(a) => (vec![p(&a.scene)], vec![p(&a.output)]),
        Command::Bake(a) => (vec![p(&a.character)], vec![p(&a.output)]),
        Command::Pattern(a) => (
            a.grid.iter().map(|g| g.as_path()).collect(),
            vec![p(&a.output)],
        ),
        _ => (Vec::new(), Vec::new()),
    }
}

/// Refuses (exit 2) an output that is one of the inputs, two outputs that
/// are one file, and an `export --name` that is not a plain file name.
pub fn check(cli: &Cli) -> anyhow::Result<()> {
    let (inputs, outputs) = io_paths(cli);
    overwrite::refuse_inputs(&outputs, &inputs)?;
    for (i, o) in outputs.iter().enumerate() {
        if let Some(other) = outputs[..i].iter().find(|p| overwrite::same_file(p, o)) {
            return Err(Error::Usage(format!(
                "outputs '{}' and '{}' are the same file",
                other.display(),
                o.display()
            ))
            .into());
        }
    }
    if let Command::Export(a) = &cli.command {
        if let Some(name) = &a.name {
            check_plain_name(name)?;
        }
    }
    Ok(())
}

/// `export --name`: a file name, never a path (it must not leave `-o`).
pub fn check_plain_name(name: &str) -> Result<(), Error> {
    let bad = name.is_empty()
        || name == "."
        || name == ".."
        || name.contains(['/', '\\', '\0'])
        || name.starts_with('.');
    if bad {
        return Err(Error::Usage(format!(
            "--name '{name}': give a plain file name (no '/', '\\', leading '.' or '..'); files are written inside -o"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::parse::parse_bytes;
    use super::*;

    #[test]
    fn byte_counts() {
        assert_eq!(parse_bytes("4096").unwrap(), 4096);
        assert_eq!(parse_bytes("512M").unwrap(), 512 << 20);
        assert_eq!(parse_bytes("4G").unwrap(), 4 << 30);
        assert_eq!(parse_bytes("1.5k").unwrap(), 1536);
        assert_eq!(parse_bytes("2GiB").unwrap(), 2 << 30);
        for bad in ["", "x", "4Q", "0", "-1", "1e30T"] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn names() {
        assert!(check_plain_name("shot").is_ok());
        for bad in ["", "..", "../x", "a/b", ".hidden", "a\\b"] {
            assert!(check_plain_name(bad).is_err(), "{bad}");
        }
    }
}
