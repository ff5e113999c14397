//! MCAP files (ROS 2's default storage since Iron, and Foxglove's recordings) through the
//! `mcap` crate: topics from the summary section's statistics when the file has them
//! (else by reading it through), messages streamed with `mcap::io::MessageReader`, which
//! holds one decompressed chunk at a time.

use super::messages::Encoding;
use super::{BagError, Msg, MsgVisitor, ReadEnd, TopicInfo};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::Path;

fn io_error(path: &Path) -> impl Fn(std::io::Error) -> BagError + '_ {
    move |source| BagError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The message encoding of a channel as imulab decodes it.
fn encoding(message_encoding: &str) -> Option<Encoding> {
    match message_encoding {
        "cdr" => Some(Encoding::Cdr),
        "ros1" => Some(Encoding::Ros1),
        _ => None,
    }
}

/// The summary section, when the file ends with one.
fn summary(path: &Path) -> Result<Option<mcap::Summary>, BagError> {
    use mcap::sans_io::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
    let mut file = File::open(path).map_err(io_error(path))?;
    let size = file.metadata().map_err(io_error(path))?.len();
    let mut reader =
        SummaryReader::new_with_options(SummaryReaderOptions::default().with_file_size(size));
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(e) => e,
            // A file without a valid footer (truncated, being written) has no summary.
            Err(_) => return Ok(None),
        };
        match event {
            SummaryReadEvent::ReadRequest(n) => {
                let read = file.read(reader.insert(n)).map_err(io_error(path))?;
                reader.notify_read(read);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let pos = file.seek(to).map_err(io_error(path))?;
                reader.notify_seeked(pos);
            }
        }
    }
    Ok(reader.finish())
}

/// Topics in channel order, from the statistics record, else counted by reading the file.
pub fn topics(path: &Path) -> Result<Vec<TopicInfo>, BagError> {
    if let Some(summary) = summary(path)? {
        if let Some(stats) = &summary.stats {
            let mut channels: Vec<_> = summary.channels.values().collect();
            channels.sort_by_key(|c| c.id);
            return Ok(merge_topics(channels.iter().map(|c| {
                (
                    c.topic.clone(),
                    c.schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    stats
                        .channel_message_counts
                        .get(&c.id)
                        .copied()
                        .unwrap_or(0),
                )
            })));
        }
    }
    let mut counts: BTreeMap<(String, String), u64> = BTreeMap::new();
    let mut order: Vec<(String, String)> = Vec::new();
    read::<BagError>(path, &mut |m| {
        let key = (m.topic.to_string(), m.type_name.to_string());
        let n = counts.entry(key.clone()).or_insert_with(|| {
            order.push(key);
            0
        });
        *n += 1;
        Ok(())
    })?;
    Ok(merge_topics(order.into_iter().map(|k| {
        let n = counts[&k];
        (k.0, k.1, n)
    })))
}

/// One entry per topic name (several channels may share a topic), counts added.
fn merge_topics(entries: impl Iterator<Item = (String, String, u64)>) -> Vec<TopicInfo> {
    let mut out: Vec<TopicInfo> = Vec::new();
    for (name, type_name, messages) in entries {
        match out.iter_mut().find(|t| t.name == name) {
            Some(t) => t.messages += messages,
            None => out.push(TopicInfo {
                name,
                type_name,
                messages,
            }),
        }
    }
    out
}

/// Streams the messages of the file at `path` (see [`super::Bag::read`]).
pub fn read<E: From<BagError>>(path: &Path, visit: &mut MsgVisitor<'_, E>) -> Result<ReadEnd, E> {
    let file = File::open(path).map_err(io_error(path))?;
    let size = file.metadata().map_err(io_error(path))?.len();
    let reader = mcap::io::MessageReader::new(BufReader::with_capacity(1 << 20, file));
    let mut end = ReadEnd::default();
    for message in reader {
        let message = match message {
            Ok(m) => m,
            Err(e) => {
                end.cut = Some(match e {
                    mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => format!(
                        "the file ends in the middle of a record ({size} bytes): it is truncated"
                    ),
                    other => format!("damaged: {other}"),
                });
                break;
            }
        };
        let channel = &message.channel;
        let type_name = channel.schema.as_ref().map_or("", |s| s.name.as_str());
        visit(&Msg {
            topic: &channel.topic,
            type_name,
            encoding: encoding(&channel.message_encoding),
            log_time_ns: i64::try_from(message.log_time).unwrap_or(i64::MAX),
            data: &message.data,
        })?;
        end.messages += 1;
    }
    Ok(end)
}
