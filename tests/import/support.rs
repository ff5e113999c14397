//! Bags for the tests, made here: MCAP files through the `mcap` crate's writer with CDR
//! messages from `imulab::bag::messages::cdr`, and ROS 1 bags (format 2.0) by a small
//! writer of the record format (no crate writes them), with chunks uncompressed, bz2 or lz4.

use imulab::bag::messages::cdr;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// One message to write: topic index, receive time (ns) and its values.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Imu {
        stamp_ns: i64,
        gyro: [f64; 3],
        accel: [f64; 3],
    },
    Fix {
        stamp_ns: i64,
        status: i8,
        lat: f64,
        lon: f64,
        alt: f64,
        h_var: f64,
        v_var: f64,
    },
    Temperature {
        stamp_ns: i64,
        celsius: f64,
    },
    Twist {
        stamp_ns: i64,
        linear: [f64; 3],
    },
    /// Bytes of a type imulab does not read.
    Other(Vec<u8>),
}

pub struct Message {
    pub topic: usize,
    pub log_ns: i64,
    pub value: Value,
}

/// A topic: name and ROS 2 type name (`sensor_msgs/msg/Imu`).
pub struct Topic {
    pub name: &'static str,
    pub type_name: &'static str,
}

fn header(stamp_ns: i64) -> cdr::Header {
    cdr::Header {
        stamp: cdr::Time {
            sec: (stamp_ns.div_euclid(1_000_000_000)) as i32,
            nanosec: stamp_ns.rem_euclid(1_000_000_000) as u32,
        },
        frame_id: "imu_link".into(),
    }
}

