//! ROS bags and MCAP files: `imulab import` writes each message type into a session exactly,
//! `imulab allan BAG --topic` and `imulab allan SESSION` agree with the same samples from a
//! CSV file, a truncated bag keeps the messages before the cut, an unknown type is skipped
//! and counted, a missing topic lists those that exist, and bags written by the `rosbags`
//! Python package (the ROS tooling without ROS) read the same.

mod rosbags;
mod support;

use imulab::store::{Session, TimeRange};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::process::{Command, Output};
use support::{mcap_chunks, write_mcap, write_mcap_compressed, write_ros1, Message, Topic, Value};

const T0_NS: i64 = 1_700_000_000_000_000_000;

fn imulab(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(args)
        .output()
        .unwrap()
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn topics() -> Vec<Topic> {
    vec![
        Topic {
            name: "/imu/data",
            type_name: "sensor_msgs/msg/Imu",
        },
        Topic {
            name: "/imu/temperature",
            type_name: "sensor_msgs/msg/Temperature",
        },
        Topic {
            name: "/gps/fix",
            type_name: "sensor_msgs/msg/NavSatFix",
        },
        Topic {
            name: "/gps/vel",
            type_name: "geometry_msgs/msg/TwistStamped",
        },
        Topic {
            name: "/tf",
            type_name: "tf2_msgs/msg/TFMessage",
        },
    ]
}

/// `n` IMU messages at 100 Hz (white noise; header stamps 2 ms before receipt), a
/// temperature at 1 Hz before each second's first IMU message, a fix and its velocity at
/// 1 Hz, and a `/tf` message of a type imulab does not read every 50 IMU messages.
fn messages(n: usize) -> Vec<Message> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(23);
    let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
    let mut out = Vec::new();
    for i in 0..n {
        let log_ns = T0_NS + i as i64 * 10_000_000 + 3_000;
        let stamp_ns = log_ns - 2_000_000;
        if i % 100 == 0 {
            out.push(Message {
                topic: 1,
                log_ns,
                value: Value::Temperature {
                    stamp_ns,
                    celsius: 20.0 + (i / 100) as f64 * 0.5,
                },
            });
        }
        out.push(Message {
            topic: 0,
            log_ns,
            value: Value::Imu {
                stamp_ns,
                gyro: [1e-3 * g(), 1e-3 * g(), 1e-3 * g() + 1e-4],
                accel: [0.02 * g(), 0.02 * g(), 9.80665 + 0.02 * g()],
            },
        });
        if i % 100 == 50 {
            let k = (i / 100) as f64;
            out.push(Message {
                topic: 2,
                log_ns,
                value: Value::Fix {
                    stamp_ns,
                    status: 0,
                    lat: 48.1 + k * 1e-5,
                    lon: 11.5 - k * 1e-5,
                    alt: 520.0 + k,
                    h_var: 1.44,
                    v_var: 4.0,
                },
            });
            out.push(Message {
                topic: 3,
                log_ns: log_ns + 1_000,
                value: Value::Twist {
                    stamp_ns,
                    linear: [1.0 + k, 2.0, 0.5],
                },
            });
        }
        if i % 50 == 25 {
            out.push(Message {
                topic: 4,
                log_ns,
                value: Value::Other(vec![0, 1, 0, 0, 9, 9, 9, 9]),
            });
        }
    }
    out
}

fn imu_values(messages: &[Message]) -> Vec<(i64, i64, [f64; 3], [f64; 3])> {
    messages
        .iter()
        .filter_map(|m| match m.value {
            Value::Imu {
                stamp_ns,
                gyro,
                accel,
            } => Some((m.log_ns, stamp_ns, gyro, accel)),
            _ => None,
        })
        .collect()
}

