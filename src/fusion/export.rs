//! Writes a replayed trajectory as CSV (every state, sensor-error estimates and 1σ) and as a
//! GeoJSON LineString (for a map), and the error summary against truth as JSON.

use crate::metrics::ErrorSummary;
use crate::navigator::NavSolution;
use std::path::Path;

/// Column names of the trajectory CSV, with units.
pub const CSV_HEADER: [&str; 37] = [
    "t_s",
    "lat_deg",
    "lon_deg",
    "height_m",
    "vn_mps",
    "ve_mps",
    "vd_mps",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
    "bgx_rad_s",
    "bgy_rad_s",
    "bgz_rad_s",
    "bax_mps2",
    "bay_mps2",
    "baz_mps2",
    "sgx",
    "sgy",
    "sgz",
    "sax",
    "say",
    "saz",
    "sd_pn_m",
    "sd_pe_m",
    "sd_pd_m",
    "sd_vn_mps",
    "sd_ve_mps",
    "sd_vd_mps",
    "sd_att_n_deg",
    "sd_att_e_deg",
    "sd_att_d_deg",
    "sd_bgx_rad_s",
    "sd_bgy_rad_s",
    "sd_bgz_rad_s",
    "sd_bax_mps2",
    "sd_bay_mps2",
    "sd_baz_mps2",
];

/// One row of the trajectory table, in [`CSV_HEADER`] order.
fn row(s: &NavSolution) -> Vec<f64> {
    {
        let n = &s.nav;
        let (r, p, y) = n.quat_nb.euler_angles();
        let mut row: Vec<f64> = vec![
            n.t_s,
            n.lat_rad.to_degrees(),
            n.lon_rad.to_degrees(),
            n.height_m,
            n.vel_ned.x,
            n.vel_ned.y,
            n.vel_ned.z,
            r.to_degrees(),
            p.to_degrees(),
            y.to_degrees(),
        ];
        for v in [
            s.sensors.gyro_bias,
            s.sensors.accel_bias,
            s.sensors.gyro_scale,
            s.sensors.accel_scale,
        ] {
            row.extend(v.iter());
        }
        for i in 0..9 {
            let sd = s.cov_nav[(i, i)].sqrt();
            row.push(if i >= 6 { sd.to_degrees() } else { sd });
        }
        row.extend(s.sigma_sensors[0].iter());
        row.extend(s.sigma_sensors[1].iter());
        row
    }
}

/// Writes the trajectory CSV.
pub fn write_csv(path: &Path, solutions: &[NavSolution]) -> anyhow::Result<()> {
    let mut w =
        csv::Writer::from_path(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    w.write_record(CSV_HEADER)?;
    for s in solutions {
        w.write_record(row(s).iter().map(|v| v.to_string()))?;
    }
    w.flush()?;
    Ok(())
}

/// Writes trajectories into an HDF5 file: group `/replay/<name>` per set, one 1-D dataset
/// per [`CSV_HEADER`] column.
pub fn write_hdf5(path: &Path, sets: &[(&str, &[NavSolution])]) -> anyhow::Result<()> {
    let ctx = |e: hdf5::Error| anyhow::anyhow!("{}: {e}", path.display());
    let file = hdf5::File::create(path).map_err(ctx)?;
    let top = file.create_group("replay").map_err(ctx)?;
    for (name, solutions) in sets {
        let group = top.create_group(name).map_err(ctx)?;
        let rows: Vec<Vec<f64>> = solutions.iter().map(row).collect();
        for (c, column) in CSV_HEADER.iter().enumerate() {
            let values: Vec<f64> = rows.iter().map(|r| r[c]).collect();
            group
                .new_dataset_builder()
                .with_data(&values)
                .create(*column)
                .map_err(ctx)?;
        }
    }
    Ok(())
}

/// Writes the horizontal track as a GeoJSON Feature with a LineString (lon, lat, height).
pub fn write_geojson(path: &Path, solutions: &[NavSolution]) -> anyhow::Result<()> {
    let coords: Vec<[f64; 3]> = solutions
        .iter()
        .map(|s| {
            [
                s.nav.lon_rad.to_degrees(),
                s.nav.lat_rad.to_degrees(),
                s.nav.height_m,
            ]
        })
        .collect();
    let doc = serde_json::json!({
        "type": "Feature",
        "properties": { "name": "imulab replay" },
        "geometry": { "type": "LineString", "coordinates": coords },
    });
    std::fs::write(path, serde_json::to_string(&doc)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The error summary as a JSON value.
pub fn summary_json(s: &ErrorSummary) -> serde_json::Value {
    let spread = |x: &crate::metrics::Spread| serde_json::json!({ "rms": x.rms, "p95": x.p95, "max": x.max });
    serde_json::json!({
        "epochs": s.epochs,
        "horizontal_m": spread(&s.horizontal),
        "vertical_m": spread(&s.vertical),
        "horizontal_with_gnss_m": spread(&s.horizontal_gnss),
        "attitude_rms_deg": s.attitude_rms_deg,
        "nees_mean": s.nees_mean,
        "inside_3sigma": s.inside_3sigma,
        "outages": s.outages.iter().map(|o| serde_json::json!({
            "start_s": o.start_s, "duration_s": o.duration_s, "max_horizontal_m": o.max_horizontal_m,
            "unbounded": o.unbounded
        })).collect::<Vec<_>>(),
        "unbounded_epochs": s.unbounded_epochs,
        "unbounded_from_s": s.unbounded_from_s,
    })
}
