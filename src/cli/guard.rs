//! Guards applied to every command line before any work (issue 13):
//! no output may be (or resolve to) one of the command's inputs, `export
//! --name` stays a plain file name, and `--max-memory` sets the memory
//! budget of the readers.

use std::path::Path;

use super::{Cli, Command};
use crate::io::overwrite;
use crate::pipeline::Error;

/// Parses a byte count with an optional binary suffix: `4096`, `512K`,
/// `512M`, `4G`, `1T` (also `MB`, `MiB`, ...).
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, suffix) = t.split_at(split);
    let shift = match suffix.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => {
            return Err(format!(
                "'{s}': expected BYTES with an optional K, M, G or T suffix, e.g. 4G"
            ))
        }
    };
    let v: f64 = num.parse().map_err(|_| {
        format!("'{s}': expected BYTES with an optional K, M, G or T suffix, e.g. 4G")
    })?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!(
            "'{s}': the budget must be at least 1 byte and below 2^64"
        ));
    }
    Ok(bytes as u64)
}

/// A finite number > 0 (lengths, densities, weights), checked by clap so a
/// bad value is a usage error naming the option.
pub fn parse_positive(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!(
            "'{}': expected a finite number > 0",
            crate::geom::excerpt(s)
        )),
    }
}

/// A finite number >= 0.
pub fn parse_non_negative(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!(
            "'{}': expected a finite number >= 0",
            crate::geom::excerpt(s)
        )),
    }
}

/// A fraction in [0, 1].
pub fn parse_fraction(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!(
            "'{}': expected a number from 0 to 1",
            crate::geom::excerpt(s)
        )),
    }
}

/// BCC spline samples per span: 1 to `io::bcc::MAX_SPLINE_SAMPLES`.
pub fn parse_spline_samples(s: &str) -> Result<usize, String> {
    let max = crate::io::bcc::MAX_SPLINE_SAMPLES;
    match s.trim().parse::<usize>() {
        Ok(v) if (1..=max).contains(&v) => Ok(v),
        _ => Err(format!(
            "'{}': expected an integer from 1 to {max}",
            crate::geom::excerpt(s)
        )),
    }
}

/// The memory budget when `--max-memory` is not given: a quarter of the
/// physical memory (`MemTotal` of /proc/meminfo), else the library default.
pub fn default_max_memory() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find_map(|l| l.strip_prefix("MemTotal:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        })
        .map(|kib| kib.saturating_mul(1024) / 4)
        .filter(|&b| b > 0)
        .unwrap_or(crate::io::DEFAULT_MAX_MEMORY)
}

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
