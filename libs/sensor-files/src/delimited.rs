//! CSV/TSV exports read as a layout describes them: each sensor's rows to samples in SI units
//! and its own frame, then merged into frames.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};

use crate::error::Error;
use crate::layout::{
    Column, Layout, MissingAccelerometer, Quantity, QuaternionColumns, SensorLayout, TimeLayout,
};
use crate::recording::{SensorRecording, Track, count, merge};
use crate::sample::{
    Sample, axis_matrix, derive_gyroscope, gravity_in_inertial, normalise_arbitrary_magnetometer,
    quaternion_from_euler_xyz, remap_axes, specific_force_from_free_acceleration, unit_quaternion,
};
use crate::table::{Row, Table};
use crate::units::MagnetometerUnit;
use crate::{MAX_SITES, SITES, SiteMask};

/// Reads the sensors of `wanted` from the recording at `path` (a file, or a folder of per-sensor
/// files) as `layout` says; each of them must be listed in the layout.
pub fn read(path: &Path, layout: &Layout, wanted: SiteMask) -> Result<SensorRecording, Error> {
    let unlisted = wanted.missing_from(layout.site_mask());
    if !unlisted.is_empty() {
        return Err(Error::file(
            path,
            format!(
                "the layout has no [sensors.<site>] for {} (it lists {}); the sensor set read ({}) needs every one of its sites",
                unlisted.names(),
                layout.site_mask().names(),
                wanted.names()
            ),
        ));
    }

    let base = if path.is_dir() {
        path.to_owned()
    } else {
        path.parent().map(Path::to_owned).unwrap_or_default()
    };
    let found = match &layout.files {
        Some(files) if path.is_dir() => Some(crate::sites::find(path, files, layout)?),
        Some(_) => {
            return Err(Error::file(
                path,
                "the layout finds each sensor's file in a folder ([files] match): give the recording's folder",
            ));
        }
        None => None,
    };
    // Sensors the folder holds for sites the set does not wear (known where each site's file is
    // found by name or id).
    let left_out: Vec<&'static str> = match &found {
        Some(found) => layout
            .sites()
            .filter(|(i, _)| !wanted.contains_slot(*i) && found[*i].is_some())
            .map(|(i, _)| SITES[i])
            .collect(),
        None => Vec::new(),
    };
    let mut site_files: Vec<(usize, &SensorLayout, Vec<PathBuf>)> = Vec::new();
    let mut missing: Vec<&str> = Vec::new();
    let mut missing_files: Vec<String> = Vec::new();
    for (i, sensor) in layout.sites().filter(|(i, _)| wanted.contains_slot(*i)) {
        let files = match &found {
            Some(found) => match &found[i] {
                Some(entry) => files_in(sensor, entry),
                None => {
                    missing.push(SITES[i]);
                    continue;
                }
            },
            None => files_of(sensor, path, &base),
        }
        .map_err(|m| Error::file(path, format!("[sensors.{}]: {m}", SITES[i])))?;
        if found.is_none() && !files[0].exists() {
            missing.push(SITES[i]);
            missing_files.push(files[0].display().to_string());
            continue;
        }
        site_files.push((i, sensor, files));
    }
    if !missing.is_empty() {
        return Err(missing_sites(
            path,
            layout,
            &missing,
            &missing_files,
            &site_files,
            wanted,
        ));
    }
    let mut tables: BTreeMap<PathBuf, Table> = BTreeMap::new();
    let mut tracks: [Track; MAX_SITES] = Default::default();
    let mut counts = [Default::default(); MAX_SITES];
    for (i, sensor, files) in site_files {
        for f in &files {
            if !tables.contains_key(f) {
                tables.insert(f.clone(), Table::read(f, &layout.table)?);
            }
        }
        let sensor_tables: Vec<&Table> = files.iter().filter_map(|f| tables.get(f)).collect();
        let read = read_sensor(layout, sensor, &sensor_tables)?;
        let mut track = read.track;
        let derived = if !read.has.gyroscope && read.has.orientation {
            derive_gyroscope(&mut track.samples) as u64
        } else {
            0
        };
        if layout.units.magnetometer == MagnetometerUnit::Arbitrary {
            normalise_arbitrary_magnetometer(&mut track.samples);
        }
        counts[i] = count(&track, read.has.magnetometer, read.has.orientation);
        counts[i].derived_gyroscope = derived;
        counts[i].unjoined_rows = read.unjoined;
        counts[i].lost = read.lost;
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
        sites: wanted,
        left_out,
    })
}