/// Imports `bag` and checks every row of the session against `messages`.
fn check_import(bag: &Path, messages: &[Message], session: &Path) {
    let out = imulab(&[
        "import",
        bag.to_str().unwrap(),
        "-o",
        session.to_str().unwrap(),
    ]);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains("/tf") && said.contains("skipped: type not read"),
        "{said}"
    );
    let tf = messages.iter().filter(|m| m.topic == 4).count();
    assert!(
        said.contains(&format!("skipped {tf} messages on 1 topic(s)")),
        "{said}"
    );
    let s = Session::open(session).unwrap();
    let names: Vec<&str> = s.devices().iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, ["imu_data", "gps_fix"]);
    let imu = s.manifest().device("imu_data").unwrap();
    assert!((imu.rate_hz - 100.0).abs() < 1e-6, "{}", imu.rate_hz);
    assert_eq!(imu.port, "/imu/data");
    let rows: Vec<_> = s
        .imu_blocks("imu_data", TimeRange::all(), 4096)
        .unwrap()
        .flat_map(|b| {
            let b = b.unwrap();
            (0..b.len()).map(move |i| b.record(i)).collect::<Vec<_>>()
        })
        .collect();
    let want = imu_values(messages);
    assert_eq!(rows.len(), want.len());
    for (i, (r, (log, stamp, gyro, accel))) in rows.iter().zip(&want).enumerate() {
        assert_eq!(r.t_mono_ns, *log, "row {i}");
        assert_eq!(r.t_wall_ns, *log, "row {i}");
        assert!((r.t_sensor - *stamp as f64 * 1e-9).abs() < 1e-6, "row {i}");
        assert_eq!(r.gyro, *gyro, "row {i}");
        assert_eq!(r.accel, *accel, "row {i}");
        // The temperature published at the start of each second, held.
        assert_eq!(r.temp, 20.0 + (i / 100) as f64 * 0.5, "row {i}");
    }
    let fixes: Vec<_> = s
        .gnss_blocks("gps_fix", TimeRange::all(), 4096)
        .unwrap()
        .flat_map(|b| {
            let b = b.unwrap();
            (0..b.len()).map(move |i| b.record(i)).collect::<Vec<_>>()
        })
        .collect();
    let want: Vec<&Message> = messages.iter().filter(|m| m.topic == 2).collect();
    assert_eq!(fixes.len(), want.len());
    for (k, (r, m)) in fixes.iter().zip(want).enumerate() {
        let Value::Fix {
            stamp_ns,
            lat,
            lon,
            alt,
            ..
        } = m.value
        else {
            unreachable!()
        };
        assert_eq!(r.t_mono_ns, m.log_ns);
        assert_eq!(r.utc_ns, stamp_ns);
        assert_eq!((r.lat_deg, r.lon_deg, r.height_m), (lat, lon, alt));
        assert!((r.h_acc_m - 1.2).abs() < 1e-12 && (r.v_acc_m - 2.0).abs() < 1e-12);
        assert_eq!(r.fix_type, imulab_drivers::types::FixType::Fix3D);
        // ENU (east 1 + k, north 2, up 0.5) as NED.
        assert_eq!(r.vel_ned, [2.0, 1.0 + k as f64, -0.5], "fix {k}");
    }
}

#[test]
fn mcap_import_keeps_every_message_type() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("run.mcap");
    let messages = messages(1_000);
    write_mcap(&bag, &topics(), &messages, 16 << 10);
    check_import(&bag, &messages, &dir.path().join("session"));
}

#[test]
fn ros1_import_keeps_every_message_type_for_each_compression() {
    for compression in ["none", "bz2", "lz4"] {
        let dir = tempfile::tempdir().unwrap();
        let bag = dir.path().join("run.bag");
        let messages = messages(1_000);
        write_ros1(&bag, &topics(), &messages, compression, 300);
        check_import(&bag, &messages, &dir.path().join("session"));
    }
}

/// The deviations of every axis of an `imulab allan --json` document.
fn deviations(json: &Path) -> Vec<(String, Vec<(f64, f64)>)> {
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    doc["axes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| {
            let points = a["curve"]["points"]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| (p["tau"].as_f64().unwrap(), p["deviation"].as_f64().unwrap()))
                .collect();
            (a["axis"].as_str().unwrap().to_string(), points)
        })
        .collect()
}

fn assert_same_curves(a: &[(String, Vec<(f64, f64)>)], b: &[(String, Vec<(f64, f64)>)]) {
    assert_eq!(a.len(), 6);
    assert_eq!(a.len(), b.len());
    for ((name_a, pa), (name_b, pb)) in a.iter().zip(b) {
        assert!(
            name_b.ends_with(&name_a[name_a.len() - 1..]),
            "{name_a} {name_b}"
        );
        assert_eq!(pa.len(), pb.len(), "{name_a}");
        for ((ta, da), (tb, db)) in pa.iter().zip(pb) {
            assert!((ta / tb - 1.0).abs() < 1e-6, "{name_a}: tau {ta} {tb}");
            assert!(
                (da / db - 1.0).abs() < 1e-6,
                "{name_a}: tau {ta}: {da} vs {db}"
            );
        }
    }
}

