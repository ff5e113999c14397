//! imulogd configuration: the example config is valid, and every rejection rule says where
//! (key path), what, and gives a hint.

use std::path::Path;

use imulab::daemon::config::{parse, ConfigError};

const IMU: &str = r#"
[[device]]
name = "imu-a"
protocol = "wit"
rate_hz = 150
serial = { port = "/dev/imu-a", baud = 115200 }
"#;

fn with_session(session_extra: &str, devices: &str) -> String {
    format!("[session]\noutput_dir = \"/var/lib/imulogd\"\n{session_extra}\n{devices}")
}

fn reject(text: &str) -> ConfigError {
    match parse(text, "test.toml") {
        Ok(_) => panic!("accepted a bad config:\n{text}"),
        Err(e) => e,
    }
}

/// Asserts one issue at `path` whose message contains `needle` and that carries a hint.
fn assert_issue(text: &str, path: &str, needle: &str) {
    let e = reject(text);
    assert!(
        e.has_issue(path, needle),
        "expected `{needle}` at `{path}`, got:\n{e}"
    );
    let issue = e
        .issues
        .iter()
        .find(|i| i.path.starts_with(path) && i.message.contains(needle))
        .unwrap();
    assert!(issue.hint.is_some(), "no hint for {issue}");
    assert!(e.to_string().contains("test.toml"), "{e}");
}

fn device(extra: &str) -> String {
    format!("[[device]]\nname = \"imu-a\"\nprotocol = \"wit\"\nrate_hz = 150\n{extra}\n")
}

#[test]
fn example_config_in_systemd_dir_is_valid() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd/imulogd.toml");
    let config = imulab::daemon::config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(config.devices.len() >= 2);
}

#[test]
fn minimal_config_gets_defaults() {
    let c = parse(&with_session("", IMU), "t").unwrap();
    assert_eq!(c.session.flush_interval_ms, 1000);
    assert_eq!(c.session.chunk_interval_ms(), 10_000);
    assert_eq!(c.session.deflate_level, 1);
    assert_eq!(c.devices[0].gap_factor, 3.0);
    assert_eq!(c.devices[0].gyro_scale, 1.0);
    assert_eq!(
        c.status_path(),
        Path::new("/var/lib/imulogd/imulogd-status.json")
    );
}

#[test]
fn toml_syntax_error() {
    let e = reject("[session\noutput_dir = 1");
    assert!(e.issues[0].message.contains("TOML syntax error"), "{e}");
}

#[test]
fn unknown_top_level_key_with_suggestion() {
    assert_issue(
        &format!("[sesion]\noutput_dir = \"/x\"\n{IMU}"),
        "",
        "unknown field `sesion`",
    );
    let e = reject(&format!("[sesion]\noutput_dir = \"/x\"\n{IMU}"));
    assert_eq!(e.issues[0].hint.as_deref(), Some("did you mean `session`?"));
}

#[test]
fn unknown_session_key_names_path_line_and_suggestion() {
    let e = reject(&with_session("flush_intervall_ms = 10", IMU));
    let issue = &e.issues[0];
    assert_eq!(issue.path, "session.flush_intervall_ms");
    assert!(
        issue.message.contains("unknown field `flush_intervall_ms`"),
        "{issue}"
    );
    assert!(issue.message.contains("line 3"), "{issue}");
    assert_eq!(
        issue.hint.as_deref(),
        Some("did you mean `flush_interval_ms`?")
    );
}

#[test]
fn unknown_nested_device_key_names_full_path() {
    let text = with_session(
        "",
        "[[device]]\nname = \"a\"\nprotocol = \"wit\"\nrate_hz = 1\nserial = { port = \"/dev/x\", baudrate = 9600 }\n",
    );
    let e = reject(&text);
    assert_eq!(e.issues[0].path, "device[0].serial.baudrate", "{e}");
    assert_eq!(e.issues[0].hint.as_deref(), Some("did you mean `baud`?"));
}

#[test]
fn wrong_type_names_path() {
    let text = with_session(
        "",
        "[[device]]\nname = \"a\"\nprotocol = \"wit\"\nrate_hz = \"fast\"\nserial = { port = \"/dev/x\" }\n",
    );
    let e = reject(&text);
    assert_eq!(e.issues[0].path, "device[0].rate_hz", "{e}");
    assert!(e.issues[0].message.contains("invalid type"), "{e}");
}

