//! Writing to stdout without panicking: `println!` panics when the reader has gone
//! (`rotacal … | head`), and rotacal must never panic on its way out.

use std::io::{ErrorKind, Write};

/// Write `text` to stdout. A closed pipe ends the output quietly; other errors are
/// returned.
pub fn emit(text: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}
