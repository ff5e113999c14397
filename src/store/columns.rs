//! Column layout of every table (one HDF5 dataset per field, struct-of-arrays) and the code
//! that moves rows between record structs and those datasets. The writer and the reader both
//! use these lists, so a column is named, typed and documented in exactly one place.

use std::ops::Range;

use hdf5::types::{FixedAscii, FixedUnicode, VarLenUnicode};
use hdf5::{Dataset, Group, H5Type, Location};

use super::chunkio::{put_rows, ChunkEncoder, Plain};
use super::journal::{put_str, Cursor};
use super::layout::{ATTR_DESCRIPTION, ATTR_SCHEMA_VERSION, ATTR_UNITS};
use super::records::{
    EventKind, EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord,
};
use super::SCHEMA_VERSION;
use imulab_drivers::types::FixType;

/// Fixed string types of the events table (fixed size so a SWMR writer can append them).
pub(crate) type DeviceStr = FixedAscii<64>;
pub(crate) type KindStr = FixedAscii<32>;
pub(crate) type DetailStr = FixedUnicode<512>;

/// On-disk element type of a column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ColType {
    I64,
    U64,
    F64,
    U32,
    U16,
    U8,
    Device,
    Kind,
    Detail,
}

/// One dataset of a table. `width` 0 means a 1-D column, otherwise N×width.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Column {
    pub name: &'static str,
    pub ty: ColType,
    pub width: usize,
    pub units: &'static str,
    pub description: &'static str,
    /// Added after the first files were written: a file without it is read as if every
    /// row held the column's missing value (optional columns come last in a table).
    pub optional: bool,
}

const fn col(
    name: &'static str,
    ty: ColType,
    width: usize,
    units: &'static str,
    description: &'static str,
) -> Column {
    Column {
        name,
        ty,
        width,
        units,
        description,
        optional: false,
    }
}

/// A column that older files lack (see [`Column::optional`]).
const fn optional(c: Column) -> Column {
    Column {
        optional: true,
        ..c
    }
}

/// Host CLOCK_MONOTONIC at arrival; every table's first column. Its fill value is `i64::MIN`,
/// which marks rows whose data never reached the disk (see `recover`).
pub(crate) const T_MONO: Column = col(
    "t_mono_ns",
    ColType::I64,
    0,
    "ns",
    "host CLOCK_MONOTONIC at arrival",
);
const T_WALL: Column = col(
    "t_wall_ns",
    ColType::I64,
    0,
    "ns",
    "host CLOCK_REALTIME at arrival, since the Unix epoch",
);
pub(crate) const FILL_T_MONO: i64 = i64::MIN;

pub(crate) const IMU_COLUMNS: &[Column] = &[
    T_MONO,
    T_WALL,
    col(
        "t_sensor",
        ColType::F64,
        0,
        "device",
        "the device's own counter or time, as given (NaN if none)",
    ),
    col(
        "gyro",
        ColType::F64,
        3,
        "rad/s",
        "angular rate x,y,z in the device axis frame",
    ),
    col(
        "accel",
        ColType::F64,
        3,
        "m/s^2",
        "specific force x,y,z in the device axis frame",
    ),
    col(
        "temp",
        ColType::F64,
        0,
        "degC",
        "temperature (NaN if the device gives none)",
    ),
    col("status", ColType::U32, 0, "", "device status word"),
];

pub(crate) const GNSS_COLUMNS: &[Column] = &[
    T_MONO,
    T_WALL,
    col("week", ColType::U16, 0, "week", "GPS week (0 when unknown)"),
    col("tow_s", ColType::F64, 0, "s", "GPS time of week"),
    col(
        "utc_ns",
        ColType::I64,
        0,
        "ns",
        "UTC since the Unix epoch (-2^63 when unknown)",
    ),
    col("lat_deg", ColType::F64, 0, "deg", "latitude, WGS-84"),
    col("lon_deg", ColType::F64, 0, "deg", "longitude, WGS-84"),
    col(
        "height_m",
        ColType::F64,
        0,
        "m",
        "height above the WGS-84 ellipsoid",
    ),
    col(
        "vel_ned",
        ColType::F64,
        3,
        "m/s",
        "velocity north, east, down",
    ),
    col(
        "h_acc_m",
        ColType::F64,
        0,
        "m",
        "horizontal accuracy (1 sigma)",
    ),
    col(
        "v_acc_m",
        ColType::F64,
        0,
        "m",
        "vertical accuracy (1 sigma)",
    ),
    col(
        "s_acc_mps",
        ColType::F64,
        0,
        "m/s",
        "speed accuracy (1 sigma)",
    ),
    col(
        "fix_type",
        ColType::U8,
        0,
        "",
        "0 none, 1 DR, 2 2D, 3 3D, 4 GNSS+DR, 5 time, 6 DGNSS, 7 RTK float, 8 RTK fixed",
    ),
    col("num_sats", ColType::U8, 0, "", "satellites used"),
    col("pdop", ColType::F64, 0, "", "position DOP"),
    col("hdop", ColType::F64, 0, "", "horizontal DOP"),
    col("vdop", ColType::F64, 0, "", "vertical DOP"),
    optional(col(
        "heading_deg",
        ColType::F64,
        0,
        "deg",
        "true heading, clockwise from true north (NMEA HDT, NAV-RELPOSNED, vehicle heading); NaN if none",
    )),
];

