//! ROS 1 bags (format 2.0), read here record by record. The `rosbag` crate reads only the
//! chunk section its header's `index_pos` bounds, by slicing a memory map: a bag whose
//! recording was cut (`index_pos` 0 or past the end, the commonest damage) makes it panic
//! or read nothing, and a truncated bag is a case imulab must read up to the cut. The
//! format is small (records of `name=value` header fields and data; chunks of records,
//! uncompressed, bz2 or lz4 frames), so it is parsed here, with the `bzip2` and `lz4` crates
//! for the chunks.
//!
//! Topics come from the index section (connection and chunk-info records) when the header
//! points at one, else from reading the whole file.

use super::messages::Encoding;
use super::{BagError, Msg, MsgVisitor, ReadEnd, TopicInfo};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

const OP_MESSAGE_DATA: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;

/// Largest record or decompressed chunk accepted (a corrupt length must not demand memory).
const MAX_RECORD: u64 = 1 << 30;

/// The `name=value` fields of a record header.
struct Fields<'a>(Vec<(&'a str, &'a [u8])>);

impl<'a> Fields<'a> {
    fn parse(mut bytes: &'a [u8]) -> Result<Self, String> {
        let mut out = Vec::new();
        while !bytes.is_empty() {
            if bytes.len() < 4 {
                return Err("header field length cut".into());
            }
            let len = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as usize;
            let field = bytes
                .get(4..4 + len)
                .ok_or_else(|| format!("header field of {len} bytes overruns its header"))?;
            let eq = field
                .iter()
                .position(|&b| b == b'=')
                .ok_or("header field without `=`")?;
            let name = std::str::from_utf8(&field[..eq]).map_err(|_| "field name not UTF-8")?;
            out.push((name, &field[eq + 1..]));
            bytes = &bytes[4 + len..];
        }
        Ok(Fields(out))
    }
    fn get(&self, name: &str) -> Option<&'a [u8]> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
    }
    fn op(&self) -> Option<u8> {
        self.get("op").and_then(|v| v.first().copied())
    }
    fn u32(&self, name: &str) -> Result<u32, String> {
        let v = self.get(name).ok_or_else(|| format!("no `{name}` field"))?;
        let b: [u8; 4] = v
            .try_into()
            .map_err(|_| format!("`{name}` is not 4 bytes"))?;
        Ok(u32::from_le_bytes(b))
    }
    fn u64(&self, name: &str) -> Result<u64, String> {
        let v = self.get(name).ok_or_else(|| format!("no `{name}` field"))?;
        let b: [u8; 8] = v
            .try_into()
            .map_err(|_| format!("`{name}` is not 8 bytes"))?;
        Ok(u64::from_le_bytes(b))
    }
    /// A ROS time field (u32 seconds, u32 nanoseconds) in ns.
    fn time_ns(&self, name: &str) -> Result<i64, String> {
        let t = self.u64(name)?;
        Ok(i64::from(t as u32) * 1_000_000_000 + (t >> 32) as i64)
    }
    fn str(&self, name: &str) -> Result<&'a str, String> {
        let v = self.get(name).ok_or_else(|| format!("no `{name}` field"))?;
        std::str::from_utf8(v).map_err(|_| format!("`{name}` is not UTF-8"))
    }
}

/// Reads records from the file, tracking the byte position.
struct RecordReader {
    reader: BufReader<File>,
    pos: u64,
    len: u64,
}

/// What a read of one record gave.
enum Next {
    Record {
        at: u64,
        header: Vec<u8>,
        data: Vec<u8>,
    },
    End,
    Cut(String),
}

impl RecordReader {
    fn open(path: &Path) -> Result<Self, BagError> {
        let io = |source| BagError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        Ok(RecordReader {
            reader: BufReader::with_capacity(1 << 20, file),
            pos: 0,
            len,
        })
    }

    fn seek(&mut self, pos: u64) -> std::io::Result<()> {
        self.reader.seek(SeekFrom::Start(pos))?;
        self.pos = pos;
        Ok(())
    }

    fn block(&mut self, what: &str, at: u64) -> Result<Vec<u8>, String> {
        let mut len = [0u8; 4];
        if self.len.saturating_sub(self.pos) < 4 {
            return Err(format!(
                "truncated: the record at byte {at} is cut in its {what} length (the file ends at byte {})",
                self.len
            ));
        }
        self.reader
            .read_exact(&mut len)
            .map_err(|e| format!("byte {}: {e}", self.pos))?;
        self.pos += 4;
        let n = u64::from(u32::from_le_bytes(len));
        if n > MAX_RECORD {
            return Err(format!(
                "damaged: the record at byte {at} has a {what} of {n} bytes"
            ));
        }
        if self.pos + n > self.len {
            return Err(format!(
                "truncated: the record at byte {at} needs {} bytes, the file ends at byte {}",
                self.pos + n - at,
                self.len
            ));
        }
        let mut buf = vec![0u8; n as usize];
        self.reader
            .read_exact(&mut buf)
            .map_err(|e| format!("byte {}: {e}", self.pos))?;
        self.pos += n;
        Ok(buf)
    }

