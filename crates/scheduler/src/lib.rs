//! (module map added with the crate)
