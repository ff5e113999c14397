//! Writes a session with rotation and reads it back through `Session`: values, block
//! boundaries across files, time ranges, events, summaries and the manifest.

use crate::common::*;
use imulab::store::{layout, ImuColumnSet, ImuColumns, Session, TimeRange};

#[test]
fn session_reads_back_exactly_across_rotated_files() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s1");
    let manifest = write_session(&dir, 25, 37, fast_opts());

    // 25 s of data with rotation every 10 s of data time: 3 chunk files, no partials.
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        vec![
            "chunk-000000.h5",
            "chunk-000001.h5",
            "chunk-000002.h5",
            "session.toml"
        ]
    );

    let s = Session::open(&dir).unwrap();
    assert!(s.problems().is_empty(), "{:?}", s.problems());
    assert_eq!(s.manifest(), &manifest);

    for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
        let mut n = 0;
        for block in s.imu_blocks(name, TimeRange::all(), 333).unwrap() {
            let block = block.unwrap();
            assert!(block.len() <= 333 && !block.is_empty());
            for k in 0..block.len() {
                assert_eq!(block.record(k), imu_row(d, n), "{name} row {n}");
                n += 1;
            }
        }
        assert_eq!(n, 2500);
    }
    let mut n = 0;
    for block in s.gnss_blocks("gps", TimeRange::all(), 64).unwrap() {
        let block = block.unwrap();
        for k in 0..block.len() {
            assert_eq!(block.record(k), gnss_row(n));
            n += 1;
        }
    }
    assert_eq!(n, 125);

    let (events, problems) = s.events();
    assert!(problems.is_empty());
    assert_eq!(events[0].detail, "3 frames dropped, ünïcode ok");
    assert_eq!(events[0].device, "imu_a");
    let rotations = events
        .iter()
        .filter(|e| e.kind == imulab::store::EventKind::Rotation)
        .count();
    assert_eq!(rotations, 2);

    let sum = s.stream_summary(&layout::imu_path("imu_b"));
    assert_eq!(sum.rows, 2500);
    assert_eq!(sum.first_t_mono_ns, Some(imu_row(1, 0).t_mono_ns));
    assert_eq!(sum.last_t_mono_ns, Some(imu_row(1, 2499).t_mono_ns));
}

#[test]
fn time_range_selects_exactly_the_half_open_interval() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s2");
    write_session(&dir, 25, 150, fast_opts());
    let s = Session::open(&dir).unwrap();
    // Rows 950..1250 span the first rotation (at 10 s of data).
    let range = TimeRange::new(
        Some(imu_row(0, 950).t_mono_ns),
        Some(imu_row(0, 1250).t_mono_ns),
    );
    let got: Vec<_> = s
        .imu_blocks("imu_a", range, 1000)
        .unwrap()
        .flat_map(|b| {
            let b = b.unwrap();
            (0..b.len()).map(move |k| b.record(k)).collect::<Vec<_>>()
        })
        .collect();
    assert_eq!(got.len(), 300);
    assert_eq!(got[0], imu_row(0, 950));
    assert_eq!(got[299], imu_row(0, 1249));
    // Empty and out-of-span ranges give nothing, not an error.
    let none = TimeRange::new(Some(i64::MAX - 1), None);
    assert_eq!(s.imu_blocks("imu_a", none, 10).unwrap().count(), 0);
}

#[test]
fn datasets_carry_units_axis_frame_and_schema_version() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s3");
    write_session(&dir, 2, 50, fast_opts());
    let f = hdf5::File::open(dir.join("chunk-000000.h5")).unwrap();
    let gyro = f.dataset("imu/imu_a/gyro").unwrap();
    assert_eq!(gyro.shape()[1], 3);
    let units: hdf5::types::VarLenUnicode = gyro.attr("units").unwrap().read_scalar().unwrap();
    assert_eq!(units.as_str(), "rad/s");
    let frame: hdf5::types::VarLenUnicode = gyro.attr("axis_frame").unwrap().read_scalar().unwrap();
    assert_eq!(frame.as_str(), "FRD");
    for path in [
        "imu/imu_a",
        "gnss/gps",
        "events",
        "imu/imu_a/t_mono_ns",
        "gnss/gps/vel_ned",
    ] {
        let v: u32 = f
            .group(path)
            .map(|g| g.attr("schema_version").unwrap().read_scalar().unwrap())
            .unwrap_or_else(|_| {
                f.dataset(path)
                    .unwrap()
                    .attr("schema_version")
                    .unwrap()
                    .read_scalar()
                    .unwrap()
            });
        assert_eq!(v, imulab::store::SCHEMA_VERSION, "{path}");
    }
    // Chunk rows = rate × chunk interval (10 s by default), and the filters are on.
    assert_eq!(gyro.chunk(), Some(vec![1000, 3]));
    assert_eq!(
        f.dataset("gnss/gps/lat_deg").unwrap().chunk(),
        Some(vec![50])
    );
    assert!(gyro.filters().len() >= 2);
    // The writer grows tables ahead of the rows written; a finished file has every column
    // cut back to them: same length, no trailing unwritten (fill value) rows.
    for (group, need_rows) in [("imu/imu_a", true), ("gnss/gps", true), ("events", false)] {
        let g = f.group(group).unwrap();
        let t: Vec<i64> = g.dataset("t_mono_ns").unwrap().read_raw().unwrap();
        assert!(!need_rows || !t.is_empty(), "{group}: no rows");
        assert!(t.iter().all(|&x| x != i64::MIN), "{group}: unwritten rows");
        for name in g.member_names().unwrap() {
            let n = g.dataset(&name).unwrap().shape()[0];
            assert_eq!(n, t.len(), "{group}/{name}");
        }
    }
}

