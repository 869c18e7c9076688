//! The viewer's error type.

use std::path::PathBuf;

/// Why the viewer could not start or went wrong.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// No display server to open a window on.
    #[error(
        "no display to open a window on ({0}); for a headless machine render to a file with \
         `isin render SCENE -o out.png`, or replay a camera path with `isin fly`"
    )]
    NoDisplay(String),
    /// The window or its drawing surface could not be created or drawn to.
    #[error("window system error: {0}")]
    Window(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
    /// A camera path file is malformed.
    #[error("camera path {path}: {message}")]
    Path {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A camera path file is malformed at a line.
    #[error("camera path {path}:{line}: {message}")]
    PathAt {
        /// The file.
        path: PathBuf,
        /// The line (1-based).
        line: usize,
        /// What is wrong there.
        message: String,
    },
    /// An image could not be encoded or written.
    #[error("cannot write image {path}: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}
