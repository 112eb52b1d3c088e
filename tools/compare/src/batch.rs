//! Batch mode of `imuflow compare`: every clip of a dataset split (or of whole folders, several data
//! sets side by side) through all variants, then the variants' means over clips and their paired
//! differences with bootstrap intervals, per data set too when a batch mixes them.
//!
//! Each clip runs exactly what a single comparison runs: the variants combined into one graph
//! (byte-identical input to every variant), launched as processes, its recording scored by
//! [`score_recording`]. The source is the clip's motion with the variants' sensors synthesized the way
//! `imuflow compare --input clip.bvh` does (T-pose + walk calibration prelude, random mountings,
//! the reference sensor noise), so the numbers are end to end, calibration included.
//!
//! Every finished clip is appended to `OUT/clips.jsonl` at once, so an interrupted or crashed batch
//! resumes where it stopped (the same variants and split; `fresh` starts over). A clip whose run
//! fails, or in which a variant's branch stopped, is listed with the reason and left out of every
//! mean and pair (a clip counts for all variants or for none, so pairs stay paired).

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::io::{BufRead, Write as _};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::clips::{Clip, DataSource, Exclusions, Selected, Selection, select_clips};
use crate::combine::{AblationVariant, SensorErrors, SinkPaths, Variant};
use crate::run::{CombinedRun, Input, RunError, run_combined};
use anyhow::Context;
use imuflow_graph::launch::LaunchOptions;
use imuflow_graph::spec::Registry;
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use crate::plots;
use crate::report::{Row, fmt_value, score_recording};
use imuflow_eval::score::{PairedDifference, paired_bootstrap};

/// Resamples of the paired bootstrap; 2000 keeps the 2.5 % / 97.5 % percentiles within about
/// ±0.05 standard errors of their limit.
const RESAMPLES: usize = 2000;

/// Fewer paired clips than this get a mean difference but no interval: a percentile bootstrap over
/// a handful of clips gives intervals far too narrow (one clip: a single point).
pub const MIN_PAIRS_FOR_INTERVAL: usize = 5;

/// What to run and where the results go.
pub struct BatchOptions {
    /// The comparison's name (graph name, report title).
    pub name: String,
    pub out: PathBuf,
    /// The motion clips: folders of .bvh files, each with its joint mapping.
    pub sources: Vec<DataSource>,
    /// Which clips of each folder: a split as `imuflow dataset build` splits them, or all.
    pub selection: Selection,
    /// Clips left out by name.
    pub exclusions: Exclusions,
    /// At most this many clips, spread evenly over the selection's sorted clip list.
    pub limit: Option<usize>,
    /// What the synthesized IMUs get wrong besides their mounting.
    pub sensor_errors: SensorErrors,
    /// Source parameters set after the clip replaced the source (`--source-set`).
    pub source_set: Vec<(String, toml::Value)>,
    /// How each clip's graph is launched (its own progress bar and logs stay off).
    pub imuflow_exe: PathBuf,
    /// The batch's progress bar.
    pub progress: bool,
    /// Keep each clip's recording (`OUT/recordings/`); deleted once scored otherwise.
    pub keep_recordings: bool,
    /// Discard earlier results in `OUT` instead of resuming.
    pub fresh: bool,
    /// Identifies the variants (their files' contents): results of other variants are not mixed.
    pub fingerprint: String,
    /// The command line, printed in the report so the table can be regenerated.
    pub command: String,
}

/// One clip's scores (a line of `clips.jsonl`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClipRecord {
    /// The clip's key (path relative to its data folder, after `<source>/` when a batch mixes
    /// folders).
    pub clip: String,
    /// Its data folder's name, when a batch mixes folders.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    /// Frames every variant was scored on.
    pub frames: usize,
    pub rows: Vec<Row>,
    /// Why the clip was not scored; `None` when it was.
    pub error: Option<String>,
    pub wall_s: f64,
}

/// The first line of `clips.jsonl`: which comparison the clips belong to.
#[derive(Debug, PartialEq, Serialize, Deserialize)]
struct Header {
    variants: Vec<String>,
    fingerprint: String,
    split: String,
}

