//! CSV/TSV exports read as a layout describes them: each sensor's rows to samples in SI units
//! and its own frame, then merged into frames.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};

use crate::error::Error;
use crate::layout::{
    Column, Layout, MissingAccelerometer, QuaternionColumns, SensorLayout, TimeLayout,
};
use crate::recording::{SensorRecording, Track, count, merge};
use crate::sample::{
    Sample, axis_matrix, derive_gyroscope, gravity_in_inertial, normalise_arbitrary_magnetometer,
    quaternion_from_euler_xyz, remap_axes, specific_force_from_free_acceleration, unit_quaternion,
};
use crate::table::{Row, Table};
use crate::units::MagnetometerUnit;
use crate::{NUM_IMUS, SITES};

/// Reads the recording at `path` (a file, or a folder of per-sensor files) as `layout` says.
pub fn read(path: &Path, layout: &Layout) -> Result<SensorRecording, Error> {
    let base = if path.is_dir() {
        path.to_owned()
    } else {
        path.parent().map(Path::to_owned).unwrap_or_default()
    };
    let mut tables: BTreeMap<PathBuf, Table> = BTreeMap::new();
    let mut tracks: [Track; NUM_IMUS] = Default::default();
    let mut counts = [Default::default(); NUM_IMUS];
    for (i, sensor) in layout.sites() {
        let files = files_of(sensor, path, &base)
            .map_err(|m| Error::file(path, format!("[sensors.{}]: {m}", SITES[i])))?;
        for f in &files {
            if !tables.contains_key(f) {
                tables.insert(f.clone(), Table::read(f, &layout.table)?);
            }
        }
        let sensor_tables: Vec<&Table> = files.iter().filter_map(|f| tables.get(f)).collect();
        let (mut track, unjoined) = read_sensor(layout, sensor, &sensor_tables)?;
        let derived = if sensor.gyroscope.is_none() && sensor.has_orientation() {
            derive_gyroscope(&mut track.samples) as u64
        } else {
            0
        };
        if layout.units.magnetometer == MagnetometerUnit::Arbitrary {
            normalise_arbitrary_magnetometer(&mut track.samples);
        }
        counts[i] = count(
            &track,
            sensor.magnetometer.is_some(),
            sensor.has_orientation(),
        );
        counts[i].derived_gyroscope = derived;
        counts[i].unjoined_rows = unjoined;
        tracks[i] = track;
    }
    let (frames, _) = merge(&tracks);
    if frames.is_empty() {
        return Err(Error::file(path, "no samples: the files have no data rows"));
    }
    Ok(SensorRecording {
        source: path.to_owned(),
        frames,
        truth: None,
        counts,
    })
}

/// The files a sensor reads, resolved against the recording.
fn files_of(sensor: &SensorLayout, path: &Path, base: &Path) -> Result<Vec<PathBuf>, String> {
    let listed: Vec<PathBuf> = match (&sensor.files, &sensor.file) {
        (Some(files), _) => files.clone(),
        (None, Some(file)) => vec![file.clone()],
        (None, None) if path.is_dir() => {
            return Err("the recording is a folder: give this sensor's `file`".into());
        }
        (None, None) => return Ok(vec![path.to_owned()]),
    };
    Ok(listed.iter().map(|f| base.join(f)).collect())
}

/// Which table and cell a column is read from, and its name for messages.
#[derive(Debug, Clone)]
struct Cell {
    table: usize,
    index: usize,
    label: String,
}

/// The cells of every quantity a sensor has.
#[derive(Debug, Clone, Default)]
struct Cells {
    accelerometer: Option<[Cell; 3]>,
    free_acceleration: Option<[Cell; 3]>,
    gyroscope: Option<[Cell; 3]>,
    magnetometer: Option<[Cell; 3]>,
    quaternion: Option<Vec<Cell>>,
    euler_xyz: Option<[Cell; 3]>,
}

/// A row read: the sample so far (vectors in the file's sensor frame) and the free acceleration.
#[derive(Debug, Clone, Copy, Default)]
struct Read {
    sample: Sample,
    free_acceleration: Option<Vector3<f64>>,
}