/// The refusal of a recording without some of the sites the layout lists: which ones, and what
/// the folder does hold.
fn missing_sites(
    path: &Path,
    layout: &Layout,
    missing: &[&str],
    missing_files: &[String],
    present: &[(usize, &SensorLayout, Vec<PathBuf>)],
    wanted: SiteMask,
) -> Error {
    let have: Vec<&str> = present.iter().map(|(i, _, _)| SITES[*i]).collect();
    let how = match &layout.files {
        Some(f) if f.pattern.contains("{id}") => format!(
            "no file matching [files] match = \"{}\" with a sensor id{} mapped to it",
            f.pattern,
            f.ids
                .as_ref()
                .map(|t| {
                    let names: Vec<String> =
                        t.list().iter().map(|p| p.display().to_string()).collect();
                    format!(" by {} or the layout's `id`", names.join(" or "))
                })
                .unwrap_or_default()
        ),
        Some(f) => format!(
            "no file or folder matching [files] match = \"{}\" with the site's name",
            f.pattern
        ),
        None => format!("no file {}", missing_files.join(", ")),
    };
    Error::file(
        path,
        format!(
            "no sensor for {} ({how}); found {}. The sensor set read needs every one of its sites ({}): for a recording of fewer sensors, a graph names a set of fewer sites (`sensors`: lower-body, a set file)",
            missing.join(", "),
            if have.is_empty() {
                "none of the sites".to_owned()
            } else {
                have.join(", ")
            },
            wanted.names()
        ),
    )
}

/// The files a sensor reads when `[files] match` found its `entry`: the entry itself, or the
/// sensor's `file`/`files` inside it when it is a folder.
fn files_in(sensor: &SensorLayout, entry: &Path) -> Result<Vec<PathBuf>, String> {
    let listed: Vec<PathBuf> = match (&sensor.files, &sensor.file) {
        (Some(files), _) => files.clone(),
        (None, Some(file)) => vec![file.clone()],
        (None, None) if entry.is_dir() => {
            return Err(format!(
                "'{}' is a folder: give this sensor's `file` in it",
                entry.display()
            ));
        }
        (None, None) => return Ok(vec![entry.to_owned()]),
    };
    if !entry.is_dir() {
        return Err(format!(
            "'{}' is a file, but the layout names files in it (`file`/`files`)",
            entry.display()
        ));
    }
    Ok(listed.iter().map(|f| with_gz(entry.join(f))).collect())
}

/// `path`, or `path.gz` when only the compressed file is there.
fn with_gz(path: PathBuf) -> PathBuf {
    if path.exists() {
        return path;
    }
    let mut gz = path.clone().into_os_string();
    gz.push(".gz");
    let gz = PathBuf::from(gz);
    if gz.exists() { gz } else { path }
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
    Ok(listed.iter().map(|f| with_gz(base.join(f))).collect())
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
    rotation_matrix: Option<[Cell; 9]>,
}

/// Which quantities a sensor's files turned out to hold (optional ones may be absent).
#[derive(Debug, Clone, Copy, Default)]
struct Has {
    gyroscope: bool,
    magnetometer: bool,
    orientation: bool,
}

