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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_short_line() {
        assert_eq!(excerpt("abc"), "abc");
        assert_eq!(excerpt("ab\ncd"), "ab…");
        assert_eq!(excerpt("a\tb"), "a\\tb");
        let long = "x".repeat(5000);
        assert_eq!(excerpt(&long).chars().count(), MAX_EXCERPT_CHARS + 1);
    }
}
