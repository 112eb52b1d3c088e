//! The runs' shared-memory files: each run has its own domain (`<base><launcher pid>_<run id>_`),
//! removed when the run ends; a crashed launcher's files are removed by the next run.

use std::collections::BTreeSet;
use std::path::PathBuf;

use crate::transport;

/// Removes the files of earlier runs whose launcher is no longer alive (it crashed or was
/// killed). Returns the number of files removed.
pub fn remove_stale_runs(base: &str) -> usize {
    let mut stale = BTreeSet::new();
    for file in shared_memory_files(base) {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(rest) = name.strip_prefix(base) else {
            continue;
        };
        let mut parts = rest.splitn(3, '_');
        let (Some(pid), Some(run), Some(_)) = (parts.next(), parts.next(), parts.next()) else {
            continue;
        };
        let Ok(pid) = pid.parse::<i32>() else {
            continue;
        };
        if !process_alive(pid) {
            stale.insert(format!("{base}{pid}_{run}_"));
        }
    }
    stale.iter().map(|prefix| remove_run_files(prefix)).sum()
}

/// Removes every file of the run domain `prefix`, first through iceoryx2 (dead-node cleanup),
/// then whatever remains. Only call it when no process of that run is alive.
pub(super) fn remove_run_files(prefix: &str) -> usize {
    if let Err(e) = transport::cleanup_dead_nodes(prefix) {
        tracing::debug!("iceoryx2 cleanup of {prefix}: {e}");
    }
    let files = shared_memory_files(prefix);
    let mut removed = 0;
    for file in &files {
        if std::fs::remove_file(file).is_ok() {
            removed += 1;
        }
        // iceoryx2 keeps per-node files in a directory named after the node id.
        if let Some(dir) = file.parent()
            && dir.starts_with("/tmp/iceoryx2/nodes/")
        {
            let _ = std::fs::remove_dir(dir);
        }
    }
    removed
}

fn process_alive(pid: i32) -> bool {
    // SAFETY: kill(2) with signal 0 only checks that the process exists.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::kill(pid, 0) };
    rc == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// imuflow's shared-memory and iceoryx2 files on this machine with `prefix`, for `imuflow clean`
/// and tests that prove a run left nothing behind.
pub fn shared_memory_files(prefix: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let roots = [PathBuf::from("/dev/shm"), PathBuf::from("/tmp/iceoryx2")];
    let mut stack: Vec<PathBuf> = roots.to_vec();
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if entry.file_name().to_string_lossy().starts_with(prefix) {
                found.push(path);
            }
        }
    }
    found.sort();
    found
}
