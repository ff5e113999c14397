//! MCAP files (ROS 2's default storage since Iron, and Foxglove's recordings): topics from
//! the summary section's statistics when the file has them (else by reading it through,
//! through the `mcap` crate's summary reader), and every message streamed in file order.
//! The data section is read record by record; its chunks are decompressed (zstd, lz4 or
//! none) and checked against their CRC-32 on the rayon pool, a bounded window of them
//! ahead of the one being visited, in buffers that are reused, so memory is a few chunks
//! whatever the file's size. A damaged or truncated chunk ends the read after every message
//! of the chunks before it, naming the chunk and its byte offset.

use super::messages::Encoding;
use super::{BagError, Msg, MsgVisitor, ReadEnd, TopicInfo};
use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::Path;
use std::sync::mpsc;

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
    let mut reader = DataSection {
        records: Records {
            file: BufReader::with_capacity(1 << 20, file),
            size,
            pos: 0,
        },
        channels: Vec::new(),
        schemas: BTreeMap::new(),
        window: VecDeque::new(),
        window_bytes: 0,
        pool: Vec::new(),
        chunks: 0,
        messages: 0,
    };
    let stopped = reader.run(visit);
    let mut end = ReadEnd {
        messages: reader.messages,
        cut: None,
    };
    match stopped {
        Ok(()) => {}
        Err(Stop::Cut(why)) => end.cut = Some(why),
        Err(Stop::Io(source)) => {
            return Err(BagError::Io {
                path: path.to_path_buf(),
                source,
            }
            .into())
        }
        Err(Stop::Visitor(e)) => return Err(e),
    }
    Ok(end)
}

/// Chunks decompressed ahead of the one being visited, at most, per rayon thread.
const CHUNKS_AHEAD_PER_THREAD: usize = 2;
/// Decompressed bytes ahead of the one being visited, at most (one chunk always goes ahead).
const BYTES_AHEAD: u64 = 64 << 20;
/// A chunk (or schema, channel or message record) that says it holds more than this,
/// compressed or not, is taken as damaged.
const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// Buffers kept for reuse, at most.
const POOL_BUFFERS: usize = 16;
/// Bytes of a record's opcode and length.
const RECORD_HEAD: u64 = 9;
/// Bytes of a message record before its data: channel id, sequence, log and publish times.
const MESSAGE_HEAD: usize = 22;

/// Why a read stopped early.
enum Stop<E> {
    /// The file is truncated or damaged here: the messages before were delivered.
    Cut(String),
    /// Reading the file failed.
    Io(std::io::Error),
    /// The visitor stopped the read.
    Visitor(E),
}

/// Why reading the file's records stopped.
enum Broken {
    Cut(String),
    Io(std::io::Error),
}

impl<E> From<Broken> for Stop<E> {
    fn from(b: Broken) -> Self {
        match b {
            Broken::Cut(why) => Stop::Cut(why),
            Broken::Io(e) => Stop::Io(e),
        }
    }
}

/// The top-level records of the file, read in turn, each with its byte offset.
struct Records {
    file: BufReader<File>,
    size: u64,
    pos: u64,
}

/// A record's opcode, offset in the file and data length.
struct RecordHead {
    opcode: u8,
    offset: u64,
    len: u64,
}

impl Records {
    fn truncated(&self) -> String {
        format!(
            "the file ends in the middle of a record ({} bytes): it is truncated",
            self.size
        )
    }

    /// Checks the magic at the start of the file.
    fn magic(&mut self) -> Result<(), Broken> {
        let mut magic = [0u8; 8];
        self.exact(&mut magic)?;
        if &magic[..] != super::MCAP_MAGIC {
            return Err(Broken::Cut(
                "the file does not start with the MCAP magic".into(),
            ));
        }
        Ok(())
    }

    fn exact(&mut self, buf: &mut [u8]) -> Result<(), Broken> {
        match self.file.read_exact(buf) {
            Ok(()) => {
                self.pos += buf.len() as u64;
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                Err(Broken::Cut(self.truncated()))
            }
            Err(e) => Err(Broken::Io(e)),
        }
    }

    /// The next record's opcode and length; its data is read next with [`Records::data`] or
    /// passed over with [`Records::skip`]. The file ending before a footer is a truncation.
    fn head(&mut self) -> Result<RecordHead, Broken> {
        let offset = self.pos;
        let mut head = [0u8; RECORD_HEAD as usize];
        self.exact(&mut head)?;
        let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
        if len > self.size.saturating_sub(self.pos) {
            return Err(Broken::Cut(self.truncated()));
        }
        Ok(RecordHead {
            opcode: head[0],
            offset,
            len,
        })
    }

