//! The ROS messages imulab reads from bags: `sensor_msgs/Imu`, `sensor_msgs/NavSatFix`,
//! `sensor_msgs/Temperature` and `geometry_msgs/TwistStamped`, in both of their wire
//! encodings. ROS 2 messages are CDR (the OMG Common Data Representation: little- or
//! big-endian by the 4-byte encapsulation header, each value aligned to its size from the
//! start of the body). ROS 1 messages are the ROS 1 serialisation (little-endian, packed, no
//! alignment); the only Rust crate for it (`serde_rosmsg`) has been unmaintained since 2017
//! and expects the TCPROS length prefix. Both have strings as a u32 length then the bytes,
//! so [`decode`] reads both with one small cursor, field by field, without allocating (a
//! bag holds millions of IMU messages). The serde structs of [`cdr`] write CDR messages
//! with the `cdr-encoding` crate (for test bags and benchmarks), which also checks the
//! cursor's alignment rules in the tests below.

use serde::Serialize;

/// The message types imulab reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MessageType {
    Imu,
    NavSatFix,
    Temperature,
    TwistStamped,
}

impl MessageType {
    /// The type of a ROS type name, ROS 1 (`sensor_msgs/Imu`) or ROS 2
    /// (`sensor_msgs/msg/Imu`) spelling; `None` for every other type.
    pub fn from_name(name: &str) -> Option<Self> {
        match normalise_type(name).as_str() {
            "sensor_msgs/Imu" => Some(MessageType::Imu),
            "sensor_msgs/NavSatFix" => Some(MessageType::NavSatFix),
            "sensor_msgs/Temperature" => Some(MessageType::Temperature),
            "geometry_msgs/TwistStamped" => Some(MessageType::TwistStamped),
            _ => None,
        }
    }

    /// The ROS 1 spelling of the type name.
    pub fn name(self) -> &'static str {
        match self {
            MessageType::Imu => "sensor_msgs/Imu",
            MessageType::NavSatFix => "sensor_msgs/NavSatFix",
            MessageType::Temperature => "sensor_msgs/Temperature",
            MessageType::TwistStamped => "geometry_msgs/TwistStamped",
        }
    }
}

/// A type name in the ROS 1 spelling: `pkg/msg/Name` → `pkg/Name`.
pub fn normalise_type(name: &str) -> String {
    name.replacen("/msg/", "/", 1)
}

/// How a message's bytes are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// ROS 2: CDR with its encapsulation header.
    Cdr,
    /// ROS 1 serialisation.
    Ros1,
}

/// One decoded message: the header stamp in ns since the epoch of its clock, and the values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reading {
    /// Angular velocity (rad/s) and linear acceleration (m/s²), x, y, z.
    Imu {
        stamp_ns: i64,
        gyro: [f64; 3],
        accel: [f64; 3],
    },
    /// A GNSS fix.
    Fix(Fix),
    /// Temperature, °C.
    Temperature { stamp_ns: i64, celsius: f64 },
    /// Linear (m/s) and angular (rad/s) velocity.
    Twist {
        stamp_ns: i64,
        linear: [f64; 3],
        angular: [f64; 3],
    },
}

/// A `sensor_msgs/NavSatFix`: `status` as NavSatStatus (-1 no fix, 0 fix, 1 SBAS, 2 GBAS),
/// WGS-84 latitude/longitude (deg) and altitude above the ellipsoid (m), the ENU position
/// covariance (m², row-major) and its type (0 unknown, 1 approximated, 2 diagonal known,
/// 3 known).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    pub stamp_ns: i64,
    pub status: i8,
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
    pub covariance: [f64; 9],
    pub covariance_type: u8,
}

impl Reading {
    /// The header stamp, ns.
    pub fn stamp_ns(&self) -> i64 {
        match *self {
            Reading::Fix(Fix { stamp_ns, .. }) => stamp_ns,
            Reading::Imu { stamp_ns, .. }
            | Reading::Temperature { stamp_ns, .. }
            | Reading::Twist { stamp_ns, .. } => stamp_ns,
        }
    }
}

/// The ROS 2 message definitions as serde structs, field for field in CDR order.
pub mod cdr {
    use super::*;

    /// `builtin_interfaces/Time`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
    pub struct Time {
        pub sec: i32,
        pub nanosec: u32,
    }

    /// `std_msgs/Header`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize)]
    pub struct Header {
        pub stamp: Time,
        pub frame_id: String,
    }

    /// `geometry_msgs/Vector3`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
    pub struct Vector3 {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    /// `geometry_msgs/Quaternion`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
    pub struct Quaternion {
        pub x: f64,
        pub y: f64,
        pub z: f64,
        pub w: f64,
    }

    /// `sensor_msgs/Imu`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize)]
    pub struct Imu {
        pub header: Header,
        pub orientation: Quaternion,
        pub orientation_covariance: [f64; 9],
        pub angular_velocity: Vector3,
        pub angular_velocity_covariance: [f64; 9],
        pub linear_acceleration: Vector3,
        pub linear_acceleration_covariance: [f64; 9],
    }

