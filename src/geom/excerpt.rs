//! Quoting input text in messages: never more than a short piece of one line,
//! so an error about a 1 MB line (or a binary file) stays one readable line.

/// Characters of input a message quotes at most.
pub const MAX_EXCERPT_CHARS: usize = 60;

/// `s` cut to its first line and [`MAX_EXCERPT_CHARS`] characters, control
/// characters escaped; `…` marks a cut.
pub fn excerpt(s: &str) -> String {
    excerpt_chars(s, MAX_EXCERPT_CHARS)
}

/// `s` cut to its first line and `max` characters, as [`excerpt`].
pub fn excerpt_chars(s: &str, max: usize) -> String {
    let line = s.split(['\n', '\r']).next().unwrap_or("");
    let mut out = String::new();
    for c in line.chars().take(max) {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    if line.chars().count() > max || line.len() < s.len() {
        out.push('…');
    }
    out
}

/// Bytes a whole message keeps at most (see [`cap_message`]).
pub const MAX_MESSAGE_BYTES: usize = 4096;

/// `s` cut in the middle to at most about `max` bytes, the cut marked
/// `… [N bytes cut] …` and made on character boundaries, so a message
/// quoting a huge input (a 10 MB path) keeps its start and its end.
pub fn cap_message(s: &str, max: usize) -> std::borrow::Cow<'_, str> {
    if s.len() <= max {
        return s.into();
    }
    let keep = max.saturating_sub(40) / 2;
    let mut head = keep;
    while !s.is_char_boundary(head) {
        head -= 1;
    }
    let mut tail = s.len() - keep;
    while !s.is_char_boundary(tail) {
        tail += 1;
    }
    format!(
        "{}… [{} bytes cut] …{}",
        &s[..head],
        tail - head,
        &s[tail..]
    )
    .into()
}

/// A number for a message, short whatever its magnitude: `{}` for ordinary
/// magnitudes, `{:e}` below 1e-4 or above 1e9 (so `1e-300` is not printed
/// as 300 digits), `nan`, `inf`, `-inf`.
pub fn num(x: f64) -> Num {
    Num(x)
}

/// See [`num`].
#[derive(Debug, Clone, Copy)]
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let x = self.0;
        if x.is_nan() {
            f.write_str("nan")
        } else if x.is_infinite() {
            f.write_str(if x > 0.0 { "inf" } else { "-inf" })
        } else if x != 0.0 && !(1e-4..=1e9).contains(&x.abs()) {
            write!(f, "{x:e}")
        } else {
            write!(f, "{x}")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_stay_short() {
        assert_eq!(num(1e-300).to_string(), "1e-300");
        assert_eq!(num(2.5e-3).to_string(), "0.0025");
        assert_eq!(num(0.0).to_string(), "0");
        assert_eq!(num(-3e20).to_string(), "-3e20");
        assert_eq!(num(f64::NAN).to_string(), "nan");
        assert_eq!(num(f64::NEG_INFINITY).to_string(), "-inf");
        assert_eq!(num(1e9).to_string(), "1000000000");
        assert!(num(f64::MAX).to_string().len() < 30);
    }

    #[test]
    fn long_messages_are_cut_in_the_middle() {
        let s = format!("start {} end", "é".repeat(1 << 20));
        let c = cap_message(&s, MAX_MESSAGE_BYTES);
        assert!(c.len() <= MAX_MESSAGE_BYTES, "{}", c.len());
        assert!(c.starts_with("start ") && c.ends_with(" end"));
        assert!(c.contains("bytes cut]"));
        assert_eq!(cap_message("short", 10), "short");
    }

    #[test]
    fn one_short_line() {
        assert_eq!(excerpt("abc"), "abc");
        assert_eq!(excerpt("ab\ncd"), "ab…");
        assert_eq!(excerpt("a\tb"), "a\\tb");
        let long = "x".repeat(5000);
        assert_eq!(excerpt(&long).chars().count(), MAX_EXCERPT_CHARS + 1);
    }
}
