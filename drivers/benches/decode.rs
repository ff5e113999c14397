//! Decode throughput of the GNSS codecs on one core: NMEA, UBX and the mixed decoder over
//! synthetic streams built with the encoders (and the gpsd captures when present), pushed in
//! 64 KiB chunks as a file replay would. Prints MB/s and frames/s per codec.
//!
//! Run: `cargo bench -p imulab-drivers --bench decode` (release profile).

#[path = "../../benches/support/results.rs"]
mod results;

use serde_json::json;
use std::sync::Mutex;
use std::time::Instant;

/// A codec's name, MB in, MB/s of CPU, MB/s of wall and frames/s of CPU.
type Measured = (String, f64, f64, f64, f64);

/// Every codec's figures as printed.
static MEASURED: Mutex<Vec<Measured>> = Mutex::new(Vec::new());

use imulab_drivers::codec::gnss::GnssDecoder;
use imulab_drivers::codec::nmea::NmeaDecoder;
use imulab_drivers::codec::ubx::{parse_message, UbxDecoder, UbxEncoder};
use imulab_drivers::codec::{Decoder, Encoder};

const TARGET_BYTES: usize = 48 << 20;
const CHUNK: usize = 64 << 10;

/// One 1 Hz NMEA reporting cycle of a typical u-blox receiver.
fn nmea_cycle(second: u32) -> Vec<u8> {
    let hhmmss = format!(
        "{:02}{:02}{:02}",
        12 + second / 3600 % 12,
        second / 60 % 60,
        second % 60
    );
    let bodies = [
        format!("GNRMC,{hhmmss}.00,A,4404.12845,N,12118.85848,W,0.011,,251018,,,A"),
        "GNVTG,,T,,M,0.011,N,0.020,K,A".to_string(),
        format!("GNGGA,{hhmmss}.00,4404.12845,N,12118.85848,W,1,12,0.67,1132.8,M,-22.2,M,,"),
        "GNGSA,A,3,10,12,14,20,25,31,32,,,,,,1.21,0.67,1.01".to_string(),
        "GPGSV,3,1,11,10,60,045,44,12,35,300,40,14,20,120,35,20,70,200,46".to_string(),
        "GPGSV,3,2,11,25,30,250,38,31,45,080,42,32,15,320,30,02,05,010,".to_string(),
        format!("GNGLL,4404.12845,N,12118.85848,W,{hhmmss}.00,A,A"),
        format!("GNGST,{hhmmss}.00,12,1.2,0.9,45,0.95,1.1,2.1"),
    ];
    let mut out = Vec::new();
    for body in bodies {
        let ck = body.bytes().fold(0u8, |a, b| a ^ b);
        out.extend_from_slice(format!("${body}*{ck:02X}\r\n").as_bytes());
    }
    out
}

/// One UBX epoch: NAV-PVT, NAV-SAT with 20 satellites and 10 ESF-MEAS messages.
fn ubx_epoch(itow: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut pvt = vec![0u8; 92];
    pvt[..4].copy_from_slice(&itow.to_le_bytes());
    pvt[20] = 3;
    pvt[24..28].copy_from_slice(&(-1_213_143_091i32).to_le_bytes());
    pvt[28..32].copy_from_slice(&440_688_095i32.to_le_bytes());
    let mut sat = vec![0u8; 8 + 12 * 20];
    sat[..4].copy_from_slice(&itow.to_le_bytes());
    sat[5] = 20;
    let mut esf = vec![0u8; 8 + 4 * 7];
    esf[4..6].copy_from_slice(&(7u16 << 11).to_le_bytes());
    let mut msgs = vec![
        parse_message(0x01, 0x07, &pvt),
        parse_message(0x01, 0x35, &sat),
    ];
    for _ in 0..10 {
        msgs.push(parse_message(0x10, 0x02, &esf));
    }
    for m in &msgs {
        if UbxEncoder.encode(m, &mut out).is_err() {
            eprintln!("bench: could not encode {m:?}");
        }
    }
    out
}

fn build(mut epoch: impl FnMut(u32) -> Vec<u8>) -> Vec<u8> {
    let mut out = Vec::with_capacity(TARGET_BYTES + 4096);
    let mut i = 0;
    while out.len() < TARGET_BYTES {
        out.extend_from_slice(&epoch(i));
        i += 1;
    }
    out
}

/// CPU time this thread has run, in seconds (Linux `/proc/thread-self/schedstat`), so the
/// figures hold on a shared, loaded machine; `None` elsewhere.
fn thread_cpu_s() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns / 1e9)
}

