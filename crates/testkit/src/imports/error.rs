//! Why the import scan could not look at the workspace. Odd source text is never an error (the lexer and
//! scanner take anything); only the file system can fail.

use std::io;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ImportScanError {
    /// A manifest, source file or directory that could not be read (a source file that is not UTF-8 is one:
    /// rustc could not compile it either).
    #[error("cannot read {}: {source}", path.display())]
    Read { path: PathBuf, source: io::Error },
    /// The root holds no crate at all: most likely the wrong directory, and "no loops" would be a false pass.
    #[error("no crate with a [package] and a src/lib.rs or src/main.rs under {}", .0.display())]
    NoCrates(PathBuf),
}
