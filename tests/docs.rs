//! The docs are documentation, not a lab notebook: what a newcomer reads is short, current and
//! runnable. The rules, each a test below:
//!
//! - README.md has at most 200 lines.
//! - The docs (README.md, docs/*.md, docs/results/*.md, models/README.md, python/README.md and the
//!   crate READMEs graph/, libs/*/, stages/*/, tools/*/) name no absolute machine path: none of
//!   [`MACHINE_PATHS`] where a path starts. Use placeholders (`DATA=path/to/data`, `$CKPT`). The
//!   journal (docs/journal/) is held to this rule too.
//! - The docs hold no diary: no heading (a line that starts with `#`, outside code blocks) with a
//!   date `YYYY-MM-DD`, and none of [`DIARY_PHRASES`] anywhere. History goes to
//!   docs/journal/YYYY-MM-DD-topic.md, which is exempt from this rule.
//! - Every `configs/....toml` the docs mention exists and is valid: a graph passes
//!   `imuflow graph check`; an ablation file (one with `[[variant]]`s) passes
//!   `imuflow compare FILE --print-graph`, which loads and validates every variant and combines
//!   them. Templates (`configs/<graph>.toml`) are skipped; a `*` must match at least one file.
//!   Sensor layouts and tracker maps (`configs/sensor-layouts/`, `configs/trackers/`) only have to
//!   exist: their readers' tests load them.
//! - The README's two commands (the first lines of its code blocks that start with `cargo test` and
//!   with `cargo run ... -- run`): the test command is the one .ci/run runs, and the run command's
//!   graph (with none given, `imuflow run`'s default) exists and passes `imuflow graph check`.
//! - docs/architecture.md exists and graph/src/frames.rs (the wire contract) points to it.
//! - Every relative markdown link in the docs and the journal resolves to a file or folder.

mod common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use common::{Sandbox, text};

/// Absolute paths of one machine; a doc uses placeholders instead.
const MACHINE_PATHS: [&str; 7] = [
    "/home/", "/root/", "/tmp/", "/work/", "/Users/", "/mnt/", "C:\\",
];

/// Phrases of a diary (compared in lower case): a doc says what is true, not when it was found.
const DIARY_PHRASES: [&str; 7] = [
    "this evening",
    "this morning",
    "this afternoon",
    "the first binary of the day",
    "at the start of the day",
    "this 2-core vm",
    "the session's first",
];

/// The graph `imuflow run` runs when none is given (src/main.rs).
const DEFAULT_GRAPH: &str = "configs/examples/sample.toml";

const README_MAX_LINES: usize = 200;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `path` relative to the repository, for messages.
fn rel(path: &Path) -> String {
    path.strip_prefix(root())
        .unwrap_or(path)
        .display()
        .to_string()
}

/// The `*.md` files directly in `dir`, sorted; none when it does not exist.
fn markdown_in(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == "md"))
        .collect();
    files.sort();
    files
}

/// `parent/*/README.md`, sorted.
fn crate_readmes(parent: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(root().join(parent))
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path().join("README.md"))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

/// The documentation a user reads (the journal apart).
fn docs() -> Vec<PathBuf> {
    let r = root();
    let mut files = vec![r.join("README.md")];
    files.extend(markdown_in(&r.join("docs")));
    files.extend(markdown_in(&r.join("docs/results")));
    for single in ["models/README.md", "python/README.md", "graph/README.md"] {
        if r.join(single).is_file() {
            files.push(r.join(single));
        }
    }
    for parent in ["libs", "stages", "tools"] {
        files.extend(crate_readmes(parent));
    }
    files
}

/// The dated history: docs/journal/*.md.
fn journal() -> Vec<PathBuf> {
    markdown_in(&root().join("docs/journal"))
}

/// Each line (numbered from 1) and whether it belongs to a fenced code block (fences included).
fn lines_with_fences(text: &str) -> Vec<(usize, &str, bool)> {
    let mut in_code = false;
    let mut lines = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fence = {
            let t = line.trim_start();
            t.starts_with("```") || t.starts_with("~~~")
        };
        if fence {
            in_code = !in_code;
        }
        lines.push((i + 1, line, in_code || fence));
    }
    lines
}

/// The lines of the fenced code blocks, trimmed, each without a trailing `# comment`.
fn code_lines(text: &str) -> Vec<String> {
    lines_with_fences(text)
        .into_iter()
        .filter(|(_, line, code)| {
            let t = line.trim_start();
            *code && !t.starts_with("```") && !t.starts_with("~~~")
        })
        .map(|(_, line, _)| {
            let line = line.split(" #").next().unwrap_or("");
            line.trim().to_owned()
        })
        .filter(|line| !line.is_empty())
        .collect()
}

