//! `imuflow bench live`: glass-to-glass latency of a live graph, measured with third-party clients
//! at both ends (docs/live-latency.md).
//!
//! - `onboard`: SlimeVR's own tracker emulator (`tools/live-bench/emulate.mjs`, npm
//!   `@slimevr/tracker-emulation`) plays six trackers that replay the bundled sample's IMUs as the
//!   firmware sends them (on-board rotation and linear acceleration per tick) into the slimevr
//!   source of `configs/examples/slimevr-vmc.toml` (fusion, walking calibration, PIP, vmc);
//! - `burst`: the same with Wi-Fi-like stalls: every few seconds the trackers send nothing for a
//!   while, then the ticks due meanwhile back to back;
//! - `raw`: raw 200 Hz sensors (the imu-source synthesizing them, paced in real time) through the
//!   fusion stage and the same chain.
//!
//! In every scenario an independent VMC implementation (`tools/live-bench/receive_vmc.py`, PyPI
//! `vmcp` on `osc4py3`) receives the vmc stage's bundles. The latency of a bundle is its receive
//! time minus the moment its pose describes (`/imuflow/CaptureTime`, the frame's `capture_ns`),
//! both on the host clock. The pure parts (the sample as the firmware sends it, percentiles, the
//! pairing of received samples with the emulator's sends) are functions tested here.

use std::collections::{BTreeMap, HashMap};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, ExitStatus, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use imuflow_body::{MAX_SITES, NUM_IMUS};
use imuflow_graph::Graph;
use imuflow_graph::frames::{ImuFrame, RawImuFrame};
use imuflow_graph::launch::{self, LaunchOptions, RunReport};
use imuflow_graph::spec::Registry;
use imuflow_graph::transform::load_without;

/// The firmware's gravity (SlimeVR-Tracker-ESP `CONST_EARTH_GRAVITY`), as the slimevr source's
/// `specific_force` uses it.
pub const FIRMWARE_GRAVITY_MPS2: f64 = 9.80665;
/// The emulator package and the version `tools/live-bench/package.json` pins.
pub const EMULATOR: (&str, &str) = ("@slimevr/tracker-emulation", "0.2.6");
/// The VMC receiver's package and version.
pub const RECEIVER: (&str, &str) = ("vmcp", "1.0.6");
/// Where the node package and the receiver live, relative to the repository root.
const LIVE_BENCH_DIR: &str = "tools/live-bench";
/// The graph of the emulator scenarios.
const TRACKERS_GRAPH: &str = "configs/examples/slimevr-vmc.toml";
/// Bones per bundle (stages/vmc: the 22 humanoid bones).
const BONES: u32 = 22;
/// The slimevr source ends its stream this long after the last tracker packet.
const SOURCE_SILENCE_MS: u64 = 1500;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Scenario {
    /// SlimeVR's tracker emulator sends on-board orientations and accelerations.
    Onboard,
    /// As onboard, with Wi-Fi-like stalls and the delayed ticks sent back to back.
    Burst,
    /// Raw 200 Hz sensors (synthesized, real time) through the fusion stage.
    Raw,
}

impl Scenario {
    fn name(self) -> &'static str {
        match self {
            Scenario::Onboard => "onboard",
            Scenario::Burst => "burst",
            Scenario::Raw => "raw",
        }
    }
}

#[derive(clap::Args, Debug, Clone)]
pub struct LiveArgs {
    /// What drives the graph: onboard (SlimeVR's tracker emulator, on-board orientations), burst
    /// (the same with Wi-Fi-like stalls), raw (raw 200 Hz sensors through the fusion stage).
    #[arg(long, value_enum, default_value_t = Scenario::Onboard)]
    pub scenario: Scenario,
    /// Seconds of tracker data the emulator sends (onboard, burst): the sample from its start, at
    /// most its 25.1 s; walking calibration needs its first 12-13 s. The raw scenario runs the
    /// sample's walk (14 s) whatever this says.
    #[arg(long, default_value_t = 25.0)]
    pub seconds: f64,
    /// Emulator ticks per second (onboard, burst; default 100), or the raw sensors' rate (raw;
    /// default 200).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// burst: a stall every this many seconds.
    #[arg(long, default_value_t = 2.0)]
    pub burst_every_s: f64,
    /// burst: how long each stall lasts, ms.
    #[arg(long, default_value_t = 100.0)]
    pub burst_stall_ms: f64,
    /// The trackers file: which MAC the emulator gives each site's tracker (sensor 0 of each).
    #[arg(long, default_value = "configs/trackers/slimevr-sim.toml")]
    pub trackers_file: PathBuf,
    /// The recording whose IMUs the trackers replay (its `source.imu` channel).
    #[arg(long, default_value = "models/sample/walk.mcap")]
    pub sample: PathBuf,
    /// Keep every file of the run (the emulator's data and send log, the bundles received, the
    /// graph, the run report) in DIR/SCENARIO instead of a temporary folder.
    #[arg(long, value_name = "DIR")]
    pub keep: Option<PathBuf>,
    /// The node executable that runs the emulator.
    #[arg(long, default_value = "node")]
    pub node: PathBuf,
    /// A python with vmcp[osc4py3]==1.0.6 installed (default: the verify venv,
    /// $IMUFLOW_VERIFY_VENV/bin/python or ~/.cache/imuflow/verify-venv/bin/python).
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Write the numbers as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

// ---------------------------------------------------------------------------------------------
// Pure parts

/// One tracker sample as the SlimeVR firmware sends it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirmwareSample {
    /// `R_IT` as x, y, z, w (the rotation packet's order), normalized.
    pub rotation_xyzw: [f32; 4],
    /// Linear acceleration in the tracker frame, gravity removed, m/s².
    pub linear_mps2: [f32; 3],
}

/// An IMU's orientation `R_IS` ([w, x, y, z], z-up inertial frame) and specific force (sensor
/// frame) as the firmware would send them: the rotation reordered to x, y, z, w, and the linear
/// acceleration `a = f − g·R_ISᵀ·e_z` (the inverse of the slimevr source's `specific_force`).
pub fn firmware_sample(r_is_wxyz: [f32; 4], specific_force_mps2: [f32; 3]) -> FirmwareSample {
    let [w, x, y, z] = r_is_wxyz.map(f64::from);
    let n = (w * w + x * x + y * y + z * z).sqrt();
    let (w, x, y, z) = (w / n, x / n, y / n, z / n);
    // R's third row: the inertial up axis in the sensor frame.
    let up = [
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        w * w - x * x - y * y + z * z,
    ];
    FirmwareSample {
        rotation_xyzw: [x as f32, y as f32, z as f32, w as f32],
        linear_mps2: std::array::from_fn(|i| {
            (f64::from(specific_force_mps2[i]) - FIRMWARE_GRAVITY_MPS2 * up[i]) as f32
        }),
    }
}

/// Spherical interpolation between unit quaternions (either order of components; the shorter
/// way).
fn slerp(a: [f64; 4], b: [f64; 4], t: f64) -> [f64; 4] {
    let mut dot: f64 = a.iter().zip(&b).map(|(p, q)| p * q).sum();
    let b = if dot < 0.0 {
        dot = -dot;
        b.map(|v| -v)
    } else {
        b
    };
    let (wa, wb) = if dot > 0.9995 {
        (1.0 - t, t)
    } else {
        let theta = dot.clamp(-1.0, 1.0).acos();
        let s = theta.sin();
        (((1.0 - t) * theta).sin() / s, (t * theta).sin() / s)
    };
    let q: [f64; 4] = std::array::from_fn(|i| wa * a[i] + wb * b[i]);
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / n)
}

/// One IMU frame of a recording: its time (s from the first) and per sensor `R_IS` and force.
#[derive(Debug, Clone)]
pub struct ImuSample {
    pub time_s: f64,
    pub orientation_wxyz: [[f32; 4]; MAX_SITES],
    pub specific_force_mps2: [[f32; 3]; MAX_SITES],
}

/// `frames` resampled to `rate_hz` for `seconds` (slerp between orientations, linear between
/// forces) and converted to what the firmware sends: `ticks[k][sensor]`.
pub fn tracker_ticks(
    frames: &[ImuSample],
    rate_hz: f64,
    seconds: f64,
) -> anyhow::Result<Vec<[FirmwareSample; NUM_IMUS]>> {
    let Some(last) = frames.last() else {
        bail!("the sample holds no IMU frames");
    };
    let ticks = (seconds * rate_hz).floor() as usize;
    let span = last.time_s - frames[0].time_s;
    if ticks == 0 || (ticks - 1) as f64 / rate_hz > span + 1e-9 {
        bail!(
            "--seconds {seconds} at {rate_hz} Hz: the sample holds {span:.2} s (at most that, and at least one tick)"
        );
    }
    let mut out = Vec::with_capacity(ticks);
    let mut j = 0;
    for k in 0..ticks {
        let t = frames[0].time_s + k as f64 / rate_hz;
        while j + 1 < frames.len() && frames[j + 1].time_s <= t {
            j += 1;
        }
        let (a, b) = (&frames[j], &frames[(j + 1).min(frames.len() - 1)]);
        let alpha = if b.time_s > a.time_s {
            ((t - a.time_s) / (b.time_s - a.time_s)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(std::array::from_fn(|s| {
            let q = slerp(
                a.orientation_wxyz[s].map(f64::from),
                b.orientation_wxyz[s].map(f64::from),
                alpha,
            );
            let f: [f32; 3] = std::array::from_fn(|i| {
                let (fa, fb) = (
                    f64::from(a.specific_force_mps2[s][i]),
                    f64::from(b.specific_force_mps2[s][i]),
                );
                (fa + alpha * (fb - fa)) as f32
            });
            firmware_sample(q.map(|v| v as f32), f)
        }));
    }
    Ok(out)
}

/// The emulator's input file: `tick,tracker,qx,qy,qz,qw,ax,ay,az`, each f32 written in its
/// shortest form that reads back exactly (so the rotations the source receives are these bits).
pub fn samples_csv(ticks: &[[FirmwareSample; NUM_IMUS]]) -> String {
    let mut out = String::from("tick,tracker,qx,qy,qz,qw,ax,ay,az\n");
    for (k, tick) in ticks.iter().enumerate() {
        for (i, s) in tick.iter().enumerate() {
            let [qx, qy, qz, qw] = s.rotation_xyzw;
            let [ax, ay, az] = s.linear_mps2;
            out += &format!("{k},{i},{qx},{qy},{qz},{qw},{ax},{ay},{az}\n");
        }
    }
    out
}

/// Count, mean and nearest-rank percentiles of a set of values.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Stats {
    pub count: usize,
    pub mean: f64,
    pub p50: f64,
    pub p95: f64,
    pub p99: f64,
    pub max: f64,
}

/// The nearest-rank percentile `p` (0..1] of sorted values: the smallest value with at least
/// p·n values at or below it.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (p * sorted.len() as f64).ceil().max(1.0) as usize;
    sorted[rank.min(sorted.len()) - 1]
}

