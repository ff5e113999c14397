//! Captures played back through the daemon (`[device.file]`): a session recorded live with
//! the raw journal, replayed from its raw record, gives the same decoded rows; a raw byte
//! capture is paced at its baud; the daemon ends by itself at the end of its captures, and
//! keeps logging a live device after a capture ended. Bad file sources are refused before
//! the daemon runs, naming the file and what is missing.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::daemon::parts_for;
use crate::common::encode::wit_sample;
use crate::common::pty::Pty;
use crate::common::{gnss_rows, imu_rows};
use crate::end_to_end::{same, serve_and_log, without_times_gnss, without_times_imu};
use imulab::daemon::config::parse;
use imulab::daemon::session::open_session_sink;
use imulab::daemon::source::connector_for;
use imulab::daemon::{run, Outcome};
use imulab::store::{EventKind, Session};

/// Runs the daemon on `text` until it stops by itself (at most `limit`); returns how it ended
/// and how long it ran.
async fn run_until_done(text: &str, session_dir: &Path, limit: Duration) -> (Outcome, Duration) {
    let config = parse(text, "replay").unwrap_or_else(|e| panic!("{e}"));
    let sink = Box::new(open_session_sink(&config, session_dir).unwrap());
    let parts = parts_for(&config, sink, session_dir.to_path_buf());
    // Nobody sends a stop: the captures' ends must end the run.
    let (_stop, stop_rx) = tokio::sync::watch::channel(false);
    let started = Instant::now();
    let outcome = tokio::time::timeout(limit, async move { run(&config, parts, stop_rx).await })
        .await
        .expect("the daemon ends by itself at the end of its captures");
    (outcome, started.elapsed())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_live_session_with_raw_journal_replays_to_the_same_rows() {
    let (dir, _report, live_dir) = serve_and_log(Vec::new(), true).await;
    let live = Session::open(&live_dir).unwrap();
    let mut devices = String::new();
    for d in live.devices() {
        let protocol = d.protocol.as_str();
        devices.push_str(&format!(
            "[[device]]\nname = \"{}\"\nprotocol = \"{protocol}\"\nrate_hz = {}\n\
             file = {{ path = \"{}\", pace = \"fast\" }}\n",
            d.name,
            d.rate_hz,
            live_dir.display()
        ));
    }
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nname = \"replayed\"\nflush_interval_ms = 100\n\n{devices}",
        dir.path().display()
    );
    let replay_dir = dir.path().join("replayed");
    let (outcome, took) = run_until_done(&text, &replay_dir, Duration::from_secs(60)).await;
    println!(
        "replayed {} devices fast in {took:?}: {outcome:?}",
        live.devices().len()
    );
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");

    let replayed = Session::open(&replay_dir).unwrap();
    assert!(replayed.problems().is_empty(), "{:?}", replayed.problems());
    for name in ["wit", "mti"] {
        let (a, b) = (imu_rows(&live, name), imu_rows(&replayed, name));
        assert!(a.len() > 2000, "{name}: {} live rows", a.len());
        assert_eq!(a.len(), b.len(), "{name}: live vs replayed rows");
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(
                same(&without_times_imu(*x), &without_times_imu(*y)),
                "{name} row {k}: live {x:?}, replayed {y:?}"
            );
        }
    }
    let (a, b) = (gnss_rows(&live, "rx"), gnss_rows(&replayed, "rx"));
    assert!(a.len() > 100, "{} live fixes", a.len());
    assert_eq!(a.len(), b.len(), "rx: live vs replayed fixes");
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!(
            same(&without_times_gnss(*x), &without_times_gnss(*y)),
            "rx fix {k}: live {x:?}, replayed {y:?}"
        );
    }
    let (events, _) = replayed.events();
    for name in ["wit", "mti", "rx"] {
        assert!(
            events.iter().any(|e| e.device == name
                && e.kind == EventKind::Info
                && e.detail.contains("end of the capture")),
            "{name}: {events:?}"
        );
        assert!(
            !events
                .iter()
                .any(|e| e.device == name && e.kind == EventKind::QueueOverflow),
            "a fast replay waits for the writer instead of dropping: {events:?}"
        );
    }
}