/// How a batch ended.
pub struct BatchOutcome {
    pub report: PathBuf,
    pub scored: usize,
    pub failed: usize,
    /// Clips of the selection not run (the user stopped the batch).
    pub remaining: usize,
}

/// Mean, sample standard deviation and count of one variant's per-clip values.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Stats {
    pub mean: f64,
    pub std: f64,
    pub n: usize,
}

/// One metric over the clips: each variant's stats and every pair's paired difference.
#[derive(Debug, Serialize)]
pub struct MetricSummary {
    pub metric: String,
    pub unit: String,
    pub lower_is_better: bool,
    pub stats: Vec<Option<Stats>>,
    pub pairs: Vec<Pair>,
}

/// Variant `b` minus variant `a` (`a` < `b` in variant order) on the clips both have a value for.
#[derive(Debug, Serialize)]
pub struct Pair {
    pub a: usize,
    pub b: usize,
    pub difference: Option<PairedDifference>,
    /// Enough clips ([`MIN_PAIRS_FOR_INTERVAL`]) for the interval to mean something.
    pub with_interval: bool,
}

/// Runs the batch (see the module docs).
pub fn run(
    variants: &[Variant],
    registry: &Registry,
    options: &BatchOptions,
) -> anyhow::Result<BatchOutcome> {
    let Selected { clips, excluded } = select_clips(
        &options.sources,
        options.selection,
        options.limit,
        &options.exclusions,
    )?;
    std::fs::create_dir_all(&options.out)
        .with_context(|| format!("cannot create {}", options.out.display()))?;
    let names: Vec<String> = variants.iter().map(|v| v.name.clone()).collect();
    let header = Header {
        variants: names.clone(),
        fingerprint: options.fingerprint.clone(),
        split: options.selection.name().to_owned(),
    };
    // One batch per folder: two writing the same clips.jsonl and recordings corrupt both.
    let lock_path = options.out.join(".lock");
    let lock = std::fs::File::create(&lock_path)
        .with_context(|| format!("cannot create {}", lock_path.display()))?;
    if lock.try_lock().is_err() {
        anyhow::bail!(
            "another imuflow compare batch is writing to {}; wait for it or use another --out",
            options.out.display()
        );
    }
    let log_path = options.out.join("clips.jsonl");
    let mut records = open_log(&log_path, &header, options.fresh)?;
    let done: BTreeSet<String> = records.iter().map(|r| r.clip.clone()).collect();
    let todo: Vec<&Clip> = clips.iter().filter(|c| !done.contains(&c.key)).collect();
    if !done.is_empty() {
        eprintln!(
            "resuming: {} of {} clips already in {} ({} to run; --fresh starts over)",
            clips.len() - todo.len(),
            clips.len(),
            log_path.display(),
            todo.len()
        );
    }

    // A Ctrl-C between two clips' runs: each run watches its own flag only while it runs.
    let stop = Arc::new(AtomicBool::new(false));
    let signal_ids: Vec<_> = [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM]
        .into_iter()
        .filter_map(|sig| signal_hook::flag::register(sig, stop.clone()).ok())
        .collect();
    let bar = clip_bar(todo.len(), options.progress);
    let mut log = std::fs::OpenOptions::new()
        .append(true)
        .open(&log_path)
        .with_context(|| format!("cannot append to {}", log_path.display()))?;
    let mut remaining = todo.len();
    for clip in &todo {
        let key = &clip.key;
        if stop.load(Ordering::Relaxed) {
            break;
        }
        bar.set_message(key.clone());
        let Some(record) = run_clip(variants, registry, options, clip, &stop)? else {
            break; // interrupted: the clip is not recorded, a resume runs it again
        };
        if let Some(error) = &record.error {
            // suspend, not println: println prints nothing when the bar is hidden (no terminal).
            bar.suspend(|| eprintln!("warning: clip {key} not scored: {error}"));
        }
        let line = serde_json::to_string(&record)?;
        writeln!(log, "{line}")
            .and_then(|()| log.flush())
            .with_context(|| format!("cannot append to {}", log_path.display()))?;
        records.push(record);
        remaining -= 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    for id in signal_ids {
        signal_hook::low_level::unregister(id);
    }

    let selected: BTreeSet<&str> = clips.iter().map(|c| c.key.as_str()).collect();
    records.retain(|r| selected.contains(r.clip.as_str()));
    let scored: Vec<&ClipRecord> = records.iter().filter(|r| r.error.is_none()).collect();
    let failed: Vec<&ClipRecord> = records.iter().filter(|r| r.error.is_some()).collect();
    let summaries = summarize(&names, &scored);
    let per_source = summarize_sources(options, &names, &scored);
    let plot = quantile_plot(&options.out, &names, &scored)?;
    let outcome = Outcomes {
        scored: &scored,
        failed: &failed,
        excluded: &excluded,
        remaining,
    };
    let report = markdown(
        options,
        variants,
        &names,
        &summaries,
        &per_source,
        &outcome,
        plot,
    );
    let report_path = options.out.join("report.md");
    std::fs::write(&report_path, report)
        .with_context(|| format!("cannot write {}", report_path.display()))?;
    let json = serde_json::json!({
        "variants": names,
        "split": options.selection.name(),
        "data": options.sources.iter().map(|s| s.dir.display().to_string()).collect::<Vec<_>>(),
        "clips_scored": scored.len(),
        "clips_failed": failed.iter().map(|r| serde_json::json!({"clip": r.clip, "error": r.error})).collect::<Vec<_>>(),
        "clips_excluded": excluded,
        "clips_not_run": remaining,
        "frames_scored": scored.iter().map(|r| r.frames).sum::<usize>(),
        "bootstrap_resamples": RESAMPLES,
        "metrics": summaries,
        "sources": per_source.iter().map(|s| serde_json::json!({
            "name": s.name,
            "data": s.dir.display().to_string(),
            "mapping": s.mapping.as_ref().map(|m| m.display().to_string()),
            "clips_scored": s.clips,
            "metrics": s.summaries,
        })).collect::<Vec<_>>(),
        "per_clip": "clips.jsonl",
    });
    let json_path = options.out.join("results.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    Ok(BatchOutcome {
        report: report_path,
        scored: scored.len(),
        failed: failed.len(),
        remaining,
    })
}

