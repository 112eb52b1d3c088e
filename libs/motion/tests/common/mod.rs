//! Shared by the data-set tests (they need extracted data sets and are ignored by default).

use std::path::{Path, PathBuf};

/// Every `.bvh` file under `dir`, recursively (an unreadable folder adds none).
pub fn bvh_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            bvh_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "bvh") {
            out.push(p);
        }
    }
}