/// The statistics of `values`; `None` when there are none.
pub fn stats(values: &[f64]) -> Option<Stats> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    Some(Stats {
        count: v.len(),
        mean: v.iter().sum::<f64>() / v.len() as f64,
        p50: percentile(&v, 0.50),
        p95: percentile(&v, 0.95),
        p99: percentile(&v, 0.99),
        max: v[v.len() - 1],
    })
}

/// One tick of one tracker as the emulator logged it (ns since the Unix epoch).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sent {
    pub tick: usize,
    pub tracker: usize,
    pub due_ns: u64,
    pub send_ns: u64,
}

/// One sample as the source published it (`source.raw`): its rotation as it arrived, the time
/// the source dated it to (`sample_time_ns`) and its frame's capture time (the earliest arrival
/// among the frame's samples).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrival {
    pub tracker: usize,
    pub rotation_xyzw: [f32; 4],
    pub dated_ns: u64,
    pub capture_ns: u64,
}

/// A tick sent more than this after it was due was held back by a stall (the emulator's pacing
/// is late by 1.4 ms at its p99), ns.
const HELD_BACK_NS: u64 = 2_000_000;

/// Received samples paired with the ticks that sent them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Pairing {
    /// Per paired sample: its frame's capture − send, ms.
    pub send_to_capture_ms: Vec<f64>,
    /// Per paired sample: the source's date for it − when the tracker took it (its send; a tick
    /// a stall held back: its due time, when the motion it carries happened), ms.
    pub dating_error_ms: Vec<f64>,
    /// Per paired sample: its frame's capture − the tick's nominal time (includes a stall), ms.
    pub due_to_capture_ms: Vec<f64>,
    /// Received samples whose rotation no sent tick of their tracker has.
    pub unmatched: usize,
}

/// Pairs each received sample with the tick of its tracker that sent its exact rotation (bit for
/// bit: the firmware protocol carries f32); where several ticks sent the same rotation (a tracker
/// held still), the one sent nearest before the frame's capture (else the first).
pub fn pair_arrivals(
    ticks: &[[FirmwareSample; NUM_IMUS]],
    sent: &[Sent],
    arrivals: &[Arrival],
) -> Pairing {
    let key = |tracker: usize, q: [f32; 4]| (tracker, q.map(f32::to_bits));
    let mut by_rotation: HashMap<(usize, [u32; 4]), Vec<Sent>> = HashMap::new();
    for s in sent {
        if let Some(sample) = ticks.get(s.tick).and_then(|t| t.get(s.tracker)) {
            by_rotation
                .entry(key(s.tracker, sample.rotation_xyzw))
                .or_default()
                .push(*s);
        }
    }
    let mut out = Pairing::default();
    for a in arrivals {
        let Some(candidates) = by_rotation.get(&key(a.tracker, a.rotation_xyzw)) else {
            out.unmatched += 1;
            continue;
        };
        let before = candidates
            .iter()
            .filter(|s| s.send_ns <= a.capture_ns)
            .max_by_key(|s| s.send_ns);
        let s = before.or_else(|| candidates.iter().min_by_key(|s| s.send_ns));
        if let Some(s) = s {
            let ms = |to: u64, from: u64| (to as f64 - from as f64) / 1e6;
            out.send_to_capture_ms.push(ms(a.capture_ns, s.send_ns));
            // A stall holds a tick back (the emulator's stand-in for a radio that delivers late):
            // its sample was taken when it was due, which is what the source dates back to.
            let taken_ns = if s.send_ns > s.due_ns + HELD_BACK_NS {
                s.due_ns
            } else {
                s.send_ns
            };
            out.dating_error_ms.push(ms(a.dated_ns, taken_ns));
            out.due_to_capture_ms.push(ms(a.capture_ns, s.due_ns));
        }
    }
    out
}

/// A unit quaternion [w, x, y, z] in f64.
type Quat = [f64; 4];

fn quat_mul(a: Quat, b: Quat) -> Quat {
    let [aw, ax, ay, az] = a;
    let [bw, bx, by, bz] = b;
    [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]
}

/// The rotation vector (axis · angle, rad) of `conj(a) · b`: b seen from a.
fn rotation_between(a: Quat, b: Quat) -> [f64; 3] {
    let [w, x, y, z] = quat_mul([a[0], -a[1], -a[2], -a[3]], b);
    let (w, v) = if w < 0.0 {
        (-w, [-x, -y, -z])
    } else {
        (w, [x, y, z])
    };
    let s = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if s < 1e-12 {
        return v.map(|c| 2.0 * c);
    }
    let angle = 2.0 * s.atan2(w);
    v.map(|c| c / s * angle)
}

/// What one frame of the fusion stage's output showed, on the trackers' own timeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shown {
    /// The frame's capture time (it travels unchanged to the vmc stage's bundle).
    pub capture_ns: u64,
    /// When the trackers sent the motion the frame shows (ns since the epoch, fractional).
    pub send_ns: f64,
    /// When that motion was due (the emulator's schedule, before any stall).
    pub due_ns: f64,
}

/// The fusion stage's frames (capture time, per sensor `R_IS` [w, x, y, z] and valid mask)
/// placed on the trackers' timeline by their content: per sensor, the tick segment whose arc
/// between two sent rotations the frame's orientation lies on (within 0.5°), and where on it; the
/// send (and due) time interpolated there; per frame the median over the sensors that turned
/// enough between the two ticks (0.05°) for the position to mean something, at least three. This
/// needs no clock of the graph's: it is what the avatar shows against when the trackers sent it.
pub fn shown_moments(
    ticks: &[[FirmwareSample; NUM_IMUS]],
    sent: &[Sent],
    frames: &[(u64, [[f32; 4]; MAX_SITES], u32)],
) -> Vec<Shown> {
    const MAX_OFF_ARC_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;
    const MIN_STEP_RAD: f64 = 0.05 * std::f64::consts::PI / 180.0;
    let n = ticks.len();
    let mut times = vec![[(0u64, 0u64); NUM_IMUS]; n];
    let mut have = vec![[false; NUM_IMUS]; n];
    for s in sent {
        if s.tick < n && s.tracker < NUM_IMUS {
            times[s.tick][s.tracker] = (s.send_ns, s.due_ns);
            have[s.tick][s.tracker] = true;
        }
    }
    let quat = |k: usize, i: usize| -> Quat {
        let [x, y, z, w] = ticks[k][i].rotation_xyzw.map(f64::from);
        [w, x, y, z]
    };
    let mut cursor = [0usize; NUM_IMUS];
    let mut out = Vec::new();
    for (capture_ns, orientations, valid) in frames {
        let mut sends = Vec::new();
        let mut dues = Vec::new();
        for i in 0..NUM_IMUS {
            if valid & (1 << i) == 0 || n < 2 {
                continue;
            }
            let p = orientations[i].map(f64::from);
            let mut best: Option<(f64, usize, f64)> = None;
            let search = |range: std::ops::Range<usize>, best: &mut Option<(f64, usize, f64)>| {
                for j in range {
                    let (a, b) = (quat(j, i), quat(j + 1, i));
                    let step = rotation_between(a, b);
                    let len2: f64 = step.iter().map(|v| v * v).sum();
                    if len2 < MIN_STEP_RAD * MIN_STEP_RAD {
                        continue;
                    }
                    let to_p = rotation_between(a, p);
                    let tau = (to_p.iter().zip(&step).map(|(u, v)| u * v).sum::<f64>() / len2)
                        .clamp(0.0, 1.0);
                    let off: f64 = to_p
                        .iter()
                        .zip(&step)
                        .map(|(u, v)| (u - tau * v).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    if best.is_none_or(|(d, _, _)| off < d) {
                        *best = Some((off, j, tau));
                    }
                }
            };
            // Frames advance with the ticks: look near the last match first.
            let from = cursor[i].saturating_sub(20);
            search(from..(cursor[i] + 60).min(n - 1), &mut best);
            if best.is_none_or(|(d, _, _)| d > MAX_OFF_ARC_RAD) {
                search(0..n - 1, &mut best);
            }
            let Some((off, j, tau)) = best else { continue };
            if off > MAX_OFF_ARC_RAD || !have[j][i] || !have[j + 1][i] {
                continue;
            }
            cursor[i] = j;
            let lerp = |a: u64, b: u64| a as f64 + tau * (b as f64 - a as f64);
            sends.push(lerp(times[j][i].0, times[j + 1][i].0));
            dues.push(lerp(times[j][i].1, times[j + 1][i].1));
        }
        if sends.len() >= 3 {
            let median = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                let m = v.len() / 2;
                if v.len() % 2 == 1 {
                    v[m]
                } else {
                    0.5 * (v[m - 1] + v[m])
                }
            };
            out.push(Shown {
                capture_ns: *capture_ns,
                send_ns: median(&mut sends),
                due_ns: median(&mut dues),
            });
        }
    }
    out
}

