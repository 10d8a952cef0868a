//! A cursor over the bytes of a whole mesh file: whitespace-separated tokens with line
//! numbers for text, fixed-size reads with byte offsets for binary blocks. Every failure is
//! a [`PalpateError::MeshFile`] that names the line (text) or byte offset (binary).

use super::file_err;
use crate::error::{PalpateError, Result};
use std::fmt::Display;
use std::path::Path;
use std::str::FromStr;

/// Reading position in a file, and how to name it in errors.
#[derive(Clone)]
pub(super) struct Cursor<'a> {
    /// The whole file.
    pub data: &'a [u8],
    /// Next byte to read.
    pub pos: usize,
    /// The file, for error messages.
    pub path: &'a Path,
    /// Name places by byte offset (binary data) rather than by line.
    pub binary: bool,
    /// The part of the file being read (a section or keyword), for error messages.
    pub context: &'static str,
}

impl<'a> Cursor<'a> {
    /// A cursor at the start of `data`.
    pub fn new(path: &'a Path, data: &'a [u8]) -> Self {
        Cursor {
            data,
            pos: 0,
            path,
            binary: false,
            context: "",
        }
    }

    /// 1-based line number of byte `pos`.
    pub fn line_at(&self, pos: usize) -> usize {
        let end = pos.min(self.data.len());
        1 + self.data[..end].iter().filter(|&&b| b == b'\n').count()
    }

    /// An error at byte `pos`, named by line (text) or byte offset (binary).
    pub fn err(&self, pos: usize, msg: impl Display) -> PalpateError {
        let place = if self.binary {
            format!("byte {pos}")
        } else {
            format!("line {}", self.line_at(pos))
        };
        let ctx = if self.context.is_empty() {
            String::new()
        } else {
            format!(" ({})", self.context)
        };
        file_err(self.path, format!("{place}{ctx}: {msg}"))
    }

    /// An error at the current position.
    pub fn err_here(&self, msg: impl Display) -> PalpateError {
        self.err(self.pos, msg)
    }

    /// Bytes left after the cursor.
    pub fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    /// Skip spaces, tabs and line breaks.
    pub fn skip_ws(&mut self) {
        while self
            .data
            .get(self.pos)
            .is_some_and(|b| b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
    }

    /// True when only whitespace is left.
    pub fn at_end(&mut self) -> bool {
        self.skip_ws();
        self.pos >= self.data.len()
    }

    /// The next whitespace-separated token and its start.
    pub fn token(&mut self) -> Option<(usize, &'a [u8])> {
        self.skip_ws();
        let start = self.pos;
        while self
            .data
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        (self.pos > start).then(|| (start, &self.data[start..self.pos]))
    }

    /// The next token without moving.
    pub fn peek(&self) -> Option<&'a [u8]> {
        let mut c = self.clone();
        c.token().map(|(_, t)| t)
    }

    /// The next token without moving, if it stands on the current line.
    pub fn peek_on_line(&self) -> Option<&'a [u8]> {
        let rest = &self.data[self.pos.min(self.data.len())..];
        let blanks = rest
            .iter()
            .take_while(|b| **b == b' ' || **b == b'\t')
            .count();
        match rest.get(blanks) {
            Some(b) if !b.is_ascii_whitespace() => self.peek(),
            _ => None,
        }
    }

    /// The next token as text; `what` names it in the error.
    pub fn word(&mut self, what: &str) -> Result<(usize, &'a str)> {
        let (start, tok) = self
            .token()
            .ok_or_else(|| self.err_here(format!("file ends where {what} was expected")))?;
        let s = std::str::from_utf8(tok)
            .map_err(|_| self.err(start, format!("{what} {} is not text", show(tok))))?;
        Ok((start, s))
    }

    /// The next token parsed as a number (any type implementing `FromStr`). A section
    /// marker or keyword where a number was due (`$EndNodes`, `CELL_TYPES`: most often a
    /// count larger than the entries after it) is said to be one.
    pub fn num<T: FromStr>(&mut self, what: &str) -> Result<T> {
        let (start, s) = self.word(what)?;
        s.parse().map_err(|_| {
            let message = if is_section_word(s) {
                format!(
                    "found the keyword {} where {what} was due (a count larger than the entries after it, or a value missing)",
                    show(s.as_bytes())
                )
            } else {
                format!("{what} {} is not a valid number", show(s.as_bytes()))
            };
            self.err(start, message)
        })
    }

    /// The next token as a finite floating-point number.
    pub fn float(&mut self, what: &str) -> Result<f64> {
        let start = self.pos;
        let v: f64 = self.num(what)?;
        if !v.is_finite() {
            return Err(self.err(start, format!("{what} is not finite ({v})")));
        }
        Ok(v)
    }

    /// Expect the token `word` (ASCII case-insensitive).
    pub fn expect(&mut self, word: &str) -> Result<()> {
        match self.token() {
            Some((_, t)) if t.eq_ignore_ascii_case(word.as_bytes()) => Ok(()),
            Some((start, t)) => Err(self.err(start, format!("expected {word}, found {}", show(t)))),
            None => Err(self.err_here(format!("file ends where {word} was expected"))),
        }
    }

    /// The rest of the current line (without its line break) and its start; the cursor
    /// moves to the start of the next line.
    pub fn line(&mut self) -> Option<(usize, &'a [u8])> {
        if self.pos >= self.data.len() {
            return None;
        }
        let start = self.pos;
        let end = self.data[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(self.data.len(), |k| start + k);
        self.pos = (end + 1).min(self.data.len());
        let mut line = &self.data[start..end];
        if line.last() == Some(&b'\r') {
            line = &line[..line.len() - 1];
        }
        Some((start, line))
    }

    /// The next non-blank line, trimmed.
    pub fn nonblank_line(&mut self) -> Option<(usize, &'a [u8])> {
        self.skip_ws();
        self.line().map(|(s, l)| (s, l.trim_ascii()))
    }

    /// Move past the end of the current line: binary data starts after it. Only blanks may
    /// stand between the cursor and the line break.
    pub fn end_line(&mut self) -> Result<()> {
        let start = self.pos;
        if let Some((_, rest)) = self.line() {
            if !rest.trim_ascii().is_empty() {
                return Err(self.err(
                    start,
                    format!("unexpected {} at the end of the line", show(rest)),
                ));
            }
        }
        Ok(())
    }

    /// The next `n` bytes; `what` names them in the error.
    pub fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(self.err(
                self.pos,
                format!(
                    "file ends inside {what} ({n} bytes needed, {} left)",
                    self.remaining()
                ),
            ));
        }
        let b = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(b)
    }

    /// Find `needle` at or after the cursor and move past it.
    pub fn skip_past(&mut self, needle: &[u8]) -> bool {
        match find(&self.data[self.pos.min(self.data.len())..], needle) {
            Some(k) => {
                self.pos += k + needle.len();
                true
            }
            None => false,
        }
    }
}

