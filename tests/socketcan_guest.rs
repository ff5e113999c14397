//! SocketCAN tests against a real kernel CAN stack (vcan), for the stack and `socketcan` crate the
//! project's CAN transport runs on.
//!
//! The development and CI host kernels have no CAN at all, so these tests skip (printing why) unless
//! `vcan0` exists; `tests/vcan/run-in-guest.sh` (used by `.ci/vcan`) boots a Debian kernel under QEMU
//! with vcan0 up and runs this binary there. In the guest (`IMULAB_VCAN_GUEST=1`) a missing vcan0 is
//! a failure, not a skip. Each test makes its own vcan interface through netlink, because libtest runs
//! tests in parallel and frames on a shared interface would reach every test's sockets.

use std::collections::HashMap;
use std::io;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use imulab_drivers::codec::candump::CandumpDecoder;
use imulab_drivers::codec::Decoder;
use imulab_drivers::transport::socketcan::{from_socketcan, SocketCanTransport};
use socketcan::dump::Reader as SocketcanDumpReader;
use socketcan::{
    CanAnyFrame, CanDataFrame, CanError, CanErrorFrame, CanFrame, CanInterface, CanRemoteFrame,
    CanSocket, EmbeddedFrame, ErrorCause, ExtendedId, Frame, Id, Socket, SocketOptions, StandardId,
};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// Frames in the burst test.
const BURST_FRAMES: u32 = 10_000;
/// Longest any single wait in these tests may take before it counts as a hang.
const HANG_LIMIT: Duration = Duration::from_secs(20);

/// True when a kernel CAN stack with vcan0 is present. Otherwise prints why the test is skipped and
/// returns false; inside the QEMU guest a missing vcan0 is a harness bug and panics.
fn vcan_present(test: &str) -> bool {
    if Path::new("/sys/class/net/vcan0").exists() {
        return true;
    }
    assert!(
        std::env::var_os("IMULAB_VCAN_GUEST").is_none(),
        "{test}: running in the vcan guest but /sys/class/net/vcan0 does not exist"
    );
    // Straight to stderr, not eprintln!: libtest captures the print macros of passing tests, and a
    // skip must be seen.
    let _ = writeln!(
        io::stderr(),
        "{test}: SKIPPED: no vcan0 here (this kernel has no CAN); \
         run it in the QEMU guest with .ci/vcan or tests/vcan/run-in-guest.sh"
    );
    false
}

/// A vcan interface made for one test, up while it lives and deleted on drop.
struct TestInterface {
    name: &'static str,
    link: Option<CanInterface>,
}

impl TestInterface {
    fn create(name: &'static str) -> Self {
        // A previous run that crashed may have left it behind.
        if let Ok(stale) = CanInterface::open(name) {
            let _ = stale.delete();
        }
        let link = CanInterface::create_vcan(name, None)
            .unwrap_or_else(|e| panic!("creating vcan interface {name} via netlink: {e}"));
        link.bring_up()
            .unwrap_or_else(|e| panic!("bringing {name} up: {e}"));
        TestInterface {
            name,
            link: Some(link),
        }
    }

    fn link(&self) -> &CanInterface {
        self.link.as_ref().expect("interface deleted already")
    }

    /// Opens a raw CAN socket on this interface.
    fn socket(&self) -> CanSocket {
        let socket = CanSocket::open(self.name)
            .unwrap_or_else(|e| panic!("opening a CAN_RAW socket on {}: {e}", self.name));
        socket
            .set_read_timeout(HANG_LIMIT)
            .expect("setting a read timeout");
        socket
    }

    /// Deletes the interface now (as if a USB adapter was unplugged).
    fn delete(&mut self) {
        if let Some(link) = self.link.take() {
            link.delete()
                .unwrap_or_else(|(_, e)| panic!("deleting {}: {e}", self.name));
        }
    }
}

impl Drop for TestInterface {
    fn drop(&mut self) {
        if let Some(link) = self.link.take() {
            let _ = link.delete();
        }
    }
}

fn std_id(raw: u16) -> Id {
    Id::Standard(StandardId::new(raw).expect("test uses valid 11-bit ids"))
}

fn ext_id(raw: u32) -> Id {
    Id::Extended(ExtendedId::new(raw).expect("test uses valid 29-bit ids"))
}

fn data_frame(id: Id, data: &[u8]) -> CanFrame {
    CanFrame::Data(CanDataFrame::new(id, data).expect("test frames hold at most 8 bytes"))
}

