//! `imulab export SESSION --device NAME --format csv`: one device's rows as CSV, streamed in
//! blocks so memory stays bounded whatever the session length. With `--compensate MODEL`
//! the IMU rate columns have the thermal model's bias removed, and a first `#` comment line
//! says so.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;

use crate::store::{layout, DeviceKind, Session, TimeRange};
use crate::thermal::model::{require_session_temperature, ImuCompensator, ThermalModel};

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    Csv,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example: imulab export runs/chamber --device imu0 --format csv --start 60 --end 120 -o imu0.csv\n  imulab export runs/chamber --device imu0 --compensate thermal-model.json -o imu0-compensated.csv"
)]
pub struct ExportArgs {
    /// Session directory.
    pub session: PathBuf,
    /// Device to export (as named in session.toml).
    #[arg(long)]
    pub device: String,
    #[arg(long, value_enum, default_value_t = ExportFormat::Csv)]
    pub format: ExportFormat,
    /// Output file (default: standard output).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Start, in seconds after the device's first sample (inclusive).
    #[arg(long)]
    pub start: Option<f64>,
    /// End, in seconds after the device's first sample (exclusive).
    #[arg(long)]
    pub end: Option<f64>,
    /// Thermal model (JSON from `imulab thermal --model`): remove its change of bias with
    /// temperature, bias(T) − bias(reference), from the IMU's gyro and accel columns, using
    /// the row's `temp`.
    #[arg(long, value_name = "MODEL")]
    pub compensate: Option<PathBuf>,
    /// Calibration file (`imulab calibrate`, docs/calibration.md): correct the gyro and
    /// accel columns with its biases and scale/misalignment matrices (before --compensate).
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

/// Rows per block read from the session.
const BLOCK_ROWS: usize = 8192;

fn f(x: f64) -> String {
    x.to_string()
}

/// Writes the CSV for `args` to `out`; returns the number of rows written.
pub fn export_csv(
    session: &Session,
    args: &ExportArgs,
    out: &mut dyn Write,
) -> anyhow::Result<u64> {
    let device = session
        .manifest()
        .device(&args.device)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "{}: no device {:?} in this session",
                session.dir().display(),
                args.device
            )
        })?
        .clone();
    for (name, v) in [("--start", args.start), ("--end", args.end)] {
        if v.is_some_and(|v| !v.is_finite()) {
            anyhow::bail!("{name} must be a finite number of seconds");
        }
    }
    let group = match device.kind {
        DeviceKind::Imu => layout::imu_path(&device.name),
        DeviceKind::Gnss => layout::gnss_path(&device.name),
    };
    let range = match session.stream_summary(&group).first_t_mono_ns {
        Some(t0) => {
            let at = |s: f64| t0.saturating_add((s * 1e9).round() as i64);
            TimeRange::new(args.start.map(at), args.end.map(at))
        }
        None => TimeRange::all(),
    };
    let calibration = match (&args.calibration, device.kind) {
        (Some(path), DeviceKind::Imu) => {
            let c = crate::calib::Corrector::new(
                &crate::calib::Calibration::load(path)?,
                &device.name,
            )?;
            writeln!(
                out,
                "# {} calibrated with {} (corrected = inverse(M) * (raw - b))",
                c.describe(),
                path.display()
            )?;
            Some(c)
        }
        (Some(_), DeviceKind::Gnss) => anyhow::bail!(
            "--calibration applies to an IMU; `{}` is a GNSS receiver",
            device.name
        ),
        (None, _) => None,
    };
    let mut compensator = match (&args.compensate, device.kind) {
        (Some(path), DeviceKind::Imu) => {
            let model = ThermalModel::load(path)?;
            let c = ImuCompensator::new(&model, &device.name)
                .with_context(|| format!("thermal model {}", path.display()))?;
            require_session_temperature(session, &device.name)?;
            writeln!(
                out,
                "# {} compensated with thermal model {} (bias(T) − bias(reference) by the temp column removed)",
                c.axes().join(" "),
                path.display()
            )?;
            Some(c)
        }
        (Some(_), DeviceKind::Gnss) => anyhow::bail!(
            "--compensate applies to an IMU; `{}` is a GNSS receiver",
            device.name
        ),
        (None, _) => None,
    };
    let mut w = csv::Writer::from_writer(out);
    let mut rows = 0u64;
    match device.kind {
        DeviceKind::Imu => {
            w.write_record([
                "t_mono_ns",
                "t_wall_ns",
                "t_sensor",
                "gyro_x",
                "gyro_y",
                "gyro_z",
                "accel_x",
                "accel_y",
                "accel_z",
                "temp",
                "status",
            ])?;
            for block in session.imu_blocks(&device.name, range, BLOCK_ROWS)? {
                let mut b = block?;
                if let Some(c) = &calibration {
                    c.apply(&mut b.gyro, &mut b.accel);
                }
                if let Some(c) = compensator.as_mut() {
                    c.compensate_block(&mut b.gyro, &mut b.accel, &b.temp);
                }
                for i in 0..b.len() {
                    let (g, a) = (b.gyro[i], b.accel[i]);
                    w.write_record([
                        b.t_mono_ns[i].to_string(),
                        b.t_wall_ns[i].to_string(),
                        f(b.t_sensor[i]),
                        f(g[0]),
                        f(g[1]),
                        f(g[2]),
                        f(a[0]),
                        f(a[1]),
                        f(a[2]),
                        f(b.temp[i]),
                        b.status[i].to_string(),
                    ])?;
                }
                rows += b.len() as u64;
            }
        }
        DeviceKind::Gnss => {
            w.write_record([
                "t_mono_ns",
                "t_wall_ns",
                "week",
                "tow_s",
                "utc_ns",
                "lat_deg",
                "lon_deg",
                "height_m",
                "vel_n",
                "vel_e",
                "vel_d",
                "h_acc_m",
                "v_acc_m",
                "s_acc_mps",
                "fix_type",
                "num_sats",
                "pdop",
                "hdop",
                "vdop",
                "heading_deg",
            ])?;
            for block in session.gnss_blocks(&device.name, range, BLOCK_ROWS)? {
                let b = block?;
                for i in 0..b.len() {
                    let v = b.vel_ned[i];
                    w.write_record([
                        b.t_mono_ns[i].to_string(),
                        b.t_wall_ns[i].to_string(),
                        b.week[i].to_string(),
                        f(b.tow_s[i]),
                        b.utc_ns[i].to_string(),
                        f(b.lat_deg[i]),
                        f(b.lon_deg[i]),
                        f(b.height_m[i]),
                        f(v[0]),
                        f(v[1]),
                        f(v[2]),
                        f(b.h_acc_m[i]),
                        f(b.v_acc_m[i]),
                        f(b.s_acc_mps[i]),
                        b.fix_type[i].to_string(),
                        b.num_sats[i].to_string(),
                        f(b.pdop[i]),
                        f(b.hdop[i]),
                        f(b.vdop[i]),
                        f(b.heading_deg[i]),
                    ])?;
                }
                rows += b.len() as u64;
            }
        }
    }
    w.flush()?;
    for warning in compensator.iter().flat_map(ImuCompensator::warnings) {
        tracing::warn!("{warning}");
    }
    Ok(rows)
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    let session = Session::open(&args.session)?;
    let rows = match &args.output {
        Some(path) => {
            let file = std::fs::File::create(path)
                .with_context(|| format!("{}: cannot create", path.display()))?;
            let mut out = std::io::BufWriter::new(file);
            let rows = export_csv(&session, &args, &mut out)?;
            out.flush()
                .with_context(|| format!("{}: write failed", path.display()))?;
            rows
        }
        None => {
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::new(stdout.lock());
            let rows = export_csv(&session, &args, &mut out)?;
            out.flush().context("writing to standard output")?;
            rows
        }
    };
    tracing::info!("exported {rows} rows of {}", args.device);
    Ok(())
}