#[test]
fn unknown_protocol_lists_the_codec_table() {
    let text = with_session(
        "",
        "[[device]]\nname = \"a\"\nprotocol = \"witt\"\nrate_hz = 1\nserial = { port = \"/dev/x\" }\n",
    );
    assert_issue(&text, "device[0].protocol", "unknown variant `witt`");
    assert_eq!(
        reject(&text).issues[0].hint.as_deref(),
        Some("did you mean `wit`?")
    );
}

#[test]
fn missing_session_table() {
    let e = reject(IMU);
    assert!(
        e.issues[0].message.contains("missing field `session`"),
        "{e}"
    );
}

#[test]
fn no_devices() {
    assert_issue(&with_session("", ""), "device", "no devices configured");
}

#[test]
fn duplicate_device_names() {
    assert_issue(
        &with_session("", &format!("{IMU}{IMU}")),
        "device[1].name",
        "duplicate device name",
    );
}

#[test]
fn bad_device_name() {
    let text = with_session("", &IMU.replace("imu-a", "imu a/1"));
    assert_issue(&text, "device[0].name", "not a valid device name");
}

#[test]
fn bad_rates() {
    for rate in ["0", "-5", "nan", "inf", "1e9"] {
        let text = with_session(
            "",
            &IMU.replace("rate_hz = 150", &format!("rate_hz = {rate}")),
        );
        assert_issue(&text, "device[0].rate_hz", "not a usable rate");
    }
}

#[test]
fn bad_gap_factor() {
    assert_issue(
        &with_session(
            "",
            &device("gap_factor = 1.0\nserial = { port = \"/dev/x\" }"),
        ),
        "device[0].gap_factor",
        "out of range",
    );
}

#[test]
fn bad_retry_delays() {
    assert_issue(
        &with_session(
            "",
            &device("retry_initial_ms = 9000\nretry_max_ms = 100\nserial = { port = \"/dev/x\" }"),
        ),
        "device[0].retry_initial_ms",
        "at most retry_max_ms",
    );
    assert_issue(
        &with_session(
            "",
            &device("retry_max_ms = 9000000\nserial = { port = \"/dev/x\" }"),
        ),
        "device[0].retry_max_ms",
        "more than 10 minutes",
    );
}

#[test]
fn no_transport_and_two_transports() {
    assert_issue(
        &with_session("", &device("")),
        "device[0]",
        "no transport given",
    );
    assert_issue(
        &with_session(
            "",
            &device("serial = { port = \"/dev/x\" }\ntcp = { address = \"h:1\" }"),
        ),
        "device[0]",
        "more than one transport given (serial, tcp)",
    );
}

#[test]
fn relative_port_and_bad_baud() {
    assert_issue(
        &with_session("", &device("serial = { port = \"ttyUSB0\" }")),
        "device[0].serial.port",
        "not an absolute device path",
    );
    assert_issue(
        &with_session("", &device("serial = { port = \"/dev/x\", baud = 7 }")),
        "device[0].serial.baud",
        "not a serial baud rate",
    );
}

#[test]
fn bad_tcp_address() {
    for address in ["localhost", "host:99999", ":4001"] {
        assert_issue(
            &with_session("", &device(&format!("tcp = {{ address = \"{address}\" }}"))),
            "device[0].tcp.address",
            "is not host:port",
        );
    }
    assert!(parse(
        &with_session("", &device("tcp = { address = \"[::1]:4001\" }")),
        "t"
    )
    .is_ok());
}

const DBC: &str = "dbc = { file = \"/etc/imu.dbc\", mapping = \"/etc/imu_mapping.toml\" }";

fn can_device(extra: &str) -> String {
    format!("[[device]]\nname = \"canimu\"\nprotocol = \"can-dbc\"\nrate_hz = 100\n{extra}\n")
}

#[test]
fn can_protocol_needs_can_transport_and_back() {
    assert_issue(
        &with_session(
            "",
            &can_device(&format!("serial = {{ port = \"/dev/x\" }}\n{DBC}")),
        ),
        "device[0].serial",
        "cannot run over a serial transport",
    );
    assert_issue(
        &with_session("", &device("can = { interface = \"can0\" }")),
        "device[0].can",
        "protocol `wit` cannot run over a can transport",
    );
    assert!(parse(
        &with_session(
            "",
            &can_device(&format!("can = {{ interface = \"vcan0\" }}\n{DBC}"))
        ),
        "t"
    )
    .is_ok());
}

