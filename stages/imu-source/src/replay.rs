//! Mode `replay`: the frames of a recorder's mcap file, published again in file order.
//!
//! The raw channels (message encoding `imuflow-raw`) hold each frame's exact bytes; their schema's
//! name is the versioned frame type (`imuflow.ImuFrame.v1`). Frames keep their recorded `seq`,
//! `capture_ns` and flags; `publish_ns` is stamped anew.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use imuflow_graph::StageContext;
use imuflow_graph::frames::{Frame, ImuFrame, MotionFrame, frame_from_bytes};

use crate::Publisher;

/// Message encoding of the recorder's raw channels.
pub const RAW_ENCODING: &str = "imuflow-raw";

/// One recorded frame, in file order.
#[derive(Debug, Clone)]
pub enum Recorded {
    Imu(Box<ImuFrame>),
    Truth(Box<MotionFrame>),
}

/// The frames of one recording to replay.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// Topic the IMU frames come from.
    pub imu_topic: String,
    /// Topic the truth frames come from, if any.
    pub truth_topic: Option<String>,
    /// Every frame of both topics, in file order.
    pub frames: Vec<Recorded>,
    /// Number of IMU frames.
    pub imu_frames: u64,
}

type Channel = Arc<mcap::Channel<'static>>;

fn schema_name<'a>(channel: &'a mcap::Channel<'_>) -> &'a str {
    channel.schema.as_ref().map_or("", |s| s.name.as_str())
}

/// Whether `channel` holds raw frames of type `T`.
fn carries<T: Frame>(channel: &mcap::Channel<'_>) -> bool {
    channel.message_encoding == RAW_ENCODING && schema_name(channel) == T::layout().type_name
}

/// The channel to read frames of type `T` from: the one named `topic`, or the first (lowest id)
/// raw channel of `T`.
fn pick<T: Frame>(
    channels: &BTreeMap<u16, Channel>,
    topic: Option<&str>,
) -> anyhow::Result<Option<Channel>> {
    let want = T::layout().type_name;
    let Some(topic) = topic else {
        return Ok(channels.values().find(|c| carries::<T>(c)).cloned());
    };
    let Some(channel) = channels.values().find(|c| c.topic == topic) else {
        let known: Vec<&str> = channels.values().map(|c| c.topic.as_str()).collect();
        bail!(
            "no topic '{topic}' (topics: {})",
            if known.is_empty() {
                "none".to_owned()
            } else {
                known.join(", ")
            }
        );
    };
    if !carries::<T>(channel) {
        bail!(
            "topic '{topic}' holds '{}' messages of schema '{}', not {RAW_ENCODING} {want}",
            channel.message_encoding,
            schema_name(channel)
        );
    }
    Ok(Some(channel.clone()))
}

fn decode<T: Frame>(data: &[u8], topic: &str, index: u64) -> anyhow::Result<T> {
    frame_from_bytes::<T>(data).ok_or_else(|| {
        anyhow!(
            "topic '{topic}' message {index}: {} bytes, but a {} is {} bytes",
            data.len(),
            T::layout().type_name,
            std::mem::size_of::<T>()
        )
    })
}

impl Recording {
    /// Reads the IMU frames (from `topic`, default the first ImuFrame raw channel) and the truth
    /// frames (from `truth_topic`, default the first MotionFrame raw channel, if any) of `path`.
    pub fn load(
        path: &Path,
        topic: Option<&str>,
        truth_topic: Option<&str>,
    ) -> anyhow::Result<Recording> {
        let file = path.display().to_string();
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read recording '{file}'"))?;
        Recording::parse(&bytes, topic, truth_topic).with_context(|| format!("recording '{file}'"))
    }

