//! The plots of `imuflow compare`'s report (PNG, plotters' bitmap backend): error over time, error
//! per joint, top-down root trajectories, latency histograms. Colours follow the rerun recording's
//! (the rerun logger's group palette), so a variant looks the same in both.

use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::Context;
use imuflow_body::{JointId, NUM_JOINTS};
use plotters::prelude::*;

use crate::report::Series;

const SIZE: (u32, u32) = (1000, 520);
/// The rerun logger's group palette (Okabe & Ito), in variant order.
const PALETTE: [RGBColor; 6] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(240, 228, 66),
];
const TRUTH: RGBColor = RGBColor(120, 200, 120);
/// Bundled so plots render the same on any machine (no system font libraries).
static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSansMono.ttf");

fn colour(k: usize) -> RGBColor {
    PALETTE[k % PALETTE.len()]
}

fn register_font() -> anyhow::Result<()> {
    static REGISTER: Once = Once::new();
    let mut result = Ok(());
    REGISTER.call_once(|| {
        result = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| anyhow::anyhow!("the bundled plot font is unreadable"));
    });
    result
}

/// Draws every plot that has data; returns (title, file) pairs.
pub fn draw(
    out: &Path,
    series: &[Series],
    truth_trajectory: &[(f64, f64)],
) -> anyhow::Result<Vec<(String, PathBuf)>> {
    register_font()?;
    let mut plots = Vec::new();
    if series.iter().any(|s| !s.error_cm.is_empty()) {
        let path = out.join("error_over_time.png");
        error_over_time(&path, series).context("error over time")?;
        plots.push(("Joint position error over time".to_owned(), path));
        let path = out.join("error_per_joint.png");
        error_per_joint(&path, series).context("error per joint")?;
        plots.push(("Mean joint position error per joint".to_owned(), path));
    }
    if series.iter().any(|s| !s.trajectory.is_empty()) {
        let path = out.join("trajectories.png");
        trajectories(&path, series, truth_trajectory).context("trajectories")?;
        plots.push(("Root trajectories, top-down".to_owned(), path));
    }
    if series.iter().any(|s| !s.latency_ms.is_empty()) {
        let path = out.join("latency.png");
        latency(&path, series).context("latency")?;
        plots.push(("Source-to-motion latency".to_owned(), path));
    }
    Ok(plots)
}