#[test]
fn dbc_required_for_can_and_refused_otherwise() {
    assert_issue(
        &with_session("", &can_device("can = { interface = \"can0\" }")),
        "device[0].dbc",
        "needs a DBC mapping",
    );
    assert_issue(
        &with_session(
            "",
            &device(&format!("serial = {{ port = \"/dev/x\" }}\n{DBC}")),
        ),
        "device[0].dbc",
        "does not use a DBC file",
    );
    assert_issue(
        &with_session(
            "",
            &can_device(&format!(
                "can = {{ interface = \"can0\" }}\n{}",
                DBC.replace("/etc/imu_mapping.toml", "")
            )),
        ),
        "device[0].dbc.mapping",
        "is empty",
    );
    assert_issue(
        &with_session(
            "",
            &can_device(&format!(
                "can = {{ interface = \"can0\" }}\n{}",
                DBC.replace("mapping", "gyro")
            )),
        ),
        "device[0].dbc.gyro",
        "unknown field `gyro`",
    );
}

#[test]
fn csv_line_format_is_checked_and_only_for_csv() {
    assert_issue(
        &with_session(
            "",
            &device("serial = { port = \"/dev/x\" }\ncsv = { separator = \";\" }"),
        ),
        "device[0].csv",
        "does not use a CSV line format",
    );
    let csv_device = |table: &str| {
        format!(
            "[[device]]\nname = \"home\"\nprotocol = \"csv\"\nrate_hz = 100\nserial = {{ port = \"/dev/x\" }}\n{table}\n"
        )
    };
    assert_issue(
        &with_session("", &csv_device("csv = { separator = \"\\n\" }")),
        "device[0].csv.separator",
        "must be one ASCII character",
    );
    assert_issue(
        &with_session(
            "",
            &csv_device("csv = { gyro = [{ index = 1 }, { index = 1 }, { index = 2 }] }"),
        ),
        "device[0].csv",
        "same column index",
    );
    assert_issue(
        &with_session("", &csv_device("csv = { colums = 3 }")),
        "device[0].csv.colums",
        "unknown field",
    );
    assert!(parse(
        &with_session(
            "",
            &csv_device("csv = { separator = \"\\t\", time = { index = 0, scale = 1e-6 } }")
        ),
        "t"
    )
    .is_ok());
}

#[test]
fn bad_dbc_or_mapping_file_is_refused_before_the_daemon_runs() {
    let dir = tempfile::tempdir().unwrap();
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let mapping = dir.path().join("mapping.toml");
    std::fs::write(
        &mapping,
        "gyro = [ { message = \"IMU_Rate\", signal = \"RateX\" }, { message = \"IMU_Rate\", signal = \"RateY\" }, { message = \"IMU_Rate\", signal = \"NoSuchSignal\" } ]\n",
    )
    .unwrap();
    let text = with_session(
        "",
        &can_device(&format!(
            "can = {{ interface = \"can0\" }}\ndbc = {{ file = \"{}\", mapping = \"{}\" }}",
            fixtures.join("imu_can.dbc").display(),
            mapping.display()
        )),
    );
    let config = parse(&text, "t").unwrap();
    let err = imulab::daemon::source::decoder_for(&config.devices[0])
        .err()
        .expect("an unknown signal is refused");
    assert!(
        err.contains("gyro[2]") && err.contains("NoSuchSignal"),
        "{err}"
    );
    let missing = text.replace("imu_can.dbc", "no_such.dbc");
    let config = parse(&missing, "t").unwrap();
    let err = imulab::daemon::source::decoder_for(&config.devices[0])
        .err()
        .expect("a missing DBC file is refused");
    assert!(err.contains("no_such.dbc"), "{err}");
}

#[test]
fn bad_can_interface_and_slcan_bitrate() {
    assert_issue(
        &with_session(
            "",
            &can_device(&format!(
                "can = {{ interface = \"a very long name\" }}\n{DBC}"
            )),
        ),
        "device[0].can.interface",
        "not a network interface name",
    );
    assert_issue(
        &with_session(
            "",
            &can_device(&format!(
                "slcan = {{ port = \"/dev/x\", bitrate = 333000 }}\n{DBC}"
            )),
        ),
        "device[0].slcan.bitrate",
        "not an slcan bitrate",
    );
}

