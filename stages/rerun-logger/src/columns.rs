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

    /// The stream, for what goes straight to it (a blueprint) while calls are gathered.
    pub fn stream(&self) -> &RecordingStream {
        &self.rec
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
            // (A component is only listed once a row of it was logged: none is empty.)
            let mut pending = std::mem::take(components);
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

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use rerun::external::arrow::array::Array;
    use rerun::log::{Chunk, LogMsg};
    use rerun::time::TimelineName;

    use super::*;

    /// (entity, component, seq, capture_ns) → the cell, as text.
    type Cells = BTreeMap<(String, String, i64, i64), String>;

    fn at(seq: u64) -> FrameTime {
        FrameTime {
            seq,
            capture_ns: 1_000_000 + seq * 16_666_667,
            live: false,
        }
    }

    /// A run's log calls, made through `log`: what the logger does, including a series' held
    /// first value logged at its own, earlier time and entities whose component sets change.
    fn log_a_run(log: &mut Log) -> anyhow::Result<()> {
        for seq in 0..7u64 {
            log.set_time(at(seq))?;
            let x = seq as f32;
            log.log(
                "skeleton/joints",
                &rerun::Points3D::new([[x, 0.0, 0.0], [x, 1.0, 0.0]]).with_radii([0.1, 0.2]),
            )?;
            if seq % 2 == 1 {
                log.log(
                    "plots/speed",
                    &rerun::Scalars::new([x as f64, 2.0 * x as f64]),
                )?;
            }
            // Colours on the first frame only: the entity's components differ in their rows.
            let points = rerun::Points3D::new([[0.0, x, 0.0]]);
            if seq == 0 {
                log.log(
                    "contacts",
                    &points.with_colors([rerun::Color::from_rgb(1, 2, 3)]),
                )?;
            } else {
                log.log("contacts", &points)?;
            }
            if seq == 4 {
                // As `Plots::series`: a held value at the time it came, then back to now.
                log.set_time(at(2))?;
                log.log("plots/late", &rerun::Scalars::single(7.0))?;
                log.set_time(at(4))?;
                log.log("plots/late", &rerun::Scalars::single(8.0))?;
            }
        }
        log.send_gathered()
    }

    fn cells_of(messages: Vec<LogMsg>) -> Cells {
        let seq_name = TimelineName::from_static_str("seq");
        let capture_name = TimelineName::from_static_str("capture_time");
        let mut cells = Cells::new();
        for message in messages {
            let LogMsg::ArrowMsg(_, arrow) = message else {
                continue;
            };
            let chunk = Chunk::from_arrow_msg(&arrow).expect("a chunk");
            if chunk.is_static() {
                continue;
            }
            let seq = chunk.timelines()[&seq_name].times_raw().to_vec();
            let capture = chunk.timelines()[&capture_name].times_raw().to_vec();
            for column in chunk.components().0.values() {
                for row in 0..chunk.num_rows() {
                    if column.list_array.is_null(row) {
                        continue;
                    }
                    let key = (
                        chunk.entity_path().to_string(),
                        column.descriptor.component.to_string(),
                        seq[row],
                        capture[row],
                    );
                    let value = format!("{:?}", column.list_array.value(row));
                    assert!(cells.insert(key.clone(), value).is_none(), "{key:?} twice");
                }
            }
        }
        cells
    }

    fn run_with(make: impl FnOnce(RecordingStream) -> Log) -> Cells {
        let (rec, storage) = rerun::RecordingStreamBuilder::new("columns-test")
            .memory()
            .expect("memory recording");
        let mut log = make(rec);
        log_a_run(&mut log).expect("logged");
        let rec = log.into_stream();
        rec.flush_blocking().expect("flushed");
        cells_of(storage.take())
    }

    #[test]
    fn columns_hold_what_call_by_call_logging_holds() {
        let by_call = run_with(Log::call_by_call);
        // Three frames a send: sends at seq 3 and 6, the rest at the end.
        let in_columns = run_with(|rec| Log::in_columns(rec, 3));
        // Counted by hand from `log_a_run`: joints 7 rows × (positions, radii); speed 3 rows;
        // contacts 7 positions and 1 colour; late 2 rows.
        let count = |entity: &str| in_columns.keys().filter(|k| k.0 == entity).count();
        assert_eq!(count("/skeleton/joints"), 14);
        assert_eq!(count("/plots/speed"), 3);
        assert_eq!(count("/contacts"), 8);
        assert_eq!(count("/plots/late"), 2);
        assert_eq!(in_columns.len(), 27);
        assert_eq!(in_columns, by_call);
        // The held value kept its own time.
        let late: Vec<i64> = in_columns
            .keys()
            .filter(|k| k.0 == "/plots/late")
            .map(|k| k.2)
            .collect();
        assert_eq!(late, [2, 4]);
    }
}
