//! Scene loading errors and the helpers that turn byte offsets into lines.

use crate::cameras::CameraError;
use std::fmt;
use std::ops::Range;

/// A place in a scene file: its name and a 1-based line (0 when unknown).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Location {
    /// Scene file name, as given to [`crate::parse_scene`].
    pub file: String,
    /// 1-based line number, or 0 when the error concerns the whole file.
    pub line: usize,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 { write!(f, "{}", self.file) } else { write!(f, "{}:{}", self.file, self.line) }
    }
}

/// Why a scene could not be loaded. Every variant names the scene file and,
/// where it can, the line and the field or object concerned.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The TOML text does not parse or does not match the scene format: syntax
    /// errors, unknown keys, wrong types, NaN or infinite numbers.
    #[error("{at}:{column}: {message}\n    | {snippet}")]
    Syntax {
        /// File and line.
        at: Location,
        /// 1-based column.
        column: usize,
        /// What is wrong.
        message: String,
        /// The offending line of the scene file.
        snippet: String,
    },
    /// A value is well-formed TOML but not acceptable (a missing or
    /// inapplicable field, an out-of-range number, a wrong vertex count…).
    #[error("{at}: {what}: {message}")]
    Invalid {
        /// File and line.
        at: Location,
        /// The object, light, material… and field concerned, e.g. `objects[2].segments`.
        what: String,
        /// What is wrong.
        message: String,
    },
    /// A material or texture name that the scene does not define.
    #[error("{at}: {what} refers to unknown {kind} `{name}` (defined: {defined})")]
    UnknownName {
        /// File and line of the reference.
        at: Location,
        /// Who refers to it, e.g. `objects[3].material`.
        what: String,
        /// `material` or `texture`.
        kind: &'static str,
        /// The unknown name.
        name: String,
        /// The names that are defined, comma-separated.
        defined: String,
    },
    /// An asset file (mesh, MTL library, buffer, image) could not be read.
    #[error("{at}: {what}: cannot read asset `{path}`: {reason}")]
    MissingAsset {
        /// File and line of the scene entry that (directly or indirectly) needs it.
        at: Location,
        /// The object, material or texture that needs it.
        what: String,
        /// The asset's path relative to the scene file.
        path: String,
        /// Why it could not be read.
        reason: String,
    },
    /// An asset file was read but its content is unusable (bad OBJ, glTF or image).
    #[error("{at}: {what}: bad asset `{path}`: {message}")]
    BadAsset {
        /// File and line of the scene entry that needs it.
        at: Location,
        /// The object, material or texture that needs it.
        what: String,
        /// The asset's path relative to the scene file.
        path: String,
        /// What is wrong with it.
        message: String,
    },
    /// The camera cannot produce rays.
    #[error("{at}: invalid camera: {source}")]
    Camera {
        /// File and line of the `[camera]` section.
        at: Location,
        /// The camera's own complaint.
        source: CameraError,
    },
    /// The scene has no triangles at all.
    #[error("{file}: the scene is empty: it defines no triangles (add some [[objects]])")]
    Empty {
        /// Scene file name.
        file: String,
    },
}

/// Maps byte offsets of a scene file to lines and columns.
pub(crate) struct SourceMap<'a> {
    /// Scene file name.
    pub file: &'a str,
    /// Scene file text.
    pub text: &'a str,
}

impl<'a> SourceMap<'a> {
    /// 1-based (line, column) of a byte offset.
    pub fn line_col(&self, offset: usize) -> (usize, usize) {
        let offset = offset.min(self.text.len());
        let before = &self.text.as_bytes()[..offset];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let line_start = before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
        let column = self.text[line_start..offset].chars().count() + 1;
        (line, column)
    }

    /// Location of a byte offset.
    pub fn at(&self, offset: usize) -> Location {
        Location { file: self.file.to_owned(), line: self.line_col(offset).0 }
    }

    /// Location of the line where `key = …` is written inside `span`, or of
    /// the span's start when the key is not written there (a default).
    pub fn field(&self, span: &Range<usize>, key: &str) -> Location {
        self.at(self.field_offset(span, key).unwrap_or(span.start))
    }

    fn field_offset(&self, span: &Range<usize>, key: &str) -> Option<usize> {
        let text = self.text.get(span.clone())?;
        let bytes = text.as_bytes();
        let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_' || b == b'-';
        text.match_indices(key)
            .map(|(i, _)| i)
            .find(|&i| {
                let before_ok = i == 0 || !ident(bytes[i - 1]);
                let rest = text[i + key.len()..].trim_start_matches([' ', '\t']);
                before_ok && rest.starts_with('=')
            })
            .map(|i| span.start + i)
    }

    /// The text of the 1-based line `line`.
    pub fn line_text(&self, line: usize) -> &'a str {
        self.text.lines().nth(line.saturating_sub(1)).unwrap_or("").trim_end()
    }

    /// Converts a TOML deserialisation error.
    pub fn syntax(&self, e: &toml::de::Error) -> SceneError {
        let (line, column) = e.span().map_or((0, 0), |s| self.line_col(s.start));
        SceneError::Syntax {
            at: Location { file: self.file.to_owned(), line },
            column,
            message: excerpt(&e.message().trim().replace('\n', ": ")),
            snippet: excerpt(self.line_text(line)),
        }
    }
}

/// Longest excerpt of a scene's text an error message quotes, in characters.
pub const EXCERPT_CHARS: usize = 120;

/// At most [`EXCERPT_CHARS`] of `text` (then `…`), control characters shown
/// as `�`: a one-line 200 MB file of zeros is quoted in a line, not echoed.
pub fn excerpt(text: &str) -> String {
    let mut out: String = text
        .chars()
        .take(EXCERPT_CHARS)
        .map(|c| if c.is_control() && c != '\t' { '\u{FFFD}' } else { c })
        .collect();
    if text.chars().nth(EXCERPT_CHARS).is_some() {
        out.push('…');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_huge_line_of_zeros_is_quoted_short() {
        let text = "\0".repeat(10_000_000);
        let e = crate::parse_scene("zeros.toml", &text, &mut crate::SceneBundle::default()).unwrap_err();
        let shown = e.to_string();
        assert!(shown.len() < 2 * EXCERPT_CHARS * 4, "{} bytes", shown.len());
        assert!(!shown.contains('\0'), "{shown}");
        assert!(shown.starts_with("zeros.toml:1"), "{shown}");
    }

    #[test]
    fn offsets_map_to_lines_and_columns() {
        let m = SourceMap { file: "a.toml", text: "one\ntwo = 2\n  three = [1]\n" };
        assert_eq!(m.line_col(0), (1, 1));
        assert_eq!(m.line_col(4), (2, 1));
        assert_eq!(m.line_col(6), (2, 3));
        assert_eq!(m.line_col(14), (3, 3));
        assert_eq!(m.at(14).to_string(), "a.toml:3");
        assert_eq!(m.line_text(3), "  three = [1]");
    }

    #[test]
    fn field_lines_are_found_inside_a_span() {
        let text = "[a]\nx = 1\nxx = 2\n\n[b]\nfoo_x = 3\nx= 4\n";
        let m = SourceMap { file: "f", text };
        let b = text.find("[b]").unwrap();
        assert_eq!(m.field(&(b..text.len()), "x").line, 7, "`foo_x` is not `x`");
        assert_eq!(m.field(&(0..b), "xx").line, 3);
        assert_eq!(m.field(&(0..b), "y").line, 1, "absent keys point at the section");
    }
}