#[test]
fn axis_map_rules() {
    let with_axes = |axes: &str| {
        with_session(
            "",
            &device(&format!("serial = {{ port = \"/dev/x\" }}\naxes = {axes}")),
        )
    };
    let ok = parse(&with_axes("{ map = [\"-y\", \"x\", \"z\"] }"), "t").unwrap();
    let r = ok.devices[0].body_from_sensor;
    assert_eq!((r[(0, 1)], r[(1, 0)], r[(2, 2)]), (-1.0, 1.0, 1.0));
    assert_issue(
        &with_axes("{ map = [\"x\", \"x\", \"z\"] }"),
        "device[0].axes.map[1]",
        "used twice",
    );
    assert_issue(
        &with_axes("{ map = [\"x\", \"w\", \"z\"] }"),
        "device[0].axes.map[1]",
        "is not an axis",
    );
    assert_issue(
        &with_axes("{ map = [\"-x\", \"y\", \"z\"] }"),
        "device[0].axes",
        "reflection",
    );
    assert_issue(
        &with_axes("{}"),
        "device[0].axes",
        "exactly one of `map` and `rotation`",
    );
}

#[test]
fn rotation_matrix_rules() {
    let with_rotation = |rows: &str| {
        with_session(
            "",
            &device(&format!(
                "serial = {{ port = \"/dev/x\" }}\naxes = {{ rotation = {rows} }}"
            )),
        )
    };
    let c = 0.5f64.sqrt();
    let good = format!("[[{c}, -{c}, 0.0], [{c}, {c}, 0.0], [0.0, 0.0, 1.0]]");
    assert!(parse(&with_rotation(&good), "t").is_ok());
    assert_issue(
        &with_rotation("[[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]"),
        "device[0].axes.rotation",
        "not orthonormal",
    );
    assert_issue(
        &with_rotation("[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]"),
        "device[0].axes",
        "reflection",
    );
}

#[test]
fn unit_overrides() {
    let c = parse(
        &with_session(
            "",
            &device("serial = { port = \"/dev/x\" }\nunits = { gyro = \"deg/s\", accel = \"mg\" }"),
        ),
        "t",
    )
    .unwrap();
    assert!((c.devices[0].gyro_scale - std::f64::consts::PI / 180.0).abs() < 1e-15);
    assert!((c.devices[0].accel_scale - 9.80665e-3).abs() < 1e-15);
    assert_issue(
        &with_session(
            "",
            &device("serial = { port = \"/dev/x\" }\nunits = { gyro = \"rpm\" }"),
        ),
        "device[0].units.gyro",
        "unknown variant `rpm`",
    );
}

#[test]
fn session_value_rules() {
    let reject_session = |extra: &str, path: &str, needle: &str| {
        assert_issue(&with_session(extra, IMU), path, needle)
    };
    reject_session(
        "flush_interval_ms = 5",
        "session.flush_interval_ms",
        "out of range",
    );
    reject_session(
        "flush_interval_ms = 100000",
        "session.flush_interval_ms",
        "out of range",
    );
    reject_session(
        "chunk_interval_ms = 1500",
        "session.chunk_interval_ms",
        "not a whole multiple",
    );
    reject_session(
        "flush_interval_ms = 300\nchunk_interval_ms = 100",
        "session.chunk_interval_ms",
        "flush_interval_ms = 300",
    );
    reject_session(
        "deflate_level = 12",
        "session.deflate_level",
        "out of range",
    );
    reject_session(
        "rotate_minutes = -1",
        "session.rotate_minutes",
        "not a duration",
    );
    reject_session(
        "queue_capacity = 0",
        "session.queue_capacity",
        "out of range",
    );
    reject_session(
        "name = \"a/b\"",
        "session.name",
        "not a valid directory name",
    );
    reject_session(
        "name = \"{date}-{user}\"",
        "session.name",
        "unknown placeholder `{user}`",
    );
    reject_session(
        "status_file = \"/\"",
        "session.status_file",
        "not a file path",
    );
    let e = reject("[session]\noutput_dir = \"\"\n[[device]]\nname = \"a\"\nprotocol = \"wit\"\nrate_hz = 1\nserial = { port = \"/dev/x\" }\n");
    assert!(e.has_issue("session.output_dir", "is empty"), "{e}");
}

#[test]
fn several_issues_are_reported_together() {
    let text = with_session(
        "deflate_level = 11",
        "[[device]]\nname = \"\"\nprotocol = \"wit\"\nrate_hz = 0\n",
    );
    let e = reject(&text);
    assert!(e.issues.len() >= 4, "{e}");
}

#[test]
fn session_name_expands_placeholders() {
    let now = chrono::DateTime::parse_from_rfc3339("2026-11-23T14:05:09Z")
        .unwrap()
        .with_timezone(&chrono::Utc);
    assert_eq!(
        imulab::daemon::config::expand_session_name("{host}-{date}-{time}", now, "bench1"),
        "bench1-20261123-140509"
    );
}