#[test]
fn writer_refuses_bad_input_with_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s4");
    let mut w = imulab::store::SessionWriter::create(&dir, manifest(), fast_opts()).unwrap();
    let e = w
        .append_imu("nope", &[imu_row(0, 0)])
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope") && e.contains("manifest"), "{e}");
    let e = w
        .append_gnss("imu_a", &[gnss_row(0)])
        .unwrap_err()
        .to_string();
    assert!(e.contains("imu_a") && e.contains("imu device"), "{e}");
    w.append_imu("imu_a", &[imu_row(0, 5)]).unwrap();
    let e = w
        .append_imu("imu_a", &[imu_row(0, 4)])
        .unwrap_err()
        .to_string();
    assert!(e.contains("back in time"), "{e}");
    w.close().unwrap();
    // A second session in the same directory is refused.
    let e = imulab::store::SessionWriter::create(&dir, manifest(), fast_opts())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("not empty"), "{e}");
}

#[test]
fn rotation_by_size_and_a_slow_device_still_read_back_in_order() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s5");
    // Chunks of 10 s reach the file every 10 s (before that the rows are in the journal),
    // so the file passes 40 kB, and rotates, after each.
    let opts = imulab::store::WriterOptions {
        rotate_bytes: 40_000,
        rotate_after: std::time::Duration::from_secs(3600),
        ..fast_opts()
    };
    write_session(&dir, 40, 20, opts);
    let s = Session::open(&dir).unwrap();
    assert!(
        s.files().len() >= 3,
        "expected rotation by size, got {:?}",
        s.files()
    );
    assert!(s.problems().is_empty());
    // The 5 Hz GNSS fills a 50-row chunk per 10 s; everything comes back in order.
    let mut n = 0;
    for b in s.gnss_blocks("gps", TimeRange::all(), 7).unwrap() {
        let b = b.unwrap();
        for k in 0..b.len() {
            assert_eq!(b.record(k), gnss_row(n));
            n += 1;
        }
    }
    assert_eq!(n, 200);
    let sum = s.stream_summary(&layout::imu_path("imu_a"));
    assert_eq!(sum.rows, 4000);
}