    fn next(&mut self) -> Next {
        if self.pos >= self.len {
            return Next::End;
        }
        let at = self.pos;
        let header = match self.block("header", at) {
            Ok(h) => h,
            Err(e) => return Next::Cut(e),
        };
        match self.block("data", at) {
            Ok(data) => Next::Record { at, header, data },
            Err(e) => Next::Cut(e),
        }
    }
}

/// The bag header's `index_pos` when it points inside the file (0: not indexed).
fn read_bag_header(r: &mut RecordReader, path: &Path) -> Result<u64, BagError> {
    let fail = |message: String| BagError::Format {
        path: path.to_path_buf(),
        message,
    };
    let mut magic = [0u8; 13];
    r.reader
        .read_exact(&mut magic)
        .map_err(|_| fail("shorter than a bag header".into()))?;
    r.pos = 13;
    match r.next() {
        Next::Record { header, .. } => {
            let fields = Fields::parse(&header).map_err(|e| fail(format!("bag header: {e}")))?;
            if fields.op() != Some(OP_BAG_HEADER) {
                return Err(fail("the first record is not the bag header".into()));
            }
            let index = fields.u64("index_pos").unwrap_or(0);
            Ok(if index >= r.pos && index < r.len {
                index
            } else {
                0
            })
        }
        Next::End => Err(fail("no bag header record".into())),
        Next::Cut(e) => Err(fail(format!("bag header: {e}"))),
    }
}

/// A connection: topic and type.
#[derive(Clone)]
struct Connection {
    topic: String,
    type_name: String,
}

fn connection(header: &Fields<'_>, data: &[u8]) -> Result<(u32, Connection), String> {
    let id = header.u32("conn")?;
    let info = Fields::parse(data)?;
    Ok((
        id,
        Connection {
            topic: header.str("topic")?.to_string(),
            type_name: info.str("type")?.to_string(),
        },
    ))
}

fn decompress(fields: &Fields<'_>, data: Vec<u8>) -> Result<Vec<u8>, String> {
    let size = u64::from(fields.u32("size")?);
    if size > MAX_RECORD {
        return Err(format!("a chunk of {size} bytes"));
    }
    let mut out = Vec::with_capacity(size as usize);
    match fields.str("compression")? {
        "none" => return Ok(data),
        "bz2" => bzip2::read::BzDecoder::new(data.as_slice())
            .read_to_end(&mut out)
            .map_err(|e| format!("bz2 chunk: {e}"))?,
        "lz4" => lz4::Decoder::new(data.as_slice())
            .and_then(|mut d| d.read_to_end(&mut out))
            .map_err(|e| format!("lz4 chunk: {e}"))?,
        other => return Err(format!("chunk compression `{other}` is not known")),
    };
    if out.len() as u64 != size {
        return Err(format!(
            "chunk decompresses to {} bytes, its header says {size}",
            out.len()
        ));
    }
    Ok(out)
}

/// The next length-prefixed block of `chunk` at `*at`.
fn take<'a>(chunk: &'a [u8], at: &mut usize) -> Result<&'a [u8], String> {
    let len = chunk
        .get(*at..*at + 4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        .ok_or("record length cut")?;
    let body = chunk
        .get(*at + 4..*at + 4 + len)
        .ok_or("record overruns its chunk")?;
    *at += 4 + len;
    Ok(body)
}

/// Records inside a decompressed chunk: `(header fields, data)`.
fn chunk_records(chunk: &[u8]) -> impl Iterator<Item = Result<(Fields<'_>, &[u8]), String>> {
    let mut at = 0usize;
    std::iter::from_fn(move || {
        if at >= chunk.len() {
            return None;
        }
        let result = take(chunk, &mut at).and_then(|header| {
            let data = take(chunk, &mut at)?;
            Ok((Fields::parse(header)?, data))
        });
        if result.is_err() {
            at = chunk.len();
        }
        Some(result)
    })
}