pub(crate) const EVENT_COLUMNS: &[Column] = &[
    T_MONO,
    T_WALL,
    col(
        "device",
        ColType::Device,
        0,
        "",
        "device name, empty for session-wide events",
    ),
    col("kind", ColType::Kind, 0, "", "event kind (snake_case name)"),
    col(
        "detail",
        ColType::Detail,
        0,
        "",
        "free text, UTF-8, at most 512 bytes",
    ),
];

pub(crate) const RAW_INDEX_COLUMNS: &[Column] = &[
    T_MONO,
    col(
        "offset",
        ColType::U64,
        0,
        "byte",
        "start of this read in `bytes`",
    ),
    col(
        "len",
        ColType::U32,
        0,
        "byte",
        "length of this read in `bytes`",
    ),
];
pub(crate) const RAW_BYTES: Column = col(
    "bytes",
    ColType::U8,
    0,
    "byte",
    "undecoded bytes as received, concatenated",
);

pub(crate) const TRUTH_NAV_COLUMNS: &[Column] = &[
    T_MONO,
    col("lat_deg", ColType::F64, 0, "deg", "true latitude, WGS-84"),
    col("lon_deg", ColType::F64, 0, "deg", "true longitude, WGS-84"),
    col(
        "height_m",
        ColType::F64,
        0,
        "m",
        "true height above the WGS-84 ellipsoid",
    ),
    col(
        "vel_ned",
        ColType::F64,
        3,
        "m/s",
        "true velocity north, east, down",
    ),
    col(
        "quat_nb",
        ColType::F64,
        4,
        "",
        "true attitude body to NED, unit quaternion w,x,y,z",
    ),
];

pub(crate) const TRUTH_IMU_COLUMNS: &[Column] = &[
    T_MONO,
    col(
        "gyro_bias",
        ColType::F64,
        3,
        "rad/s",
        "total true gyro bias",
    ),
    col(
        "accel_bias",
        ColType::F64,
        3,
        "m/s^2",
        "total true accel bias",
    ),
    col(
        "gyro_true",
        ColType::F64,
        3,
        "rad/s",
        "error-free angular rate, sensor frame",
    ),
    col(
        "accel_true",
        ColType::F64,
        3,
        "m/s^2",
        "error-free specific force, sensor frame",
    ),
];

/// Writes a string attribute (variable-length UTF-8, what h5py and MATLAB read as text).
pub(crate) fn put_str_attr(loc: &Location, name: &str, value: &str) -> hdf5::Result<()> {
    let v: VarLenUnicode = value
        .parse()
        .map_err(|e| hdf5::Error::from(format!("attribute {name}: {e}")))?;
    loc.new_attr::<VarLenUnicode>()
        .create(name)?
        .write_scalar(&v)
}

pub(crate) fn put_u32_attr(loc: &Location, name: &str, value: u32) -> hdf5::Result<()> {
    loc.new_attr::<u32>().create(name)?.write_scalar(&value)
}

pub(crate) fn put_f64_attr(loc: &Location, name: &str, value: f64) -> hdf5::Result<()> {
    loc.new_attr::<f64>().create(name)?.write_scalar(&value)
}

