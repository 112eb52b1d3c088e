//! Where the logger's log calls go: straight to the recording stream, or gathered per entity and
//! component and sent as columns.
//!
//! A graph frame makes some fifty log calls (skeletons, forces, every small field as a series).
//! Sent one by one, each becomes a row that rerun's batcher thread groups into chunks again; on
//! the 2-core machine this project is measured on, the logger and its batcher took about a third
//! of all CPU in an offline run of a whole graph, more than the rapier judge. Gathered here, each
//! entity's calls of `batch_frames` frames leave as one chunk per component set
//! ([`rerun::RecordingStream::send_columns`]): the same rows at the same times, without the
//! batcher's per-row work.
//!
//! The difference a reader can see: columns carry only the graph's two timelines, not the
//! `log_time` (wall clock at the call) that `log` adds; the batches reach the file
//! `batch_frames` frames later. A live viewer connection therefore logs call by call.

use std::collections::HashMap;

use anyhow::Context;
use rerun::external::arrow::array::{Array, ArrayRef};
use rerun::external::re_arrow_util::concat_arrays;
use rerun::{AsComponents, ComponentDescriptor, RecordingStream, SerializedComponentBatch};

/// When a frame was captured, on the recording's two timelines.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct FrameTime {
    pub seq: u64,
    pub capture_ns: u64,
    /// Live runs put wall-clock capture times on `capture_time`, offline runs the time since
    /// the recording started.
    pub live: bool,
}

impl FrameTime {
    fn set_on(&self, rec: &RecordingStream) {
        rec.set_time_sequence("seq", self.seq as i64);
        if self.live {
            rec.set_timestamp_nanos_since_epoch("capture_time", self.capture_ns as i64);
        } else {
            rec.set_duration_secs("capture_time", self.capture_secs());
        }
    }

    fn capture_secs(&self) -> f64 {
        self.capture_ns as f64 * 1e-9
    }
}

/// The logger's recording stream, and the calls gathered for it.
pub(crate) struct Log {
    rec: RecordingStream,
    now: FrameTime,
    gathered: Option<Gathered>,
}

/// Log calls not yet sent, per entity (in the order first logged) and component.
struct Gathered {
    frames_per_send: u64,
    /// The first seq logged since the last send.
    first_seq: Option<u64>,
    entities: Vec<(String, Vec<ComponentRows>)>,
    entity_index: HashMap<String, usize>,
}

/// One component's rows of one entity: each log call's array and time.
struct ComponentRows {
    descriptor: ComponentDescriptor,
    arrays: Vec<ArrayRef>,
    times: Vec<FrameTime>,
}

impl Log {
    /// Each call goes to `rec` as it comes (rerun's batcher groups them).
    pub fn call_by_call(rec: RecordingStream) -> Log {
        Log {
            rec,
            now: FrameTime::default(),
            gathered: None,
        }
    }

    /// Calls are gathered and sent as columns every `frames_per_send` frames of `seq`.
    pub fn in_columns(rec: RecordingStream, frames_per_send: u64) -> Log {
        Log {
            rec,
            now: FrameTime::default(),
            gathered: Some(Gathered {
                frames_per_send: frames_per_send.max(1),
                first_seq: None,
                entities: Vec::new(),
                entity_index: HashMap::new(),
            }),
        }
    }

    /// The stream, once everything gathered was sent.
    pub fn into_stream(self) -> RecordingStream {
        self.rec
    }

    /// The time of the following calls.
    pub fn now(&self) -> FrameTime {
        self.now
    }

    /// Sets the time of the following calls; sends what was gathered once `time` is
    /// `frames_per_send` frames past the first gathered.
    pub fn set_time(&mut self, time: FrameTime) -> anyhow::Result<()> {
        self.now = time;
        let Some(gathered) = &mut self.gathered else {
            time.set_on(&self.rec);
            return Ok(());
        };
        if gathered
            .first_seq
            .is_some_and(|first| time.seq >= first + gathered.frames_per_send)
        {
            self.send_gathered()?;
        }
        if let Some(gathered) = &mut self.gathered {
            gathered.first_seq.get_or_insert(time.seq);
        }
        Ok(())
    }

    /// Logs `what` under `entity` at the current time.
    pub fn log(
        &mut self,
        entity: impl Into<String>,
        what: &impl AsComponents,
    ) -> anyhow::Result<()> {
        let entity = entity.into();
        let Some(gathered) = &mut self.gathered else {
            self.rec.log(entity, what)?;
            return Ok(());
        };
        let index = match gathered.entity_index.get(&entity) {
            Some(index) => *index,
            None => {
                gathered.entities.push((entity.clone(), Vec::new()));
                gathered
                    .entity_index
                    .insert(entity, gathered.entities.len() - 1);
                gathered.entities.len() - 1
            }
        };
        let components = &mut gathered.entities[index].1;
        for batch in what.as_serialized_batches() {
            let rows = match components
                .iter_mut()
                .position(|c| c.descriptor == batch.descriptor)
            {
                Some(k) => &mut components[k],
                None => {
                    components.push(ComponentRows {
                        descriptor: batch.descriptor.clone(),
                        arrays: Vec::new(),
                        times: Vec::new(),
                    });
                    components.last_mut().expect("just pushed")
                }
            };
            rows.arrays.push(batch.array);
            rows.times.push(self.now);
        }
        Ok(())
    }

    /// Sends every gathered call as columns: per entity, one chunk for each set of components
    /// logged at the same times (usually all of the entity's).
    pub fn send_gathered(&mut self) -> anyhow::Result<()> {
        let Some(gathered) = &mut self.gathered else {
            return Ok(());
        };
        gathered.first_seq = None;
        for (entity, components) in &mut gathered.entities {
            let mut pending: Vec<ComponentRows> = std::mem::take(components)
                .into_iter()
                .filter(|c| !c.times.is_empty())
                .collect();
            while !pending.is_empty() {
                let times = pending[0].times.clone();
                let (same, rest): (Vec<_>, Vec<_>) =
                    pending.into_iter().partition(|c| c.times == times);
                pending = rest;
                send_columns(&self.rec, entity, &times, same)
                    .with_context(|| format!("rerun entity {entity}"))?;
            }
        }
        Ok(())
    }
}

/// One chunk: `columns`' rows at `times` under `entity`.
fn send_columns(
    rec: &RecordingStream,
    entity: &str,
    times: &[FrameTime],
    columns: Vec<ComponentRows>,
) -> anyhow::Result<()> {
    let seq = rerun::TimeColumn::new_sequence("seq", times.iter().map(|t| t.seq as i64));
    // All of a run's frames are live or none is.
    let capture = if times.first().is_some_and(|t| t.live) {
        rerun::TimeColumn::new_timestamp_nanos_since_epoch(
            "capture_time",
            times.iter().map(|t| t.capture_ns as i64),
        )
    } else {
        rerun::TimeColumn::new_duration_secs("capture_time", times.iter().map(|t| t.capture_secs()))
    };
    let mut serialized = Vec::with_capacity(columns.len());
    for rows in columns {
        let lengths: Vec<usize> = rows.arrays.iter().map(|a| a.len()).collect();
        let arrays: Vec<&dyn Array> = rows.arrays.iter().map(|a| a.as_ref()).collect();
        let array = concat_arrays(&arrays)?;
        let batch = SerializedComponentBatch::new(array, rows.descriptor);
        serialized.push(batch.partitioned(lengths)?);
    }
    rec.send_columns(entity, [seq, capture], serialized)?;
    Ok(())
}
