//! Xsens MVNX, MVN's XML export (MVN User Manual MV0319P, "MVNX file format"):
//!
//! ```text
//! <mvnx><subject frameRate="60">
//!   <segments><segment label="Pelvis" id="1">...</segment>...</segments>
//!   <sensors><sensor label="Pelvis"/>...</sensors>
//!   <frames>
//!     <frame time="0" index="..." type="identity|tpose|tpose-isb|npose|normal">
//!       <orientation>  q_GB (w x y z) per segment   </orientation>
//!       <position>     origin in G (m) per segment  </position>
//!       <sensorOrientation>      q_GS (w x y z) per sensor                </sensorOrientation>
//!       <sensorFreeAcceleration> a in G, gravity removed (m/s²) per sensor </sensorFreeAcceleration>
//!       <sensorMagneticField>    field in S (normalised units) per sensor  </sensorMagneticField>
//! ```
//!
//! Older files carry `sensorAcceleration` and `sensorAngularVelocity` (sensor frame) instead of
//! or beside the free acceleration. The file is streamed: each frame becomes its samples and its
//! pose as soon as it is read.

use std::path::Path;

use nalgebra::Vector3;
use quick_xml::events::{BytesStart, Event};
use quick_xml::reader::Reader;

use crate::error::{Error, read_text};
use crate::mvn::SegmentMap;
use crate::recording::{SensorRecording, Track, count, merge};
use crate::sample::{
    Sample, derive_gyroscope, gravity_in_inertial, normalise_arbitrary_magnetometer,
    specific_force_from_free_acceleration, unit_quaternion,
};
use crate::units::{GRAVITY_MPS2, SignedAxis};
use crate::{MAX_SITES, SITES, SiteMask};

/// MVN's sensor labels on the catalogue's sites, in wire slot order (MVN names sensors by
/// segment; its chest sensor sits on the T8 segment, the sternum).
pub const SENSOR_LABELS: [&str; MAX_SITES] = [
    "LeftForeArm",
    "RightForeArm",
    "LeftLowerLeg",
    "RightLowerLeg",
    "Head",
    "Pelvis",
    "LeftUpperLeg",
    "RightUpperLeg",
    "LeftFoot",
    "RightFoot",
    "T8",
    "LeftShoulder",
    "RightShoulder",
    "LeftUpperArm",
    "RightUpperArm",
    "LeftHand",
    "RightHand",
];

/// The per-frame elements this reader uses.
const ELEMENTS: [&str; 7] = [
    "orientation",
    "position",
    "sensorOrientation",
    "sensorFreeAcceleration",
    "sensorMagneticField",
    "sensorAcceleration",
    "sensorAngularVelocity",
];

/// One `<frame>` as read: its numbers per element of [`ELEMENTS`].
#[derive(Debug, Default)]
struct FrameData {
    line: usize,
    kind: String,
    time_ms: Option<f64>,
    values: [Option<Vec<f64>>; ELEMENTS.len()],
}

impl FrameData {
    fn get(&self, element: &str) -> Option<&[f64]> {
        let i = ELEMENTS.iter().position(|e| *e == element)?;
        self.values[i].as_deref()
    }
}

/// Reads the sensors of `wanted` from an MVNX file into a recording with truth.
pub fn read(path: &Path, wanted: SiteMask) -> Result<SensorRecording, Error> {
    let text = read_text(path)?;
    let mut doc = Document::new(path, &text, wanted);
    doc.parse()?;
    doc.finish()
}

/// The reading state.
struct Document<'a> {
    path: &'a Path,
    text: &'a str,
    lines: LineIndex,
    frame_rate: Option<f64>,
    segments: Vec<String>,
    sensors: Vec<String>,
    /// The sites to read.
    wanted: SiteMask,
    /// Set at the first frame: the segment map and each wanted site's (slot, sensor index).
    map: Option<(SegmentMap, Vec<(usize, usize)>)>,
    tracks: [Track; MAX_SITES],
    truth: Vec<(i64, imuflow_graph::frames::MotionFrame)>,
    /// Calibration and reference poses (`identity`, `tpose`, ...), by type.
    poses: Vec<(String, imuflow_graph::frames::MotionFrame)>,
    has_angular_velocity: bool,
    last_time_ns: Option<i64>,
}