fn remote_frame(id: Id, dlc: usize) -> CanFrame {
    CanFrame::Remote(CanRemoteFrame::new_remote(id, dlc).expect("test uses dlc <= 8"))
}

/// The classic frames the round-trip and candump tests send: standard and extended ids, every data
/// length from 0 to 8, id extremes, and remote requests.
fn classic_frame_set() -> Vec<CanFrame> {
    let mut frames = Vec::new();
    for len in 0..=8u8 {
        let data: Vec<u8> = (0..len).map(|i| 0xA0 ^ (i * 17) ^ len).collect();
        frames.push(data_frame(std_id(0x100 + u16::from(len)), &data));
        frames.push(data_frame(ext_id(0x1ABC_D000 + u32::from(len)), &data));
    }
    frames.push(data_frame(std_id(0x000), &[0x00]));
    frames.push(data_frame(std_id(0x7FF), &[0xFF; 8]));
    frames.push(data_frame(ext_id(0x1FFF_FFFF), &[0x55, 0xAA]));
    frames.push(remote_frame(std_id(0x321), 0));
    frames.push(remote_frame(std_id(0x322), 4));
    frames.push(remote_frame(ext_id(0x0765_4321), 8));
    frames
}

/// What a receiver must see of a frame: the full id word (with EFF/RTR/ERR flags), dlc and data.
fn frame_signature(frame: &CanFrame) -> (u32, usize, Vec<u8>) {
    let data = if frame.is_remote_frame() {
        Vec::new()
    } else {
        frame.data().to_vec()
    };
    (frame.id_word(), frame.dlc(), data)
}

#[test]
fn classic_frames_round_trip_between_sockets() {
    if !vcan_present("classic_frames_round_trip_between_sockets") {
        return;
    }
    let iface = TestInterface::create("imuv_classic");
    let sender = iface.socket();
    let receiver = iface.socket();
    let frames = classic_frame_set();
    for frame in &frames {
        sender.write_frame(frame).expect("writing a classic frame");
    }
    for (index, sent) in frames.iter().enumerate() {
        let got = receiver
            .read_frame()
            .unwrap_or_else(|e| panic!("reading frame {index} of {}: {e}", frames.len()));
        assert_eq!(
            frame_signature(&got),
            frame_signature(sent),
            "frame {index} differs after the kernel round trip"
        );
        assert_eq!(
            got.is_extended(),
            sent.is_extended(),
            "frame {index} id kind"
        );
        assert_eq!(
            got.is_remote_frame(),
            sent.is_remote_frame(),
            "frame {index} RTR"
        );
    }
    // By default a CAN_RAW socket does not get its own frames back (CAN_RAW_RECV_OWN_MSGS off).
    sender.set_nonblocking(true).expect("nonblocking");
    match sender.read_frame() {
        Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
        other => panic!("the sending socket should not receive its own frames, got {other:?}"),
    }
    // Nothing beyond what was sent arrived at the receiver either.
    receiver.set_nonblocking(true).expect("nonblocking");
    match receiver.read_frame() {
        Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
        other => panic!("receiver got an extra frame: {other:?}"),
    }
}