/// Creates one extendable, chunked (shuffle+deflate when `deflate > 0`) dataset for `c`.
pub(crate) fn create_column(
    group: &Group,
    c: &Column,
    chunk_rows: usize,
    deflate: u8,
) -> hdf5::Result<Dataset> {
    fn make<T>(
        group: &Group,
        c: &Column,
        chunk_rows: usize,
        deflate: u8,
        fill: Option<T>,
    ) -> hdf5::Result<Dataset>
    where
        T: H5Type + Into<hdf5::types::OwnedDynValue>,
    {
        let chunk_rows = chunk_rows.max(1);
        let mut b = group.new_dataset::<T>();
        if deflate > 0 {
            b = b.shuffle().deflate(deflate);
        }
        if let Some(f) = fill {
            b = b.fill_value(f);
        }
        if c.width == 0 {
            b.chunk(chunk_rows).shape(0..).create(c.name)
        } else {
            b.chunk((chunk_rows, c.width))
                .shape(hdf5::SimpleExtents::new([
                    hdf5::Extent::resizable(0),
                    hdf5::Extent::fixed(c.width),
                ]))
                .create(c.name)
        }
    }
    let ds = match c.ty {
        ColType::I64 => make::<i64>(
            group,
            c,
            chunk_rows,
            deflate,
            (c.name == T_MONO.name).then_some(FILL_T_MONO),
        )?,
        ColType::U64 => make::<u64>(group, c, chunk_rows, deflate, None)?,
        ColType::F64 => make::<f64>(group, c, chunk_rows, deflate, None)?,
        ColType::U32 => make::<u32>(group, c, chunk_rows, deflate, None)?,
        ColType::U16 => make::<u16>(group, c, chunk_rows, deflate, None)?,
        ColType::U8 => make::<u8>(group, c, chunk_rows, deflate, None)?,
        ColType::Device => make::<DeviceStr>(group, c, chunk_rows, deflate, None)?,
        ColType::Kind => make::<KindStr>(group, c, chunk_rows, deflate, None)?,
        ColType::Detail => make::<DetailStr>(group, c, chunk_rows, deflate, None)?,
    };
    put_str_attr(&ds, ATTR_UNITS, c.units)?;
    put_str_attr(&ds, ATTR_DESCRIPTION, c.description)?;
    put_u32_attr(&ds, ATTR_SCHEMA_VERSION, SCHEMA_VERSION)?;
    Ok(ds)
}

/// Grows a 1-D column to `start + values.len()` and writes `values` at `start`.
pub(crate) fn put_1d<T: H5Type>(ds: &Dataset, start: usize, values: &[T]) -> hdf5::Result<()> {
    let end = start + values.len();
    ds.resize(end)?;
    write_1d(ds, start, values)
}

/// Writes `values` at row `start` of a 1-D column that already extends that far.
fn write_1d<T: H5Type>(ds: &Dataset, start: usize, values: &[T]) -> hdf5::Result<()> {
    ds.write_slice(values, start..start + values.len())
}

/// How a table's numeric columns are written: whole chunks of `chunk_rows` rows are encoded
/// here and written directly (see `chunkio`), partial ones through HDF5's filter pipeline.
pub(crate) struct ChunkSink {
    pub chunk_rows: usize,
    pub enc: ChunkEncoder,
}

impl ChunkSink {
    fn put<T: super::chunkio::Plain>(
        &mut self,
        ds: &Dataset,
        start: usize,
        values: &[T],
    ) -> hdf5::Result<()> {
        put_rows(ds, &mut self.enc, self.chunk_rows, start, values)
    }
}

impl ChunkSink {
    /// A sink that writes every row through HDF5's own filter pipeline (used by `recover`,
    /// which does not know the writer's encoder settings and writes few rows): with a chunk
    /// of `usize::MAX` rows no write ever covers a whole chunk.
    pub(crate) fn through_pipeline() -> Self {
        ChunkSink {
            chunk_rows: usize::MAX,
            enc: ChunkEncoder::new(0),
        }
    }
}

/// A record type stored as one table. `write` puts `rows` at row `start` of the table's
/// datasets (given in `COLUMNS` order, already extended past the rows), writing `t_mono_ns` last so that a valid time implies
/// the rest of the row was handed to HDF5 before it.
pub(crate) trait Row: Clone {
    const COLUMNS: &'static [Column];
    fn t_mono_ns(&self) -> i64;
    fn write(rows: &[Self], ds: &[Dataset], start: usize, sink: &mut ChunkSink)
        -> hdf5::Result<()>;
    /// Appends the row to a write-ahead journal payload: its fields in column order,
    /// little-endian (strings as a u16 length and their bytes).
    fn encode(&self, out: &mut Vec<u8>);
    /// Reads back one row written by [`Row::encode`].
    fn decode(c: &mut Cursor<'_>) -> Result<Self, String>;
}

/// An event converted to its fixed-size on-disk strings (checked when appended, so a
/// bad device name is reported to the caller instead of failing a later flush).
#[derive(Debug, Clone)]
pub(crate) struct EventRow {
    pub t_mono_ns: i64,
    pub t_wall_ns: i64,
    pub device: DeviceStr,
    pub kind: KindStr,
    pub detail: DetailStr,
}

impl EventRow {
    pub fn from_record(ev: &EventRecord) -> Result<Self, String> {
        let device = DeviceStr::from_ascii(ev.device.as_bytes())
            .map_err(|e| format!("event device name {:?}: {e}", ev.device))?;
        let kind = KindStr::from_ascii(event_kind_name(ev.kind).as_bytes())
            .map_err(|e| format!("event kind: {e}"))?;
        let detail = truncate_utf8(&ev.detail, 512)
            .parse::<DetailStr>()
            .map_err(|e| format!("event detail: {e}"))?;
        Ok(EventRow {
            t_mono_ns: ev.t_mono_ns,
            t_wall_ns: ev.t_wall_ns,
            device,
            kind,
            detail,
        })
    }
}

/// The longest prefix of `s` that fits in `max` bytes without splitting a character.
fn truncate_utf8(s: &str, max: usize) -> &str {
    if s.len() <= max {
        return s;
    }
    let mut end = max;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

const EVENT_KINDS: &[(EventKind, &str)] = &[
    (EventKind::SessionStart, "session_start"),
    (EventKind::SessionStop, "session_stop"),
    (EventKind::Rotation, "rotation"),
    (EventKind::Connect, "connect"),
    (EventKind::Disconnect, "disconnect"),
    (EventKind::Reconnect, "reconnect"),
    (EventKind::Resync, "resync"),
    (EventKind::ChecksumError, "checksum_error"),
    (EventKind::Gap, "gap"),
    (EventKind::QueueOverflow, "queue_overflow"),
    (EventKind::DiskLow, "disk_low"),
    (EventKind::Info, "info"),
];

/// The on-disk (and serde) name of an event kind.
pub(crate) fn event_kind_name(kind: EventKind) -> &'static str {
    EVENT_KINDS
        .iter()
        .find(|(k, _)| *k == kind)
        .map(|(_, n)| *n)
        .unwrap_or("info")
}

pub(crate) fn event_kind_from_name(name: &str) -> Option<EventKind> {
    EVENT_KINDS
        .iter()
        .find(|(_, n)| *n == name)
        .map(|(k, _)| *k)
}

/// One read of undecoded bytes: where it sits in the device's `bytes` dataset.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RawIndexRow {
    pub t_mono_ns: i64,
    pub offset: u64,
    pub len: u32,
}

