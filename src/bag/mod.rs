//! Recordings from ROS: ROS 2 bags and other MCAP files ([`mcap`], through the `mcap`
//! crate) and ROS 1 bags ([`ros1`]). [`Bag::open`] tells the format by the file's first
//! bytes and lists its topics (type, message count); [`Bag::read`] streams every message in
//! file order, holding a few chunks at a time, and ends at a cut (a truncated file) with the
//! messages before it delivered. [`messages`] decodes the message types imulab uses.
//!
//! ROS 2's default sqlite3 storage (`.db3`) is not read: it is refused with the command
//! that converts it to MCAP (`ros2 bag convert`).

pub mod mcap;
pub mod messages;
pub mod ros1;

use messages::{Encoding, MessageType};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Errors reading a bag; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

/// The container format of a bag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Mcap,
    Ros1,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::Mcap => "MCAP",
            Format::Ros1 => "ROS 1 bag",
        }
    }
}

/// One topic of a bag.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    pub name: String,
    /// The type name as the bag spells it (`sensor_msgs/msg/Imu` or `sensor_msgs/Imu`).
    pub type_name: String,
    /// Messages on the topic (from the bag's index when it has one, else counted).
    pub messages: u64,
}

impl TopicInfo {
    /// The type when imulab reads it.
    pub fn message_type(&self) -> Option<MessageType> {
        MessageType::from_name(&self.type_name)
    }
}

/// One message as stored.
pub struct Msg<'a> {
    pub topic: &'a str,
    pub type_name: &'a str,
    /// `None` for a message encoding other than CDR and ROS 1 (e.g. JSON, protobuf).
    pub encoding: Option<Encoding>,
    /// When the recorder received the message, ns since the epoch of the recording clock.
    pub log_time_ns: i64,
    pub data: &'a [u8],
}

/// How a read ended.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadEnd {
    /// Messages delivered.
    pub messages: u64,
    /// Why the read stopped before the end of the file (truncated, corrupt), when it did.
    pub cut: Option<String>,
}

/// Callback of [`Bag::read`].
pub type MsgVisitor<'a, E> = dyn FnMut(&Msg<'_>) -> Result<(), E> + 'a;

/// An open bag: its path, format and topics.
#[derive(Debug, Clone)]
pub struct Bag {
    path: PathBuf,
    format: Format,
    topics: Vec<TopicInfo>,
}

const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";
const ROS1_MAGIC: &[u8] = b"#ROSBAG V2.0\n";
const SQLITE_MAGIC: &[u8] = b"SQLite format 3\0";

/// The format of the file at `path` by its first bytes (`None`: not a bag).
pub fn sniff(path: &Path) -> Option<Format> {
    use std::io::Read;
    let mut head = [0u8; 16];
    let mut file = std::fs::File::open(path).ok()?;
    let n = file.read(&mut head).ok()?;
    let head = &head[..n];
    if head.starts_with(MCAP_MAGIC) {
        Some(Format::Mcap)
    } else if head.starts_with(ROS1_MAGIC) {
        Some(Format::Ros1)
    } else {
        None
    }
}

/// Whether `path` is a bag imulab reads, or one it refuses with advice (a `.db3` file, a
/// ROS 2 bag directory): the inputs `imulab allan` and `imulab import` treat as bags.
pub fn looks_like_bag(path: &Path) -> bool {
    if path.is_dir() {
        return path.join("metadata.yaml").is_file();
    }
    if sniff(path).is_some() {
        return true;
    }
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    ["mcap", "bag", "db3"]
        .iter()
        .any(|e| ext.eq_ignore_ascii_case(e))
}