/// The first machine path in `line`: one of [`MACHINE_PATHS`] where a path starts (the line's start
/// or after a character that cannot continue a path), so `out/tmp/x` or `$DATA/work/x` is not one.
fn machine_path(line: &str) -> Option<&'static str> {
    MACHINE_PATHS.into_iter().find(|pattern| {
        line.match_indices(*pattern).any(|(at, _)| {
            line[..at]
                .chars()
                .next_back()
                .is_none_or(|c| !(c.is_alphanumeric() || "._-/~})".contains(c)))
        })
    })
}

/// Whether `line` holds a date `YYYY-MM-DD`.
fn holds_date(line: &str) -> bool {
    line.as_bytes().windows(10).any(|w| {
        w.iter().enumerate().all(|(i, b)| match i {
            4 | 7 => *b == b'-',
            _ => b.is_ascii_digit(),
        })
    })
}

#[test]
fn the_readme_is_at_most_200_lines() {
    let lines = read(&root().join("README.md")).lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines, at most {README_MAX_LINES}: move detail to docs/ and history to docs/journal/"
    );
}

#[test]
fn the_docs_name_no_machine_path_and_hold_no_diary() {
    let mut problems = Vec::new();
    for file in docs().iter().chain(journal().iter()) {
        let is_journal = file.starts_with(root().join("docs/journal"));
        let text = read(file);
        for (n, line, code) in lines_with_fences(&text) {
            if let Some(pattern) = machine_path(line) {
                problems.push(format!(
                    "{}:{n}: machine path ({pattern}): {line}",
                    rel(file)
                ));
            }
            if is_journal {
                continue;
            }
            if !code && line.trim_start().starts_with('#') && holds_date(line) {
                problems.push(format!("{}:{n}: dated heading: {line}", rel(file)));
            }
            let lower = line.to_lowercase();
            if let Some(phrase) = DIARY_PHRASES.iter().find(|p| lower.contains(*p)) {
                problems.push(format!("{}:{n}: diary ({phrase:?}): {line}", rel(file)));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "docs must describe what is true now, with no machine paths (history: docs/journal/):\n{}",
        problems.join("\n")
    );
}

/// Every `configs/....toml` mentioned in `text`.
fn config_mentions(text: &str) -> Vec<String> {
    let mut found = Vec::new();
    for (at, _) in text.match_indices("configs/") {
        let before = text[..at].chars().next_back();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '-') {
            continue;
        }
        let rest = &text[at..];
        let end = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || "_-./*<>{}$".contains(c)))
            .unwrap_or(rest.len());
        let token = rest[..end].trim_end_matches('.');
        if token.ends_with(".toml") {
            found.push(token.to_owned());
        }
    }
    found
}

/// The files a mention names: itself, or what its one `*` matches in its folder.
fn expand(mention: &str) -> Vec<PathBuf> {
    if !mention.contains('*') {
        return vec![root().join(mention)];
    }
    let (dir, pattern) = mention.rsplit_once('/').unwrap_or(("", mention));
    let (prefix, suffix) = pattern.split_once('*').unwrap_or((pattern, ""));
    let mut files: Vec<PathBuf> = std::fs::read_dir(root().join(dir))
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.len() >= prefix.len() + suffix.len()
                && name.starts_with(prefix)
                && name.ends_with(suffix)
        })
        .map(|e| e.path())
        .collect();
    files.sort();
    files
}

/// Why `file` (a graph or an ablation file) is not valid, if it is not.
fn invalid_config(sb: &Sandbox, file: &Path) -> Option<String> {
    let path = file.to_str().expect("utf8 path");
    let ablation = read(file).contains("[[variant]]");
    let out = if ablation {
        sb.run(&["compare", path, "--print-graph"])
    } else {
        sb.run(&["graph", "check", path])
    };
    let ok = out.status.success() && (ablation || text(&out.stdout).contains(": ok ("));
    (!ok).then(|| {
        let how = if ablation {
            "imuflow compare --print-graph"
        } else {
            "imuflow graph check"
        };
        format!(
            "{}: {how} fails:\n{}{}",
            rel(file),
            text(&out.stdout),
            text(&out.stderr)
        )
    })
}