impl Cells {
    fn has(&self) -> Has {
        Has {
            gyroscope: self.gyroscope.is_some(),
            magnetometer: self.magnetometer.is_some(),
            orientation: self.quaternion.is_some()
                || self.euler_xyz.is_some()
                || self.rotation_matrix.is_some(),
        }
    }
}

/// One sensor read: its track, rows of further files that joined no sample, samples lost (gaps
/// in the packet counter or the time column) and what its files hold.
struct SensorRead {
    track: Track,
    unjoined: u64,
    lost: u64,
    has: Has,
}

/// A row read: the sample so far (vectors in the file's sensor frame) and the free acceleration.
#[derive(Debug, Clone, Copy, Default)]
struct Read {
    sample: Sample,
    free_acceleration: Option<Vector3<f64>>,
}

/// Reads one sensor: rows of its first table are its samples, rows of further tables join them.
fn read_sensor(
    layout: &Layout,
    sensor: &SensorLayout,
    tables: &[&Table],
) -> Result<SensorRead, Error> {
    let time = layout
        .time_of(sensor)
        .ok_or_else(|| Error::file(&tables[0].path, "no [time] for this sensor"))?;
    let cells = locate(sensor, tables)?;
    if cells.free_acceleration.is_some() && !cells.has().orientation {
        return Err(Error::file(
            &tables[0].path,
            "free acceleration without an orientation column: it cannot be turned into the sensor frame",
        ));
    }
    let (mut reads, lost) = read_table(layout, time, &cells, tables, 0)?;
    let mut unjoined = 0;
    for t in 1..tables.len() {
        let (extra, _) = read_table(layout, time, &cells, tables, t)?;
        unjoined += join(&mut reads, &extra, &cells, t, sensor.join_tolerance_s);
    }
    let remap = sensor
        .axes
        .map(axis_matrix)
        .transpose()
        .map_err(|m| Error::file(&tables[0].path, m))?;
    let gravity = gravity_in_inertial(layout.units.up, layout.units.gravity_mps2);
    let gravity_only = layout.units.missing_accelerometer == MissingAccelerometer::Gravity
        && cells.accelerometer.is_none()
        && cells.free_acceleration.is_none();
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
    Ok(SensorRead {
        track: Track { samples, offset_ns },
        unjoined,
        lost,
        has: cells.has(),
    })
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
    // An optional quantity whose columns are not all in the files is left out.
    let there = |cs: &[&Column], q: Quantity| {
        !sensor.is_optional(q) || cs.iter().all(|c| tables.iter().any(|t| t.has(c)))
    };
    let three = |cs: &Option<[Column; 3]>, q: Quantity| -> Result<Option<[Cell; 3]>, Error> {
        match cs {
            Some([a, b, c]) if there(&[a, b, c], q) => Ok(Some([one(a)?, one(b)?, one(c)?])),
            _ => Ok(None),
        }
    };
    // Orientations in this order: the first the files have is used.
    let quaternion = match &sensor.quaternion {
        Some(QuaternionColumns::One(c)) if there(&[c], Quantity::Quaternion) => Some(vec![one(c)?]),
        Some(QuaternionColumns::Four(cs))
            if there(&cs.iter().collect::<Vec<_>>(), Quantity::Quaternion) =>
        {
            Some(cs.iter().map(one).collect::<Result<Vec<_>, _>>()?)
        }
        _ => None,
    };
    let rotation_matrix = match &sensor.rotation_matrix {
        Some(cs)
            if quaternion.is_none()
                && there(&cs.iter().collect::<Vec<_>>(), Quantity::RotationMatrix) =>
        {
            let cells = cs.iter().map(one).collect::<Result<Vec<_>, _>>()?;
            cells.try_into().ok()
        }
        _ => None,
    };
    let euler_xyz = if quaternion.is_none() && rotation_matrix.is_none() {
        three(&sensor.euler_xyz, Quantity::EulerXyz)?
    } else {
        None
    };
    Ok(Cells {
        accelerometer: three(&sensor.accelerometer, Quantity::Accelerometer)?,
        free_acceleration: three(&sensor.free_acceleration, Quantity::FreeAcceleration)?,
        gyroscope: three(&sensor.gyroscope, Quantity::Gyroscope)?,
        magnetometer: three(&sensor.magnetometer, Quantity::Magnetometer)?,
        quaternion,
        euler_xyz,
        rotation_matrix,
    })
}