/// Reads one sensor: rows of its first table are its samples, rows of further tables join them.
/// Returns the track and how many rows of further tables joined no sample.
fn read_sensor(
    layout: &Layout,
    sensor: &SensorLayout,
    tables: &[&Table],
) -> Result<(Track, u64), Error> {
    let time = layout
        .time_of(sensor)
        .ok_or_else(|| Error::file(&tables[0].path, "no [time] for this sensor"))?;
    let cells = locate(sensor, tables)?;
    let mut reads = read_table(layout, time, &cells, tables, 0)?;
    let mut unjoined = 0;
    for t in 1..tables.len() {
        let extra = read_table(layout, time, &cells, tables, t)?;
        unjoined += join(&mut reads, &extra, &cells, t, sensor.join_tolerance_s);
    }
    let remap = sensor
        .axes
        .map(axis_matrix)
        .transpose()
        .map_err(|m| Error::file(&tables[0].path, m))?;
    let gravity = gravity_in_inertial(layout.units.up, layout.units.gravity_mps2);
    let gravity_only = layout.units.missing_accelerometer == MissingAccelerometer::Gravity
        && sensor.accelerometer.is_none()
        && sensor.free_acceleration.is_none();
    let samples = reads
        .into_iter()
        .map(|r| {
            let mut s = r.sample;
            if let (Some(a), Some(q)) = (r.free_acceleration, s.orientation) {
                s.accelerometer_mps2 =
                    Some(specific_force_from_free_acceleration(&a, &q, &gravity));
            }
            if gravity_only && let Some(q) = s.orientation {
                s.accelerometer_mps2 = Some(specific_force_from_free_acceleration(
                    &Vector3::zeros(),
                    &q,
                    &gravity,
                ));
            }
            if let Some(p) = &remap {
                remap_axes(&mut s, p);
            }
            s
        })
        .collect();
    let offset_ns = (sensor.time_offset_s * 1e9).round() as i64;
    Ok((Track { samples, offset_ns }, unjoined))
}

/// Finds every column of `sensor` in the first of `tables` that has it (numbers: the first).
fn locate(sensor: &SensorLayout, tables: &[&Table]) -> Result<Cells, Error> {
    let one = |c: &Column| -> Result<Cell, Error> {
        let Some(t) = tables.iter().position(|t| t.has(c)) else {
            let names: Vec<String> = tables
                .iter()
                .map(|t| t.path.display().to_string())
                .collect();
            return Err(match tables {
                [only] => only
                    .index(c)
                    .err()
                    .unwrap_or_else(|| Error::file(&only.path, format!("no column {c}"))),
                _ => Error::file(
                    &tables[0].path,
                    format!("no column {c} in any of {}", names.join(", ")),
                ),
            });
        };
        Ok(Cell {
            table: t,
            index: tables[t].index(c)?,
            label: match c {
                Column::Name(n) => format!("'{n}'"),
                Column::Number(n) => format!("number {n}"),
            },
        })
    };
    let three = |cs: &Option<[Column; 3]>| -> Result<Option<[Cell; 3]>, Error> {
        cs.as_ref()
            .map(|[a, b, c]| Ok([one(a)?, one(b)?, one(c)?]))
            .transpose()
    };
    let quaternion = match &sensor.quaternion {
        None => None,
        Some(QuaternionColumns::One(c)) => Some(vec![one(c)?]),
        Some(QuaternionColumns::Four(cs)) => {
            Some(cs.iter().map(one).collect::<Result<Vec<_>, _>>()?)
        }
    };
    Ok(Cells {
        accelerometer: three(&sensor.accelerometer)?,
        free_acceleration: three(&sensor.free_acceleration)?,
        gyroscope: three(&sensor.gyroscope)?,
        magnetometer: three(&sensor.magnetometer)?,
        quaternion,
        euler_xyz: three(&sensor.euler_xyz)?,
    })
}

/// Reads the quantities `cells` places in table `t`, one `Read` per row, with the row's time.
fn read_table(
    layout: &Layout,
    time: &TimeLayout,
    cells: &Cells,
    tables: &[&Table],
    t: usize,
) -> Result<Vec<Read>, Error> {
    let table = tables[t];
    let time_cell = time
        .column
        .as_ref()
        .map(|c| table.index(c).map(|i| (i, c.to_string())))
        .transpose()?;
    let mut clock = Clock::new(time);
    let mut out = Vec::with_capacity(table.rows.len());
    for (k, row) in table.rows.iter().enumerate() {
        let at = |m: String| Error::line(&table.path, row.line, m);
        let time_ns = match &time_cell {
            Some((i, label)) => clock
                .next(&cell(row, *i, label, table.decimal).map_err(at)?, label)
                .map_err(at)?,
            None => clock.at_row(k),
        };
        let mut r = Read {
            sample: Sample {
                time_ns,
                ..Sample::default()
            },
            free_acceleration: None,
        };
        fill(&mut r, layout, cells, table, t, row).map_err(at)?;
        out.push(r);
    }
    Ok(out)
}

