//! Reading imuflow recordings: the frames of a recorder's mcap file, in file order, and a killed
//! writer's file record by record. A library with no process: the imu-source stage's `replay`
//! mode, the tools and the tests read recordings through it.
//!
//! The raw channels (message encoding `imuflow-raw`) hold each frame's exact bytes; their schema's
//! name is the versioned frame type (`imuflow.ImuFrame.v2`). Recordings of an earlier version of a
//! frame type (`imuflow.ImuFrame.v1`, six IMU slots) read as the current one, widened.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, anyhow, bail};
use imuflow_graph::frames::{Frame, FrameHeader, ImuFrame, MotionFrame, frame_from_recorded};

/// Message encoding of the recorder's raw channels.
pub const RAW_ENCODING: &str = "imuflow-raw";

/// One recorded frame, in file order.
#[derive(Debug, Clone)]
pub enum Recorded {
    Imu(Box<ImuFrame>),
    Truth(Box<MotionFrame>),
}

impl Recorded {
    pub fn header(&self) -> &FrameHeader {
        match self {
            Recorded::Imu(f) => &f.header,
            Recorded::Truth(f) => &f.header,
        }
    }
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

/// A channel of a recording, with its schema.
pub type Channel = Arc<mcap::Channel<'static>>;

/// The name of `channel`'s schema (imuflow's raw channels: the versioned frame type), or "".
pub fn schema_name<'a>(channel: &'a mcap::Channel<'_>) -> &'a str {
    channel.schema.as_ref().map_or("", |s| s.name.as_str())
}

/// Whether `channel` holds raw frames of type `T` (its current version or an earlier one).
pub fn carries<T: Frame>(channel: &mcap::Channel<'_>) -> bool {
    let name = schema_name(channel);
    channel.message_encoding == RAW_ENCODING
        && (name == T::layout().type_name || T::EARLIER_TYPE_NAMES.contains(&name))
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

/// Message `index` of `topic` as a frame of type `T` (an earlier version's widened); an error
/// names both and the sizes.
pub fn decode<T: Frame>(data: &[u8], topic: &str, index: u64) -> anyhow::Result<T> {
    frame_from_recorded::<T>(data).ok_or_else(|| {
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
        for_each_record(bytes, |n, record| {
            let mcap::records::Record::Message { header, data } = record else {
                return Ok(());
            };
            let id = header.channel_id;
            if id == imu.id {
                let f: ImuFrame = decode(&data, &imu.topic, rec.imu_frames)
                    .with_context(|| format!("mcap record {n}"))?;
                rec.imu_frames += 1;
                if !f.header.is_end() {
                    rec.frames.push(Recorded::Imu(Box::new(f)));
                }
            } else if let Some(t) = truth.as_ref().filter(|t| t.id == id) {
                let f: MotionFrame = decode(&data, &t.topic, truth_frames)
                    .with_context(|| format!("mcap record {n}"))?;
                truth_frames += 1;
                if !f.header.is_end() {
                    rec.frames.push(Recorded::Truth(Box::new(f)));
                }
            }
            Ok(())
        })?;
        if rec.imu_frames == 0 {
            tracing::warn!(topic = %rec.imu_topic, "the recording's IMU topic holds no messages");
        }
        Ok(rec)
    }
}

/// The file's channels by id: from the summary when the file has one, else from its messages.
pub fn channels(bytes: &[u8]) -> anyhow::Result<BTreeMap<u16, Channel>> {
    let summary = match mcap::Summary::read(bytes) {
        Ok(summary) => summary,
        // No footer (a recorder killed before it finished): read the records themselves.
        Err(_) if bytes.starts_with(mcap::MAGIC) => None,
        Err(e) => return Err(e).context("not an mcap file"),
    };
    if let Some(summary) = summary
        && !summary.channels.is_empty()
    {
        return Ok(summary.channels.into_iter().collect());
    }
    // No summary (a file whose writer was killed): collect the channels as the records declare them.
    let mut schemas: BTreeMap<u16, Arc<mcap::Schema<'static>>> = BTreeMap::new();
    let mut found = BTreeMap::new();
    for_each_record(bytes, |_, record| {
        match record {
            mcap::records::Record::Schema { header, data } => {
                let schema = mcap::Schema {
                    id: header.id,
                    name: header.name,
                    encoding: header.encoding,
                    data: std::borrow::Cow::Owned(data.into_owned()),
                };
                schemas.insert(schema.id, Arc::new(schema));
            }
            mcap::records::Record::Channel(c) => {
                let channel = mcap::Channel {
                    id: c.id,
                    topic: c.topic,
                    schema: schemas.get(&c.schema_id).cloned(),
                    message_encoding: c.message_encoding,
                    metadata: c.metadata,
                };
                found.entry(channel.id).or_insert_with(|| Arc::new(channel));
            }
            _ => {}
        }
        Ok(())
    })?;
    Ok(found)
}

/// Chunks declaring more than this uncompressed are taken as damage, not data: imuflow's recorder
/// writes chunks of a few MB, mcap's writers default to 1 MiB.
const MAX_RECORD_BYTES: usize = 1 << 30;

/// Every record of an mcap file in order (chunks opened), with its index: imuflow's one way to
/// read mcap files it did not just write (replay, and `imuflow compare`'s report). Read with mcap's sans-io
/// reader set to check each chunk whole (its sizes against a limit, its CRC) before yielding the
/// records in it: mcap 0.26's `MessageStream` reserves memory for a record length read out of a
/// chunk before checking it, so one damaged byte of compressed data made it panic ("capacity
/// overflow", found by tests/fuzzed_inputs.rs) or abort on a failed allocation.
pub fn for_each_record(
    bytes: &[u8],
    mut visit: impl FnMut(usize, mcap::records::Record<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES)
            // A recording whose writer was killed has no end magic; it is still replayable.
            .with_skip_end_magic(true),
    );
    // A finalized file ends with the magic; one whose writer was killed ends wherever the writer
    // stopped, often inside a chunk it was still writing. There a broken record is the cut-off
    // end, not damage: every record before it is read.
    let finalized = bytes.len() > mcap::MAGIC.len() && bytes.ends_with(mcap::MAGIC);
    let mut rest = bytes;
    let mut n = 0;
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(event) => event,
            Err(e) if !finalized => {
                tracing::warn!(
                    "the recording ends inside record {n} (its writer was stopped before it \
                     finished: {e}); read the {n} records before it"
                );
                return Ok(());
            }
            Err(e) => return Err(e).with_context(|| format!("mcap record {n} is corrupt")),
        };
        match event {
            LinearReadEvent::ReadRequest(need) => {
                let len = need.min(rest.len());
                reader.insert(len).copy_from_slice(&rest[..len]);
                reader.notify_read(len);
                rest = &rest[len..];
            }
            LinearReadEvent::Record { data, opcode } => {
                let record = mcap::parse_record(opcode, data)
                    .with_context(|| format!("mcap record {n} is corrupt"))?;
                visit(n, record)?;
                n += 1;
            }
        }
    }
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<u8> {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sample/walk.mcap");
        std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    }

