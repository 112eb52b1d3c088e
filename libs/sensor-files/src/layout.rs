//! The layout TOML that describes a CSV/TSV export: how the text is laid out, where the time is,
//! which units the values are in, and which columns of which file hold each sensor's samples.
//! The crate README documents every key; `configs/sensor-layouts/` has one layout per supported
//! vendor export.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::SITES;
use crate::error::{Error, read_text};
use crate::units::{
    AccelerometerUnit, AngleUnit, GyroscopeUnit, MagnetometerUnit, QuaternionOrder, SignedAxis,
    TimeUnit,
};

/// A whole layout file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layout {
    /// How the text of every file is laid out.
    #[serde(default)]
    pub table: TableLayout,
    /// Where each sample's time comes from (a sensor may override it).
    pub time: Option<TimeLayout>,
    /// Units and frame conventions of the values.
    #[serde(default)]
    pub units: Units,
    /// The sensors, by site name (`left_forearm`, ..., `pelvis`).
    #[serde(default)]
    pub sensors: BTreeMap<String, SensorLayout>,
    /// How each sensor's file or folder is found in the recording folder when the export names
    /// them by sensor id or by the vendor's name of the body part (rather than fixed names).
    pub files: Option<FilesLayout>,
}

/// Per-sensor files or folders found by name: `match` is a pattern of names in the recording
/// folder, with `{site}` (a name of the site: `left_lower_leg`, "Left Lower Leg", `LTibia`, ...)
/// or `{id}` (the sensor's id, from its `id` key or the `ids` table) and `*` (any text).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilesLayout {
    /// The name pattern; letters match either case.
    #[serde(rename = "match")]
    pub pattern: String,
    /// A file in the recording folder mapping sensor ids to sites: a CSV whose header names an
    /// id column (`sensor_id`, `id`, `sensor`) and a site column (`segment`, `site`), or an
    /// OpenSense `myIMUMappings.xml`. Rows for other body parts are ignored. Several names: the
    /// first file that is there.
    pub ids: Option<Paths>,
}

/// One path or several.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum Paths {
    One(PathBuf),
    Many(Vec<PathBuf>),
}

impl Paths {
    pub fn list(&self) -> &[PathBuf] {
        match self {
            Paths::One(p) => std::slice::from_ref(p),
            Paths::Many(ps) => ps,
        }
    }
}

/// How the text is laid out.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableLayout {
    /// Cell separator; `auto` picks it from the file's extension.
    #[serde(default)]
    pub delimiter: Delimiter,
    /// Decimal separator of the numbers: "." or ",".
    #[serde(default = "default_decimal")]
    pub decimal: char,
    /// Lines dropped at the start of the file before anything else.
    #[serde(default)]
    pub skip_lines: usize,
    /// Lines dropped up to and including the first one that reads this (trimmed), e.g.
    /// `endheader` in OpenSim storage files.
    pub skip_until: Option<String>,
    /// Whether a header row names the columns (false: columns are given by number).
    #[serde(default = "default_true")]
    pub header: bool,
    /// The header is the first line (after the skipped ones) that starts with this.
    pub header_starts_with: Option<String>,
    /// Lines starting with this are ignored.
    pub comment: Option<String>,
}

impl Default for TableLayout {
    fn default() -> Self {
        TableLayout {
            delimiter: Delimiter::Auto,
            decimal: '.',
            skip_lines: 0,
            skip_until: None,
            header: true,
            header_starts_with: None,
            comment: None,
        }
    }
}

fn default_decimal() -> char {
    '.'
}

fn default_true() -> bool {
    true
}

/// Cell separator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Delimiter {
    /// From the extension: `.csv` comma; `.tsv`, `.tab`, `.sto`, `.mot` and `.txt` tab.
    #[default]
    Auto,
    Comma,
    Tab,
    Semicolon,
    /// Any run of spaces and tabs.
    Whitespace,
    /// One space per cell boundary: two spaces in a row are an empty cell (MT Manager's
    /// space-separated export writes its empty cells so).
    Space,
    /// From the header line (or the first row without a header): tab, semicolon or comma, the
    /// first of them the line has, else space. For exporters that let the user choose.
    Detect,
}

/// Where a sample's time comes from: a column, or a fixed rate.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeLayout {
    /// The time column.
    pub column: Option<Column>,
    /// Unit of the time column.
    pub unit: Option<TimeUnit>,
    /// The time column is a counter that wraps at this value (in `unit`), e.g. 4294967296 for
    /// a 32-bit microsecond counter; a step backwards then adds one wrap.
    pub wrap: Option<f64>,
    /// No time column: row k of a file is at k / rate_hz seconds (with `counter`: count k).
    pub rate_hz: Option<f64>,
    /// The rate is the first number on the first line before the header that contains this
    /// text (MT Manager: `// Update Rate: 60.0Hz`); `rate_hz`, if given, is used when no line has it.
    pub rate_from: Option<String>,
    /// A packet counter column: a gap in it is lost packets (counted); without a time `column`
    /// the sample's time is its count / rate.
    pub counter: Option<Column>,
    /// The counter wraps at this value (default 65536, a 16-bit counter).
    pub counter_wrap: Option<f64>,
}