/// Streams the messages of the bag at `path` (see [`super::Bag::read`]).
pub fn read<E: From<BagError>>(path: &Path, visit: &mut MsgVisitor<'_, E>) -> Result<ReadEnd, E> {
    let mut r = RecordReader::open(path)?;
    let index_pos = read_bag_header(&mut r, path)?;
    let stop = if index_pos > 0 { index_pos } else { r.len };
    let mut connections: BTreeMap<u32, Connection> = BTreeMap::new();
    let mut end = ReadEnd::default();
    let mut deliver = |fields: &Fields<'_>,
                       data: &[u8],
                       connections: &mut BTreeMap<u32, Connection>,
                       end: &mut ReadEnd|
     -> Result<Result<(), String>, E> {
        match fields.op() {
            Some(OP_CONNECTION) => match connection(fields, data) {
                Ok((id, c)) => {
                    connections.insert(id, c);
                }
                Err(e) => return Ok(Err(format!("connection record: {e}"))),
            },
            Some(OP_MESSAGE_DATA) => {
                let (conn, time) = match (fields.u32("conn"), fields.time_ns("time")) {
                    (Ok(c), Ok(t)) => (c, t),
                    (Err(e), _) | (_, Err(e)) => return Ok(Err(format!("message record: {e}"))),
                };
                let Some(c) = connections.get(&conn) else {
                    return Ok(Err(format!(
                        "a message of connection {conn}, which no connection record defines"
                    )));
                };
                visit(&Msg {
                    topic: &c.topic,
                    type_name: &c.type_name,
                    encoding: Some(Encoding::Ros1),
                    log_time_ns: time,
                    data,
                })?;
                end.messages += 1;
            }
            _ => {}
        }
        Ok(Ok(()))
    };
    while r.pos < stop {
        let (at, header, data) = match r.next() {
            Next::Record { at, header, data } => (at, header, data),
            Next::End => break,
            Next::Cut(e) => {
                end.cut = Some(e);
                break;
            }
        };
        let fields = match Fields::parse(&header) {
            Ok(f) => f,
            Err(e) => {
                end.cut = Some(format!("damaged: the record at byte {at}: {e}"));
                break;
            }
        };
        let result = if fields.op() == Some(OP_CHUNK) {
            match decompress(&fields, data) {
                Ok(chunk) => {
                    let mut outcome = Ok(());
                    for record in chunk_records(&chunk) {
                        outcome = match record {
                            Ok((f, d)) => deliver(&f, d, &mut connections, &mut end)?,
                            Err(e) => Err(e),
                        };
                        if outcome.is_err() {
                            break;
                        }
                    }
                    outcome
                }
                Err(e) => Err(e),
            }
        } else {
            deliver(&fields, &data, &mut connections, &mut end)?
        };
        if let Err(e) = result {
            end.cut = Some(format!("damaged: the record at byte {at}: {e}"));
            break;
        }
    }
    Ok(end)
}

/// Topics from the index section, else counted by reading the bag.
pub fn topics(path: &Path) -> Result<Vec<TopicInfo>, BagError> {
    let mut r = RecordReader::open(path)?;
    let index_pos = read_bag_header(&mut r, path)?;
    if index_pos > 0 {
        if let Some(topics) = indexed_topics(&mut r, index_pos) {
            return Ok(topics);
        }
    }
    let mut out: Vec<TopicInfo> = Vec::new();
    read::<BagError>(path, &mut |m| {
        match out.iter_mut().find(|t| t.name == m.topic) {
            Some(t) => t.messages += 1,
            None => out.push(TopicInfo {
                name: m.topic.to_string(),
                type_name: m.type_name.to_string(),
                messages: 1,
            }),
        }
        Ok(())
    })?;
    Ok(out)
}

/// Connection and chunk-info records after `index_pos`; `None` when they do not read whole.
fn indexed_topics(r: &mut RecordReader, index_pos: u64) -> Option<Vec<TopicInfo>> {
    r.seek(index_pos).ok()?;
    let mut connections: BTreeMap<u32, Connection> = BTreeMap::new();
    let mut counts: BTreeMap<u32, u64> = BTreeMap::new();
    loop {
        match r.next() {
            Next::Record { header, data, .. } => {
                let fields = Fields::parse(&header).ok()?;
                match fields.op() {
                    Some(OP_CONNECTION) => {
                        let (id, c) = connection(&fields, &data).ok()?;
                        connections.insert(id, c);
                    }
                    Some(OP_CHUNK_INFO) => {
                        for pair in data.chunks_exact(8) {
                            let conn = u32::from_le_bytes([pair[0], pair[1], pair[2], pair[3]]);
                            let n = u32::from_le_bytes([pair[4], pair[5], pair[6], pair[7]]);
                            *counts.entry(conn).or_default() += u64::from(n);
                        }
                    }
                    _ => {}
                }
            }
            Next::End => break,
            Next::Cut(_) => return None,
        }
    }
    let mut out: Vec<TopicInfo> = Vec::new();
    for (id, c) in connections {
        let n = counts.get(&id).copied().unwrap_or(0);
        match out.iter_mut().find(|t| t.name == c.topic) {
            Some(t) => t.messages += n,
            None => out.push(TopicInfo {
                name: c.topic,
                type_name: c.type_name,
                messages: n,
            }),
        }
    }
    Some(out)
}
