//! `/events` in a live writer's session: written as whole chunks, the incomplete chunk only
//! when due, so a session with a steady trickle of events does not store the same events
//! chunk again and again (each earlier copy stays in the file as dead space).

use std::path::Path;

use crate::common::*;
use crate::space::bytes_outside_chunks;
use imulab::store::{EventKind, EventRecord, Session, SessionWriter, WriterOptions};

/// Writes `seconds` of data the way imulogd hands it over: every 0.1 s a batch per device
/// and `maybe_flush_and_rotate` at its time; `imu_b` and `gps` start 3.3 s and 6.6 s after
/// `imu_a` (so their chunks complete at other flushes), and an event every `event_every`
/// batches. Returns the session's only chunk file.
pub fn write_daemon_like(dir: &Path, seconds: usize, event_every: usize) -> std::path::PathBuf {
    let opts = WriterOptions {
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    let mut w = SessionWriter::create(dir, manifest(), opts).unwrap();
    let mut next_gnss = 33;
    for batch in 0..seconds * 10 {
        let i = batch * 10;
        w.append_imu(
            "imu_a",
            &(i..i + 10).map(|k| imu_row(0, k)).collect::<Vec<_>>(),
        )
        .unwrap();
        if i >= 330 {
            let rows: Vec<_> = (i..i + 10).map(|k| imu_row(1, k)).collect();
            w.append_imu("imu_b", &rows).unwrap();
        }
        let now = imu_row(0, i + 9).t_mono_ns;
        let mut fixes = Vec::new();
        while gnss_row(next_gnss).t_mono_ns <= now {
            fixes.push(gnss_row(next_gnss));
            next_gnss += 1;
        }
        w.append_gnss("gps", &fixes).unwrap();
        if batch % event_every == 0 {
            w.append_event(&EventRecord {
                t_mono_ns: now,
                t_wall_ns: 0,
                device: "imu_a".into(),
                kind: EventKind::ChecksumError,
                detail: format!("count=1 bad frame at batch {batch}"),
            })
            .unwrap();
        }
        w.maybe_flush_and_rotate(now).unwrap();
    }
    let dir = w.close().unwrap();
    let s = Session::open(&dir).unwrap();
    let files = s.files();
    assert_eq!(files.len(), 1, "{files:?}");
    files[0].path.clone()
}

/// One event a second for 5 minutes of two 100 Hz IMUs and a 5 Hz GNSS written like
/// imulogd writes them. Bytes outside chunks are metadata and dead copies; the same session
/// with only its first event has the same metadata (to a kilobyte), so the difference is
/// what the events cost outside their chunks. Storing the incomplete events chunk with
/// every data chunk written made that 48 963 bytes (`h5stat -S` unaccounted: 61 142 bytes
/// of 1.14 MB); storing it once its oldest event has waited a chunk interval, 17 791
/// (unaccounted 29 970 bytes).
#[test]
fn a_trickle_of_events_does_not_store_the_events_chunk_again_and_again() {
    let tmp = tempfile::tempdir().unwrap();
    let measure = |name: &str, event_every: usize| {
        let file = write_daemon_like(&tmp.path().join(name), 300, event_every);
        let (size, outside) = bytes_outside_chunks(&file);
        eprintln!("{}: {size} bytes, {outside} outside chunks", file.display());
        if let Ok(keep) = std::env::var("IMULAB_KEEP_EVENTS_SESSION") {
            std::fs::copy(&file, format!("{keep}-{name}.h5")).unwrap();
        }
        outside
    };
    let trickle = measure("trickle", 10);
    let one = measure("one", usize::MAX);
    // Deterministic sizes: 17 791 now, 48 963 with the chunk stored with every data chunk.
    let cost = trickle.saturating_sub(one);
    if super::results::requested() {
        let row = super::results::Row::new(
            "store-events",
            super::results::ACQUISITION,
            3,
            "`/events` space",
            "docs/bench/store.md",
        )
        .data("5 min, 300 events")
        .ours(format!("{cost} B"))
        .target("≤ 25 000 B")
        .met(cost <= 25_000)
        .command(format!(
            "IMULAB_BENCH_RESULTS=benches/results cargo test{} --test store events::",
            if cfg!(debug_assertions) {
                ""
            } else {
                " --release"
            }
        ));
        super::results::write(
            "store_events",
            "test",
            serde_json::json!({ "seconds": 300, "event_every_s": 10 }),
            serde_json::json!({ "outside_chunks_trickle": trickle, "outside_chunks_one_event": one, "cost": cost }),
            &[row],
        );
    }
    assert!(
        cost <= 25_000,
        "300 events cost {cost} bytes outside their chunks ({trickle} vs {one} with one event)"
    );
}
