//! rotacal host library.