    /// `sensor_msgs/NavSatStatus`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
    pub struct NavSatStatus {
        pub status: i8,
        pub service: u16,
    }

    /// `sensor_msgs/NavSatFix`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize)]
    pub struct NavSatFix {
        pub header: Header,
        pub status: NavSatStatus,
        pub latitude: f64,
        pub longitude: f64,
        pub altitude: f64,
        pub position_covariance: [f64; 9],
        pub position_covariance_type: u8,
    }

    /// `sensor_msgs/Temperature`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize)]
    pub struct Temperature {
        pub header: Header,
        pub temperature: f64,
        pub variance: f64,
    }

    /// `geometry_msgs/Twist`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
    pub struct Twist {
        pub linear: Vector3,
        pub angular: Vector3,
    }

    /// `geometry_msgs/TwistStamped`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize)]
    pub struct TwistStamped {
        pub header: Header,
        pub twist: Twist,
    }

    /// The 4-byte encapsulation header of little-endian CDR (representation id 0x0001).
    pub const ENCAPSULATION_LE: [u8; 4] = [0, 1, 0, 0];

    /// Serialises `value` as a ROS 2 message: encapsulation header, then little-endian CDR.
    pub fn encode<T: Serialize>(value: &T) -> Vec<u8> {
        let mut out = ENCAPSULATION_LE.to_vec();
        // Serialising these plain structs into a Vec cannot fail.
        let body = cdr_encoding::to_vec::<T, byteorder::LittleEndian>(value).unwrap_or_default();
        out.extend_from_slice(&body);
        out
    }
}

/// Reads a message field by field: ROS 1 (little-endian, packed) or CDR (either byte order,
/// each value aligned to its size from the start of the body).
struct Cursor<'a> {
    data: &'a [u8],
    at: usize,
    little: bool,
    aligned: bool,
}

impl<'a> Cursor<'a> {
    fn ros1(data: &'a [u8]) -> Self {
        Cursor {
            data,
            at: 0,
            little: true,
            aligned: false,
        }
    }

    /// The body after the CDR encapsulation header, in the byte order it names.
    fn cdr(data: &'a [u8]) -> Result<Self, String> {
        if data.len() < 4 {
            return Err(format!("{} bytes, shorter than the CDR header", data.len()));
        }
        // Representation id: 0x0000/0x0002 big-endian CDR/PL_CDR, 0x0001/0x0003 little.
        let little = match [data[0], data[1]] {
            [0, 0] | [0, 2] => false,
            [0, 1] | [0, 3] => true,
            other => return Err(format!("unknown CDR representation {other:02x?}")),
        };
        Ok(Cursor {
            data: &data[4..],
            at: 0,
            little,
            aligned: true,
        })
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(format!(
                "message ends at byte {} of {} needed",
                self.data.len(),
                self.at.saturating_add(n)
            ));
        };
        let bytes = &self.data[self.at..end];
        self.at = end;
        Ok(bytes)
    }

    /// `N` bytes of one value, aligned to `N` in CDR, in little-endian order.
    fn value<const N: usize>(&mut self) -> Result<[u8; N], String> {
        if self.aligned {
            self.at = self.at.next_multiple_of(N);
        }
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        if !self.little {
            a.reverse();
        }
        Ok(a)
    }

    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.value::<1>()?[0])
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.value()?))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.value()?))
    }
    fn f64s<const N: usize>(&mut self) -> Result<[f64; N], String> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64()?;
        }
        Ok(out)
    }
    fn skip_string(&mut self) -> Result<(), String> {
        let len = self.u32()? as usize;
        self.take(len)?;
        Ok(())
    }

    /// `std_msgs/Header`: ROS 1 seq, stamp secs and nsecs, frame_id; ROS 2 stamp sec and
    /// nanosec, frame_id. The stamp in ns.
    fn header(&mut self) -> Result<i64, String> {
        let secs = if self.aligned {
            i64::from(self.u32()? as i32)
        } else {
            let _seq = self.u32()?;
            i64::from(self.u32()?)
        };
        let nsecs = self.u32()?;
        self.skip_string()?;
        Ok(secs * 1_000_000_000 + i64::from(nsecs))
    }
}

