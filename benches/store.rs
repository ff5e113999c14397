//! Session store benchmark (issue 3): writes H hours (default 6) of 2 IMUs at 150 Hz and one
//! GNSS receiver at 10 Hz in the daemon's batch size (150 IMU rows per append, 1 s of data),
//! then streams it back. Prints CPU time, MB on disk against the raw row size, and reader
//! rows/s, for several deflate levels and chunk sizes. Case 0 is the default layout (10 s
//! chunks, 1 s flushes into the write-ahead journal); case 1 the layout before the journal
//! (1 s chunks, an HDF5 flush every second), as the peer in the same run.
//!
//! Run: `cargo bench --bench store` (full matrix), or `cargo bench --bench store -- --hours 1`.
//! `--only 0,3` runs only those cases (numbered from 0 in table order); `--no-read` skips
//! the reader tables (whole rows of every stream from the first case; then the IMU rows of
//! the first case and of the 10 s chunk case, as whole rows and as the analysis' columns).

#[path = "support/results.rs"]
mod results;

use serde_json::json;
use std::path::Path;
use std::time::{Duration, Instant};

use imulab::store::{
    DeviceInfo, DeviceKind, GnssRecord, ImuColumnSet, ImuColumns, ImuRecord, Manifest, Session,
    SessionWriter, TimeRange, WriterOptions,
};
use imulab_drivers::types::FixType;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

const IMU_HZ: usize = 150;
const GNSS_HZ: usize = 10;
/// Bytes of one IMU row's fields (t_mono, t_wall, t_sensor, gyro×3, accel×3, temp: 8 B each; status 4 B).
const IMU_ROW_BYTES: u64 = 10 * 8 + 4;
/// Bytes of one GNSS row's fields (13 f64/i64 incl. vel×3, week u16, fix u8, sats u8).
const GNSS_ROW_BYTES: u64 = 15 * 8 + 2 + 1 + 1;

fn cpu_seconds() -> f64 {
    let mut ru = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given; RUSAGE_SELF is always valid.
    let ru = unsafe {
        libc::getrusage(libc::RUSAGE_SELF, ru.as_mut_ptr());
        ru.assume_init()
    };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

fn device(name: &str, kind: DeviceKind, rate_hz: usize) -> DeviceInfo {
    DeviceInfo {
        name: name.into(),
        kind,
        model: "bench".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz: rate_hz as f64,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    }
}

/// One minute of noisy IMU rows (a tactical-grade-like noise floor on a bench), reused with
/// shifted times so generating data costs almost nothing inside the timed loop.
fn imu_pool(seed: u64) -> Vec<ImuRecord> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let gyro_noise = Normal::new(0.0, 2e-3).unwrap_or_else(|_| unreachable!());
    let accel_noise = Normal::new(0.0, 5e-3).unwrap_or_else(|_| unreachable!());
    (0..60 * IMU_HZ)
        .map(|i| ImuRecord {
            t_mono_ns: 0,
            t_wall_ns: 0,
            t_sensor: i as f64,
            gyro: [0, 1, 2].map(|k| 1e-4 * k as f64 + gyro_noise.sample(&mut rng)),
            accel: [0.0, 0.0, -9.80665].map(|g| g + accel_noise.sample(&mut rng)),
            temp: 25.0 + 0.01 * (i as f64 / 900.0).sin(),
            status: 0,
        })
        .collect()
}

fn gnss_row(i: usize, t: i64) -> GnssRecord {
    GnssRecord {
        t_mono_ns: t,
        t_wall_ns: t + 1_700_000_000_000_000_000,
        week: 2390,
        tow_s: 100_000.0 + i as f64 * 0.1,
        utc_ns: t + 1_700_000_000_000_000_000,
        lat_deg: 52.0 + 1e-9 * (i % 97) as f64,
        lon_deg: 4.0 + 1e-9 * (i % 89) as f64,
        height_m: 10.0 + 0.01 * (i % 31) as f64,
        vel_ned: [0.01, -0.02, 0.005],
        h_acc_m: 1.2,
        v_acc_m: 2.1,
        s_acc_mps: 0.1,
        fix_type: FixType::Fix3D,
        num_sats: 14,
        pdop: 1.3,
        hdop: 0.7,
        vdop: 1.1,
        heading_deg: f64::NAN,
    }
}

struct Case {
    label: &'static str,
    deflate: u8,
    flush: Duration,
    chunk: Duration,
    rows_per_chunk: Option<usize>,
    fsync: bool,
}

struct Written {
    rows: u64,
    raw_bytes: u64,
    disk_bytes: u64,
    files: usize,
    cpu_s: f64,
    wall_s: f64,
}