impl<'a> Document<'a> {
    fn new(path: &'a Path, text: &'a str, wanted: SiteMask) -> Self {
        Document {
            path,
            text,
            wanted,
            lines: LineIndex::default(),
            frame_rate: None,
            segments: Vec::new(),
            sensors: Vec::new(),
            map: None,
            tracks: Default::default(),
            truth: Vec::new(),
            poses: Vec::new(),
            has_angular_velocity: false,
            last_time_ns: None,
        }
    }

    fn line_at(&mut self, pos: u64) -> usize {
        self.lines.line(self.text, pos as usize)
    }

    /// Streams the XML, handling each element as it closes.
    fn parse(&mut self) -> Result<(), Error> {
        let mut reader = Reader::from_str(self.text);
        reader.config_mut().trim_text(true);
        let mut stack: Vec<String> = Vec::new();
        let mut frame: Option<FrameData> = None;
        let mut capture: Option<(usize, usize, String)> = None; // element, line, text
        loop {
            let event = match reader.read_event() {
                Ok(e) => e,
                Err(e) => {
                    let line = self.line_at(reader.error_position());
                    return Err(Error::line(self.path, line, format!("broken XML: {e}")));
                }
            };
            match event {
                Event::Start(e) => {
                    let name = local(&e);
                    // Just after the tag's `>`: the tag's own line (before the event, the
                    // position is still on the line of what came before).
                    let line = self.line_at(reader.buffer_position());
                    if stack.is_empty() && name != "mvnx" {
                        return Err(Error::line(
                            self.path,
                            line,
                            format!("not an MVNX file: the root element is <{name}>, not <mvnx>"),
                        ));
                    }
                    self.open(&e, &name, &stack, line, &mut frame)?;
                    if frame.is_some() && stack.last().is_some_and(|p| p == "frame") {
                        capture = ELEMENTS
                            .iter()
                            .position(|x| *x == name)
                            .map(|i| (i, line, String::new()));
                    }
                    stack.push(name);
                }
                Event::Empty(e) => {
                    let name = local(&e);
                    // Just after the tag's `>`: the tag's own line (before the event, the
                    // position is still on the line of what came before).
                    let line = self.line_at(reader.buffer_position());
                    self.open(&e, &name, &stack, line, &mut frame)?;
                }
                Event::Text(t) => {
                    if let Some((_, _, buf)) = &mut capture {
                        let s = t.decode().map_err(|e| {
                            Error::line(
                                self.path,
                                self.lines.last_line(),
                                format!("broken text: {e}"),
                            )
                        })?;
                        buf.push_str(&s);
                    }
                }
                Event::End(_) => {
                    let name = stack.pop().unwrap_or_default();
                    if let (Some((i, line, buf)), Some(f)) = (capture.take(), frame.as_mut()) {
                        f.values[i] = Some(numbers(&buf).map_err(|m| {
                            Error::line(self.path, line, format!("<{}>: {m}", ELEMENTS[i]))
                        })?);
                    }
                    if name == "frame"
                        && let Some(f) = frame.take()
                    {
                        self.frame(f)?;
                    }
                }
                Event::Eof => break,
                _ => {}
            }
        }
        if let Some(open) = stack.last() {
            let line = self.line_at(self.text.len() as u64);
            return Err(Error::line(
                self.path,
                line,
                format!("the file ends inside <{open}> (truncated?)"),
            ));
        }
        Ok(())
    }

