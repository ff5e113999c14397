//! The ROS messages imulab reads from bags: `sensor_msgs/Imu`, `sensor_msgs/NavSatFix`,
//! `sensor_msgs/Temperature` and `geometry_msgs/TwistStamped`, in both of their wire
//! encodings. ROS 2 messages are CDR (the OMG Common Data Representation: little- or
//! big-endian by the 4-byte encapsulation header, each value aligned to its size) and are
//! decoded with the `cdr-encoding` crate through the serde structs of [`cdr`]. ROS 1
//! messages are the ROS 1 serialisation (little-endian, packed, no alignment, strings as a
//! u32 length then the bytes); the only Rust crate for it (`serde_rosmsg`) has been
//! unmaintained since 2017 and expects the TCPROS length prefix, so [`decode`] reads it with
//! a small cursor here.

use serde::{Deserialize, Serialize};

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
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Time {
        pub sec: i32,
        pub nanosec: u32,
    }

    /// `std_msgs/Header`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        pub stamp: Time,
        pub frame_id: String,
    }

    /// `geometry_msgs/Vector3`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Vector3 {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    /// `geometry_msgs/Quaternion`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        pub x: f64,
        pub y: f64,
        pub z: f64,
        pub w: f64,
    }

    /// `sensor_msgs/Imu`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
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
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct NavSatStatus {
        pub status: i8,
        pub service: u16,
    }

    /// `sensor_msgs/NavSatFix`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
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
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct Temperature {
        pub header: Header,
        pub temperature: f64,
        pub variance: f64,
    }

    /// `geometry_msgs/Twist`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Twist {
        pub linear: Vector3,
        pub angular: Vector3,
    }

    /// `geometry_msgs/TwistStamped`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
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

    pub(super) fn decode<'de, T: Deserialize<'de>>(data: &'de [u8]) -> Result<T, String> {
        if data.len() < 4 {
            return Err(format!("{} bytes, shorter than the CDR header", data.len()));
        }
        // Representation id: 0x0000/0x0002 big-endian CDR/PL_CDR, 0x0001/0x0003 little.
        let little = match [data[0], data[1]] {
            [0, 0] | [0, 2] => false,
            [0, 1] | [0, 3] => true,
            other => return Err(format!("unknown CDR representation {other:02x?}")),
        };
        let body = &data[4..];
        let result = if little {
            cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body)
        } else {
            cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body)
        };
        result.map(|(v, _)| v).map_err(|e| format!("CDR: {e}"))
    }

    pub(super) fn stamp(h: &Header) -> i64 {
        i64::from(h.stamp.sec) * 1_000_000_000 + i64::from(h.stamp.nanosec)
    }

    pub(super) fn v3(v: &Vector3) -> [f64; 3] {
        [v.x, v.y, v.z]
    }
}

/// Decodes one message of type `kind` from its bytes.
pub fn decode(kind: MessageType, encoding: Encoding, data: &[u8]) -> Result<Reading, String> {
    match encoding {
        Encoding::Cdr => decode_cdr(kind, data),
        Encoding::Ros1 => decode_ros1(kind, data),
    }
}

fn decode_cdr(kind: MessageType, data: &[u8]) -> Result<Reading, String> {
    use cdr::{stamp, v3};
    Ok(match kind {
        MessageType::Imu => {
            let m: cdr::Imu = cdr::decode(data)?;
            Reading::Imu {
                stamp_ns: stamp(&m.header),
                gyro: v3(&m.angular_velocity),
                accel: v3(&m.linear_acceleration),
            }
        }
        MessageType::NavSatFix => {
            let m: cdr::NavSatFix = cdr::decode(data)?;
            Reading::Fix(Fix {
                stamp_ns: stamp(&m.header),
                status: m.status.status,
                lat_deg: m.latitude,
                lon_deg: m.longitude,
                alt_m: m.altitude,
                covariance: m.position_covariance,
                covariance_type: m.position_covariance_type,
            })
        }
        MessageType::Temperature => {
            let m: cdr::Temperature = cdr::decode(data)?;
            Reading::Temperature {
                stamp_ns: stamp(&m.header),
                celsius: m.temperature,
            }
        }
        MessageType::TwistStamped => {
            let m: cdr::TwistStamped = cdr::decode(data)?;
            Reading::Twist {
                stamp_ns: stamp(&m.header),
                linear: v3(&m.twist.linear),
                angular: v3(&m.twist.angular),
            }
        }
    })
}

/// Reads the ROS 1 serialisation: little-endian, packed.
struct Ros1Cursor<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Ros1Cursor<'a> {
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
    fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array()?))
    }
    fn f64s<const N: usize>(&mut self) -> Result<[f64; N], String> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64()?;
        }
        Ok(out)
    }
    /// `std_msgs/Header` (seq, stamp secs and nsecs, frame_id); returns the stamp in ns.
    fn header(&mut self) -> Result<i64, String> {
        let _seq = self.u32()?;
        let secs = self.u32()?;
        let nsecs = self.u32()?;
        let frame = self.u32()? as usize;
        self.take(frame)?;
        Ok(i64::from(secs) * 1_000_000_000 + i64::from(nsecs))
    }
}

fn decode_ros1(kind: MessageType, data: &[u8]) -> Result<Reading, String> {
    let mut c = Ros1Cursor { data, at: 0 };
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
            let status = c.array::<1>()?[0] as i8;
            let _service = c.array::<2>()?;
            Reading::Fix(Fix {
                stamp_ns,
                status,
                lat_deg: c.f64()?,
                lon_deg: c.f64()?,
                alt_m: c.f64()?,
                covariance: c.f64s()?,
                covariance_type: c.array::<1>()?[0],
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