/// How one field of a record is stored: the element of its dataset, how a run of them is
/// written (through the table's [`ChunkSink`]), and its bytes in the write-ahead journal
/// (little-endian; strings as a u16 length and their bytes).
trait Field: Sized {
    type Disk: H5Type;
    fn disk(&self) -> Self::Disk;
    fn put(
        sink: &mut ChunkSink,
        ds: &Dataset,
        start: usize,
        values: &[Self::Disk],
    ) -> hdf5::Result<()>;
    fn encode(&self, out: &mut Vec<u8>);
    fn decode(c: &mut Cursor<'_>) -> Result<Self, String>;
}

macro_rules! plain_field {
    ($($t:ty => $read:ident),* $(,)?) => {$(
        impl Field for $t {
            type Disk = $t;
            fn disk(&self) -> $t {
                *self
            }
            fn put(sink: &mut ChunkSink, ds: &Dataset, start: usize, values: &[$t])
                -> hdf5::Result<()> {
                sink.put(ds, start, values)
            }
            fn encode(&self, out: &mut Vec<u8>) {
                self.put_le(out);
            }
            fn decode(c: &mut Cursor<'_>) -> Result<$t, String> {
                c.$read()
            }
        }
    )*};
}
plain_field!(i64 => i64, u64 => u64, f64 => f64, u32 => u32, u16 => u16, u8 => u8);

impl<const W: usize> Field for [f64; W]
where
    [f64; W]: H5Type,
{
    type Disk = [f64; W];
    fn disk(&self) -> [f64; W] {
        *self
    }
    fn put(
        sink: &mut ChunkSink,
        ds: &Dataset,
        start: usize,
        values: &[[f64; W]],
    ) -> hdf5::Result<()> {
        sink.put(ds, start, values)
    }
    fn encode(&self, out: &mut Vec<u8>) {
        self.put_le(out);
    }
    fn decode(c: &mut Cursor<'_>) -> Result<[f64; W], String> {
        c.f64s()
    }
}

/// A fix type is stored as its code.
impl Field for FixType {
    type Disk = u8;
    fn disk(&self) -> u8 {
        *self as u8
    }
    fn put(sink: &mut ChunkSink, ds: &Dataset, start: usize, values: &[u8]) -> hdf5::Result<()> {
        sink.put(ds, start, values)
    }
    fn encode(&self, out: &mut Vec<u8>) {
        out.push(*self as u8);
    }
    fn decode(c: &mut Cursor<'_>) -> Result<FixType, String> {
        Ok(fix_type_from_code(c.u8()?))
    }
}

/// The events table's fixed strings go through HDF5's own pipeline (no direct chunks).
macro_rules! string_field {
    ($($t:ty => $parse:expr),* $(,)?) => {$(
        impl Field for $t {
            type Disk = $t;
            fn disk(&self) -> $t {
                *self
            }
            fn put(_: &mut ChunkSink, ds: &Dataset, start: usize, values: &[$t])
                -> hdf5::Result<()> {
                write_1d(ds, start, values)
            }
            fn encode(&self, out: &mut Vec<u8>) {
                put_str(out, self.as_str());
            }
            fn decode(c: &mut Cursor<'_>) -> Result<$t, String> {
                let text = c.str()?;
                $parse(text).map_err(|e| format!("{}: {e}", stringify!($t)))
            }
        }
    )*};
}
string_field!(
    DeviceStr => |t: &str| DeviceStr::from_ascii(t.as_bytes()),
    KindStr => |t: &str| KindStr::from_ascii(t.as_bytes()),
    DetailStr => |t: &str| t.parse::<DetailStr>(),
);

/// Writes one field of `rows` into `ds` (the next dataset of the table).
fn put_field<R, F: Field>(
    sink: &mut ChunkSink,
    ds: Option<&Dataset>,
    start: usize,
    rows: &[R],
    field: impl Fn(&R) -> &F,
) -> hdf5::Result<()> {
    let ds = ds.ok_or("a table has fewer datasets than its record has fields")?;
    let values: Vec<F::Disk> = rows.iter().map(|r| field(r).disk()).collect();
    F::put(sink, ds, start, &values)
}

/// True when `columns` are named `fields`, in order (checked when the build compiles).
const fn columns_are(columns: &[Column], fields: &[&str]) -> bool {
    if columns.len() != fields.len() {
        return false;
    }
    let mut i = 0;
    while i < fields.len() {
        let (a, b) = (columns[i].name.as_bytes(), fields[i].as_bytes());
        if a.len() != b.len() {
            return false;
        }
        let mut j = 0;
        while j < a.len() {
            if a[j] != b[j] {
                return false;
            }
            j += 1;
        }
        i += 1;
    }
    true
}

/// Implements [`Row`] for a record from its field list, which is its table's column list
/// (`t_mono_ns` first, then every column in order; the build fails if they differ). A field
/// added to the journal in a later record version is `field since VERSION else MISSING`.
macro_rules! row {
    ($record:ident, $columns:ident { $($field:ident $(since $version:literal else $missing:expr)?),* $(,)? }) => {
        const _: () = assert!(
            columns_are($columns, &["t_mono_ns", $(stringify!($field)),*]),
            concat!(stringify!($record), "'s fields are not the columns of ", stringify!($columns))
        );
        impl Row for $record {
            const COLUMNS: &'static [Column] = $columns;
            fn t_mono_ns(&self) -> i64 {
                self.t_mono_ns
            }
            fn write(rows: &[Self], ds: &[Dataset], start: usize, sink: &mut ChunkSink)
                -> hdf5::Result<()> {
                let mut rest = ds.iter().skip(1);
                $(put_field(sink, rest.next(), start, rows, |r| &r.$field)?;)*
                put_field(sink, ds.first(), start, rows, |r| &r.t_mono_ns)
            }
            fn encode(&self, out: &mut Vec<u8>) {
                self.t_mono_ns.encode(out);
                $(self.$field.encode(out);)*
            }
            fn decode(c: &mut Cursor<'_>) -> Result<Self, String> {
                Ok($record {
                    t_mono_ns: Field::decode(c)?,
                    $($field: row!(@decode c $(, $version, $missing)?),)*
                })
            }
        }
    };
    (@decode $c:ident) => { Field::decode($c)? };
    (@decode $c:ident, $version:literal, $missing:expr) => {
        if $c.version >= $version { Field::decode($c)? } else { $missing }
    };
}

row!(
    ImuRecord,
    IMU_COLUMNS {
        t_wall_ns,
        t_sensor,
        gyro,
        accel,
        temp,
        status
    }
);
row!(GnssRecord, GNSS_COLUMNS {
    t_wall_ns, week, tow_s, utc_ns, lat_deg, lon_deg, height_m, vel_ned, h_acc_m, v_acc_m,
    s_acc_mps, fix_type, num_sats, pdop, hdop, vdop,
    heading_deg since 2 else f64::NAN,
});
row!(
    TruthNavRecord,
    TRUTH_NAV_COLUMNS {
        lat_deg,
        lon_deg,
        height_m,
        vel_ned,
        quat_nb
    }
);
row!(
    TruthImuRecord,
    TRUTH_IMU_COLUMNS {
        gyro_bias,
        accel_bias,
        gyro_true,
        accel_true
    }
);
row!(
    EventRow,
    EVENT_COLUMNS {
        t_wall_ns,
        device,
        kind,
        detail
    }
);
row!(RawIndexRow, RAW_INDEX_COLUMNS { offset, len });

// ---------------------------------------------------------------------------------------
// Reading: blocks are struct-of-arrays, the same shape as on disk.

fn get_1d<T: H5Type>(ds: &Dataset, r: Range<usize>) -> hdf5::Result<Vec<T>> {
    Ok(ds.read_slice_1d::<T, _>(r)?.into_iter().collect())
}

fn get_2d<const W: usize>(ds: &Dataset, r: Range<usize>) -> hdf5::Result<Vec<[f64; W]>> {
    let arr = ds.read_slice_2d::<f64, _>((r, ..))?;
    if arr.ncols() != W {
        return Err(format!("{} has {} columns, expected {W}", ds.name(), arr.ncols()).into());
    }
    Ok(arr
        .outer_iter()
        .map(|row| {
            let mut a = [0.0; W];
            for (dst, src) in a.iter_mut().zip(row.iter()) {
                *dst = *src;
            }
            a
        })
        .collect())
}

/// A block of rows read back from one table.
pub(crate) trait Block: Sized {
    const COLUMNS: &'static [Column];
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self>;
}

/// IMU rows, struct-of-arrays (see [`ImuRecord`] for units).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImuBlock {
    pub t_mono_ns: Vec<i64>,
    pub t_wall_ns: Vec<i64>,
    pub t_sensor: Vec<f64>,
    pub gyro: Vec<[f64; 3]>,
    pub accel: Vec<[f64; 3]>,
    pub temp: Vec<f64>,
    pub status: Vec<u32>,
}