    /// An opening tag: subject, segment and sensor labels, the start of a frame.
    fn open(
        &mut self,
        e: &BytesStart,
        name: &str,
        stack: &[String],
        line: usize,
        frame: &mut Option<FrameData>,
    ) -> Result<(), Error> {
        let parent = stack.last().map(String::as_str);
        let attr = |key: &str| -> Result<Option<String>, Error> {
            match e.try_get_attribute(key) {
                Ok(Some(a)) => a
                    .unescape_value()
                    .map(|v| Some(v.into_owned()))
                    .map_err(|err| Error::line(self.path, line, format!("attribute {key}: {err}"))),
                Ok(None) => Ok(None),
                Err(err) => Err(Error::line(self.path, line, format!("broken XML: {err}"))),
            }
        };
        match (name, parent) {
            ("subject", _) => {
                if let Some(rate) = attr("frameRate")? {
                    let r: f64 = rate.trim().parse().map_err(|_| {
                        Error::line(self.path, line, format!("frameRate: bad number '{rate}'"))
                    })?;
                    self.frame_rate = (r > 0.0).then_some(r);
                }
            }
            ("segment", Some("segments")) => self.segments.push(attr("label")?.unwrap_or_default()),
            ("sensor", Some("sensors")) => self.sensors.push(attr("label")?.unwrap_or_default()),
            ("frame", Some("frames")) => {
                let time_ms = match attr("time")? {
                    Some(t) => Some(t.trim().parse::<f64>().map_err(|_| {
                        Error::line(self.path, line, format!("frame time: bad number '{t}'"))
                    })?),
                    None => None,
                };
                *frame = Some(FrameData {
                    line,
                    kind: attr("type")?.unwrap_or_else(|| "normal".into()),
                    time_ms,
                    values: Default::default(),
                });
            }
            _ => {}
        }
        Ok(())
    }

    /// The segment map and the sensors of our sites, found at the first frame.
    fn mapping(&mut self) -> Result<(SegmentMap, Vec<(usize, usize)>), Error> {
        if let Some(m) = &self.map {
            return Ok(m.clone());
        }
        let map = SegmentMap::new(&self.segments).map_err(|m| Error::file(self.path, m))?;
        let mut sites = Vec::new();
        for slot in self.wanted.sites().map(|s| s.index()) {
            let label = SENSOR_LABELS[slot];
            let sensor = self
                .sensors
                .iter()
                .position(|s| s == label)
                .ok_or_else(|| {
                    Error::file(
                        self.path,
                        format!(
                            "no sensor '{label}' (needed for {} of the sensor set read: {}; sensors: {})",
                            SITES[slot],
                            self.wanted.names(),
                            self.sensors.join(", ")
                        ),
                    )
                })?;
            sites.push((slot, sensor));
        }
        self.map = Some((map.clone(), sites.clone()));
        Ok((map, sites))
    }

