//! The one error type of the readers: every problem names the file, and the line where it has one.

use std::path::{Path, PathBuf};

/// A problem with a recording or a layout: which file, which line (where there is one) and what.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file could not be read at all.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A problem at one line of the file (1-based), e.g. a bad number or a short row.
    #[error("{}:{line}: {message}", path.display())]
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// A problem with the file as a whole, e.g. a missing column or sensor label.
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
}

impl Error {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io {
            path: path.to_owned(),
            source,
        }
    }

    pub(crate) fn line(path: &Path, line: usize, message: impl Into<String>) -> Self {
        Error::Line {
            path: path.to_owned(),
            line,
            message: message.into(),
        }
    }

    pub(crate) fn file(path: &Path, message: impl Into<String>) -> Self {
        Error::File {
            path: path.to_owned(),
            message: message.into(),
        }
    }
}

/// Reads a whole text file, naming it when that fails. A `.gz` file is decompressed first (gzip,
/// as `gzip` and most exporters' "compress" options write it); other compressed or binary files
/// are named as such instead of failing as text that is not UTF-8.
pub(crate) fn read_text(path: &Path) -> Result<String, Error> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    // Gzip by its magic bytes (RFC 1952: 1f 8b), whatever the extension says.
    let bytes = if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::MultiGzDecoder::new(&bytes[..]), &mut out)
            .map_err(|e| Error::file(path, format!("cannot decompress the gzip file: {e}")))?;
        out
    } else {
        bytes
    };
    if let Some(kind) = compressed_kind(&bytes) {
        return Err(Error::file(
            path,
            format!("a {kind} file: not supported (gzip `.gz` is); decompress it first"),
        ));
    }
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let text = std::str::from_utf8(&e.as_bytes()[..at]).unwrap_or_default();
        Error::line(
            path,
            crate::layout::line_of(text, at),
            format!(
                "not UTF-8 text (byte {at}): export the file as UTF-8 (or ASCII) text, uncompressed or gzip"
            ),
        )
    })
}

/// Compressed or archive formats recognised by their magic bytes, to name them in the error.
fn compressed_kind(bytes: &[u8]) -> Option<&'static str> {
    const KINDS: [(&[u8], &str); 5] = [
        (b"PK\x03\x04", "zip"),
        (b"BZh", "bzip2"),
        (&[0xfd, b'7', b'z', b'X', b'Z', 0x00], "xz"),
        (&[0x28, 0xb5, 0x2f, 0xfd], "zstd"),
        (&[b'7', b'z', 0xbc, 0xaf, 0x27, 0x1c], "7-zip"),
    ];
    KINDS
        .iter()
        .find(|(magic, _)| bytes.starts_with(magic))
        .map(|(_, kind)| *kind)
}
