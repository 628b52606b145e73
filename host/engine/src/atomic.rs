//! Writing a command's output file whole or not at all: into a temporary file beside it,
//! renamed into place once everything is written and on disk. A command that fails part
//! way leaves no partial file, and an older file of the same name as it was. (The
//! recorder is the exception: its files are written as samples come, so that a crash keeps
//! what was recorded; docs/recording.md.)

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// A problem writing `path`, named.
fn at(path: &Path, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// The folder `path` is in ("." for a bare name).
fn folder(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Write `path` by `write` into a temporary file beside it, then rename it into place:
/// only if `write` succeeds. `E` carries both the writer's errors and I/O errors.
pub fn write_with<T, E: From<io::Error>>(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&File>) -> Result<T, E>,
) -> Result<T, E> {
    let mut builder = tempfile::Builder::new();
    builder.prefix(".rotacal-");
    // As a file created the usual way would be (a temporary file is private): the old
    // file's permissions, or read-write for the owner and readable by all.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(path).map_or(0o644, |m| m.permissions().mode());
        builder.permissions(std::fs::Permissions::from_mode(mode));
    }
    let tmp = builder.tempfile_in(folder(path)).map_err(|e| at(path, e))?;
    let mut out = BufWriter::new(tmp.as_file());
    let value = write(&mut out)?;
    out.flush().map_err(|e| at(path, e))?;
    drop(out);
    tmp.as_file().sync_all().map_err(|e| at(path, e))?;
    tmp.persist(path).map_err(|e| at(path, e.error))?;
    Ok(value)
}

/// Fill the folder `dir` whole or not at all: `fill` writes into a temporary folder beside
/// it, whose files are moved into `dir` (created if missing) only once `fill` succeeded.
/// Files of `dir` that `fill` did not write are left as they were.
pub fn fill_dir<T, E: From<io::Error>>(
    dir: &Path,
    fill: impl FnOnce(&Path) -> Result<T, E>,
) -> Result<T, E> {
    let staging = tempfile::Builder::new()
        .prefix(".rotacal-")
        .tempdir_in(folder(dir))
        .map_err(|e| at(dir, e))?;
    let value = fill(staging.path())?;
    std::fs::create_dir_all(dir).map_err(|e| at(dir, e))?;
    for entry in std::fs::read_dir(staging.path()).map_err(|e| at(dir, e))? {
        let entry = entry.map_err(|e| at(dir, e))?;
        let to = dir.join(entry.file_name());
        std::fs::rename(entry.path(), &to).map_err(|e| at(&to, e))?;
    }
    Ok(value)
}

/// Write `bytes` to `path`, whole or not at all.
pub fn write(path: &Path, bytes: impl AsRef<[u8]>) -> io::Result<()> {
    write_with(path, |w| w.write_all(bytes.as_ref()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_nothing_and_the_old_file_as_it_was() {
        let d = std::env::temp_dir().join(format!("rotacal-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("out.txt");
        write(&p, "first\n").unwrap();
        let r: io::Result<()> = write_with(&p, |w| {
            w.write_all(b"half of it")?;
            Err(io::Error::other("failed"))
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "first\n");
        std::fs::remove_file(&p).unwrap();
        let _: io::Result<()> = write_with(&p, |_| Err(io::Error::other("failed")));
        assert!(!p.exists());
        // Nothing else in the folder: the temporary files went with their failures.
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 0);
        // A folder: nothing of a failed fill; all of a good one.
        let out = d.join("report");
        let r: io::Result<()> = fill_dir(&out, |tmp| {
            write(&tmp.join("a.svg"), "a")?;
            Err(io::Error::other("failed"))
        });
        assert!(r.is_err() && !out.exists());
        fill_dir(&out, |tmp| write(&tmp.join("a.svg"), "a")).unwrap();
        assert_eq!(std::fs::read_to_string(out.join("a.svg")).unwrap(), "a");
        std::fs::remove_dir_all(&out).unwrap();
        write(&p, "second\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "second\n");
        // Not a temporary file's private permissions.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o644);
        }
        std::fs::remove_dir_all(&d).unwrap();
    }
}