    /// Handles one complete frame.
    fn frame(&mut self, f: FrameData) -> Result<(), Error> {
        let (map, sites) = self.mapping()?;
        let at = |m: String| Error::line(self.path, f.line, m);
        let pose = self.pose(&map, &f)?;
        if f.kind != "normal" {
            if let Some(p) = pose {
                self.poses.push((f.kind.clone(), p));
            }
            return Ok(());
        }
        let time_ns = self.time_ns(&f).map_err(at)?;
        if let Some(last) = self.last_time_ns
            && time_ns <= last
        {
            return Err(at(format!(
                "frame time {} ms does not increase",
                f.time_ms.unwrap_or(0.0)
            )));
        }
        self.last_time_ns = Some(time_ns);
        let pose =
            pose.ok_or_else(|| at("normal frame without <orientation> and <position>".into()))?;
        self.truth.push((time_ns, pose));
        let n = self.sensors.len();
        let q = need(&f, "sensorOrientation", 4, n).map_err(at)?;
        let free = optional(&f, "sensorFreeAcceleration", 3, n).map_err(at)?;
        let acc = optional(&f, "sensorAcceleration", 3, n).map_err(at)?;
        if free.is_none() && acc.is_none() {
            return Err(at("no <sensorFreeAcceleration> (nor <sensorAcceleration>): export the MVNX with sensor data".into()));
        }
        let mag = optional(&f, "sensorMagneticField", 3, n).map_err(at)?;
        let gyr = optional(&f, "sensorAngularVelocity", 3, n).map_err(at)?;
        self.has_angular_velocity |= gyr.is_some();
        let gravity = gravity_in_inertial(SignedAxis::PlusZ, GRAVITY_MPS2);
        for &(site, s) in &sites {
            let v3 = |v: Option<&[f64]>| {
                v.map(|v| Vector3::new(v[3 * s], v[3 * s + 1], v[3 * s + 2]))
                    .filter(|v| v.iter().all(|x| x.is_finite()))
            };
            let orientation = unit_quaternion([q[4 * s], q[4 * s + 1], q[4 * s + 2], q[4 * s + 3]])
                .map_err(|m| {
                    at(format!(
                        "<sensorOrientation> of sensor '{}': {m}",
                        SENSOR_LABELS[site]
                    ))
                })?;
            let accelerometer_mps2 = match (v3(free), orientation) {
                (Some(a), Some(r)) => Some(specific_force_from_free_acceleration(&a, &r, &gravity)),
                _ if free.is_none() => v3(acc),
                _ => None,
            };
            self.tracks[site].samples.push(Sample {
                time_ns,
                accelerometer_mps2,
                gyroscope_radps: v3(gyr),
                magnetometer_ut: v3(mag),
                orientation,
            });
        }
        Ok(())
    }

    /// The frame's pose on imuflow's body, if it has segment orientations and positions.
    fn pose(
        &self,
        map: &SegmentMap,
        f: &FrameData,
    ) -> Result<Option<imuflow_graph::frames::MotionFrame>, Error> {
        let n = self.segments.len();
        let at = |m: String| Error::line(self.path, f.line, m);
        let (Some(q), Some(p)) = (
            optional(f, "orientation", 4, n).map_err(at)?,
            optional(f, "position", 3, n).map_err(at)?,
        ) else {
            return Ok(None);
        };
        let mut orientations = Vec::with_capacity(n);
        for s in 0..n {
            let q = unit_quaternion([q[4 * s], q[4 * s + 1], q[4 * s + 2], q[4 * s + 3]])
                .map_err(|m| {
                    at(format!(
                        "<orientation> of segment '{}': {m}",
                        self.segments[s]
                    ))
                })?
                .ok_or_else(|| {
                    at(format!(
                        "<orientation> of segment '{}' is missing (NaN or zero)",
                        self.segments[s]
                    ))
                })?;
            orientations.push(q);
        }
        let positions: Vec<Vector3<f64>> = (0..n)
            .map(|s| Vector3::new(p[3 * s], p[3 * s + 1], p[3 * s + 2]))
            .collect();
        Ok(Some(map.pose(&orientations, &positions)))
    }

    /// A normal frame's time in ns: the `time` attribute (ms), snapped to the frame period when
    /// the subject has a `frameRate`: MVN writes the time of frame n as n/rate in whole ms, so at
    /// 240 Hz the written times are up to 0.5 ms off; the nearest frame instant undoes that.
    fn time_ns(&self, f: &FrameData) -> Result<i64, String> {
        let ms = f.time_ms.ok_or("frame without a time attribute")?;
        if !(ms.is_finite() && ms >= 0.0) {
            return Err(format!("frame time {ms} ms is not a time"));
        }
        let seconds = match self.frame_rate {
            Some(rate) => (ms * 1e-3 * rate).round() / rate,
            None => ms * 1e-3,
        };
        Ok((seconds * 1e9).round() as i64)
    }

