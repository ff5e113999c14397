//! Bag benchmark: an 8 h, 200 Hz `sensor_msgs/Imu` recording (5.76 M messages) as a ROS 2
//! MCAP file (CDR messages, zstd chunks as `ros2 bag record` writes them) and as a ROS 1 bag
//! (lz4 chunks), analysed with `imulab allan BAG --topic /imu/data --fit` (all six axes,
//! OADEV, octave τ, noise-term fit) as a child process under GNU time: wall, CPU and peak
//! memory. The anchor is allan_variance_ros's own figure: 727.7 s for 4.728 M samples
//! (its issue #39). The bags are written once into `target/bag-bench/` and reused.
//!
//! Run: `cargo bench --bench bag` (both formats) or `cargo bench --bench bag -- mcap|ros1`.

#[path = "support/results.rs"]
mod results;

use imulab::bag::messages::cdr;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

const RATE_HZ: f64 = 200.0;
const MESSAGES: usize = 8 * 3600 * 200;
const T0_NS: i64 = 1_700_000_000_000_000_000;
/// allan_variance_ros, issue #39: 727.7 s for 4.728 M samples.
const PEER_S: f64 = 727.7;
const PEER_SAMPLES: f64 = 4.728e6;

/// White noise plus a bias random walk on every axis, as one IMU message per sample.
struct Imu {
    rng: Xoshiro256PlusPlus,
    walk: [f64; 6],
}

impl Imu {
    fn next(&mut self, i: usize) -> cdr::Imu {
        let mut v = [0.0; 6];
        for (k, slot) in v.iter_mut().enumerate() {
            let n: f64 = StandardNormal.sample(&mut self.rng);
            let w: f64 = StandardNormal.sample(&mut self.rng);
            let (white, walk) = if k < 3 { (1e-3, 1e-6) } else { (2e-2, 1e-5) };
            self.walk[k] += walk * w;
            *slot = white * n + self.walk[k];
        }
        v[5] += 9.80665;
        let stamp = T0_NS + (i as f64 * 1e9 / RATE_HZ) as i64;
        cdr::Imu {
            header: cdr::Header {
                stamp: cdr::Time {
                    sec: (stamp / 1_000_000_000) as i32,
                    nanosec: (stamp % 1_000_000_000) as u32,
                },
                frame_id: "imu_link".into(),
            },
            orientation: cdr::Quaternion {
                w: 1.0,
                ..Default::default()
            },
            orientation_covariance: [-1.0; 9],
            angular_velocity: cdr::Vector3 {
                x: v[0],
                y: v[1],
                z: v[2],
            },
            angular_velocity_covariance: [0.0; 9],
            linear_acceleration: cdr::Vector3 {
                x: v[3],
                y: v[4],
                z: v[5],
            },
            linear_acceleration_covariance: [0.0; 9],
        }
    }
}

fn source() -> Imu {
    Imu {
        rng: Xoshiro256PlusPlus::seed_from_u64(39),
        walk: [0.0; 6],
    }
}

/// Receive time of message `i`: its stamp plus 1-3 ms of transport latency.
fn log_ns(m: &cdr::Imu, i: usize) -> i64 {
    i64::from(m.header.stamp.sec) * 1_000_000_000
        + i64::from(m.header.stamp.nanosec)
        + 1_000_000
        + (i as i64 * 7919 % 2_000_000)
}

fn write_mcap(path: &Path) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut writer = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(Some(mcap::Compression::Zstd))
        .create(file)
        .unwrap();
    let schema = writer
        .add_schema("sensor_msgs/msg/Imu", "ros2msg", b"")
        .unwrap();
    let channel = writer
        .add_channel(schema, "/imu/data", "cdr", &BTreeMap::new())
        .unwrap();
    let mut imu = source();
    for i in 0..MESSAGES {
        let m = imu.next(i);
        let t = log_ns(&m, i) as u64;
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: i as u32,
                    log_time: t,
                    publish_time: t,
                },
                &cdr::encode(&m),
            )
            .unwrap();
    }
    writer.finish().unwrap();
}

/// ROS 1 record: header fields then data, each with its u32 length.
fn record(fields: &[(&str, &[u8])], data: &[u8], out: &mut Vec<u8>) {
    let header: Vec<u8> = fields
        .iter()
        .flat_map(|(name, value)| {
            let mut f = ((name.len() + 1 + value.len()) as u32)
                .to_le_bytes()
                .to_vec();
            f.extend_from_slice(name.as_bytes());
            f.push(b'=');
            f.extend_from_slice(value);
            f
        })
        .collect();
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
}

fn ros_time(ns: i64) -> [u8; 8] {
    ((ns / 1_000_000_000) as u64 | (((ns % 1_000_000_000) as u64) << 32)).to_le_bytes()
}

