//! Value parsers of command-line options: checked before any work, each
//! error naming what it expected.

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

/// Parses `--tile NxM` (each between 1 and 10000).
pub fn parse_tile(s: &str) -> Result<[usize; 2], String> {
    let (a, b) = s
        .to_ascii_lowercase()
        .split_once('x')
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .ok_or_else(|| format!("'{s}': expected NxM, e.g. 3x3"))?;
    let parse = |t: &str| {
        t.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=10_000).contains(n))
    };
    match (parse(&a), parse(&b)) {
        (Some(n), Some(m)) => Ok([n, m]),
        _ => Err(format!(
            "'{s}': expected NxM with N and M between 1 and 10000"
        )),
    }
}
