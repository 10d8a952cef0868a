//! Reading a user's input file (scene, mesh, trajectory): a regular file (after symlinks) of
//! bounded size, so that a path to a device or a FIFO (`/dev/zero`, `/dev/stdin`) is a clear
//! error instead of a read that never ends. [`excerpt`] quotes a piece of one in an error.

use std::io;
use std::path::Path;

/// The largest mesh file read, bytes (a 1M-tet mesh is about 100 MB as text).
pub const MAX_MESH_BYTES: u64 = 8 << 30;
/// The largest scene file read, bytes.
pub const MAX_SCENE_BYTES: u64 = 64 << 20;
/// The largest scripted trajectory read, bytes.
pub const MAX_TRAJECTORY_BYTES: u64 = 1 << 30;

/// The bytes of `path` when it is a regular file of at most `max_bytes`; otherwise an
/// `InvalidInput` error saying which.
pub fn read_regular(path: &Path, max_bytes: u64) -> io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "not a regular file (a directory, device or pipe)",
        ));
    }
    if meta.len() > max_bytes {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{} bytes, more than the {} read", meta.len(), max_bytes),
        ));
    }
    std::fs::read(path)
}

/// [`read_regular`] as UTF-8 text; bytes that are not say the line and column where they
/// start ("line 3, column 9: not UTF-8 text (byte 0xff)").
pub fn read_regular_text(path: &Path, max_bytes: u64) -> io::Result<String> {
    String::from_utf8(read_regular(path, max_bytes)?).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        let before = &bytes[..at];
        let line = 1 + before.iter().filter(|&&b| b == b'\n').count();
        let line_start = before.iter().rposition(|&b| b == b'\n').map_or(0, |k| k + 1);
        let column = 1 + String::from_utf8_lossy(&before[line_start..]).chars().count();
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "line {line}, column {column}: not UTF-8 text (byte 0x{:02x}); save the file as UTF-8",
                bytes[at]
            ),
        )
    })
}

/// Characters of input an error quotes at most ([`excerpt`]).
pub const MAX_EXCERPT_CHARS: usize = 120;

/// `text` as an error may quote it on one line: control characters (a NUL, a tab, a stray
/// escape) and bidirectional controls written as Rust escapes (`\0`, `\t`, `\u{1b}`,
/// `\u{202e}`), and cut after
/// [`MAX_EXCERPT_CHARS`] characters with "… (N more characters)" (a 10 MB line once became
/// a 10 MB error).
pub fn excerpt(text: &str) -> String {
    clip(text, MAX_EXCERPT_CHARS)
}

/// A bidirectional override or isolate (U+202A–U+202E, U+2066–U+2069): printed as it is,
/// it reorders the rest of the console line.
pub fn is_bidi_control(c: char) -> bool {
    matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

/// [`excerpt`] with room for `max_chars` characters (a parser's message, which may quote a
/// value of the input, and lists of expected keys worth keeping whole).
pub fn clip(text: &str, max_chars: usize) -> String {
    let mut out = String::new();
    let mut chars = text.chars();
    for c in chars.by_ref().take(max_chars) {
        if c.is_control() || is_bidi_control(c) {
            out.extend(c.escape_debug());
        } else {
            out.push(c);
        }
    }
    let rest = chars.count();
    if rest > 0 {
        out.push_str(&format!("… ({rest} more characters)"));
    }
    out
}

/// [`clip`], keeping the end too: a text longer than `max_chars` keeps its first three
/// quarters and its last quarter, what is between counted (a long path in an error must not
/// cut off the reason that follows it).
pub fn clip_middle(text: &str, max_chars: usize) -> String {
    let n = text.chars().count();
    if n <= max_chars {
        return clip(text, max_chars);
    }
    let tail = max_chars / 4;
    let head = max_chars - tail;
    let first: String = text.chars().take(head).collect();
    let last: String = text.chars().skip(n - tail).collect();
    format!(
        "{}… ({} characters) …{}",
        clip(&first, head),
        n - head - tail,
        clip(&last, tail)
    )
}

#[cfg(test)]
mod excerpt_tests {
    use super::*;

    #[test]
    fn a_long_text_clipped_in_the_middle_keeps_its_end() {
        let text = format!("{}: cannot write: File name too long", "e/".repeat(2000));
        let c = clip_middle(&text, 200);
        assert!(
            c.starts_with("e/e/") && c.ends_with(": cannot write: File name too long"),
            "{c}"
        );
        assert!(
            c.contains("… (3834 characters) …") && c.chars().count() < 240,
            "{c}"
        );
        assert_eq!(clip_middle("short", 200), "short");
    }

    #[test]
    fn excerpts_escape_control_characters_and_cut_long_text() {
        assert_eq!(excerpt("youngs_modulus = 3e5"), "youngs_modulus = 3e5");
        assert_eq!(excerpt("foo\0bar\tx\u{1b}"), "foo\\0bar\\tx\\u{1b}");
        let long = "a".repeat(MAX_EXCERPT_CHARS + 5000);
        let e = excerpt(&long);
        assert!(e.starts_with(&"a".repeat(MAX_EXCERPT_CHARS)), "{e}");
        assert!(e.ends_with("… (5000 more characters)"), "{e}");
        // Characters, not bytes: a multi-byte character is never split.
        assert_eq!(
            excerpt(&"é".repeat(MAX_EXCERPT_CHARS)),
            "é".repeat(MAX_EXCERPT_CHARS)
        );
    }
}