fn run<D: Decoder>(name: &str, data: &[u8], mut decoder: D) {
    // Best of 3 passes, by on-CPU time when available (wall time otherwise).
    let (mut best_cpu, mut best_wall) = (f64::INFINITY, f64::INFINITY);
    let mut frames = 0u64;
    for _ in 0..3 {
        let mut n = 0u64;
        let cpu0 = thread_cpu_s();
        let start = Instant::now();
        for chunk in data.chunks(CHUNK) {
            decoder.decode(chunk, |f| {
                std::hint::black_box(&f);
                n += 1;
            });
        }
        best_wall = best_wall.min(start.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (cpu0, thread_cpu_s()) {
            best_cpu = best_cpu.min(b - a);
        }
        frames = n;
    }
    let secs = if best_cpu.is_finite() {
        best_cpu
    } else {
        best_wall
    };
    let stats = decoder.stats();
    MEASURED.lock().expect("measured").push((
        name.to_string(),
        data.len() as f64 / 1e6,
        data.len() as f64 / 1e6 / secs,
        data.len() as f64 / 1e6 / best_wall,
        frames as f64 / secs,
    ));
    println!(
        "| {name:<28} | {:>6.1} | {:>8.0} | {:>8.0} | {:>10.0} | {:>8} |",
        data.len() as f64 / 1e6,
        data.len() as f64 / 1e6 / secs,
        data.len() as f64 / 1e6 / best_wall,
        frames as f64 / secs,
        stats.checksum_errors + stats.frames_malformed + stats.frames_too_long,
    );
}

fn main() {
    let nmea = build(nmea_cycle);
    let ubx = build(|i| ubx_epoch(i * 1000));
    let mixed = build(|i| {
        let mut v = ubx_epoch(i * 1000);
        v.extend_from_slice(&nmea_cycle(i));
        v
    });
    println!("| codec / stream               |     MB | MB/s cpu | MB/s wall | frames/s cpu | rejected |");
    println!("|------------------------------|-------:|---------:|----------:|-------------:|---------:|");
    run("nmea (NmeaDecoder)", &nmea, NmeaDecoder::new());
    run("ubx (UbxDecoder)", &ubx, UbxDecoder::new());
    run("nmea (GnssDecoder, fixes)", &nmea, GnssDecoder::new());
    run("ubx (GnssDecoder, fixes)", &ubx, GnssDecoder::new());
    run("nmea+ubx (GnssDecoder)", &mixed, GnssDecoder::new());

    // Same search order as the gpsd capture test.
    let gpsd = std::env::var("IMULAB_EXTERNAL")
        .ok()
        .map(|p| std::path::Path::new(&p).join("gpsd"))
        .into_iter()
        .chain([
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/external/gpsd"),
            std::path::PathBuf::from("/work/shared/external/gpsd"),
        ])
        .find(|p| p.is_dir());
    if let Some(dir) = gpsd {
        let mut all = Vec::new();
        if let Ok(entries) = std::fs::read_dir(&dir) {
            for e in entries.flatten() {
                if e.path().extension().is_some_and(|x| x == "log") {
                    all.extend(std::fs::read(e.path()).unwrap_or_default());
                }
            }
        }
        let once = all.len();
        while !all.is_empty() && all.len() < TARGET_BYTES {
            all.extend_from_within(..once);
        }
        run("gpsd captures (GnssDecoder)", &all, GnssDecoder::new());
    }
    let measured = MEASURED.lock().expect("measured").clone();
    let rate = |name: &str| {
        measured
            .iter()
            .find(|m| m.0 == name)
            .map_or(f64::NAN, |m| m.2)
    };
    let (nmea, ubx) = (rate("nmea (NmeaDecoder)"), rate("ubx (UbxDecoder)"));
    let gpsd = measured.iter().any(|m| m.0.starts_with("gpsd"));
    let row = results::Row::new(
        "decode-gnss",
        results::ACQUISITION,
        6,
        "NMEA / UBX decode",
        "docs/bench/drivers.md",
    )
    .data(if gpsd {
        "gpsd captures + simulated"
    } else {
        "simulated"
    })
    .ours(format!("{nmea:.0} / {ubx:.0} MB/s"))
    .target("≥ 200 / 500 MB/s")
    .met(nmea >= 200.0 && ubx >= 500.0)
    .timed()
    .command("cargo bench -p imulab-drivers --bench decode");
    results::write(
        "decode",
        "gnss",
        json!({ "chunk_bytes": CHUNK, "target_bytes": TARGET_BYTES }),
        json!({ "codecs": measured.iter().map(|m| json!({
            "codec": m.0, "mb": m.1, "mb_per_cpu_s": m.2, "mb_per_wall_s": m.3, "frames_per_cpu_s": m.4,
        })).collect::<Vec<_>>() }),
        &[row],
    );
}