#[test]
fn error_frames_reach_only_sockets_that_ask_for_them() {
    if !vcan_present("error_frames_reach_only_sockets_that_ask_for_them") {
        return;
    }
    let iface = TestInterface::create("imuv_errors");
    let sender = iface.socket();
    let error_listener = iface.socket();
    error_listener
        .set_error_filter_accept_all()
        .expect("setting CAN_RAW_ERR_FILTER");
    let plain_listener = iface.socket();

    // Bus-off plus a controller problem (RX passive) and the error counters, as a CAN controller
    // driver would report them.
    const CAN_ERR_CRTL: u32 = 0x0000_0004;
    const CAN_ERR_BUSOFF: u32 = 0x0000_0040;
    const CAN_ERR_CNT: u32 = 0x0000_0200;
    const CAN_ERR_CRTL_RX_PASSIVE: u8 = 0x10;
    let error = CanErrorFrame::new_error(
        CAN_ERR_CRTL | CAN_ERR_BUSOFF | CAN_ERR_CNT,
        &[0, CAN_ERR_CRTL_RX_PASSIVE, 0, 0, 0, 0, 131, 140],
    )
    .expect("8 bytes of error data");
    sender
        .write_frame(&CanFrame::Error(error))
        .expect("writing an error frame");
    let marker = data_frame(std_id(0x55), &[1, 2, 3]);
    sender
        .write_frame(&marker)
        .expect("writing the marker frame");

    let got = error_listener
        .read_frame()
        .expect("reading the error frame");
    let CanFrame::Error(got_error) = got else {
        panic!("expected an error frame first, got {got:?}");
    };
    assert_eq!(
        got_error.error_bits(),
        CAN_ERR_CRTL | CAN_ERR_BUSOFF | CAN_ERR_CNT
    );
    let decoded: CanError = got_error.into_error();
    let causes: Vec<ErrorCause> = decoded.causes().copied().collect();
    assert!(
        causes.contains(&ErrorCause::BusOff),
        "bus-off missing in {causes:?}"
    );
    assert!(
        causes.contains(&ErrorCause::Counters { tx: 131, rx: 140 }),
        "error counters missing in {causes:?}"
    );
    assert!(
        decoded.controller().is_some(),
        "controller problem missing in {causes:?}"
    );
    let after = error_listener.read_frame().expect("reading the marker");
    assert_eq!(frame_signature(&after), frame_signature(&marker));

    // Without an error filter the kernel delivers no error frames: the marker comes first.
    let first_plain = plain_listener
        .read_frame()
        .expect("reading on the plain socket");
    assert_eq!(
        frame_signature(&first_plain),
        frame_signature(&marker),
        "a socket without CAN_RAW_ERR_FILTER must not see error frames"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn burst_of_ten_thousand_frames_arrives_complete_and_in_order() {
    if !vcan_present("burst_of_ten_thousand_frames_arrives_complete_and_in_order") {
        return;
    }
    let iface = TestInterface::create("imuv_burst");
    // The project's transport (what imulogd reads CAN with), not the crate's socket.
    let mut receiver =
        SocketCanTransport::open(iface.name, Some(HANG_LIMIT)).expect("SocketCAN transport");
    // A receive queue that holds the whole burst (each frame costs ~1 KiB of socket memory); the
    // default (~200 KiB) overflows when one sender outpaces one reader on a single emulated CPU.
    // SO_RCVBUFFORCE needs CAP_NET_ADMIN, which the guest's root has.
    receiver
        .set_receive_buffer(16 << 20)
        .expect("a 16 MiB receive queue");
    let sender = iface.socket();

    let reader = tokio::spawn(async move {
        let mut sequences = Vec::with_capacity(BURST_FRAMES as usize);
        while sequences.len() < BURST_FRAMES as usize {
            let frame = receiver
                .recv()
                .await
                .map_err(|e| format!("after {} frames: {e}", sequences.len()))?;
            let bytes: [u8; 4] = frame
                .payload()
                .get(..4)
                .and_then(|b| b.try_into().ok())
                .ok_or_else(|| format!("frame without a sequence number: {frame:?}"))?;
            sequences.push(u32::from_le_bytes(bytes));
        }
        Ok::<_, String>(sequences)
    });

    let started = Instant::now();
    let writer = tokio::task::spawn_blocking(move || {
        for sequence in 0..BURST_FRAMES {
            let mut data = [0u8; 8];
            data[..4].copy_from_slice(&sequence.to_le_bytes());
            data[4..].copy_from_slice(&(!sequence).to_le_bytes());
            let id = std_id(0x200 + (sequence % 0x100) as u16);
            sender
                .write_frame_insist(&data_frame(id, &data))
                .map_err(|e| format!("writing frame {sequence}: {e}"))?;
        }
        Ok::<_, String>(())
    });
    writer
        .await
        .expect("writer task")
        .unwrap_or_else(|e| panic!("{e}"));
    let sequences = reader
        .await
        .expect("reader task")
        .unwrap_or_else(|e| panic!("{e}"));
    let elapsed = started.elapsed();

    let out_of_place = sequences
        .iter()
        .enumerate()
        .find(|(index, &sequence)| sequence != *index as u32);
    assert!(
        out_of_place.is_none(),
        "burst lost or reordered frames: first mismatch (index, sequence) = {out_of_place:?}"
    );
    println!(
        "burst: {BURST_FRAMES} frames in {:.3} s = {:.0} frames/s, none lost",
        elapsed.as_secs_f64(),
        f64::from(BURST_FRAMES) / elapsed.as_secs_f64()
    );
}

/// A CAN_RAW socket read through tokio, waiting for readable **or error** readiness.
///
/// `socketcan::tokio::CanSocket::read_frame` waits for `Interest::READABLE` only. When the link
/// goes down under a waiting reader the kernel signals EPOLLERR alone (no EPOLLIN), tokio records
/// it as error readiness, and that read never wakes (pinned by
/// `socketcan_tokio_read_frame_misses_link_down_while_waiting`). Waiting for
/// `READABLE | ERROR` makes the read return the socket error instead.
struct ErrorAwareReader(AsyncFd<CanSocket>);

impl ErrorAwareReader {
    fn open(iface: &str) -> Self {
        let socket = CanSocket::open(iface).expect("opening a CAN_RAW socket");
        socket.set_nonblocking(true).expect("nonblocking");
        // SAFETY: the CanSocket owns its file descriptor, keeps it open until it is dropped and
        // never swaps it; the AsyncFd owns the CanSocket.
        let registered = unsafe { AsyncFd::register(socket) };
        ErrorAwareReader(registered.unwrap_or_else(|e| panic!("registering with tokio: {e}")))
    }

    async fn read_frame(&self) -> io::Result<CanFrame> {
        self.0
            .async_io(Interest::READABLE | Interest::ERROR, |socket| {
                socket.read_frame()
            })
            .await
    }

    /// Reads, without waiting, whatever is queued; returns each frame's first data byte.
    fn drain_queued(&self) -> Vec<Option<u8>> {
        let mut queued = Vec::new();
        loop {
            match self.0.get_ref().read_frame() {
                Ok(frame) => queued.push(frame.data().first().copied()),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return queued,
                Err(e) => panic!("reading the frames queued before the link went down: {e}"),
            }
        }
    }

    /// Reads until an error comes, within `HANG_LIMIT`; returns the frames read before it and the
    /// error.
    async fn read_until_error(&self) -> (usize, io::Error) {
        let mut frames = 0;
        loop {
            match tokio::time::timeout(HANG_LIMIT, self.read_frame()).await {
                Err(_) => {
                    panic!("read hung for {HANG_LIMIT:?} after {frames} frames: no error surfaced")
                }
                Ok(Ok(_)) => frames += 1,
                Ok(Err(e)) => return (frames, e),
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interface_going_down_mid_stream_is_an_error_not_a_hang() {
    if !vcan_present("interface_going_down_mid_stream_is_an_error_not_a_hang") {
        return;
    }
    let mut iface = TestInterface::create("imuv_down");
    let receiver = Arc::new(ErrorAwareReader::open(iface.name));
    let sender = iface.socket();

    // 1. Link down while frames are queued. The kernel reports the pending socket error
    // (ENETDOWN) before handing out the queue; the frames received before the drop are still there.
    for sequence in 0..50u8 {
        sender
            .write_frame(&data_frame(std_id(0x10), &[sequence]))
            .expect("writing while up");
    }
    iface.link().bring_down().expect("bringing the link down");
    let (frames_before, error) = receiver.read_until_error().await;
    assert_eq!(frames_before, 0, "the error comes before the queued frames");
    assert_eq!(
        error.raw_os_error(),
        Some(libc::ENETDOWN),
        "reader error after link down: {error}"
    );
    assert_eq!(error.kind(), io::ErrorKind::NetworkDown);
    let expected: Vec<Option<u8>> = (0..50u8).map(Some).collect();
    assert_eq!(
        receiver.drain_queued(),
        expected,
        "frames queued before the link went down"
    );
    let write_error = sender
        .write_frame(&data_frame(std_id(0x10), &[0xEE]))
        .expect_err("writing on a down link must fail");
    assert_eq!(
        write_error.raw_os_error(),
        Some(libc::ENETDOWN),
        "writer error: {write_error}"
    );

    // 2. Back up: the same sockets carry frames again (what a retrying transport relies on).
    iface.link().bring_up().expect("bringing the link up again");
    sender
        .write_frame(&data_frame(std_id(0x11), &[0x42]))
        .expect("writing after the link came back");
    let resumed = tokio::time::timeout(HANG_LIMIT, receiver.read_frame())
        .await
        .expect("no frame after the link came back")
        .expect("reading after the link came back");
    assert_eq!(resumed.data(), &[0x42]);

    // 3. Mid-stream: a reader waiting in read while frames stream in; the link goes down under
    // it. The waiting read must wake with ENETDOWN.
    let streaming_reader = tokio::spawn({
        let receiver = Arc::clone(&receiver);
        async move { receiver.read_until_error().await }
    });
    for sequence in 0..20u8 {
        sender
            .write_frame(&data_frame(std_id(0x12), &[sequence]))
            .expect("streaming while up");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    iface
        .link()
        .bring_down()
        .expect("bringing the link down mid-stream");
    let (frames_streamed, error) = streaming_reader.await.expect("streaming reader task");
    assert_eq!(
        error.raw_os_error(),
        Some(libc::ENETDOWN),
        "waiting reader's error when the link went down: {error}"
    );
    let late = receiver.drain_queued().len();
    assert_eq!(
        frames_streamed + late,
        20,
        "every streamed frame is read, before the error ({frames_streamed}) or after it ({late})"
    );

    // 4. Interface removed (adapter unplugged) under a waiting reader. Unregistering takes the
    // link down first, so the reader sees ENETDOWN and then ENODEV, or ENODEV alone when both
    // happened before it woke; either way an error and not a hang.
    iface
        .link()
        .bring_up()
        .expect("bringing the link up before removal");
    let waiting_reader = tokio::spawn({
        let receiver = Arc::clone(&receiver);
        async move { receiver.read_until_error().await }
    });
    tokio::time::sleep(Duration::from_millis(200)).await;
    iface.delete();
    let (frames_after_delete, mut error) = waiting_reader.await.expect("waiting reader task");
    assert_eq!(frames_after_delete, 0);
    if error.raw_os_error() == Some(libc::ENETDOWN) {
        let (frames, next) = receiver.read_until_error().await;
        assert_eq!(frames, 0);
        error = next;
    }
    assert_eq!(
        error.raw_os_error(),
        Some(libc::ENODEV),
        "reader error after the interface was deleted: {error}"
    );
}

/// Pins a limitation of `socketcan` 4.0's tokio socket that the project's transport must work
/// around (see `ErrorAwareReader`): a `read_frame` already waiting when the link goes down is not
/// woken by the error. If this starts failing, a newer `socketcan` wakes it and the work-around
/// can go.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn socketcan_tokio_read_frame_misses_link_down_while_waiting() {
    if !vcan_present("socketcan_tokio_read_frame_misses_link_down_while_waiting") {
        return;
    }
    let iface = TestInterface::create("imuv_tokiodown");
    let receiver = Arc::new(socketcan::tokio::CanSocket::open(iface.name).expect("async socket"));
    let waiting = tokio::spawn({
        let receiver = Arc::clone(&receiver);
        async move { tokio::time::timeout(Duration::from_secs(2), receiver.read_frame()).await }
    });
    tokio::time::sleep(Duration::from_millis(200)).await;
    iface.link().bring_down().expect("bringing the link down");
    let outcome = waiting.await.expect("waiting reader task");
    assert!(
        outcome.is_err(),
        "socketcan's tokio read_frame now wakes on link down ({outcome:?}): \
         the READABLE|ERROR work-around may be dropped"
    );
    // The error was pending on the socket all along: a fresh read attempt returns it at once.
    let error = receiver
        .try_read_frame()
        .expect_err("the pending socket error");
    assert_eq!(error.raw_os_error(), Some(libc::ENETDOWN), "{error}");
}

/// Waits until some CAN_RAW socket (other than ones filtering nothing in) listens on `iface`, as
/// listed by /proc/net/can/rcvlist_all; that is when a freshly started candump is ready.
fn wait_for_listener(iface: &str, child: &mut Child) {
    let deadline = Instant::now() + HANG_LIMIT;
    loop {
        let list = std::fs::read_to_string("/proc/net/can/rcvlist_all").unwrap_or_default();
        if list
            .lines()
            .any(|line| line.split_whitespace().next() == Some(iface))
        {
            return;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("candump exited before listening: {status}");
        }
        assert!(
            Instant::now() < deadline,
            "candump did not start listening on {iface}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn wait_with_limit(child: &mut Child, what: &str) {
    let deadline = Instant::now() + HANG_LIMIT;
    loop {
        match child.try_wait() {
            Ok(Some(status)) => {
                let mut stderr = String::new();
                if let Some(pipe) = child.stderr.as_mut() {
                    let _ = pipe.read_to_string(&mut stderr);
                }
                assert!(status.success(), "{what} failed: {status}: {stderr}");
                return;
            }
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Ok(None) => {
                let _ = child.kill();
                panic!("{what} did not finish within {HANG_LIMIT:?}");
            }
            Err(e) => panic!("waiting for {what}: {e}"),
        }
    }
}

fn single_log_file(dir: &Path) -> PathBuf {
    let logs: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("listing candump's directory")
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|path| path.extension().is_some_and(|ext| ext == "log"))
        .collect();
    assert_eq!(
        logs.len(),
        1,
        "candump -l should write one log, found {logs:?}"
    );
    logs.into_iter().next().expect("one log")
}

#[test]
fn candump_log_from_can_utils_decodes_with_our_reader() {
    if !vcan_present("candump_log_from_can_utils_decodes_with_our_reader") {
        return;
    }
    let iface = TestInterface::create("imuv_candump");
    let sender = iface.socket();
    // The sender itself must not show up as a listener while we wait for candump.
    sender.set_filter_drop_all().expect("sender filter");
    let mut frames = classic_frame_set();
    frames.push(CanFrame::Error(
        CanErrorFrame::new_error(0x0000_0040, &[0; 8]).expect("bus-off error frame"),
    ));

    let log_dir = tempfile::tempdir().expect("temp dir for candump");
    // -l: log to candump-<date>.log in the working directory; -n: exit after that many frames;
    // filters `0:0` (every data frame) and `#FFFFFFFF` (every error class: can-utils 2020.11's -e
    // only changes how errors print, the error mask comes from this filter).
    let mut candump = Command::new("candump")
        .args(["-l", "-n", &frames.len().to_string()])
        .arg(format!("{},0:0,#FFFFFFFF", iface.name))
        .current_dir(log_dir.path())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("starting candump (can-utils on PATH in the guest): {e}"));
    wait_for_listener(iface.name, &mut candump);
    let before = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock after 1970");
    for frame in &frames {
        sender.write_frame(frame).expect("writing for candump");
    }
    wait_with_limit(&mut candump, "candump");

    let log_path = single_log_file(log_dir.path());
    let text = std::fs::read_to_string(&log_path).expect("reading candump's log");
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), frames.len(), "log lines:\n{text}");
    // The project's candump reader (the drivers' sans-IO codec) decodes can-utils' log exactly.
    let mut decoder = CandumpDecoder::new();
    decoder.push(text.as_bytes());
    let records: Vec<_> = std::iter::from_fn(|| decoder.poll()).collect();
    let stats = decoder.stats();
    assert_eq!(records.len(), frames.len(), "{stats:?}\n{text}");
    assert_eq!(stats.frames_ok, frames.len() as u64, "{stats:?}");
    assert_eq!(
        (
            stats.frames_malformed,
            stats.frames_too_long,
            stats.bytes_skipped
        ),
        (0, 0, 0),
        "{stats:?}"
    );
    let mut previous_micros = before.as_micros() as u64;
    for (index, (record, sent)) in records.iter().zip(&frames).enumerate() {
        let line = lines[index];
        assert_eq!(record.interface.as_str(), iface.name, "line {}", index + 1);
        assert!(
            record.timestamp_us >= previous_micros,
            "line {}: timestamp goes back ({} < {previous_micros})",
            index + 1,
            record.timestamp_us
        );
        previous_micros = record.timestamp_us;
        let expected = from_socketcan(&CanAnyFrame::from(*sent))
            .unwrap_or_else(|e| panic!("frame {} has no drivers form: {e}", index + 1));
        assert_eq!(
            record.frame,
            expected,
            "{}:{}: {line}",
            log_path.display(),
            index + 1
        );
    }

    // Cross-check: the socketcan crate's own candump reader agrees on every frame.
    let mut reader = SocketcanDumpReader::from_reader(text.as_bytes());
    let mut crate_frames = HashMap::new();
    let mut line_number = 0;
    while let Some(record) = reader
        .next_record()
        .unwrap_or_else(|e| panic!("socketcan::dump line {}: {e:?}", line_number + 1))
    {
        line_number += 1;
        let CanAnyFrame::Normal(frame) = record.frame else {
            // Remote and error frames are their own variants in the crate's reader.
            crate_frames.insert(line_number, None);
            continue;
        };
        crate_frames.insert(line_number, Some((frame.id_word(), frame.data().to_vec())));
    }
    assert_eq!(line_number, frames.len());
    for (index, sent) in frames.iter().enumerate() {
        if let Some(Some((id_word, data))) = crate_frames.get(&(index + 1)) {
            assert_eq!(
                *id_word,
                sent.id_word(),
                "socketcan::dump line {}",
                index + 1
            );
            assert_eq!(
                data.as_slice(),
                sent.data(),
                "socketcan::dump line {}",
                index + 1
            );
        }
    }
}

/// Seconds the daemon logs the CAN IMU before the interface is removed (issue 10: at least 60).
/// `IMULAB_VCAN_DAEMON_SECS` shortens it for a quick local look.
fn daemon_log_secs() -> u64 {
    std::env::var("IMULAB_VCAN_DAEMON_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60)
}

/// What the simulated CAN IMU measures: the simulator's `bench-cheap` model (white noise, bias
/// instability, random walks, quantisation …) on a static bench at 25 °C, one sample per sequence
/// number at 150 Hz. The status byte carries `seq % 7`, so a shuffled or repeated sample shows.
fn simulated_can_imu(count: u64) -> Vec<imulab_drivers::ImuSample> {
    use imulab::sim::imu_model::{Channels, ImuSimulator};
    let spec = imulab::sim::presets::imu_preset("bench-cheap").expect("bench-cheap preset");
    let mut sim = ImuSimulator::new(&spec, "canimu", 10, 150.0, Channels::ALL).expect("simulator");
    let rate = nalgebra::Vector3::zeros();
    let specific_force = nalgebra::Vector3::new(0.0, 0.0, -9.80665);
    (0..count)
        .map(|seq| {
            // A dropped sample (the preset's drop model) is simply not one of ours: take the next.
            let record = loop {
                if let Some(r) = sim.step(&rate, &specific_force, 25.0, 0, 0).record {
                    break r;
                }
            };
            imulab_drivers::ImuSample {
                sensor_time: Some(seq as f64 / 150.0),
                gyro: Some(record.gyro),
                accel: Some(record.accel),
                temp_c: Some(record.temp),
                status: (seq % 7) as u32,
            }
        })
        .collect()
}

/// Sends the simulated CAN IMU's frames (fixtures/imu_can.dbc through imu_can_mapping.toml) at
/// 150 Hz on `iface`, samples `seqs`, on schedule. Returns how many were sent whole.
fn send_can_imu(
    iface: &str,
    imu: &imulab_drivers::codec::dbc::DbcImu,
    samples: &[imulab_drivers::ImuSample],
    seqs: std::ops::Range<u64>,
) -> u64 {
    let socket = CanSocket::open(iface).expect("sender socket");
    let start = Instant::now();
    let first = seqs.start;
    let mut sent = 0;
    for seq in seqs {
        let sample = samples[seq as usize];
        for frame in imu.encode(&sample).expect("encodable sample") {
            let data = CanDataFrame::new(
                if frame.is_extended() {
                    Id::Extended(ExtendedId::new(frame.id()).expect("29-bit id"))
                } else {
                    Id::Standard(StandardId::new(frame.id() as u16).expect("11-bit id"))
                },
                frame.payload(),
            )
            .expect("classic frame");
            // vcan drops nothing, but a full socket buffer says ENOBUFS: wait and retry.
            loop {
                match socket.write_frame(&data) {
                    Ok(()) => break,
                    Err(e) if e.raw_os_error() == Some(libc::ENOBUFS) => {
                        std::thread::sleep(Duration::from_micros(200))
                    }
                    Err(e) => panic!("sending on {iface}: {e}"),
                }
            }
        }
        sent += 1;
        let next = start + Duration::from_micros((seq - first + 1) * 1_000_000 / 150);
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    sent
}

/// The daemon (as a library, through the same `connector_for`/`decoder_for` as `imulogd`)
/// logging a simulated CAN IMU at 150 Hz on a vcan interface through the fixture DBC for at
/// least 60 s: every sample in the session, in order, with its values; then the interface is
/// removed and re-added: a disconnect, a gap and a reconnect event, and the data resume.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_logs_a_can_imu_through_the_dbc_and_survives_the_interface_going_away() {
    use imulab::daemon::config::parse;
    use imulab::daemon::sink::MemorySink;
    use imulab::daemon::source::{connector_for, decoder_for};
    use imulab::daemon::{run, DaemonParts};
    use imulab::store::EventKind;
    use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping};

    let test = "daemon_logs_a_can_imu_through_the_dbc_and_survives_the_interface_going_away";
    if !vcan_present(test) {
        return;
    }
    const IFACE: &str = "vcand";
    let mut iface = TestInterface::create(IFACE);
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let dir = std::env::temp_dir().join(format!("imulab-vcan-daemon-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 200\n\
         [[device]]\nname = \"canimu\"\nprotocol = \"can-dbc\"\nrate_hz = 150\nretry_initial_ms = 50\nretry_max_ms = 200\n\
         can = {{ interface = \"{IFACE}\" }}\n\
         dbc = {{ file = \"{}\", mapping = \"{}\" }}\n",
        dir.display(),
        fixtures.join("imu_can.dbc").display(),
        fixtures.join("imu_can_mapping.toml").display()
    );
    let config = parse(&text, "vcan test").unwrap_or_else(|e| panic!("{e}"));
    let sink = MemorySink::new();
    let parts = DaemonParts {
        sink: Box::new(sink.clone()),
        session_dir: dir.join("session"),
        connectors: vec![connector_for(&config.devices[0]).unwrap()],
        decoders: vec![decoder_for(&config.devices[0]).unwrap_or_else(|e| panic!("{e}"))],
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: dir.join("status.json"),
    };
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    tokio::time::sleep(Duration::from_millis(300)).await;

    let imu = Arc::new(
        DbcImu::new(
            &std::fs::read_to_string(fixtures.join("imu_can.dbc")).unwrap(),
            &DbcImuMapping::from_toml_str(
                &std::fs::read_to_string(fixtures.join("imu_can_mapping.toml")).unwrap(),
            )
            .unwrap(),
        )
        .unwrap(),
    );
    let first_run = 150 * daemon_log_secs();
    let second_run = 300;
    let samples = Arc::new(simulated_can_imu(first_run + second_run));
    let sent = {
        let (imu, samples) = (imu.clone(), samples.clone());
        tokio::task::spawn_blocking(move || send_can_imu(IFACE, &imu, &samples, 0..first_run))
            .await
            .unwrap()
    };
    assert_eq!(sent, first_run);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let before_unplug = sink.snapshot().imu.get("canimu").map_or(0, Vec::len) as u64;
    // Each sample is complete on the message that closes the mapped set, the last one too.
    assert!(
        before_unplug >= first_run,
        "{before_unplug} of {first_run} samples logged before the unplug"
    );

    iface.delete();
    tokio::time::sleep(Duration::from_millis(700)).await;
    let iface = TestInterface::create(IFACE);
    tokio::time::sleep(Duration::from_millis(700)).await;
    {
        let (imu, samples) = (imu.clone(), samples.clone());
        tokio::task::spawn_blocking(move || {
            send_can_imu(IFACE, &imu, &samples, first_run..first_run + second_run)
        })
        .await
        .unwrap();
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let _ = stop.send(true);
    let outcome = daemon.await.unwrap();
    drop(iface);
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    let store = sink.snapshot();
    let _ = std::fs::remove_dir_all(&dir);

    let rows = &store.imu["canimu"];
    let seqs: Vec<u64> = rows
        .iter()
        .map(|r| (r.t_sensor * 150.0).round() as u64)
        .collect();
    let want: Vec<u64> = (0..first_run + second_run).collect();
    if seqs != want {
        let missing: Vec<u64> = want.iter().filter(|s| !seqs.contains(s)).copied().collect();
        panic!(
            "{} rows for {} samples sent; missing {:?}",
            seqs.len(),
            want.len(),
            &missing[..missing.len().min(20)]
        );
    }
    // Every value equals what the simulator produced, to the DBC's resolution (half an LSB:
    // 0.01 °/s, 0.0005 g, 0.01 °C).
    let d2r = std::f64::consts::PI / 180.0;
    for (seq, row) in want.iter().zip(rows) {
        let sent = &samples[*seq as usize];
        let (gyro, accel) = (sent.gyro.unwrap(), sent.accel.unwrap());
        for axis in 0..3 {
            assert!(
                (row.gyro[axis] - gyro[axis]).abs() <= 0.005 * d2r + 1e-9,
                "sample {seq} gyro {axis}: logged {row:?}, sent {sent:?}"
            );
            assert!(
                (row.accel[axis] - accel[axis]).abs() <= 0.000_25 * 9.806_65 + 1e-9,
                "sample {seq} accel {axis}: logged {row:?}, sent {sent:?}"
            );
        }
        assert!(
            (row.temp - sent.temp_c.unwrap()).abs() <= 0.005 + 1e-9,
            "sample {seq}: {row:?}"
        );
        assert_eq!(row.status, (seq % 7) as u32, "sample {seq}");
    }
    let kinds: Vec<EventKind> = store
        .events
        .iter()
        .filter(|e| e.device == "canimu")
        .map(|e| e.kind)
        .collect();
    for kind in [
        EventKind::Connect,
        EventKind::Disconnect,
        EventKind::Gap,
        EventKind::Reconnect,
    ] {
        assert!(kinds.contains(&kind), "{kind:?} missing from {kinds:?}");
    }
}
