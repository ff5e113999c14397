//! `imulab decode` end to end: a mixed NMEA + UBX capture (built with the encoders) comes
//! out as one JSON object per frame plus merged fixes, with the counters on stderr; NMEA
//! values come out in SI units with the sentence text kept in `raw`; a bad protocol name and
//! an undecodable file fail with a clear message.

use std::path::Path;
use std::process::Command;

use imulab_drivers::codec::nmea::{Decimal, Hdt, NmeaDecoder, NmeaEncoder, NmeaSentence, Talker};
use imulab_drivers::codec::ubx::{parse_message, UbxEncoder};
use imulab_drivers::codec::{Decoder, Encoder};

fn imulab() -> Command {
    Command::new(env!("CARGO_BIN_EXE_imulab"))
}

/// Runs `imulab decode ARGS… PATH`, which must succeed; returns its stdout, the JSON object
/// of each stdout line, and its stderr.
fn decode_json(args: &[&str], path: &Path) -> (String, Vec<serde_json::Value>, String) {
    let out = imulab()
        .arg("decode")
        .args(args)
        .arg(path)
        .output()
        .expect("run imulab");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let lines = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("each line is JSON"))
        .collect();
    (stdout, lines, stderr)
}

#[test]
fn decodes_mixed_capture_to_json_lines() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("capture.bin");
    let mut bytes = b"garbage".to_vec();
    for i in 0..3u32 {
        let mut posllh = vec![0u8; 28];
        posllh[..4].copy_from_slice(&(1000 * i).to_le_bytes());
        posllh[8..12].copy_from_slice(&440_600_000i32.to_le_bytes());
        UbxEncoder
            .encode(&parse_message(0x01, 0x02, &posllh), &mut bytes)
            .expect("encode ubx");
        let hdt = NmeaSentence::Hdt(Hdt {
            talker: Talker(*b"GP"),
            heading_deg: Some(Decimal::new(27407, 2)),
        });
        NmeaEncoder.encode(&hdt, &mut bytes).expect("encode nmea");
    }
    std::fs::write(&path, &bytes).expect("write capture");

    let (stdout, lines, stderr) = decode_json(&[], &path);
    let count = |kind: &str| lines.iter().filter(|v| v["kind"] == kind).count();
    assert_eq!(count("ubx"), 3, "{stdout}");
    assert_eq!(count("nmea"), 3, "{stdout}");
    assert_eq!(count("fix"), 3, "{stdout}");
    let fix = lines.iter().find(|v| v["kind"] == "fix").expect("a fix");
    assert_eq!(fix["lat_deg"], 44.06);
    let summary: serde_json::Value =
        serde_json::from_str(stderr.lines().last().unwrap_or("")).expect("summary JSON");
    assert_eq!(summary["protocol"], "gnss");
    assert_eq!(summary["stats"]["frames_ok"], 6);
    assert_eq!(summary["stats"]["bytes_skipped"], 7);
}

/// `$body*hh\r\n` with the checksum computed.
fn sentence(body: &str) -> String {
    let checksum = body.bytes().fold(0u8, |acc, b| acc ^ b);
    format!("${body}*{checksum:02X}\r\n")
}

fn decode_one(text: &str) -> NmeaSentence {
    let mut decoder = NmeaDecoder::new();
    let mut frames = Vec::new();
    decoder.decode(text.as_bytes(), |f| frames.push(f));
    assert_eq!(frames.len(), 1, "{text}");
    frames.remove(0)
}