    /// Offset of the first record with opcode `op` (records: opcode u8, length u64 LE, body).
    fn first_record(bytes: &[u8], op: u8) -> usize {
        let mut at = 8; // after the magic
        while at + 9 <= bytes.len() {
            if bytes[at] == op {
                return at;
            }
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            at += 9 + len;
        }
        panic!("no record {op:#x}");
    }

    #[test]
    fn a_recording_cut_after_its_data_replays_the_same_frames() {
        // A recorder killed before it wrote the summary: no DataEnd, summary, footer or end magic.
        let whole = sample();
        let data_end = first_record(&whole, 0x0F);
        let full = Recording::parse(&whole, None, None).expect("the sample");
        let cut = Recording::parse(&whole[..data_end], None, None).expect("the cut file");
        assert_eq!(full.imu_frames, 1511);
        assert_eq!(cut.imu_frames, full.imu_frames);
        assert_eq!(cut.frames.len(), full.frames.len());
        assert_eq!(cut.truth_topic, full.truth_topic);
    }

    /// Offset of the last record with opcode `op`.
    fn last_record(bytes: &[u8], op: u8) -> usize {
        let (mut at, mut last) = (8, None);
        while at + 9 <= bytes.len() {
            if bytes[at] == op {
                last = Some(at);
            }
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            at += 9 + len;
        }
        last.unwrap_or_else(|| panic!("no record {op:#x}"))
    }