fn v3(v: [f64; 3]) -> cdr::Vector3 {
    cdr::Vector3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

/// The CDR bytes of a value.
pub fn cdr_bytes(value: &Value) -> Vec<u8> {
    match value {
        Value::Imu {
            stamp_ns,
            gyro,
            accel,
        } => cdr::encode(&cdr::Imu {
            header: header(*stamp_ns),
            orientation: cdr::Quaternion {
                w: 1.0,
                ..Default::default()
            },
            orientation_covariance: [-1.0; 9],
            angular_velocity: v3(*gyro),
            angular_velocity_covariance: [0.0; 9],
            linear_acceleration: v3(*accel),
            linear_acceleration_covariance: [0.0; 9],
        }),
        Value::Fix {
            stamp_ns,
            status,
            lat,
            lon,
            alt,
            h_var,
            v_var,
        } => {
            let mut cov = [0.0; 9];
            cov[0] = *h_var;
            cov[4] = *h_var;
            cov[8] = *v_var;
            cdr::encode(&cdr::NavSatFix {
                header: header(*stamp_ns),
                status: cdr::NavSatStatus {
                    status: *status,
                    service: 1,
                },
                latitude: *lat,
                longitude: *lon,
                altitude: *alt,
                position_covariance: cov,
                position_covariance_type: 2,
            })
        }
        Value::Temperature { stamp_ns, celsius } => cdr::encode(&cdr::Temperature {
            header: header(*stamp_ns),
            temperature: *celsius,
            variance: 0.0,
        }),
        Value::Twist { stamp_ns, linear } => cdr::encode(&cdr::TwistStamped {
            header: header(*stamp_ns),
            twist: cdr::Twist {
                linear: v3(*linear),
                angular: v3([0.0; 3]),
            },
        }),
        Value::Other(bytes) => bytes.clone(),
    }
}

/// The ROS 1 serialisation of a value.
pub fn ros1_bytes(value: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    let head = |out: &mut Vec<u8>, stamp_ns: i64| {
        out.extend_from_slice(&7u32.to_le_bytes()); // seq
        out.extend_from_slice(&((stamp_ns / 1_000_000_000) as u32).to_le_bytes());
        out.extend_from_slice(&((stamp_ns % 1_000_000_000) as u32).to_le_bytes());
        out.extend_from_slice(&8u32.to_le_bytes());
        out.extend_from_slice(b"imu_link");
    };
    let f = |out: &mut Vec<u8>, values: &[f64]| {
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
    };
    match value {
        Value::Imu {
            stamp_ns,
            gyro,
            accel,
        } => {
            head(&mut out, *stamp_ns);
            f(&mut out, &[0.0, 0.0, 0.0, 1.0]);
            f(&mut out, &[-1.0; 9]);
            f(&mut out, gyro);
            f(&mut out, &[0.0; 9]);
            f(&mut out, accel);
            f(&mut out, &[0.0; 9]);
        }
        Value::Fix {
            stamp_ns,
            status,
            lat,
            lon,
            alt,
            h_var,
            v_var,
        } => {
            head(&mut out, *stamp_ns);
            out.push(*status as u8);
            out.extend_from_slice(&1u16.to_le_bytes());
            f(&mut out, &[*lat, *lon, *alt]);
            f(
                &mut out,
                &[*h_var, 0.0, 0.0, 0.0, *h_var, 0.0, 0.0, 0.0, *v_var],
            );
            out.push(2);
        }
        Value::Temperature { stamp_ns, celsius } => {
            head(&mut out, *stamp_ns);
            f(&mut out, &[*celsius, 0.0]);
        }
        Value::Twist { stamp_ns, linear } => {
            head(&mut out, *stamp_ns);
            f(&mut out, linear);
            f(&mut out, &[0.0; 3]);
        }
        Value::Other(bytes) => out.extend_from_slice(bytes),
    }
    out
}

/// Writes an MCAP file of CDR messages, chunked (zstd) with chunks of about `chunk_bytes`.
pub fn write_mcap(path: &Path, topics: &[Topic], messages: &[Message], chunk_bytes: u64) {
    write_mcap_compressed(
        path,
        topics,
        messages,
        chunk_bytes,
        Some(mcap::Compression::Zstd),
    );
}

/// [`write_mcap`] with the chunks' compression chosen (`None`: stored as they are).
pub fn write_mcap_compressed(
    path: &Path,
    topics: &[Topic],
    messages: &[Message],
    chunk_bytes: u64,
    compression: Option<mcap::Compression>,
) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut writer = mcap::WriteOptions::new()
        .chunk_size(Some(chunk_bytes))
        .compression(compression)
        .profile("ros2")
        .create(file)
        .unwrap();
    let mut channels = Vec::new();
    for t in topics {
        let schema = writer
            .add_schema(t.type_name, "ros2msg", b"# definition not needed")
            .unwrap();
        let channel = writer
            .add_channel(schema, t.name, "cdr", &BTreeMap::new())
            .unwrap();
        channels.push(channel);
    }
    for (seq, m) in messages.iter().enumerate() {
        let data = cdr_bytes(&m.value);
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channels[m.topic],
                    sequence: seq as u32,
                    log_time: m.log_ns as u64,
                    publish_time: m.log_ns as u64,
                },
                &data,
            )
            .unwrap();
    }
    writer.finish().unwrap();
}

fn field(name: &str, value: &[u8]) -> Vec<u8> {
    let mut out = ((name.len() + 1 + value.len()) as u32)
        .to_le_bytes()
        .to_vec();
    out.extend_from_slice(name.as_bytes());
    out.push(b'=');
    out.extend_from_slice(value);
    out
}