/// Decodes one message of type `kind` from its bytes.
pub fn decode(kind: MessageType, encoding: Encoding, data: &[u8]) -> Result<Reading, String> {
    let mut c = match encoding {
        Encoding::Cdr => Cursor::cdr(data)?,
        Encoding::Ros1 => Cursor::ros1(data),
    };
    let stamp_ns = c.header()?;
    Ok(match kind {
        MessageType::Imu => {
            let _orientation: [f64; 4] = c.f64s()?;
            let _cov: [f64; 9] = c.f64s()?;
            let gyro = c.f64s()?;
            let _cov: [f64; 9] = c.f64s()?;
            let accel = c.f64s()?;
            let _cov: [f64; 9] = c.f64s()?;
            Reading::Imu {
                stamp_ns,
                gyro,
                accel,
            }
        }
        MessageType::NavSatFix => {
            let status = c.u8()? as i8;
            let _service = c.value::<2>()?;
            Reading::Fix(Fix {
                stamp_ns,
                status,
                lat_deg: c.f64()?,
                lon_deg: c.f64()?,
                alt_m: c.f64()?,
                covariance: c.f64s()?,
                covariance_type: c.u8()?,
            })
        }
        MessageType::Temperature => Reading::Temperature {
            stamp_ns,
            celsius: c.f64()?,
        },
        MessageType::TwistStamped => Reading::Twist {
            stamp_ns,
            linear: c.f64s()?,
            angular: c.f64s()?,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(sec: i32, nanosec: u32, frame_id: &str) -> cdr::Header {
        cdr::Header {
            stamp: cdr::Time { sec, nanosec },
            frame_id: frame_id.into(),
        }
    }

    /// `value` in big-endian CDR, as some DDS vendors write it.
    fn encode_big_endian<T: Serialize>(value: &T) -> Vec<u8> {
        let mut out = vec![0, 0, 0, 0];
        out.extend(cdr_encoding::to_vec::<T, byteorder::BigEndian>(value).unwrap());
        out
    }

    #[test]
    fn cdr_messages_decode_in_both_byte_orders_whatever_the_frame_ids_padding() {
        // Frame ids of 0-8 characters shift every later value's alignment padding.
        for frame_id in ["", "a", "imu", "imu_lnk", "imu_link"] {
            let imu = cdr::Imu {
                header: header(1_700_000_000, 123_456_789, frame_id),
                angular_velocity: cdr::Vector3 {
                    x: 0.1,
                    y: -0.2,
                    z: 0.3,
                },
                linear_acceleration: cdr::Vector3 {
                    x: 1.0,
                    y: 2.0,
                    z: 9.8,
                },
                orientation_covariance: [-1.0; 9],
                ..Default::default()
            };
            let fix = cdr::NavSatFix {
                header: header(-5, 7, frame_id),
                status: cdr::NavSatStatus {
                    status: -1,
                    service: 9,
                },
                latitude: 48.1,
                longitude: 11.5,
                altitude: 520.25,
                position_covariance: std::array::from_fn(|i| i as f64),
                position_covariance_type: 2,
            };
            let temperature = cdr::Temperature {
                header: header(3, 4, frame_id),
                temperature: 24.5,
                variance: 0.1,
            };
            let twist = cdr::TwistStamped {
                header: header(5, 6, frame_id),
                twist: cdr::Twist {
                    linear: cdr::Vector3 {
                        x: 1.0,
                        y: 0.0,
                        z: -1.0,
                    },
                    angular: cdr::Vector3 {
                        x: 0.0,
                        y: 0.5,
                        z: 0.0,
                    },
                },
            };
            let expected = [
                (
                    MessageType::Imu,
                    Reading::Imu {
                        stamp_ns: 1_700_000_000_123_456_789,
                        gyro: [0.1, -0.2, 0.3],
                        accel: [1.0, 2.0, 9.8],
                    },
                ),
                (
                    MessageType::NavSatFix,
                    Reading::Fix(Fix {
                        stamp_ns: -5_000_000_000 + 7,
                        status: -1,
                        lat_deg: 48.1,
                        lon_deg: 11.5,
                        alt_m: 520.25,
                        covariance: std::array::from_fn(|i| i as f64),
                        covariance_type: 2,
                    }),
                ),
                (
                    MessageType::Temperature,
                    Reading::Temperature {
                        stamp_ns: 3_000_000_004,
                        celsius: 24.5,
                    },
                ),
                (
                    MessageType::TwistStamped,
                    Reading::Twist {
                        stamp_ns: 5_000_000_006,
                        linear: [1.0, 0.0, -1.0],
                        angular: [0.0, 0.5, 0.0],
                    },
                ),
            ];
            let encoded: [(Vec<u8>, Vec<u8>); 4] = [
                (cdr::encode(&imu), encode_big_endian(&imu)),
                (cdr::encode(&fix), encode_big_endian(&fix)),
                (cdr::encode(&temperature), encode_big_endian(&temperature)),
                (cdr::encode(&twist), encode_big_endian(&twist)),
            ];
            for ((kind, reading), (little, big)) in expected.iter().zip(&encoded) {
                for bytes in [little, big] {
                    assert_eq!(
                        decode(*kind, Encoding::Cdr, bytes).as_ref(),
                        Ok(reading),
                        "{kind:?}, frame id {frame_id:?}"
                    );
                }
                // Cut short anywhere: never a panic; an error once a value read is cut (an
                // IMU message ends with its last value read).
                for n in 0..little.len() {
                    let cut = decode(*kind, Encoding::Cdr, &little[..n]);
                    if *kind == MessageType::Imu {
                        assert!(cut.is_err(), "{n} bytes");
                    }
                }
            }
        }
    }
}