#[test]
fn raw_journal_and_truth_read_back_through_the_session() {
    use imulab::store::{SessionWriter, TruthImuRecord, TruthNavRecord, WriterOptions};
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s6");
    let mut m = manifest();
    m.truth_nav_rate_hz = Some(10.0);
    let opts = WriterOptions {
        raw_journal: true,
        rotate_after: std::time::Duration::from_secs(3),
        ..fast_opts()
    };
    let mut w = SessionWriter::create(&dir, m, opts).unwrap();
    let read_of = |i: usize| -> Vec<u8> { (0..(i % 5 + 1)).map(|k| (i + k) as u8).collect() };
    for i in 0..800 {
        let r = imu_row(0, i);
        w.append_raw("imu_a", r.t_mono_ns, &read_of(i)).unwrap();
        w.append_imu("imu_a", &[r]).unwrap();
        w.append_truth_imu(
            "imu_a",
            &[TruthImuRecord {
                t_mono_ns: r.t_mono_ns,
                gyro_bias: [i as f64, 0.0, 0.0],
                accel_bias: [0.0; 3],
                gyro_true: [0.0; 3],
                accel_true: [0.0, 0.0, i as f64],
            }],
        )
        .unwrap();
        if i % 10 == 0 {
            w.append_truth_nav(&[TruthNavRecord {
                t_mono_ns: r.t_mono_ns,
                lat_deg: i as f64,
                lon_deg: 0.0,
                height_m: 0.0,
                vel_ned: [0.0; 3],
                quat_nb: [1.0, 0.0, 0.0, 0.0],
            }])
            .unwrap();
        }
    }
    w.close().unwrap();
    // Truth tables are chunked at the truth rate (10 Hz × 10 s), not at the IMU's 100 Hz.
    let f = hdf5::File::open(dir.join("chunk-000000.h5")).unwrap();
    for (path, chunk) in [
        ("truth/imu/imu_a/accel_true", vec![100, 3]),
        ("truth/nav/lat_deg", vec![100]),
        ("imu/imu_a/gyro", vec![1000, 3]),
    ] {
        assert_eq!(f.dataset(path).unwrap().chunk(), Some(chunk), "{path}");
    }
    drop(f);
    let s = Session::open(&dir).unwrap();
    assert!(s.files().len() >= 3);
    let mut i = 0;
    for b in s.raw_blocks("imu_a", TimeRange::all(), 64).unwrap() {
        let b = b.unwrap();
        let mut at = 0;
        for k in 0..b.t_mono_ns.len() {
            assert_eq!(b.t_mono_ns[k], imu_row(0, i).t_mono_ns);
            let len = b.len[k] as usize;
            assert_eq!(&b.bytes[at..at + len], read_of(i).as_slice(), "read {i}");
            at += len;
            i += 1;
        }
        assert_eq!(at, b.bytes.len());
    }
    assert_eq!(i, 800);
    // Every device has a raw group; one that received no bytes reads as empty.
    assert_eq!(
        s.raw_blocks("gps", TimeRange::all(), 64)
            .unwrap()
            .map(|b| b.unwrap().t_mono_ns.len())
            .sum::<usize>(),
        0
    );
    let nav: Vec<f64> = s
        .truth_nav_blocks(TimeRange::all(), 7)
        .unwrap()
        .flat_map(|b| b.unwrap().lat_deg)
        .collect();
    assert_eq!(nav, (0..80).map(|k| (k * 10) as f64).collect::<Vec<_>>());
    let acc: Vec<f64> = s
        .truth_imu_blocks("imu_a", TimeRange::all(), 100)
        .unwrap()
        .flat_map(|b| b.unwrap().accel_true.into_iter().map(|a| a[2]))
        .collect();
    assert_eq!(acc, (0..800).map(|k| k as f64).collect::<Vec<_>>());
    // Sessions without truth say so.
    let plain = tmp.path().join("s7");
    write_session(&plain, 1, 50, fast_opts());
    let e = Session::open(&plain)
        .unwrap()
        .truth_nav_blocks(TimeRange::all(), 10)
        .err()
        .unwrap();
    assert!(e.to_string().contains("not a simulated session"));
}

/// `imu_columns` gives exactly the rows `imu_blocks` gives, per axis, across rotated files,
/// with blocks that split chunks, with a time range, and only the columns asked for.
#[test]
fn chosen_columns_read_back_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("cols");
    write_session(&dir, 25, 37, fast_opts());
    let s = Session::open(&dir).unwrap();
    let all = ImuColumnSet {
        t_sensor: true,
        gyro: true,
        accel: true,
        temp: true,
    };
    let read = |range: TimeRange, set: ImuColumnSet| {
        let mut reader = s.imu_columns("imu_b", range, 333, set).unwrap();
        let mut block = ImuColumns::default();
        let mut rows = Vec::new();
        while let Some(r) = reader.next_into(&mut block) {
            r.unwrap();
            assert!(block.len() <= 333 && !block.is_empty());
            for k in 0..block.len() {
                let pick = |v: &Vec<f64>| v.get(k).copied().unwrap_or(f64::NAN);
                rows.push((
                    block.t_mono_ns[k],
                    pick(&block.t_sensor),
                    [0, 1, 2].map(|a| pick(&block.gyro[a])),
                    [0, 1, 2].map(|a| pick(&block.accel[a])),
                    pick(&block.temp),
                ));
            }
        }
        rows
    };
    let got = read(TimeRange::all(), all);
    assert_eq!(got.len(), 2500);
    for (i, row) in got.iter().enumerate() {
        let want = imu_row(1, i);
        assert_eq!(
            *row,
            (
                want.t_mono_ns,
                want.t_sensor,
                want.gyro,
                want.accel,
                want.temp
            ),
            "row {i}"
        );
    }
    let range = TimeRange::new(
        Some(imu_row(1, 950).t_mono_ns),
        Some(imu_row(1, 1250).t_mono_ns),
    );
    let gyro_only = ImuColumnSet {
        gyro: true,
        ..ImuColumnSet::default()
    };
    let part = read(range, gyro_only);
    assert_eq!(part.len(), 300);
    assert_eq!(part[0].0, imu_row(1, 950).t_mono_ns);
    assert_eq!(part[0].2, imu_row(1, 950).gyro);
    assert!(part[0].1.is_nan() && part[0].3[0].is_nan() && part[0].4.is_nan());
}

