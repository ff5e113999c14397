//! The server's rules, against the real binary: loopback Host names only (DNS rebinding),
//! GET/HEAD only, nothing outside the session served (path traversal, links), bounded
//! connections.

use super::common::{finished_session, Served};

#[test]
fn foreign_host_headers_are_refused_on_loopback() {
    let dir = tempfile::tempdir().unwrap();
    let session = finished_session(dir.path(), 30.0);
    let s = Served::start(env!("CARGO_BIN_EXE_imulab"), &session, &[]);
    let port = s.addr.port();
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        "localhost".to_string(),
    ] {
        let (code, body) = s.raw(&format!("GET / HTTP/1.1\r\nHost: {host}"));
        assert_eq!(code, 200, "{host}: {body}");
        assert!(body.contains("Data health"), "{host}");
    }
    for host in [
        format!("evil.example:{port}"),
        "attacker.test".to_string(),
        format!("127.0.0.1.nip.example:{port}"),
        format!("10.1.2.3:{port}"),
    ] {
        let (code, body) = s.raw(&format!("GET /state.json HTTP/1.1\r\nHost: {host}"));
        assert_eq!(code, 403, "{host}: {body}");
        assert!(body.contains("is not this machine"), "{body}");
        assert!(!body.contains("session_id"), "{host}: state leaked");
    }
    // No Host header at all (HTTP/1.0): refused too.
    let (code, _) = s.raw("GET / HTTP/1.0");
    assert_eq!(code, 403);
}

#[test]
fn only_get_and_head_are_answered() {
    let dir = tempfile::tempdir().unwrap();
    let session = finished_session(dir.path(), 20.0);
    let s = Served::start(env!("CARGO_BIN_EXE_imulab"), &session, &[]);
    let host = format!("Host: {}", s.addr);
    for method in ["POST", "PUT", "DELETE", "PATCH", "OPTIONS", "TRACE"] {
        for path in ["/", "/files/session.toml", "/nothing"] {
            let (code, body) = s.raw(&format!(
                "{method} {path} HTTP/1.1\r\n{host}\r\nContent-Length: 0"
            ));
            assert_eq!(code, 405, "{method} {path}: {body}");
            assert!(
                body.contains("Allow: GET, HEAD") || body.contains("allow: GET, HEAD"),
                "{body}"
            );
        }
    }
    let (code, body) = s.raw(&format!("HEAD / HTTP/1.1\r\n{host}"));
    assert_eq!(code, 200, "{body}");
    assert!(!body.contains("Data health"), "HEAD has no body");
    let before = std::fs::read_dir(&session).unwrap().count();
    assert_eq!(before, std::fs::read_dir(&session).unwrap().count());
}

#[test]
fn nothing_outside_the_session_is_served() {
    let dir = tempfile::tempdir().unwrap();
    let session = finished_session(dir.path(), 20.0);
    // A secret beside the session, and a link to it inside.
    std::fs::write(dir.path().join("secret.txt"), "the secret").unwrap();
    std::os::unix::fs::symlink(dir.path().join("secret.txt"), session.join("link.txt")).unwrap();
    std::fs::create_dir(session.join("sub")).unwrap();
    std::fs::write(session.join("sub").join("inner.txt"), "inner").unwrap();
    let s = Served::start(env!("CARGO_BIN_EXE_imulab"), &session, &[]);
    let (code, body) = s.get("/files/session.toml");
    assert_eq!(code, 200, "{body}");
    assert!(body.contains("[[devices]]"), "{body}");
    for path in [
        "/files/../secret.txt",
        "/files/..%2fsecret.txt",
        "/files/..%2Fsecret.txt",
        "/files/%2e%2e%2fsecret.txt",
        "/files/%2e%2e/secret.txt",
        "/files/..%5csecret.txt",
        "/files/link.txt",
        "/files/sub",
        "/files/sub/inner.txt",
        "/files/sub%2finner.txt",
        "/files/%2fetc%2fpasswd",
        "/files//etc/passwd",
        "/../../../../etc/passwd",
        "/files/..",
        "/files/.",
        "/files/",
        "/etc/passwd",
        "/files/%00session.toml",
    ] {
        let (code, body) = s.get(path);
        assert!(code == 404 || code == 400, "{path}: {code} {body}");
        assert!(!body.contains("the secret"), "{path} served the secret");
        assert!(
            !body.contains("inner"),
            "{path} served a file below the session"
        );
        assert!(!body.contains("root:"), "{path} served /etc/passwd");
    }
}

#[test]
fn connections_are_bounded() {
    use std::io::{Read, Write};
    let dir = tempfile::tempdir().unwrap();
    let session = finished_session(dir.path(), 20.0);
    let s = Served::start(
        env!("CARGO_BIN_EXE_imulab"),
        &session,
        &["--max-connections", "2"],
    );
    // Two idle connections hold the two slots (no request sent yet).
    let held: Vec<_> = (0..2)
        .map(|_| std::net::TcpStream::connect(s.addr).unwrap())
        .collect();
    std::thread::sleep(std::time::Duration::from_millis(300));
    let (code, body) = s.get("/");
    assert_eq!(code, 503, "{body}");
    // Once they go, the page is served again.
    drop(held);
    let mut ok = false;
    for _ in 0..50 {
        std::thread::sleep(std::time::Duration::from_millis(100));
        if s.get("/").0 == 200 {
            ok = true;
            break;
        }
    }
    assert!(ok, "slots not released");
    // A connection that never finishes its request head is closed after the head timeout.
    let mut slow = std::net::TcpStream::connect(s.addr).unwrap();
    slow.write_all(b"GET / HTTP/1.1\r\n").unwrap();
    slow.set_read_timeout(Some(std::time::Duration::from_secs(30)))
        .unwrap();
    let started = std::time::Instant::now();
    let mut buf = Vec::new();
    let _ = slow.read_to_end(&mut buf);
    assert!(started.elapsed().as_secs_f64() < 20.0, "slow client kept");
}
