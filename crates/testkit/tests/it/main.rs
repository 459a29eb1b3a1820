//! Integration tests of gonio-testkit: one test binary.
//!
//! - `imports_fixtures`: the import-loop check on small fixture crates written to a temporary directory.
//! - `no_import_loops`: ARCHITECTURE.md's rule, checked on this workspace.
//! - `typed_errors`: no public function of a library crate returns `Result<_, String>`.

mod imports_fixtures;
mod no_import_loops;
mod typed_errors;