/// Reads the quantities of table `t` from `row` into `r`, converted to SI units.
fn fill(
    r: &mut Read,
    layout: &Layout,
    cells: &Cells,
    table: &Table,
    t: usize,
    row: &Row,
) -> Result<(), String> {
    let u = &layout.units;
    let vector =
        |cs: &Option<[Cell; 3]>, scale: f64| -> Result<Option<Option<Vector3<f64>>>, String> {
            match cs {
                Some(cs) if cs[0].table == t => {
                    let v = numbers(row, cs, table.decimal)?;
                    Ok(Some(v.map(|v| Vector3::from(v) * scale)))
                }
                _ => Ok(None),
            }
        };
    if let Some(v) = vector(&cells.accelerometer, u.accelerometer.mps2())? {
        r.sample.accelerometer_mps2 = v;
    }
    if let Some(v) = vector(&cells.free_acceleration, u.accelerometer.mps2())? {
        r.free_acceleration = v;
    }
    if let Some(v) = vector(&cells.gyroscope, u.gyroscope.radps())? {
        r.sample.gyroscope_radps = v;
    }
    if let Some(v) = vector(&cells.magnetometer, u.magnetometer.ut().unwrap_or(1.0))? {
        r.sample.magnetometer_ut = v;
    }
    if let Some(v) = vector(&cells.euler_xyz, u.angles.rad())? {
        r.sample.orientation = v.map(|a| quaternion_from_euler_xyz([a.x, a.y, a.z]));
    }
    if let Some(cs) = cells.quaternion.as_ref().filter(|cs| cs[0].table == t) {
        r.sample.orientation = quaternion(row, cs, table.decimal, u.quaternion_order)?;
    }
    Ok(())
}

/// A quaternion from four cells, or from one cell holding four numbers.
fn quaternion(
    row: &Row,
    cs: &[Cell],
    decimal: char,
    order: crate::units::QuaternionOrder,
) -> Result<Option<UnitQuaternion<f64>>, String> {
    let values: Option<[f64; 4]> = match cs {
        [one] => {
            let text = raw_cell(row, one)?;
            // Within the cell: comma-separated, unless commas are the decimal separator.
            let separators: &[char] = if decimal == ',' {
                &[';', ' ']
            } else {
                &[',', ';', ' ']
            };
            let parts: Vec<(&str, &str)> = text
                .split(separators)
                .map(str::trim)
                .filter(|p| !p.is_empty())
                .map(|p| (p, one.label.as_str()))
                .collect();
            match parts.len() {
                0 => None,
                4 => all(&parts, decimal)?,
                _ => {
                    return Err(format!(
                        "column {}: expected a quaternion of 4 numbers, found '{text}'",
                        one.label
                    ));
                }
            }
        }
        _ => {
            let parts = cs
                .iter()
                .map(|c| raw_cell(row, c).map(|text| (text, c.label.as_str())))
                .collect::<Result<Vec<_>, _>>()?;
            all(&parts, decimal)?
        }
    };
    match values {
        None => Ok(None),
        Some(q) => {
            unit_quaternion(order.wxyz(q)).map_err(|m| format!("column {}: {m}", cs[0].label))
        }
    }
}

/// Three numbers, or `None` when any of them is missing.
fn numbers(row: &Row, cs: &[Cell; 3], decimal: char) -> Result<Option<[f64; 3]>, String> {
    let parts = cs
        .iter()
        .map(|c| raw_cell(row, c).map(|text| (text, c.label.as_str())))
        .collect::<Result<Vec<_>, _>>()?;
    all(&parts, decimal)
}

/// The numbers of `parts` (text, column label), or `None` when any of them is missing.
fn all<const N: usize>(parts: &[(&str, &str)], decimal: char) -> Result<Option<[f64; N]>, String> {
    let mut out = [0.0; N];
    let mut missing = false;
    for (v, (text, label)) in out.iter_mut().zip(parts) {
        match number(text, decimal).map_err(|m| format!("column {label}: {m}"))? {
            Some(x) => *v = x,
            None => missing = true,
        }
    }
    Ok((!missing).then_some(out))
}

