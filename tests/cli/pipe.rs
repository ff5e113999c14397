//! A reader that stops early (`imulab export … | head`) ends the writer quietly, as with any Unix
//! tool: killed by SIGPIPE or exit 0, never a Rust panic (exit 101) from `println!`.

use std::io::{BufRead, BufReader};
use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};

#[test]
fn export_into_a_closed_pipe_ends_without_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("session");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/scenes/short_static.toml"
    );
    let sim = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(["sim", scene, "-o"])
        .arg(&session)
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );

    let mut export = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(["export"])
        .arg(&session)
        .args(["--device", "cheap", "--format", "csv"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(export.stdout.take().unwrap()).lines();
    assert!(lines.next().unwrap().unwrap().contains("t_mono_ns"));
    drop(lines); // the reader goes away with most of the rows unread
    let out = export.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        out.status.signal() == Some(libc::SIGPIPE) || out.status.success(),
        "{:?}: {stderr}",
        out.status
    );
}