fn write(dir: &Path, hours: f64, case: &Case, pools: &[Vec<ImuRecord>; 2]) -> Written {
    let manifest = Manifest::new(
        vec![
            device("imu0", DeviceKind::Imu, IMU_HZ),
            device("imu1", DeviceKind::Imu, IMU_HZ),
            device("gnss0", DeviceKind::Gnss, GNSS_HZ),
        ],
        toml::Table::new(),
    );
    let opts = WriterOptions {
        deflate_level: case.deflate,
        flush_interval: case.flush,
        chunk_interval: case.chunk,
        rows_per_chunk: case.rows_per_chunk,
        // 6 h of data time pass in seconds here; per-flush fsyncs mostly measure the disk,
        // not the store (a live daemon does one per flush), so most cases leave them off.
        fsync_on_flush: case.fsync,
        ..WriterOptions::default()
    };
    let seconds = (hours * 3600.0) as usize;
    let period = 1_000_000_000 / IMU_HZ as i64;
    let (cpu0, wall0) = (cpu_seconds(), Instant::now());
    let mut w = SessionWriter::create(dir, manifest, opts).expect("create session");
    let mut batch = Vec::with_capacity(IMU_HZ);
    let mut gnss = Vec::with_capacity(GNSS_HZ);
    for s in 0..seconds {
        for (d, name) in ["imu0", "imu1"].iter().enumerate() {
            batch.clear();
            for k in 0..IMU_HZ {
                let i = s * IMU_HZ + k;
                let mut r = pools[d][i % pools[d].len()];
                r.t_mono_ns = i as i64 * period + d as i64 * 1000;
                r.t_wall_ns = r.t_mono_ns + 1_700_000_000_000_000_000;
                batch.push(r);
            }
            w.append_imu(name, &batch).expect("append imu");
        }
        gnss.clear();
        for k in 0..GNSS_HZ {
            let i = s * GNSS_HZ + k;
            gnss.push(gnss_row(i, i as i64 * 100_000_000 + 500));
        }
        w.append_gnss("gnss0", &gnss).expect("append gnss");
    }
    w.close().expect("close");
    let (cpu_s, wall_s) = (cpu_seconds() - cpu0, wall0.elapsed().as_secs_f64());
    let mut disk_bytes = 0;
    let mut files = 0;
    for e in std::fs::read_dir(dir).expect("list") {
        let e = e.expect("entry");
        disk_bytes += e.metadata().expect("stat").len();
        files += 1;
    }
    let imu_rows = (2 * seconds * IMU_HZ) as u64;
    let gnss_rows = (seconds * GNSS_HZ) as u64;
    Written {
        rows: imu_rows + gnss_rows,
        raw_bytes: imu_rows * IMU_ROW_BYTES + gnss_rows * GNSS_ROW_BYTES,
        disk_bytes,
        files: files - 1,
        cpu_s,
        wall_s,
    }
}

/// Runs `read` on the session in `dir`; returns (the rows it counted, CPU s, wall s).
fn timed_read(dir: &Path, read: impl FnOnce(&Session) -> u64) -> (u64, f64, f64) {
    let (cpu0, wall0) = (cpu_seconds(), Instant::now());
    let rows = read(&Session::open(dir).expect("open"));
    (rows, cpu_seconds() - cpu0, wall0.elapsed().as_secs_f64())
}

/// Streams every row of IMU `name` back as whole rows (`imu_blocks`, HDF5's filter
/// pipeline); returns the row count.
fn imu_rows_as_blocks(s: &Session, name: &str, block_rows: usize) -> u64 {
    let mut rows = 0u64;
    let mut checksum = 0.0;
    for b in s
        .imu_blocks(name, TimeRange::all(), block_rows)
        .expect("imu")
    {
        let b = b.expect("block");
        rows += b.len() as u64;
        checksum += b.gyro.iter().map(|g| g[0]).sum::<f64>();
    }
    std::hint::black_box(checksum);
    rows
}

/// Streams IMU `name` back as the numeric columns an analysis reads (`imu_columns`: t_mono,
/// t_sensor, gyro, accel, temp; chunks decoded directly); returns the row count.
fn imu_rows_as_columns(s: &Session, name: &str, block_rows: usize) -> u64 {
    let set = ImuColumnSet {
        t_sensor: true,
        gyro: true,
        accel: true,
        temp: true,
    };
    let mut reader = s
        .imu_columns(name, TimeRange::all(), block_rows, set)
        .expect("imu");
    let mut rows = 0u64;
    let mut checksum = 0.0;
    let mut b = ImuColumns::default();
    while let Some(r) = reader.next_into(&mut b) {
        r.expect("block");
        rows += b.len() as u64;
        checksum += b.gyro[0].iter().sum::<f64>();
    }
    std::hint::black_box(checksum);
    rows
}

