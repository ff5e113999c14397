//! `imulab::sim::serve`: every served protocol read back from its pty with the drivers'
//! decoders equals what the server says it sent, in order, nothing missing; the sent
//! values match the simulated records within each protocol's resolution; pacing follows
//! the speed factor (loosely: the machine is shared); the stable symlink survives a pty
//! reopen; garbage is skipped by the decoders without losing a frame.

use std::fs::File;
use std::io::{ErrorKind, Read};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use imulab::sim::scene::Scene;
use imulab::sim::serve::{
    Fault, FaultKind, Sent, SentGnss, SentImu, ServeOptions, Server, Speed, StartWhen,
};
use imulab::sim::wire::ImuWire;
use imulab_drivers::codec::gnss::{EpochFix, GnssDecoder, GnssFrame};
use imulab_drivers::codec::{Decoder, Protocol};
use imulab_drivers::types::{DecoderStats, ImuSample};

/// Every protocol: four IMUs (one gyro-only), three receivers, a drive with an outage.
const ALL_PROTOCOLS: &str = r#"
duration_s = 4
rate_hz = 50
seed = 9
[location]
lat_deg = -33.9
lon_deg = -70.6
height_m = 600.0
[motion]
kind = "segments"
heading_deg = 200.0
speed_mps = 8.0
segments = [ { kind = "turn", angle_deg = 45, duration_s = 2 }, { kind = "cruise", duration_s = 3 } ]
[[imu]]
name = "wit"
preset = "bench-cheap"
[[imu]]
name = "mti"
preset = "industrial"
protocol = "xbus"
[[imu]]
name = "line"
preset = "consumer"
protocol = "csv"
channels = ["gyro"]
[[imu]]
name = "can"
preset = "tactical"
protocol = "slcan"
[[imu]]
name = "vn"
preset = "industrial"
protocol = "vectornav"
[[imu]]
name = "gx5"
preset = "industrial"
protocol = "mip"
[[gnss]]
name = "ublox"
preset = "standalone"
rate_hz = 10
outages = [ { start_s = 1.0, duration_s = 0.5 } ]
[[gnss]]
name = "nmea_only"
preset = "rtk"
rate_hz = 5
protocol = "nmea"
[[gnss]]
name = "ubx_only"
preset = "sbas"
rate_hz = 5
protocol = "ubx"
"#;

fn scene(text: &str) -> Scene {
    Scene::parse(text, Path::new(".")).unwrap_or_else(|e| panic!("{e:#}"))
}

/// Opens a pty slave the way a serial reader does (no controlling tty), non-blocking.
fn open_reader(path: &Path) -> std::io::Result<File> {
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
        .open(path)
}