/// The number written just before `label` in `text` ("1800 samples, 0 lost" → `samples`: 1800).
pub fn number_before(text: &str, label: &str) -> Option<u64> {
    let at = text.find(label)?;
    let head = text[..at].trim_end();
    let digits: String = head
        .chars()
        .rev()
        .take_while(char::is_ascii_digit)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    digits.parse().ok()
}

/// One bundle as the receiver logged it.
#[derive(Debug, Clone, PartialEq)]
pub struct Bundle {
    pub read_ns: u64,
    pub capture_ns: Option<u64>,
    pub bones: u32,
    pub root: u32,
    pub ok: bool,
}

/// The bundles after the calibration's catch-up. A calibration that completes may release the
/// frames it held while it calibrated, and the graph then processes them faster than real time:
/// the receiver gets a short backlog captured before the first bundle arrived, whose latency is
/// the calibration's catch-up, not the live path's. The catch-up is the bundles captured before
/// the first one arrived when there are at least two of them (the first bundle alone is always
/// captured before it arrives); everything from the first bundle captured after that is settled.
pub fn settled(bundles: &[Bundle]) -> impl Iterator<Item = &Bundle> {
    let first = bundles.first().map_or(0, |b| b.read_ns);
    let early = |b: &Bundle| b.capture_ns.is_some_and(|c| c < first);
    let backlog = bundles.iter().take_while(|b| early(b)).count();
    let skip = if backlog >= 2 { backlog } else { 0 };
    bundles[skip.min(bundles.len())..]
        .iter()
        .filter(|b| b.capture_ns.is_some())
}

/// The receiver's CSV (`read_ns,handled_ns,capture_ns,bones,root,ok,time_s,messages`).
pub fn parse_bundles(text: &str) -> anyhow::Result<Vec<Bundle>> {
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default();
    let names: Vec<&str> = header.split(',').collect();
    let col = |name: &str| {
        names
            .iter()
            .position(|n| *n == name)
            .ok_or_else(|| anyhow!("the receiver's CSV has no column '{name}'"))
    };
    let (read, capture, bones, root, ok) = (
        col("read_ns")?,
        col("capture_ns")?,
        col("bones")?,
        col("root")?,
        col("ok")?,
    );
    let mut out = Vec::new();
    for (n, line) in lines.enumerate().filter(|(_, l)| !l.is_empty()) {
        let v: Vec<&str> = line.split(',').collect();
        let field = |i: usize| v.get(i).copied().unwrap_or("");
        let int = |i: usize| -> anyhow::Result<u64> {
            field(i)
                .parse()
                .with_context(|| format!("the receiver's CSV, row {}: '{line}'", n + 2))
        };
        out.push(Bundle {
            read_ns: int(read)?,
            capture_ns: if field(capture).is_empty() {
                None
            } else {
                Some(int(capture)?)
            },
            bones: int(bones)? as u32,
            root: int(root)? as u32,
            ok: int(ok)? == 1,
        });
    }
    Ok(out)
}

/// The emulator's send log (`tick,tracker,due_ns,send_ns`).
pub fn parse_sends(text: &str) -> anyhow::Result<Vec<Sent>> {
    let mut out = Vec::new();
    for (n, line) in text
        .lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| !l.is_empty())
    {
        let v: Vec<u64> = line
            .split(',')
            .map(str::parse)
            .collect::<Result<_, _>>()
            .with_context(|| format!("the emulator's log, row {}: '{line}'", n + 1))?;
        let [tick, tracker, due_ns, send_ns] = v[..] else {
            bail!(
                "the emulator's log, row {}: '{line}' is not 4 numbers",
                n + 1
            );
        };
        out.push(Sent {
            tick: tick as usize,
            tracker: tracker as usize,
            due_ns,
            send_ns,
        });
    }
    Ok(out)
}

/// The trackers' MACs in site (IMU) order, from a trackers file: sensor 0 of each site.
pub fn macs_by_site(text: &str, file: &str) -> anyhow::Result<[String; NUM_IMUS]> {
    let table: toml::Table = text
        .parse()
        .with_context(|| format!("cannot parse the trackers file '{file}'"))?;
    let sites = imuflow_body::skeleton::Imu::SIX.map(imuflow_body::skeleton::Imu::name);
    let mut macs: [Option<String>; NUM_IMUS] = Default::default();
    let entries = table
        .get("tracker")
        .and_then(toml::Value::as_array)
        .map(Vec::as_slice)
        .unwrap_or_default();
    for entry in entries {
        let text = |k: &str| entry.get(k).and_then(toml::Value::as_str);
        let sensor = entry
            .get("sensor")
            .and_then(toml::Value::as_integer)
            .unwrap_or(0);
        if let (Some(mac), Some(site), 0) = (text("mac"), text("site"), sensor)
            && let Some(i) = sites.iter().position(|s| *s == site)
        {
            macs[i] = Some(mac.to_owned());
        }
    }
    let missing: Vec<&str> = (0..NUM_IMUS)
        .filter(|&i| macs[i].is_none())
        .map(|i| sites[i])
        .collect();
    if !missing.is_empty() {
        bail!(
            "the trackers file '{file}' maps no tracker's sensor 0 to {} (the emulator plays one tracker with one sensor per site)",
            missing.join(", ")
        );
    }
    Ok(macs.map(Option::unwrap_or_default))
}

// ---------------------------------------------------------------------------------------------
// Processes

/// A child process that is stopped (SIGTERM, then SIGKILL) and reaped on every way out.
struct Proc {
    name: &'static str,
    child: Option<Child>,
    status: Option<ExitStatus>,
    stderr: PathBuf,
}

impl Proc {
    fn spawn(
        name: &'static str,
        mut command: Command,
        stderr: PathBuf,
    ) -> anyhow::Result<(Proc, mpsc::Receiver<String>)> {
        let err = std::fs::File::create(&stderr)
            .with_context(|| format!("cannot create '{}'", stderr.display()))?;
        let mut child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(err)
            .spawn()
            .with_context(|| format!("cannot start the {name} ({command:?})"))?;
        let lines = read_lines(child.stdout.take().expect("piped"));
        Ok((
            Proc {
                name,
                child: Some(child),
                status: None,
                stderr,
            },
            lines,
        ))
    }

    /// The exit status once it has exited.
    fn exited(&mut self) -> Option<ExitStatus> {
        if self.status.is_none()
            && let Some(child) = self.child.as_mut()
            && let Ok(Some(status)) = child.try_wait()
        {
            self.status = Some(status);
        }
        self.status
    }

    /// Waits up to `timeout` for it to exit.
    fn wait(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let until = Instant::now() + timeout;
        while Instant::now() < until {
            if let Some(s) = self.exited() {
                return Some(s);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.exited()
    }

    /// SIGTERM, `grace` to exit, then SIGKILL; reaped either way.
    fn stop(&mut self, grace: Duration) -> Option<ExitStatus> {
        if let Some(s) = self.exited() {
            return Some(s);
        }
        let pid = self.child.as_ref().map(Child::id)?;
        if let Ok(pid) = i32::try_from(pid) {
            // SAFETY: kill(2) on our own child's pid; it has not been reaped (try_wait saw it run).
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(pid, libc::SIGTERM);
            }
        }
        if let Some(s) = self.wait(grace) {
            return Some(s);
        }
        let child = self.child.as_mut()?;
        let _ = child.kill();
        self.status = child.wait().ok();
        self.status
    }

    /// The last lines it wrote on stderr.
    fn stderr_tail(&self) -> String {
        let text = std::fs::read_to_string(&self.stderr).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        let tail = &lines[lines.len().saturating_sub(12)..];
        if tail.is_empty() {
            format!("(the {} wrote nothing on stderr)", self.name)
        } else {
            tail.iter()
                .map(|l| format!("    | {l}"))
                .collect::<Vec<_>>()
                .join("\n")
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(3));
    }
}

/// Lines of a child's stdout, read on a thread.
fn read_lines(stdout: ChildStdout) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// The launcher on its own thread: `launch::run` as `imuflow run` does it.
struct GraphRun {
    handle: Option<std::thread::JoinHandle<anyhow::Result<RunReport>>>,
}

impl GraphRun {
    fn start(graph: Graph) -> anyhow::Result<GraphRun> {
        let options = LaunchOptions {
            imuflow_exe: std::env::current_exe().context("cannot find the imuflow executable")?,
            progress: false,
            forward_logs: false,
        };
        let handle = std::thread::Builder::new()
            .name("launcher".into())
            .spawn(move || launch::run(&graph, &options).map_err(|e| anyhow!("{e}")))
            .context("cannot start the launcher thread")?;
        Ok(GraphRun {
            handle: Some(handle),
        })
    }