impl Bag {
    /// Opens a bag file, or the one MCAP file of a ROS 2 bag directory, and lists its topics.
    pub fn open(path: &Path) -> Result<Bag, BagError> {
        let fail = |message: String| BagError::Format {
            path: path.to_path_buf(),
            message,
        };
        let path = if path.is_dir() {
            bag_in_directory(path)?
        } else {
            path.to_path_buf()
        };
        let head = {
            use std::io::Read;
            let mut head = [0u8; 16];
            let mut file = std::fs::File::open(&path).map_err(|source| BagError::Io {
                path: path.clone(),
                source,
            })?;
            let n = file.read(&mut head).map_err(|source| BagError::Io {
                path: path.clone(),
                source,
            })?;
            head[..n].to_vec()
        };
        let format = if head.starts_with(MCAP_MAGIC) {
            Format::Mcap
        } else if head.starts_with(ROS1_MAGIC) {
            Format::Ros1
        } else if head.starts_with(SQLITE_MAGIC) {
            return Err(fail(db3_advice(&path)));
        } else if head.starts_with(b"#ROSBAG V") {
            return Err(fail(format!(
                "ROS 1 bag version {} is not read (only 2.0); migrate it with `rosbag fix`",
                String::from_utf8_lossy(&head[9..]).trim()
            )));
        } else {
            return Err(fail(
                "not a bag: neither MCAP (ROS 2) nor ROS 1 bag 2.0 (the first bytes do not match)"
                    .into(),
            ));
        };
        let topics = match format {
            Format::Mcap => mcap::topics(&path)?,
            Format::Ros1 => ros1::topics(&path)?,
        };
        Ok(Bag {
            path,
            format,
            topics,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn format(&self) -> Format {
        self.format
    }

    pub fn topics(&self) -> &[TopicInfo] {
        &self.topics
    }

    pub fn topic(&self, name: &str) -> Option<&TopicInfo> {
        self.topics.iter().find(|t| t.name == name)
    }

    /// Streams every message in file order to `visit`. A visitor error stops the read and is
    /// returned; a damaged or truncated file ends it with [`ReadEnd::cut`] set, after every
    /// message before the damage was delivered.
    pub fn read<E: From<BagError>>(&self, visit: &mut MsgVisitor<'_, E>) -> Result<ReadEnd, E> {
        match self.format {
            Format::Mcap => mcap::read(&self.path, visit),
            Format::Ros1 => ros1::read(&self.path, visit),
        }
    }

    /// The topic table, one line per topic: name, type, messages, and whether imulab reads
    /// the type.
    pub fn topic_table(&self) -> String {
        let mut out = String::new();
        let width = self.topics.iter().map(|t| t.name.len()).max().unwrap_or(5);
        let type_width = self
            .topics
            .iter()
            .map(|t| t.type_name.len())
            .max()
            .unwrap_or(4);
        for t in &self.topics {
            let _ = writeln!(
                out,
                "  {:<width$}  {:<type_width$}  {:>9} messages{}",
                t.name,
                t.type_name,
                t.messages,
                if t.message_type().is_some() {
                    ""
                } else {
                    "  (type not read)"
                }
            );
        }
        if self.topics.is_empty() {
            out.push_str("  (no topics)\n");
        }
        out
    }

    /// The `sensor_msgs/Imu` topic `name`; without a name, the bag's only one. The error
    /// lists the topics the bag has.
    pub fn imu_topic(&self, name: Option<&str>) -> Result<&TopicInfo, BagError> {
        let fail = |message: String| BagError::Format {
            path: self.path.clone(),
            message,
        };
        let imus: Vec<&TopicInfo> = self
            .topics
            .iter()
            .filter(|t| t.message_type() == Some(MessageType::Imu))
            .collect();
        match name {
            Some(name) => match self.topic(name) {
                Some(t) if t.message_type() == Some(MessageType::Imu) => Ok(t),
                Some(t) => Err(fail(format!(
                    "topic `{name}` is {}, not sensor_msgs/Imu; the topics are:\n{}",
                    t.type_name,
                    self.topic_table()
                ))),
                None => Err(fail(format!(
                    "no topic `{name}`; the topics are:\n{}",
                    self.topic_table()
                ))),
            },
            None if imus.len() == 1 => Ok(imus[0]),
            None => Err(fail(format!(
                "choose the IMU topic with --topic ({} sensor_msgs/Imu topics); the topics are:\n{}",
                imus.len(),
                self.topic_table()
            ))),
        }
    }
}

/// The MCAP file of a ROS 2 bag directory (`metadata.yaml` beside `*.mcap` or `*.db3`).
fn bag_in_directory(dir: &Path) -> Result<PathBuf, BagError> {
    let entries = std::fs::read_dir(dir).map_err(|source| BagError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    let with = |ext: &str| -> Vec<PathBuf> {
        files
            .iter()
            .filter(|p| p.extension().and_then(|e| e.to_str()) == Some(ext))
            .cloned()
            .collect()
    };
    let fail = |message: String| BagError::Format {
        path: dir.to_path_buf(),
        message,
    };
    match (with("mcap").as_slice(), with("db3").as_slice()) {
        ([one], _) => Ok(one.clone()),
        ([], [db3, ..]) => Err(fail(db3_advice(db3))),
        ([], []) => Err(fail("a directory with no .mcap file in it".into())),
        (several, _) => Err(fail(format!(
            "a bag split into {} MCAP files; give one file at a time ({})",
            several.len(),
            several
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

fn db3_advice(path: &Path) -> String {
    format!(
        "{}: a ROS 2 bag in sqlite3 storage, which imulab does not read; convert it to MCAP \
         with `ros2 bag convert -i BAG_DIR -o out.yaml` (out.yaml: `output_bags: [{{uri: \
         BAG_mcap, storage_id: mcap}}]`) or, without ROS, `rosbags-convert --dst-storage mcap \
         BAG_DIR`",
        path.display()
    )
}
