//! `imulab decode`: decode a capture file or a live serial port with any protocol of the
//! codec table and print one JSON object per frame on stdout, then the decoder's counters
//! on stderr. Lets a user check a capture or a device without starting the daemon.
//!
//! Protocols plug in through `imulab_drivers::codec::PROTOCOLS` (name, detector,
//! constructor); nothing here is protocol specific, so a new table row is all a new
//! protocol needs.

use std::fs::File;
use std::io::{self, BufWriter, Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use imulab_drivers::codec::{self, DecoderOptions, JsonDecoder, NamedText, Protocol, PROTOCOLS};

/// How many bytes `auto` looks at before deciding.
const DETECT_SAMPLE: usize = 16 * 1024;
/// How long `auto` waits on a live port for that sample.
const DETECT_WAIT: Duration = Duration::from_secs(5);

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    imulab decode capture.ubx                     # auto-detect, JSON lines on stdout\n  \
    imulab decode /dev/ttyACM0 --baud 115200 --duration 10\n  \
    imulab decode nmea.log --protocol nmea | jq 'select(.sentence==\"GGA\")'\n  \
    imulab decode - --protocol ubx < capture.bin")]
pub struct DecodeArgs {
    /// Capture file, serial port (e.g. /dev/ttyUSB0, a pty) or `-` for stdin.
    pub input: PathBuf,
    /// Protocol name from the codec table, or `auto` to detect it from the first bytes.
    #[arg(long, short, default_value = "auto")]
    pub protocol: String,
    /// DBC file for IMU-over-CAN protocols.
    #[arg(long)]
    pub dbc: Option<PathBuf>,
    /// Protocol-specific configuration (e.g. CSV column map, DBC signal map).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Baud rate when INPUT is a serial port (ignored on a pty).
    #[arg(long, default_value_t = 9600)]
    pub baud: u32,
    /// Stop after this many seconds (for a live port; files stop at their end).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Print only the counters, not the frames.
    #[arg(long)]
    pub quiet: bool,
}

/// Where bytes come from.
enum Source {
    Reader(Box<dyn Read>),
    Port(Box<dyn tokio_serial::SerialPort>),
}

impl Source {
    fn open(args: &DecodeArgs) -> anyhow::Result<Source> {
        if args.input.as_os_str() == "-" {
            return Ok(Source::Reader(Box::new(io::stdin())));
        }
        let meta = std::fs::metadata(&args.input)
            .with_context(|| format!("cannot open `{}`", args.input.display()))?;
        if is_char_device(&meta) {
            let path = args.input.to_string_lossy().into_owned();
            let port = tokio_serial::new(&path, args.baud)
                .timeout(Duration::from_millis(200))
                .open()
                .map_err(|e| imulab_drivers::transport::serial::open_error(&path, e))
                .with_context(|| format!("cannot open serial port `{path}`"))?;
            return Ok(Source::Port(port));
        }
        let file = File::open(&args.input)
            .with_context(|| format!("cannot open `{}`", args.input.display()))?;
        Ok(Source::Reader(Box::new(file)))
    }

    /// Reads some bytes; `Ok(0)` means the input ended. A port timeout is `Ok(None)`.
    fn read(&mut self, buf: &mut [u8]) -> io::Result<Option<usize>> {
        match self {
            Source::Reader(r) => r.read(buf).map(Some),
            Source::Port(p) => match p.read(buf) {
                Ok(n) => Ok(Some(n)),
                Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(None),
                // The device went away (pty closed, USB unplugged): end of input, not a
                // failure of the decode itself.
                Err(e) => {
                    eprintln!("imulab decode: port closed ({e}); stopping");
                    Ok(Some(0))
                }
            },
        }
    }

    fn is_live(&self) -> bool {
        matches!(self, Source::Port(_))
    }
}

#[cfg(unix)]
fn is_char_device(meta: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::FileTypeExt;
    meta.file_type().is_char_device()
}

#[cfg(not(unix))]
fn is_char_device(_meta: &std::fs::Metadata) -> bool {
    false
}

/// What frames that are intact but fail their checksum mean.
const CHECKSUM_ADVICE: &str = "the frames are whole, so the baud rate is right; the data \
     is corrupted on the way or its sender computes the checksum differently";

/// Whether rejected checksums, rather than a wrong baud rate or protocol, explain a stream
/// without valid frames: at least 3 of them, and at least one per 160 bytes. Random bytes (a
/// wrong baud rate) also fail checksums now and then, about one Xbus "frame" per 250 bytes.
fn checksums_explain(stats: &imulab_drivers::types::DecoderStats, bytes: u64) -> bool {
    stats.checksum_errors >= 3 && stats.checksum_errors.saturating_mul(160) >= bytes
}

/// The protocol whose frames in `sample` fail their checksum (see [`checksums_explain`]),
/// with its decoder's counters, when no protocol was detected.
fn checksum_failures(sample: &[u8]) -> Option<(Protocol, imulab_drivers::types::DecoderStats)> {
    let mut line = Vec::new();
    PROTOCOLS
        .iter()
        .filter_map(|entry| {
            let mut d = entry.protocol.open(&DecoderOptions::default()).ok()?;
            d.push(sample);
            while d.next_json(&mut line) {
                line.clear();
            }
            Some((entry.protocol, d.stats()))
        })
        .filter(|(_, stats)| checksums_explain(stats, sample.len() as u64))
        .max_by_key(|(_, stats)| stats.checksum_errors)
}

pub fn run(args: DecodeArgs) -> anyhow::Result<()> {
    let mut source = Source::open(&args)?;
    let started = Instant::now();
    let deadline = args
        .duration
        .map(|s| started + Duration::from_secs_f64(s.max(0.0)));
    let expired = || deadline.is_some_and(|d| Instant::now() >= d);
    let mut chunk = vec![0u8; 64 * 1024];
    let mut pending = Vec::new();
    let mut ended = false;

    // Choose the protocol, reading a sample first when asked to detect it.
    let protocol = if args.protocol.eq_ignore_ascii_case("auto") {
        while pending.len() < DETECT_SAMPLE && !ended {
            if source.is_live() && (started.elapsed() > DETECT_WAIT || expired()) {
                break;
            }
            match source.read(&mut chunk).context("reading input")? {
                Some(0) => ended = true,
                Some(n) => {
                    pending.extend_from_slice(&chunk[..n]);
                    // A live port need not fill the whole sample once a protocol is clear.
                    if source.is_live()
                        && pending.len() >= 1024
                        && codec::detect(&pending).is_some()
                    {
                        break;
                    }
                }
                None => {}
            }
        }
        if pending.is_empty() && ended {
            bail!(
                "{}: empty input (0 bytes): nothing to decode",
                args.input.display()
            );
        }
        match codec::detect(&pending) {
            Some(p) => p,
            None => match checksum_failures(&pending) {
                Some((p, stats)) => bail!(
                    "no valid frame in the first {} bytes, but {} {} frames failed their checksum: {}",
                    pending.len(),
                    stats.checksum_errors,
                    p.name(),
                    CHECKSUM_ADVICE
                ),
                None => bail!(
                    "no known protocol found in the first {} bytes; pass --protocol ({})",
                    pending.len(),
                    PROTOCOLS
                        .iter()
                        .map(|p| p.name)
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            },
        }
    } else {
        Protocol::from_name(&args.protocol)
            .map_err(|e| anyhow::anyhow!("{e}; pass one of these, or `auto` to detect it"))?
    };
    let read = |path: &Option<std::path::PathBuf>| -> anyhow::Result<Option<NamedText>> {
        path.as_ref()
            .map(|p| {
                let text = std::fs::read_to_string(p)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
                Ok(NamedText {
                    name: p.display().to_string(),
                    text,
                })
            })
            .transpose()
    };
    let options = DecoderOptions {
        dbc: read(&args.dbc)?,
        config: read(&args.config)?,
        ..DecoderOptions::default()
    };
    let mut decoder = protocol.open(&options)?;

    let stdout = io::stdout();
    let mut out = BufWriter::with_capacity(256 * 1024, stdout.lock());
    let mut line = Vec::with_capacity(1024);
    let mut total_bytes = pending.len() as u64;
    let mut frames = 0u64;
    let mut emit = |decoder: &mut dyn JsonDecoder, finishing: bool| -> io::Result<()> {
        loop {
            line.clear();
            let got = if finishing {
                decoder.finish_json(&mut line)
            } else {
                decoder.next_json(&mut line)
            };
            if !got {
                return Ok(());
            }
            frames += 1;
            if !args.quiet {
                line.push(b'\n');
                out.write_all(&line)?;
            }
        }
    };

    decoder.push(&pending);
    emit(decoder.as_mut(), false).context("writing output")?;
    while !ended && !expired() {
        match source.read(&mut chunk).context("reading input")? {
            Some(0) => ended = true,
            Some(n) => {
                total_bytes += n as u64;
                decoder.push(&chunk[..n]);
                match emit(decoder.as_mut(), false) {
                    Ok(()) => {}
                    // A closed pipe (`| head`) ends the run quietly.
                    Err(e) if e.kind() == io::ErrorKind::BrokenPipe => break,
                    Err(e) => return Err(e).context("writing output"),
                }
            }
            None => {}
        }
    }
    match emit(decoder.as_mut(), true).and_then(|()| out.flush()) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => {}
        Err(e) => return Err(e).context("writing output"),
    }
    drop(out);

    let stats = decoder.stats();
    let summary = serde_json::json!({
        "protocol": protocol.name(),
        "bytes": total_bytes,
        "frames_out": frames,
        "seconds": started.elapsed().as_secs_f64(),
        "stats": stats,
    });
    eprintln!("{summary}");
    if total_bytes == 0 {
        bail!(
            "{}: empty input (0 bytes): nothing to decode",
            args.input.display()
        );
    }
    if stats.frames_ok == 0 && checksums_explain(&stats, total_bytes) {
        bail!(
            "no frames decoded: all {} {} frames in {total_bytes} bytes failed their checksum: {}",
            stats.checksum_errors,
            protocol.name(),
            CHECKSUM_ADVICE
        );
    }
    if stats.frames_ok == 0 {
        let advice = if args.protocol.eq_ignore_ascii_case("auto") {
            "check the baud rate (--baud) or name the protocol with --protocol"
        } else {
            "try --protocol auto, or check the baud rate (--baud)"
        };
        bail!(
            "no frames decoded: no valid {} frame in {total_bytes} bytes (wrong protocol or baud rate); {advice}",
            protocol.name()
        );
    }
    Ok(())
}