impl ImuBlock {
    pub fn len(&self) -> usize {
        self.t_mono_ns.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t_mono_ns.is_empty()
    }
    /// Row `i` as a record (panics if `i >= len()`, like slice indexing).
    pub fn record(&self, i: usize) -> ImuRecord {
        ImuRecord {
            t_mono_ns: self.t_mono_ns[i],
            t_wall_ns: self.t_wall_ns[i],
            t_sensor: self.t_sensor[i],
            gyro: self.gyro[i],
            accel: self.accel[i],
            temp: self.temp[i],
            status: self.status[i],
        }
    }
}

impl Block for ImuBlock {
    const COLUMNS: &'static [Column] = IMU_COLUMNS;
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        Ok(ImuBlock {
            t_mono_ns: get_1d(&ds[0], r.clone())?,
            t_wall_ns: get_1d(&ds[1], r.clone())?,
            t_sensor: get_1d(&ds[2], r.clone())?,
            gyro: get_2d(&ds[3], r.clone())?,
            accel: get_2d(&ds[4], r.clone())?,
            temp: get_1d(&ds[5], r.clone())?,
            status: get_1d(&ds[6], r)?,
        })
    }
}

/// GNSS rows, struct-of-arrays (see [`GnssRecord`] for units).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GnssBlock {
    pub t_mono_ns: Vec<i64>,
    pub t_wall_ns: Vec<i64>,
    pub week: Vec<u16>,
    pub tow_s: Vec<f64>,
    pub utc_ns: Vec<i64>,
    pub lat_deg: Vec<f64>,
    pub lon_deg: Vec<f64>,
    pub height_m: Vec<f64>,
    pub vel_ned: Vec<[f64; 3]>,
    pub h_acc_m: Vec<f64>,
    pub v_acc_m: Vec<f64>,
    pub s_acc_mps: Vec<f64>,
    /// Fix type as stored (see [`FixType`]); [`GnssBlock::record`] converts it.
    pub fix_type: Vec<u8>,
    pub num_sats: Vec<u8>,
    pub pdop: Vec<f64>,
    pub hdop: Vec<f64>,
    pub vdop: Vec<f64>,
    /// NaN where there is none (and for every row of a file written before the column).
    pub heading_deg: Vec<f64>,
}