/// `n` WitMotion samples as one raw byte capture.
fn wit_capture(path: &Path, n: u64) -> usize {
    let bytes: Vec<u8> = (0..n).flat_map(wit_sample).collect();
    std::fs::write(path, &bytes).unwrap();
    bytes.len()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_raw_capture_plays_at_its_baud_and_faster_by_a_factor() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("wit.bin");
    let n = 300;
    let bytes = wit_capture(&capture, n);
    // 9600 baud: 960 bytes/s.
    let line_s = bytes as f64 / 960.0;
    for (pace, factor) in [("\"recorded\"", 1.0), ("4", 4.0)] {
        let name = format!("x{factor}");
        let text = format!(
            "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 100\n\
             [[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = 100\n\
             file = {{ path = \"{}\", baud = 9600, pace = {pace} }}\n",
            dir.path().display(),
            capture.display()
        );
        let session_dir = dir.path().join(&name);
        let (outcome, took) = run_until_done(&text, &session_dir, Duration::from_secs(30)).await;
        assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
        let want = line_s / factor;
        println!(
            "{bytes} bytes at 9600 baud, pace {pace}: {took:?} (line time / factor {want:.2} s)"
        );
        assert!(
            took.as_secs_f64() > 0.9 * want && took.as_secs_f64() < want + 1.5,
            "pace {pace}: took {took:?}, expected about {want:.2} s"
        );
        let session = Session::open(&session_dir).unwrap();
        let rows = imu_rows(&session, "imu");
        assert_eq!(rows.len() as u64, n, "pace {pace}");
        // Spread over the line time, not in one burst.
        let span_s = (rows[rows.len() - 1].t_mono_ns - rows[0].t_mono_ns) as f64 * 1e-9;
        assert!(span_s > 0.8 * want, "pace {pace}: rows span {span_s:.2} s");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_live_device_keeps_logging_after_a_capture_ended() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("wit.bin");
    wit_capture(&capture, 50);
    let mut pty = Pty::open();
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nname = \"mixed\"\nflush_interval_ms = 100\n\
         [[device]]\nname = \"replay\"\nprotocol = \"wit\"\nrate_hz = 100\n\
         file = {{ path = \"{}\", pace = \"fast\" }}\n\
         [[device]]\nname = \"live\"\nprotocol = \"wit\"\nrate_hz = 100\n\
         serial = {{ port = \"{}\" }}\n",
        dir.path().display(),
        capture.display(),
        pty.slave_path.display()
    );
    let config = parse(&text, "mixed").unwrap_or_else(|e| panic!("{e}"));
    let session_dir = dir.path().join("mixed");
    let sink = Box::new(open_session_sink(&config, &session_dir).unwrap());
    let parts = parts_for(&config, sink, session_dir.clone());
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    tokio::time::sleep(Duration::from_millis(300)).await;
    // The capture has ended by now; the live device is still read.
    let pty = tokio::task::spawn_blocking(move || {
        for seq in 0..40 {
            pty.write(&wit_sample(seq));
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(200));
        pty
    })
    .await
    .unwrap();
    assert!(
        !daemon.is_finished(),
        "one capture ending must not end the session"
    );
    let _ = stop.send(true);
    let outcome = daemon.await.unwrap();
    drop(pty);
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    let session = Session::open(&session_dir).unwrap();
    assert_eq!(imu_rows(&session, "replay").len(), 50);
    // The last WitMotion sample waits for the next one's first packet (or the end).
    assert!(imu_rows(&session, "live").len() >= 39);
}