/// Reads the earlier results in `path` (creating it with `header` if absent or `fresh`).
fn open_log(path: &Path, header: &Header, fresh: bool) -> anyhow::Result<Vec<ClipRecord>> {
    let write_header = || -> anyhow::Result<Vec<ClipRecord>> {
        std::fs::write(path, format!("{}\n", serde_json::to_string(header)?))
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(Vec::new())
    };
    if fresh || !path.exists() {
        return write_header();
    }
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut lines = std::io::BufReader::new(file).lines().enumerate();
    let Some((_, first)) = lines.next() else {
        return write_header();
    };
    let earlier: Header = serde_json::from_str(&first?)
        .with_context(|| format!("{}:1: not a compare batch header", path.display()))?;
    if earlier != *header {
        anyhow::bail!(
            "{} holds the results of another comparison (variants {}, split {}); use --fresh to discard them or another --out",
            path.display(),
            earlier.variants.join(", "),
            earlier.split
        );
    }
    let mut records = Vec::new();
    for (i, line) in lines {
        let line = line.with_context(|| format!("cannot read {}", path.display()))?;
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str::<ClipRecord>(&line) {
            Ok(r) => records.push(r),
            // A line cut short by a crash: the clip is run again.
            Err(e) => eprintln!(
                "warning: {}:{}: unreadable clip record ({e}); that clip runs again",
                path.display(),
                i + 1
            ),
        }
    }
    Ok(records)
}

