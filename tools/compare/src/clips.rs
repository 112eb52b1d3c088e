//! Which clips a batch runs: the `--data` folders (each with its joint mapping, labelled by the
//! folder's name when there are several), the split of each (`train` ... `holdout` by the rule of
//! `imuflow dataset build`, or `all`), the clips an exclusion list leaves out, and `--limit`.

use std::fmt;
use std::path::{Path, PathBuf};

use anyhow::Context;
use imuflow_dataset::{Split, find_bvh_files, split_of};

/// One folder of clips (`--data`).
#[derive(Clone, Debug, PartialEq)]
pub struct DataSource {
    /// The folder's name: labels its clips (the `source` column) when a batch mixes folders.
    pub name: String,
    pub dir: PathBuf,
    /// Its clips' joint-mapping TOML (default: Bandai Namco).
    pub mapping: Option<PathBuf>,
}

impl DataSource {
    /// The `--data` folders with their `--mapping` files: no mapping (Bandai Namco for all), one
    /// for every folder, or one per folder in the same order. Two folders with the same name are
    /// refused: their clips could not be told apart.
    pub fn from_args(dirs: &[PathBuf], mappings: &[PathBuf]) -> anyhow::Result<Vec<DataSource>> {
        if mappings.len() > 1 && mappings.len() != dirs.len() {
            anyhow::bail!(
                "{} --mapping files for {} --data folders: give one mapping for all folders, or one per folder in the order of --data",
                mappings.len(),
                dirs.len()
            );
        }
        let mut sources: Vec<DataSource> = Vec::with_capacity(dirs.len());
        for (k, dir) in dirs.iter().enumerate() {
            let name = folder_name(dir);
            if let Some(other) = sources.iter().find(|s| s.name == name) {
                anyhow::bail!(
                    "--data {} and --data {} are both named '{name}': each folder's name labels its clips, so give folders with different names",
                    other.dir.display(),
                    dir.display()
                );
            }
            let mapping = match mappings {
                [] => None,
                [one] => Some(one.clone()),
                each => Some(each[k].clone()),
            };
            sources.push(DataSource {
                name,
                dir: dir.clone(),
                mapping,
            });
        }
        Ok(sources)
    }
}

/// The last component of `dir` (of its absolute form for `.` or `..`).
fn folder_name(dir: &Path) -> String {
    let named = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| n != "." && n != "..")
    };
    named(dir)
        .or_else(|| dir.canonicalize().ok().as_deref().and_then(named))
        .unwrap_or_else(|| dir.display().to_string())
}

/// Which clips of each folder: one split of the dataset rule, or every clip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Selection {
    Split(Split),
    /// Every clip: a folder that is not training data (another data set) has no split.
    All,
}

impl Selection {
    /// The values `--split` accepts.
    pub const NAMES: [&'static str; 5] = ["train", "validation", "test", "holdout", "all"];

    pub fn parse(name: &str) -> Option<Selection> {
        if name == "all" {
            return Some(Selection::All);
        }
        Split::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .map(Selection::Split)
    }

    pub fn name(self) -> &'static str {
        match self {
            Selection::Split(s) => s.name(),
            Selection::All => "all",
        }
    }

    fn contains(self, key: &str) -> bool {
        match self {
            Selection::Split(s) => split_of(key) == s,
            Selection::All => true,
        }
    }
}

impl fmt::Display for Selection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Clips left out by name (`--exclude FILE`): one per line, the clip's file name or its path under
/// its `--data` folder; `#` starts a comment.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Exclusions {
    /// The list's file, for messages and the report.
    pub file: Option<PathBuf>,
    /// Each entry with its line.
    entries: Vec<(String, usize)>,
}

impl Exclusions {
    pub fn read(path: &Path) -> anyhow::Result<Exclusions> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the exclusion list {}", path.display()))?;
        let entries = text
            .lines()
            .enumerate()
            .filter_map(|(i, line)| {
                let entry = line.split('#').next().unwrap_or_default().trim();
                (!entry.is_empty()).then(|| (entry.replace('\\', "/"), i + 1))
            })
            .collect();
        Ok(Exclusions {
            file: Some(path.to_owned()),
            entries,
        })
    }

    /// The entry that names `key` (a clip's path under its folder): the whole key, or its last
    /// components.
    fn matching(&self, key: &str) -> Option<usize> {
        self.entries.iter().position(|(entry, _)| {
            key == entry
                || key
                    .strip_suffix(entry.as_str())
                    .is_some_and(|head| head.ends_with('/'))
        })
    }
}

/// One clip of a batch.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    /// Its name in the results: the path under its folder, after `<source>/` when a batch mixes
    /// folders.
    pub key: String,
    pub path: PathBuf,
    /// Index into the batch's sources.
    pub source: usize,
}

