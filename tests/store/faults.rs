//! Fault injection, the way SQLite tests crash safety. A child writer is SIGKILLed at many
//! points of a run (between appends, inside them, across rotations and the journal's
//! fsyncs); the files of a killed session are truncated and overwritten at many offsets.
//! After each fault no reader hangs (`inspect` every time; `export` and `allan` every sixth
//! case, `report`, `watch --once` and `replay` every twelfth; a watchdog fails the test, it
//! times nothing), `recover` succeeds, and every row older than one flush interval that the
//! fault did not destroy is kept, with its exact values. The counts are printed (`--nocapture`) for BENCHMARKS.md.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::common::*;
use imulab::store::{recover, Session, TimeRange, WriterOptions};

const KILL_ENV: &str = "IMULAB_STORE_FAULT_KILL_DIR";
const DAMAGE_ENV: &str = "IMULAB_STORE_FAULT_DAMAGE_DIR";
/// A reader that has not finished by then hangs.
const WATCHDOG: Duration = Duration::from_secs(60);
const FLUSH_NS: i64 = 1_000_000_000;
const IMUS: [&str; 2] = ["imu_a", "imu_b"];

/// GNSS at 5 Hz beside the IMUs' 100 Hz: fix `k` is due with IMU row `20 k`.
fn with_gnss(w: &mut imulab::store::SessionWriter, i: usize) {
    if i.is_multiple_of(20) {
        w.append_gnss("gps", &[gnss_row(i / 20)]).unwrap();
    }
}

/// The writer killed at many points: rotation every 2 s of data, fsync on, so kills land
/// in rotations and journal syncs as well as between appends.
#[test]
fn kill_child_writer() {
    let opts = WriterOptions {
        rotate_after: Duration::from_secs(2),
        fsync_on_flush: true,
        ..WriterOptions::default()
    };
    run_writer_child(KILL_ENV, opts, with_gnss);
}

/// The writer whose session is damaged: 2 s chunks (so the partial file holds rows of its
/// own, not only the journal), rotation every 6 s.
#[test]
fn damage_child_writer() {
    let opts = WriterOptions {
        rotate_after: Duration::from_secs(6),
        chunk_interval: Duration::from_secs(2),
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    run_writer_child(DAMAGE_ENV, opts, with_gnss);
}

/// Runs `f` on another thread and fails the test if it does not return within [`WATCHDOG`].
fn within_watchdog<T: Send + 'static>(what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(WATCHDOG) {
        Ok(v) => v,
        Err(_) => panic!("{what}: no answer within {WATCHDOG:?}: the reader hangs"),
    }
}