/// Stored fix type code back to [`FixType`]; unknown codes read as `NoFix`.
pub fn fix_type_from_code(code: u8) -> FixType {
    match code {
        1 => FixType::DeadReckoning,
        2 => FixType::Fix2D,
        3 => FixType::Fix3D,
        4 => FixType::GnssDeadReckoning,
        5 => FixType::TimeOnly,
        6 => FixType::Dgnss,
        7 => FixType::RtkFloat,
        8 => FixType::RtkFixed,
        _ => FixType::NoFix,
    }
}

impl GnssBlock {
    pub fn len(&self) -> usize {
        self.t_mono_ns.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t_mono_ns.is_empty()
    }
    /// Row `i` as a record (panics if `i >= len()`, like slice indexing).
    pub fn record(&self, i: usize) -> GnssRecord {
        GnssRecord {
            t_mono_ns: self.t_mono_ns[i],
            t_wall_ns: self.t_wall_ns[i],
            week: self.week[i],
            tow_s: self.tow_s[i],
            utc_ns: self.utc_ns[i],
            lat_deg: self.lat_deg[i],
            lon_deg: self.lon_deg[i],
            height_m: self.height_m[i],
            vel_ned: self.vel_ned[i],
            h_acc_m: self.h_acc_m[i],
            v_acc_m: self.v_acc_m[i],
            s_acc_mps: self.s_acc_mps[i],
            fix_type: fix_type_from_code(self.fix_type[i]),
            num_sats: self.num_sats[i],
            pdop: self.pdop[i],
            hdop: self.hdop[i],
            vdop: self.vdop[i],
            heading_deg: self.heading_deg[i],
        }
    }
}

