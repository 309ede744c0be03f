//! Files written so that a reader sees the old file or the complete new one,
//! never a part of one (an interrupted run, a full disk): the bytes go to a
//! temporary name in the same folder, are synced, then renamed over the target.
//! On failure the temporary file is removed and the target is left as it was.
//! A killed process cannot remove its temporaries: [`remove_stale_siblings`]
//! and [`remove_stale_temporaries`] let the next run delete those of dead
//! processes.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// The temporary name next to `path`: `.<name>.<pid>.tmp`.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Writes `path` through `write` (given a buffered writer on the temporary
/// file), then syncs and renames it into place.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let temp = temp_path(path);
    let result = (|| {
        let mut out = BufWriter::new(File::create(&temp)?);
        write(&mut out)?;
        let file = out.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&temp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result
}

/// Delete the temporaries [`write_atomically`] left next to `path` in
/// processes that were killed mid-write (`.<name>.<pid>.tmp` of dead
/// processes). For outputs a run rewrites under its own lock (the journal,
/// poses.json), called before writing them. Returns how many were removed.
pub fn remove_stale_temporaries(path: &Path) -> usize {
    remove_dead(path, |file, name| {
        file.strip_prefix('.')?
            .strip_prefix(name)?
            .strip_prefix('.')?
            .strip_suffix(".tmp")?
            .parse()
            .ok()
    })
}

/// Writes `bytes` as the whole of `path`, atomically.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomically(path, |out| out.write_all(bytes))
}

/// True unless process `pid` of this machine is known to be gone (no
/// `/proc/<pid>`). Without `/proc` nothing is known, so every process counts
/// as alive and nothing is deleted.
pub fn process_alive(pid: u32) -> bool {
    pid == std::process::id()
        || !Path::new("/proc/self").exists()
        || Path::new(&format!("/proc/{pid}")).exists()
}

/// Delete the temporaries of dead processes next to `path`: files named
/// `<name><tag><pid>` or `<name><tag><pid>-<n>` for each tag in `tags` (the
/// COG writer's `.spill-` and `.tmp-`). Returns how many were removed;
/// errors are ignored (a temporary that cannot be removed is harmless).
pub fn remove_stale_siblings(path: &Path, tags: &[&str]) -> usize {
    remove_dead(path, |file, name| {
        let rest = file.strip_prefix(name)?;
        let tail = tags.iter().find_map(|t| rest.strip_prefix(t))?;
        let pid_text = tail.split('-').next().unwrap_or("");
        let pid = pid_text.parse::<u32>().ok()?;
        let tail_ok = tail[pid_text.len()..]
            .strip_prefix('-')
            .is_none_or(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
        tail_ok.then_some(pid)
    })
}

/// Removes the files next to `path` for which `pid_of(file name, name of
/// path)` names a process that is gone; how many were removed.
fn remove_dead(path: &Path, pid_of: impl Fn(&str, &str) -> Option<u32>) -> usize {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
        return 0;
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let name = name.to_string_lossy();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.filter_map(Result::ok) {
        let file = entry.file_name().to_string_lossy().into_owned();
        let dead = pid_of(&file, &name).is_some_and(|pid| !process_alive(pid));
        if dead && std::fs::remove_file(entry.path()).is_ok() {
            tracing::info!(path = %entry.path().display(), "stale temporary removed");
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stale_siblings_of_dead_processes_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("fused.tif");
        let me = std::process::id();
        let names = [
            "fused.tif.spill-0-3".to_string(), // pid 0: never a live process
            "fused.tif.tmp-0".to_string(),
            format!("fused.tif.spill-{me}-0"), // alive: kept
            "fused.tif.spill-0-x".to_string(), // not ours: kept
            "other.tif.spill-0-1".to_string(), // another output: kept
        ];
        for n in &names {
            std::fs::write(dir.path().join(n), b"x").unwrap();
        }
        assert_eq!(remove_stale_siblings(&out, &[".spill-", ".tmp-"]), 2);
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut want = names[2..].to_vec();
        want.sort();
        assert_eq!(left, want);
    }

    #[test]
    fn temporaries_of_killed_writers_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("p.json.journal");
        let mine = temp_path(&out);
        let names = [
            ".p.json.journal.0.tmp", // pid 0: never a live process
            ".p.json.journal.x.tmp", // not a pid: kept
            ".p.json.0.tmp",         // another output: kept
            "p.json.journal",
        ];
        for n in names {
            std::fs::write(dir.path().join(n), b"x").unwrap();
        }
        std::fs::write(&mine, b"x").unwrap(); // this process is alive: kept
        assert_eq!(remove_stale_temporaries(&out), 1);
        assert!(!dir.path().join(names[0]).exists());
        assert!(names[1..].iter().all(|n| dir.path().join(n).exists()));
        assert!(mine.exists());
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.json");
        write_atomically(&path, |w| w.write_all(b"old")).unwrap();
        let err = write_atomically(&path, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("disk full"))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "disk full");
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "the temporary file is gone");
    }
}