/// Units and frame conventions.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Units {
    #[serde(default)]
    pub accelerometer: AccelerometerUnit,
    #[serde(default)]
    pub gyroscope: GyroscopeUnit,
    #[serde(default)]
    pub magnetometer: MagnetometerUnit,
    /// Unit of Euler-angle columns.
    #[serde(default)]
    pub angles: AngleUnit,
    /// Order of quaternion components, for four columns and for one cell holding all four.
    #[serde(default)]
    pub quaternion_order: QuaternionOrder,
    /// The up axis of the inertial frame the orientations (and free accelerations) are in.
    #[serde(default = "default_up")]
    pub up: SignedAxis,
    /// Gravity added back to free acceleration, m/s².
    #[serde(default = "default_gravity")]
    pub gravity_mps2: f64,
    /// A sensor with an orientation but no acceleration columns: `invalid` (its samples are not
    /// valid) or `gravity` (specific force = what gravity alone gives, free acceleration 0).
    #[serde(default)]
    pub missing_accelerometer: MissingAccelerometer,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            accelerometer: AccelerometerUnit::default(),
            gyroscope: GyroscopeUnit::default(),
            magnetometer: MagnetometerUnit::default(),
            angles: AngleUnit::default(),
            quaternion_order: QuaternionOrder::default(),
            up: default_up(),
            gravity_mps2: default_gravity(),
            missing_accelerometer: MissingAccelerometer::default(),
        }
    }
}

fn default_up() -> SignedAxis {
    SignedAxis::PlusZ
}

fn default_gravity() -> f64 {
    crate::units::GRAVITY_MPS2
}

/// What a sensor without acceleration columns delivers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MissingAccelerometer {
    #[default]
    Invalid,
    Gravity,
}

/// A column: by header name, or by 1-based number (counting as a spreadsheet does).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(untagged)]
pub enum Column {
    Name(String),
    Number(usize),
}

impl std::fmt::Display for Column {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Column::Name(n) => write!(f, "'{n}'"),
            Column::Number(n) => write!(f, "number {n}"),
        }
    }
}

/// A quaternion: four columns, or one cell holding all four separated by commas or spaces.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(untagged)]
pub enum QuaternionColumns {
    One(Column),
    Four([Column; 4]),
}

/// One sensor's files and columns.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorLayout {
    /// The sensor's file, relative to the recording folder (or to the recording file's folder);
    /// none: the recording file itself.
    pub file: Option<PathBuf>,
    /// Several files (e.g. one per quantity): the first one's rows are the samples; each other
    /// file's rows join the sample nearest in time (within `join_tolerance_s`).
    pub files: Option<Vec<PathBuf>>,
    /// Overrides the layout's `[time]` for this sensor.
    pub time: Option<TimeLayout>,
    /// Added to this sensor's times to put it on the recording's shared clock, s.
    #[serde(default)]
    pub time_offset_s: f64,
    /// Largest time difference at which a row of a further file joins a sample, s (default: half
    /// the median sample interval of the first file).
    pub join_tolerance_s: Option<f64>,
    /// Our sensor axes in terms of the file's: `["-y", "x", "z"]` means our x is the file's −y,
    /// and so on. Must be a rotation.
    pub axes: Option<[SignedAxis; 3]>,
    /// Specific force in the sensor frame (what an accelerometer measures).
    pub accelerometer: Option<[Column; 3]>,
    /// Free acceleration (gravity removed) in the inertial frame; turned into specific force
    /// with the orientation.
    pub free_acceleration: Option<[Column; 3]>,
    pub gyroscope: Option<[Column; 3]>,
    pub magnetometer: Option<[Column; 3]>,
    /// On-board orientation R_IS as a quaternion.
    pub quaternion: Option<QuaternionColumns>,
    /// On-board orientation as Euler angles about x, y, z (roll, pitch, yaw):
    /// R_IS = Rz(z)·Ry(y)·Rx(x), the Xsens convention.
    pub euler_xyz: Option<[Column; 3]>,
    /// On-board orientation R_IS as a rotation matrix, nine columns row by row (R11, R12, R13,
    /// R21, ...).
    pub rotation_matrix: Option<[Column; 9]>,
    /// The sensor's id, for `{id}` in `[files] match`.
    pub id: Option<String>,
    /// Quantities read only when the file has their columns (one export, several variants).
    #[serde(default)]
    pub optional: Vec<Quantity>,
}