/// Runs `imulab ARGS` and fails the test if it does not exit within [`WATCHDOG`] or panics.
/// Returns its exit status and stderr.
fn imulab_within_watchdog(args: &[&str]) -> (bool, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            use std::io::Read;
            child
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut err)
                .unwrap();
            assert_ne!(status.code(), Some(101), "imulab {args:?} panicked: {err}");
            return (status.success(), err);
        }
        if started.elapsed() > WATCHDOG {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("imulab {args:?}: still running after {WATCHDOG:?}: the reader hangs");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Every row of the session, per IMU and of the GNSS, read through [`Session`] under the
/// watchdog. Blocks that fail are skipped (the reader goes on with the other files); the
/// errors are returned, each of which must name its file.
struct Read {
    imu: [Vec<imulab::store::ImuRecord>; 2],
    gnss: Vec<imulab::store::GnssRecord>,
    errors: Vec<String>,
}

fn read_all(dir: &Path) -> Read {
    let dir = dir.to_path_buf();
    within_watchdog(&format!("reading {}", dir.display()), move || {
        let s = Session::open(&dir).unwrap();
        let mut errors = s.problems();
        let mut imu = [Vec::new(), Vec::new()];
        for (d, name) in IMUS.iter().enumerate() {
            for b in s.imu_blocks(name, TimeRange::all(), 1000).unwrap() {
                match b {
                    Ok(b) => imu[d].extend((0..b.len()).map(|k| b.record(k))),
                    Err(e) => errors.push(e.to_string()),
                }
            }
        }
        let mut gnss = Vec::new();
        for b in s.gnss_blocks("gps", TimeRange::all(), 1000).unwrap() {
            match b {
                Ok(b) => gnss.extend((0..b.len()).map(|k| b.record(k))),
                Err(e) => errors.push(e.to_string()),
            }
        }
        Read { imu, gnss, errors }
    })
}

/// Row index of a test row from its time (rows are 10 ms apart from 1 s on).
fn imu_index(t: i64) -> usize {
    ((t - 1_000_000_000) / 10_000_000) as usize
}

/// Every row read holds exactly the values written for its time, in increasing time.
fn check_values(r: &Read) {
    for (d, rows) in r.imu.iter().enumerate() {
        let mut last = None;
        for row in rows {
            let k = imu_index(row.t_mono_ns);
            assert_eq!(*row, imu_row(d, k), "{} row {k}", IMUS[d]);
            assert!(last < Some(k), "{}: row {k} after row {last:?}", IMUS[d]);
            last = Some(k);
        }
    }
    for row in &r.gnss {
        let k = ((row.t_mono_ns - 1_000_000_000) / 200_000_000) as usize;
        assert_eq!(*row, gnss_row(k), "gps fix {k}");
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

#[test]
fn killed_at_many_points_recover_keeps_all_but_the_last_flush_interval() {
    if std::env::var(KILL_ENV).is_ok() || std::env::var(DAMAGE_ENV).is_ok() {
        return;
    }
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    const KILL_POINTS: usize = 24;
    let mut max_lost_rows = 0;
    let mut rebuilt = 0;
    for k in 0..KILL_POINTS {
        let dir = tmp.path().join(format!("kill{k}"));
        let mut child = WriterChild::spawn("faults::kill_child_writer", KILL_ENV, &dir);
        // Data times from 0.05 s to 6.5 s: before the first flush, across three rotations
        // (every 2 s) and six journal flushes; then a spin of 0-0.5 ms lands the kill inside
        // the appends, syncs and rotations of the next batches.
        child.wait_for(imu_row(0, 5 + k * 27).t_mono_ns);
        let spin = Instant::now();
        let spin_for = Duration::from_micros((k as u64 * 137) % 500);
        while spin.elapsed() < spin_for {
            std::hint::spin_loop();
        }
        let last_t = child.kill();
        let report = recover(&dir).unwrap_or_else(|e| panic!("kill point {k}: recover: {e}"));
        rebuilt += report.files.iter().filter(|f| f.rebuilt.is_some()).count();
        let r = read_all(&dir);
        assert!(r.errors.is_empty(), "kill point {k}: {:?}", r.errors);
        check_values(&r);
        for (d, rows) in r.imu.iter().enumerate() {
            // Rows are kept from the first on, without a hole.
            assert!(
                rows.iter()
                    .enumerate()
                    .all(|(i, row)| imu_index(row.t_mono_ns) == i),
                "kill point {k}: {} has a hole",
                IMUS[d]
            );
            let kept_t = rows
                .last()
                .map_or(imu_row(0, 0).t_mono_ns - 10_000_000, |r| r.t_mono_ns);
            assert!(
                last_t - kept_t <= FLUSH_NS,
                "kill point {k}: {} kept {} rows, up to {kept_t} ns; appended up to {last_t} ns",
                IMUS[d],
                rows.len()
            );
            max_lost_rows = max_lost_rows.max(imu_index(last_t) + 1 - rows.len());
        }
        let gnss_t = r
            .gnss
            .last()
            .map_or(gnss_row(0).t_mono_ns - 200_000_000, |g| g.t_mono_ns);
        assert!(
            last_t - gnss_t <= FLUSH_NS + 200_000_000,
            "kill point {k}: GNSS kept up to {gnss_t} ns, appended up to {last_t} ns"
        );
        // Nothing left to recover, and nothing in the way of the next run.
        assert!(recover(&dir).unwrap().files.is_empty(), "kill point {k}");
    }
    eprintln!(
        "fault injection: {KILL_POINTS} kill points, at most {max_lost_rows} rows of an IMU \
         lost (100 Hz, 1 s flush interval); {rebuilt} partial files needed a rebuild from \
         the journal (a kill leaves the HDF5 file repairable)"
    );
    if super::results::requested() {
        // Rows of one IMU in a flush interval (100 Hz, 1 s).
        let interval_rows = (FLUSH_NS / 10_000_000) as usize;
        let row = super::results::Row::new(
            "store-kill",
            super::results::ACQUISITION,
            4,
            "crash",
            "docs/bench/store.md",
        )
        .data(format!("{KILL_POINTS} SIGKILLs of a writer"))
        .ours(format!(
            "≤ {max_lost_rows} rows lost per kill; recover always succeeds"
        ))
        .target("≤ 1 flush interval")
        .met(max_lost_rows <= interval_rows)
        .command(FAULTS_COMMAND);
        super::results::write(
            "store_faults",
            "kill",
            serde_json::json!({ "kill_points": KILL_POINTS, "flush_ns": FLUSH_NS }),
            serde_json::json!({ "max_lost_rows": max_lost_rows, "rebuilt": rebuilt }),
            &[row],
        );
    }
}

/// The command that writes the fault rows' JSON.
const FAULTS_COMMAND: &str = if cfg!(debug_assertions) {
    "IMULAB_BENCH_RESULTS=benches/results cargo test --test store faults::"
} else {
    "IMULAB_BENCH_RESULTS=benches/results cargo test --release --test store faults::"
};

/// How a damaged copy of the session is made.
#[derive(Debug, Clone, Copy)]
enum Damage {
    Truncate(u64),
    Overwrite(u64),
}

fn damage(file: &Path, how: Damage) {
    let f = std::fs::OpenOptions::new().write(true).open(file).unwrap();
    match how {
        Damage::Truncate(at) => f.set_len(at).unwrap(),
        Damage::Overwrite(at) => {
            use std::os::unix::fs::FileExt;
            f.write_all_at(&[0xa5; 64], at).unwrap();
        }
    }
}

/// Offsets spread over a file of `size` bytes: the start, its superblock, and 14 more
/// evenly apart up to its last byte.
fn offsets(size: u64) -> Vec<u64> {
    let mut v = vec![0, 9, 40, 600];
    v.extend((1..=14).map(|i| size * i / 15));
    v.push(size.saturating_sub(1));
    v.retain(|&o| o < size);
    v.dedup();
    v
}

#[test]
fn damaged_files_never_hang_a_reader_and_recover_keeps_what_survives() {
    if std::env::var(KILL_ENV).is_ok() || std::env::var(DAMAGE_ENV).is_ok() {
        return;
    }
    // Held throughout: a child of another test would inherit this test's HDF5 file locks.
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    let killed = tmp.path().join("killed");
    let last_t = write_damage_session(&killed);
    let partial = PathBuf::from(layout_name(2, true));
    let completed = PathBuf::from(layout_name(0, false));
    let journal0 = PathBuf::from(format!("{}.journal0", layout_name(2, false)));
    let journal1 = PathBuf::from(format!("{}.journal1", layout_name(2, false)));
    assert!(killed.join(&partial).exists() && killed.join(&journal0).exists());

    // Before recover, inspect says the journal holds more and what to run.
    let (ok, err) = imulab_within_watchdog(&["inspect", killed.to_str().unwrap()]);
    assert!(
        !ok && err.contains("its journal holds") && err.contains("run `imulab recover"),
        "{err}"
    );
    // Undamaged: what recover keeps, and which rows come from the journal.
    let base = tmp.path().join("base");
    copy_dir(&killed, &base);
    let report = recover(&base).unwrap();
    let from_journal = report.files[0]
        .tables
        .iter()
        .find(|t| t.group == "imu/imu_a")
        .unwrap()
        .rows_from_journal as usize;
    let base_rows = read_all(&base).imu[0].len();
    // Rows of each table of the partial file after the undamaged recovery.
    let base_tables: Vec<(String, u64)> = report.files[0]
        .tables
        .iter()
        .map(|t| (t.group.clone(), t.rows_kept))
        .collect();
    assert!(from_journal > 0 && last_t - imu_row(0, base_rows - 1).t_mono_ns <= FLUSH_NS);
    let journal_first = base_rows - from_journal;

    let mut cases = Vec::new();
    for file in [&partial, &completed, &journal0, &journal1] {
        let Ok(meta) = std::fs::metadata(killed.join(file)) else {
            continue;
        };
        let size = meta.len();
        for at in offsets(size) {
            cases.push((file.clone(), Damage::Truncate(at)));
            cases.push((file.clone(), Damage::Overwrite(at)));
        }
    }
    let (mut truncations, mut overwrites, mut max_lost, mut rebuilt) = (0, 0, 0, 0);
    // Per rebuilt partial file: the damage, and the most rows of a table it lost.
    let mut rebuilds: Vec<(Damage, u64)> = Vec::new();
    for (n, (file, how)) in cases.iter().enumerate() {
        let case = format!("{} {how:?}", file.display());
        let dir = tmp.path().join(format!("case{n}"));
        copy_dir(&killed, &dir);
        damage(&dir.join(file), *how);
        match how {
            Damage::Truncate(_) => truncations += 1,
            Damage::Overwrite(_) => overwrites += 1,
        }
        let d = dir.to_str().unwrap();
        // Readers on the damaged, unrecovered session: they end, and name the file.
        let (_, err) = imulab_within_watchdog(&["inspect", d]);
        if file == &completed {
            let r = read_all(&dir);
            for e in &r.errors {
                assert!(e.contains("chunk-000000.h5"), "{case}: {e}");
            }
            check_values(&r);
        }
        if n.is_multiple_of(6) {
            imulab_within_watchdog(&["export", d, "--device", "imu_a"]);
            imulab_within_watchdog(&["allan", d, "--device", "imu_a", "--kind", "oadev"]);
        }
        if n.is_multiple_of(12) {
            let out = tmp.path().join(format!("case{n}-out"));
            std::fs::create_dir_all(&out).unwrap();
            let html = out.join("report.html");
            let json = out.join("watch.json");
            let (html, json, out) = (
                html.to_str().unwrap(),
                json.to_str().unwrap(),
                out.to_str().unwrap(),
            );
            imulab_within_watchdog(&["report", d, "--html", html, "--study-runs", "0"]);
            imulab_within_watchdog(&["watch", d, "--once", "--json", json]);
            imulab_within_watchdog(&["replay", d, "--imu", "imu_a", "--gnss", "gps", "--out", out]);
        }
        let _ = err;
        // The partial file without its superblock (cut or overwritten at its start) is
        // beyond repair: it must be rebuilt from the journal, and the CLI says so with each
        // table's rows saved and lost.
        let beyond_repair =
            file == &partial && matches!(how, Damage::Truncate(0 | 9 | 40) | Damage::Overwrite(0));
        if beyond_repair && matches!(how, Damage::Truncate(40)) {
            let copy = tmp.path().join(format!("case{n}-cli"));
            copy_dir(&dir, &copy);
            let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
                .arg("recover")
                .arg(&copy)
                .output()
                .unwrap();
            let said = String::from_utf8_lossy(&out.stdout);
            eprintln!("imulab recover ({case}):\n{}", said.trim_end());
            assert!(
                out.status.success(),
                "{case}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            assert!(said.contains("rebuilt from the journal"), "{case}: {said}");
            for name in IMUS {
                let line = said
                    .lines()
                    .find(|l| l.contains(&format!("/imu/{name} ")))
                    .unwrap_or_else(|| panic!("{case}: no line for {name}: {said}"));
                assert!(line.contains("saved") && line.contains("lost"), "{line}");
            }
        }
        let report = recover(&dir).unwrap_or_else(|e| panic!("{case}: recover: {e}"));
        rebuilt += report.files.iter().filter(|f| f.rebuilt.is_some()).count();
        if let Some(f) = report.files.iter().find(|f| f.rebuilt.is_some()) {
            // Every table of the rebuilt file holds the journal's rows, and the rows it had
            // in the undamaged recovery are either saved or counted as lost.
            let mut most_lost = 0;
            for (group, base_kept) in &base_tables {
                let t = f
                    .tables
                    .iter()
                    .find(|t| &t.group == group)
                    .unwrap_or_else(|| panic!("{case}: rebuilt without /{group}"));
                assert_eq!(t.rows_kept, t.rows_from_journal, "{case}: /{group}");
                assert_eq!(t.rows_kept + t.rows_dropped, *base_kept, "{case}: /{group}");
                if group.starts_with("imu/") {
                    most_lost = most_lost.max(t.rows_dropped);
                }
            }
            rebuilds.push((*how, most_lost));
        } else {
            assert!(
                !beyond_repair,
                "{case}: not rebuilt from the journal ({report:?})"
            );
        }
        let r = read_all(&dir);
        check_values(&r);
        if file != &completed {
            // The completed files are untouched, and the journal's rows older than one flush
            // interval are kept whatever happened to the partial file.
            assert!(r.errors.is_empty(), "{case}: {:?}", r.errors);
            let kept: std::collections::BTreeSet<usize> = r.imu[0]
                .iter()
                .map(|row| imu_index(row.t_mono_ns))
                .collect();
            assert!(
                (0..1200).all(|i| kept.contains(&i)),
                "{case}: completed chunks cut"
            );
            if file == &partial {
                let missing: Vec<usize> = (journal_first..base_rows)
                    .filter(|i| !kept.contains(i))
                    .collect();
                assert!(
                    missing.is_empty(),
                    "{case}: journal rows lost: {missing:?} ({report:?})"
                );
            }
            max_lost = max_lost.max(base_rows - r.imu[0].len());
        }
    }
    let rebuilt_truncations: Vec<u64> = rebuilds
        .iter()
        .filter_map(|(how, _)| match how {
            Damage::Truncate(at) => Some(*at),
            Damage::Overwrite(_) => None,
        })
        .collect();
    let rebuilt_lost = rebuilds.iter().map(|(_, lost)| *lost).max().unwrap_or(0);
    eprintln!(
        "fault injection: {truncations} truncations and {overwrites} overwrites of 64 bytes \
         (partial file, completed file, journal); {rebuilt} partial files rebuilt from the \
         journal ({} truncations, at offsets {rebuilt_truncations:?}, and {} overwrites), \
         each rebuilt IMU table losing at most {rebuilt_lost} of its rows (those the HDF5 file \
         held and the journal no longer did); at most {max_lost} of {base_rows} rows of an IMU \
         lost against the undamaged recovery",
        rebuilt_truncations.len(),
        rebuilds.len() - rebuilt_truncations.len(),
    );
    if super::results::requested() {
        let row = super::results::Row::new(
            "store-damage",
            super::results::ACQUISITION,
            5,
            "damaged files",
            "docs/bench/store.md",
        )
        .data(format!("{truncations} truncations, {overwrites} overwrites"))
        .ours(format!(
            "no reader hangs; ≤ {max_lost} of {base_rows} rows lost, {rebuilt} rebuilt from the journal"
        ))
        .target("recover keeps what survives")
        .met(rebuilt >= 4)
        .command(FAULTS_COMMAND);
        super::results::write(
            "store_faults",
            "damage",
            serde_json::json!({ "truncations": truncations, "overwrites": overwrites }),
            serde_json::json!({
                "rebuilt": rebuilt, "rebuilt_lost_max": rebuilt_lost, "max_lost": max_lost,
                "base_rows": base_rows,
            }),
            &[row],
        );
    }
    assert!(rebuilt >= 4, "{rebuilt} rebuilt");
}

fn layout_name(index: u32, partial: bool) -> String {
    if partial {
        imulab::store::layout::partial_file_name(index)
    } else {
        imulab::store::layout::chunk_file_name(index)
    }
}

/// Writes 15.35 s of data into `dir` and kills the writer: chunk files 0 (0-6 s) and 1
/// (6-12 s) complete, the partial file 2 holding 12-14 s, its journal the rest. Returns the
/// last data time appended.
fn write_damage_session(dir: &Path) -> i64 {
    let mut child = WriterChild::spawn("faults::damage_child_writer", DAMAGE_ENV, dir);
    child.wait_for(imu_row(0, 1535).t_mono_ns);
    child.kill()
}

fn free_bytes(dir: &Path) -> u64 {
    let st = nix::sys::statvfs::statvfs(dir).unwrap();
    st.blocks_available() as u64 * st.fragment_size() as u64
}

/// Unmounts the test's tmpfs when the test ends, however it ends.
struct Unmount(PathBuf);

impl Drop for Unmount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

#[test]
fn recover_on_a_full_disk_says_what_is_missing_and_leaves_the_session_as_it_was() {
    if std::env::var(KILL_ENV).is_ok() || std::env::var(DAMAGE_ENV).is_ok() {
        return;
    }
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    let mnt = tmp.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=8m", "tmpfs"])
        .arg(&mnt)
        .stderr(Stdio::piped())
        .output();
    match mounted {
        Ok(out) if out.status.success() => {}
        Ok(out) => {
            eprintln!(
                "skipped: cannot mount an 8 MiB tmpfs here ({}); the test needs root, as in CI",
                String::from_utf8_lossy(&out.stderr).trim()
            );
            return;
        }
        Err(e) => {
            eprintln!("skipped: cannot run mount ({e}); the test needs root, as in CI");
            return;
        }
    }
    let _unmount = Unmount(mnt.clone());
    let dir = mnt.join("session");
    let last_t = write_damage_session(&dir);
    // Every file but the dead writer's lock, which recover clears.
    let files = |dir: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| !p.ends_with("writer.lock"))
            .collect();
        v.sort();
        v
    };
    let before: Vec<(PathBuf, Vec<u8>)> = files(&dir)
        .into_iter()
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap();
            (p, bytes)
        })
        .collect();
    // Fill the disk, leaving 32 KiB.
    let filler = mnt.join("filler");
    {
        use std::io::Write;
        let mut f = std::fs::File::create(&filler).unwrap();
        let block = vec![0x5a_u8; 1 << 16];
        while f.write_all(&block).is_ok() {}
        let len = f.metadata().unwrap().len();
        f.set_len(len.saturating_sub(32 << 10)).unwrap();
    }
    let have = free_bytes(&mnt);
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(["recover", dir.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "recover on a full disk succeeded: {err}"
    );
    assert!(
        err.contains(&format!("no space left on {}", mnt.display()))
            && err.contains("need ")
            && err.contains(", have "),
        "{err}"
    );
    eprintln!("full disk ({have} bytes free): {}", err.trim());
    // The session is exactly as it was, with nothing added.
    let after = files(&dir);
    assert_eq!(
        after.len(),
        before.len(),
        "files added or removed: {after:?}"
    );
    for (p, bytes) in &before {
        assert!(
            std::fs::read(p).unwrap() == *bytes,
            "{} changed",
            p.display()
        );
    }
    // With room again, recover keeps all but the last flush interval.
    std::fs::remove_file(&filler).unwrap();
    recover(&dir).unwrap();
    let r = read_all(&dir);
    assert!(r.errors.is_empty(), "{:?}", r.errors);
    check_values(&r);
    let kept_t = r.imu[0].last().unwrap().t_mono_ns;
    assert!(
        last_t - kept_t <= FLUSH_NS,
        "kept up to {kept_t}, appended {last_t}"
    );
}