fn clip_bar(len: usize, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "compare {bar:30} {pos}/{len} clips [{elapsed} < {eta}] {wide_msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// Runs one clip through the combined graph and scores it; `None` when the user stopped it.
fn run_clip(
    variants: &[Variant],
    registry: &Registry,
    options: &BatchOptions,
    clip: &Clip,
    stop: &AtomicBool,
) -> anyhow::Result<Option<ClipRecord>> {
    let start = Instant::now();
    let key = clip.key.as_str();
    let source = &options.sources[clip.source];
    let label = (options.sources.len() > 1).then(|| source.name.clone());
    let failed = |error: String| ClipRecord {
        clip: key.to_owned(),
        source: label.clone(),
        frames: 0,
        rows: Vec::new(),
        error: Some(error),
        wall_s: start.elapsed().as_secs_f64(),
    };
    let recordings = options.out.join("recordings");
    std::fs::create_dir_all(&recordings)
        .with_context(|| format!("cannot create {}", recordings.display()))?;
    let mcap = recordings.join(format!("{}.mcap", key.replace(['/', '\\'], "__")));
    let sinks = SinkPaths {
        mcap: mcap.display().to_string(),
        rrd: None,
        overlaid: false,
    };
    let input = Input {
        path: clip.path.clone(),
        mapping: source.mapping.clone(),
        sensor_errors: options.sensor_errors,
        source_set: options.source_set.clone(),
    };
    let launch_options = LaunchOptions {
        imuflow_exe: options.imuflow_exe.clone(),
        progress: false,
        forward_logs: false,
    };
    let run = CombinedRun {
        name: &options.name,
        variants,
        input: Some(&input),
        sinks: &sinks,
        graph_path: &options.out.join(format!("{}.toml", options.name)),
        registry,
        launch: &launch_options,
    };
    let record = match run_combined(&run, |_, _| {}) {
        // The clip's file could not become the source: the clip's fault, the batch goes on.
        Err(RunError::Input(e)) => Some(failed(e)),
        // Stopped by the user: whatever the run says, the clip is not done (a resume runs it).
        _ if stop.load(Ordering::Relaxed) => None,
        Err(RunError::Launch(e)) => Some(failed(e)),
        // The variants were checked before the batch started: a refusal now is not the clip's
        // fault, and neither is an invalid combination or an unwritable folder.
        Err(e) => return Err(e.into()),
        Ok(ran) if ran.report.interrupted => None,
        Ok(ran) => Some(match ran.report.failed_branches.first() {
            Some(branch) => failed(format!("variant branch stopped: {branch}")),
            None => match score_recording(&mcap, &ran.combined, ran.graph.rate_hz) {
                Ok(scored) if scored.frames == 0 => {
                    failed("no frame usable in every variant".into())
                }
                Ok(scored) => ClipRecord {
                    clip: key.to_owned(),
                    source: label.clone(),
                    frames: scored.frames,
                    rows: scored.rows,
                    error: None,
                    wall_s: start.elapsed().as_secs_f64(),
                },
                Err(e) => failed(format!("{e:#}")),
            },
        }),
    };
    // Whatever the outcome: a failed run may have left a partial recording too.
    if !options.keep_recordings {
        let _ = std::fs::remove_file(&mcap);
    }
    Ok(record)
}

/// Rows that are not a quality of the estimate: a count, and latencies that in an offline run
/// measure how far the source ran ahead.
fn is_aggregated(row: &Row) -> bool {
    row.name != "frames scored" && !row.name.starts_with("source-to-motion latency")
}

/// Every metric over the scored clips: stats per variant, paired differences per pair.
pub fn summarize(names: &[String], scored: &[&ClipRecord]) -> Vec<MetricSummary> {
    let mut metrics: Vec<(String, String, bool)> = Vec::new();
    for record in scored {
        for row in record.rows.iter().filter(|r| is_aggregated(r)) {
            if !metrics.iter().any(|(name, _, _)| *name == row.name) {
                metrics.push((row.name.clone(), row.unit.clone(), row.lower_is_better));
            }
        }
    }
    let value = |record: &ClipRecord, metric: &str, k: usize| -> Option<f64> {
        record
            .rows
            .iter()
            .find(|r| r.name == metric)
            .and_then(|r| r.values.get(k).copied().flatten())
            .filter(|v| v.is_finite())
    };
    metrics
        .into_iter()
        .map(|(metric, unit, lower_is_better)| {
            let stats = (0..names.len())
                .map(|k| {
                    let values: Vec<f64> =
                        scored.iter().filter_map(|r| value(r, &metric, k)).collect();
                    stats_of(&values)
                })
                .collect();
            let mut pairs = Vec::new();
            for a in 0..names.len() {
                for b in a + 1..names.len() {
                    let (va, vb): (Vec<f64>, Vec<f64>) = scored
                        .iter()
                        .filter_map(|r| Some((value(r, &metric, a)?, value(r, &metric, b)?)))
                        .unzip();
                    // b − a: negative when b is lower. Seeded: the same clips give the same interval.
                    let difference = paired_bootstrap(&vb, &va, RESAMPLES, 0).ok();
                    let with_interval = va.len() >= MIN_PAIRS_FOR_INTERVAL;
                    pairs.push(Pair {
                        a,
                        b,
                        difference,
                        with_interval,
                    });
                }
            }
            MetricSummary {
                metric,
                unit,
                lower_is_better,
                stats,
                pairs,
            }
        })
        .collect()
}

fn stats_of(values: &[f64]) -> Option<Stats> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    let std = if n > 1 {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
    } else {
        0.0
    };
    Some(Stats { mean, std, n })
}

