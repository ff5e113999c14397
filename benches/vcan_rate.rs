//! How many classic CAN frames per second a vcan interface delivers without loss to one async
//! (tokio) reader, against the offered rate and the reader's socket receive buffer.
//!
//! Needs a kernel with vcan (the host has none): run it in the QEMU guest,
//! `tests/vcan/run-in-guest.sh -- target/release/deps/vcan_rate-<hash>` (see docs/vcan.md and
//! docs/bench/vcan.md). Without vcan0 it prints that it skipped and exits 0.
//! Prints one table row per (receive buffer, offered rate): frames sent, received, lost, and the
//! rate actually achieved.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use socketcan::{CanDataFrame, CanFrame, CanInterface, EmbeddedFrame, Socket, SocketOptions};
use socketcan::{Id, StandardId};

const INTERFACE: &str = "imuv_bench";
/// How long each rate is offered.
const RUN_TIME: Duration = Duration::from_secs(2);
/// Once the sender is done, a reader that sees nothing for this long has got everything it will get
/// (vcan delivers in the sender's own system call, so nothing is in flight by then).
const QUIET_TIME: Duration = Duration::from_millis(300);

struct RunResult {
    sent: u64,
    received: u64,
    send_seconds: f64,
}

/// Offers `rate` frames/s (0: as fast as the sender can) for `RUN_TIME` to one tokio reader whose
/// socket has `receive_buffer` bytes (0: the kernel default) and counts what arrives.
fn run_once(
    runtime: &tokio::runtime::Runtime,
    rate: u64,
    receive_buffer: i32,
) -> Result<RunResult, String> {
    let receiver = runtime.block_on(async {
        let socket = socketcan::tokio::CanSocket::open(INTERFACE)
            .map_err(|e| format!("opening reader: {e}"))?;
        if receive_buffer > 0 {
            socket
                .set_socket_option_int(libc::SOL_SOCKET, libc::SO_RCVBUFFORCE, receive_buffer)
                .map_err(|e| format!("SO_RCVBUFFORCE: {e}"))?;
        }
        Ok::<_, String>(socket)
    })?;
    let sender_done = Arc::new(AtomicBool::new(false));
    let reader_sees_done = Arc::clone(&sender_done);
    let reader = runtime.spawn(async move {
        let mut received = 0u64;
        loop {
            match tokio::time::timeout(QUIET_TIME, receiver.read_frame()).await {
                Ok(Ok(_)) => received += 1,
                Ok(Err(e)) => return Err(format!("read error after {received} frames: {e}")),
                Err(_) if reader_sees_done.load(Ordering::Acquire) => return Ok(received),
                Err(_) => {}
            }
        }
    });

    let sender =
        socketcan::CanSocket::open(INTERFACE).map_err(|e| format!("opening sender: {e}"))?;
    sender
        .set_filter_drop_all()
        .map_err(|e| format!("sender filter: {e}"))?;
    let id = Id::Standard(StandardId::new(0x123).ok_or("bad id")?);
    let started = Instant::now();
    let mut sent = 0u64;
    while started.elapsed() < RUN_TIME {
        if rate > 0 {
            // Send what is due, then sleep 1 ms: the reader needs the CPU too (one vCPU).
            let due = (started.elapsed().as_secs_f64() * rate as f64) as u64;
            if sent >= due {
                std::thread::sleep(Duration::from_millis(1));
                continue;
            }
        }
        let frame = CanDataFrame::new(id, &sent.to_le_bytes()).ok_or("frame")?;
        sender
            .write_frame_insist(&CanFrame::Data(frame))
            .map_err(|e| format!("writing frame {sent}: {e}"))?;
        sent += 1;
    }
    let send_seconds = started.elapsed().as_secs_f64();
    sender_done.store(true, Ordering::Release);
    let received = runtime
        .block_on(reader)
        .map_err(|e| format!("reader task: {e}"))??;
    Ok(RunResult {
        sent,
        received,
        send_seconds,
    })
}

fn main() {
    if !std::path::Path::new("/sys/class/net/vcan0").exists() {
        println!(
            "vcan_rate: SKIPPED: no vcan0 here (this kernel has no CAN); run it in the guest: \
             tests/vcan/run-in-guest.sh -- <this binary>"
        );
        return;
    }
    if let Err(e) = run() {
        eprintln!("vcan_rate: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    if let Ok(stale) = CanInterface::open(INTERFACE) {
        let _ = stale.delete();
    }
    let link = CanInterface::create_vcan(INTERFACE, None).map_err(|e| format!("create: {e}"))?;
    link.bring_up().map_err(|e| format!("up: {e}"))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| format!("tokio runtime: {e}"))?;

    println!(
        "| receive buffer | offered (frames/s) | sent | received | lost | achieved (frames/s) |"
    );
    println!("|---|---|---|---|---|---|");
    for (buffer_label, buffer) in [("default", 0), ("16 MiB", 16 << 20)] {
        for rate in [1_000u64, 2_000, 5_000, 10_000, 20_000, 0] {
            let result = run_once(&runtime, rate, buffer)?;
            let offered = if rate == 0 {
                "unpaced".to_string()
            } else {
                rate.to_string()
            };
            println!(
                "| {buffer_label} | {offered} | {} | {} | {} | {:.0} |",
                result.sent,
                result.received,
                result.sent.saturating_sub(result.received),
                result.received as f64 / result.send_seconds
            );
        }
    }
    link.delete().map_err(|(_, e)| format!("delete: {e}"))?;
    Ok(())
}