fn raw_cell<'a>(row: &'a Row, c: &Cell) -> Result<&'a str, String> {
    row.cells
        .get(c.index)
        .map(String::as_str)
        .ok_or_else(|| short_row(row, c.index, &c.label))
}

fn short_row(row: &Row, index: usize, label: &str) -> String {
    format!(
        "short row: {} cells, column {label} is cell {}",
        row.cells.len(),
        index + 1
    )
}

/// The number in cell `index` of `row` (`None`: empty or NaN).
fn cell(row: &Row, index: usize, label: &str, decimal: char) -> Result<Option<f64>, String> {
    let text = row
        .cells
        .get(index)
        .ok_or_else(|| short_row(row, index, label))?;
    number(text, decimal).map_err(|m| format!("column {label}: {m}"))
}

/// A number; `None` for an empty cell, NaN or an infinity (a missing value).
pub(crate) fn number(text: &str, decimal: char) -> Result<Option<f64>, String> {
    let text = text.trim();
    if text.is_empty() {
        return Ok(None);
    }
    let parsed = if decimal == ',' {
        text.replace(',', ".").parse::<f64>()
    } else {
        text.parse::<f64>()
    };
    match parsed {
        Ok(v) if v.is_finite() => Ok(Some(v)),
        Ok(_) => Ok(None),
        Err(_) => Err(format!("bad number '{text}'")),
    }
}

/// Turns a file's time values into nanoseconds on the sensor's clock: unit, counter wraps, and
/// the check that time increases.
struct Clock {
    ns_per_unit: f64,
    wrap: Option<f64>,
    rate_hz: Option<f64>,
    wraps: f64,
    last_raw: Option<f64>,
    last_ns: Option<i64>,
}

impl Clock {
    fn new(time: &TimeLayout) -> Clock {
        Clock {
            ns_per_unit: time.unit.map_or(1e9, |u| u.ns()),
            wrap: time.wrap,
            rate_hz: time.rate_hz,
            wraps: 0.0,
            last_raw: None,
            last_ns: None,
        }
    }

    /// Row `k` of a file without a time column.
    fn at_row(&self, k: usize) -> i64 {
        (k as f64 / self.rate_hz.unwrap_or(1.0) * 1e9).round() as i64
    }

    /// The next row's time from its time cell.
    fn next(&mut self, value: &Option<f64>, label: &str) -> Result<i64, String> {
        let Some(raw) = *value else {
            return Err(format!("time column {label} is empty"));
        };
        if let (Some(wrap), Some(last)) = (self.wrap, self.last_raw)
            && raw < last
        {
            self.wraps += wrap;
        }
        self.last_raw = Some(raw);
        let ns = ((raw + self.wraps) * self.ns_per_unit).round();
        if ns < 0.0 {
            return Err(format!("time {raw} is negative"));
        }
        let ns = ns as i64;
        if let Some(last) = self.last_ns
            && ns <= last
        {
            return Err(format!(
                "time does not increase: {raw} after {} (column {label})",
                last as f64 / self.ns_per_unit - self.wraps
            ));
        }
        self.last_ns = Some(ns);
        Ok(ns)
    }
}

/// Joins the rows of table `t` (`extra`) to the samples nearest in time (within the tolerance:
/// the given one, or half the median sample interval). Each sample takes the nearest such row;
/// returns how many rows joined none.
fn join(
    reads: &mut [Read],
    extra: &[Read],
    cells: &Cells,
    t: usize,
    tolerance_s: Option<f64>,
) -> u64 {
    let tolerance_ns =
        tolerance_s.map_or_else(|| half_median_interval(reads), |s| (s * 1e9) as i64);
    let mut best: Vec<Option<(i64, usize)>> = vec![None; reads.len()];
    let mut joined = 0u64;
    for (e, r) in extra.iter().enumerate() {
        let t_ns = r.sample.time_ns;
        let k = reads.partition_point(|s| s.sample.time_ns < t_ns);
        let nearest = [k.checked_sub(1), (k < reads.len()).then_some(k)]
            .into_iter()
            .flatten()
            .min_by_key(|&i| (reads[i].sample.time_ns - t_ns).abs());
        let Some(i) = nearest else { continue };
        let dt = (reads[i].sample.time_ns - t_ns).abs();
        if dt > tolerance_ns {
            continue;
        }
        match best[i] {
            Some((old, _)) if old <= dt => {}
            Some(_) => best[i] = Some((dt, e)),
            None => {
                best[i] = Some((dt, e));
                joined += 1;
            }
        }
    }
    for (read, b) in reads.iter_mut().zip(&best) {
        if let Some((_, e)) = b {
            take(read, &extra[*e], cells, t);
        }
    }
    extra.len() as u64 - joined
}