#[test]
fn nmea_json_is_si_with_the_sentence_text_kept() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("speeds.nmea");
    let rmc = sentence("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W");
    // km/h only: the knots field is empty.
    let vtg = sentence("GPVTG,054.7,T,034.4,M,,N,010.8,K");
    let gga = sentence("GPGGA,123519,4807.038,S,01131.000,W,1,08,0.9,545.4,M,46.9,M,,");
    std::fs::write(&path, format!("{rmc}{vtg}{gga}")).expect("write capture");

    let (stdout, lines, _) = decode_json(&["--protocol", "nmea"], &path);
    assert_eq!(lines.len(), 3, "{stdout}");
    let close = |v: &serde_json::Value, want: f64| {
        let got = v.as_f64().unwrap_or(f64::NAN);
        assert!((got - want).abs() < 1e-9, "{got} vs {want}: {stdout}");
    };

    let (rmc_json, vtg_json, gga_json) = (&lines[0], &lines[1], &lines[2]);
    assert_eq!(rmc_json["sentence"], "RMC");
    close(&rmc_json["speed_mps"], 22.4 * 1852.0 / 3600.0);
    assert!(rmc_json.get("speed_knots").is_none(), "{stdout}");
    close(&rmc_json["lat"], 48.0 + 7.038 / 60.0);
    close(&rmc_json["lon"], 11.0 + 31.0 / 60.0);
    assert_eq!(vtg_json["sentence"], "VTG");
    close(&vtg_json["speed_mps"], 3.0);
    assert!(vtg_json.get("speed_kmh").is_none(), "{stdout}");
    close(&gga_json["lat"], -(48.0 + 7.038 / 60.0));
    close(&gga_json["lon"], -(11.0 + 31.0 / 60.0));
    close(&gga_json["alt_msl_m"], 545.4);
    close(&gga_json["time"], 12.0 * 3600.0 + 35.0 * 60.0 + 19.0);

    // The raw values stay recoverable: `raw` is the sentence's text, which decodes to the
    // same sentence as what the receiver sent (knots and km/h included).
    for (json, original) in [(rmc_json, &rmc), (vtg_json, &vtg), (gga_json, &gga)] {
        let raw = json["raw"].as_str().expect("raw text");
        assert_eq!(decode_one(raw), decode_one(original), "{raw} vs {original}");
    }
    let raw_vtg = vtg_json["raw"].as_str().unwrap_or("");
    assert!(
        raw_vtg.contains(",010.8,K") || raw_vtg.contains(",10.8,K"),
        "{raw_vtg}"
    );
}

#[test]
fn unknown_protocol_and_undecodable_input_fail_clearly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("noise.bin");
    std::fs::write(&path, [0u8; 100]).expect("write");

    let out = imulab()
        .args(["decode", "--protocol", "morse"])
        .arg(&path)
        .output()
        .expect("run");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown protocol `morse`"));

    let out = imulab()
        .args(["decode", "--protocol", "nmea"])
        .arg(&path)
        .output()
        .expect("run");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no valid nmea frame in 100 bytes"));

    let out = imulab().arg("decode").arg(&path).output().expect("run");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no known protocol"));

    // An empty file is an error like garbage, with or without a protocol.
    let empty = dir.path().join("empty.bin");
    std::fs::write(&empty, b"").expect("write");
    for args in [&["decode"][..], &["decode", "--protocol", "nmea"][..]] {
        let out = imulab().args(args).arg(&empty).output().expect("run");
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("empty input (0 bytes)"), "{args:?}: {err}");
    }

    // Whole NMEA sentences with wrong checksums: a checksum message, not a baud-rate hint.
    let bad = dir.path().join("bad.nmea");
    let mut text = String::new();
    for k in 0..5 {
        text += &format!("$GPGGA,12351{k},4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*00\r\n");
    }
    std::fs::write(&bad, text).expect("write");
    for args in [&["decode"][..], &["decode", "--protocol", "nmea"][..]] {
        let out = imulab().args(args).arg(&bad).output().expect("run");
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("5 nmea frames") && err.contains("failed their checksum"),
            "{args:?}: {err}"
        );
        assert!(!err.contains("--baud"), "{args:?}: {err}");
    }
}