    #[test]
    fn a_recording_cut_inside_a_chunk_replays_the_chunks_before_it() {
        // A recorder killed while writing a chunk (tests/fault_injection.rs): the file ends inside
        // it. Every chunk before it is read, exactly as from the same file cut cleanly before it.
        let whole = sample();
        let last_chunk = last_record(&whole, 0x06);
        let chunk_len =
            u64::from_le_bytes(whole[last_chunk + 1..last_chunk + 9].try_into().unwrap()) as usize;
        let clean = Recording::parse(&whole[..last_chunk], None, None).expect("cut before");
        for inside in [
            last_chunk + 5,
            last_chunk + 9 + chunk_len / 2,
            last_chunk + chunk_len,
        ] {
            let cut = Recording::parse(&whole[..inside], None, None).expect("cut inside");
            assert_eq!(cut.imu_frames, clean.imu_frames, "cut at {inside}");
            assert_eq!(cut.frames.len(), clean.frames.len());
        }
        assert!(clean.imu_frames > 0 && clean.imu_frames < 1511);
        // A finalized file (end magic) damaged in the same place is still an error.
        let mut damaged = whole.clone();
        damaged[last_chunk + 9 + chunk_len / 2] ^= 0xFF;
        assert!(Recording::parse(&damaged, None, None).is_err());
    }

    #[test]
    fn a_damaged_chunk_is_an_error_not_a_crash() {
        // The byte tests/fuzzed_inputs.rs found: inside a zstd chunk's compressed records. mcap's
        // MessageStream panicked ("capacity overflow") on the record length it decompressed.
        let mut bytes = sample();
        let offset = 357_054;
        assert!(first_record(&bytes, 0x06) <= offset);
        bytes[offset] = 0;
        let err = Recording::parse(&bytes, None, None).expect_err("damaged");
        assert!(format!("{err:#}").contains("corrupt"), "{err:#}");
    }

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
        let bytes = write_mcap("src.imu", "imuflow.ImuFrame.v2", &[good.clone(), good]);
        let rec = Recording::parse(&bytes, None, None).expect("parses");
        assert_eq!(rec.imu_frames, 2);
        assert_eq!(rec.imu_topic, "src.imu");
        assert!(rec.truth_topic.is_none());

        let bytes = write_mcap(
            "src.imu",
            "imuflow.ImuFrame.v2",
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

    #[test]
    fn a_recording_of_six_slot_frames_reads_widened() {
        // An ImuFrame.v1 (the bundled sample's kind): 280 bytes, header first, the valid mask at
        // byte 272 after six quaternions, forces and rates.
        let mut v1 = vec![0u8; 280];
        v1[..8].copy_from_slice(&9u64.to_le_bytes());
        v1[32..36].copy_from_slice(&0.5f32.to_le_bytes()); // slot 0's w
        v1[272..276].copy_from_slice(&0b11_1111u32.to_le_bytes());
        let bytes = write_mcap("source.imu", "imuflow.ImuFrame.v1", &[v1]);
        let rec = Recording::parse(&bytes, None, None).expect("a v1 recording parses");
        let Recorded::Imu(f) = &rec.frames[0] else {
            panic!("an IMU frame")
        };
        assert_eq!(f.header.seq, 9);
        assert_eq!(f.valid_mask, 0b11_1111);
        assert_eq!(f.orientation_wxyz[0][0], 0.5);
        assert_eq!(ImuFrame::layout().type_name, "imuflow.ImuFrame.v2");
    }

    fn bytemuck_bytes(f: &ImuFrame) -> Vec<u8> {
        bytemuck::bytes_of(f).to_vec()
    }
}