/// A quantity a sensor's columns hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    Accelerometer,
    FreeAcceleration,
    Gyroscope,
    Magnetometer,
    Quaternion,
    RotationMatrix,
    EulerXyz,
}

impl SensorLayout {
    /// Whether the sensor has an on-board orientation.
    pub fn has_orientation(&self) -> bool {
        self.quaternion.is_some() || self.euler_xyz.is_some() || self.rotation_matrix.is_some()
    }

    /// Whether `q` may be absent from the file.
    pub fn is_optional(&self, q: Quantity) -> bool {
        self.optional.contains(&q)
    }
}

impl Layout {
    /// Reads and checks a layout file.
    pub fn load(path: &Path) -> Result<Layout, Error> {
        let text = read_text(path)?;
        Layout::parse(&text, path)
    }

    /// Parses and checks a layout; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Layout, Error> {
        let layout: Layout = toml::from_str(text).map_err(|e| toml_error(path, text, &e))?;
        layout.check(path)?;
        Ok(layout)
    }

    /// The sites the layout lists.
    pub fn site_mask(&self) -> crate::SiteMask {
        crate::SiteMask(self.sites().fold(0, |m, (i, _)| m | 1 << i))
    }

    /// The sensors in site order, each with its index.
    pub fn sites(&self) -> impl Iterator<Item = (usize, &SensorLayout)> {
        SITES
            .iter()
            .enumerate()
            .filter_map(|(i, name)| self.sensors.get(*name).map(|s| (i, s)))
    }

    /// The time layout of `sensor`.
    pub fn time_of<'a>(&'a self, sensor: &'a SensorLayout) -> Option<&'a TimeLayout> {
        sensor.time.as_ref().or(self.time.as_ref())
    }

    fn check(&self, path: &Path) -> Result<(), Error> {
        let fail = |m: String| Err(Error::file(path, m));
        if self.sensors.is_empty() {
            return fail(format!(
                "no [sensors.<site>] table (sites: {})",
                SITES.join(", ")
            ));
        }
        if let Some(name) = self.sensors.keys().find(|k| !SITES.contains(&k.as_str())) {
            return fail(format!(
                "[sensors.{name}]: unknown site (sites: {})",
                SITES.join(", ")
            ));
        }
        if !matches!(self.table.decimal, '.' | ',') {
            return fail(format!(
                "[table] decimal = '{}': must be \".\" or \",\"",
                self.table.decimal
            ));
        }
        if self.table.decimal == ',' && self.table.delimiter == Delimiter::Comma {
            return fail("[table]: a decimal comma needs a delimiter other than comma".into());
        }
        if !(self.units.gravity_mps2.is_finite() && self.units.gravity_mps2 > 0.0) {
            return fail("[units] gravity_mps2 must be a positive number".into());
        }
        if let Some(files) = &self.files {
            let (site, id) = (
                files.pattern.contains("{site}"),
                files.pattern.contains("{id}"),
            );
            if site == id {
                return fail(format!(
                    "[files] match = \"{}\": give `{{site}}` or `{{id}}` in the pattern, once",
                    files.pattern
                ));
            }
            if files.ids.is_some() && !id {
                return fail("[files] ids: the ids need `{id}` in `match`".into());
            }
        }
        let by_id = self
            .files
            .as_ref()
            .is_some_and(|f| f.pattern.contains("{id}"));
        for (name, sensor) in &self.sensors {
            if sensor.id.is_some() && !by_id {
                return fail(format!(
                    "[sensors.{name}] id: an id needs [files] match with `{{id}}`"
                ));
            }
        }
        for (name, sensor) in &self.sensors {
            self.check_sensor(sensor)
                .map_err(|m| Error::file(path, format!("[sensors.{name}]: {m}")))?;
        }
        Ok(())
    }

    fn check_sensor(&self, s: &SensorLayout) -> Result<(), String> {
        if s.file.is_some() && s.files.is_some() {
            return Err("give `file` or `files`, not both".into());
        }
        if s.files.as_ref().is_some_and(|f| f.is_empty()) {
            return Err("`files` is empty".into());
        }
        let several = s.files.as_ref().is_some_and(|f| f.len() > 1);
        if several && !self.table.header {
            return Err("several files need a header row: columns must be given by name".into());
        }
        let Some(time) = self.time_of(s) else {
            return Err("no [time] (a `column` with its `unit`, or a `rate_hz`)".into());
        };
        check_time(time)?;
        let required_orientations = [
            (s.quaternion.is_some(), Quantity::Quaternion),
            (s.rotation_matrix.is_some(), Quantity::RotationMatrix),
            (s.euler_xyz.is_some(), Quantity::EulerXyz),
        ]
        .iter()
        .filter(|(given, q)| *given && !s.is_optional(*q))
        .count();
        if required_orientations > 1 {
            return Err(
                "give one of `quaternion`, `rotation_matrix` or `euler_xyz` (others may be listed in `optional`)"
                    .into(),
            );
        }
        if s.accelerometer.is_some() && s.free_acceleration.is_some() {
            return Err("give `accelerometer` or `free_acceleration`, not both".into());
        }
        if s.free_acceleration.is_some() && !s.has_orientation() {
            return Err(
                "`free_acceleration` needs the orientation (`quaternion` or `euler_xyz`) to turn it into the sensor frame"
                    .into(),
            );
        }
        let has_acceleration = s.accelerometer.is_some() || s.free_acceleration.is_some();
        if !has_acceleration && !s.has_orientation() {
            return Err(
                "no data: give `accelerometer` or `free_acceleration`, or an orientation".into(),
            );
        }
        if !s.time_offset_s.is_finite() {
            return Err("`time_offset_s` must be a number".into());
        }
        if s.join_tolerance_s
            .is_some_and(|t| !(t.is_finite() && t >= 0.0))
        {
            return Err("`join_tolerance_s` must be a number >= 0".into());
        }
        if let Some(axes) = s.axes {
            crate::sample::axis_matrix(axes)?;
        }
        if let Some(c) = self
            .columns(s)
            .into_iter()
            .find(|c| *c == &Column::Number(0))
        {
            return Err(format!("column {c}: columns are numbered from 1"));
        }
        if !self.table.header
            && let Some(c) = self
                .columns(s)
                .into_iter()
                .find(|c| matches!(c, Column::Name(_)))
        {
            return Err(format!(
                "column {c} is a name but [table] header = false: give column numbers"
            ));
        }
        Ok(())
    }

    /// Every column `s` names, the time column included.
    fn columns<'a>(&'a self, s: &'a SensorLayout) -> Vec<&'a Column> {
        let mut out: Vec<&Column> = Vec::new();
        for triple in [
            &s.accelerometer,
            &s.free_acceleration,
            &s.gyroscope,
            &s.magnetometer,
            &s.euler_xyz,
        ]
        .into_iter()
        .flatten()
        {
            out.extend(triple.iter());
        }
        if let Some(m) = &s.rotation_matrix {
            out.extend(m.iter());
        }
        match &s.quaternion {
            Some(QuaternionColumns::One(c)) => out.push(c),
            Some(QuaternionColumns::Four(cs)) => out.extend(cs.iter()),
            None => {}
        }
        if let Some(t) = self.time_of(s) {
            out.extend(t.column.iter().chain(&t.counter));
        }
        out
    }
}