/// Position of `needle` in `hay`.
pub(super) fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() {
        return Some(0);
    }
    hay.windows(needle.len()).position(|w| w == needle)
}

/// A token for an error message: quoted, escaped, at most 32 characters.
pub(super) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(&tok[..tok.len().min(32)]);
    let more = if tok.len() > 32 { "…" } else { "" };
    format!("{:?}{more}", s)
}

/// A binary number type.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Num {
    /// Signed integer of this many bytes.
    Int(usize),
    /// Unsigned integer of this many bytes.
    UInt(usize),
    /// IEEE float of this many bytes (4 or 8).
    Float(usize),
}

impl Num {
    /// Size in bytes.
    pub fn size(self) -> usize {
        match self {
            Num::Int(n) | Num::UInt(n) | Num::Float(n) => n,
        }
    }

    /// The value of `b` (exactly [`Num::size`] bytes) as f64 (integers beyond 2^53 round).
    pub fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        match self {
            Num::Int(_) => sint(b, big_endian) as f64,
            Num::UInt(_) => uint(b, big_endian) as f64,
            Num::Float(4) => f32::from_bits(uint(b, big_endian) as u32) as f64,
            Num::Float(_) => f64::from_bits(uint(b, big_endian)),
        }
    }
}

/// Unsigned integer of up to 8 bytes.
pub(super) fn uint(b: &[u8], big_endian: bool) -> u64 {
    let fold = |acc: u64, &x: &u8| (acc << 8) | x as u64;
    if big_endian {
        b.iter().fold(0, fold)
    } else {
        b.iter().rev().fold(0, fold)
    }
}

/// Signed (two's complement) integer of 1 to 8 bytes.
pub(super) fn sint(b: &[u8], big_endian: bool) -> i64 {
    let shift = 64 - 8 * b.len().clamp(1, 8) as u32;
    ((uint(b, big_endian) << shift) as i64) >> shift
}

/// A Gmsh section marker (`$EndNodes`) or a keyword of the legacy VTK format (`CELL_TYPES`,
/// `POINT_DATA`, any case): `$` then a letter, or one of the format's keywords.
fn is_section_word(s: &str) -> bool {
    const VTK_KEYWORDS: [&str; 20] = [
        "DATASET",
        "POINTS",
        "CELLS",
        "CELL_TYPES",
        "OFFSETS",
        "CONNECTIVITY",
        "POINT_DATA",
        "CELL_DATA",
        "SCALARS",
        "LOOKUP_TABLE",
        "VECTORS",
        "NORMALS",
        "TENSORS",
        "TENSORS6",
        "GLOBAL_IDS",
        "PEDIGREE_IDS",
        "FIELD",
        "METADATA",
        "COLOR_SCALARS",
        "TEXTURE_COORDINATES",
    ];
    match s.as_bytes() {
        [b'$', c, ..] => c.is_ascii_alphabetic(),
        _ => VTK_KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(s)),
    }
}
