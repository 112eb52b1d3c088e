//! A read recording: every sensor's samples merged into `RawImuFrame`s on a shared clock, the
//! true motion where the file has one, and what was counted on the way.

use std::fmt;
use std::path::PathBuf;

use imuflow_body::{MAX_SITES, SiteMask};
use imuflow_graph::frames::{MotionFrame, RawImuFrame};

use crate::sample::Sample;

/// What was read for one sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SensorCounts {
    /// Samples (rows) read.
    pub samples: u64,
    /// Samples with accelerometer and gyroscope (`valid_mask` set).
    pub valid: u64,
    /// Samples whose accelerometer (or free acceleration) was missing: empty or NaN cells, or
    /// free acceleration without an orientation.
    pub missing_accelerometer: u64,
    /// Samples whose gyroscope was missing.
    pub missing_gyroscope: u64,
    /// Samples whose magnetometer was missing (only counted when the sensor has one).
    pub missing_magnetometer: u64,
    /// Samples whose on-board orientation was missing (only counted when the sensor has one).
    pub missing_orientation: u64,
    /// Samples whose angular rate was derived from the on-board orientations (no gyroscope in
    /// the file).
    pub derived_gyroscope: u64,
    /// Rows of a sensor's further files that joined no sample (no sample within the tolerance).
    pub unjoined_rows: u64,
    /// Samples lost: gaps in the packet counter (`[time] counter`), or without one gaps in the
    /// time column longer than 1.5 median intervals (each holding round(gap / median) − 1).
    pub lost: u64,
}

impl fmt::Display for SensorCounts {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} samples, {} valid", self.samples, self.valid)?;
        let extra = [
            (self.missing_accelerometer, "without accelerometer"),
            (self.missing_gyroscope, "without gyroscope"),
            (self.missing_magnetometer, "without magnetometer"),
            (self.missing_orientation, "without orientation"),
            (self.derived_gyroscope, "gyroscope from orientation"),
            (self.unjoined_rows, "rows of further files joined no sample"),
            (self.lost, "lost (gaps in the packet counter or the time)"),
        ];
        for (n, what) in extra.iter().filter(|(n, _)| *n > 0) {
            write!(f, ", {n} {what}")?;
        }
        Ok(())
    }
}

/// A recording read from files.
#[derive(Debug, Clone, Default)]
pub struct SensorRecording {
    /// The recording (file or folder) it was read from.
    pub source: PathBuf,
    /// Every sample, merged into frames sorted by capture time; at most one sample per sensor
    /// per frame. `seq` is the index; `capture_ns` the time on the recording's shared clock,
    /// which starts at 0 with the earliest sample; `sample_time_ns` each sensor's own time
    /// (the file's time column).
    pub frames: Vec<RawImuFrame>,
    /// The true motion where the file has one (MVNX): local pose and root position per file
    /// frame, `capture_ns` on the same shared clock, `seq` the index.
    pub truth: Option<Vec<MotionFrame>>,
    /// Per sensor, by wire slot (zero for the sites not read).
    pub counts: [SensorCounts; MAX_SITES],
    /// The sites read.
    pub sites: SiteMask,
    /// Sites the recording holds a sensor for that were not asked for, by name: not read (MVNX;
    /// CSV/TSV folders whose files are found by site or sensor id).
    pub left_out: Vec<&'static str>,
}

impl SensorRecording {
    /// One line per sensor read, for logs and run summaries.
    pub fn summary(&self) -> String {
        self.sites
            .sites()
            .map(|site| format!("{site}: {}", self.counts[site.index()]))
            .collect::<Vec<_>>()
            .join("; ")
    }
}

/// One sensor's samples before merging: sorted by its own time, with its offset to the shared
/// clock.
#[derive(Debug, Clone, Default)]
pub struct Track {
    pub samples: Vec<Sample>,
    /// Added to the sensor's own times to put them on the shared clock, ns.
    pub offset_ns: i64,
}

/// Counts what `track` holds; `has_*` say which quantities the sensor delivers at all.
pub fn count(track: &Track, has_magnetometer: bool, has_orientation: bool) -> SensorCounts {
    let mut c = SensorCounts::default();
    for s in &track.samples {
        c.samples += 1;
        let (acc, gyr) = (s.accelerometer_mps2.is_some(), s.gyroscope_radps.is_some());
        c.valid += u64::from(acc && gyr);
        c.missing_accelerometer += u64::from(!acc);
        c.missing_gyroscope += u64::from(!gyr);
        c.missing_magnetometer += u64::from(has_magnetometer && s.magnetometer_ut.is_none());
        c.missing_orientation += u64::from(has_orientation && s.orientation.is_none());
    }
    c
}

/// Merges the tracks (in site order) into frames: samples sorted by shared-clock time, a new
/// frame at every new time (sensors sampled at the same instant share a frame). The shared clock
/// starts at 0 with the earliest sample. Also returns that start, in the tracks' shared time, so
/// other streams (the truth) can be put on the same clock.
pub fn merge(tracks: &[Track; MAX_SITES]) -> (Vec<RawImuFrame>, i64) {
    let mut events: Vec<(i64, usize, &Sample)> = tracks
        .iter()
        .enumerate()
        .flat_map(|(i, t)| {
            t.samples
                .iter()
                .map(move |s| (s.time_ns + t.offset_ns, i, s))
        })
        .collect();
    events.sort_by_key(|(t, i, _)| (*t, *i));
    let start = events.first().map_or(0, |e| e.0);
    let mut frames: Vec<RawImuFrame> = Vec::new();
    // Sensors that already have a sample in the last frame.
    let mut occupied = 0u32;
    for (t, i, s) in events {
        let capture_ns = (t - start) as u64;
        let same_time = frames
            .last()
            .is_some_and(|f| f.header.capture_ns == capture_ns);
        if !same_time || occupied >> i & 1 == 1 {
            let mut f = RawImuFrame::default();
            f.header.seq = frames.len() as u64;
            f.header.capture_ns = capture_ns;
            frames.push(f);
            occupied = 0;
        }
        if let Some(f) = frames.last_mut() {
            put(f, i, s);
            occupied |= 1 << i;
        }
    }
    (frames, start)
}

/// Writes sample `s` of sensor `i` into `f`.
fn put(f: &mut RawImuFrame, i: usize, s: &Sample) {
    let bit = 1u32 << i;
    let v = |v: &nalgebra::Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
    f.sample_time_ns[i] = s.time_ns.max(0) as u64;
    if let Some(a) = &s.accelerometer_mps2 {
        f.accelerometer_mps2[i] = v(a);
    }
    if let Some(w) = &s.gyroscope_radps {
        f.gyroscope_radps[i] = v(w);
    }
    if s.accelerometer_mps2.is_some() && s.gyroscope_radps.is_some() {
        f.valid_mask |= bit;
    }
    if let Some(m) = &s.magnetometer_ut {
        f.magnetometer_ut[i] = v(m);
        f.magnetometer_mask |= bit;
    }
    if let Some(q) = &s.orientation {
        // w ≥ 0, as everywhere on the wire.
        let q = if q.w < 0.0 {
            -q.into_inner()
        } else {
            q.into_inner()
        };
        f.orientation_wxyz[i] = [q.w as f32, q.i as f32, q.j as f32, q.k as f32];
        f.orientation_mask |= bit;
    }
}