fn check_time(time: &TimeLayout) -> Result<(), String> {
    let rate_given = time.rate_hz.is_some() || time.rate_from.is_some();
    if time.counter_wrap.is_some() && time.counter.is_none() {
        return Err("[time] counter_wrap needs a `counter`".into());
    }
    if time
        .counter_wrap
        .is_some_and(|w| !(w.is_finite() && w >= 2.0))
    {
        return Err("[time] counter_wrap must be a number >= 2".into());
    }
    match (&time.column, rate_given) {
        (Some(_), true) => Err("[time]: give `column` or a rate, not both".into()),
        (None, false) if time.counter.is_some() => {
            Err("[time]: a `counter` as the time needs its rate (`rate_hz` or `rate_from`)".into())
        }
        (None, false) => Err("[time]: give a `column` (with its `unit`) or a `rate_hz`".into()),
        (Some(_), false) if time.unit.is_none() => {
            Err("[time]: the time column needs its `unit` (s, ms, us or ns)".into())
        }
        (None, true) if time.rate_hz.is_some_and(|r| !(r.is_finite() && r > 0.0)) => {
            Err("[time] rate_hz must be a positive number".into())
        }
        _ if time.wrap.is_some_and(|w| !(w.is_finite() && w > 0.0)) => {
            Err("[time] wrap must be a positive number".into())
        }
        _ => Ok(()),
    }
}

/// A TOML error as a line error when it has a position.
fn toml_error(path: &Path, text: &str, e: &toml::de::Error) -> Error {
    let message = e.message().to_owned();
    match e.span() {
        Some(span) => Error::line(path, line_of(text, span.start), message),
        None => Error::file(path, message),
    }
}

/// The 1-based line of byte offset `at` in `text`.
pub(crate) fn line_of(text: &str, at: usize) -> usize {
    let at = at.min(text.len());
    1 + text.as_bytes()[..at]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
}