/// Reads the quantities `cells` places in table `t`, one `Read` per row, with the row's time;
/// also returns how many samples the table lacks (gaps in the counter or the time column).
fn read_table(
    layout: &Layout,
    time: &TimeLayout,
    cells: &Cells,
    tables: &[&Table],
    t: usize,
) -> Result<(Vec<Read>, u64), Error> {
    let table = tables[t];
    // A column's index in the table and its name for messages.
    let find = |c: &Option<Column>| {
        c.as_ref()
            .map(|c| table.index(c).map(|i| (i, c.to_string())))
            .transpose()
    };
    let time_cell = find(&time.column)?;
    let counter_cell = find(&time.counter)?;
    let rate_hz = match (&time.rate_from, time.rate_hz) {
        (Some(text), fallback) => match rate_in(&table.preamble, text) {
            Some(r) => Some(r),
            None if fallback.is_some() => fallback,
            None => {
                return Err(Error::file(
                    &table.path,
                    format!(
                        "no line above the header gives the rate ('{text}', [time] rate_from): set [time] rate_hz to the recording's rate"
                    ),
                ));
            }
        },
        (None, r) => r,
    };
    let mut clock = Clock::new(time, rate_hz);
    let mut counter = time.counter.as_ref().map(|_| Counter::new(time));
    let mut out = Vec::with_capacity(table.rows.len());
    for (k, row) in table.rows.iter().enumerate() {
        let at = |m: String| Error::line(&table.path, row.line, m);
        let count = match (&counter_cell, counter.as_mut()) {
            (Some((i, label)), Some(counter)) => Some(
                counter
                    .next(cell(row, *i, label, table.decimal).map_err(at)?, label)
                    .map_err(at)?,
            ),
            _ => None,
        };
        let time_ns = match (&time_cell, count) {
            (Some((i, label)), _) => clock
                .next(&cell(row, *i, label, table.decimal).map_err(at)?, label)
                .map_err(at)?,
            (None, Some(count)) => clock.at_row(count),
            (None, None) => clock.at_row(k as u64),
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
    let lost = match (counter, &time_cell) {
        (Some(counter), _) => counter.lost,
        (None, Some(_)) => lost_by_time(&out),
        (None, None) => 0,
    };
    Ok((out, lost))
}

/// The first number after `text` on the first line of `preamble` that has it: MT Manager's
/// `// Update Rate: 60.0Hz`, the DOT app's `OutputRate:,60Hz`.
fn rate_in(preamble: &[String], text: &str) -> Option<f64> {
    let line = preamble.iter().find(|l| l.contains(text))?;
    let after = &line[line.find(text)? + text.len()..];
    let start = after.find(|c: char| c.is_ascii_digit())?;
    let digits: String = after[start..]
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.')
        .collect();
    digits.parse().ok().filter(|r: &f64| *r > 0.0)
}

/// Samples missing from a time column without a counter: a gap of more than 1.5 median
/// intervals holds round(gap / median) − 1 lost samples (what a steady rate would have had).
fn lost_by_time(reads: &[Read]) -> u64 {
    let mut d: Vec<i64> = reads
        .windows(2)
        .map(|w| w[1].sample.time_ns - w[0].sample.time_ns)
        .collect();
    if d.len() < 2 {
        return 0;
    }
    d.sort_unstable();
    let median = d[d.len() / 2].max(1) as f64;
    d.iter()
        .filter(|&&g| g as f64 > 1.5 * median)
        .map(|&g| ((g as f64 / median).round() as u64).saturating_sub(1))
        .sum()
}

/// A packet counter: unwrapped across its wraps, each gap counted as lost packets.
struct Counter {
    wrap: f64,
    last: Option<(f64, u64)>,
    lost: u64,
}

impl Counter {
    fn new(time: &TimeLayout) -> Counter {
        Counter {
            wrap: time.counter_wrap.unwrap_or(65536.0),
            last: None,
            lost: 0,
        }
    }

    /// The row's count, unwrapped (the first row's raw value, then one more per packet).
    fn next(&mut self, value: Option<f64>, label: &str) -> Result<u64, String> {
        let Some(raw) = value else {
            return Err(format!("packet counter column {label} is empty"));
        };
        if raw < 0.0 || raw.fract() != 0.0 || raw >= self.wrap {
            return Err(format!(
                "packet counter column {label}: {raw} is not a count below its wrap {}",
                self.wrap
            ));
        }
        let count = match self.last {
            None => raw as u64,
            Some((last_raw, last)) => {
                let mut step = raw - last_raw;
                if step == 0.0 {
                    return Err(format!(
                        "packet counter column {label} repeats {raw} (a duplicated row?)"
                    ));
                }
                if step < 0.0 {
                    step += self.wrap;
                }
                self.lost += step as u64 - 1;
                last + step as u64
            }
        };
        self.last = Some((raw, count));
        Ok(count)
    }
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
    if let Some(cs) = cells.rotation_matrix.as_ref().filter(|cs| cs[0].table == t) {
        let parts = cs
            .iter()
            .map(|c| raw_cell(row, c).map(|text| (text, c.label.as_str())))
            .collect::<Result<Vec<_>, _>>()?;
        r.sample.orientation = match all::<9>(&parts, table.decimal)? {
            Some(m) => Some(
                rotation_from_matrix(m).map_err(|e| format!("columns {}..: {e}", cs[0].label))?,
            ),
            None => None,
        };
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

/// R_IS from its nine elements row by row; an error when they are far from a rotation (the
/// wrong columns, or the matrix's transpose read as itself would still pass: order is the
/// layout's to get right).
fn rotation_from_matrix(m: [f64; 9]) -> Result<UnitQuaternion<f64>, String> {
    let r = nalgebra::Matrix3::from_row_slice(&m);
    // Exports round to about six digits; an error this large means the columns are not R.
    let off = (r.transpose() * r - nalgebra::Matrix3::identity())
        .abs()
        .max();
    if off > 0.05 || r.determinant() < 0.0 {
        return Err(format!(
            "{m:?} is not a rotation matrix (|RᵀR − I| = {off:.3}, det {:.3}): are these the matrix's columns, row by row?",
            r.determinant()
        ));
    }
    let rotation =
        nalgebra::Rotation3::from_matrix_eps(&r, 1e-12, 100, nalgebra::Rotation3::identity());
    Ok(UnitQuaternion::from_rotation_matrix(&rotation))
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
    fn new(time: &TimeLayout, rate_hz: Option<f64>) -> Clock {
        Clock {
            ns_per_unit: time.unit.map_or(1e9, |u| u.ns()),
            wrap: time.wrap,
            rate_hz,
            wraps: 0.0,
            last_raw: None,
            last_ns: None,
        }
    }

    /// Row (or count) `k` of a file without a time column.
    fn at_row(&self, k: u64) -> i64 {
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
        || here(cells.rotation_matrix.as_ref().map(|c| &c[0]))
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
            rate_from: None,
            counter: None,
            counter_wrap: None,
        };
        let mut clock = Clock::new(&time, None);
        let got: Vec<i64> = [90.0, 99.0, 3.0, 50.0, 2.0]
            .iter()
            .map(|v| clock.next(&Some(*v), "t").unwrap())
            .collect();
        assert_eq!(got, [90_000, 99_000, 103_000, 150_000, 202_000]);
        let mut plain = Clock::new(&TimeLayout { wrap: None, ..time }, None);
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