/// The clips a batch runs, and the ones it leaves out.
#[derive(Debug, PartialEq)]
pub struct Selected {
    pub clips: Vec<Clip>,
    /// Clips of the selection that the exclusion list names (their keys).
    pub excluded: Vec<String>,
}

/// The selection's clips of every source (sorted by source, then key) that the exclusion list
/// does not name; at most `limit`, spread evenly so a limited run still sees every kind of motion
/// of a sorted list (Bandai's clips sort by dataset and content). Entries of the list that name
/// no clip of any folder are reported (a misspelt name would silently keep its clip).
pub fn select_clips(
    sources: &[DataSource],
    selection: Selection,
    limit: Option<usize>,
    exclusions: &Exclusions,
) -> anyhow::Result<Selected> {
    if limit == Some(0) {
        anyhow::bail!("--limit must be at least 1");
    }
    let mut clips = Vec::new();
    let mut excluded = Vec::new();
    let mut used = vec![false; exclusions.entries.len()];
    for (k, source) in sources.iter().enumerate() {
        let all = find_bvh_files(&source.dir)
            .with_context(|| format!("--data {}", source.dir.display()))?;
        for (key, path) in all {
            let named = exclusions.matching(&key);
            if let Some(e) = named {
                used[e] = true;
            }
            if !selection.contains(&key) {
                continue;
            }
            let key = if sources.len() > 1 {
                format!("{}/{key}", source.name)
            } else {
                key
            };
            match named {
                Some(_) => excluded.push(key),
                None => clips.push(Clip {
                    key,
                    path,
                    source: k,
                }),
            }
        }
    }
    if let Some(file) = &exclusions.file {
        for ((entry, line), used) in exclusions.entries.iter().zip(used) {
            if !used {
                eprintln!(
                    "warning: {}:{line}: '{entry}' names no clip under --data",
                    file.display()
                );
            }
        }
    }
    if clips.is_empty() {
        let folders: Vec<String> = sources
            .iter()
            .map(|s| s.dir.display().to_string())
            .collect();
        anyhow::bail!(
            "--data {}: no .bvh clip {}{}",
            folders.join(", "),
            match selection {
                Selection::Split(s) => format!(
                    "falls in the {s} split (the split rule of `imuflow dataset build`; --split all takes every clip)"
                ),
                Selection::All => "found".to_owned(),
            },
            if excluded.is_empty() {
                String::new()
            } else {
                format!(" but the {} the exclusion list names", excluded.len())
            }
        );
    }
    Ok(Selected {
        clips: spread(clips, limit),
        excluded,
    })
}

