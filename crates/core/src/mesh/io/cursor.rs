//! A bounds-checked reader over a file's bytes: text lines with line numbers for errors, and
//! binary little/big-endian values. Never panics; every failure is a [`MeshError::Parse`].

use crate::mesh::MeshError;
use std::fmt::Display;
use std::path::Path;
use std::str::FromStr;

/// Byte order of binary MSH data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Endian {
    Little,
    Big,
}

pub(super) struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Cursor<'a> {
    pub(super) fn new(data: &'a [u8], path: &'a Path) -> Self {
        Cursor { data, pos: 0, path }
    }

    pub(super) fn data(&self) -> &'a [u8] {
        self.data
    }

    pub(super) fn pos(&self) -> usize {
        self.pos
    }

    pub(super) fn seek(&mut self, pos: usize) {
        self.pos = pos.min(self.data.len());
    }

    pub(super) fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// 1-based line number of byte `pos`.
    pub(super) fn line_no(&self, pos: usize) -> usize {
        let end = pos.min(self.data.len());
        1 + self.data[..end].iter().filter(|&&b| b == b'\n').count()
    }

    /// A parse error at the line holding byte `pos`.
    pub(super) fn err(&self, pos: usize, msg: impl Display) -> MeshError {
        MeshError::Parse {
            path: self.path.to_path_buf(),
            msg: format!("line {}: {msg}", self.line_no(pos)),
        }
    }

    /// A parse error at byte offset `pos` of binary data.
    pub(super) fn err_bin(&self, pos: usize, msg: impl Display) -> MeshError {
        MeshError::Parse {
            path: self.path.to_path_buf(),
            msg: format!("byte offset {pos}: {msg}"),
        }
    }

    /// The next raw line (without `\n` and a trailing `\r`) and its start; `None` at the end.
    pub(super) fn raw_line(&mut self) -> Option<(usize, &'a [u8])> {
        if self.pos >= self.data.len() {
            return None;
        }
        let start = self.pos;
        let rest = &self.data[start..];
        let (line, next) = match rest.iter().position(|&b| b == b'\n') {
            Some(i) => (&rest[..i], start + i + 1),
            None => (rest, self.data.len()),
        };
        self.pos = next;
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        Some((start, line))
    }

    /// The next line that is not blank, trimmed, as text; `Ok(None)` at the end of the file.
    pub(super) fn text_line(&mut self) -> Result<Option<(usize, &'a str)>, MeshError> {
        while let Some((pos, line)) = self.raw_line() {
            let text = std::str::from_utf8(line)
                .map_err(|_| self.err(pos, "expected a line of text, found non-UTF-8 bytes"))?;
            let text = text.trim();
            if !text.is_empty() {
                return Ok(Some((pos, text)));
            }
        }
        Ok(None)
    }

    /// Like [`Cursor::text_line`], but the end of the file is an error mentioning `what`.
    pub(super) fn expect_text_line(&mut self, what: &str) -> Result<(usize, &'a str), MeshError> {
        match self.text_line()? {
            Some(l) => Ok(l),
            None => Err(self.err(
                self.data.len(),
                format!("unexpected end of file, expected {what}"),
            )),
        }
    }

    /// Consumes the rest of the current line (after binary data: its terminating newline).
    pub(super) fn skip_line_end(&mut self) {
        let _ = self.raw_line();
    }

    /// The next `n` bytes, or `None` (consuming nothing) when fewer remain.
    pub(super) fn bytes(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let b = self.data.get(self.pos..end)?;
        self.pos = end;
        Some(b)
    }

    pub(super) fn i32(&mut self, e: Endian) -> Option<i32> {
        let b: [u8; 4] = self.bytes(4)?.try_into().ok()?;
        Some(match e {
            Endian::Little => i32::from_le_bytes(b),
            Endian::Big => i32::from_be_bytes(b),
        })
    }

    pub(super) fn f64(&mut self, e: Endian) -> Option<f64> {
        let b: [u8; 8] = self.bytes(8)?.try_into().ok()?;
        Some(match e {
            Endian::Little => f64::from_le_bytes(b),
            Endian::Big => f64::from_be_bytes(b),
        })
    }
}

/// Parses an optional token as a number, describing the problem with `what`.
pub(super) fn parse_num<T: FromStr>(tok: Option<&str>, what: &str) -> Result<T, String> {
    match tok {
        None => Err(format!("missing {what}")),
        Some(t) => t
            .parse()
            .map_err(|_| format!("{what} is not a valid number: '{}'", shorten(t))),
    }
}

/// Parses a line that must hold exactly one number.
pub(super) fn parse_single<T: FromStr>(line: &str, what: &str) -> Result<T, String> {
    let mut tok = line.split_ascii_whitespace();
    let v = parse_num(tok.next(), what)?;
    match tok.next() {
        None => Ok(v),
        Some(t) => Err(format!(
            "expected only {what} on this line, found also '{}'",
            shorten(t)
        )),
    }
}

/// At most 40 characters of `s`, for error messages.
pub(super) fn shorten(s: &str) -> String {
    if s.chars().count() <= 40 {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(40).collect::<String>())
    }
}

/// The offset of the first line (at or after `from`) that is exactly `needle` (ignoring a
/// trailing `\r` and surrounding blanks on that line).
pub(super) fn find_line(data: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    let mut start = from;
    while start < data.len() {
        let rest = &data[start..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        if rest[..end].trim_ascii() == needle {
            return Some(start);
        }
        start += end + 1;
    }
    None
}