/// Copies the quantities that table `t` holds from `from` into `into`.
fn take(into: &mut Read, from: &Read, cells: &Cells, t: usize) {
    let here = |c: Option<&Cell>| c.is_some_and(|c| c.table == t);
    if here(cells.accelerometer.as_ref().map(|c| &c[0])) {
        into.sample.accelerometer_mps2 = from.sample.accelerometer_mps2;
    }
    if here(cells.free_acceleration.as_ref().map(|c| &c[0])) {
        into.free_acceleration = from.free_acceleration;
    }
    if here(cells.gyroscope.as_ref().map(|c| &c[0])) {
        into.sample.gyroscope_radps = from.sample.gyroscope_radps;
    }
    if here(cells.magnetometer.as_ref().map(|c| &c[0])) {
        into.sample.magnetometer_ut = from.sample.magnetometer_ut;
    }
    if here(cells.euler_xyz.as_ref().map(|c| &c[0]))
        || here(cells.quaternion.as_ref().map(|c| &c[0]))
    {
        into.sample.orientation = from.sample.orientation;
    }
}

/// Half the median interval between consecutive samples, ns (0 for fewer than two).
fn half_median_interval(reads: &[Read]) -> i64 {
    let mut d: Vec<i64> = reads
        .windows(2)
        .map(|w| w[1].sample.time_ns - w[0].sample.time_ns)
        .collect();
    if d.is_empty() {
        return 0;
    }
    d.sort_unstable();
    d[d.len() / 2] / 2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::TimeUnit;

    #[test]
    fn numbers_missing_values_and_decimal_commas() {
        assert_eq!(number(" 1.5 ", '.'), Ok(Some(1.5)));
        assert_eq!(number("-2,25", ','), Ok(Some(-2.25)));
        assert_eq!(number("", '.'), Ok(None));
        assert_eq!(number("NaN", '.'), Ok(None));
        assert_eq!(number("inf", '.'), Ok(None));
        assert!(
            number("1.2.3", '.')
                .unwrap_err()
                .contains("bad number '1.2.3'")
        );
    }

    #[test]
    fn a_wrapping_counter_keeps_counting() {
        let time = TimeLayout {
            column: Some(Column::Number(1)),
            unit: Some(TimeUnit::Microseconds),
            wrap: Some(100.0),
            rate_hz: None,
        };
        let mut clock = Clock::new(&time);
        let got: Vec<i64> = [90.0, 99.0, 3.0, 50.0, 2.0]
            .iter()
            .map(|v| clock.next(&Some(*v), "t").unwrap())
            .collect();
        assert_eq!(got, [90_000, 99_000, 103_000, 150_000, 202_000]);
        let mut plain = Clock::new(&TimeLayout { wrap: None, ..time });
        plain.next(&Some(5.0), "t").unwrap();
        assert!(
            plain
                .next(&Some(5.0), "t")
                .unwrap_err()
                .contains("does not increase")
        );
        assert!(plain.next(&None, "t").unwrap_err().contains("empty"));
    }

    #[test]
    fn a_quaternion_cell_needs_four_numbers() {
        let row = Row {
            line: 7,
            cells: vec!["1,0,0".into(), "0;0;0;1".into(), String::new()],
        };
        let cell = |index| {
            vec![Cell {
                table: 0,
                index,
                label: "'q'".into(),
            }]
        };
        let order = crate::units::QuaternionOrder::Wxyz;
        assert!(
            quaternion(&row, &cell(0), '.', order)
                .unwrap_err()
                .contains("4 numbers")
        );
        let q = quaternion(&row, &cell(1), '.', order).unwrap().unwrap();
        assert!((q.k - 1.0).abs() < 1e-12, "w, x, y, z = 0, 0, 0, 1");
        assert_eq!(
            quaternion(&row, &cell(2), '.', order),
            Ok(None),
            "empty cell: missing"
        );
    }
}