/// At most `limit` of `clips`, evenly spread over them.
fn spread(clips: Vec<Clip>, limit: Option<usize>) -> Vec<Clip> {
    match limit {
        Some(n) if n < clips.len() => {
            let total = clips.len();
            (0..n).map(|i| clips[i * total / n].clone()).collect()
        }
        _ => clips,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Folder(PathBuf);

    impl Folder {
        /// A fresh folder under the temp dir holding `files` (relative paths), each a stub.
        fn new(name: &str, files: &[&str]) -> Folder {
            let dir = std::env::temp_dir()
                .join(format!("imuflow-clips-{}-{name}", std::process::id()))
                .join(name);
            let _ = std::fs::remove_dir_all(&dir);
            for f in files {
                let path = dir.join(f);
                std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                std::fs::write(path, "x").unwrap();
            }
            Folder(dir)
        }
    }

    impl Drop for Folder {
        fn drop(&mut self) {
            if let Some(parent) = self.0.parent() {
                let _ = std::fs::remove_dir_all(parent);
            }
        }
    }

    fn source(folder: &Folder) -> DataSource {
        DataSource::from_args(std::slice::from_ref(&folder.0), &[])
            .unwrap()
            .remove(0)
    }

    #[test]
    fn a_limited_selection_spreads_over_the_sorted_clips() {
        // Enough names that the test split (10 % by hash) holds several.
        let names: Vec<String> = (0..200).map(|i| format!("clip_{i:03}.bvh")).collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let folder = Folder::new("spread", &refs);
        let sources = [source(&folder)];
        let test = Selection::Split(Split::Test);
        let none = Exclusions::default();
        let all = select_clips(&sources, test, None, &none).unwrap().clips;
        assert!(all.len() >= 6, "{} test clips", all.len());
        assert!(all.iter().all(|c| split_of(&c.key) == Split::Test));
        let three = select_clips(&sources, test, Some(3), &none).unwrap().clips;
        let n = all.len();
        let expected: Vec<_> = [0, n / 3, 2 * n / 3]
            .iter()
            .map(|&i| all[i].clone())
            .collect();
        assert_eq!(three, expected);
        assert!(select_clips(&sources, test, Some(0), &none).is_err());
        let every = select_clips(&sources, Selection::All, None, &none).unwrap();
        assert_eq!(every.clips.len(), 200, "`all` ignores the split rule");
        let missing = DataSource {
            dir: folder.0.join("missing"),
            ..sources[0].clone()
        };
        let err = select_clips(&[missing], test, None, &none).unwrap_err();
        assert!(format!("{err:#}").contains("missing"), "{err:#}");
    }

    #[test]
    fn several_folders_label_their_clips_by_folder_name_and_keep_their_own_mapping() {
        let a = Folder::new("bandai", &["walk.bvh", "sub/run.bvh"]);
        let b = Folder::new("cmu", &["bvh/walk.bvh"]);
        let mappings = [PathBuf::from("bandai.toml"), PathBuf::from("cmu.toml")];
        let sources = DataSource::from_args(&[a.0.clone(), b.0.clone()], &mappings).unwrap();
        assert_eq!(sources[0].name, "bandai");
        assert_eq!(sources[1].mapping.as_deref(), Some(Path::new("cmu.toml")));
        let picked = select_clips(&sources, Selection::All, None, &Exclusions::default())
            .unwrap()
            .clips;
        let keys: Vec<(&str, usize)> = picked.iter().map(|c| (c.key.as_str(), c.source)).collect();
        assert_eq!(
            keys,
            [
                ("bandai/sub/run.bvh", 0),
                ("bandai/walk.bvh", 0),
                ("cmu/bvh/walk.bvh", 1)
            ]
        );
        // One mapping serves every folder; any other count than 0, 1 or one per folder is refused.
        let one = DataSource::from_args(&[a.0.clone(), b.0.clone()], &mappings[..1]).unwrap();
        assert!(
            one.iter()
                .all(|s| s.mapping.as_deref() == Some(Path::new("bandai.toml")))
        );
        let three = [
            mappings[0].clone(),
            mappings[1].clone(),
            mappings[0].clone(),
        ];
        let err = DataSource::from_args(&[a.0.clone(), b.0.clone()], &three).unwrap_err();
        assert!(
            err.to_string().contains("3 --mapping files for 2 --data"),
            "{err}"
        );
        // Two folders of the same name cannot be told apart.
        let twin = Folder::new("cmu-twin", &[]);
        let same = twin.0.join("cmu");
        let err = DataSource::from_args(&[b.0.clone(), same], &[]).unwrap_err();
        assert!(err.to_string().contains("both named 'cmu'"), "{err}");
    }

    #[test]
    fn an_exclusion_list_names_clips_by_file_name_or_path_and_reports_strays() {
        let folder = Folder::new(
            "excl",
            &["bvh/001_08.bvh", "bvh/002_01.bvh", "other/001_08x.bvh"],
        );
        let list = folder.0.join("../exclude.txt");
        std::fs::write(
            &list,
            "# climbing\n001_08.bvh   # no floor\n\nbvh/002_01.bvh\nnot_there.bvh\n",
        )
        .unwrap();
        let exclusions = Exclusions::read(&list).unwrap();
        let sources = [source(&folder)];
        let picked = select_clips(&sources, Selection::All, None, &exclusions).unwrap();
        let keys: Vec<&str> = picked.clips.iter().map(|c| c.key.as_str()).collect();
        // `001_08.bvh` names bvh/001_08.bvh, not other/001_08x.bvh (whole components only).
        assert_eq!(keys, ["other/001_08x.bvh"]);
        assert_eq!(picked.excluded, ["bvh/001_08.bvh", "bvh/002_01.bvh"]);
        // Everything excluded: refused, saying why.
        std::fs::write(&list, "001_08.bvh\n002_01.bvh\n001_08x.bvh\n").unwrap();
        let all_out = Exclusions::read(&list).unwrap();
        let err = select_clips(&sources, Selection::All, None, &all_out).unwrap_err();
        assert!(
            err.to_string()
                .contains("but the 3 the exclusion list names"),
            "{err}"
        );
        let err = Exclusions::read(&folder.0.join("nope.txt")).unwrap_err();
        assert!(format!("{err:#}").contains("nope.txt"), "{err:#}");
    }

    #[test]
    fn the_split_names_include_all() {
        for name in Selection::NAMES {
            assert_eq!(Selection::parse(name).unwrap().name(), name);
        }
        assert_eq!(
            Selection::parse("test"),
            Some(Selection::Split(Split::Test))
        );
        assert_eq!(Selection::parse("everything"), None);
    }
}
