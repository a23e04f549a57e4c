//! The one way the workspace writes a file that must survive a crash or a
//! full disk whole (checkpoints, the learner's state, `summary.json`): into
//! a temporary file beside it, synced to disk, renamed over the old one,
//! and the directory synced, so that after a crash the path holds either
//! the old file or the new one, never a part of either.

use std::path::{Path, PathBuf};

/// The temporary file `atomic_write` writes first: the path with `.tmp`
/// added (`best.safetensors.tmp`).
pub fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(".tmp");
    path.with_file_name(name)
}

/// Writes `path` through `write`, which is given the temporary path to
/// write; then [`commit`]s it. On any failure the temporary file is
/// removed and `path` is left as it was; `io` turns an I/O error of the
/// commit into the caller's error (naming the file).
pub fn atomic_write<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
    io: impl FnOnce(std::io::Error) -> E,
) -> Result<(), E> {
    let tmp = tmp_path(path);
    let done = write(&tmp).and_then(|()| commit(&tmp, path).map_err(io));
    if done.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    done
}

/// Makes the finished file `tmp` the file `path`: syncs its data, renames
/// it over `path`, and syncs the directory so that the rename is durable.
pub fn commit(tmp: &Path, path: &Path) -> std::io::Result<()> {
    std::fs::File::open(tmp)?.sync_all()?;
    std::fs::rename(tmp, path)?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::File::open(dir)?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = std::env::temp_dir().join(format!("rotorhive-durable-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.bin");
        atomic_write(&path, |t| std::fs::write(t, b"old"), |e| e).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        let failed = atomic_write(
            &path,
            |t| {
                std::fs::write(t, b"half")?;
                Err(std::io::Error::other("disk full"))
            },
            |e| e,
        );
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"old", "the old file stays");
        assert!(!tmp_path(&path).exists(), "no temporary file is left");
        atomic_write(&path, |t| std::fs::write(t, b"new"), |e| e).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