/// Per-clip joint position error of each variant, sorted.
fn quantile_plot(
    out: &Path,
    names: &[String],
    scored: &[&ClipRecord],
) -> anyhow::Result<Option<PathBuf>> {
    const METRIC: &str = "joint position error";
    let per_variant: Vec<(String, Vec<f64>)> = names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let values = scored
                .iter()
                .filter_map(|r| r.rows.iter().find(|row| row.name == METRIC))
                .filter_map(|row| row.values.get(k).copied().flatten())
                .collect();
            (name.clone(), values)
        })
        .collect();
    if per_variant.iter().all(|(_, v)| v.is_empty()) {
        return Ok(None);
    }
    plots::clip_quantiles(out, "clip_errors.png", METRIC, "cm", &per_variant)
        .context("per-clip error plot")
        .map(Some)
}

/// What became of the selection's clips.
struct Outcomes<'a> {
    scored: &'a [&'a ClipRecord],
    failed: &'a [&'a ClipRecord],
    /// Keys of the clips the exclusion list left out.
    excluded: &'a [String],
    /// Clips not run (the user stopped the batch).
    remaining: usize,
}

/// One data folder's share of a batch that mixes folders.
pub struct SourceSummary {
    pub name: String,
    pub dir: PathBuf,
    pub mapping: Option<PathBuf>,
    /// Its clips scored.
    pub clips: usize,
    /// The metrics over its clips alone.
    pub summaries: Vec<MetricSummary>,
}

/// Each folder's metrics over its own scored clips, when the batch has more than one folder.
fn summarize_sources(
    options: &BatchOptions,
    names: &[String],
    scored: &[&ClipRecord],
) -> Vec<SourceSummary> {
    if options.sources.len() < 2 {
        return Vec::new();
    }
    options
        .sources
        .iter()
        .map(|source| {
            let own: Vec<&ClipRecord> = scored
                .iter()
                .copied()
                .filter(|r| r.source.as_deref() == Some(source.name.as_str()))
                .collect();
            SourceSummary {
                name: source.name.clone(),
                dir: source.dir.clone(),
                mapping: source.mapping.clone(),
                clips: own.len(),
                summaries: summarize(names, &own),
            }
        })
        .collect()
}

