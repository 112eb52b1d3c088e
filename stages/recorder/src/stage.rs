//! The `recorder` stage process: one mcap channel per input (and a JSON one with `json`), then
//! every frame as it arrives, until END_OF_STREAM or a stop request.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;

use anyhow::Context;
use imuflow_graph::StageContext;
use imuflow_graph::frames::FrameType;
use imuflow_graph::spec::{InputsSpec, Role, StageSpec};

use crate::{JSON_TOPIC_SUFFIX, LAYOUT_ENCODING, RAW_ENCODING, json};

imuflow_graph::stage_params! {
    /// The recorder's parameters.
    pub struct RecorderParams {
        /// mcap file to write (overwritten)
        path: Option<PathBuf> = required, path;
        /// also write a JSON channel per edge (bigger files; readable by Foxglove without code)
        json: bool = false, bool;
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "recorder",
    role: Role::Sink,
    summary: "records the frames of any edges into an mcap file (raw bytes for exact replay, optional JSON)",
    inputs: InputsSpec::Any,
    outputs: &[],
    params: RecorderParams::SPECS,
};

struct Channels {
    raw: u16,
    json: Option<u16>,
    frame: FrameType,
}

/// Runs the recorder as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let params = RecorderParams::from_params(ctx.params());
    let path = params.path.context("params.path is required")?;
    let with_json = params.json;

    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let file = File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut writer = mcap::WriteOptions::new()
        .profile("imuflow")
        .library(concat!("imuflow-recorder ", env!("CARGO_PKG_VERSION")))
        .create(BufWriter::new(file))
        .with_context(|| format!("{}: cannot start the mcap file", path.display()))?;

    let channels = add_channels(&ctx, &mut writer, with_json)
        .with_context(|| format!("{}: cannot write channel headers", path.display()))?;
    let mut metadata = BTreeMap::new();
    metadata.insert("graph".to_owned(), ctx.graph().name.clone());
    metadata.insert(
        "graph_file".to_owned(),
        ctx.graph().file.display().to_string(),
    );
    metadata.insert("rate_hz".to_owned(), ctx.graph().rate_hz.to_string());
    metadata.insert("stage".to_owned(), ctx.id().to_owned());
    writer
        .write_metadata(&mcap::records::Metadata {
            name: "imuflow".into(),
            metadata,
        })
        .with_context(|| format!("{}: cannot write metadata", path.display()))?;

    let recorded = if ctx.ready()? {
        record(&mut ctx, &mut writer, &channels)
    } else {
        Ok(())
    };
    // Finalize whatever happened while recording, so the file stays valid.
    let finished = writer
        .finish()
        .with_context(|| format!("{}: cannot finalize the mcap file", path.display()));
    recorded.with_context(|| format!("{}: recording stopped", path.display()))?;
    finished?;
    ctx.finish(&mut [])?;
    Ok(())
}

/// The sensor sites a channel's frames were made from, for `sites` in its metadata: the set of
/// the stage that publishes it, named when it is not the six (whose recordings stay as they
/// were; exports keep every joint for them) and the stage is not a source (a source delivers the
/// sensors and the truth, which holds every joint).
fn estimated_from(ctx: &StageContext, stage: &str) -> anyhow::Result<Option<String>> {
    let Some(sensors) = ctx.graph().estimated_from(stage) else {
        return Ok(None);
    };
    let set = imuflow_body::SensorSet::resolve(sensors)
        .with_context(|| format!("stage '{stage}': `sensors`"))?;
    Ok((!set.is_six()).then(|| set.site_names().join(",")))
}

fn add_channels<W: std::io::Write + std::io::Seek>(
    ctx: &StageContext,
    writer: &mut mcap::Writer<W>,
    with_json: bool,
) -> anyhow::Result<Vec<Channels>> {
    let mut schemas: BTreeMap<(FrameType, bool), u16> = BTreeMap::new();
    let mut channels = Vec::new();
    for name in ctx.input_names() {
        let edge = &ctx.node().inputs[&name];
        let layout = edge.frame.layout();
        let topic = format!("{}.{}", edge.from_stage, edge.from_port);
        let mut meta = BTreeMap::new();
        meta.insert("input".to_owned(), name.clone());
        meta.insert("frame".to_owned(), edge.frame.name().to_owned());
        meta.insert("frame_size".to_owned(), layout.size.to_string());
        if let Some(sites) = estimated_from(ctx, &edge.from_stage)? {
            meta.insert("sites".to_owned(), sites);
        }

        let raw_schema = match schemas.get(&(edge.frame, false)) {
            Some(id) => *id,
            None => {
                let id = writer.add_schema(
                    layout.type_name,
                    LAYOUT_ENCODING,
                    &serde_json::to_vec_pretty(layout)?,
                )?;
                schemas.insert((edge.frame, false), id);
                id
            }
        };
        let raw = writer.add_channel(raw_schema, &topic, RAW_ENCODING, &meta)?;
        let json = if with_json {
            let schema = match schemas.get(&(edge.frame, true)) {
                Some(id) => *id,
                None => {
                    let id = writer.add_schema(
                        layout.type_name,
                        "jsonschema",
                        &serde_json::to_vec(&json::schema(layout))?,
                    )?;
                    schemas.insert((edge.frame, true), id);
                    id
                }
            };
            Some(writer.add_channel(
                schema,
                &format!("{topic}{JSON_TOPIC_SUFFIX}"),
                "json",
                &meta,
            )?)
        } else {
            None
        };
        channels.push(Channels {
            raw,
            json,
            frame: edge.frame,
        });
    }
    Ok(channels)
}

fn record<W: std::io::Write + std::io::Seek>(
    ctx: &mut StageContext,
    writer: &mut mcap::Writer<W>,
    channels: &[Channels],
) -> anyhow::Result<()> {
    while let Some(index) = ctx.next_any()? {
        let (Some(held), Some(ch)) = (ctx.held(index), channels.get(index)) else {
            continue;
        };
        let header = *held.header();
        let bytes = held.bytes();
        // mcap sequence numbers are 32-bit; a 60 Hz stream wraps after 2.2 years.
        let message = mcap::records::MessageHeader {
            channel_id: ch.raw,
            sequence: header.seq as u32,
            log_time: header.capture_ns,
            publish_time: header.publish_ns,
        };
        writer.write_to_known_channel(&message, bytes)?;
        if let Some(json_channel) = ch.json {
            let value = json::encode(ch.frame.layout(), bytes);
            writer.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: json_channel,
                    ..message
                },
                &serde_json::to_vec(&value)?,
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<RecorderParams>().unwrap();
    }
}