    /// The data of the record whose head was read last, into `buf`.
    fn data(&mut self, head: &RecordHead, buf: &mut Vec<u8>) -> Result<(), Broken> {
        buf.clear();
        // `head` checked the length against the file's size.
        buf.reserve(head.len as usize);
        let read = (&mut self.file)
            .take(head.len)
            .read_to_end(buf)
            .map_err(Broken::Io)?;
        self.pos += read as u64;
        if (read as u64) < head.len {
            return Err(Broken::Cut(self.truncated()));
        }
        Ok(())
    }

    fn skip(&mut self, head: &RecordHead) -> Result<(), Broken> {
        // `head` checked the length against the file's size, which fits an i64.
        self.file
            .seek_relative(head.len as i64)
            .map_err(Broken::Io)?;
        self.pos += head.len;
        Ok(())
    }
}

/// What a channel's messages are.
struct Channel {
    topic: String,
    type_name: String,
    encoding: Option<Encoding>,
}

/// A chunk record: where it is and how to decompress it.
#[derive(Clone)]
struct ChunkHead {
    /// 1 for the file's first chunk.
    number: u64,
    offset: u64,
    compression: String,
    uncompressed_size: u64,
    /// 0: the writer did not compute it.
    uncompressed_crc: u32,
    /// Where the compressed records start in the record's data.
    records_at: usize,
}

impl ChunkHead {
    fn place(&self) -> String {
        format!("chunk {} (at byte {})", self.number, self.offset)
    }

    /// Parses the fixed fields of a chunk record's data.
    fn parse(number: u64, offset: u64, data: &[u8]) -> Result<ChunkHead, String> {
        let mut at = 0usize;
        let mut take = |n: usize| -> Result<&[u8], String> {
            let field = data
                .get(at..at + n)
                .ok_or_else(|| "its header is cut short".to_string())?;
            at += n;
            Ok(field)
        };
        let u64_at = |b: &[u8]| u64::from_le_bytes(b.try_into().expect("8 bytes"));
        take(16)?; // message start and end times
        let uncompressed_size = u64_at(take(8)?);
        let uncompressed_crc = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes"));
        let name_len = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes")) as usize;
        let compression = String::from_utf8_lossy(take(name_len)?).into_owned();
        let compressed_size = u64_at(take(8)?);
        let records_at = at;
        let place = format!("chunk {number} (at byte {offset})");
        if compressed_size != (data.len() - records_at) as u64 {
            return Err(format!(
                "{place} is damaged: it says {compressed_size} compressed bytes in a record that holds {}",
                data.len() - records_at
            ));
        }
        if uncompressed_size > MAX_CHUNK_BYTES {
            return Err(format!(
                "{place} is damaged: it says it decompresses to {uncompressed_size} bytes (more than {MAX_CHUNK_BYTES})"
            ));
        }
        Ok(ChunkHead {
            number,
            offset,
            compression,
            uncompressed_size,
            uncompressed_crc,
            records_at,
        })
    }
}

/// A chunk decompressed (or why it could not be), and its record's buffer back.
struct Decompressed {
    records: Result<Vec<u8>, String>,
    record: Vec<u8>,
}

/// A chunk being decompressed on the pool.
struct InFlight {
    head: ChunkHead,
    done: mpsc::Receiver<Decompressed>,
}