#[test]
fn missing_file_is_an_error_not_a_panic() {
    let e = imulab::daemon::config::load(Path::new("/no/such/imulogd.toml")).unwrap_err();
    assert!(e.to_string().contains("cannot read the file"), "{e}");
}

#[test]
fn dbc_paths_are_relative_to_the_config_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("imulogd.toml");
    std::fs::write(
        &path,
        with_session(
            "",
            &can_device("can = { interface = \"can0\" }\ndbc = { file = \"imu.dbc\", mapping = \"/etc/m.toml\" }"),
        ),
    )
    .unwrap();
    let config = imulab::daemon::config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let dbc = config.devices[0].dbc.as_ref().unwrap();
    assert_eq!(dbc.file, dir.path().join("imu.dbc"));
    assert_eq!(dbc.mapping, std::path::Path::new("/etc/m.toml"));
}

#[test]
fn rows_from_deltas_is_only_for_vectornav_and_mip() {
    use imulab_drivers::codec::RowsFrom;
    assert_issue(
        &with_session(
            "",
            &device("serial = { port = \"/dev/x\" }\nrows_from = \"deltas\""),
        ),
        "device[0].rows_from",
        "sends no delta theta",
    );
    let vn = |extra: &str| {
        with_session(
            "",
            &format!(
                "[[device]]\nname = \"vn\"\nprotocol = \"vectornav\"\nrate_hz = 200\nserial = {{ port = \"/dev/x\" }}\n{extra}\n"
            ),
        )
    };
    let c = parse(&vn("rows_from = \"deltas\""), "t").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.devices[0].rows_from, RowsFrom::Deltas);
    let c = parse(&vn(""), "t").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.devices[0].rows_from, RowsFrom::Rates);
    let e = reject(&vn("rows_from = \"integrals\""));
    assert!(e.to_string().contains("rows_from"), "{e}");
}

#[test]
fn a_receivers_imu_needs_a_ubx_port_and_a_name_of_its_own() {
    let receiver = |protocol: &str, imu: &str| {
        with_session(
            "",
            &format!(
                "[[device]]\nname = \"f9r\"\nprotocol = \"{protocol}\"\nrate_hz = 10\nserial = {{ port = \"/dev/f9r\" }}\nimu = {imu}\n{IMU}"
            ),
        )
    };
    let c = parse(
        &receiver("ubx", "{ name = \"f9r_imu\", rate_hz = 100 }"),
        "t",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let imu = c.devices[0].imu.as_ref().expect("imu kept");
    assert_eq!((imu.name.as_str(), imu.rate_hz), ("f9r_imu", 100.0));
    assert_eq!(c.devices[0].rows_rate_hz(), 110.0);
    parse(
        &receiver("gnss", "{ name = \"f9r_imu\", rate_hz = 100 }"),
        "t",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_issue(
        &receiver("nmea", "{ name = \"f9r_imu\", rate_hz = 100 }"),
        "device[0].imu",
        "carries no UBX ESF messages",
    );
    // Clashes: another device's name, the receiver's own, another receiver's IMU.
    assert_issue(
        &receiver("ubx", "{ name = \"imu-a\", rate_hz = 100 }"),
        "device[0].imu.name",
        "already the name of device[1]",
    );
    assert_issue(
        &receiver("ubx", "{ name = \"f9r\", rate_hz = 100 }"),
        "device[0].imu.name",
        "this device's own name",
    );
    let two = with_session(
        "",
        "[[device]]\nname = \"a\"\nprotocol = \"ubx\"\nrate_hz = 10\nserial = { port = \"/dev/a\" }\nimu = { name = \"esf\", rate_hz = 100 }\n\
         [[device]]\nname = \"b\"\nprotocol = \"gnss\"\nrate_hz = 10\nserial = { port = \"/dev/b\" }\nimu = { name = \"esf\", rate_hz = 100 }\n",
    );
    assert_issue(&two, "device[1].imu.name", "the name of device[0]'s imu");
    assert_issue(
        &receiver("ubx", "{ name = \"f9r imu\", rate_hz = 100 }"),
        "device[0].imu.name",
        "not a valid device name",
    );
    assert_issue(
        &receiver("ubx", "{ name = \"f9r_imu\", rate_hz = 0 }"),
        "device[0].imu.rate_hz",
        "not a usable rate",
    );
    let e = reject(&receiver("ubx", "{ name = \"f9r_imu\" }"));
    assert!(e.to_string().contains("rate_hz"), "{e}");
}
