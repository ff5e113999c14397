//! A real headless Chromium loads the live page of a session being written and sees its
//! content and its updates. Skipped, saying why, where `/usr/bin/chromium` is absent (CI
//! installs Debian's `chromium`). With `IMULAB_WATCH_SCREENSHOT=FILE` the screenshot is
//! also copied there (how docs/img/watch.png is made).

use super::common::{mono_now, LiveSession, Served, IMUS};
use imulab_test_support::browser::{chromium, chromium_missing, run};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// The `(look N` number of the page's summary line.
fn look_number(dom: &str) -> u64 {
    dom.split("(look ")
        .nth(1)
        .and_then(|r| r.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no look number in the page"))
}

/// The rows cell of the first IMU in the health table.
fn rows_of_first_imu(dom: &str) -> u64 {
    let row = dom
        .split(&format!("<tr><td>{}<br>", IMUS[0]))
        .nth(1)
        .expect("no health row for the first IMU");
    row.split("<td>")
        .nth(1)
        .and_then(|c| c.split('<').next())
        .and_then(|n| n.parse().ok())
        .expect("no rows cell")
}

#[test]
fn chromium_shows_the_live_page_and_its_updates() {
    if chromium_missing("the browser check") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("run");
    let mut live = LiveSession::create(&session, mono_now());
    live.append(120.0);
    let stop = Arc::new(AtomicBool::new(false));
    let writer = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            // 10 s of data every 250 ms (40× real time).
            while !stop.load(Ordering::Relaxed) {
                live.append(10.0);
                std::thread::sleep(Duration::from_millis(250));
            }
            live.close();
        })
    };
    let served = Served::start(
        env!("CARGO_BIN_EXE_imulab"),
        &session,
        &["--refresh", "1", "--target", "random-walk=2%"],
    );
    let url = format!("http://{}/", served.addr);
    let profile = tempfile::tempdir().unwrap();
    let dump = || {
        let mut c = chromium(profile.path());
        c.args(["--dump-dom", &url]);
        let out = run(c);
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    let first = dump();
    std::thread::sleep(Duration::from_secs(3));
    let second = dump();
    for dom in [&first, &second] {
        for text in [
            "Data health",
            "When can I stop?",
            "recording",
            IMUS[0],
            IMUS[1],
            "<svg",
            "ADEV",
            "temperature",
        ] {
            assert!(dom.contains(text), "the page lacks `{text}`");
        }
        assert!(dom.contains("random-walk"), "no targeted term row");
    }
    let (a, b) = (look_number(&first), look_number(&second));
    assert!(b > a, "the page did not update: look {a} then {b}");
    let (ra, rb) = (rows_of_first_imu(&first), rows_of_first_imu(&second));
    assert!(rb > ra, "rows did not grow: {ra} then {rb}");
    // A screenshot of the page as a browser draws it.
    let shot = dir.path().join("watch.png");
    let mut c = chromium(profile.path());
    c.arg(format!("--screenshot={}", shot.display()))
        .args(["--window-size=1200,2200", &url]);
    run(c);
    let png = std::fs::read(&shot).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 20_000,
        "{} bytes",
        png.len()
    );
    if let Ok(target) = std::env::var("IMULAB_WATCH_SCREENSHOT") {
        std::fs::copy(&shot, target).unwrap();
    }
    stop.store(true, Ordering::Relaxed);
    writer.join().unwrap();
}

/// The health table of two IMUs and a receiver fits a 1200 px wide window: Chromium lays out
/// the static page (`--once --html`) with a line of script added that writes the table's
/// right edge into the DOM it dumps.
#[test]
fn chromium_lays_the_health_table_out_within_1200_px() {
    if chromium_missing("the browser check") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("run");
    let mut live = LiveSession::create(&session, mono_now());
    live.append(300.0);
    live.event(IMUS[0], imulab::store::EventKind::Resync, "count=2");
    live.event(IMUS[1], imulab::store::EventKind::Reconnect, "reopened");
    live.append(30.0);
    let html = dir.path().join("page.html");
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("watch")
        .arg(&session)
        .arg("--once")
        .arg("--html")
        .arg(&html)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    live.close();
    let page = std::fs::read_to_string(&html).unwrap();
    let measure = "<script>const t=document.getElementById('health');\
         document.body.setAttribute('data-health-right',Math.ceil(t.getBoundingClientRect().right));\
         document.body.setAttribute('data-page-width',document.documentElement.scrollWidth);</script></body>";
    std::fs::write(&html, page.replace("</body>", measure)).unwrap();
    let profile = tempfile::tempdir().unwrap();
    let mut c = chromium(profile.path());
    c.args(["--window-size=1200,900", "--dump-dom"])
        .arg(format!("file://{}", html.display()));
    let out = run(c);
    let dom = String::from_utf8_lossy(&out.stdout);
    let attribute = |name: &str| -> f64 {
        dom.split(&format!("{name}=\""))
            .nth(1)
            .and_then(|r| r.split('"').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no {name} in the dumped page"))
    };
    let (right, width) = (attribute("data-health-right"), attribute("data-page-width"));
    println!("health table right edge {right} px, page width {width} px in a 1200 px window");
    assert!(right <= 1200.0, "the health table ends at {right} px");
    assert!(width <= 1200.0, "the page is {width} px wide");
}