#[test]
fn every_config_the_docs_mention_exists_and_is_valid() {
    let mut mentions: BTreeSet<(String, String)> = BTreeSet::new();
    for file in docs() {
        for mention in config_mentions(&read(&file)) {
            if !mention.contains(['<', '{', '$']) {
                mentions.insert((mention, rel(&file)));
            }
        }
    }
    assert!(
        mentions.iter().any(|(m, _)| m == "configs/pip.toml"),
        "the docs mention configs/pip.toml (the mention scan works): {mentions:?}"
    );
    let mut problems = Vec::new();
    let mut files = BTreeSet::new();
    for (mention, doc) in &mentions {
        let found = expand(mention);
        if found.is_empty() {
            problems.push(format!("{doc}: {mention} matches no file"));
        }
        for file in found {
            // Sensor layouts and tracker maps are not graphs; their readers' tests read them.
            if file.is_file()
                && (mention.starts_with("configs/sensor-layouts/")
                    || mention.starts_with("configs/trackers/"))
            {
                continue;
            }
            if file.is_file() {
                files.insert(file);
            } else {
                problems.push(format!("{doc}: {mention} does not exist"));
            }
        }
    }
    let sb = Sandbox::new("docs-configs");
    problems.extend(files.iter().filter_map(|file| invalid_config(&sb, file)));
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_readme_commands_are_the_ones_ci_runs_and_their_graph_is_valid() {
    let readme = code_lines(&read(&root().join("README.md")));
    let ci: Vec<String> = read(&root().join(".ci/run"))
        .lines()
        .map(str::trim)
        .filter(|l| l.starts_with("cargo test"))
        .map(str::to_owned)
        .collect();
    assert_eq!(
        ci,
        ["cargo test --workspace"],
        ".ci/run runs the tests with one command"
    );
    let test = readme.iter().find(|l| l.starts_with("cargo test"));
    assert_eq!(
        test,
        Some(&ci[0]),
        "the README's test command (in a code block) is the one .ci/run runs"
    );

    // `cargo run [cargo options] -- run [GRAPH] [options]`
    let run_args = readme
        .iter()
        .filter(|l| l.starts_with("cargo run"))
        .filter_map(|l| l.split_once(" -- ").map(|(_, args)| args))
        .map(|args| args.split_whitespace().collect::<Vec<_>>())
        .find(|args| args.first() == Some(&"run"))
        .expect("a `cargo run ... -- run` command in a README code block");
    let graph = run_args
        .iter()
        .find(|a| a.ends_with(".toml"))
        .copied()
        .unwrap_or(DEFAULT_GRAPH);
    let file = root().join(graph);
    assert!(
        file.is_file(),
        "the README's run command's graph {graph} exists"
    );
    let sb = Sandbox::new("docs-readme-run");
    if let Some(problem) = invalid_config(&sb, &file) {
        panic!("the README's run command: {problem}");
    }
}

#[test]
fn the_architecture_doc_exists_and_the_wire_contract_points_to_it() {
    let doc = root().join("docs/architecture.md");
    assert!(doc.is_file(), "docs/architecture.md exists");
    let frames = read(&root().join("graph/src/frames.rs"));
    assert!(
        frames.contains("docs/architecture.md"),
        "graph/src/frames.rs points to docs/architecture.md"
    );
}

/// Inline code spans removed from a line (a link inside backticks is not a link).
fn without_inline_code(line: &str) -> String {
    let mut out = String::new();
    let mut in_code = false;
    for c in line.chars() {
        if c == '`' {
            in_code = !in_code;
        } else if !in_code {
            out.push(c);
        }
    }
    out
}

/// The targets of the markdown links in `text` (inline `[text](target)`, images, and reference
/// definitions `[label]: target`), outside code, with their line numbers.
fn link_targets(text: &str) -> Vec<(usize, String)> {
    let mut targets = Vec::new();
    for (n, line, code) in lines_with_fences(text) {
        if code {
            continue;
        }
        let line = without_inline_code(line);
        let trimmed = line.trim_start();
        if trimmed.starts_with('[')
            && let Some((_, target)) = trimmed.split_once("]: ")
        {
            targets.push((n, target.trim().to_owned()));
        }
        for (at, _) in line.match_indices("](") {
            let rest = &line[at + 2..];
            let end = rest.find(')').unwrap_or(rest.len());
            targets.push((n, rest[..end].trim().to_owned()));
        }
    }
    targets
}

/// The file a relative link target names, from the doc `from`; `None` for a link that is not
/// relative (a URL, an anchor in the same page).
fn link_file(from: &Path, target: &str) -> Option<PathBuf> {
    let target = target
        .trim_start_matches('<')
        .split(['>', ' ', '\t'])
        .next()
        .unwrap_or("");
    let path = target.split(['#', '?']).next().unwrap_or("");
    if path.is_empty() || target.contains("://") || target.starts_with("mailto:") {
        return None;
    }
    let path = path.replace("%20", " ");
    Some(match path.strip_prefix('/') {
        Some(from_root) => root().join(from_root),
        None => from.parent().expect("a doc's folder").join(path),
    })
}

#[test]
fn every_relative_link_in_the_docs_resolves() {
    let mut problems = Vec::new();
    let mut links = 0;
    for file in docs().iter().chain(journal().iter()) {
        for (n, target) in link_targets(&read(file)) {
            if let Some(path) = link_file(file, &target) {
                links += 1;
                if !path.exists() {
                    problems.push(format!("{}:{n}: ({target}) does not resolve", rel(file)));
                }
            }
        }
    }
    assert!(
        links > 0,
        "no relative links found: the link scan is broken"
    );
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
