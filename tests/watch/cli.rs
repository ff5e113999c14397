//! `imulab watch` from the command line: the static page of a finished session, the JSON
//! state, and clear errors.

use super::common::{finished_session, IMUS};
use std::process::Command;

fn imulab() -> Command {
    Command::new(env!("CARGO_BIN_EXE_imulab"))
}

#[test]
fn once_writes_a_static_page_and_the_state() {
    let dir = tempfile::tempdir().unwrap();
    let session = finished_session(dir.path(), 600.0);
    let html = dir.path().join("state.html");
    let json = dir.path().join("state.json");
    let out = imulab()
        .arg("watch")
        .arg(&session)
        .args([
            "--once",
            "--target",
            "random-walk=5%",
            "--target",
            "bias-instability=20%",
        ])
        .arg("--html")
        .arg(&html)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(!page.contains("<script"), "a static page has no script");
    assert!(
        !page.contains("src=\"http"),
        "nothing loaded from elsewhere"
    );
    for text in [
        "Data health",
        "When can I stop?",
        "finished",
        IMUS[0],
        IMUS[1],
        "rx",
        "<svg",
        "ARW",
    ] {
        assert!(page.contains(text), "page lacks {text}");
    }
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(state["live"], false);
    let a = &state["devices"][0];
    assert_eq!(a["name"], IMUS[0]);
    assert_eq!(a["rows"], 90_000);
    assert_eq!(a["events"]["resync"], 2);
    assert_eq!(a["axes"].as_array().unwrap().len(), 6);
    // The random walk of the first gyro axis: written as 1e-3 rad/s/√Hz; ARW in
    // deg/√h = 1e-3 · 180/π · 60 ≈ 3.44.
    let terms = a["axes"][0]["terms"].as_array().unwrap();
    let arw = terms.iter().find(|t| t["key"] == "random-walk").unwrap();
    let value = arw["value"].as_f64().unwrap();
    assert!(
        (value / 3.4377 - 1.0).abs() < 0.05,
        "ARW {value} {}",
        arw["unit"]
    );
    assert!(arw["low"].as_f64().unwrap() < value && value < arw["high"].as_f64().unwrap());
    // Each targeted term has a prediction.
    assert!(arw["prediction"]["state"].is_string(), "{arw}");
    // The GNSS receiver has health but no axes.
    assert_eq!(state["devices"][2]["rows"], 3000);
    assert_eq!(state["devices"][2]["axes"].as_array().unwrap().len(), 0);
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&[&str], &str); 4] = [
        (
            &["watch", "/nonexistent/run", "--once", "--html", "x.html"],
            "/nonexistent/run",
        ),
        (
            &[
                "watch", ".", "--target", "bias=10%", "--once", "--html", "x.html",
            ],
            "unknown term `bias`",
        ),
        (
            &[
                "watch",
                ".",
                "--target",
                "random-walk=0%",
                "--once",
                "--html",
                "x.html",
            ],
            "width must be above 0",
        ),
        (&["watch", ".", "--html", "x.html"], "--once"),
    ];
    for (args, expected) in cases {
        let out = imulab()
            .current_dir(dir.path())
            .args(args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(expected), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    // --once with nowhere to write.
    let session = finished_session(dir.path(), 10.0);
    let out = imulab()
        .arg("watch")
        .arg(&session)
        .arg("--once")
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--html FILE"));
    // A port in use.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let out = imulab()
        .arg("watch")
        .arg(&session)
        .args(["--listen", &addr])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("cannot listen on {addr}")), "{err}");
}

#[test]
fn listening_beyond_loopback_warns() {
    let dir = tempfile::tempdir().unwrap();
    let session = finished_session(dir.path(), 10.0);
    let mut child = imulab()
        .arg("watch")
        .arg(&session)
        .args(["--listen", "0.0.0.0:0"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::BufRead;
    let mut line = String::new();
    std::io::BufReader::new(child.stderr.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        line.starts_with("warning:") && line.contains("reachable from the network"),
        "{line}"
    );
}
