//! Parts of the `rotacal` binary that are terminal UI rather than library: the progress
//! display and the wiring of `record`.
pub mod import;
pub mod record;