    fn finished(&self) -> bool {
        self.handle.as_ref().is_none_or(|h| h.is_finished())
    }

    /// Waits up to `timeout` for the run to end; then asks the launcher to stop (SIGTERM to this
    /// process, which it turns into a clean stop of every stage) and waits as long again.
    fn join(
        &mut self,
        timeout: Duration,
        stop_requested: &AtomicBool,
    ) -> anyhow::Result<RunReport> {
        let until = Instant::now() + timeout;
        while !self.finished() && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(20));
        }
        if !self.finished() {
            self.request_stop(stop_requested);
            let until = Instant::now() + timeout;
            while !self.finished() && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        let Some(handle) = self.handle.take().filter(|h| h.is_finished()) else {
            bail!(
                "the graph did not stop within {:?} of being asked to",
                timeout
            );
        };
        handle
            .join()
            .map_err(|_| anyhow!("the launcher thread panicked"))?
    }

    fn request_stop(&self, stop_requested: &AtomicBool) {
        if self.finished() {
            return;
        }
        stop_requested.store(true, Ordering::SeqCst);
        // SAFETY: raise(3) on this process; our own handlers (and the launcher's) are installed
        // for SIGTERM, so it does not end the process.
        #[allow(unsafe_code)]
        unsafe {
            libc::raise(libc::SIGTERM);
        }
    }
}

impl Drop for GraphRun {
    fn drop(&mut self) {
        if self.handle.is_some() {
            let requested = AtomicBool::new(false);
            let _ = self.join(Duration::from_secs(10), &requested);
        }
    }
}

/// SIGINT / SIGTERM as flags while the benchmark runs (so that the children are stopped on the
/// way out), unregistered at the end.
struct Signals {
    interrupted: Arc<AtomicBool>,
    /// Set before the benchmark raises SIGTERM itself to stop the launcher.
    requested: AtomicBool,
    ids: Vec<signal_hook::SigId>,
}

impl Signals {
    fn install() -> Signals {
        let interrupted = Arc::new(AtomicBool::new(false));
        let ids = [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM]
            .into_iter()
            .filter_map(|sig| signal_hook::flag::register(sig, interrupted.clone()).ok())
            .collect();
        Signals {
            interrupted,
            requested: AtomicBool::new(false),
            ids,
        }
    }

    /// Whether a SIGINT / SIGTERM came from outside (a user's Ctrl-C).
    fn by_user(&self) -> bool {
        self.interrupted.load(Ordering::SeqCst) && !self.requested.load(Ordering::SeqCst)
    }
}