/// The ROS 1 serialisation of the message.
fn ros1_bytes(m: &cdr::Imu) -> Vec<u8> {
    let mut out = Vec::with_capacity(324);
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(m.header.stamp.sec as u32).to_le_bytes());
    out.extend_from_slice(&m.header.stamp.nanosec.to_le_bytes());
    out.extend_from_slice(&(m.header.frame_id.len() as u32).to_le_bytes());
    out.extend_from_slice(m.header.frame_id.as_bytes());
    let q = &m.orientation;
    let (g, a) = (&m.angular_velocity, &m.linear_acceleration);
    let values = [q.x, q.y, q.z, q.w]
        .into_iter()
        .chain(m.orientation_covariance)
        .chain([g.x, g.y, g.z])
        .chain(m.angular_velocity_covariance)
        .chain([a.x, a.y, a.z])
        .chain(m.linear_acceleration_covariance);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// A ROS 1 bag with lz4 chunks of about 768 KiB, as `rosbag record --lz4` writes them.
fn write_ros1(path: &Path) {
    let mut file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut out = b"#ROSBAG V2.0\n".to_vec();
    // The bag header, rewritten at the end with the index position.
    let header_at = out.len();
    let bag_header = |index_pos: u64, chunks: u32| {
        let mut h = Vec::new();
        let fields: [(&str, &[u8]); 4] = [
            ("op", &[0x03]),
            ("index_pos", &index_pos.to_le_bytes()),
            ("conn_count", &1u32.to_le_bytes()),
            ("chunk_count", &chunks.to_le_bytes()),
        ];
        record(&fields, &[], &mut h);
        let pad = 4096 - h.len();
        h.clear();
        record(&fields, &vec![b' '; pad], &mut h);
        h
    };
    out.extend_from_slice(&bag_header(0, 0));
    let mut connection = Vec::new();
    let mut conn_data = Vec::new();
    for (name, value) in [
        ("topic", &b"/imu/data"[..]),
        ("type", b"sensor_msgs/Imu"),
        ("md5sum", b"6a62c6daae103f4ff57a132d6f95cec2"),
        ("message_definition", b""),
    ] {
        let mut f = ((name.len() + 1 + value.len()) as u32)
            .to_le_bytes()
            .to_vec();
        f.extend_from_slice(name.as_bytes());
        f.push(b'=');
        f.extend_from_slice(value);
        conn_data.extend_from_slice(&f);
    }
    record(
        &[
            ("op", &[0x07]),
            ("conn", &0u32.to_le_bytes()),
            ("topic", b"/imu/data"),
        ],
        &conn_data,
        &mut connection,
    );
    let mut infos = Vec::new();
    let mut chunks = 0u32;
    let mut imu = source();
    let mut inner = connection.clone();
    let mut pos = out.len() as u64;
    file.write_all(&out).unwrap();
    let (mut first_t, mut count) = (0i64, 0u32);
    let mut last_t: i64;
    for i in 0..MESSAGES {
        let m = imu.next(i);
        let t = log_ns(&m, i);
        if count == 0 {
            first_t = t;
        }
        last_t = t;
        count += 1;
        record(
            &[
                ("op", &[0x02]),
                ("conn", &0u32.to_le_bytes()),
                ("time", &ros_time(t)),
            ],
            &ros1_bytes(&m),
            &mut inner,
        );
        if inner.len() >= 768 << 10 || i + 1 == MESSAGES {
            let mut e = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
            e.write_all(&inner).unwrap();
            let (compressed, result) = e.finish();
            result.unwrap();
            let mut chunk = Vec::new();
            record(
                &[
                    ("op", &[0x05]),
                    ("compression", b"lz4"),
                    ("size", &(inner.len() as u32).to_le_bytes()),
                ],
                &compressed,
                &mut chunk,
            );
            let mut data = 0u32.to_le_bytes().to_vec();
            data.extend_from_slice(&count.to_le_bytes());
            record(
                &[
                    ("op", &[0x06]),
                    ("ver", &1u32.to_le_bytes()),
                    ("chunk_pos", &pos.to_le_bytes()),
                    ("start_time", &ros_time(first_t)),
                    ("end_time", &ros_time(last_t)),
                    ("count", &1u32.to_le_bytes()),
                ],
                &data,
                &mut infos,
            );
            file.write_all(&chunk).unwrap();
            pos += chunk.len() as u64;
            chunks += 1;
            count = 0;
            inner.clear();
        }
    }
    let index_pos = pos;
    file.write_all(&connection).unwrap();
    file.write_all(&infos).unwrap();
    let mut file = file.into_inner().unwrap();
    use std::io::Seek;
    file.seek(std::io::SeekFrom::Start(header_at as u64))
        .unwrap();
    file.write_all(&bag_header(index_pos, chunks)).unwrap();
}