impl Block for GnssBlock {
    const COLUMNS: &'static [Column] = GNSS_COLUMNS;
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        Ok(GnssBlock {
            t_mono_ns: get_1d(&ds[0], r.clone())?,
            t_wall_ns: get_1d(&ds[1], r.clone())?,
            week: get_1d(&ds[2], r.clone())?,
            tow_s: get_1d(&ds[3], r.clone())?,
            utc_ns: get_1d(&ds[4], r.clone())?,
            lat_deg: get_1d(&ds[5], r.clone())?,
            lon_deg: get_1d(&ds[6], r.clone())?,
            height_m: get_1d(&ds[7], r.clone())?,
            vel_ned: get_2d(&ds[8], r.clone())?,
            h_acc_m: get_1d(&ds[9], r.clone())?,
            v_acc_m: get_1d(&ds[10], r.clone())?,
            s_acc_mps: get_1d(&ds[11], r.clone())?,
            fix_type: get_1d(&ds[12], r.clone())?,
            num_sats: get_1d(&ds[13], r.clone())?,
            pdop: get_1d(&ds[14], r.clone())?,
            hdop: get_1d(&ds[15], r.clone())?,
            vdop: get_1d(&ds[16], r.clone())?,
            heading_deg: match ds.get(17) {
                Some(d) => get_1d(d, r)?,
                None => vec![f64::NAN; r.len()],
            },
        })
    }
}

/// True trajectory rows, struct-of-arrays (see [`TruthNavRecord`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TruthNavBlock {
    pub t_mono_ns: Vec<i64>,
    pub lat_deg: Vec<f64>,
    pub lon_deg: Vec<f64>,
    pub height_m: Vec<f64>,
    pub vel_ned: Vec<[f64; 3]>,
    pub quat_nb: Vec<[f64; 4]>,
}

impl TruthNavBlock {
    pub fn len(&self) -> usize {
        self.t_mono_ns.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t_mono_ns.is_empty()
    }
}

impl Block for TruthNavBlock {
    const COLUMNS: &'static [Column] = TRUTH_NAV_COLUMNS;
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        Ok(TruthNavBlock {
            t_mono_ns: get_1d(&ds[0], r.clone())?,
            lat_deg: get_1d(&ds[1], r.clone())?,
            lon_deg: get_1d(&ds[2], r.clone())?,
            height_m: get_1d(&ds[3], r.clone())?,
            vel_ned: get_2d(&ds[4], r.clone())?,
            quat_nb: get_2d(&ds[5], r)?,
        })
    }
}

/// True IMU error-state rows, struct-of-arrays (see [`TruthImuRecord`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TruthImuBlock {
    pub t_mono_ns: Vec<i64>,
    pub gyro_bias: Vec<[f64; 3]>,
    pub accel_bias: Vec<[f64; 3]>,
    pub gyro_true: Vec<[f64; 3]>,
    pub accel_true: Vec<[f64; 3]>,
}

impl TruthImuBlock {
    pub fn len(&self) -> usize {
        self.t_mono_ns.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t_mono_ns.is_empty()
    }
}

impl Block for TruthImuBlock {
    const COLUMNS: &'static [Column] = TRUTH_IMU_COLUMNS;
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        Ok(TruthImuBlock {
            t_mono_ns: get_1d(&ds[0], r.clone())?,
            gyro_bias: get_2d(&ds[1], r.clone())?,
            accel_bias: get_2d(&ds[2], r.clone())?,
            gyro_true: get_2d(&ds[3], r.clone())?,
            accel_true: get_2d(&ds[4], r)?,
        })
    }
}

/// Events, struct-of-arrays.
#[derive(Debug, Clone, Default)]
pub(crate) struct EventBlock(pub Vec<EventRecord>);

impl Block for EventBlock {
    const COLUMNS: &'static [Column] = EVENT_COLUMNS;
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        let t_mono: Vec<i64> = get_1d(&ds[0], r.clone())?;
        let t_wall: Vec<i64> = get_1d(&ds[1], r.clone())?;
        let device: Vec<DeviceStr> = get_1d(&ds[2], r.clone())?;
        let kind: Vec<KindStr> = get_1d(&ds[3], r.clone())?;
        let detail: Vec<DetailStr> = get_1d(&ds[4], r)?;
        let mut out = Vec::with_capacity(t_mono.len());
        for i in 0..t_mono.len() {
            let kind_name = kind[i].as_str();
            let kind = event_kind_from_name(kind_name).ok_or_else(|| {
                hdf5::Error::from(format!("events: unknown kind {kind_name:?} in row {i}"))
            })?;
            out.push(EventRecord {
                t_mono_ns: t_mono[i],
                t_wall_ns: t_wall[i],
                device: device[i].as_str().to_string(),
                kind,
                detail: detail[i].as_str().to_string(),
            });
        }
        Ok(EventBlock(out))
    }
}