fn markdown(
    options: &BatchOptions,
    variants: &[Variant],
    names: &[String],
    summaries: &[MetricSummary],
    per_source: &[SourceSummary],
    outcome: &Outcomes,
    plot: Option<PathBuf>,
) -> String {
    let mut md = String::new();
    let (scored, failed, remaining) = (outcome.scored, outcome.failed, outcome.remaining);
    let frames: usize = scored.iter().map(|r| r.frames).sum();
    let what = match options.selection {
        Selection::Split(split) => format!("on the {split} split"),
        Selection::All => "on every clip".to_owned(),
    };
    let _ = writeln!(
        md,
        "# imuflow compare (batch): {} {what}\n",
        names.join(" vs ")
    );
    let folders: Vec<String> = options
        .sources
        .iter()
        .map(|s| format!("`{}`", s.dir.display()))
        .collect();
    let _ = writeln!(
        md,
        "{} clips of {} scored ({frames} frames){}{}{}. Each clip ran as one combined graph (every variant on byte-identical input: {} synthesized from the clip with a T-pose + walk calibration prelude, random sensor mountings and {}), scored on the frames all variants share{}. Means are over clips (each clip counts once, whatever its length).\n",
        scored.len(),
        folders.join(" and "),
        if failed.is_empty() {
            String::new()
        } else {
            format!("; {} not scored (listed below)", failed.len())
        },
        if outcome.excluded.is_empty() {
            String::new()
        } else {
            format!(
                "; {} left out by the exclusion list (below)",
                outcome.excluded.len()
            )
        },
        if remaining > 0 {
            format!(
                "; **stopped early: {remaining} clips not run** (run the same command again to resume)"
            )
        } else {
            String::new()
        },
        match crate::combine::union_of_sets(variants) {
            Ok(set) if set == imuflow_graph::graph::DEFAULT_SENSORS => "six IMUs".to_owned(),
            Ok(set) => format!("the IMUs of the sensor set `{set}`"),
            Err(_) => "the IMUs".to_owned(),
        },
        options.sensor_errors.describe(),
        if options.source_set.is_empty() {
            String::new()
        } else {
            let set: Vec<String> = options
                .source_set
                .iter()
                .map(|(k, v)| format!("`{k} = {v}`"))
                .collect();
            format!("; the source's parameters then set: {}", set.join(", "))
        },
    );
    let _ = writeln!(md, "Regenerate: `{}`\n", options.command);

    let _ = writeln!(md, "## Mean ± standard deviation over clips\n");
    means_table(&mut md, names, summaries, None);
    let sets = variants
        .iter()
        .map(|v| (v.name.as_str(), v.graph.sensors.as_str()));
    if let Some(note) = crate::report::unobserved_note(sets) {
        let _ = writeln!(md, "\n{note}");
    }
    if !per_source.is_empty() {
        let _ = writeln!(
            md,
            "\n## Mean ± standard deviation over each data set's clips\n\nEach `--data` folder (named by its last component) on its own clips; the table above pools them.\n"
        );
        for (k, source) in per_source.iter().enumerate() {
            means_table(
                &mut md,
                names,
                &source.summaries,
                Some((&source.name, k == 0)),
            );
        }
    }

    let pairs: Vec<(usize, usize)> = summaries
        .first()
        .map(|s| s.pairs.iter().map(|p| (p.a, p.b)).collect())
        .unwrap_or_default();
    if !pairs.is_empty() {
        let _ = writeln!(
            md,
            "\n## Paired differences, 95 % confidence intervals\n\nEach cell is the mean over clips of (second − first) with a paired percentile bootstrap interval ({RESAMPLES} resamples of whole clips, seed 0; none below {MIN_PAIRS_FOR_INTERVAL} clips). **Bold**: the interval excludes 0, so the difference is more than clip-to-clip noise; negative means the second variant is lower. A metric that needs long clips (translation at 7 m of travel) is paired over the clips that have it.\n"
        );
        let _ = write!(md, "| metric |");
        for (a, b) in &pairs {
            let _ = write!(md, " {} − {} |", names[*b], names[*a]);
        }
        let _ = writeln!(md);
        let _ = writeln!(md, "|---|{}", "---:|".repeat(pairs.len()));
        for s in summaries.iter().filter(|s| s.lower_is_better) {
            let _ = write!(md, "| {}{} |", s.metric, unit_suffix(&s.unit));
            for p in &s.pairs {
                let cell = p.difference.map_or("–".to_owned(), |d| {
                    let mean = fmt_value(Some(d.mean_diff));
                    if !p.with_interval {
                        let clips = if d.n == 1 { "clip" } else { "clips" };
                        return format!("{mean} ({} {clips}, no interval)", d.n);
                    }
                    let interval = format!(
                        "[{}, {}]",
                        fmt_value(Some(d.ci95_low)),
                        fmt_value(Some(d.ci95_high))
                    );
                    if d.ci95_low > 0.0 || d.ci95_high < 0.0 {
                        format!("**{mean}** {interval}")
                    } else {
                        format!("{mean} {interval}")
                    }
                });
                let _ = write!(md, " {cell} |");
            }
            let _ = writeln!(md);
        }
    }
    if let Some(plot) = plot {
        let file = plot
            .file_name()
            .map_or_else(String::new, |f| f.to_string_lossy().into_owned());
        let _ = writeln!(
            md,
            "\n## Per-clip error\n\n![joint position error per clip, sorted]({file})\n"
        );
    }
    if !failed.is_empty() {
        let _ = writeln!(md, "\n## Clips not scored\n");
        for r in failed {
            let error = r.error.as_deref().unwrap_or_default().replace('\n', " ");
            let _ = writeln!(md, "- `{}`: {error}", r.clip);
        }
    }
    if !outcome.excluded.is_empty() {
        let list = options
            .exclusions
            .file
            .as_ref()
            .map_or_else(String::new, |f| format!(" (`{}`)", f.display()));
        let _ = writeln!(
            md,
            "\n## Clips left out\n\nNamed by the exclusion list{list}, not run:\n"
        );
        for clip in outcome.excluded {
            let _ = writeln!(md, "- `{clip}`");
        }
    }
    let _ = writeln!(
        md,
        "\nMetrics: imuflow_eval::score, definitions in tools/eval/README.md (pose errors with GlobalPose's protocol G). Per-clip values: `clips.jsonl`; these tables: `results.json`."
    );
    md
}