    /// [`Recording::load`] on the file's bytes.
    pub fn parse(
        bytes: &[u8],
        topic: Option<&str>,
        truth_topic: Option<&str>,
    ) -> anyhow::Result<Recording> {
        let channels = channels(bytes)?;
        let imu = pick::<ImuFrame>(&channels, topic)?.ok_or_else(|| {
            anyhow!(
                "no {RAW_ENCODING} channel of {} (topics: {})",
                ImuFrame::layout().type_name,
                describe(&channels)
            )
        })?;
        let truth = pick::<MotionFrame>(&channels, truth_topic)?;
        let mut rec = Recording {
            imu_topic: imu.topic.clone(),
            truth_topic: truth.as_ref().map(|c| c.topic.clone()),
            ..Recording::default()
        };
        let mut truth_frames = 0u64;
        let stream = mcap::MessageStream::new(bytes).context("not a readable mcap file")?;
        for (n, message) in stream.enumerate() {
            let message = message.with_context(|| format!("mcap message {n} is corrupt"))?;
            let id = message.channel.id;
            if id == imu.id {
                let f: ImuFrame = decode(&message.data, &imu.topic, rec.imu_frames)?;
                rec.imu_frames += 1;
                if !f.header.is_end() {
                    rec.frames.push(Recorded::Imu(Box::new(f)));
                }
            } else if let Some(t) = truth.as_ref().filter(|t| t.id == id) {
                let f: MotionFrame = decode(&message.data, &t.topic, truth_frames)?;
                truth_frames += 1;
                if !f.header.is_end() {
                    rec.frames.push(Recorded::Truth(Box::new(f)));
                }
            }
        }
        if rec.imu_frames == 0 {
            tracing::warn!(topic = %rec.imu_topic, "the recording's IMU topic holds no messages");
        }
        Ok(rec)
    }
}

/// The file's channels by id: from the summary when the file has one, else from its messages.
fn channels(bytes: &[u8]) -> anyhow::Result<BTreeMap<u16, Channel>> {
    let summary = mcap::Summary::read(bytes).context("not an mcap file")?;
    if let Some(summary) = summary
        && !summary.channels.is_empty()
    {
        return Ok(summary.channels.into_iter().collect());
    }
    // No summary (a file whose writer was killed): collect the channels of the messages.
    let mut found = BTreeMap::new();
    let stream = mcap::MessageStream::new(bytes).context("not an mcap file")?;
    for (n, message) in stream.enumerate() {
        let message = message.with_context(|| format!("mcap message {n} is corrupt"))?;
        found
            .entry(message.channel.id)
            .or_insert_with(|| owned_channel(&message.channel));
    }
    Ok(found)
}

fn owned_channel(c: &mcap::Channel<'_>) -> Channel {
    Arc::new(mcap::Channel {
        id: c.id,
        topic: c.topic.clone(),
        schema: c.schema.as_ref().map(|s| {
            Arc::new(mcap::Schema {
                id: s.id,
                name: s.name.clone(),
                encoding: s.encoding.clone(),
                data: std::borrow::Cow::Owned(s.data.to_vec()),
            })
        }),
        message_encoding: c.message_encoding.clone(),
        metadata: c.metadata.clone(),
    })
}