/// Raw journal index rows.
#[derive(Debug, Clone, Default)]
pub(crate) struct RawIndexBlock {
    pub t_mono_ns: Vec<i64>,
    pub offset: Vec<u64>,
    pub len: Vec<u32>,
}

impl Block for RawIndexBlock {
    const COLUMNS: &'static [Column] = RAW_INDEX_COLUMNS;
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        Ok(RawIndexBlock {
            t_mono_ns: get_1d(&ds[0], r.clone())?,
            offset: get_1d(&ds[1], r.clone())?,
            len: get_1d(&ds[2], r)?,
        })
    }
}

/// Only the time column of a table (for gap scans).
#[derive(Debug, Clone, Default)]
pub(crate) struct TimeBlock(pub Vec<i64>);

impl Block for TimeBlock {
    const COLUMNS: &'static [Column] = &[T_MONO];
    fn read(ds: &[Dataset], r: Range<usize>) -> hdf5::Result<Self> {
        Ok(TimeBlock(get_1d(&ds[0], r)?))
    }
}

pub(crate) fn read_bytes(ds: &Dataset, r: Range<usize>) -> hdf5::Result<Vec<u8>> {
    get_1d(ds, r)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The journal bytes of a row are its fields in column order, little-endian: the format
    /// journals already on disk were written in.
    #[test]
    fn journal_rows_are_their_fields_in_column_order() {
        let imu = ImuRecord {
            t_mono_ns: 1,
            t_wall_ns: 2,
            t_sensor: 3.0,
            gyro: [4.0, 5.0, 6.0],
            accel: [7.0, 8.0, 9.0],
            temp: 10.0,
            status: 11,
        };
        let mut out = Vec::new();
        imu.encode(&mut out);
        let mut expected = Vec::new();
        expected.extend_from_slice(&1i64.to_le_bytes());
        expected.extend_from_slice(&2i64.to_le_bytes());
        for v in [3.0f64, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0] {
            expected.extend_from_slice(&v.to_le_bytes());
        }
        expected.extend_from_slice(&11u32.to_le_bytes());
        assert_eq!(out, expected);
        let back = ImuRecord::decode(&mut Cursor {
            bytes: &out,
            version: 2,
        })
        .unwrap();
        assert_eq!(back, imu);

        let gnss = GnssRecord {
            t_mono_ns: 5,
            t_wall_ns: 6,
            week: 2300,
            tow_s: 1.5,
            utc_ns: 7,
            lat_deg: 48.0,
            lon_deg: 11.0,
            height_m: 500.0,
            vel_ned: [1.0, 2.0, 3.0],
            h_acc_m: 0.5,
            v_acc_m: 0.8,
            s_acc_mps: 0.1,
            fix_type: FixType::Fix3D,
            num_sats: 9,
            pdop: 1.1,
            hdop: 1.2,
            vdop: 1.3,
            heading_deg: 90.0,
        };
        let mut v2 = Vec::new();
        gnss.encode(&mut v2);
        assert_eq!(
            v2.len(),
            8 + 8 + 2 + 8 + 8 + 3 * 8 + 3 * 8 + 3 * 8 + 1 + 1 + 3 * 8 + 8
        );
        assert_eq!(v2[8 + 8 + 2 + 8 + 8 + 72], FixType::Fix3D as u8);
        // A version-1 record has no heading: it reads back as NaN.
        let v1 = &v2[..v2.len() - 8];
        let old = GnssRecord::decode(&mut Cursor {
            bytes: v1,
            version: 1,
        })
        .unwrap();
        assert!(old.heading_deg.is_nan());
        assert_eq!(old.num_sats, 9);

        let event = EventRow::from_record(&EventRecord {
            t_mono_ns: 1,
            t_wall_ns: 2,
            device: "imu".into(),
            kind: EventKind::Gap,
            detail: "gap of 3 samples".into(),
        })
        .unwrap();
        let mut ev = Vec::new();
        event.encode(&mut ev);
        assert_eq!(&ev[16..18], &3u16.to_le_bytes());
        assert_eq!(&ev[18..21], b"imu");
        let back = EventRow::decode(&mut Cursor {
            bytes: &ev,
            version: 2,
        })
        .unwrap();
        assert_eq!(back.detail.as_str(), "gap of 3 samples");
    }
}