/// The means table: one row per metric, a cell per variant (the best in bold) and the clip count.
/// With `source` (its name, and whether it is the first), the rows of one data set under a leading
/// `source` column, the header written with the first.
fn means_table(
    md: &mut String,
    names: &[String],
    summaries: &[MetricSummary],
    source: Option<(&str, bool)>,
) {
    let (lead, lead_rule) = match source {
        Some(_) => ("| source ", "|---"),
        None => ("", ""),
    };
    if source.is_none_or(|(_, first)| first) {
        let _ = write!(md, "{lead}| metric |");
        for n in names {
            let _ = write!(md, " {n} |");
        }
        let _ = writeln!(md, " clips |");
        let _ = writeln!(md, "{lead_rule}|---|{}---:|", "---:|".repeat(names.len()));
    }
    for s in summaries {
        let best = best_mean(s);
        if let Some((name, _)) = source {
            let _ = write!(md, "| {name} ");
        }
        let _ = write!(md, "| {}{} |", s.metric, unit_suffix(&s.unit));
        for (k, st) in s.stats.iter().enumerate() {
            let cell = st.map_or("–".to_owned(), |st| {
                if st.n > 1 {
                    format!("{} ± {}", fmt_value(Some(st.mean)), fmt_value(Some(st.std)))
                } else {
                    fmt_value(Some(st.mean))
                }
            });
            if best == Some(k) {
                let _ = write!(md, " **{cell}** |");
            } else {
                let _ = write!(md, " {cell} |");
            }
        }
        let n = s.stats.iter().flatten().map(|st| st.n).max().unwrap_or(0);
        let _ = writeln!(md, " {n} |");
    }
}

fn unit_suffix(unit: &str) -> String {
    if unit.is_empty() {
        String::new()
    } else {
        format!(" ({unit})")
    }
}

/// The variant with the best mean, for rows where lower is better.
fn best_mean(s: &MetricSummary) -> Option<usize> {
    if !s.lower_is_better {
        return None;
    }
    s.stats
        .iter()
        .enumerate()
        .filter_map(|(k, st)| st.map(|st| (k, st.mean)))
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .map(|(k, _)| k)
}