/// Pty loopback: the encoders write into the master side, `imulab decode` reads the slave
/// side as a serial port, and every frame arrives intact.
#[cfg(target_os = "linux")]
#[test]
fn decodes_a_live_pty_port() {
    use std::io::{Read, Write};
    use std::os::fd::AsRawFd;

    use nix::pty::openpty;
    use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

    let pty = openpty(None, None).expect("openpty");
    let mut attrs = tcgetattr(&pty.slave).expect("tcgetattr");
    cfmakeraw(&mut attrs);
    tcsetattr(&pty.slave, SetArg::TCSANOW, &attrs).expect("raw mode");
    let slave_path =
        std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd())).expect("slave path");

    let mut child = imulab()
        .args(["decode", "--baud", "115200", "--duration", "3"])
        .arg(&slave_path)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn imulab");

    let mut bytes = Vec::new();
    for i in 0..5u32 {
        let mut posllh = vec![0u8; 28];
        posllh[..4].copy_from_slice(&(1000 * i).to_le_bytes());
        UbxEncoder
            .encode(&parse_message(0x01, 0x02, &posllh), &mut bytes)
            .expect("encode ubx");
        let hdt = NmeaSentence::Hdt(Hdt {
            talker: Talker(*b"GN"),
            heading_deg: Some(Decimal::new(i64::from(i), 1)),
        });
        NmeaEncoder.encode(&hdt, &mut bytes).expect("encode nmea");
    }
    let mut master = std::fs::File::from(pty.master);
    master.write_all(&bytes).expect("write to pty");
    master.flush().expect("flush");

    let mut stdout = String::new();
    child
        .stdout
        .take()
        .expect("stdout")
        .read_to_string(&mut stdout)
        .expect("read stdout");
    let status = child.wait().expect("wait");
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .expect("stderr")
        .read_to_string(&mut stderr)
        .ok();
    assert!(status.success(), "{stderr}");
    let kinds: Vec<String> = stdout
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).expect("JSON")["kind"].to_string())
        .collect();
    assert_eq!(
        kinds.iter().filter(|k| *k == "\"ubx\"").count(),
        5,
        "{stdout}"
    );
    assert_eq!(
        kinds.iter().filter(|k| *k == "\"nmea\"").count(),
        5,
        "{stdout}"
    );
    assert!(stderr.contains("\"checksum_errors\":0"), "{stderr}");
}

/// A VectorNav ASCII-only capture (`$VNYMR` sentences, which are also well-formed NMEA) is
/// detected as VectorNav, not NMEA; a MIP capture as MIP; both come out as JSON frames.
#[test]
fn auto_detects_vectornav_ascii_and_mip_captures() {
    use imulab_drivers::codec::mip::{MipEncoder, MipImuData, MipPacket};
    let dir = tempfile::tempdir().expect("tempdir");
    let vn = dir.path().join("vn100.txt");
    let mut text = String::new();
    for k in 0..10 {
        let body = format!(
            "VNYMR,+{k:03}.071,-000.278,-000.636,+01.0267,-00.2052,+02.7264,-00.497,+00.154,-09.802,-00.003823,+00.000159,-00.000344"
        );
        let ck = body.bytes().fold(0u8, |a, b| a ^ b);
        text.push_str(&format!("${body}*{ck:02X}\r\n"));
    }
    std::fs::write(&vn, text).expect("write capture");
    let (stdout, lines, stderr) = decode_json(&[], &vn);
    assert_eq!(lines.len(), 10, "{stdout}");
    assert!(stderr.contains("vectornav"), "{stderr}");
    assert_eq!(lines[3]["type"], "ascii", "{stdout}");
    assert_eq!(lines[3]["kind"], "YMR", "{stdout}");
    assert_eq!(lines[3]["values"]["accel"][2], -9.802, "{stdout}");

    let mip = dir.path().join("gx5.bin");
    let mut bytes = Vec::new();
    for k in 0..5 {
        let packet = MipPacket::Imu(MipImuData {
            scaled_accel_g: Some([0.0, 0.0, -1.0]),
            scaled_gyro: Some([0.01 * k as f32, 0.0, 0.0]),
            ..MipImuData::default()
        });
        MipEncoder.encode(&packet, &mut bytes).expect("encode");
    }
    std::fs::write(&mip, bytes).expect("write capture");
    let (stdout, lines, stderr) = decode_json(&[], &mip);
    assert_eq!(lines.len(), 5, "{stdout}");
    assert!(stderr.contains("mip"), "{stderr}");
    assert_eq!(lines[0]["type"], "imu", "{stdout}");
}
