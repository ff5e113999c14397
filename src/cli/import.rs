//! `imulab import BAG -o SESSION`: a ROS 1 bag or ROS 2 bag / MCAP file written as a normal
//! session (docs/import.md). Each `sensor_msgs/Imu` topic becomes an IMU device and each
//! `sensor_msgs/NavSatFix` topic a GNSS device; a `sensor_msgs/Temperature` topic fills the
//! `temp` column of the IMU in its namespace and a `geometry_msgs/TwistStamped` topic the
//! velocity of the GNSS device in its namespace. The receive (log) time is both host clocks
//! (`t_mono_ns`, `t_wall_ns`), the header stamp the sensor clock (`t_sensor`, seconds; for
//! fixes also `utc_ns`). Other topics are skipped and counted, and so are messages that do
//! not decode; a truncated bag keeps every message before the cut.

use crate::bag::messages::{decode, normalise_type, Fix, MessageType, Reading};
use crate::bag::{Bag, TopicInfo};
use crate::store::manifest::{DeviceInfo, DeviceKind, Manifest};
use crate::store::{EventKind, EventRecord, GnssRecord, ImuRecord, SessionWriter, WriterOptions};
use anyhow::{bail, Context};
use imulab_drivers::types::FixType;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example: imulab import run.mcap -o runs/run1   (then: imulab inspect runs/run1; imulab allan runs/run1)"
)]
pub struct ImportArgs {
    /// The bag: a ROS 1 .bag, an MCAP file, or a ROS 2 bag directory holding one.
    pub bag: PathBuf,
    /// The session directory to create (must not exist or be empty).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Topics to import (default: every topic of a type imulab reads).
    #[arg(long, value_delimiter = ',')]
    pub topic: Vec<String>,
}

/// Receive time per flush of buffered rows to the writer.
const FLUSH_NS: i64 = 10_000_000_000;
/// Fixes wait this long (receive time) for the TwistStamped of their epoch.
const VELOCITY_WAIT_NS: i64 = 2_000_000_000;
/// A twist belongs to the fix whose header stamp is within this of its own.
const VELOCITY_MATCH_NS: i64 = 50_000_000;
/// Messages per topic whose header stamps give the device's nominal rate.
const RATE_PROBE: usize = 200;

/// What happens to one topic.
#[derive(Debug, Clone, PartialEq)]
enum Role {
    Imu(usize),
    Gnss(usize),
    /// Temperature of IMU device `usize`.
    Temperature(usize),
    /// Velocity of GNSS device `usize`.
    Velocity(usize),
    Skipped(String),
}

/// Rows of one device waiting to be written.
#[derive(Default)]
struct Pending {
    imu: Vec<ImuRecord>,
    gnss: Vec<GnssRecord>,
    /// Twists (header stamp, ENU velocity) of a GNSS device not yet matched to a fix.
    twists: Vec<(i64, [f64; 3])>,
    temperature: f64,
    last_written_ns: Option<i64>,
    written: u64,
    /// Rows whose receive time was older than one already written (kept, at that time).
    reordered: u64,
}

/// A device name from a topic: `/imu/data` → `imu_data` (letters, digits, `_ - .`).
fn device_name(topic: &str, taken: &[String]) -> String {
    let mut name: String = topic
        .trim_start_matches('/')
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "_-.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .take(56)
        .collect();
    if name.is_empty() {
        name = "topic".into();
    }
    let mut candidate = name.clone();
    let mut k = 2;
    while taken.contains(&candidate) {
        candidate = format!("{name}_{k}");
        k += 1;
    }
    candidate
}

/// The namespace of a topic: `/imu/data` → `/imu`.
fn namespace(topic: &str) -> &str {
    topic.rfind('/').map_or("", |i| &topic[..i])
}

/// The device among `candidates` (topic, device index) whose topic shares the longest
/// namespace with `topic`; with a single candidate, that one.
fn nearest(topic: &str, candidates: &[(String, usize)]) -> Option<usize> {
    if candidates.len() == 1 {
        return Some(candidates[0].1);
    }
    let ns = namespace(topic);
    candidates
        .iter()
        .map(|(t, d)| {
            let other = namespace(t);
            let common = ns
                .split('/')
                .zip(other.split('/'))
                .take_while(|(a, b)| a == b)
                .count();
            (common, *d)
        })
        .filter(|(common, _)| *common > 1)
        .max_by_key(|(common, _)| *common)
        .map(|(_, d)| d)
}