#[test]
fn bad_file_sources_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("wit.bin");
    wit_capture(&capture, 5);
    let device = |file: &str| {
        format!(
            "[session]\noutput_dir = \"{}\"\n[[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = 100\nfile = {file}\n",
            dir.path().display()
        )
    };
    // A pace that is not one: a config error with the key path.
    let e = parse(
        &device(&format!(
            "{{ path = \"{}\", pace = \"slow\" }}",
            capture.display()
        )),
        "t",
    )
    .unwrap_err();
    assert!(e.has_issue("device[0].file.pace", "not a pace"), "{e}");
    let e = parse(
        &device(&format!(
            "{{ path = \"{}\", pace = -2 }}",
            capture.display()
        )),
        "t",
    )
    .unwrap_err();
    assert!(e.has_issue("device[0].file.pace", "not a pace"), "{e}");

    let refused = |file: String| {
        let config = parse(&device(&file), "t").unwrap_or_else(|e| panic!("{e}"));
        match connector_for(&config.devices[0]) {
            Ok(_) => panic!("{file}: accepted"),
            Err(e) => e,
        }
    };
    // A raw capture has no time stamps: recorded pace needs a baud.
    let e = refused(format!("{{ path = \"{}\" }}", capture.display()));
    assert!(e.contains("file.baud") && e.contains("wit.bin"), "{e}");
    // A file that is not there.
    let e = refused(format!(
        "{{ path = \"{}\", pace = \"fast\" }}",
        dir.path().join("nope.bin").display()
    ));
    assert!(e.contains("nope.bin"), "{e}");
    // A session recorded without the raw journal has nothing to replay.
    let session = dir.path().join("no-raw");
    let text = format!(
        "[session]\noutput_dir = \"{}\"\n[[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = 100\nserial = {{ port = \"/dev/imu-x\" }}\n",
        dir.path().display()
    );
    let config = parse(&text, "t").unwrap();
    let mut sink = open_session_sink(&config, &session).unwrap();
    imulab::daemon::sink::RecordSink::close(&mut sink).unwrap();
    let e = refused(format!("{{ path = \"{}\" }}", session.display()));
    assert!(e.contains("raw_journal") && e.contains("no-raw"), "{e}");
    // A session device that does not exist: the ones that do are listed.
    let e = refused(format!(
        "{{ path = \"{}\", device = \"gps\" }}",
        session.display()
    ));
    assert!(e.contains("no device `gps`") && e.contains("imu"), "{e}");
}

fn nmea_line(body: &str) -> String {
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{sum:02X}\r\n")
}

/// A python with h5py: the store tests' venv under `target/` when it was made, else the
/// system's; `None` when neither has h5py.
fn python_with_h5py() -> Option<std::path::PathBuf> {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/store-pyvenv/bin/python");
    [venv, "python3".into()].into_iter().find(|p| {
        std::process::Command::new(p)
            .args(["-c", "import h5py"])
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// An NMEA receiver with a heading (HDT) in every other epoch, played through the daemon: the
/// heading is in `/gnss/<name>/heading_deg`, NaN where HDT was missing, as the Rust reader,
/// `imulab export` and h5py read it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nmea_hdt_heading_is_stored_with_its_epoch() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("nmea.txt");
    let epochs = 20u32;
    let mut text = String::new();
    for k in 0..epochs {
        let (m, s) = (k / 60, k % 60);
        text += &nmea_line(&format!(
            "GPGGA,12{m:02}{s:02}.00,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"
        ));
        text += &nmea_line(&format!(
            "GPRMC,12{m:02}{s:02}.00,A,4807.038,N,01131.000,E,022.4,084.4,011226,,"
        ));
        if k % 2 == 0 {
            text += &nmea_line(&format!("GPHDT,{:.2},T", 10.0 + f64::from(k) * 1.5));
        }
    }
    std::fs::write(&capture, text).unwrap();
    let config = format!(
        "[session]\noutput_dir = \"{}\"\nname = \"hdt\"\nflush_interval_ms = 100\n\
         [[device]]\nname = \"rx\"\nprotocol = \"nmea\"\nrate_hz = 1\n\
         file = {{ path = \"{}\", pace = \"fast\" }}\n",
        dir.path().display(),
        capture.display()
    );
    let session_dir = dir.path().join("hdt");
    let (outcome, _) = run_until_done(&config, &session_dir, Duration::from_secs(20)).await;
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    let session = Session::open(&session_dir).unwrap();
    let rows = gnss_rows(&session, "rx");
    assert_eq!(rows.len(), epochs as usize);
    for (k, r) in rows.iter().enumerate() {
        if k % 2 == 0 {
            assert_eq!(r.heading_deg, 10.0 + k as f64 * 1.5, "epoch {k}");
        } else {
            assert!(r.heading_deg.is_nan(), "epoch {k}: {}", r.heading_deg);
        }
    }
    let Some(python) = python_with_h5py() else {
        println!("SKIPPED the h5py half of nmea_hdt_heading_is_stored: no python with h5py");
        return;
    };
    let chunk = session_dir.join("chunk-000000.h5");
    let out = std::process::Command::new(python)
        .args([
            "-c",
            "import h5py, sys, math\n\
             f = h5py.File(sys.argv[1], 'r')\n\
             d = f['gnss/rx/heading_deg']\n\
             print(d.attrs['units'], ' '.join('nan' if math.isnan(x) else repr(float(x)) for x in d[:4]))",
        ])
        .arg(&chunk)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let printed = String::from_utf8_lossy(&out.stdout);
    println!("h5py: {printed}");
    assert_eq!(printed.trim(), "deg 10.0 nan 13.0 nan");
}