fn describe(channels: &BTreeMap<u16, Channel>) -> String {
    if channels.is_empty() {
        return "none".to_owned();
    }
    channels
        .values()
        .map(|c| format!("{} [{} {}]", c.topic, c.message_encoding, schema_name(c)))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Publishes the recording (paced by the recorded capture times when `realtime`).
/// Replays `recording`; `limit` > 0 ends the stream after that many IMU frames.
pub fn run(
    ctx: StageContext,
    recording: &Recording,
    realtime: bool,
    limit: u64,
) -> anyhow::Result<()> {
    if let Some(t) = &recording.truth_topic {
        tracing::debug!(imu = %recording.imu_topic, truth = %t, "replaying");
    }
    let total = match limit {
        0 => recording.imu_frames,
        n => n.min(recording.imu_frames),
    };
    // The last seq replayed: that of the `total`-th IMU frame (its truth may come before or after it).
    let last_seq = (total < recording.imu_frames)
        .then(|| {
            recording
                .frames
                .iter()
                .filter_map(|f| match f {
                    Recorded::Imu(f) => Some(f.header.seq),
                    Recorded::Truth(_) => None,
                })
                .nth((total as usize).saturating_sub(1))
        })
        .flatten();
    let Some(mut out) = Publisher::start(ctx, total)? else {
        return Ok(());
    };
    let first_capture = recording.frames.iter().find_map(|f| match f {
        Recorded::Imu(f) => Some(f.header.capture_ns),
        Recorded::Truth(_) => None,
    });
    for frame in &recording.frames {
        if out.ctx.should_stop() {
            break;
        }
        let seq = match frame {
            Recorded::Imu(f) => f.header.seq,
            Recorded::Truth(f) => f.header.seq,
        };
        if last_seq.is_some_and(|last| seq > last) {
            continue;
        }
        match frame {
            Recorded::Imu(f) => {
                if realtime && let Some(first) = first_capture {
                    out.pace(Duration::from_nanos(
                        f.header.capture_ns.saturating_sub(first),
                    ));
                }
                out.publish_imu(f, Instant::now())?;
            }
            Recorded::Truth(f) => {
                // Paced like its IMU frame (the same capture time), so that truth and estimate
                // of one sample leave together instead of the truth a frame early.
                if realtime && let Some(first) = first_capture {
                    out.pace(Duration::from_nanos(
                        f.header.capture_ns.saturating_sub(first),
                    ));
                }
                out.publish_truth(f)?
            }
        }
    }
    out.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn not_an_mcap_file_is_a_named_error() {
        let err = Recording::parse(b"HIERARCHY\nROOT Hips\n", None, None).expect_err("fails");
        assert!(format!("{err:#}").contains("not an mcap file"), "{err:#}");
        let err = Recording::load(Path::new("/nonexistent/a.mcap"), None, None).expect_err("fails");
        assert!(
            format!("{err:#}").contains("/nonexistent/a.mcap"),
            "{err:#}"
        );
    }

    fn write_mcap(topic: &str, schema: &str, messages: &[Vec<u8>]) -> Vec<u8> {
        let mut buf = std::io::Cursor::new(Vec::new());
        {
            let mut w = mcap::Writer::new(&mut buf).expect("writer");
            let s = w
                .add_schema(schema, "imuflow-layout", b"{}")
                .expect("schema");
            let c = w
                .add_channel(s, topic, RAW_ENCODING, &BTreeMap::new())
                .expect("channel");
            for (i, m) in messages.iter().enumerate() {
                w.write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: c,
                        sequence: i as u32,
                        log_time: i as u64,
                        publish_time: i as u64,
                    },
                    m,
                )
                .expect("message");
            }
            w.finish().expect("finish");
        }
        buf.into_inner()
    }

    #[test]
    fn reads_frames_and_names_a_message_of_the_wrong_size() {
        let mut f = ImuFrame::default();
        f.header.seq = 7;
        let good = bytemuck_bytes(&f);
        let bytes = write_mcap("src.imu", "imuflow.ImuFrame.v1", &[good.clone(), good]);
        let rec = Recording::parse(&bytes, None, None).expect("parses");
        assert_eq!(rec.imu_frames, 2);
        assert_eq!(rec.imu_topic, "src.imu");
        assert!(rec.truth_topic.is_none());

        let bytes = write_mcap(
            "src.imu",
            "imuflow.ImuFrame.v1",
            &[bytemuck_bytes(&f), vec![0u8; 12]],
        );
        let err = Recording::parse(&bytes, None, None).expect_err("fails");
        let msg = format!("{err:#}");
        assert!(
            msg.contains("src.imu") && msg.contains("message 1"),
            "{msg}"
        );

        let bytes = write_mcap("src.pose", "imuflow.MotionFrame.v1", &[]);
        let err = Recording::parse(&bytes, None, None).expect_err("fails");
        assert!(
            format!("{err:#}").contains("no imuflow-raw channel"),
            "{err:#}"
        );
        let err = Recording::parse(&bytes, Some("nope"), None).expect_err("fails");
        assert!(format!("{err:#}").contains("no topic 'nope'"), "{err:#}");
        let err = Recording::parse(&bytes, Some("src.pose"), None).expect_err("fails");
        assert!(format!("{err:#}").contains("not imuflow-raw"), "{err:#}");
    }

    fn bytemuck_bytes(f: &ImuFrame) -> Vec<u8> {
        bytemuck::bytes_of(f).to_vec()
    }
}