/// Damaged compressed bytes inside a chunk file give an error naming the file, never a
/// crash or wrong values, and the next file is still read.
#[test]
fn damaged_chunks_give_errors_from_the_column_reader() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("dmg");
    write_session(&dir, 12, 100, fast_opts());
    let path = dir.join("chunk-000000.h5");
    // Damage the middle of imu_a's first gyro chunk (the middle of the file, used before,
    // moves with the layout: it hit the events chunk once that was written later).
    let chunk = hdf5::File::open(&path)
        .unwrap()
        .dataset("imu/imu_a/gyro")
        .unwrap()
        .chunk_info(0)
        .unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let len = chunk.size.min(256) as usize;
    let at = (chunk.addr + chunk.size / 2) as usize - len / 2;
    for b in &mut bytes[at..at + len] {
        *b ^= 0x5a;
    }
    std::fs::write(&path, &bytes).unwrap();
    let s = Session::open(&dir).unwrap();
    let set = ImuColumnSet {
        t_sensor: true,
        gyro: true,
        accel: true,
        temp: true,
    };
    let mut found = 0;
    for device in ["imu_a", "imu_b"] {
        let mut reader = s.imu_columns(device, TimeRange::all(), 64, set).unwrap();
        let mut block = ImuColumns::default();
        let (mut good, mut errors) = (0usize, Vec::new());
        while let Some(r) = reader.next_into(&mut block) {
            match r {
                Ok(()) => {
                    for k in 0..block.len() {
                        let i =
                            ((block.t_mono_ns[k] - imu_row(0, 0).t_mono_ns) / 10_000_000) as usize;
                        let d = usize::from(device == "imu_b");
                        assert_eq!(block.gyro[0][k], imu_row(d, i).gyro[0], "{device} row {i}");
                        good += 1;
                    }
                }
                Err(e) => errors.push(e.to_string()),
            }
        }
        // The second file (2 s of rows) always reads; an error names the damaged file.
        assert!(good >= 200, "{device}: {good} rows, {errors:?}");
        for e in &errors {
            assert!(e.contains("chunk-000000.h5"), "{e}");
        }
        eprintln!("{device}: {good} rows, errors {errors:?}");
        found += errors.len();
    }
    // The damage lands in an IMU column's compressed data: the inflater refuses it.
    assert!(found > 0, "the damage went unnoticed");
}

/// Rotation must leave nothing of a finished file open in the HDF5 library: a leaked dataset
/// or group handle keeps the whole file open (its metadata cache, chunk index, free space),
/// and a daemon's memory would then grow with every rotation. Opening a finished file again
/// shares HDF5's state of the file if it is still open, so the open-object count there
/// includes any handle the writer leaked; only our own file handle may be open.
#[test]
fn rotation_leaves_nothing_of_the_finished_file_open_in_hdf5() {
    use imulab::store::SessionWriter;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s7");
    let mut w = SessionWriter::create(&dir, crate::common::manifest(), fast_opts()).unwrap();
    for n in 0..24 {
        let rows: Vec<_> = (n * 50..(n + 1) * 50).map(|k| imu_row(0, k)).collect();
        w.append_imu("imu_a", &rows).unwrap();
        w.rotate().unwrap();
        let finished = dir.join(layout::chunk_file_name(n as u32));
        let file = hdf5::File::open(&finished)
            .unwrap_or_else(|e| panic!("{} after rotation {n}: {e}", finished.display()));
        // SAFETY: `file` is a live file handle for the whole call; the HDF5 lock is held.
        let open = hdf5::sync::sync(|| unsafe {
            hdf5_sys::h5f::H5Fget_obj_count(file.id(), hdf5_sys::h5f::H5F_OBJ_ALL)
        });
        assert_eq!(
            open,
            1,
            "{} after rotation {n}: HDF5 objects still open in it",
            finished.display()
        );
    }
    w.close().unwrap();
}