thread_local! {
    static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

/// Decompresses the records of the chunk in `record` into `out` and checks their CRC-32.
fn decompress(head: &ChunkHead, record: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
    let compressed = &record[head.records_at..];
    let size = head.uncompressed_size as usize;
    out.clear();
    out.reserve(size);
    match head.compression.as_str() {
        "" => out.extend_from_slice(compressed),
        "zstd" => ZSTD.with(|cell| {
            let mut cell = cell.borrow_mut();
            let decompressor = match cell.as_mut() {
                Some(d) => d,
                None => {
                    cell.insert(zstd::bulk::Decompressor::new().map_err(|e| format!("zstd: {e}"))?)
                }
            };
            decompressor
                .decompress_to_buffer(compressed, out)
                .map(|_| ())
                .map_err(|e| format!("its zstd data does not decompress ({e})"))
        })?,
        "lz4" => {
            let mut decoder = lz4::Decoder::new(compressed)
                .map_err(|e| format!("its lz4 data does not decompress ({e})"))?;
            decoder
                .read_to_end(out)
                .map_err(|e| format!("its lz4 data does not decompress ({e})"))?;
        }
        other => {
            return Err(format!(
                "it is compressed with `{other}`, which imulab does not read (zstd, lz4 or none)"
            ))
        }
    }
    if out.len() != size {
        return Err(format!(
            "it decompresses to {} bytes where its header says {size}",
            out.len()
        ));
    }
    if head.uncompressed_crc != 0 {
        let crc = crc32fast::hash(out);
        if crc != head.uncompressed_crc {
            return Err(format!(
                "the CRC-32 of its records is {crc:08x} where its header says {:08x}",
                head.uncompressed_crc
            ));
        }
    }
    Ok(())
}

/// The state of one read through the data section.
struct DataSection {
    records: Records,
    /// By channel id.
    channels: Vec<Option<Channel>>,
    /// Schema names by id.
    schemas: BTreeMap<u16, String>,
    window: VecDeque<InFlight>,
    /// Decompressed bytes of the chunks in the window.
    window_bytes: u64,
    pool: Vec<Vec<u8>>,
    chunks: u64,
    messages: u64,
}

impl DataSection {
    fn buffer(&mut self) -> Vec<u8> {
        self.pool.pop().unwrap_or_default()
    }

    fn give_back(&mut self, buf: Vec<u8>) {
        if self.pool.len() < POOL_BUFFERS {
            self.pool.push(buf);
        }
    }

    /// Every record of the data section up to its end, a cut, or the visitor stopping.
    fn run<E>(&mut self, visit: &mut MsgVisitor<'_, E>) -> Result<(), Stop<E>> {
        let ahead = CHUNKS_AHEAD_PER_THREAD * rayon::current_num_threads().max(1);
        let read = self.read_records(visit, ahead);
        // The chunks in the window come before whatever ended the read of records.
        while !self.window.is_empty() {
            self.visit_oldest(visit)?;
        }
        read
    }

    fn read_records<E>(
        &mut self,
        visit: &mut MsgVisitor<'_, E>,
        ahead: usize,
    ) -> Result<(), Stop<E>> {
        use mcap::records::op;
        self.records.magic()?;
        loop {
            let head = self.records.head()?;
            let read_whole = matches!(
                head.opcode,
                op::CHUNK | op::SCHEMA | op::CHANNEL | op::MESSAGE
            );
            if read_whole && head.len > MAX_CHUNK_BYTES {
                return Err(Stop::Cut(format!(
                    "the record at byte {} is damaged: it says {} bytes (more than {MAX_CHUNK_BYTES})",
                    head.offset, head.len
                )));
            }
            match head.opcode {
                op::CHUNK => {
                    let mut record = self.buffer();
                    self.records.data(&head, &mut record)?;
                    self.chunks += 1;
                    let chunk =
                        ChunkHead::parse(self.chunks, head.offset, &record).map_err(Stop::Cut)?;
                    while self.window.len() >= ahead
                        || (!self.window.is_empty()
                            && self.window_bytes + chunk.uncompressed_size > BYTES_AHEAD)
                    {
                        self.visit_oldest(visit)?;
                    }
                    self.start(chunk, record);
                }
                op::SCHEMA | op::CHANNEL | op::MESSAGE => {
                    // Outside chunks: in order after the chunks before it.
                    while !self.window.is_empty() {
                        self.visit_oldest(visit)?;
                    }
                    let mut data = self.buffer();
                    self.records.data(&head, &mut data)?;
                    let place = || format!("the record at byte {}", head.offset);
                    let done = self.visit_record(head.opcode, &data, &place, visit);
                    self.give_back(data);
                    done?;
                }
                op::DATA_END | op::FOOTER => return Ok(()),
                _ => self.records.skip(&head)?,
            }
        }
    }

    /// Starts decompressing a chunk: on the rayon pool, or here when this thread is one of
    /// the pool's (waiting there for work queued behind it could wait forever).
    fn start(&mut self, head: ChunkHead, record: Vec<u8>) {
        let (tx, rx) = mpsc::sync_channel(1);
        let mut out = self.buffer();
        self.window_bytes += head.uncompressed_size;
        let job_head = head.clone();
        let job = move || {
            let records = decompress(&job_head, &record, &mut out).map(|()| out);
            // The receiver is gone when the read stopped early; the result is not needed.
            let _ = tx.send(Decompressed { records, record });
        };
        if rayon::current_thread_index().is_some() {
            job();
        } else {
            rayon::spawn(job);
        }
        self.window.push_back(InFlight { head, done: rx });
    }

    /// Waits for the oldest chunk of the window and visits its messages. When that ends
    /// the read (a damaged chunk, the visitor stopping), the chunks after it are dropped.
    fn visit_oldest<E>(&mut self, visit: &mut MsgVisitor<'_, E>) -> Result<(), Stop<E>> {
        let Some(chunk) = self.window.pop_front() else {
            return Ok(());
        };
        self.window_bytes -= chunk.head.uncompressed_size;
        let visited = self.visit_decompressed(chunk, visit);
        if visited.is_err() {
            self.window.clear();
            self.window_bytes = 0;
        }
        visited
    }

    fn visit_decompressed<E>(
        &mut self,
        chunk: InFlight,
        visit: &mut MsgVisitor<'_, E>,
    ) -> Result<(), Stop<E>> {
        let place = chunk.head.place();
        let done = chunk
            .done
            .recv()
            .map_err(|_| Stop::Cut(format!("{place}: its decompression did not finish")))?;
        self.give_back(done.record);
        let records = done
            .records
            .map_err(|why| Stop::Cut(format!("{place} is damaged: {why}")))?;
        let visited = self.visit_chunk(&records, &chunk.head, visit);
        self.give_back(records);
        visited
    }

    /// The records of a decompressed chunk, in order.
    fn visit_chunk<E>(
        &mut self,
        records: &[u8],
        head: &ChunkHead,
        visit: &mut MsgVisitor<'_, E>,
    ) -> Result<(), Stop<E>> {
        let mut at = 0usize;
        while at < records.len() {
            let place = || format!("the record at byte {at} of {}", head.place());
            let Some(record_head) = records.get(at..at + RECORD_HEAD as usize) else {
                return Err(Stop::Cut(format!("{}: it is cut short", place())));
            };
            let opcode = record_head[0];
            let len = u64::from_le_bytes(record_head[1..].try_into().expect("8 bytes"));
            let start = at + RECORD_HEAD as usize;
            let data = usize::try_from(len)
                .ok()
                .and_then(|len| records.get(start..start.checked_add(len)?))
                .ok_or_else(|| {
                    Stop::Cut(format!(
                        "{}: it says {len} bytes, past the end of the chunk",
                        place()
                    ))
                })?;
            if matches!(
                opcode,
                mcap::records::op::SCHEMA | mcap::records::op::CHANNEL | mcap::records::op::MESSAGE
            ) {
                self.visit_record(opcode, data, &place, visit)?;
            }
            at = start + data.len();
        }
        Ok(())
    }

    /// A schema, channel or message record; `place` says where it is, for an error.
    fn visit_record<E>(
        &mut self,
        opcode: u8,
        data: &[u8],
        place: &dyn Fn() -> String,
        visit: &mut MsgVisitor<'_, E>,
    ) -> Result<(), Stop<E>> {
        if opcode == mcap::records::op::MESSAGE {
            if data.len() < MESSAGE_HEAD {
                return Err(Stop::Cut(format!(
                    "{}: a message of {} bytes, shorter than its {MESSAGE_HEAD}-byte header",
                    place(),
                    data.len()
                )));
            }
            let channel_id = u16::from_le_bytes([data[0], data[1]]);
            let log_time = u64::from_le_bytes(data[6..14].try_into().expect("8 bytes"));
            let Some(Some(channel)) = self.channels.get(usize::from(channel_id)) else {
                return Err(Stop::Cut(format!(
                    "{}: a message on channel {channel_id}, which no channel record before it defines",
                    place()
                )));
            };
            visit(&Msg {
                topic: &channel.topic,
                type_name: &channel.type_name,
                encoding: channel.encoding,
                log_time_ns: i64::try_from(log_time).unwrap_or(i64::MAX),
                data: &data[MESSAGE_HEAD..],
            })
            .map_err(Stop::Visitor)?;
            self.messages += 1;
            return Ok(());
        }
        let record = mcap::parse_record(opcode, data)
            .map_err(|e| Stop::Cut(format!("{} is damaged: {e}", place())))?;
        match record {
            mcap::records::Record::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name);
            }
            mcap::records::Record::Channel(c) => {
                let type_name = match c.schema_id {
                    0 => String::new(),
                    id => self.schemas.get(&id).cloned().ok_or_else(|| {
                        Stop::Cut(format!(
                            "{}: channel {} (`{}`) names schema {id}, which no schema record before it defines",
                            place(),
                            c.id,
                            c.topic
                        ))
                    })?,
                };
                let slot = usize::from(c.id);
                if self.channels.len() <= slot {
                    self.channels.resize_with(slot + 1, || None);
                }
                self.channels[slot] = Some(Channel {
                    encoding: encoding(&c.message_encoding),
                    topic: c.topic,
                    type_name,
                });
            }
            _ => {}
        }
        Ok(())
    }
}