/// Identifies a comparison by its variants' files (contents and overrides), the BVH mapping and
/// the sensor-error model: a resumed batch must run the same graphs on the same signals.
pub fn fingerprint(
    sources: &[AblationVariant],
    mappings: &[PathBuf],
    sensor_errors: SensorErrors,
    source_set: &[(String, toml::Value)],
) -> anyhow::Result<String> {
    let mut fingerprint = String::new();
    for source in sources {
        let path = &source.graph;
        let mut text =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        text.extend(source.set.join("\n").bytes());
        fingerprint.push_str(&format!("{:016x}", imuflow_dataset::fnv1a64(&text)));
    }
    for m in mappings {
        let text = std::fs::read(m).with_context(|| format!("cannot read {}", m.display()))?;
        fingerprint.push_str(&format!("{:016x}", imuflow_dataset::fnv1a64(&text)));
    }
    if sensor_errors != SensorErrors::default() {
        fingerprint.push_str(&format!("-sensor-errors={sensor_errors:?}"));
    }
    for (key, value) in source_set {
        fingerprint.push_str(&format!("-{key}={value}"));
    }
    Ok(fingerprint)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(clip: &str, values: [f64; 2]) -> ClipRecord {
        ClipRecord {
            clip: clip.into(),
            source: None,
            frames: 100,
            rows: vec![
                Row {
                    name: "joint position error".into(),
                    unit: "cm".into(),
                    lower_is_better: true,
                    values: values.iter().map(|v| Some(*v)).collect(),
                },
                Row {
                    name: "frames scored".into(),
                    unit: String::new(),
                    lower_is_better: false,
                    values: vec![Some(100.0), Some(100.0)],
                },
            ],
            error: None,
            wall_s: 1.0,
        }
    }

    #[test]
    fn paired_differences_see_a_consistent_gain_that_the_spread_between_clips_hides() {
        // Clips differ a lot (2..20 cm) but b is 0.5 cm better on every one: the spread between
        // clips (std ≈ 6 cm) dwarfs the gap between the means, yet every paired difference is −0.5,
        // so the paired interval is exactly [−0.5, −0.5].
        let records: Vec<ClipRecord> = (0..10)
            .map(|i| {
                let a = 2.0 + 2.0 * i as f64;
                record(&format!("c{i}"), [a, a - 0.5])
            })
            .collect();
        let refs: Vec<&ClipRecord> = records.iter().collect();
        let names = ["a".to_owned(), "b".to_owned()];
        let summaries = summarize(&names, &refs);
        assert_eq!(summaries.len(), 1, "frames scored is not a metric");
        let s = &summaries[0];
        let (sa, sb) = (s.stats[0].unwrap(), s.stats[1].unwrap());
        assert!((sa.mean - 11.0).abs() < 1e-12);
        assert!((sb.mean - 10.5).abs() < 1e-12);
        // Sample std of 2, 4, ..., 20: sqrt(sum((2i − 9)^2 for i in 0..10) / 9) = sqrt(330/9).
        assert!((sa.std - (330.0f64 / 9.0).sqrt()).abs() < 1e-9);
        assert!(sa.std > 5.0 && (sa.mean - sb.mean) < 1.0);
        let d = s.pairs[0].difference.unwrap();
        assert_eq!((s.pairs[0].a, s.pairs[0].b), (0, 1));
        assert!(s.pairs[0].with_interval);
        assert!((d.mean_diff + 0.5).abs() < 1e-12, "b − a = −0.5: {d:?}");
        assert!((d.ci95_low + 0.5).abs() < 1e-12 && (d.ci95_high + 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_metric_missing_on_some_clips_pairs_only_the_clips_that_have_it() {
        let mut records: Vec<ClipRecord> = (0..4)
            .map(|i| record(&format!("c{i}"), [1.0 + i as f64, 2.0 + i as f64]))
            .collect();
        records[3].rows[0].values[1] = None; // b has no value on c3
        let refs: Vec<&ClipRecord> = records.iter().collect();
        let s = &summarize(&["a".into(), "b".into()], &refs)[0];
        assert_eq!(s.stats[0].unwrap().n, 4);
        assert_eq!(s.stats[1].unwrap().n, 3);
        let d = s.pairs[0].difference.unwrap();
        assert_eq!(d.n, 3);
        assert!(
            !s.pairs[0].with_interval,
            "3 clips are too few for an interval"
        );
        assert!((d.mean_diff - 1.0).abs() < 1e-12);
    }
}