fn error_over_time(path: &Path, series: &[Series]) -> anyhow::Result<()> {
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let t_max = series
        .iter()
        .flat_map(|s| s.error_cm.iter().map(|(seq, _)| *seq as f64 / 60.0))
        .fold(1.0, f64::max);
    let e_max = series
        .iter()
        .flat_map(|s| s.error_cm.iter().map(|(_, e)| *e))
        .fold(1.0, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption("joint position error vs truth", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..t_max, 0.0..e_max * 1.05)?;
    chart
        .configure_mesh()
        .x_desc("time (s, from the source's first frame)")
        .y_desc("cm")
        .draw()?;
    for (k, s) in series.iter().enumerate() {
        let c = colour(k);
        chart
            .draw_series(LineSeries::new(
                s.error_cm.iter().map(|(seq, e)| (*seq as f64 / 60.0, *e)),
                c.stroke_width(2),
            ))?
            .label(s.name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn error_per_joint(path: &Path, series: &[Series]) -> anyhow::Result<()> {
    // Horizontal bars: 24 joint names stay readable on the y axis, joint 0 at the top.
    let root = BitMapBackend::new(path, (SIZE.0, 760)).into_drawing_area();
    root.fill(&WHITE)?;
    let e_max = series
        .iter()
        .flat_map(|s| s.per_joint_cm.iter().copied())
        .fold(1.0, f64::max);
    let n = NUM_JOINTS as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption("mean error per joint (roots aligned)", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(130)
        .build_cartesian_2d(0.0..e_max * 1.25, 0.0..n)?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(NUM_JOINTS * 2 + 1)
        .y_label_formatter(&|y| {
            // Label the middle of each joint's row (rows run top-down from joint 0).
            let row = y.floor();
            if (y - row - 0.5).abs() > 1e-6 {
                return String::new();
            }
            JointId::from_index((n - 1.0 - row) as usize)
                .map_or_else(String::new, |j| j.name().to_owned())
        })
        .x_desc("cm")
        .draw()?;
    let height = 0.8 / series.len().max(1) as f64;
    for (k, s) in series.iter().enumerate() {
        let c = colour(k);
        chart
            // NaN: a joint whose position the variant's sensors do not place (no bar).
            .draw_series(
                s.per_joint_cm
                    .iter()
                    .enumerate()
                    .filter(|(_, e)| e.is_finite())
                    .map(|(j, e)| {
                        let row = n - 1.0 - j as f64;
                        let y1 = row + 0.9 - k as f64 * height;
                        Rectangle::new([(0.0, y1 - height), (*e, y1)], c.filled())
                    }),
            )?
            .label(s.name.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], c.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn trajectories(path: &Path, series: &[Series], truth: &[(f64, f64)]) -> anyhow::Result<()> {
    let root = BitMapBackend::new(path, (SIZE.1 + 300, SIZE.1 + 100)).into_drawing_area();
    root.fill(&WHITE)?;
    let all = series
        .iter()
        .flat_map(|s| s.trajectory.iter())
        .chain(truth.iter());
    let (mut x0, mut x1, mut z0, mut z1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, z) in all {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        z0 = z0.min(*z);
        z1 = z1.max(*z);
    }
    // Equal scales on both axes: a square window around the paths.
    let half = ((x1 - x0).max(z1 - z0) / 2.0).max(0.5) * 1.1;
    let (cx, cz) = ((x0 + x1) / 2.0, (z0 + z1) / 2.0);
    let mut chart = ChartBuilder::on(&root)
        .caption("root trajectory, top-down", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(cx - half..cx + half, cz - half..cz + half)?;
    chart
        .configure_mesh()
        .x_desc("x (m, left)")
        .y_desc("z (m, forward)")
        .draw()?;
    if !truth.is_empty() {
        chart
            .draw_series(LineSeries::new(
                truth.iter().copied(),
                TRUTH.stroke_width(4),
            ))?
            .label("truth")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], TRUTH.stroke_width(4)));
    }
    for (k, s) in series.iter().enumerate() {
        let c = colour(k);
        chart
            .draw_series(LineSeries::new(
                s.trajectory.iter().copied(),
                c.stroke_width(2),
            ))?
            .label(s.name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

fn latency(path: &Path, series: &[Series]) -> anyhow::Result<()> {
    const BINS: usize = 40;
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let mut all: Vec<f64> = series
        .iter()
        .flat_map(|s| s.latency_ms.iter().copied())
        .collect();
    all.sort_by(f64::total_cmp);
    // The 99th percentile bounds the axis: a few start-up outliers must not squash the rest.
    let top = all[(all.len() * 99 / 100).min(all.len() - 1)].max(1e-3);
    let bin = top / BINS as f64;
    let histograms: Vec<Vec<usize>> = series
        .iter()
        .map(|s| {
            let mut h = vec![0usize; BINS];
            for l in &s.latency_ms {
                h[((l / bin) as usize).min(BINS - 1)] += 1;
            }
            h
        })
        .collect();
    let count_max = histograms
        .iter()
        .flatten()
        .copied()
        .max()
        .unwrap_or(1)
        .max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "source-to-motion latency (source publish to motion publish)",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..top, 0.0..count_max as f64 * 1.05)?;
    chart
        .configure_mesh()
        .x_desc("ms (the last bin holds everything above the 99th percentile)")
        .y_desc("frames")
        .draw()?;
    for (k, (s, h)) in series.iter().zip(&histograms).enumerate() {
        let c = colour(k);
        // A step outline per variant, so overlapping histograms stay readable.
        let mut points = vec![(0.0, 0.0)];
        for (i, n) in h.iter().enumerate() {
            points.push((i as f64 * bin, *n as f64));
            points.push(((i + 1) as f64 * bin, *n as f64));
        }
        points.push((top, 0.0));
        chart
            .draw_series(LineSeries::new(points, c.stroke_width(2)))?
            .label(s.name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

/// The batch report's plot: each variant's per-clip values of one metric, sorted, against the
/// fraction of clips (a quantile plot: a curve lower everywhere is better on every kind of clip,
/// crossing curves mean each variant wins on some clips). Returns the file.
pub fn clip_quantiles(
    out: &Path,
    file: &str,
    metric: &str,
    unit: &str,
    per_variant: &[(String, Vec<f64>)],
) -> anyhow::Result<PathBuf> {
    register_font()?;
    let path = out.join(file);
    let root = BitMapBackend::new(&path, SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let v_max = per_variant
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .filter(|v| v.is_finite())
        .fold(f64::MIN_POSITIVE, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{metric} per clip, sorted"), ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..1.0, 0.0..v_max * 1.05)?;
    chart
        .configure_mesh()
        .x_desc("fraction of clips")
        .y_desc(unit)
        .draw()?;
    for (k, (name, values)) in per_variant.iter().enumerate() {
        let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len().max(1) as f64;
        let c = colour(k);
        chart
            .draw_series(LineSeries::new(
                sorted
                    .iter()
                    .enumerate()
                    .map(|(i, v)| ((i as f64 + 0.5) / n, *v)),
                c.stroke_width(2),
            ))?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    drop(chart);
    drop(root);
    Ok(path)
}