fn record(fields: &[Vec<u8>], data: &[u8]) -> Vec<u8> {
    let header: Vec<u8> = fields.concat();
    let mut out = (header.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(&header);
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
    out
}

fn ros_time(ns: i64) -> [u8; 8] {
    let secs = (ns / 1_000_000_000) as u64;
    let nsecs = (ns % 1_000_000_000) as u64;
    (secs | (nsecs << 32)).to_le_bytes()
}

/// The ROS 1 spelling of a type name.
fn ros1_type(name: &str) -> String {
    name.replacen("/msg/", "/", 1)
}

fn connection(id: u32, t: &Topic) -> Vec<u8> {
    let data = [
        field("topic", t.name.as_bytes()),
        field("type", ros1_type(t.type_name).as_bytes()),
        field("md5sum", b"*"),
        field("message_definition", b""),
    ]
    .concat();
    record(
        &[
            field("op", &[0x07]),
            field("conn", &id.to_le_bytes()),
            field("topic", t.name.as_bytes()),
        ],
        &data,
    )
}

/// Writes a ROS 1 bag: `per_chunk` messages per chunk, compressed with `compression`
/// (`none`, `bz2`, `lz4`), then the index section (connections, chunk infos).
pub fn write_ros1(
    path: &Path,
    topics: &[Topic],
    messages: &[Message],
    compression: &str,
    per_chunk: usize,
) {
    let mut out: Vec<u8> = b"#ROSBAG V2.0\n".to_vec();
    let header_at = out.len();
    out.extend_from_slice(&bag_header(0, topics.len() as u32, 0));
    let mut infos: Vec<Vec<u8>> = Vec::new();
    let mut defined = vec![false; topics.len()];
    for chunk in messages.chunks(per_chunk.max(1)) {
        let mut inner = Vec::new();
        let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
        for m in chunk {
            if !defined[m.topic] {
                defined[m.topic] = true;
                inner.extend_from_slice(&connection(m.topic as u32, &topics[m.topic]));
            }
            *counts.entry(m.topic as u32).or_default() += 1;
            inner.extend_from_slice(&record(
                &[
                    field("op", &[0x02]),
                    field("conn", &(m.topic as u32).to_le_bytes()),
                    field("time", &ros_time(m.log_ns)),
                ],
                &ros1_bytes(&m.value),
            ));
        }
        let compressed = match compression {
            "none" => inner.clone(),
            "bz2" => {
                let mut e = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
                e.write_all(&inner).unwrap();
                e.finish().unwrap()
            }
            "lz4" => {
                let mut e = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
                e.write_all(&inner).unwrap();
                let (buf, result) = e.finish();
                result.unwrap();
                buf
            }
            other => panic!("compression {other}"),
        };
        let chunk_pos = out.len() as u64;
        out.extend_from_slice(&record(
            &[
                field("op", &[0x05]),
                field("compression", compression.as_bytes()),
                field("size", &(inner.len() as u32).to_le_bytes()),
            ],
            &compressed,
        ));
        let data: Vec<u8> = counts
            .iter()
            .flat_map(|(c, n)| [c.to_le_bytes(), n.to_le_bytes()].concat())
            .collect();
        infos.push(record(
            &[
                field("op", &[0x06]),
                field("ver", &1u32.to_le_bytes()),
                field("chunk_pos", &chunk_pos.to_le_bytes()),
                field("start_time", &ros_time(chunk[0].log_ns)),
                field("end_time", &ros_time(chunk[chunk.len() - 1].log_ns)),
                field("count", &(counts.len() as u32).to_le_bytes()),
            ],
            &data,
        ));
    }
    let index_pos = out.len() as u64;
    for (i, t) in topics.iter().enumerate() {
        out.extend_from_slice(&connection(i as u32, t));
    }
    let chunks = infos.len() as u32;
    for info in infos {
        out.extend_from_slice(&info);
    }
    let head = bag_header(index_pos, topics.len() as u32, chunks);
    out[header_at..header_at + head.len()].copy_from_slice(&head);
    std::fs::write(path, out).unwrap();
}

/// The bag header record, padded to 4096 bytes as rosbag writes it.
fn bag_header(index_pos: u64, connections: u32, chunks: u32) -> Vec<u8> {
    let fields = [
        field("op", &[0x03]),
        field("index_pos", &index_pos.to_le_bytes()),
        field("conn_count", &connections.to_le_bytes()),
        field("chunk_count", &chunks.to_le_bytes()),
    ];
    let header_len: usize = fields.iter().map(Vec::len).sum();
    let padding = 4096 - 8 - header_len;
    record(&fields, &vec![b' '; padding])
}

/// Offset and data length of every chunk record of an MCAP file, in file order.
pub fn mcap_chunks(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut at = 8;
    let mut out = Vec::new();
    while at + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        match bytes[at] {
            0x06 => out.push((at, len)),
            0x0F => break,
            _ => {}
        }
        at += 9 + len;
    }
    out
}
