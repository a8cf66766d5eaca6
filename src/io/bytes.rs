//! Bounds-checked little helpers shared by the decoders: a binary cursor that
//! reports byte offsets, and a text line iterator that reports line numbers
//! and rejects non-UTF-8.

use super::FormatError;

/// A cursor over a byte slice; every read is bounds-checked and failures name
/// the byte offset and what was being read.
pub struct ByteReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> ByteReader<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        ByteReader { data, pos: 0 }
    }

    /// Current offset from the start of the data.
    pub fn pos(&self) -> usize {
        self.pos
    }

    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    pub fn is_at_end(&self) -> bool {
        self.pos == self.data.len()
    }

    /// Takes `n` bytes, or fails naming `what`.
    pub fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], FormatError> {
        if n > self.remaining() {
            return Err(FormatError::at_byte(
                self.pos as u64,
                format!(
                    "file ends early: {what} needs {n} bytes, only {} left",
                    self.remaining()
                ),
            ));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], FormatError> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u8(&mut self, what: &str) -> Result<u8, FormatError> {
        Ok(self.array::<1>(what)?[0])
    }
    pub fn i32_le(&mut self, what: &str) -> Result<i32, FormatError> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    pub fn u32_le(&mut self, what: &str) -> Result<u32, FormatError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    pub fn u64_le(&mut self, what: &str) -> Result<u64, FormatError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }
    pub fn f32_le(&mut self, what: &str) -> Result<f32, FormatError> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }
}

/// Splits text into lines, yielding `(1-based line number, line)`; a line
/// that is not UTF-8 becomes an error naming its line number. Handles `\n`
/// and `\r\n` endings.
pub fn text_lines(data: &[u8]) -> impl Iterator<Item = Result<(usize, &str), FormatError>> {
    let trailing_newline = data.last() == Some(&b'\n');
    let mut parts = data.split(|&b| b == b'\n').enumerate().peekable();
    std::iter::from_fn(move || {
        let (i, raw) = parts.next()?;
        if trailing_newline && parts.peek().is_none() {
            return None; // the empty piece after the final newline
        }
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        Some(match std::str::from_utf8(raw) {
            Ok(s) => Ok((i + 1, s)),
            Err(e) => Err(FormatError::at_line(
                i + 1,
                format!(
                    "not UTF-8 text (invalid byte at column {})",
                    e.valid_up_to() + 1
                ),
            )),
        })
    })
}

/// Parses a finite float token, naming the line and what it is on failure.
pub fn parse_finite(token: &str, line: usize, what: &str) -> Result<f64, FormatError> {
    match token.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(FormatError::at_line(
            line,
            format!("{what} is not finite ({v})"),
        )),
        Err(_) => Err(FormatError::at_line(
            line,
            format!("{what}: '{}' is not a number", crate::geom::excerpt(token)),
        )),
    }
}

/// Reserves capacity for `claimed` items only as far as `available_bytes`
/// could hold at `min_item_bytes` each: file-declared counts never drive
/// allocation beyond what the file can justify.
pub fn guarded_capacity(claimed: u64, min_item_bytes: usize, available_bytes: usize) -> usize {
    let justified = (available_bytes / min_item_bytes.max(1)) as u64;
    claimed.min(justified) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_numbered_and_utf8_checked() {
        let lines: Vec<_> = text_lines(b"a\r\nb\n\nc")
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(lines, vec![(1, "a"), (2, "b"), (3, ""), (4, "c")]);
        let lines: Vec<_> = text_lines(b"a\n").collect::<Result<_, _>>().unwrap();
        assert_eq!(lines, vec![(1, "a")]);
        let err = text_lines(b"ok\n\xff\xfe\n").nth(1).unwrap().unwrap_err();
        assert_eq!(err.location, super::super::Location::Line(2));
    }

    #[test]
    fn reader_reports_offset() {
        let mut r = ByteReader::new(&[1, 0, 0, 0, 9]);
        assert_eq!(r.i32_le("count").unwrap(), 1);
        let e = r.u64_le("size").unwrap_err();
        assert_eq!(e.location, super::super::Location::Byte(4));
        assert!(e.message.contains("size"));
    }

    #[test]
    fn capacity_guard() {
        assert_eq!(guarded_capacity(1 << 60, 12, 120), 10);
        assert_eq!(guarded_capacity(3, 12, 120), 3);
    }
}
