//! [`OutputLock`]: one `align` at a time per output. An exclusive lock
//! (`File::try_lock`, flock on Unix) on `<out>.lock`, taken before the journal is
//! opened and held until the poses are written; a second run on the same
//! `--out` is refused instead of truncating the first one's journal. The lock
//! file stays (removing it would let a third run lock a new file while the
//! second still holds the old one); the lock ends with the process.

use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};

use super::JournalError;

/// Held while an `align` writes `<out>` and `<out>.journal`.
#[derive(Debug)]
pub struct OutputLock {
    _file: File,
    path: PathBuf,
}

impl OutputLock {
    /// The lock file of an output: `<out>.lock`.
    pub fn path_for(output: &Path) -> PathBuf {
        let mut name = output
            .file_name()
            .map(|n| n.to_os_string())
            .unwrap_or_default();
        name.push(".lock");
        output.with_file_name(name)
    }

    /// Takes the lock of `output`, or fails at once if another process holds it.
    pub fn acquire(output: &Path) -> Result<OutputLock, JournalError> {
        let path = Self::path_for(output);
        let io = |source| JournalError::Io {
            path: path.display().to_string(),
            source,
        };
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => Ok(OutputLock { _file: file, path }),
            Err(std::fs::TryLockError::WouldBlock) => Err(JournalError::Busy {
                output: output.display().to_string(),
                lock: path.display().to_string(),
            }),
            Err(std::fs::TryLockError::Error(source)) => Err(io(source)),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_on_one_output_is_refused_until_the_first_ends() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("poses.json");
        let first = OutputLock::acquire(&out).unwrap();
        assert_eq!(first.path(), dir.path().join("poses.json.lock"));
        let second = OutputLock::acquire(&out).unwrap_err();
        assert!(matches!(second, JournalError::Busy { .. }), "{second}");
        assert!(second.to_string().contains("another dsmstream align"));
        drop(first);
        OutputLock::acquire(&out).unwrap();
    }
}