impl Drop for Signals {
    fn drop(&mut self) {
        for id in self.ids.drain(..) {
            signal_hook::low_level::unregister(id);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The benchmark

/// The launcher's end-to-end latency of the vmc stage's input, every frame, ms.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GraphLatency {
    pub frames: u64,
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

/// What one scenario measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LiveResult {
    pub scenario: &'static str,
    pub build: &'static str,
    pub source: String,
    pub seconds: f64,
    pub rate_hz: f64,
    /// Receive time − capture time per bundle, ms, for the bundles captured after the first one
    /// arrived ([`settled`]: not the backlog a calibration releases when it completes).
    pub latency_ms: Option<Stats>,
    /// The same over every bundle.
    pub latency_all_ms: Option<Stats>,
    /// Bundles captured before the first one arrived: the calibration's catch-up.
    pub catch_up_bundles: usize,
    /// Receive time − when the trackers sent the motion the bundle shows (placed by content,
    /// [`shown_moments`]), ms.
    pub latency_from_send_ms: Option<Stats>,
    /// Receive time − when that motion was due (before a stall), ms.
    pub latency_from_due_ms: Option<Stats>,
    /// Capture → the vmc stage's input (the launcher's end-to-end latency), ms.
    pub graph_latency_ms: Option<GraphLatency>,
    pub bundles_sent: u64,
    pub bundles_received: u64,
    pub bundles_lost: i64,
    pub bundles_duplicated: u64,
    pub bundles_malformed: u64,
    pub decode_failures: u64,
    pub frames_not_sent_calibrating: Option<u64>,
    pub samples_sent: Option<u64>,
    pub samples_received: Option<u64>,
    pub samples_lost: Option<u64>,
    pub samples_unaccounted: Option<i64>,
    /// Per sample: the source's capture of its frame − its send, ms.
    pub send_to_capture_ms: Option<Stats>,
    /// Per sample: the source's date for it − its send, ms.
    pub source_dating_error_ms: Option<Stats>,
    pub samples_paired: usize,
    pub samples_unpaired: usize,
    pub emulator_pacing_late_p99_us: Option<f64>,
    pub drops: BTreeMap<String, u64>,
    pub details: BTreeMap<String, String>,
    pub problems: Vec<String>,
}

/// The python with vmcp: `--python`, else the verify venv's.
fn default_python() -> PathBuf {
    let venv = std::env::var_os("IMUFLOW_VERIFY_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(std::env::var_os("HOME").unwrap_or_default())
                .join(".cache/imuflow/verify-venv")
        });
    venv.join("bin/python")
}

fn check_python(python: &Path) -> anyhow::Result<()> {
    let install = format!(
        "install the receiver's client there: {} -m pip install \"{}[osc4py3]=={}\" (or pass --python)",
        python.display(),
        RECEIVER.0,
        RECEIVER.1
    );
    let out = Command::new(python)
        .args([
            "-c",
            "import importlib.metadata as m, osc4py3, vmcp; print(m.version('vmcp'))",
        ])
        .output()
        .with_context(|| format!("cannot run the python '{}'; {install}", python.display()))?;
    let version = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    if !out.status.success() {
        bail!(
            "'{}' cannot import vmcp and osc4py3: {}; {install}",
            python.display(),
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    if version != RECEIVER.1 {
        bail!(
            "'{}' has vmcp {version}, the benchmark pins {}; {install}",
            python.display(),
            RECEIVER.1
        );
    }
    Ok(())
}

fn check_node(node: &Path, dir: &Path) -> anyhow::Result<()> {
    let out = Command::new(node)
        .arg("--version")
        .output()
        .with_context(|| {
            format!(
                "cannot run node ('{}'): install Node.js 18 or newer, or pass --node",
                node.display()
            )
        })?;
    if !out.status.success() {
        bail!("'{} --version' failed", node.display());
    }
    let manifest = dir
        .join("node_modules")
        .join(EMULATOR.0)
        .join("package.json");
    let installed = std::fs::read_to_string(&manifest)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v.get("version").and_then(|v| v.as_str().map(str::to_owned)));
    match installed {
        Some(v) if v == EMULATOR.1 => Ok(()),
        Some(v) => bail!(
            "{} {v} is installed in {}/node_modules, the benchmark pins {}: run `npm ci --prefix {LIVE_BENCH_DIR}`",
            EMULATOR.0,
            dir.display(),
            EMULATOR.1
        ),
        None => bail!(
            "SlimeVR's tracker emulator is not installed: run `npm ci --prefix {LIVE_BENCH_DIR}` (node_modules with {}@{})",
            EMULATOR.0,
            EMULATOR.1
        ),
    }
}

/// The sample's IMU frames (`source.imu`).
fn load_sample(path: &Path) -> anyhow::Result<Vec<ImuSample>> {
    let recording = imuflow_recording::Recording::load(path, Some("source.imu"), None)?;
    let mut first = None;
    Ok(recording
        .frames
        .iter()
        .filter_map(|f| match f {
            imuflow_recording::Recorded::Imu(f) => Some(f),
            imuflow_recording::Recorded::Truth(_) => None,
        })
        .map(|f| {
            let t0 = *first.get_or_insert(f.header.capture_ns);
            ImuSample {
                time_s: f.header.capture_ns.saturating_sub(t0) as f64 * 1e-9,
                orientation_wxyz: f.orientation_wxyz,
                specific_force_mps2: f.specific_force_mps2,
            }
        })
        .collect())
}

/// What the recorder stored of the source and the fusion stage: per sample the source published
/// (`source.raw`, per site with an orientation) its rotation (x, y, z, w), its date and its
/// frame's capture time; per fusion output frame (`fusion.imu`) its capture time, orientations and
/// valid mask.
type FusionFrame = (u64, [[f32; 4]; MAX_SITES], u32);

fn read_recording(path: &Path) -> anyhow::Result<(Vec<Arrival>, Vec<FusionFrame>)> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read '{}'", path.display()))?;
    let channels = imuflow_recording::channels(&bytes)?;
    let find = |topic: &str| channels.values().find(|c| c.topic == topic).map(|c| c.id);
    let (Some(raw), Some(imu)) = (find("source.raw"), find("fusion.imu")) else {
        bail!(
            "'{}' lacks the source.raw or the fusion.imu channel",
            path.display()
        );
    };
    let mut arrivals = Vec::new();
    let mut fused = Vec::new();
    let (mut n_raw, mut n_imu) = (0, 0);
    imuflow_recording::for_each_record(&bytes, |_, record| {
        let mcap::records::Record::Message { header, data } = record else {
            return Ok(());
        };
        if header.channel_id == raw {
            let f: RawImuFrame = imuflow_recording::decode(&data, "source.raw", n_raw)?;
            n_raw += 1;
            if f.header.is_end() {
                return Ok(());
            }
            for i in 0..NUM_IMUS {
                if f.orientation_mask & (1 << i) != 0 {
                    let [w, x, y, z] = f.orientation_wxyz[i];
                    arrivals.push(Arrival {
                        tracker: i,
                        rotation_xyzw: [x, y, z, w],
                        dated_ns: f.sample_time_ns[i],
                        capture_ns: f.header.capture_ns,
                    });
                }
            }
        } else if header.channel_id == imu {
            let f: ImuFrame = imuflow_recording::decode(&data, "fusion.imu", n_imu)?;
            n_imu += 1;
            if !f.header.is_end() {
                fused.push((f.header.capture_ns, f.orientation_wxyz, f.valid_mask));
            }
        }
        Ok(())
    })?;
    Ok((arrivals, fused))
}

/// The raw scenario's graph: the source of configs/examples/raw-imu.toml (raw sensors with a
/// consumer MEMS's errors, their own clocks, delivery jitter), paced in real time, into the chain
/// of the onboard graph.
fn raw_graph(rate_hz: f64, vmc_port: u16) -> String {
    format!(
        r#"name = "live-bench-raw"
rate_hz = 60
mode = "live"

[stages.source]
kind = "imu-source"
params = {{ mode = "synthesize", path = "models/sample/walk.mcap", prelude = "stand", prelude_stand_s = 1.0, mounting = "random", frame = "z-up", frame_heading_deg = 30.0, seed = 3, raw = true, raw_rate_hz = {rate_hz:.1}, raw_noise = 1.0, raw_magnetometer = "disturbed", raw_clock_offset_ms = 500.0, raw_clock_drift_ppm = 100.0, raw_jitter_ms = 5.0, realtime = true }}

[stages.fusion]
kind = "fusion"
inputs = {{ raw = "source.raw" }}

[stages.calib]
kind = "calibration"
inputs = {{ imu = "fusion.imu" }}
params = {{ method = "walking", frame = "z-up" }}

[stages.kin]
kind = "kinematics"
inputs = {{ imu = "calib.body_imu" }}
params = {{ net = "pip", weights = "models/pip.safetensors" }}

[stages.opt]
kind = "optimizer"
inputs = {{ kin = "kin.kinematics" }}
params = {{ method = "pip" }}

[stages.vmc]
kind = "vmc"
inputs = {{ motion = "opt.motion" }}
params = {{ host = "127.0.0.1", port = {vmc_port}, capture_time = true }}
"#
    )
}

/// A UDP port free on 127.0.0.1 a moment ago.
fn free_udp_port() -> anyhow::Result<u16> {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").context("cannot find a free UDP port")?;
    Ok(socket.local_addr()?.port())
}

/// Where the run's files go: `--keep DIR/SCENARIO`, else a temporary folder.
enum WorkDir {
    Kept(PathBuf),
    Temp(tempfile::TempDir),
}

impl WorkDir {
    fn path(&self) -> &Path {
        match self {
            WorkDir::Kept(p) => p,
            WorkDir::Temp(t) => t.path(),
        }
    }
}

/// `imuflow bench live`.
pub fn run(args: LiveArgs, registry: &Registry) -> anyhow::Result<()> {
    let signals = Signals::install();
    let result = run_scenario(&args, registry, &signals);
    let result = match result {
        Ok(r) => r,
        Err(e) if signals.by_user() && e.to_string() != "interrupted" => {
            return Err(e.context("interrupted"));
        }
        Err(e) => return Err(e),
    };
    print_result(&result);
    if let Some(path) = &args.json {
        let json = serde_json::to_string_pretty(&result)?;
        std::fs::write(path, json + "\n")
            .with_context(|| format!("cannot write '{}'", path.display()))?;
    }
    if !result.problems.is_empty() {
        bail!(
            "live benchmark '{}': {}",
            result.scenario,
            result.problems.join("; ")
        );
    }
    Ok(())
}

fn run_scenario(
    args: &LiveArgs,
    registry: &Registry,
    signals: &Signals,
) -> anyhow::Result<LiveResult> {
    let scenario = args.scenario;
    let rate_hz = args.rate_hz.unwrap_or(match scenario {
        Scenario::Raw => 200.0,
        _ => 100.0,
    });
    if !(rate_hz > 0.0 && rate_hz <= 2000.0) {
        bail!("--rate-hz must be in (0, 2000]");
    }
    let dir = Path::new(LIVE_BENCH_DIR);
    if !dir.join("receive_vmc.py").is_file() {
        bail!(
            "{LIVE_BENCH_DIR}/receive_vmc.py not found: run the benchmark from the repository root"
        );
    }
    let python = args.python.clone().unwrap_or_else(default_python);
    check_python(&python)?;
    let trackers = scenario != Scenario::Raw;
    if trackers {
        check_node(&args.node, dir)?;
    }
    let work = match &args.keep {
        Some(keep) => {
            let p = keep.join(scenario.name());
            std::fs::create_dir_all(&p)
                .with_context(|| format!("cannot create '{}'", p.display()))?;
            WorkDir::Kept(p)
        }
        None => WorkDir::Temp(tempfile::tempdir().context("cannot create a temporary folder")?),
    };
    let w = work.path();

    // The trackers' data.
    let mut ticks = Vec::new();
    let mut macs = None;
    if trackers {
        let file = args.trackers_file.display().to_string();
        let text = std::fs::read_to_string(&args.trackers_file)
            .with_context(|| format!("cannot read the trackers file '{file}'"))?;
        macs = Some(macs_by_site(&text, &file)?);
        let frames = load_sample(&args.sample)
            .with_context(|| format!("the sample '{}'", args.sample.display()))?;
        ticks = tracker_ticks(&frames, rate_hz, args.seconds)?;
        std::fs::write(w.join("samples.csv"), samples_csv(&ticks))?;
    }

    // The receiver first, so that no bundle goes out before it listens.
    let mut command = Command::new(&python);
    command
        .arg(dir.join("receive_vmc.py"))
        .args(["--port", "0", "--csv"])
        .arg(w.join("bundles.csv"))
        .arg("--summary")
        .arg(w.join("receiver.json"));
    let (mut receiver, receiver_lines) =
        Proc::spawn("VMC receiver", command, w.join("receiver.err"))?;
    let vmc_port = wait_for_line(&receiver_lines, "listening ", Duration::from_secs(30))
        .and_then(|line| line.rsplit(':').next().and_then(|p| p.parse::<u16>().ok()))
        .ok_or_else(|| {
            anyhow!(
                "the VMC receiver did not start listening:\n{}",
                receiver.stderr_tail()
            )
        })?;

    // The graph.
    let (graph, graph_text) = match scenario {
        Scenario::Raw => {
            let text = raw_graph(rate_hz, vmc_port);
            let graph = Graph::from_str_with(Path::new("<bench live raw>"), &text, &[], registry)
                .map_err(|e| anyhow!("{e}"))?;
            (graph, text)
        }
        Scenario::Onboard | Scenario::Burst => {
            let source_port = free_udp_port()?;
            let sets = vec![
                format!("stages.source.params.bind=127.0.0.1:{source_port}"),
                format!(
                    "stages.source.params.trackers={}",
                    args.trackers_file.display()
                ),
                format!("stages.source.params.timeout_ms={SOURCE_SILENCE_MS}"),
                format!("stages.vmc.params.port={vmc_port}"),
                "stages.vmc.params.host=127.0.0.1".to_owned(),
                "stages.vmc.params.capture_time=true".to_owned(),
                format!(
                    "stages.record.params.path={}",
                    w.join("record.mcap").display()
                ),
            ];
            let graph = load_without(Path::new(TRACKERS_GRAPH), &sets, &[], registry)
                .map_err(|e| anyhow!("{e}"))?;
            let text = format!(
                "{TRACKERS_GRAPH} with\n{}\n",
                sets.iter()
                    .map(|s| format!("  --set {s}"))
                    .collect::<Vec<_>>()
                    .join("\n")
            );
            (graph, text)
        }
    };
    std::fs::write(w.join("graph.txt"), &graph_text)?;
    let source_addr = graph
        .topological_order()
        .into_iter()
        .find(|n| n.id == "source")
        .and_then(|n| {
            n.params
                .get("bind")
                .and_then(|v| v.as_str().map(str::to_owned))
        });
    let stop_requested = &signals.requested;
    eprintln!(
        "bench live {}: starting the graph{}",
        scenario.name(),
        if trackers {
            ", then SlimeVR's tracker emulator"
        } else {
            ""
        }
    );
    let mut graph_run = GraphRun::start(graph)?;

    // The emulator.
    let mut emulator_summary = None;
    if trackers {
        let addr = source_addr.unwrap_or_default();
        let (host, port) = addr
            .rsplit_once(':')
            .ok_or_else(|| anyhow!("the source's bind '{addr}' is no host:port"))?;
        let mut command = Command::new(&args.node);
        command
            .arg(dir.join("emulate.mjs"))
            .args(["--server", host, "--port", port])
            .arg("--data")
            .arg(w.join("samples.csv"))
            .arg("--log")
            .arg(w.join("sends.csv"))
            .args(["--rate", &rate_hz.to_string()])
            .args(["--macs", &macs.clone().unwrap_or_default().join(",")])
            .args(["--connect-timeout", "60"]);
        if scenario == Scenario::Burst {
            command
                .args(["--burst-every", &args.burst_every_s.to_string()])
                .args(["--burst-stall", &args.burst_stall_ms.to_string()]);
        }
        let (mut emulator, lines) =
            Proc::spawn("tracker emulator", command, w.join("emulator.err"))?;
        let limit = Duration::from_secs_f64(90.0 + args.seconds * 2.0);
        let started = Instant::now();
        let status = loop {
            for line in lines.try_iter() {
                if let Some(json) = line.strip_prefix("summary ") {
                    emulator_summary = serde_json::from_str::<serde_json::Value>(json).ok();
                } else {
                    eprintln!("bench live {}: emulator: {line}", scenario.name());
                }
            }
            if let Some(status) = emulator.exited() {
                break status;
            }
            if signals.by_user() {
                emulator.stop(Duration::from_secs(3));
                bail!("interrupted");
            }
            if graph_run.finished() {
                emulator.stop(Duration::from_secs(3));
                let report = graph_run.join(Duration::from_secs(5), stop_requested);
                bail!(
                    "the graph ended before the emulator did ({})\nemulator:\n{}",
                    match report {
                        Ok(r) => format!("its report:\n{r}"),
                        Err(e) => format!("{e:#}"),
                    },
                    emulator.stderr_tail()
                );
            }
            if started.elapsed() > limit {
                emulator.stop(Duration::from_secs(3));
                bail!("the emulator did not finish within {limit:?}");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        // The last lines (the summary) may still be in the pipe.
        std::thread::sleep(Duration::from_millis(100));
        for line in lines.try_iter() {
            if let Some(json) = line.strip_prefix("summary ") {
                emulator_summary = serde_json::from_str::<serde_json::Value>(json).ok();
            }
        }
        if !status.success() {
            graph_run.request_stop(stop_requested);
            let _ = graph_run.join(Duration::from_secs(15), stop_requested);
            bail!(
                "the tracker emulator failed ({status}):\n{}",
                emulator.stderr_tail()
            );
        }
    }

    // The graph ends on its own: the source after its silence timeout, or at the sample's end.
    let limit = Duration::from_secs_f64(if trackers { 30.0 } else { 60.0 + args.seconds });
    let until = Instant::now() + limit;
    let report = loop {
        if graph_run.finished() {
            break graph_run.join(Duration::ZERO, stop_requested)?;
        }
        if signals.by_user() {
            let _ = graph_run.join(Duration::from_secs(15), stop_requested);
            bail!("interrupted");
        }
        if Instant::now() > until {
            eprintln!("bench live: the graph did not end within {limit:?}: stopping it");
            graph_run.request_stop(stop_requested);
            break graph_run.join(Duration::from_secs(15), stop_requested)?;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    std::fs::write(w.join("report.txt"), format!("{report}\n"))?;

    // The last bundles are in flight for a moment; then the receiver writes its files.
    std::thread::sleep(Duration::from_millis(300));
    let receiver_status = receiver.stop(Duration::from_secs(10));
    if !receiver_status.is_some_and(|s| s.success()) {
        bail!(
            "the VMC receiver failed ({}):\n{}",
            receiver_status.map_or("killed".to_owned(), |s| s.to_string()),
            receiver.stderr_tail()
        );
    }
    let bundles = parse_bundles(
        &std::fs::read_to_string(w.join("bundles.csv")).context("the receiver's CSV")?,
    )?;
    let receiver_summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(w.join("receiver.json")).context("the receiver's summary")?,
    )?;

    let mut result = evaluate(
        scenario,
        &report,
        &bundles,
        &receiver_summary,
        emulator_summary.as_ref(),
    );
    result.seconds = if trackers {
        ticks.len() as f64 / rate_hz
    } else {
        report.stages.get("source").map_or(0.0, |(_, s)| s.wall_s)
    };
    result.rate_hz = rate_hz;
    result.source = match scenario {
        Scenario::Raw => format!(
            "imu-source synthesizing 6 raw sensors at {rate_hz} Hz in real time (the sample's walk)"
        ),
        _ => format!(
            "{} {}: 6 trackers at {rate_hz} Hz for {:.1} s{}",
            EMULATOR.0,
            EMULATOR.1,
            ticks.len() as f64 / rate_hz,
            if scenario == Scenario::Burst {
                format!(
                    ", a {} ms stall every {} s",
                    args.burst_stall_ms, args.burst_every_s
                )
            } else {
                String::new()
            }
        ),
    };
    if trackers {
        let sends = parse_sends(&std::fs::read_to_string(w.join("sends.csv"))?)?;
        match read_recording(&w.join("record.mcap")) {
            Ok((arrivals, fused)) => {
                let pairing = pair_arrivals(&ticks, &sends, &arrivals);
                result.samples_paired = pairing.send_to_capture_ms.len();
                result.samples_unpaired = pairing.unmatched;
                result.send_to_capture_ms = stats(&pairing.send_to_capture_ms);
                result.source_dating_error_ms = stats(&pairing.dating_error_ms);
                // Only the frames that became bundles.
                let captures: std::collections::HashSet<u64> =
                    bundles.iter().filter_map(|b| b.capture_ns).collect();
                let fused: Vec<FusionFrame> = fused
                    .into_iter()
                    .filter(|f| captures.contains(&f.0))
                    .collect();
                let shown: HashMap<u64, Shown> = shown_moments(&ticks, &sends, &fused)
                    .into_iter()
                    .map(|s| (s.capture_ns, s))
                    .collect();
                let (mut from_send, mut from_due) = (Vec::new(), Vec::new());
                for b in settled(&bundles) {
                    if let Some(s) = b.capture_ns.and_then(|c| shown.get(&c)) {
                        from_send.push((b.read_ns as f64 - s.send_ns) / 1e6);
                        from_due.push((b.read_ns as f64 - s.due_ns) / 1e6);
                    }
                }
                result.latency_from_send_ms = stats(&from_send);
                result.latency_from_due_ms = stats(&from_due);
            }
            Err(e) => eprintln!("bench live: the source's recording could not be read: {e:#}"),
        }
    }
    if let WorkDir::Kept(p) = &work {
        let mut f = std::fs::File::create(p.join("result.json"))?;
        writeln!(f, "{}", serde_json::to_string_pretty(&result)?)?;
        eprintln!("bench live: files kept in {}", p.display());
    }
    println!("{report}");
    Ok(result)
}

/// Waits up to `timeout` for a line starting with `prefix`.
fn wait_for_line(
    lines: &mpsc::Receiver<String>,
    prefix: &str,
    timeout: Duration,
) -> Option<String> {
    let until = Instant::now() + timeout;
    loop {
        let left = until.checked_duration_since(Instant::now())?;
        match lines.recv_timeout(left) {
            Ok(line) if line.starts_with(prefix) => return Some(line),
            Ok(_) => {}
            Err(_) => return None,
        }
    }
}

/// The numbers of one run, and what is wrong with it.
pub fn evaluate(
    scenario: Scenario,
    report: &RunReport,
    bundles: &[Bundle],
    receiver: &serde_json::Value,
    emulator: Option<&serde_json::Value>,
) -> LiveResult {
    let stage = |id: &str| report.stages.get(id).map(|(_, s)| s);
    let detail = |id: &str| stage(id).map(|s| s.detail.clone()).unwrap_or_default();
    let vmc = stage("vmc");
    let bundles_sent = vmc.map_or(0, |s| s.frames_out);
    let received = bundles.len() as u64;
    let mut seen = std::collections::HashSet::new();
    let duplicated = bundles
        .iter()
        .filter_map(|b| b.capture_ns)
        .filter(|c| !seen.insert(*c))
        .count() as u64;
    let malformed = bundles
        .iter()
        .filter(|b| b.bones != BONES || b.root != 1 || !b.ok || b.capture_ns.is_none())
        .count() as u64;
    let latency = |b: &Bundle| b.capture_ns.map(|c| (b.read_ns as f64 - c as f64) / 1e6);
    let latency_all: Vec<f64> = bundles.iter().filter_map(latency).collect();
    let latency_settled: Vec<f64> = settled(bundles).filter_map(latency).collect();
    let decode_failures = receiver
        .get("decode_failures")
        .and_then(serde_json::Value::as_u64)
        .unwrap_or(0);
    let graph_latency_ms = vmc.and_then(|s| {
        s.from_capture
            .iter()
            .find(|l| l.input == "motion")
            .map(|l| GraphLatency {
                frames: l.frames,
                p50: l.p50_us / 1e3,
                p99: l.p99_us / 1e3,
                max: l.max_us / 1e3,
            })
    });
    let source_detail = detail("source");
    let (samples_received, samples_lost) = match scenario {
        Scenario::Raw => (None, None),
        _ => (
            number_before(&source_detail, " samples,"),
            number_before(&source_detail, " lost,"),
        ),
    };
    let samples_sent = emulator.and_then(|e| e.get("samples_sent")?.as_u64());
    let samples_unaccounted = match (samples_sent, samples_received, samples_lost) {
        (Some(s), Some(r), Some(l)) => Some(s as i64 - r as i64 - l as i64),
        _ => None,
    };
    let drops: BTreeMap<String, u64> = report
        .stage_order
        .iter()
        .filter_map(|id| stage(id).map(|s| (id.clone(), s.dropped)))
        .collect();
    let mut details = BTreeMap::new();
    for (id, (_, s)) in &report.stages {
        if !s.detail.is_empty() {
            details.insert(id.clone(), s.detail.clone());
        }
    }
    let mut problems = Vec::new();
    if received == 0 {
        problems.push("no bundle received".to_owned());
    }
    if decode_failures > 0 {
        problems.push(format!(
            "{decode_failures} decode failure(s) at the receiver (first: {})",
            receiver
                .get("first_decode_failure")
                .and_then(serde_json::Value::as_str)
                .unwrap_or("?")
        ));
    }
    if received != bundles_sent {
        problems.push(format!(
            "the vmc stage sent {bundles_sent} bundles, the receiver got {received}"
        ));
    }
    if duplicated > 0 {
        problems.push(format!("{duplicated} bundle(s) received twice"));
    }
    if malformed > 0 {
        problems.push(format!(
            "{malformed} bundle(s) without their {BONES} bones, root, /VMC/Ext/OK or capture time"
        ));
    }
    if report.interrupted {
        problems.push("the run was interrupted".to_owned());
    }
    LiveResult {
        scenario: scenario.name(),
        build: if cfg!(debug_assertions) {
            "debug"
        } else {
            "release"
        },
        source: String::new(),
        seconds: 0.0,
        rate_hz: 0.0,
        latency_ms: stats(&latency_settled),
        latency_all_ms: stats(&latency_all),
        catch_up_bundles: latency_all.len() - latency_settled.len(),
        graph_latency_ms,
        bundles_sent,
        bundles_received: received,
        bundles_lost: bundles_sent as i64 - received as i64,
        bundles_duplicated: duplicated,
        bundles_malformed: malformed,
        decode_failures,
        frames_not_sent_calibrating: number_before(&detail("vmc"), " flagged frames"),
        samples_sent,
        samples_received,
        samples_lost,
        samples_unaccounted,
        latency_from_send_ms: None,
        latency_from_due_ms: None,
        send_to_capture_ms: None,
        source_dating_error_ms: None,
        samples_paired: 0,
        samples_unpaired: 0,
        emulator_pacing_late_p99_us: emulator.and_then(|e| e.get("pacing_late_p99_us")?.as_f64()),
        drops,
        details,
        problems,
    }
}

fn print_result(r: &LiveResult) {
    println!(
        "\nlive latency, scenario {} ({} build): {}",
        r.scenario, r.build, r.source
    );
    println!(
        "  -> imuflow -> {} {} (VMC receiver)",
        RECEIVER.0, RECEIVER.1
    );
    println!(
        "{:<38} {:>7} {:>8} {:>8} {:>8} {:>8}",
        "ms", "n", "p50", "p95", "p99", "max"
    );
    let row = |name: &str, s: &Option<Stats>| match s {
        Some(s) => println!(
            "{name:<38} {:>7} {:>8.2} {:>8.2} {:>8.2} {:>8.2}",
            s.count, s.p50, s.p95, s.p99, s.max
        ),
        None => println!("{name:<38} {:>7}", "-"),
    };
    row("bundle received - capture time", &r.latency_ms);
    if r.catch_up_bundles > 0 {
        row("  with the calibration's catch-up", &r.latency_all_ms);
    }
    if let Some(g) = r.graph_latency_ms {
        println!(
            "{:<38} {:>7} {:>8.2} {:>8} {:>8.2} {:>8.2}",
            "  capture -> vmc stage (graph, all)", g.frames, g.p50, "-", g.p99, g.max
        );
    }
    if r.scenario != "raw" {
        row(
            "bundle received - tracker send shown",
            &r.latency_from_send_ms,
        );
        if r.scenario == "burst" {
            row(
                "bundle received - motion shown (due)",
                &r.latency_from_due_ms,
            );
        }
        row("tracker send -> source capture", &r.send_to_capture_ms);
        row(
            "source's sample date - tracker sample",
            &r.source_dating_error_ms,
        );
    }
    println!(
        "bundles: {} sent by the vmc stage, {} received, {} lost, {} duplicated, {} malformed, {} decode failures; {} frames not sent (calibrating), {} sent as the calibration's catch-up (captured before the first bundle arrived)",
        r.bundles_sent,
        r.bundles_received,
        r.bundles_lost,
        r.bundles_duplicated,
        r.bundles_malformed,
        r.decode_failures,
        r.frames_not_sent_calibrating
            .map_or("?".to_owned(), |n| n.to_string()),
        r.catch_up_bundles
    );
    if r.scenario != "raw" {
        let n = |v: Option<u64>| v.map_or("?".to_owned(), |v| v.to_string());
        println!(
            "samples: {} sent by the emulator, {} received by the source, {} lost (packet numbers), {} unaccounted; {} paired with their send, {} unpaired; emulator pacing late p99 {:.0} µs",
            n(r.samples_sent),
            n(r.samples_received),
            n(r.samples_lost),
            r.samples_unaccounted
                .map_or("?".to_owned(), |v| v.to_string()),
            r.samples_paired,
            r.samples_unpaired,
            r.emulator_pacing_late_p99_us.unwrap_or(f64::NAN)
        );
    }
    let drops: Vec<String> = r.drops.iter().map(|(id, n)| format!("{id} {n}")).collect();
    println!("dropped (live readers): {}", drops.join(", "));
    for p in &r.problems {
        println!("PROBLEM: {p}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// R from a unit quaternion [w, x, y, z] (row-major).
    fn matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
        let [w, x, y, z] = q;
        [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - w * z),
                2.0 * (x * z + w * y),
            ],
            [
                2.0 * (x * y + w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - w * x),
            ],
            [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ]
    }

    fn unit(q: [f64; 4]) -> [f64; 4] {
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        q.map(|v| v / n)
    }

    #[test]
    fn the_firmware_sample_round_trips_through_the_slimevr_sources_specific_force() {
        use imuflow_imu_source::slimevr::receiver::specific_force;
        let rotations = [
            [1.0, 0.0, 0.0, 0.0],
            [0.8, 0.6, 0.0, 0.0],
            [0.5, -0.5, 0.5, 0.5],
            [0.2, 0.3, -0.9, 0.1],
            [-0.6, 0.1, 0.2, 0.77],
        ];
        let forces = [[0.0, 0.0, 9.81], [1.5, -2.0, 8.0], [-12.0, 3.25, 0.5]];
        for q in rotations {
            let q = unit(q).map(|v| v as f32);
            for f in forces {
                let s = firmware_sample(q, f);
                // The rotation goes out as x, y, z, w.
                assert_eq!(s.rotation_xyzw[3], q[0]);
                let back = specific_force(s.linear_mps2, s.rotation_xyzw).unwrap();
                for i in 0..3 {
                    assert!((back[i] - f[i]).abs() < 1e-5, "{q:?} {f:?}: {back:?}");
                }
            }
        }
    }

    #[test]
    fn a_sensor_at_rest_sends_no_linear_acceleration_whatever_its_orientation() {
        // At rest the specific force is g along the inertial up axis, seen in the sensor frame.
        for q in [
            [1.0, 0.0, 0.0, 0.0],
            [0.9, 0.3, -0.2, 0.25],
            [0.1, 0.9, 0.4, 0.1],
        ] {
            let q = unit(q);
            let r = matrix(q);
            let f: [f32; 3] = std::array::from_fn(|i| (9.80665 * r[2][i]) as f32);
            let s = firmware_sample(q.map(|v| v as f32), f);
            assert!(
                s.linear_mps2.iter().all(|a| a.abs() < 1e-5),
                "{:?}",
                s.linear_mps2
            );
        }
    }

    fn still(t: f64, q: [f32; 4], f: [f32; 3]) -> ImuSample {
        ImuSample {
            time_s: t,
            orientation_wxyz: [q; MAX_SITES],
            specific_force_mps2: [f; MAX_SITES],
        }
    }

    #[test]
    fn resampling_slerps_orientations_and_interpolates_forces() {
        // Two frames 1/60 s apart: a quarter turn about z, force from 0 to 6.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let frames = [
            still(0.0, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 9.80665]),
            still(1.0 / 60.0, [h, 0.0, 0.0, h], [6.0, 0.0, 9.80665]),
        ];
        // 120 Hz: ticks at 0 and 1/120 s (the midpoint); 1/60 s would be the third.
        let ticks = tracker_ticks(&frames, 120.0, 2.0 / 120.0).unwrap();
        assert_eq!(ticks.len(), 2);
        let mid = ticks[1][3];
        let angle = std::f64::consts::FRAC_PI_8; // half of a quarter turn, halved again
        let [x, y, z, w] = mid.rotation_xyzw.map(f64::from);
        assert!(x.abs() < 1e-6 && y.abs() < 1e-6, "{mid:?}");
        assert!(
            (z - angle.sin()).abs() < 1e-6 && (w - angle.cos()).abs() < 1e-6,
            "{mid:?}"
        );
        // z up is unchanged by a turn about z: the linear acceleration is the force's x only.
        assert!((mid.linear_mps2[0] - 3.0).abs() < 1e-5, "{mid:?}");
        assert!(mid.linear_mps2[2].abs() < 1e-5, "{mid:?}");
        // More than the sample holds is refused, naming its length.
        let err = tracker_ticks(&frames, 120.0, 1.0).unwrap_err().to_string();
        assert!(err.contains("the sample holds 0.02 s"), "{err}");
    }

    #[test]
    fn samples_csv_writes_f32_that_read_back_bit_for_bit() {
        let s = FirmwareSample {
            rotation_xyzw: [0.1, -0.0, 1.0 / 3.0, 0.93],
            linear_mps2: [1e-7, -9.80665, 123.456],
        };
        let text = samples_csv(&[[s; NUM_IMUS]]);
        let row = text.lines().nth(1).unwrap();
        let v: Vec<f32> = row.split(',').skip(2).map(|t| t.parse().unwrap()).collect();
        let want = [s.rotation_xyzw.as_slice(), s.linear_mps2.as_slice()].concat();
        assert_eq!(
            v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
        // JavaScript reads the text as f64 and writes it as f32: the same bits.
        for t in row.split(',').skip(2) {
            let js = t.parse::<f64>().unwrap() as f32;
            assert_eq!(js.to_bits(), t.parse::<f32>().unwrap().to_bits(), "{t}");
        }
    }

    #[test]
    fn percentiles_are_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.5), 50.0);
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&v, 1.0), 100.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert!(percentile(&[], 0.5).is_nan());
        let s = stats(&[4.0, 1.0, 3.0, 2.0]).unwrap();
        assert_eq!(
            (s.count, s.mean, s.p50, s.p99, s.max),
            (4, 2.5, 2.0, 4.0, 4.0)
        );
        assert_eq!(stats(&[]), None);
    }

    fn sample(q: [f32; 4]) -> FirmwareSample {
        FirmwareSample {
            rotation_xyzw: q,
            linear_mps2: [0.0; 3],
        }
    }

    #[test]
    fn arrivals_pair_with_the_tick_that_sent_their_rotation() {
        // Tracker 0 turns a little each tick, except that ticks 2 and 3 repeat tick 1 (held still).
        let q = |k: u32| [0.0, 0.0, 0.01 * k as f32, 1.0];
        let rotations = [q(0), q(1), q(1), q(1), q(4)];
        let ticks: Vec<[FirmwareSample; NUM_IMUS]> = rotations
            .iter()
            .map(|r| std::array::from_fn(|i| sample(if i == 0 { *r } else { q(100 + i as u32) })))
            .collect();
        let ms = 1_000_000u64;
        let sent: Vec<Sent> = (0..5)
            .map(|k| Sent {
                tick: k,
                tracker: 0,
                due_ns: 1_000 * ms + k as u64 * 10 * ms,
                // Tick 4 was held back 30 ms by a stall.
                send_ns: 1_000 * ms + k as u64 * 10 * ms + if k == 4 { 30 * ms } else { 0 },
            })
            .collect();
        let at = |k: u64, lag: u64| 1_000 * ms + k * 10 * ms + lag;
        // Dated 0.25 ms after the capture by the source.
        let arrival = |tracker: usize, rotation_xyzw: [f32; 4], capture_ns: u64| Arrival {
            tracker,
            rotation_xyzw,
            dated_ns: capture_ns + ms / 4,
            capture_ns,
        };
        let arrivals = [
            arrival(0, q(0), at(0, ms / 2)),
            // The repeated rotation captured after tick 3's send: tick 3 (nearest before).
            arrival(0, q(1), at(3, ms)),
            arrival(0, q(4), at(4, 31 * ms)),
            // A rotation nobody sent, and one of another tracker's.
            arrival(0, q(50), at(4, 0)),
            arrival(1, q(0), at(0, 0)),
        ];
        let p = pair_arrivals(&ticks, &sent, &arrivals);
        assert_eq!(p.unmatched, 2);
        assert_eq!(p.send_to_capture_ms, [0.5, 1.0, 1.0]);
        // Tick 4 was held back: its date against when it was due.
        assert_eq!(p.dating_error_ms, [0.75, 1.25, 31.25]);
        assert_eq!(p.due_to_capture_ms, [0.5, 1.0, 31.0]);
    }

    /// A turn of `deg` degrees about an axis that differs per sensor, [w, x, y, z].
    fn turned(deg: f64, sensor: usize) -> [f64; 4] {
        let axis = unit([0.0, 1.0, 0.3 * sensor as f64, 0.5]);
        let h = deg.to_radians() / 2.0;
        [
            h.cos(),
            axis[1] * h.sin(),
            axis[2] * h.sin(),
            axis[3] * h.sin(),
        ]
    }

    #[test]
    fn fused_frames_are_placed_on_the_trackers_timeline_by_their_content() {
        // Every sensor turns 1° per tick, except sensor 5 which holds still; ticks 10 ms apart,
        // each sent 0.1 ms late; ticks 20.. were held back 50 ms by a stall.
        let ticks: Vec<[FirmwareSample; NUM_IMUS]> = (0..40)
            .map(|k| {
                std::array::from_fn(|i| {
                    let [w, x, y, z] = turned(if i == 5 { 0.0 } else { k as f64 }, i);
                    sample([x, y, z, w].map(|v| v as f32))
                })
            })
            .collect();
        let ms = 1_000_000u64;
        let sent: Vec<Sent> = (0..40)
            .flat_map(|k| {
                (0..NUM_IMUS).map(move |i| Sent {
                    tick: k,
                    tracker: i,
                    due_ns: 5_000 * ms + k as u64 * 10 * ms,
                    send_ns: 5_000 * ms
                        + k as u64 * 10 * ms
                        + ms / 10
                        + if k >= 20 { 50 * ms } else { 0 },
                })
            })
            .collect();
        let frame = |capture_ns: u64, tick: f64| -> FusionFrame {
            (
                capture_ns,
                std::array::from_fn(|i| {
                    turned(if i == 5 { 0.0 } else { tick }, i).map(|v| v as f32)
                }),
                0b111111,
            )
        };
        let frames = [
            frame(1, 5.3),
            frame(2, 12.75),
            // Within the stall's backlog.
            frame(3, 25.5),
            // Sensor 1 does not show (off every arc by far): the others still place the frame.
            {
                let mut f = frame(4, 30.0);
                f.1[1] = [0.0, 1.0, 0.0, 0.0];
                f
            },
            // Only two sensors usable: not placed.
            (5, frame(5, 8.0).1, 0b100011),
        ];
        let shown = shown_moments(&ticks, &sent, &frames);
        assert_eq!(shown.len(), 4, "{shown:?}");
        let due = |tick: f64| 5_000.0 * 1e6 + tick * 10.0 * 1e6;
        for (s, (capture, tick)) in shown
            .iter()
            .zip([(1, 5.3), (2, 12.75), (3, 25.5), (4, 30.0)])
        {
            assert_eq!(s.capture_ns, capture);
            let late = 0.1e6 + if tick >= 20.0 { 50e6 } else { 0.0 };
            assert!((s.due_ns - due(tick)).abs() < 2e3, "{s:?} vs tick {tick}");
            assert!(
                (s.send_ns - due(tick) - late).abs() < 2e3,
                "{s:?} vs tick {tick}"
            );
        }
    }

    #[test]
    fn numbers_are_read_from_summary_lines() {
        let source = "6 tracker(s): 3654 packets, 1800 samples, 2 lost, 0 duplicated, 0 out of order, 0 of unknown type; 0 ignored";
        assert_eq!(number_before(source, " samples,"), Some(1800));
        assert_eq!(number_before(source, " lost,"), Some(2));
        assert_eq!(number_before(source, " malformed"), None);
        let vmc = "461 VMC bundles sent to 127.0.0.1:4000 (0 failed to send); not sent: 770 flagged frames, 0 unusable, 0 by send_every";
        assert_eq!(number_before(vmc, " flagged frames"), Some(770));
    }

    #[test]
    fn the_calibrations_catch_up_is_not_the_settled_latency() {
        let ms = 1_000_000u64;
        let bundle = |read_ms: u64, capture_ms: u64| Bundle {
            read_ns: read_ms * ms,
            capture_ns: Some(capture_ms * ms),
            bones: 22,
            root: 1,
            ok: true,
        };
        // Three frames held by the calibration arrive at once at 1000 ms, then the live ones.
        let bundles = [
            bundle(1000, 900),
            bundle(1001, 917),
            bundle(1002, 999),
            bundle(1005, 1000),
            bundle(1022, 1017),
        ];
        let settled: Vec<u64> = settled(&bundles).map(|b| b.read_ns / ms).collect();
        assert_eq!(settled, [1005, 1022]);
        assert_eq!(super::settled(&[]).count(), 0);
        // Without a backlog the first bundle, captured before it arrived as every bundle is, counts.
        let live = [bundle(1000, 993), bundle(1017, 1010), bundle(1034, 1027)];
        assert_eq!(super::settled(&live).count(), 3);
    }

    #[test]
    fn the_receivers_and_the_emulators_logs_parse() {
        let csv = "read_ns,handled_ns,capture_ns,bones,root,ok,time_s,messages\n\
                   1000000005,1000000009,1000000000,22,1,1,0.5,26\n\
                   2000000005,2000000009,,3,1,0,,5\n";
        let b = parse_bundles(csv).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[0].capture_ns, Some(1_000_000_000));
        assert_eq!((b[1].capture_ns, b[1].bones, b[1].ok), (None, 3, false));
        assert!(parse_bundles("read_ns\n1\n").is_err());
        let sends = parse_sends("tick,tracker,due_ns,send_ns\n0,5,10,12\n").unwrap();
        assert_eq!(
            sends,
            [Sent {
                tick: 0,
                tracker: 5,
                due_ns: 10,
                send_ns: 12
            }]
        );
        assert!(parse_sends("h\n0,1,2\n").is_err());
    }

    #[test]
    fn the_trackers_file_gives_each_sites_mac_and_names_missing_sites() {
        let text = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/trackers/slimevr-sim.toml"),
        )
        .unwrap();
        let macs = macs_by_site(&text, "sim").unwrap();
        assert_eq!(macs[0], "02:53:4c:00:00:01");
        assert_eq!(macs[5], "02:53:4c:00:00:06");
        let partial = "[[tracker]]\nmac = \"aa:bb:cc:dd:ee:ff\"\nsite = \"head\"\n";
        let err = macs_by_site(partial, "mine.toml").unwrap_err().to_string();
        assert!(
            err.contains("'mine.toml' maps no tracker's sensor 0 to left_forearm, right_forearm, left_lower_leg, right_lower_leg, pelvis"),
            "{err}"
        );
    }
}