pub fn run(args: ImportArgs) -> anyhow::Result<()> {
    let bag = Bag::open(&args.bag)?;
    for t in &args.topic {
        match bag.topic(t) {
            None => bail!(
                "{}: no topic `{t}`; the topics are:\n{}",
                bag.path().display(),
                bag.topic_table()
            ),
            Some(info) if info.message_type().is_none() => bail!(
                "{}: topic `{t}` is {}, which imulab does not read (it reads sensor_msgs/Imu, NavSatFix, Temperature and geometry_msgs/TwistStamped); the topics are:\n{}",
                bag.path().display(),
                info.type_name,
                bag.topic_table()
            ),
            Some(_) => {}
        }
    }
    let chosen = |t: &TopicInfo| args.topic.is_empty() || args.topic.contains(&t.name);
    let topics: Vec<TopicInfo> = bag.topics().to_vec();
    // Devices first (IMUs, GNSS receivers), then what attaches to them.
    let mut roles: Vec<Role> = vec![Role::Skipped(String::new()); topics.len()];
    let mut names: Vec<String> = Vec::new();
    let mut device_topics: Vec<String> = Vec::new();
    let mut imus: Vec<(String, usize)> = Vec::new();
    let mut receivers: Vec<(String, usize)> = Vec::new();
    for (i, t) in topics.iter().enumerate() {
        let kind = t.message_type();
        roles[i] = match kind {
            _ if !chosen(t) => Role::Skipped("not chosen with --topic".into()),
            None => Role::Skipped("type not read".into()),
            Some(MessageType::Imu) | Some(MessageType::NavSatFix) => {
                let d = names.len();
                names.push(device_name(&t.name, &names));
                device_topics.push(t.name.clone());
                if kind == Some(MessageType::Imu) {
                    imus.push((t.name.clone(), d));
                    Role::Imu(d)
                } else {
                    receivers.push((t.name.clone(), d));
                    Role::Gnss(d)
                }
            }
            Some(_) => Role::Skipped(String::new()),
        };
    }
    for (i, t) in topics.iter().enumerate() {
        if roles[i] != Role::Skipped(String::new()) {
            continue;
        }
        roles[i] = match t.message_type() {
            Some(MessageType::Temperature) => match nearest(&t.name, &imus) {
                Some(d) => Role::Temperature(d),
                None => Role::Skipped("no sensor_msgs/Imu topic in its namespace".into()),
            },
            Some(MessageType::TwistStamped) => match nearest(&t.name, &receivers) {
                Some(d) => Role::Velocity(d),
                None => Role::Skipped("no sensor_msgs/NavSatFix topic in its namespace".into()),
            },
            _ => Role::Skipped("type not read".into()),
        };
    }
    if names.is_empty() {
        bail!(
            "{}: no sensor_msgs/Imu or sensor_msgs/NavSatFix topic to import; the topics are:\n{}",
            bag.path().display(),
            bag.topic_table()
        );
    }
    let rates = probe_rates(&bag, &topics, &roles, names.len())?;
    let devices: Vec<DeviceInfo> = (0..names.len())
        .map(|d| {
            let topic = &device_topics[d];
            let info = topics.iter().find(|t| &t.name == topic);
            let is_imu = imus.iter().any(|(_, i)| *i == d);
            DeviceInfo {
                name: names[d].clone(),
                kind: if is_imu {
                    DeviceKind::Imu
                } else {
                    DeviceKind::Gnss
                },
                model: info
                    .map(|t| normalise_type(&t.type_name))
                    .unwrap_or_default(),
                serial: String::new(),
                port: topic.clone(),
                protocol: "ros".into(),
                rate_hz: rates[d],
                // REP 103: body frames are x forward, y left, z up.
                axis_frame: if is_imu { "FLU" } else { "NED" }.into(),
                extra: BTreeMap::new(),
            }
        })
        .collect();
    let mut config = toml::Table::new();
    let mut import = toml::Table::new();
    import.insert(
        "source".into(),
        toml::Value::String(bag.path().display().to_string()),
    );
    import.insert(
        "format".into(),
        toml::Value::String(bag.format().name().into()),
    );
    config.insert("import".into(), toml::Value::Table(import));
    let manifest = Manifest::new(devices, config);
    let options = WriterOptions {
        // A file converted once: power-loss protection per flush only costs time.
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    let mut writer = SessionWriter::create(&args.output, manifest, options)
        .with_context(|| format!("creating the session {}", args.output.display()))?;
    let outcome = copy_messages(&bag, &topics, &roles, &names, &mut writer)?;
    writer.close()?;
    print!(
        "{}",
        report(&bag, &topics, &roles, &names, &outcome, &args.output)
    );
    Ok(())
}

/// Counts of one import.
struct Outcome {
    pending: Vec<Pending>,
    /// Per topic: messages that did not decode, and the first reason.
    undecodable: Vec<(u64, Option<String>)>,
    /// Per topic: messages read.
    read: Vec<u64>,
    cut: Option<String>,
}

/// Why the rate probe stopped reading.
enum ProbeError {
    Bag(crate::bag::BagError),
    Enough,
}

impl From<crate::bag::BagError> for ProbeError {
    fn from(e: crate::bag::BagError) -> Self {
        ProbeError::Bag(e)
    }
}

/// Nominal rate per device: the median header-stamp interval of its first messages (the
/// receive times when the stamps do not increase), 1 Hz when a topic has one message.
fn probe_rates(
    bag: &Bag,
    topics: &[TopicInfo],
    roles: &[Role],
    devices: usize,
) -> anyhow::Result<Vec<f64>> {
    let device_of = |topic: &str| -> Option<usize> {
        let i = topics.iter().position(|t| t.name == topic)?;
        match roles[i] {
            Role::Imu(d) | Role::Gnss(d) => Some(d),
            _ => None,
        }
    };
    let mut stamps: Vec<Vec<(i64, i64)>> = vec![Vec::new(); devices];
    let mut full = 0usize;
    let result = bag.read::<ProbeError>(&mut |m| {
        let Some(d) = device_of(m.topic) else {
            return Ok(());
        };
        if stamps[d].len() >= RATE_PROBE {
            return Ok(());
        }
        let kind = MessageType::from_name(m.type_name);
        let stamp = match (kind, m.encoding) {
            (Some(kind), Some(enc)) => decode(kind, enc, m.data).ok().map(|r| r.stamp_ns()),
            _ => None,
        };
        if let Some(s) = stamp {
            stamps[d].push((s, m.log_time_ns));
            if stamps[d].len() == RATE_PROBE {
                full += 1;
                if full == devices {
                    return Err(ProbeError::Enough);
                }
            }
        }
        Ok(())
    });
    match result {
        Ok(_) | Err(ProbeError::Enough) => {}
        Err(ProbeError::Bag(e)) => return Err(e.into()),
    }
    Ok(stamps
        .iter()
        .map(|s| {
            let median = |pick: fn(&(i64, i64)) -> i64| -> Option<f64> {
                let mut dt: Vec<i64> = s
                    .windows(2)
                    .map(|w| pick(&w[1]) - pick(&w[0]))
                    .filter(|&d| d > 0)
                    .collect();
                dt.sort_unstable();
                dt.get(dt.len() / 2).map(|&d| 1e9 / d as f64)
            };
            median(|p| p.0).or_else(|| median(|p| p.1)).unwrap_or(1.0)
        })
        .collect())
}

fn copy_messages(
    bag: &Bag,
    topics: &[TopicInfo],
    roles: &[Role],
    names: &[String],
    writer: &mut SessionWriter,
) -> anyhow::Result<Outcome> {
    let mut pending: Vec<Pending> = (0..names.len())
        .map(|_| Pending {
            temperature: f64::NAN,
            ..Pending::default()
        })
        .collect();
    let mut undecodable: Vec<(u64, Option<String>)> = vec![(0, None); topics.len()];
    let mut read = vec![0u64; topics.len()];
    let mut next_flush: Option<i64> = None;
    let mut first_event = true;
    let end = bag.read::<anyhow::Error>(&mut |m| {
        let Some(i) = topics.iter().position(|t| t.name == m.topic) else {
            return Ok(());
        };
        read[i] += 1;
        let t = m.log_time_ns;
        if first_event {
            first_event = false;
            writer.append_event(&EventRecord {
                t_mono_ns: t,
                t_wall_ns: t,
                device: String::new(),
                kind: EventKind::SessionStart,
                detail: format!("imported from {}", bag.path().display()),
            })?;
        }
        if let Role::Skipped(_) = roles[i] {
            return Ok(());
        }
        let kind = MessageType::from_name(m.type_name);
        let reading = match (kind, m.encoding) {
            (Some(kind), Some(enc)) => decode(kind, enc, m.data),
            _ => Err("message encoding is neither CDR nor ROS 1".into()),
        };
        let reading = match reading {
            Ok(r) => r,
            Err(e) => {
                let entry = &mut undecodable[i];
                entry.0 += 1;
                entry
                    .1
                    .get_or_insert_with(|| format!("message {}: {e}", read[i]));
                return Ok(());
            }
        };
        match (&roles[i], reading) {
            (
                Role::Imu(d),
                Reading::Imu {
                    stamp_ns,
                    gyro,
                    accel,
                },
            ) => {
                let p = &mut pending[*d];
                p.imu.push(ImuRecord {
                    t_mono_ns: t,
                    t_wall_ns: t,
                    t_sensor: stamp_ns as f64 * 1e-9,
                    gyro,
                    accel,
                    temp: p.temperature,
                    status: 0,
                });
            }
            (Role::Temperature(d), Reading::Temperature { celsius, .. }) => {
                pending[*d].temperature = celsius;
            }
            (Role::Gnss(d), Reading::Fix(fix)) => {
                pending[*d].gnss.push(gnss_record(t, &fix));
            }
            (
                Role::Velocity(d),
                Reading::Twist {
                    stamp_ns, linear, ..
                },
            ) => {
                pending[*d].twists.push((stamp_ns, linear));
            }
            _ => {}
        }
        let due = *next_flush.get_or_insert(t + FLUSH_NS);
        if t >= due {
            flush(writer, names, &mut pending, Some(t))?;
            next_flush = Some(t + FLUSH_NS);
        }
        Ok(())
    })?;
    flush(writer, names, &mut pending, None)?;
    if let Some(cut) = &end.cut {
        let t = pending
            .iter()
            .filter_map(|p| p.last_written_ns)
            .max()
            .unwrap_or(0);
        writer.append_event(&EventRecord {
            t_mono_ns: t,
            t_wall_ns: t,
            device: String::new(),
            kind: EventKind::Info,
            detail: format!("the bag ends early: {cut}"),
        })?;
    }
    Ok(Outcome {
        pending,
        undecodable,
        read,
        cut: end.cut,
    })
}

/// A session GNSS row from a NavSatFix (velocity filled later from a TwistStamped).
fn gnss_record(t: i64, fix: &Fix) -> GnssRecord {
    let Fix {
        stamp_ns,
        status,
        lat_deg,
        lon_deg,
        alt_m,
        covariance,
        covariance_type,
    } = *fix;
    let known = covariance_type > 0;
    GnssRecord {
        t_mono_ns: t,
        t_wall_ns: t,
        week: 0,
        tow_s: f64::NAN,
        utc_ns: stamp_ns,
        lat_deg,
        lon_deg,
        height_m: alt_m,
        vel_ned: [f64::NAN; 3],
        // The RMS of the east and north standard deviations: the horizontal accuracy the
        // u-blox and NMEA drivers put on both diagonal entries.
        h_acc_m: if known {
            ((covariance[0] + covariance[4]) / 2.0).sqrt()
        } else {
            f64::NAN
        },
        v_acc_m: if known {
            covariance[8].sqrt()
        } else {
            f64::NAN
        },
        s_acc_mps: f64::NAN,
        // NavSatFix carries no heading.
        heading_deg: f64::NAN,
        fix_type: match status {
            s if s < 0 => FixType::NoFix,
            0 => FixType::Fix3D,
            _ => FixType::Dgnss,
        },
        num_sats: 0,
        pdop: f64::NAN,
        hdop: f64::NAN,
        vdop: f64::NAN,
    }
}

/// Writes the buffered rows: every IMU row, and the fixes received before `now` less the
/// velocity wait (all of them when `now` is `None`, at the end).
fn flush(
    writer: &mut SessionWriter,
    names: &[String],
    pending: &mut [Pending],
    now: Option<i64>,
) -> anyhow::Result<()> {
    for (d, p) in pending.iter_mut().enumerate() {
        if !p.imu.is_empty() {
            let mut rows = std::mem::take(&mut p.imu);
            rows.sort_by_key(|r| r.t_mono_ns);
            keep_order(&mut rows, p, |r| &mut r.t_mono_ns);
            writer.append_imu(&names[d], &rows)?;
            p.written += rows.len() as u64;
        }
        if p.gnss.is_empty() {
            continue;
        }
        let ready = match now {
            Some(now) => p
                .gnss
                .iter()
                .take_while(|r| r.t_mono_ns < now - VELOCITY_WAIT_NS)
                .count(),
            None => p.gnss.len(),
        };
        let mut rows: Vec<GnssRecord> = p.gnss.drain(..ready).collect();
        for r in &mut rows {
            let twist = p
                .twists
                .iter()
                .filter(|(s, _)| (s - r.utc_ns).abs() <= VELOCITY_MATCH_NS)
                .min_by_key(|(s, _)| (s - r.utc_ns).abs());
            if let Some((_, enu)) = twist {
                r.vel_ned = [enu[1], enu[0], -enu[2]];
            }
        }
        // Twists older than every fix still waiting can match nothing more.
        let oldest = p.gnss.first().map(|r| r.utc_ns);
        match oldest {
            Some(o) => p.twists.retain(|(s, _)| *s >= o - VELOCITY_MATCH_NS),
            None => p.twists.clear(),
        }
        rows.sort_by_key(|r| r.t_mono_ns);
        keep_order(&mut rows, p, |r| &mut r.t_mono_ns);
        if !rows.is_empty() {
            writer.append_gnss(&names[d], &rows)?;
            p.written += rows.len() as u64;
        }
    }
    Ok(())
}

/// A row received before one already written gets that row's time (the session's rows of a
/// device never go back in time); counted in `reordered`.
fn keep_order<R>(rows: &mut [R], p: &mut Pending, time: impl Fn(&mut R) -> &mut i64) {
    for r in rows.iter_mut() {
        let t = time(r);
        if let Some(last) = p.last_written_ns {
            if *t < last {
                *t = last;
                p.reordered += 1;
            }
        }
        p.last_written_ns = Some(*t);
    }
}

fn report(
    bag: &Bag,
    topics: &[TopicInfo],
    roles: &[Role],
    names: &[String],
    outcome: &Outcome,
    output: &Path,
) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {}, {} topics",
        bag.path().display(),
        bag.format().name(),
        topics.len()
    );
    let width = topics.iter().map(|t| t.name.len()).max().unwrap_or(5);
    let type_width = topics.iter().map(|t| t.type_name.len()).max().unwrap_or(4);
    let mut skipped_messages = 0u64;
    let mut skipped_topics = 0usize;
    for (i, t) in topics.iter().enumerate() {
        let what = match &roles[i] {
            Role::Imu(d) => format!("IMU {} ({} rows)", names[*d], outcome.pending[*d].written),
            Role::Gnss(d) => format!("GNSS {} ({} rows)", names[*d], outcome.pending[*d].written),
            Role::Temperature(d) => format!("temperature of {}", names[*d]),
            Role::Velocity(d) => format!("velocity of {}", names[*d]),
            Role::Skipped(why) => {
                skipped_topics += 1;
                skipped_messages += outcome.read[i];
                format!("skipped: {why}")
            }
        };
        let _ = writeln!(
            out,
            "  {:<width$}  {:<type_width$}  {:>9} messages  -> {what}",
            t.name, t.type_name, outcome.read[i]
        );
        let (bad, first) = &outcome.undecodable[i];
        if *bad > 0 {
            let _ = writeln!(
                out,
                "    {bad} message(s) did not decode and were skipped (first: {})",
                first.as_deref().unwrap_or("")
            );
        }
    }
    if skipped_topics > 0 {
        let _ = writeln!(
            out,
            "skipped {skipped_messages} messages on {skipped_topics} topic(s)"
        );
    }
    for (d, p) in outcome.pending.iter().enumerate() {
        if p.reordered > 0 {
            let _ = writeln!(
                out,
                "{}: {} row(s) received out of order were given the time of the row before them",
                names[d], p.reordered
            );
        }
    }
    if let Some(cut) = &outcome.cut {
        let _ = writeln!(
            out,
            "warning: the bag ends early ({cut}); every message before that point was imported"
        );
    }
    let _ = writeln!(out, "wrote {}", output.display());
    out
}