    /// The recording: angular rates derived where the file has none, magnetometers normalised,
    /// samples merged and the truth on the same clock.
    fn finish(mut self) -> Result<SensorRecording, Error> {
        if self.truth.is_empty() {
            return Err(Error::file(self.path, "no frame of type \"normal\""));
        }
        let mut counts = [Default::default(); MAX_SITES];
        let wanted = self.wanted;
        let read = self
            .tracks
            .iter_mut()
            .zip(counts.iter_mut())
            .enumerate()
            .filter(|(slot, _)| wanted.contains_slot(*slot));
        for (_, (track, c)) in read {
            let derived = if self.has_angular_velocity {
                0
            } else {
                derive_gyroscope(&mut track.samples) as u64
            };
            normalise_arbitrary_magnetometer(&mut track.samples);
            *c = count(track, true, true);
            c.derived_gyroscope = derived;
        }
        let (frames, start) = merge(&self.tracks);
        let truth = self
            .truth
            .into_iter()
            .enumerate()
            .map(|(seq, (t, mut m))| {
                m.header.seq = seq as u64;
                m.header.capture_ns = (t - start).max(0) as u64;
                m
            })
            .collect();
        Ok(SensorRecording {
            source: self.path.to_owned(),
            frames,
            truth: Some(truth),
            counts,
            sites: self.wanted,
            left_out: SENSOR_LABELS
                .iter()
                .enumerate()
                .filter(|(slot, label)| {
                    !self.wanted.contains_slot(*slot) && self.sensors.iter().any(|s| s == *label)
                })
                .map(|(slot, _)| SITES[slot])
                .collect(),
        })
    }
}

/// The element's numbers, which must be `per` × `count` of them.
fn need<'f>(
    f: &'f FrameData,
    element: &str,
    per: usize,
    count: usize,
) -> Result<&'f [f64], String> {
    optional(f, element, per, count)?.ok_or_else(|| format!("frame without <{element}>"))
}

fn optional<'f>(
    f: &'f FrameData,
    element: &str,
    per: usize,
    count: usize,
) -> Result<Option<&'f [f64]>, String> {
    match f.get(element) {
        Some(v) if v.len() != per * count => Err(format!(
            "<{element}> has {} numbers, expected {per} for each of {count}",
            v.len()
        )),
        other => Ok(other),
    }
}

/// Whitespace-separated numbers; NaN stays NaN (a missing value).
fn numbers(text: &str) -> Result<Vec<f64>, String> {
    text.split_whitespace()
        .map(|t| t.parse::<f64>().map_err(|_| format!("bad number '{t}'")))
        .collect()
}

fn local(e: &BytesStart) -> String {
    String::from_utf8_lossy(e.local_name().as_ref()).into_owned()
}

/// Line numbers of byte offsets that only grow: counts newlines from the last offset asked.
#[derive(Debug, Default)]
struct LineIndex {
    pos: usize,
    line: usize,
}

impl LineIndex {
    fn line(&mut self, text: &str, pos: usize) -> usize {
        let pos = pos.min(text.len());
        if pos < self.pos {
            self.pos = 0;
            self.line = 0;
        }
        self.line += text.as_bytes()[self.pos..pos]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        self.pos = pos;
        self.line + 1
    }

    fn last_line(&self) -> usize {
        self.line + 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn fixture(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures")
            .join(name)
    }

    #[test]
    fn the_identity_pose_is_the_rest_pose_and_the_tpose_is_near_it() {
        let path = fixture("mvnx/session.mvnx");
        let text = read_text(&path).unwrap();
        let mut doc = Document::new(&path, &text, SiteMask::of(imuflow_body::Imu::SIX));
        doc.parse().unwrap();
        let kinds: Vec<&str> = doc.poses.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(kinds, ["identity", "tpose"]);
        for (kind, pose) in &doc.poses {
            for (j, q) in pose.local_pose_wxyz.iter().enumerate() {
                let angle = 2.0 * f64::from(q[0]).clamp(-1.0, 1.0).acos();
                let limit = if kind == "identity" { 1e-6 } else { 0.1 };
                assert!(angle < limit, "{kind}: joint {j} turned {angle} rad");
            }
        }
    }
}