#[test]
fn allan_on_bag_and_imported_session_agree_with_csv() {
    let dir = tempfile::tempdir().unwrap();
    let messages = messages(30_000);
    let csv = dir.path().join("imu.csv");
    let mut text_rows = String::from("t,gx,gy,gz,ax,ay,az\n");
    for (_, stamp, g, a) in imu_values(&messages) {
        text_rows.push_str(&format!(
            "{:.9},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            (stamp - T0_NS) as f64 * 1e-9,
            g[0],
            g[1],
            g[2],
            a[0],
            a[1],
            a[2]
        ));
    }
    std::fs::write(&csv, text_rows).unwrap();
    let run = |input: &Path, extra: &[&str], json: &Path| {
        let mut args = vec!["allan", input.to_str().unwrap(), "--fit", "--json"];
        args.push(json.to_str().unwrap());
        args.extend_from_slice(extra);
        let out = imulab(&args);
        assert!(out.status.success(), "{}", text(&out));
        text(&out)
    };
    let from_csv = dir.path().join("csv.json");
    run(
        &csv,
        &["--columns", "gx,gy,gz=rad/s ax,ay,az=m/s2"],
        &from_csv,
    );
    let reference = deviations(&from_csv);
    for (bag, write) in [("run.mcap", true), ("run.bag", false)] {
        let path = dir.path().join(bag);
        if write {
            write_mcap(&path, &topics(), &messages, 256 << 10);
        } else {
            write_ros1(&path, &topics(), &messages, "lz4", 2_000);
        }
        let json = dir.path().join(format!("{bag}.json"));
        let said = run(&path, &["--topic", "/imu/data"], &json);
        assert!(said.contains("header stamps"), "{said}");
        assert_same_curves(&reference, &deviations(&json));
        let session = dir.path().join(format!("{bag}.session"));
        let out = imulab(&[
            "import",
            path.to_str().unwrap(),
            "-o",
            session.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out));
        let json = dir.path().join(format!("{bag}.session.json"));
        run(&session, &[], &json);
        assert_same_curves(&reference, &deviations(&json));
    }
}

#[test]
fn truncated_bags_keep_the_messages_before_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let messages = messages(20_000);
    let total = imu_values(&messages).len() as u64;
    for bag in ["cut.mcap", "cut.bag"] {
        let path = dir.path().join(bag);
        if bag.ends_with("mcap") {
            write_mcap(&path, &topics(), &messages, 32 << 10);
        } else {
            write_ros1(&path, &topics(), &messages, "bz2", 500);
        }
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() * 6 / 10]).unwrap();
        let session = dir.path().join(format!("{bag}.session"));
        let out = imulab(&[
            "import",
            path.to_str().unwrap(),
            "-o",
            session.to_str().unwrap(),
        ]);
        let said = text(&out);
        assert!(out.status.success(), "{said}");
        assert!(
            said.contains("the bag ends early") && said.contains("truncated"),
            "{said}"
        );
        let s = Session::open(&session).unwrap();
        let rows = s.stream_summary("/imu/imu_data").rows;
        // Everything but the chunk the cut fell in: about 60 % of the rows, give or take
        // how well each chunk compressed.
        assert!(
            rows > total / 2 && rows < total * 7 / 10,
            "{rows} of {total}"
        );
        let (events, _) = s.events();
        assert!(
            events
                .iter()
                .any(|e| e.detail.contains("the bag ends early")),
            "{events:?}"
        );
        let out = imulab(&["allan", path.to_str().unwrap(), "--topic", "/imu/data"]);
        let said = text(&out);
        assert!(out.status.success(), "{said}");
        assert!(
            said.contains(&format!("{rows} messages of the topic before it")),
            "{said}"
        );
    }
}

#[test]
fn a_damaged_mcap_chunk_keeps_the_messages_of_the_chunks_before_it() {
    let dir = tempfile::tempdir().unwrap();
    let messages = messages(6_000);
    // zstd and lz4 chunks with a byte of the compressed data flipped, and stored chunks with
    // a byte of the last message's data flipped, which only the chunk's CRC-32 shows.
    for (name, compression) in [
        ("zstd", Some(mcap::Compression::Zstd)),
        ("lz4", Some(mcap::Compression::Lz4)),
        ("stored", None),
    ] {
        let path = dir.path().join(format!("{name}.mcap"));
        write_mcap_compressed(&path, &topics(), &messages, 16 << 10, compression);
        let mut bytes = std::fs::read(&path).unwrap();
        let chunks = mcap_chunks(&bytes);
        assert!(chunks.len() >= 6, "{name}: {} chunks", chunks.len());
        let (at, len) = chunks[3];
        let flip = if compression.is_some() {
            at + 9 + len / 2
        } else {
            at + 9 + len - 1
        };
        bytes[flip] ^= 0x5a;
        std::fs::write(&path, &bytes).unwrap();
        // The messages of chunks 1-3: those logged up to the third chunk's end time.
        let (third, _) = chunks[2];
        let end_ns = u64::from_le_bytes(bytes[third + 17..third + 25].try_into().unwrap());
        let before = messages
            .iter()
            .filter(|m| m.log_ns as u64 <= end_ns)
            .count() as u64;
        let imu_before = imu_values(&messages)
            .iter()
            .filter(|v| v.0 as u64 <= end_ns)
            .count() as u64;

        let bag = imulab::bag::Bag::open(&path).unwrap();
        let mut seen = 0u64;
        let end = bag
            .read::<imulab::bag::BagError>(&mut |_| {
                seen += 1;
                Ok(())
            })
            .unwrap();
        assert_eq!(
            (end.messages, seen),
            (before, before),
            "{name}: {:?}",
            end.cut
        );
        let cut = end.cut.unwrap_or_default();
        assert!(
            cut.contains(&format!("chunk 4 (at byte {at}) is damaged")),
            "{name}: {cut}"
        );
        if compression.is_none() {
            assert!(cut.contains("CRC-32"), "{name}: {cut}");
        }

        let session = dir.path().join(format!("{name}.session"));
        let out = imulab(&[
            "import",
            path.to_str().unwrap(),
            "-o",
            session.to_str().unwrap(),
        ]);
        let said = text(&out);
        assert!(out.status.success(), "{said}");
        assert!(said.contains(&format!("chunk 4 (at byte {at})")), "{said}");
        let rows = Session::open(&session)
            .unwrap()
            .stream_summary("/imu/imu_data")
            .rows;
        assert_eq!(rows, imu_before, "{name}");
    }
}