/// Streams every IMU and GNSS row back; returns (rows, CPU s, wall s).
fn read(dir: &Path, block_rows: usize) -> (u64, f64, f64) {
    timed_read(dir, |s| {
        let imu: u64 = ["imu0", "imu1"]
            .iter()
            .map(|name| imu_rows_as_blocks(s, name, block_rows))
            .sum();
        let gnss: u64 = s
            .gnss_blocks("gnss0", TimeRange::all(), block_rows)
            .expect("gnss")
            .map(|b| b.expect("block").len() as u64)
            .sum();
        imu + gnss
    })
}

/// Streams the IMU rows back only, as whole rows or as the analysis' columns. Returns
/// (rows, CPU s, wall s).
fn read_imu(dir: &Path, block_rows: usize, columns: bool) -> (u64, f64, f64) {
    let read_one = if columns {
        imu_rows_as_columns
    } else {
        imu_rows_as_blocks
    };
    timed_read(dir, |s| {
        ["imu0", "imu1"]
            .iter()
            .map(|name| read_one(s, name, block_rows))
            .sum()
    })
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let hours: f64 = args
        .iter()
        .position(|a| a == "--hours")
        .and_then(|i| args.get(i + 1))
        .and_then(|h| h.parse().ok())
        .unwrap_or(6.0);
    // `--only 0,3` runs only those cases (numbered from 0 in the table order).
    let only: Option<Vec<usize>> = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|i| args.get(i + 1))
        .map(|l| l.split(',').filter_map(|x| x.parse().ok()).collect());
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("target/bench-store-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).expect("bench dir");
    let pools = [imu_pool(1), imu_pool(2)];
    let s = Duration::from_secs(1);
    let case = |label, deflate, flush: u64, chunk: u64, fsync| Case {
        label,
        deflate,
        flush: s * flush as u32,
        chunk: s * chunk as u32,
        rows_per_chunk: None,
        fsync,
    };
    let cases = [
        case(
            "deflate 1, flush 1 s, chunk 10 s + journal (default)",
            1,
            1,
            10,
            false,
        ),
        case(
            "deflate 1, flush 1 s, chunk 1 s (old layout, no journal)",
            1,
            1,
            1,
            false,
        ),
        case("default, fsync on", 1, 1, 10, true),
        case("old layout, fsync on", 1, 1, 1, true),
        case(
            "deflate 4, flush 1 s, chunk 10 s + journal",
            4,
            1,
            10,
            false,
        ),
        case(
            "no filters, flush 1 s, chunk 10 s + journal",
            0,
            1,
            10,
            false,
        ),
        case(
            "deflate 1, flush 10 s, chunk 10 s (no journal)",
            1,
            10,
            10,
            false,
        ),
        case(
            "deflate 1, flush 60 s, chunk 60 s (no journal)",
            1,
            60,
            60,
            false,
        ),
        Case {
            rows_per_chunk: Some(200),
            ..case(
                "deflate 1, flush 1 s, chunk 200 rows (misaligned) + journal",
                1,
                1,
                10,
                false,
            )
        },
    ];
    println!("Session store benchmark: {hours} h × 150 Hz × 2 IMUs + 10 Hz GNSS, 150-row appends, fsync off unless said\n");
    println!("| case | rows | raw MB | disk MB | disk/raw | files | write CPU s | write wall s | Mrows/s (CPU) |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut read_dirs = Vec::new();
    // `cargo bench` adds `--bench` to the arguments.
    let given: Vec<&str> = args[1..]
        .iter()
        .map(String::as_str)
        .filter(|a| *a != "--bench")
        .collect();
    let command = format!("cargo bench --bench store -- {}", given.join(" "));
    let mut written = Vec::new();
    for (i, case) in cases.iter().enumerate() {
        if only.as_ref().is_some_and(|o| !o.contains(&i)) {
            continue;
        }
        let dir = root.join(format!("case{i}"));
        let r = write(&dir, hours, case, &pools);
        println!(
            "| {} | {} | {:.1} | {:.1} | {:.3} | {} | {:.2} | {:.2} | {:.2} |",
            case.label,
            r.rows,
            r.raw_bytes as f64 / 1e6,
            r.disk_bytes as f64 / 1e6,
            r.disk_bytes as f64 / r.raw_bytes as f64,
            r.files,
            r.cpu_s,
            r.wall_s,
            r.rows as f64 / r.cpu_s / 1e6
        );
        written.push(json!({
            "case": i, "label": case.label, "rows": r.rows, "raw_bytes": r.raw_bytes,
            "disk_bytes": r.disk_bytes, "files": r.files, "cpu_s": r.cpu_s, "wall_s": r.wall_s,
        }));
        // The default case (1 s chunks) and the 10 s one are read back below.
        if read_dirs.is_empty() || case.flush == 10 * s && case.deflate == 1 {
            read_dirs.push((case.label, dir));
        } else {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    write_results(hours, &written, &command);
    let skip_read = args.iter().any(|a| a == "--no-read");
    let mut reads = Vec::new();
    for (i, (label, dir)) in read_dirs.iter().enumerate() {
        if skip_read {
            break;
        }
        if i == 0 {
            println!(
                "\nReader, session of the first case above, all IMU and GNSS rows streamed back:\n"
            );
            println!("| block rows | rows | CPU s | wall s | Mrows/s (wall) |");
            println!("|---:|---:|---:|---:|---:|");
            for block_rows in [1024, 8192, 65536] {
                let (rows, cpu, wall) = read(dir, block_rows);
                println!(
                    "| {block_rows} | {rows} | {cpu:.2} | {wall:.2} | {:.2} |",
                    rows as f64 / wall / 1e6
                );
            }
            println!("\nReader, IMU rows only, blocks of 65536 rows:\n");
            println!("| session | read | rows | CPU s | wall s | Mrows/s (CPU) |");
            println!("|---|---|---:|---:|---:|---:|");
        }
        for (how, columns) in [
            ("imu_blocks, all columns (HDF5 pipeline)", false),
            (
                "imu_columns: t_mono, t_sensor, gyro, accel, temp (direct chunks)",
                true,
            ),
        ] {
            let (rows, cpu, wall) = read_imu(dir, 65536, columns);
            println!(
                "| {label} | {how} | {rows} | {cpu:.2} | {wall:.2} | {:.2} |",
                rows as f64 / cpu / 1e6
            );
            reads.push(json!({
                "session": label, "columns": columns, "rows": rows, "cpu_s": cpu, "wall_s": wall,
            }));
        }
    }
    read_results(hours, &reads, &command);
    for (_, dir) in &read_dirs {
        let _ = std::fs::remove_dir_all(dir);
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// The writer row: the default layout's CPU time against the layout before the journal
/// (cases 0 and 1), when both ran.
fn write_results(hours: f64, written: &[serde_json::Value], command: &str) {
    let case = |i: u64| written.iter().find(|w| w["case"] == i);
    let (Some(ours), Some(peer)) = (case(0), case(1)) else {
        return;
    };
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    let cpu = f(ours, "cpu_s");
    let row = results::Row::new(
        "store-writer",
        results::ACQUISITION,
        1,
        "writer CPU",
        "docs/bench/store.md",
    )
    .data(format!(
        "{hours} h, 2 IMUs 150 Hz + GNSS, {:.1} M rows",
        f(ours, "rows") / 1e6
    ))
    .ours(format!("{cpu:.2} s, {:.0} MB", f(ours, "disk_bytes") / 1e6))
    .peer(format!("1 s chunks, no journal: {:.2} s", f(peer, "cpu_s")))
    .ratio(format!("{:.1}×", f(peer, "cpu_s") / cpu))
    .target("< 5 s")
    .met(cpu < 5.0)
    .timed()
    .command(command);
    results::write(
        "store",
        "write",
        json!({ "hours": hours, "command": command }),
        json!({ "cases": written }),
        &[row],
    );
}

/// The reader row: the first case's IMU rows as the analysis' columns against whole rows.
fn read_results(hours: f64, reads: &[serde_json::Value], command: &str) {
    let first = reads.first().map(|r| r["session"].clone());
    let pick = |columns: bool| {
        reads
            .iter()
            .find(|r| Some(&r["session"]) == first.as_ref() && r["columns"] == columns)
            .map(|r| {
                r["rows"].as_f64().unwrap_or(f64::NAN)
                    / r["cpu_s"].as_f64().unwrap_or(f64::NAN)
                    / 1e6
            })
    };
    let (Some(columns), Some(rows)) = (pick(true), pick(false)) else {
        return;
    };
    let row = results::Row::new(
        "store-reader",
        results::ACQUISITION,
        2,
        "reader",
        "docs/bench/store.md",
    )
    .data("IMU columns of that session")
    .ours(format!("{columns:.2} M rows/CPU-s"))
    .peer(format!("whole rows: {rows:.2} M"))
    .ratio(format!("{:.1}×", columns / rows))
    .command(command);
    results::write(
        "store",
        "read",
        json!({ "hours": hours, "command": command }),
        json!({ "reads": reads }),
        &[row],
    );
}