/// Runs `imulab allan` on `bag` under GNU time: (wall s, CPU s, peak RSS MB, output).
fn analyse(bag: &Path) -> (f64, f64, f64, String) {
    let t = Instant::now();
    let output = std::process::Command::new("/usr/bin/time")
        .args(["-f", "peak-rss-kib %M cpu %U %S"])
        .arg(env!("CARGO_BIN_EXE_imulab"))
        .arg("allan")
        .arg(bag)
        .args(["--topic", "/imu/data", "--kind", "oadev", "--fit"])
        .output()
        .expect("run imulab allan under /usr/bin/time");
    let wall = t.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "imulab allan failed: {stderr}");
    let fields: Vec<f64> = stderr
        .lines()
        .rev()
        .find_map(|l| l.strip_prefix("peak-rss-kib "))
        .map(|l| {
            l.split_whitespace()
                .filter_map(|v| v.parse().ok())
                .collect()
        })
        .unwrap_or_default();
    let [kib, user, system] = fields[..] else {
        panic!("no GNU time line in: {stderr}");
    };
    (wall, user + system, kib * 1024.0 / 1e6, stdout)
}

fn main() {
    let only: Option<String> = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/bag-bench");
    std::fs::create_dir_all(&dir).unwrap();
    println!(
        "8 h x 200 Hz sensor_msgs/Imu = {MESSAGES} messages; allan_variance_ros: {PEER_S} s for {} M samples ({:.0} s scaled to {:.2} M)",
        PEER_SAMPLES / 1e6,
        PEER_S * MESSAGES as f64 / PEER_SAMPLES,
        MESSAGES as f64 / 1e6
    );
    println!("| bag | size [MB] | wall [s] | CPU [s] | peak RSS [MB] | allan_variance_ros scaled [s] | ratio |");
    println!("|---|---|---|---|---|---|---|");
    let mut measured = Vec::new();
    type WriteBag = fn(&Path);
    let formats: [(&str, &str, WriteBag); 2] = [
        ("mcap", "imu-8h-200hz.mcap", write_mcap),
        ("ros1", "imu-8h-200hz.bag", write_ros1),
    ];
    for (name, file, write) in formats {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let path = dir.join(file);
        if !path.exists() {
            let t = Instant::now();
            let tmp = dir.join(format!("{file}.tmp"));
            write(&tmp);
            std::fs::rename(&tmp, &path).unwrap();
            eprintln!(
                "wrote {} in {:.1} s",
                path.display(),
                t.elapsed().as_secs_f64()
            );
        }
        let size = std::fs::metadata(&path).unwrap().len() as f64 / 1e6;
        let (wall, cpu, rss, stdout) = analyse(&path);
        let samples = format!("{MESSAGES} samples");
        assert!(stdout.contains(&samples), "expected {samples}: {stdout}");
        let peer = PEER_S * MESSAGES as f64 / PEER_SAMPLES;
        println!(
            "| {name} ({file}) | {size:.0} | {wall:.2} | {cpu:.2} | {rss:.0} | {peer:.0} | {:.4} |",
            wall / peer
        );
        measured.push((name, size, wall, cpu, rss));
    }
    write_results(&measured, only.is_none());
}

/// The ROS bag row (both formats, so only a run of both writes it).
fn write_results(measured: &[(&str, f64, f64, f64, f64)], both: bool) {
    use serde_json::json;
    let peer = PEER_S * MESSAGES as f64 / PEER_SAMPLES;
    let walls: Vec<f64> = measured.iter().map(|m| m.2).collect();
    let (lo, hi) = results::min_max(&walls);
    let row = results::Row::new("allan-bag", results::ALLAN, 5, "ROS bag", "docs/import.md")
        .data(format!(
            "8 h × 200 Hz, {:.2} M messages, load {:.1}",
            MESSAGES as f64 / 1e6,
            results::load_average()
        ))
        .ours(format!(
            "MCAP {:.2} s, ROS 1 {:.2} s",
            walls.first().copied().unwrap_or(f64::NAN),
            walls.get(1).copied().unwrap_or(f64::NAN)
        ))
        .peer(format!("allan_variance_ros (published): {peer:.0} s"))
        .ratio(format!("{:.0}-{:.0}× faster", peer / hi, peer / lo))
        .target("< 5 s")
        .met(hi < 5.0)
        .timed()
        .command("cargo bench --bench bag");
    results::write(
        "bag",
        if both { "both" } else { "one" },
        json!({ "messages": MESSAGES, "peer_published_s": PEER_S, "peer_samples": PEER_SAMPLES }),
        json!({ "bags": measured.iter().map(|m| json!({
            "format": m.0, "size_mb": m.1, "wall_s": m.2, "cpu_s": m.3, "peak_rss_mb": m.4,
        })).collect::<Vec<_>>() }),
        if both {
            std::slice::from_ref(&row)
        } else {
            &[]
        },
    );
}