#[test]
fn missing_and_wrong_topics_list_the_topics_there_are() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    write_mcap(&path, &topics(), &messages(200), 1 << 20);
    let bag = path.to_str().unwrap();
    let out = imulab(&["allan", bag, "--topic", "/imu/raw"]);
    let said = text(&out);
    assert!(!out.status.success());
    assert!(said.contains("no topic `/imu/raw`"), "{said}");
    for line in [
        "/imu/data         sensor_msgs/msg/Imu",
        "/tf               tf2_msgs/msg/TFMessage",
    ] {
        assert!(said.contains(line), "{line}: {said}");
    }
    assert!(said.contains("      200 messages"), "{said}");
    assert!(said.contains("(type not read)"), "{said}");
    let out = imulab(&["allan", bag, "--topic", "/gps/fix"]);
    assert!(text(&out).contains("is sensor_msgs/msg/NavSatFix, not sensor_msgs/Imu"));
    let out = imulab(&[
        "import",
        bag,
        "-o",
        dir.path().join("s").to_str().unwrap(),
        "--topic",
        "/nope",
    ]);
    assert!(!out.status.success());
    assert!(text(&out).contains("no topic `/nope`"), "{}", text(&out));
    // Without --topic the only IMU topic is taken.
    let out = imulab(&["allan", bag]);
    assert!(out.status.success(), "{}", text(&out));
}

#[test]
fn undecodable_messages_are_skipped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let mut messages = messages(300);
    // Three IMU messages cut short.
    let mut bad = 0;
    for m in messages
        .iter_mut()
        .filter(|m| m.topic == 0)
        .skip(10)
        .step_by(50)
    {
        let full = support::cdr_bytes(&m.value);
        m.value = Value::Other(full[..40].to_vec());
        bad += 1;
    }
    let path = dir.path().join("bad.mcap");
    write_mcap(&path, &topics(), &messages, 1 << 20);
    let session = dir.path().join("s");
    let out = imulab(&[
        "import",
        path.to_str().unwrap(),
        "-o",
        session.to_str().unwrap(),
    ]);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains(&format!("{bad} message(s) did not decode and were skipped")),
        "{said}"
    );
    let rows = Session::open(&session)
        .unwrap()
        .stream_summary("/imu/imu_data")
        .rows;
    assert_eq!(rows, 300 - bad);
}

#[test]
fn sqlite_bags_are_refused_with_the_conversion() {
    let dir = tempfile::tempdir().unwrap();
    let bag_dir = dir.path().join("rosbag2_run");
    std::fs::create_dir(&bag_dir).unwrap();
    std::fs::write(
        bag_dir.join("metadata.yaml"),
        "rosbag2_bagfile_information: {}\n",
    )
    .unwrap();
    let mut db = b"SQLite format 3\0".to_vec();
    db.resize(4096, 0);
    std::fs::write(bag_dir.join("rosbag2_run_0.db3"), &db).unwrap();
    for input in [bag_dir.clone(), bag_dir.join("rosbag2_run_0.db3")] {
        let out = imulab(&["allan", input.to_str().unwrap()]);
        let said = text(&out);
        assert!(!out.status.success());
        assert!(
            said.contains("sqlite3") && said.contains("ros2 bag convert"),
            "{said}"
        );
    }
}