/// Reads what is there; `Err` when the pty hung up (EIO).
fn read_available(file: &mut File, into: &mut Vec<u8>) -> Result<usize, ()> {
    let mut buf = [0u8; 4096];
    let mut total = 0;
    loop {
        match file.read(&mut buf) {
            Ok(0) => return Err(()),
            Ok(n) => {
                into.extend_from_slice(&buf[..n]);
                total += n;
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(total),
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => return Err(()),
        }
    }
}

/// Attaches a reader to every endpoint, serves, and returns the bytes each reader got.
fn serve_and_read(server: &mut Server) -> (imulab::sim::serve::ServeReport, Vec<Vec<u8>>) {
    let mut readers: Vec<File> = server
        .endpoints()
        .iter()
        .map(|e| open_reader(e.path()).unwrap_or_else(|err| panic!("{}: {err}", e.sensor)))
        .collect();
    let mut got = vec![Vec::new(); readers.len()];
    let deadline = Instant::now() + Duration::from_secs(60);
    while !server.is_finished() {
        for (r, g) in readers.iter_mut().zip(&mut got) {
            let _ = read_available(r, g);
        }
        std::thread::sleep(Duration::from_millis(5));
        assert!(Instant::now() < deadline, "serve did not finish");
    }
    let report = server.finish().unwrap_or_else(|e| panic!("{e:#}"));
    // The ptys stay open until the server is dropped: take the rest.
    let mut quiet_rounds = 0;
    while quiet_rounds < 3 {
        let mut n = 0;
        for (r, g) in readers.iter_mut().zip(&mut got) {
            n += read_available(r, g).unwrap_or(0);
        }
        quiet_rounds = if n == 0 { quiet_rounds + 1 } else { 0 };
        std::thread::sleep(Duration::from_millis(20));
    }
    (report, got)
}

fn decode_imu(wire: &ImuWire, bytes: &[u8]) -> (Vec<ImuSample>, DecoderStats) {
    let mut d = wire.stream_decoder();
    let mut out = d.push(bytes);
    out.extend(d.finish_one());
    (out, d.stats())
}

fn decode_gnss(bytes: &[u8]) -> (Vec<EpochFix>, DecoderStats) {
    let mut d = GnssDecoder::new();
    let mut out = Vec::new();
    d.decode(bytes, |f| {
        if let GnssFrame::Fix(fix) = f {
            out.push(fix)
        }
    });
    while let Some(f) = d.finish() {
        if let GnssFrame::Fix(fix) = f {
            out.push(fix)
        }
    }
    (out, d.stats())
}

fn imu_frames(sent: &Sent) -> &[SentImu] {
    match sent {
        Sent::Imu(v) => v,
        Sent::Gnss(_) => panic!("expected IMU frames"),
    }
}

fn gnss_frames(sent: &Sent) -> &[SentGnss] {
    match sent {
        Sent::Gnss(v) => v,
        Sent::Imu(_) => panic!("expected GNSS frames"),
    }
}

/// Largest difference between sent value and simulated record a protocol may introduce:
/// (gyro rad/s, accel m/s²).
fn resolution(protocol: Protocol) -> (f64, f64) {
    match protocol {
        // Half a count of ±2000 °/s and ±16 g over 16 bits.
        Protocol::Wit => (
            0.5 * (2000f64 / 32768.0).to_radians(),
            0.5 * 16.0 * 9.80665 / 32768.0,
        ),
        // float32 (MIP: acceleration in g).
        Protocol::Xbus | Protocol::Vectornav | Protocol::Mip => (1e-6, 1e-5),
        // Shortest round-trip text: exact.
        Protocol::Csv => (0.0, 0.0),
        // Half of 0.01 °/s and 0.0005 g (fixtures/imu_can.dbc).
        Protocol::Slcan => (
            0.5 * 0.01f64.to_radians() * 1.0001,
            0.5 * 0.0005 * 9.80665 * 1.0001,
        ),
        other => panic!("not an IMU protocol: {other:?}"),
    }
}

fn max_abs_diff(a: [f64; 3], b: [f64; 3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn every_protocol_read_back_from_its_pty_equals_what_was_sent() {
    let scene = scene(ALL_PROTOCOLS);
    let wires: Vec<ImuWire> = scene
        .imus
        .iter()
        .map(|i| ImuWire::new(i.protocol, i.channels, scene.rate_hz).unwrap())
        .collect();
    let mut server = Server::start(
        scene.clone(),
        ServeOptions {
            speed: Speed::Max,
            start: StartWhen::ReadersAttached,
            ..ServeOptions::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    let protocols: Vec<&str> = server
        .endpoints()
        .iter()
        .map(|e| e.protocol.name())
        .collect();
    assert_eq!(
        protocols,
        [
            "wit",
            "xbus",
            "csv",
            "slcan",
            "vectornav",
            "mip",
            "gnss",
            "nmea",
            "ubx"
        ]
    );
    let (report, got) = serve_and_read(&mut server);
    assert!(!report.stopped);
    assert_eq!(report.undelivered_bytes, 0);
    for (i, (stream, bytes)) in report.streams.iter().zip(&got).enumerate() {
        assert_eq!(
            stream.encode_errors, 0,
            "{}: {:?}",
            stream.sensor, stream.first_encode_error
        );
        assert_eq!(
            stream.bytes,
            bytes.len() as u64,
            "{}: bytes read",
            stream.sensor
        );
        if i < wires.len() {
            let sent = imu_frames(&stream.sent);
            assert_eq!(sent.len() as u64, stream.frames);
            // Dropped samples aside, 4 s at 50 Hz.
            assert!(
                sent.len() >= 190,
                "{}: {} frames",
                stream.sensor,
                sent.len()
            );
            let (decoded, stats) = decode_imu(&wires[i], bytes);
            let expected: Vec<ImuSample> = sent.iter().filter_map(|s| s.sample).collect();
            assert_eq!(
                expected.len(),
                sent.len(),
                "{}: every frame decodes",
                stream.sensor
            );
            assert_eq!(decoded, expected, "{}: stream decode", stream.sensor);
            assert_eq!(stats.checksum_errors + stats.bytes_skipped, 0, "{stats:?}");
            let (gyro_tol, accel_tol) = resolution(stream.protocol);
            for s in sent {
                let sample = s.sample.unwrap();
                let g = sample.gyro.expect("gyro sent");
                assert!(
                    max_abs_diff(g, s.record.gyro) <= gyro_tol,
                    "{}: {g:?} vs {:?}",
                    stream.sensor,
                    s.record.gyro
                );
                match sample.accel {
                    Some(a) => assert!(
                        max_abs_diff(a, s.record.accel) <= accel_tol,
                        "{}: {a:?} vs {:?}",
                        stream.sensor,
                        s.record.accel
                    ),
                    None => assert!(
                        s.record.accel[0].is_nan(),
                        "{}: accel missing",
                        stream.sensor
                    ),
                }
                // The MIP IMU data set has no temperature field.
                let Some(temp) = sample.temp_c else {
                    assert_eq!(
                        stream.protocol,
                        Protocol::Mip,
                        "{}: temperature",
                        stream.sensor
                    );
                    continue;
                };
                let float32 = matches!(stream.protocol, Protocol::Xbus | Protocol::Vectornav);
                assert!(
                    (temp - s.record.temp).abs() <= 0.005 + 1e-6
                        || float32 && (temp - s.record.temp).abs() < 1e-4
                );
            }
            // Frames go out in time order.
            assert!(sent.windows(2).all(|w| w[0].t_ns < w[1].t_ns));
            // The rows a reader stores for them: decoded values, simulated host times.
            let rows = stream.expected_imu_rows();
            assert_eq!(rows.len(), sent.len());
            for (row, s) in rows.iter().zip(sent) {
                let sample = s.sample.unwrap();
                assert_eq!(row.t_mono_ns, s.record.t_mono_ns);
                assert_eq!(Some(row.gyro), sample.gyro);
                assert_eq!(row.t_sensor, sample.sensor_time.unwrap());
            }
        } else {
            let sent = gnss_frames(&stream.sent);
            assert!(sent.len() >= 20, "{}: {} epochs", stream.sensor, sent.len());
            let (decoded, stats) = decode_gnss(bytes);
            let expected: Vec<EpochFix> = sent.iter().flat_map(|s| s.fixes.clone()).collect();
            // One merged fix per epoch, the mixed protocol's UBX and NMEA messages included.
            assert_eq!(expected.len(), sent.len(), "{}", stream.sensor);
            assert_eq!(decoded, expected, "{}: stream decode", stream.sensor);
            assert_eq!(stats.checksum_errors + stats.bytes_skipped, 0, "{stats:?}");
            for s in sent {
                let fixed = !s.record.lat_deg.is_nan();
                for f in &s.fixes {
                    assert_eq!(
                        f.fix.fix == imulab_drivers::types::FixType::NoFix,
                        !fixed,
                        "{}: {f:?}",
                        stream.sensor
                    );
                    if fixed {
                        // 1e-7° in UBX, 1e-7 minute in NMEA.
                        assert!((f.fix.lat_deg.unwrap() - s.record.lat_deg).abs() < 6e-8);
                        assert!((f.fix.lon_deg.unwrap() - s.record.lon_deg).abs() < 6e-8);
                        assert!((f.fix.height_m.unwrap() - s.record.height_m).abs() < 6e-4);
                        assert_eq!(f.fix.num_sats, Some(s.record.num_sats));
                        assert_eq!(f.fix.fix, s.record.fix_type);
                    }
                    assert_eq!(f.fix.utc_ns, Some(s.record.utc_ns), "{}", stream.sensor);
                }
            }
            let rows = stream.expected_gnss_rows();
            assert_eq!(rows.len(), expected.len());
            for (row, fix) in rows.iter().zip(&expected) {
                assert_eq!(row.fix_type, fix.fix.fix);
                assert_eq!(row.num_sats, fix.fix.num_sats.unwrap_or(0));
            }
            if stream.sensor == "ublox" {
                let no_fix = sent.iter().filter(|s| s.record.lat_deg.is_nan()).count();
                assert_eq!(no_fix, 5, "0.5 s outage at 10 Hz");
            }
        }
    }
}

const TWO_IMUS: &str = r#"
duration_s = 2
rate_hz = 100
seed = 4
[location]
lat_deg = 48.0
lon_deg = 11.0
height_m = 500.0
[motion]
kind = "static"
[[imu]]
name = "a"
preset = "bench-cheap"
[[imu]]
name = "b"
preset = "bench-dear"
protocol = "xbus"
"#;

#[test]
fn pacing_follows_the_speed_factor_on_one_clock() {
    let speed = 4.0;
    let mut server = Server::start(
        scene(TWO_IMUS),
        ServeOptions {
            speed: Speed::Factor(speed),
            start: StartWhen::ReadersAttached,
            ..ServeOptions::default()
        },
    )
    .unwrap();
    let (report, _) = serve_and_read(&mut server);
    // 2 s of scene at 4×: 0.5 s. Loose upper bound: the machine is shared.
    let elapsed = report.elapsed.as_secs_f64();
    assert!((0.49..3.0).contains(&elapsed), "elapsed {elapsed} s");
    let mut late = Vec::new();
    for stream in &report.streams {
        for s in imu_frames(&stream.sent) {
            let due_ns = s.t_ns as f64 / speed;
            // Never early (beyond timer granularity)...
            assert!(
                s.written_ns as f64 >= due_ns - 1e6,
                "{} written {} ns before due",
                stream.sensor,
                due_ns - s.written_ns as f64
            );
            late.push(s.written_ns as f64 - due_ns);
        }
    }
    // ...and mostly on time.
    late.sort_by(f64::total_cmp);
    let median = late[late.len() / 2];
    assert!(median < 50e6, "median lateness {} ms", median / 1e6);
}

#[test]
fn symlink_survives_a_reopen_and_garbage_is_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let faults = vec![
        Fault {
            sensor: "a".into(),
            at_s: 0.5,
            kind: FaultKind::Garbage,
            bytes: 200,
            down_s: 0.0,
        },
        Fault {
            sensor: "b".into(),
            at_s: 0.5,
            kind: FaultKind::Garbage,
            bytes: 200,
            down_s: 0.0,
        },
        Fault {
            sensor: "a".into(),
            at_s: 1.0,
            kind: FaultKind::Reopen,
            bytes: 0,
            down_s: 0.2,
        },
    ];
    let speed = 2.0;
    let mut server = Server::start(
        scene(TWO_IMUS),
        ServeOptions {
            speed: Speed::Factor(speed),
            link_dir: Some(dir.path().to_path_buf()),
            start: StartWhen::ReadersAttached,
            faults,
            ..ServeOptions::default()
        },
    )
    .unwrap();
    let link = dir.path().join("a");
    assert_eq!(server.endpoints()[0].link.as_deref(), Some(link.as_path()));
    let first_pty = std::fs::read_link(&link).unwrap();
    assert_eq!(first_pty, server.endpoints()[0].pty);
    let mut a = open_reader(&link).unwrap();
    let mut b = open_reader(&dir.path().join("b")).unwrap();
    // Bytes per connection of `a`.
    let mut a_got: Vec<Vec<u8>> = vec![Vec::new()];
    let mut b_got = Vec::new();
    let mut hangups = 0;
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut finished_rounds = 0;
    while finished_rounds < 3 {
        if server.is_finished() {
            finished_rounds += 1;
        }
        let _ = read_available(&mut b, &mut b_got);
        let last = a_got.len() - 1;
        if read_available(&mut a, &mut a_got[last]).is_err() {
            hangups += 1;
            // Unplugged: wait for the link to come back, then open it again.
            let reopened = loop {
                assert!(Instant::now() < deadline, "link never came back");
                if let Ok(f) = open_reader(&link) {
                    break f;
                }
                std::thread::sleep(Duration::from_millis(2));
            };
            a = reopened;
            a_got.push(Vec::new());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let report = server.finish().unwrap();
    let _ = read_available(&mut b, &mut b_got);
    let last = a_got.len() - 1;
    let _ = read_available(&mut a, &mut a_got[last]);
    assert_eq!(hangups, 1, "one reopen");
    let second_pty = std::fs::read_link(&link).unwrap();
    assert_eq!(Some(second_pty.clone()), server.current_pty(0));
    assert_ne!(
        second_pty, first_pty,
        "the reader still holds the old pty open"
    );

    let sc = scene(TWO_IMUS);
    let wire_a = ImuWire::new(Protocol::Wit, sc.imus[0].channels, sc.rate_hz).unwrap();
    let wire_b = ImuWire::new(Protocol::Xbus, sc.imus[1].channels, sc.rate_hz).unwrap();
    let sa = &report.streams[0];
    assert_eq!(sa.garbage_bytes, 200);
    assert_eq!(sa.faults.len(), 2);
    // 0.2 s unplugged at 100 Hz.
    assert!(
        (19..=21).contains(&sa.frames_unplugged),
        "{}",
        sa.frames_unplugged
    );
    let sent_a = imu_frames(&sa.sent);
    let gen0: Vec<ImuSample> = sent_a
        .iter()
        .filter(|s| s.generation == 0)
        .filter_map(|s| s.sample)
        .collect();
    let gen1: Vec<ImuSample> = sent_a
        .iter()
        .filter(|s| s.generation == 1)
        .filter_map(|s| s.sample)
        .collect();
    assert_eq!(gen0.len() + gen1.len(), sent_a.len());
    // Before the unplug: garbage skipped, nothing lost in between; what the reader had not
    // read yet when the pty closed is lost (a loaded machine lets it lag a few frames).
    let (before, stats) = decode_imu(&wire_a, &a_got[0]);
    assert!(stats.bytes_skipped > 0, "{stats:?}");
    assert!(
        2 * before.len() >= gen0.len() && before.len() <= gen0.len(),
        "{} of {}",
        before.len(),
        gen0.len()
    );
    assert_eq!(before[..], gen0[..before.len()]);
    // After: everything sent to the new pty.
    let (after, _) = decode_imu(&wire_a, &a_got[1]);
    assert_eq!(after, gen1);
    // The other stream was not disturbed by either fault, only by its own garbage.
    let (b_decoded, b_stats) = decode_imu(&wire_b, &b_got);
    assert!(b_stats.bytes_skipped > 0, "{b_stats:?}");
    let b_sent: Vec<ImuSample> = imu_frames(&report.streams[1].sent)
        .iter()
        .filter_map(|s| s.sample)
        .collect();
    assert_eq!(b_decoded, b_sent);
    drop(server);
    assert!(!link.exists(), "links are removed with the server");
}

#[test]
fn scene_protocol_and_fault_keys_are_checked() {
    let bad_protocol = TWO_IMUS.replace("protocol = \"xbus\"", "protocol = \"nmea\"");
    let e = format!(
        "{:#}",
        Scene::parse(&bad_protocol, Path::new(".")).unwrap_err()
    );
    assert!(
        e.contains("imu[1] (b)") && e.contains("cannot be served as `nmea`"),
        "{e}"
    );
    let unknown = TWO_IMUS.replace("protocol = \"xbus\"", "protocol = \"can\"");
    let e = format!("{:#}", Scene::parse(&unknown, Path::new(".")).unwrap_err());
    assert!(e.contains("unknown protocol `can`"), "{e}");
    let fault =
        format!("{TWO_IMUS}\n[[fault]]\nsensor = \"c\"\nat_s = 1\nkind = \"garbage\"\nbytes = 4\n");
    let e = format!("{:#}", Scene::parse(&fault, Path::new(".")).unwrap_err());
    assert!(
        e.contains("fault[0] (c)") && e.contains("not in the scene"),
        "{e}"
    );
    let fault = format!(
        "{TWO_IMUS}\n[[fault]]\nsensor = \"a\"\nat_s = 1\nkind = \"reopen\"\ndown_s = 0.5\n"
    );
    let s = Scene::parse(&fault, Path::new(".")).unwrap();
    assert_eq!(s.faults[0].kind, FaultKind::Reopen);
    assert_eq!(s.imus[0].protocol, Protocol::Wit, "IMU default");
    let _ = PathBuf::new();
}

#[test]
fn scene_imu_output_is_checked_and_serves_deltas() {
    use imulab_drivers::codec::ImuOutput;
    let with = |protocol: &str, output: &str| {
        TWO_IMUS.replace(
            "protocol = \"xbus\"",
            &format!("protocol = \"{protocol}\"\noutput = \"{output}\""),
        )
    };
    let s = Scene::parse(&with("mip", "both"), Path::new(".")).unwrap();
    assert_eq!(
        (s.imus[0].output, s.imus[1].output),
        (ImuOutput::Rates, ImuOutput::Both)
    );
    let e = format!(
        "{:#}",
        Scene::parse(&with("xbus", "deltas"), Path::new(".")).unwrap_err()
    );
    assert!(
        e.contains("imu[1] (b)") && e.contains("sends rates only"),
        "{e}"
    );
    let e = format!(
        "{:#}",
        Scene::parse(&with("mip", "integrals"), Path::new(".")).unwrap_err()
    );
    assert!(e.contains("output:") && e.contains("\"deltas\""), "{e}");
    let gyro_only =
        with("vectornav", "deltas").replace("name = \"b\"", "name = \"b\"\nchannels = [\"gyro\"]");
    let e = format!(
        "{:#}",
        Scene::parse(&gyro_only, Path::new(".")).unwrap_err()
    );
    assert!(e.contains("DeltaThetaVel"), "{e}");
    // A served frame of deltas decodes back (rows from the deltas) to the record's rates.
    let s = Scene::parse(&with("vectornav", "deltas"), Path::new(".")).unwrap();
    let imu = &s.imus[1];
    let wire = ImuWire::with_output(imu.protocol, imu.channels, s.rate_hz, imu.output).unwrap();
    let record = imulab::store::ImuRecord {
        t_mono_ns: imulab::sim::scene::START_MONO_NS + 30_000_000,
        t_wall_ns: 0,
        t_sensor: 3.0,
        gyro: [0.01, -0.02, 0.03],
        accel: [0.1, -0.2, 9.81],
        temp: 25.0,
        status: 0,
    };
    let mut bytes = Vec::new();
    wire.encode(&record, &mut bytes).unwrap();
    let sample = wire.decode_one(&bytes).expect("a sample");
    for (got, want) in sample.gyro.unwrap().iter().zip(record.gyro) {
        assert!((got - want).abs() < 1e-7 * want.abs(), "{got} vs {want}");
    }
    assert!((sample.sensor_time.unwrap() - 0.03).abs() < 1e-9);
}
