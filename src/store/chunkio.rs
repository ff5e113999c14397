//! Direct chunk writes: the writer shuffles and deflates whole chunks itself and hands the
//! finished bytes to `H5Dwrite_chunk`, instead of letting HDF5's filter pipeline do it.
//!
//! Why (measured, docs/bench/store.md): HDF5's deflate filter calls zlib's `compress2` for
//! every chunk, which sets up and zeroes a fresh ~256 KiB zlib state each time; with 150-row
//! chunks (1 s at 150 Hz) that set-up costs more than compressing the data. Here one
//! `zlib_rs` stream per table is reset and reused, and zlib-rs' level 1 is about 4× faster
//! than the system zlib's on these chunks. The bytes on disk are exactly what the declared
//! filter pipeline (shuffle by element size, then a zlib stream) produces in form, so h5py,
//! MATLAB and our reader decode them through the ordinary pipeline; the tests check that.
//! Each shuffled byte plane that deflate cannot shrink (the noisy low mantissa bytes) is kept
//! in stored deflate blocks within that zlib stream: smaller than deflate's literals, and
//! inflated by copying (see [`ChunkEncoder`]).
//!
//! Small chunks (under [`SMALL_CHUNK_BYTES`], e.g. a 10 Hz GNSS column: 80 bytes a second)
//! are deflated by [`zlib_fixed_rle`] instead: every deflate library (zlib, zlib-rs,
//! libdeflate, miniz) clears a 64-128 KiB match table for each new stream, which for an
//! 80-byte chunk costs many times the compression itself (measured: that memset was 13 % of
//! the writer's CPU). On shuffled columns nearly all the redundancy is runs of equal bytes,
//! which this encoder finds without a table.
//!
//! Only whole chunks of plain little-endian numbers go this way; a partial chunk (a stalled
//! device, the last rows before close) and string columns still go through HDF5's pipeline.

use std::ops::Range;
use std::sync::Mutex;

use hdf5::{Dataset, H5Type};

/// The scope the chunks of one read are decoded in: rayon's pool with the `parallel-read`
/// feature (decoding overlaps the next fetches), else each chunk in turn on this thread.
#[cfg(feature = "parallel-read")]
use rayon::in_place_scope as decode_scope;

#[cfg(not(feature = "parallel-read"))]
fn decode_scope<R>(f: impl FnOnce(&InTurn) -> R) -> R {
    f(&InTurn)
}

/// Runs each spawned decoding at once (the `decode_scope` without `parallel-read`).
#[cfg(not(feature = "parallel-read"))]
struct InTurn;

#[cfg(not(feature = "parallel-read"))]
impl InTurn {
    fn spawn(&self, job: impl FnOnce(&InTurn)) {
        job(self)
    }
}

/// A value stored as its little-endian bytes; `ELEM` is the HDF5 element size the shuffle
/// filter works on (8 for an `[f64; 3]` row of an N×3 f64 dataset).
pub(crate) trait Plain: H5Type + Copy {
    const ELEM: usize;
    /// Columns of the dataset: 0 for a 1-D dataset of scalars, W for N×W.
    const WIDTH: usize;
    fn put_le(&self, out: &mut Vec<u8>);
    /// Writes `values` at row `start` through HDF5 (and its filter pipeline).
    fn write_rows(ds: &Dataset, start: usize, values: &[Self]) -> hdf5::Result<()>;
}

macro_rules! plain_scalar {
    ($($t:ty),*) => {$(
        impl Plain for $t {
            const ELEM: usize = std::mem::size_of::<$t>();
            const WIDTH: usize = 0;
            fn put_le(&self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn write_rows(ds: &Dataset, start: usize, values: &[Self]) -> hdf5::Result<()> {
                ds.write_slice(values, start..start + values.len())
            }
        }
    )*};
}
plain_scalar!(i64, u64, f64, u32, u16, u8);

impl<const W: usize> Plain for [f64; W]
where
    [f64; W]: H5Type,
{
    const ELEM: usize = 8;
    const WIDTH: usize = W;
    fn put_le(&self, out: &mut Vec<u8>) {
        for v in self {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    fn write_rows(ds: &Dataset, start: usize, values: &[Self]) -> hdf5::Result<()> {
        let view = ndarray::ArrayView2::from(values);
        ds.write_slice(view, (start..start + values.len(), ..))
    }
}

/// Turns rows into the bytes of one stored chunk: shuffle + zlib when `level > 0`, the plain
/// bytes otherwise. Keeps its buffers and its deflate stream between chunks.
///
/// The zlib stream of a chunk is built one shuffled byte plane at a time (see
/// [`ChunkEncoder::deflate_planes`]): a plane that deflate cannot shrink (the noisy low
/// mantissa bytes of sensor data, 6 of the 8 planes of an f64 gyro column) goes into stored
/// deflate blocks, which every inflater copies instead of decoding symbol by symbol; the
/// others are deflated at `level`. The result is one ordinary zlib stream.
pub(crate) struct ChunkEncoder {
    level: u8,
    deflate: Option<zlib_rs::Deflate>,
    plain: Vec<u8>,
    shuffled: Vec<u8>,
    out: Vec<u8>,
    /// One plane's deflated bytes, before the choice between them and a stored block.
    segment: Vec<u8>,
}

impl ChunkEncoder {
    /// `level` 0 = no filters; 1..=9 = shuffle + deflate at that level.
    pub fn new(level: u8) -> Self {
        let level = level.min(9);
        ChunkEncoder {
            level,
            // A raw deflate stream: the zlib header and trailer are written here, since a
            // plane may be replaced by a stored block (see `deflate_planes`).
            deflate: (level > 0).then(|| zlib_rs::Deflate::new(i32::from(level), false, 15)),
            plain: Vec::new(),
            shuffled: Vec::new(),
            out: Vec::new(),
            segment: Vec::new(),
        }
    }

    /// Encodes `values` as one chunk and returns the bytes to store.
    pub fn encode<T: Plain>(&mut self, values: &[T]) -> hdf5::Result<&[u8]> {
        self.plain.clear();
        for v in values {
            v.put_le(&mut self.plain);
        }
        if self.deflate.is_none() {
            return Ok(&self.plain);
        }
        shuffle(&self.plain, T::ELEM, &mut self.shuffled);
        if self.shuffled.len() < SMALL_CHUNK_BYTES {
            zlib_fixed_rle(&self.shuffled, &mut self.out);
            return Ok(&self.out);
        }
        self.deflate_planes(T::ELEM)?;
        Ok(&self.out)
    }

    /// `self.shuffled` as a zlib stream in `self.out`: one raw deflate stream fed plane by
    /// plane, with a sync flush after each plane so that its output ends on a byte boundary
    /// (the last plane finishes the stream). When a plane's output is not smaller than the
    /// plane stored as it is, it is replaced by stored blocks of the plane's bytes. That
    /// keeps the stream valid: later planes' matches refer to the inflated bytes, which are
    /// the same whichever way a plane was coded, and stored blocks are byte-aligned. Deflate
    /// itself (here zlib-rs' level 1, fixed Huffman codes) spends 8-9 bits on every byte of a
    /// random plane, and inflating it costs a Huffman decode per byte (measured: 33 % of
    /// `imulab allan` on a session; docs/bench/allan.md, session 6).
    fn deflate_planes(&mut self, elem: usize) -> hdf5::Result<()> {
        let Some(deflate) = self.deflate.as_mut() else {
            return Err(hdf5::Error::from("deflate_planes without a deflate stream"));
        };
        let data = &self.shuffled;
        let n = data.len() / elem.max(1);
        // The planes; trailing bytes that fill no element (never for whole rows) join the last.
        let mut bounds: Vec<usize> = (0..elem.max(1)).map(|b| b * n).collect();
        bounds.retain(|&b| b < data.len());
        bounds.dedup();
        bounds.push(data.len());
        self.out.clear();
        self.out.extend_from_slice(&zlib_header(self.level));
        deflate.reset();
        let planes = bounds.len() - 1;
        for p in 0..planes {
            let plane = &data[bounds[p]..bounds[p + 1]];
            let last = p + 1 == planes;
            let flush = if last {
                zlib_rs::DeflateFlush::Finish
            } else {
                zlib_rs::DeflateFlush::SyncFlush
            };
            // Room for the worst case: the bound of a whole stream of this plane, plus the
            // empty stored block a sync flush appends.
            self.segment.clear();
            self.segment
                .resize(zlib_rs::compress_bound(plane.len()) + 64, 0);
            let (in_before, out_before) = (deflate.total_in(), deflate.total_out());
            let status = deflate
                .compress(plane, &mut self.segment, flush)
                .map_err(|e| hdf5::Error::from(format!("deflate (level {}): {e:?}", self.level)))?;
            let used_in = deflate.total_in() - in_before;
            let used_out = usize::try_from(deflate.total_out() - out_before).unwrap_or(usize::MAX);
            let done = if last {
                status == zlib_rs::Status::StreamEnd
            } else {
                used_out < self.segment.len()
            };
            if !done || used_in != plane.len() as u64 {
                return Err(hdf5::Error::from(format!(
                    "deflate (level {}) did not finish byte plane {p} ({} bytes) of a {} byte chunk",
                    self.level,
                    plane.len(),
                    data.len()
                )));
            }
            if used_out < stored_size(plane.len()) {
                self.out.extend_from_slice(&self.segment[..used_out]);
            } else {
                put_stored(plane, last, &mut self.out);
            }
        }
        self.out
            .extend_from_slice(&zlib_rs::adler32::adler32(1, data).to_be_bytes());
        Ok(())
    }
}

/// The two bytes of a zlib header (RFC 1950) for a 32 KiB window, with the compression level
/// field zlib writes for `level`.
fn zlib_header(level: u8) -> [u8; 2] {
    match level {
        0 | 1 => [0x78, 0x01],
        2..=5 => [0x78, 0x5e],
        6 => [0x78, 0x9c],
        _ => [0x78, 0xda],
    }
}

/// Largest data of one stored deflate block.
const STORED_BLOCK_MAX: usize = 65_535;

/// Bytes that `len` bytes take as stored deflate blocks (5 header bytes per block).
fn stored_size(len: usize) -> usize {
    len + 5 * len.div_ceil(STORED_BLOCK_MAX).max(1)
}

/// `data` as stored deflate blocks (RFC 1951 3.2.4), starting on a byte boundary; the last
/// block is marked final when `last`.
fn put_stored(data: &[u8], last: bool, out: &mut Vec<u8>) {
    let blocks = data.len().div_ceil(STORED_BLOCK_MAX).max(1);
    for b in 0..blocks {
        let part = &data
            [(b * STORED_BLOCK_MAX).min(data.len())..((b + 1) * STORED_BLOCK_MAX).min(data.len())];
        let len = part.len() as u16; // at most STORED_BLOCK_MAX
        out.push(u8::from(last && b + 1 == blocks)); // BFINAL, BTYPE 00, padding
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(&(!len).to_le_bytes());
        out.extend_from_slice(part);
    }
}

/// HDF5's shuffle filter: byte `b` of element `i` goes to `out[b * n + i]` (all first bytes,
/// then all second bytes, ...), so slowly varying high bytes form long runs for deflate.
/// Trailing bytes that do not fill an element are copied as they are, as HDF5 does.
fn shuffle(src: &[u8], elem: usize, out: &mut Vec<u8>) {
    out.clear();
    out.resize(src.len(), 0);
    if elem <= 1 {
        out.copy_from_slice(src);
        return;
    }
    let n = src.len() / elem;
    // One byte plane at a time: sequential writes, and the compiler unrolls the gather.
    for (b, plane) in out[..n * elem].chunks_exact_mut(n.max(1)).enumerate() {
        for (o, e) in plane.iter_mut().zip(src.chunks_exact(elem)) {
            *o = e[b];
        }
    }
    let whole = n * elem;
    out[whole..].copy_from_slice(&src[whole..]);
}

/// Chunks smaller than this (after shuffling) are deflated by [`zlib_fixed_rle`].
const SMALL_CHUNK_BYTES: usize = 1024;

/// Writes `data` as a zlib stream (RFC 1950) holding one deflate block (RFC 1951) with the
/// fixed Huffman code, whose only matches are runs (distance 1, lengths 3-258). Any inflater
/// reads it. Hand-written because no deflate crate compresses a short input without first
/// clearing a large match table (see the module docs).
fn zlib_fixed_rle(data: &[u8], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&[0x78, 0x01]); // deflate, 32 KiB window, fastest; header check ok
    let mut bits = BitSink {
        out: &mut *out,
        acc: 0,
        n: 0,
    };
    bits.put(1, 1); // last block
    bits.put(1, 2); // fixed Huffman codes
    let mut i = 0;
    while i < data.len() {
        let run = match i.checked_sub(1).map(|p| data[p]) {
            Some(prev) => data[i..]
                .iter()
                .take(258)
                .take_while(|&&b| b == prev)
                .count(),
            None => 0,
        };
        if run >= 3 {
            let k = LEN_BASE
                .iter()
                .rposition(|&base| usize::from(base) <= run)
                .unwrap_or(0);
            bits.fixed(257 + k as u32);
            bits.put(
                (run - usize::from(LEN_BASE[k])) as u32,
                u32::from(LEN_EXTRA[k]),
            );
            bits.code(0, 5); // distance code 0: distance 1, no extra bits
            i += run;
        } else {
            bits.fixed(u32::from(data[i]));
            i += 1;
        }
    }
    bits.fixed(256); // end of block
    bits.finish();
    out.extend_from_slice(&zlib_rs::adler32::adler32(1, data).to_be_bytes());
}

/// Base match length of the length codes 257..=285 and their extra bits (RFC 1951 3.2.5).
const LEN_BASE: [u16; 29] = [
    3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131,
    163, 195, 227, 258,
];
const LEN_EXTRA: [u8; 29] = [
    0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0,
];

/// The bits of a deflate stream, packed from the least significant bit (RFC 1951 3.1.1).
struct BitSink<'a> {
    out: &'a mut Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitSink<'_> {
    /// `bits` low bits of `value`, least significant first (header fields, extra bits).
    fn put(&mut self, value: u32, bits: u32) {
        self.acc |= u64::from(value) << self.n;
        self.n += bits;
        while self.n >= 8 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }

    /// A Huffman code of `bits` bits, sent from its most significant bit.
    fn code(&mut self, code: u32, bits: u32) {
        self.put(code.reverse_bits() >> (32 - bits), bits);
    }

    /// A literal/length symbol in the fixed Huffman code (RFC 1951 3.2.6).
    fn fixed(&mut self, sym: u32) {
        match sym {
            0..=143 => self.code(0x30 + sym, 8),
            144..=255 => self.code(0x190 + sym - 144, 9),
            256..=279 => self.code(sym - 256, 7),
            _ => self.code(0xC0 + sym - 280, 8),
        }
    }

    /// Pads the last byte with zero bits.
    fn finish(self) {
        if self.n > 0 {
            self.out.push(self.acc as u8);
        }
    }
}

/// Writes `values` at row `start` of `ds`, which must already extend that far (the writer
/// grows its tables ahead, see `chunkfile::Table`): the whole chunks among them directly
/// (encoded by `enc`), a partial chunk at either end through HDF5's filter pipeline (it may
/// have to merge with rows already on disk).
pub(crate) fn put_rows<T: Plain>(
    ds: &Dataset,
    enc: &mut ChunkEncoder,
    chunk_rows: usize,
    start: usize,
    values: &[T],
) -> hdf5::Result<()> {
    let end = start + values.len();
    let c = chunk_rows.max(1);
    let first_whole = start.div_ceil(c) * c;
    let last_whole = end / c * c;
    if first_whole >= last_whole {
        return T::write_rows(ds, start, values);
    }
    let (head, rest) = values.split_at(first_whole - start);
    let (body, tail) = rest.split_at(last_whole - first_whole);
    if !head.is_empty() {
        T::write_rows(ds, start, head)?;
    }
    write_whole_chunks(ds, enc, c, first_whole, body)?;
    if !tail.is_empty() {
        T::write_rows(ds, last_whole, tail)?;
    }
    Ok(())
}

/// Writes `values` as whole chunks of `chunk_rows` rows starting at row `start` (a multiple of
/// `chunk_rows`) of `ds`, which must already extend that far.
fn write_whole_chunks<T: Plain>(
    ds: &Dataset,
    enc: &mut ChunkEncoder,
    chunk_rows: usize,
    start: usize,
    values: &[T],
) -> hdf5::Result<()> {
    if chunk_rows == 0
        || !start.is_multiple_of(chunk_rows)
        || !values.len().is_multiple_of(chunk_rows)
    {
        return Err(hdf5::Error::from(format!(
            "{}: {} rows at row {start} are not whole chunks of {chunk_rows}",
            ds.name(),
            values.len()
        )));
    }
    for (k, rows) in values.chunks_exact(chunk_rows).enumerate() {
        let row = start + k * chunk_rows;
        let bytes = enc.encode(rows)?;
        let offset = [row as u64, 0];
        let rank = if T::WIDTH == 0 { 1 } else { 2 };
        write_chunk_raw(ds, &offset[..rank], bytes)
            .map_err(|e| hdf5::Error::from(format!("{}: chunk at row {row}: {e}", ds.name())))?;
    }
    Ok(())
}

/// `H5Dwrite_chunk` with filter mask 0 (every filter of the dataset's pipeline was applied to
/// `bytes`). The one unsafe call of the store; hdf5-metno's safe API has no direct chunk write.
fn write_chunk_raw(ds: &Dataset, offset: &[u64], bytes: &[u8]) -> hdf5::Result<()> {
    let id = ds.id();
    let rc = hdf5::sync::sync(|| {
        // SAFETY: `id` is a live dataset handle owned by `ds` for this whole call; `offset`
        // has one entry per dataset dimension (the caller passes the dataset's rank) and
        // `bytes` is a valid buffer of exactly the length passed. HDF5 copies the buffer
        // before returning and keeps no pointer to it. The global HDF5 lock is held.
        unsafe {
            hdf5_sys::h5d::H5Dwrite_chunk(
                id,
                hdf5_sys::h5p::H5P_DEFAULT,
                0,
                offset.as_ptr(),
                bytes.len(),
                bytes.as_ptr().cast(),
            )
        }
    });
    if rc < 0 {
        return Err(hdf5::Error::from(format!(
            "H5Dwrite_chunk of {} bytes failed",
            bytes.len()
        )));
    }
    Ok(())
}

// --- Reading ------------------------------------------------------------------------------
//
// The read side mirrors the writer: a [`ColumnReader`] fetches stored chunks with
// `H5Dread_chunk`, inflates each in one call with libdeflate (the chunk's plain size is
// known, so no streaming state is needed) and undoes the shuffle here, instead of HDF5's
// filter pipeline (system zlib, a fresh inflate state, a hyperslab selection and a type
// conversion per chunk and read). The whole chunks of a read are fetched one after the other
// (HDF5 is not thread-safe) and then decoded on the rayon pool, each straight into its own
// rows of the caller's columns, so a read costs one pass over the inflated bytes and uses
// both cores. Measured in docs/bench/store.md and docs/bench/allan.md.
//
// Anything it does not understand (other filters, a filter skipped for a chunk, a chunk not
// allocated, elements other than 8-byte numbers) goes through HDF5's ordinary read for
// that chunk, so the result never depends on which path was taken.

/// How a dataset's chunks are stored, when the direct path can decode them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StoredAs {
    /// No filters: a chunk is the little-endian bytes of its rows.
    Plain,
    /// Shuffle (by element size) then deflate, the pipeline `create_column` declares.
    ShuffleDeflate,
}

/// Reads whole rows of one numeric dataset of 8-byte elements (`i64` or `f64`, 1-D or N×W)
/// chunk by chunk. Whole chunks inside a read are decoded in parallel straight into the
/// output; a chunk split by the ends of a read is decoded once into a cache, so that
/// consecutive reads that split it do not decode it twice. Values come out as their 64 bits;
/// see [`ColumnReader::read_f64`] and [`ColumnReader::read_i64`].
pub(crate) struct ColumnReader {
    ds: Dataset,
    /// The dataset's path, for messages.
    name: String,
    /// Values per row: 1 for a 1-D dataset, W for N×W.
    width: usize,
    rank: usize,
    /// f64 elements (else i64).
    float: bool,
    rows: usize,
    chunk_rows: usize,
    stored: Option<StoredAs>,
    /// Stored bytes of whole chunks waiting to be decoded, kept between reads.
    raw_pool: Vec<Vec<u8>>,
    /// Scratch of the cached (split) chunk's decoding.
    scratch: Scratch,
    /// The cached chunk, one u64 per value (row-major), and its chunk index.
    words: Vec<u64>,
    cached: Option<usize>,
}

/// Buffers of one chunk's decoding; one per thread.
struct Scratch {
    inflater: libdeflater::Decompressor,
    inflated: Vec<u8>,
    words: Vec<u64>,
}

impl Scratch {
    fn new() -> Self {
        Scratch {
            inflater: libdeflater::Decompressor::new(),
            inflated: Vec::new(),
            words: Vec::new(),
        }
    }
}

thread_local! {
    /// Each thread's decoding buffers, kept from chunk to chunk and read to read.
    static THREAD_SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::new());
}

/// What the decoding of one stored chunk needs to know about its dataset.
#[derive(Clone, Copy)]
struct ChunkShape<'a> {
    name: &'a str,
    stored: StoredAs,
    /// Values in a whole chunk (rows × width).
    values: usize,
}

impl ColumnReader {
    /// `rows`: how many rows of the dataset are valid (the caller's table length). `direct`:
    /// whether chunks may be read directly; only for a file no writer changes any more (a
    /// live file may rewrite a partial chunk between the size query and the read).
    pub fn new(ds: Dataset, rows: usize, direct: bool) -> hdf5::Result<Self> {
        let shape = ds.shape();
        let rank = shape.len();
        let width = match shape.as_slice() {
            [_] => 1,
            [_, w] if *w > 0 => *w,
            other => return Err(format!("{}: unsupported shape {other:?}", ds.name()).into()),
        };
        let float = match ds.dtype()?.to_descriptor()? {
            hdf5::types::TypeDescriptor::Float(hdf5::types::FloatSize::U8) => true,
            hdf5::types::TypeDescriptor::Integer(hdf5::types::IntSize::U8) => false,
            other => return Err(format!("{}: elements are {other}, not i64/f64", ds.name()).into()),
        };
        let chunk = ds.chunk();
        let chunk_rows = chunk.as_ref().and_then(|c| c.first().copied()).unwrap_or(0);
        // Only chunks that span whole rows are decoded here (what the writer creates).
        let whole_rows = chunk
            .as_ref()
            .is_some_and(|c| c.len() == rank && (rank == 1 || c[1] == width));
        let filters = ds.filters();
        let stored = match filters.as_slice() {
            _ if !direct || !whole_rows || chunk_rows == 0 => None,
            [] => Some(StoredAs::Plain),
            [hdf5::filters::Filter::Shuffle, hdf5::filters::Filter::Deflate(_)] => {
                Some(StoredAs::ShuffleDeflate)
            }
            _ => None,
        };
        Ok(ColumnReader {
            name: ds.name(),
            width,
            rank,
            float,
            rows: rows.min(shape.first().copied().unwrap_or(0)),
            chunk_rows: chunk_rows.max(1),
            stored,
            ds,
            raw_pool: Vec::new(),
            scratch: Scratch::new(),
            words: Vec::new(),
            cached: None,
        })
    }

    /// Rows per stored chunk (1 when the dataset is not chunked).
    pub fn chunk_rows(&self) -> usize {
        self.chunk_rows
    }

    /// Appends rows `r` as f64: component `k` of each row to `out[k]` (`out.len()` must be
    /// the dataset's width).
    #[cfg(test)]
    pub fn read_f64(&mut self, r: Range<usize>, out: &mut [&mut Vec<f64>]) -> hdf5::Result<()> {
        let mut room = grow(out, r.len());
        self.read_with(r, &mut room, f64::from_bits)
    }

    /// Appends rows `r` of a 1-D i64 column to `out`.
    #[cfg(test)]
    pub fn read_i64(&mut self, r: Range<usize>, out: &mut Vec<i64>) -> hdf5::Result<()> {
        let mut out = [out];
        let mut room = grow(&mut out, r.len());
        self.read_with(r, &mut room, |w| w as i64)
    }

    /// Rows `r` as f64 into `out`, component `k` of each row to `out[k]`, each exactly
    /// `r.len()` long: a caller that keeps its columns at the block length from block to block
    /// has nothing cleared or zeroed before they are overwritten.
    pub fn read_f64_into(&mut self, r: Range<usize>, out: &mut [&mut [f64]]) -> hdf5::Result<()> {
        self.read_with(r, out, f64::from_bits)
    }

    /// Rows `r` of a 1-D i64 column into `out`, exactly `r.len()` long.
    pub fn read_i64_into(&mut self, r: Range<usize>, out: &mut [i64]) -> hdf5::Result<()> {
        self.read_with(r, &mut [out], |w| w as i64)
    }

    fn read_with<T: Copy + Send>(
        &mut self,
        r: Range<usize>,
        out: &mut [&mut [T]],
        convert: impl Fn(u64) -> T + Copy + Send + Sync,
    ) -> hdf5::Result<()> {
        if out.len() != self.width {
            return Err(format!(
                "{}: {} output columns for a width of {}",
                self.name,
                out.len(),
                self.width
            )
            .into());
        }
        if r.end > self.rows {
            return Err(format!(
                "{}: rows {}..{} past the {} valid rows",
                self.name, r.start, r.end, self.rows
            )
            .into());
        }
        if let Some(o) = out.iter().find(|o| o.len() != r.len()) {
            return Err(format!(
                "{}: an output column of {} rows for rows {}..{}",
                self.name,
                o.len(),
                r.start,
                r.end
            )
            .into());
        }
        // Each chunk's rows are a disjoint part of the output. The whole chunks are fetched
        // here, one after the other (HDF5 is not thread-safe), and each is decoded on the
        // rayon pool as soon as it is fetched, so that decoding overlaps the next fetches.
        let mut rest: Vec<&mut [T]> = out.iter_mut().map(|o| &mut o[..]).collect();
        let c = self.chunk_rows;
        let name = self.name.clone();
        let stored = self.stored;
        let values = c * self.width;
        // The error of the lowest row, whichever thread met it.
        let failed: Mutex<Option<(usize, hdf5::Error)>> = Mutex::new(None);
        let fail = |row: usize, e: hdf5::Error| {
            let mut slot = failed.lock().unwrap_or_else(|p| p.into_inner());
            if slot.as_ref().is_none_or(|(r, _)| row < *r) {
                *slot = Some((row, e));
            }
        };
        let used: Mutex<Vec<Vec<u8>>> = Mutex::new(Vec::new());
        decode_scope(|scope| {
            let mut row = r.start;
            while row < r.end {
                let k = row / c;
                let first = k * c;
                let (lo, hi) = (row - first, (r.end - first).min(c));
                let here: Vec<&mut [T]> = rest
                    .iter_mut()
                    .map(|s| {
                        let (head, tail) = std::mem::take(s).split_at_mut(hi - lo);
                        *s = tail;
                        head
                    })
                    .collect();
                row = first + hi;
                // A whole chunk of valid rows goes to the parallel decoding when it can.
                if let Some(stored) = stored.filter(|_| {
                    lo == 0 && hi == c && first + c <= self.rows && self.cached != Some(k)
                }) {
                    match self.fetch(first) {
                        Ok(Some(raw)) => {
                            let (name, fail, used) = (&name, &fail, &used);
                            scope.spawn(move |_| {
                                let shape = ChunkShape {
                                    name,
                                    stored,
                                    values,
                                };
                                let decoded = THREAD_SCRATCH.with_borrow_mut(|scratch| {
                                    decode_chunk_into(shape, first, &raw, scratch, here, convert)
                                });
                                if let Err(e) = decoded {
                                    fail(first, e);
                                }
                                used.lock().unwrap_or_else(|p| p.into_inner()).push(raw);
                            });
                            continue;
                        }
                        Ok(None) => {}
                        Err(e) => {
                            fail(first, e);
                            break;
                        }
                    }
                }
                if let Err(e) = self.load(k) {
                    fail(first, e);
                    break;
                }
                scatter(&self.words[lo * self.width..hi * self.width], here, convert);
            }
        });
        self.raw_pool
            .extend(used.into_inner().unwrap_or_else(|p| p.into_inner()));
        match failed.into_inner().unwrap_or_else(|p| p.into_inner()) {
            Some((_, e)) => Err(e),
            None => Ok(()),
        }
    }

    /// The stored bytes of the whole chunk starting at row `first`, or `None` when it must go
    /// through HDF5 instead (no direct path, not allocated, a filter skipped).
    fn fetch(&mut self, first: usize) -> hdf5::Result<Option<Vec<u8>>> {
        if self.stored.is_none() {
            return Ok(None);
        }
        let chunk_bytes = self.chunk_rows * self.width * 8;
        let offset = [first as u64, 0];
        let Some(size) = chunk_size(&self.ds, &offset[..self.rank])? else {
            return Ok(None);
        };
        // A damaged index must not make us allocate whatever it says.
        let largest = zlib_rs::compress_bound(chunk_bytes) + 1024;
        if size > largest {
            return Err(format!(
                "{}: chunk at row {first} claims {size} stored bytes, more than any encoding of its {chunk_bytes} bytes",
                self.name
            )
            .into());
        }
        // Pooled buffers keep their length, so only a longer chunk than any before clears
        // bytes (H5Dread_chunk overwrites all `size` of them).
        let mut raw = self.raw_pool.pop().unwrap_or_default();
        raw.resize(size, 0);
        let mask = read_chunk_raw(&self.ds, &offset[..self.rank], &mut raw)?;
        if mask != 0 {
            // A filter was skipped for this chunk: let the pipeline sort it out.
            self.raw_pool.push(raw);
            return Ok(None);
        }
        Ok(Some(raw))
    }

    /// Decodes chunk `k` into `words` (rows past the dataset's valid rows are left out).
    fn load(&mut self, k: usize) -> hdf5::Result<()> {
        if self.cached == Some(k) {
            return Ok(());
        }
        self.cached = None;
        let first = k * self.chunk_rows;
        let rows_here = self.chunk_rows.min(self.rows.saturating_sub(first));
        let values = rows_here * self.width;
        match (self.stored, self.fetch(first)?) {
            (Some(stored), Some(raw)) => {
                let shape = ChunkShape {
                    name: &self.name,
                    stored,
                    values: self.chunk_rows * self.width,
                };
                let decoded = decode_chunk(shape, first, &raw, &mut self.scratch);
                self.raw_pool.push(raw);
                self.words.clear();
                self.words.extend_from_slice(&decoded?[..values]);
            }
            _ => self.load_through_hdf5(first, rows_here)?,
        }
        self.cached = Some(k);
        Ok(())
    }

    /// HDF5's own read of the chunk's rows (its filter pipeline and fill values), read in the
    /// dataset's own type and kept as bits.
    fn load_through_hdf5(&mut self, first: usize, rows: usize) -> hdf5::Result<()> {
        fn get<T: H5Type + Copy>(
            ds: &Dataset,
            rank: usize,
            r: Range<usize>,
            bits: impl Fn(T) -> u64,
            out: &mut Vec<u64>,
        ) -> hdf5::Result<()> {
            if rank == 1 {
                out.extend(ds.read_slice_1d::<T, _>(r)?.iter().map(|&v| bits(v)));
            } else {
                out.extend(ds.read_slice_2d::<T, _>((r, ..))?.iter().map(|&v| bits(v)));
            }
            Ok(())
        }
        self.words.clear();
        let r = first..first + rows;
        if self.float {
            get::<f64>(&self.ds, self.rank, r, f64::to_bits, &mut self.words)
        } else {
            get::<i64>(&self.ds, self.rank, r, |v| v as u64, &mut self.words)
        }
    }
}

/// `len` more default values at the end of each vector, and those new parts.
#[cfg(test)]
fn grow<'a, T: Copy + Default>(out: &'a mut [&mut Vec<T>], len: usize) -> Vec<&'a mut [T]> {
    out.iter_mut()
        .map(|o| {
            let base = o.len();
            o.resize(base + len, T::default());
            &mut o[base..]
        })
        .collect()
}

/// Decodes the stored bytes of the whole chunk at row `first` straight into its rows of the
/// output columns (`out[k]`: component `k`, one value per row of the chunk); a shuffled chunk
/// is unshuffled into them directly (no row-major copy in between).
fn decode_chunk_into<T: Copy>(
    shape: ChunkShape<'_>,
    first: usize,
    raw: &[u8],
    scratch: &mut Scratch,
    out: Vec<&mut [T]>,
    convert: impl Fn(u64) -> T + Copy,
) -> hdf5::Result<()> {
    match shape.stored {
        StoredAs::Plain => {
            let words = decode_chunk(shape, first, raw, scratch)?;
            scatter(words, out, convert);
        }
        StoredAs::ShuffleDeflate => {
            inflate_chunk(shape, first, raw, scratch)?;
            unshuffle_into(&scratch.inflated, out, convert);
        }
    }
    Ok(())
}

/// Inflates the stored bytes of the whole (shuffled) chunk at row `first` into
/// `scratch.inflated`, checking that they give exactly the chunk's size.
fn inflate_chunk(
    shape: ChunkShape<'_>,
    first: usize,
    raw: &[u8],
    scratch: &mut Scratch,
) -> hdf5::Result<()> {
    let chunk_bytes = shape.values * 8;
    scratch.inflated.resize(chunk_bytes, 0);
    let n = scratch
        .inflater
        .zlib_decompress(raw, &mut scratch.inflated)
        .map_err(|e| {
            hdf5::Error::from(format!(
                "{}: chunk at row {first}: inflate: {e}",
                shape.name
            ))
        })?;
    if n != chunk_bytes {
        return Err(format!(
            "{}: chunk at row {first}: inflated to {n} bytes, expected {chunk_bytes}",
            shape.name
        )
        .into());
    }
    Ok(())
}

/// Decodes the stored bytes of the whole chunk at row `first` into `scratch.words` (one u64
/// per value, row-major) and returns them.
fn decode_chunk<'s>(
    shape: ChunkShape<'_>,
    first: usize,
    raw: &[u8],
    scratch: &'s mut Scratch,
) -> hdf5::Result<&'s [u64]> {
    let chunk_bytes = shape.values * 8;
    let plain: &[u8] = match shape.stored {
        StoredAs::Plain => raw,
        StoredAs::ShuffleDeflate => {
            inflate_chunk(shape, first, raw, scratch)?;
            &scratch.inflated
        }
    };
    if plain.len() != chunk_bytes {
        return Err(format!(
            "{}: chunk at row {first} holds {} bytes, expected {chunk_bytes}",
            shape.name,
            plain.len()
        )
        .into());
    }
    match shape.stored {
        StoredAs::Plain => words_from_le(plain, &mut scratch.words),
        StoredAs::ShuffleDeflate => unshuffle_words(plain, &mut scratch.words),
    }
    Ok(&scratch.words)
}

/// Row-major values (`out.len()` per row) into one output column per component.
fn scatter<T: Copy>(words: &[u64], mut out: Vec<&mut [T]>, convert: impl Fn(u64) -> T) {
    match out.as_mut_slice() {
        [o] => {
            for (d, &w) in o.iter_mut().zip(words) {
                *d = convert(w);
            }
        }
        [x, y, z] => {
            for (((w, x), y), z) in words
                .chunks_exact(3)
                .zip(x.iter_mut())
                .zip(y.iter_mut())
                .zip(z.iter_mut())
            {
                *x = convert(w[0]);
                *y = convert(w[1]);
                *z = convert(w[2]);
            }
        }
        cols => {
            let width = cols.len();
            for (axis, col) in cols.iter_mut().enumerate() {
                for (d, &w) in col.iter_mut().zip(words.iter().skip(axis).step_by(width)) {
                    *d = convert(w);
                }
            }
        }
    }
}

/// The little-endian 8-byte words of `plain`.
fn words_from_le(plain: &[u8], out: &mut Vec<u64>) {
    out.clear();
    out.extend(
        plain
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().unwrap_or([0; 8]))),
    );
}

/// Undoes HDF5's shuffle of 8-byte elements: byte `b` of element `i` is at `b * n + i` (`n`
/// elements in the chunk). Eight elements at a time: the next eight bytes of each byte plane,
/// an 8 × 8 byte transpose in registers, eight words out (one read and one write of each
/// byte, where a plane-by-plane loop reads and rewrites every word eight times).
fn unshuffle_words(shuffled: &[u8], out: &mut Vec<u64>) {
    let n = shuffled.len() / 8;
    out.clear();
    out.reserve(n);
    let planes: [&[u8]; 8] = std::array::from_fn(|b| &shuffled[b * n..(b + 1) * n]);
    let whole = n / 8 * 8;
    for i in (0..whole).step_by(8) {
        let mut a: [u64; 8] = std::array::from_fn(|b| {
            u64::from_le_bytes(planes[b][i..i + 8].try_into().unwrap_or([0; 8]))
        });
        transpose_8x8_bytes(&mut a);
        out.extend_from_slice(&a);
    }
    out.extend((whole..n).map(|i| {
        planes
            .iter()
            .enumerate()
            .fold(0u64, |w, (b, plane)| w | u64::from(plane[i]) << (8 * b))
    }));
}

/// [`unshuffle_words`] straight into output columns: element `e` of the chunk (row-major,
/// `out.len()` values a row) goes to `out[e % width][e / width]`. One row (1-D) and three
/// (N×3) take eight transposed words, resp. three times eight (eight rows), at a time.
fn unshuffle_into<T: Copy>(shuffled: &[u8], mut out: Vec<&mut [T]>, convert: impl Fn(u64) -> T) {
    let width = out.len().max(1);
    let n = (shuffled.len() / 8).min(out.iter().map(|o| o.len()).min().unwrap_or(0) * width);
    let planes: [&[u8]; 8] = std::array::from_fn(|b| &shuffled[b * (shuffled.len() / 8)..][..n]);
    let word = |i: usize| -> [u64; 8] {
        let mut a: [u64; 8] = std::array::from_fn(|b| {
            u64::from_le_bytes(planes[b][i..i + 8].try_into().unwrap_or([0; 8]))
        });
        transpose_8x8_bytes(&mut a);
        a
    };
    let done = match out.as_mut_slice() {
        [o] => {
            let whole = n / 8 * 8;
            for i in (0..whole).step_by(8) {
                for (d, &w) in o[i..i + 8].iter_mut().zip(&word(i)) {
                    *d = convert(w);
                }
            }
            whole
        }
        [x, y, z] => {
            let whole = n / 24 * 24;
            for i in (0..whole).step_by(24) {
                let (a, b, c) = (word(i), word(i + 8), word(i + 16));
                let w: [u64; 24] = std::array::from_fn(|k| match k {
                    0..=7 => a[k],
                    8..=15 => b[k - 8],
                    _ => c[k - 16],
                });
                let row = i / 3;
                for k in 0..8 {
                    x[row + k] = convert(w[3 * k]);
                    y[row + k] = convert(w[3 * k + 1]);
                    z[row + k] = convert(w[3 * k + 2]);
                }
            }
            whole
        }
        _ => 0,
    };
    for e in done..n {
        let w = planes
            .iter()
            .enumerate()
            .fold(0u64, |w, (b, plane)| w | u64::from(plane[e]) << (8 * b));
        out[e % width][e / width] = convert(w);
    }
}

/// Transposes the 8 × 8 byte matrix whose row `r` is the little-endian bytes of `a[r]`:
/// afterwards byte `b` of `a[j]` is what byte `j` of `a[b]` was. Three rounds of block swaps
/// (4 × 4, 2 × 2, 1 × 1 bytes).
#[inline(always)]
fn transpose_8x8_bytes(a: &mut [u64; 8]) {
    for r in 0..4 {
        let t = ((a[r] >> 32) ^ a[r + 4]) & 0x0000_0000_FFFF_FFFF;
        a[r] ^= t << 32;
        a[r + 4] ^= t;
    }
    for r in [0, 1, 4, 5] {
        let t = ((a[r] >> 16) ^ a[r + 2]) & 0x0000_FFFF_0000_FFFF;
        a[r] ^= t << 16;
        a[r + 2] ^= t;
    }
    for r in [0, 2, 4, 6] {
        let t = ((a[r] >> 8) ^ a[r + 1]) & 0x00FF_00FF_00FF_00FF;
        a[r] ^= t << 8;
        a[r + 1] ^= t;
    }
}

// Declared here because hdf5-metno-sys does not bind it; part of the HDF5 C API since 1.10.2.
// (`H5Dget_chunk_info_by_coord`, which it does bind, walks the whole chunk index on every
// call in 1.10.8: measured, 62 % of a session read.)
unsafe extern "C" {
    fn H5Dget_chunk_storage_size(
        dset_id: hdf5_sys::h5i::hid_t,
        offset: *const hdf5_sys::h5::hsize_t,
        chunk_bytes: *mut hdf5_sys::h5::hsize_t,
    ) -> hdf5_sys::h5::herr_t;
}

/// Stored size of the chunk at `offset`, or `None` when it is not allocated.
fn chunk_size(ds: &Dataset, offset: &[u64]) -> hdf5::Result<Option<usize>> {
    let id = ds.id();
    let mut size: hdf5_sys::h5::hsize_t = 0;
    let rc = hdf5::sync::sync(|| {
        // SAFETY: `id` is a live dataset handle owned by `ds`; `offset` has one entry per
        // dataset dimension (the caller passes the dataset's rank); `size` is a live local.
        // The global HDF5 lock is held.
        unsafe { H5Dget_chunk_storage_size(id, offset.as_ptr(), &mut size) }
    });
    if rc < 0 {
        return Err(format!("{}: no chunk information at {offset:?}", ds.name()).into());
    }
    if size == 0 {
        return Ok(None);
    }
    usize::try_from(size)
        .map(Some)
        .map_err(|_| hdf5::Error::from(format!("{}: chunk of {size} bytes", ds.name())))
}

/// `H5Dread_chunk`: the stored bytes of the chunk at `offset` into `buf`, whose length must
/// be the chunk's stored size (from [`chunk_size`]); returns the chunk's filter mask.
fn read_chunk_raw(ds: &Dataset, offset: &[u64], buf: &mut [u8]) -> hdf5::Result<u32> {
    let id = ds.id();
    let mut mask: u32 = 0;
    let rc = hdf5::sync::sync(|| {
        // SAFETY: `id` is a live dataset handle; `offset` has one entry per dimension;
        // `buf` is exactly the chunk's stored size, which is all HDF5 writes into it (the
        // size was read under the same lock-step use of this handle, and chunk files the
        // reader sees are not rewritten: completed files never, a live file only appends).
        unsafe {
            hdf5_sys::h5d::H5Dread_chunk(
                id,
                hdf5_sys::h5p::H5P_DEFAULT,
                offset.as_ptr(),
                &mut mask,
                buf.as_mut_ptr().cast(),
            )
        }
    });
    if rc < 0 {
        return Err(format!(
            "{}: H5Dread_chunk at {offset:?} ({} bytes) failed",
            ds.name(),
            buf.len()
        )
        .into());
    }
    Ok(mask)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shuffle_matches_hdf5_byte_planes() {
        let src: Vec<u8> = (0..19).collect();
        let mut out = Vec::new();
        shuffle(&src, 4, &mut out);
        assert_eq!(
            out,
            [0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15, 16, 17, 18]
        );
    }

    /// A xorshift64 generator from `seed`: reproducible test bytes without a dependency.
    fn xorshift(mut state: u64) -> impl FnMut() -> u64 {
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        }
    }

    /// Every input, runs or noise, any length, inflates back to itself, and runs shrink.
    #[test]
    fn fixed_rle_streams_inflate_back() {
        let mut rnd = xorshift(0x2545_f491_4f6c_dd1d);
        let mut out = Vec::new();
        let mut back = vec![0u8; 1 << 16];
        for case in 0..3000u32 {
            let len = (rnd() % 1500) as usize;
            let mode = case % 4;
            let data: Vec<u8> = (0..len)
                .map(|i| match mode {
                    0 => rnd() as u8,
                    1 => (rnd() % 3) as u8,
                    2 if (i / 37) % 2 == 0 => 7,
                    2 => rnd() as u8,
                    _ => (i / 300) as u8,
                })
                .collect();
            zlib_fixed_rle(&data, &mut out);
            let (got, rc) =
                zlib_rs::decompress_slice(&mut back, &out, zlib_rs::InflateConfig::default());
            assert_eq!(rc, zlib_rs::ReturnCode::Ok, "case {case}, {len} bytes");
            assert_eq!(got, &data[..], "case {case}, {len} bytes");
            if mode == 3 && len > 0 {
                assert!(
                    out.len() < 40,
                    "runs of 300 should shrink: {} bytes",
                    out.len()
                );
            }
        }
    }

    /// The same rows written through HDF5's own filter pipeline and through direct chunk
    /// writes read back identically, 1-D and N×3, with and without filters.
    #[test]
    fn direct_chunks_read_back_like_the_filter_pipeline() {
        // 20-row chunks take the small-chunk encoder, 200-row ones zlib-rs.
        direct_vs_pipeline(40, 20);
        direct_vs_pipeline(400, 200);
    }

    /// The direct chunk reader gives exactly what HDF5's own read gives: 1-D i64 and N×3
    /// f64, with and without filters, chunks written directly and through the pipeline, a
    /// partial last chunk, fewer valid rows than stored, and reads that split chunks.
    #[test]
    fn column_reader_matches_hdf5_reads() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = hdf5::File::create(dir.path().join("r.h5")).expect("create");
        let rows = 1037usize;
        let chunk = 100usize;
        let times: Vec<i64> = (0..rows as i64)
            .map(|i| 1_000_000 + 6_666_667 * i - (i % 7) * 13)
            .collect();
        let noise: Vec<[f64; 3]> = (0..rows)
            .map(|i| {
                let x = (i as f64 * 0.37).sin() * 1e-3;
                [x, -x * 2.0 + 1e-9 * i as f64, 9.81 + x]
            })
            .collect();
        for level in [0u8, 1, 6] {
            let mut t = file.new_dataset::<i64>();
            if level > 0 {
                t = t.shuffle().deflate(level);
            }
            let t = t
                .chunk(chunk)
                .shape(0..)
                .create(format!("t{level}").as_str())
                .expect("1-D");
            let mut b = file.new_dataset::<f64>();
            if level > 0 {
                b = b.shuffle().deflate(level);
            }
            let g = b
                .chunk((chunk, 3))
                .shape(hdf5::SimpleExtents::new([
                    hdf5::Extent::resizable(0),
                    hdf5::Extent::fixed(3),
                ]))
                .create(format!("g{level}").as_str())
                .expect("2-D");
            t.resize(rows).expect("resize");
            g.resize((rows, 3)).expect("resize");
            let mut enc = ChunkEncoder::new(level);
            // A partial head through the pipeline, then whole chunks directly, then a tail.
            put_rows(&t, &mut enc, chunk, 0, &times[..30]).expect("t head");
            put_rows(&t, &mut enc, chunk, 30, &times[30..]).expect("t rest");
            put_rows(&g, &mut enc, chunk, 0, &noise[..250]).expect("g head");
            put_rows(&g, &mut enc, chunk, 250, &noise[250..]).expect("g rest");
            // Blocks of 73 rows: most of them split a chunk; of 250 and 1037: whole chunks
            // inside a read go to the parallel decoding, the split ones to the cache.
            for (valid, block) in [(rows, 73), (1000, 73), (999, 73), (rows, 250), (999, 1037)] {
                let mut tr = ColumnReader::new(t.clone(), valid, true).expect("t reader");
                let mut gr = ColumnReader::new(g.clone(), valid, true).expect("g reader");
                let mut got_t = Vec::new();
                let mut got_g = [Vec::new(), Vec::new(), Vec::new()];
                let mut start = 0;
                while start < valid {
                    let end = (start + block).min(valid);
                    tr.read_i64(start..end, &mut got_t).expect("read t");
                    let [x, y, z] = &mut got_g;
                    gr.read_f64(start..end, &mut [x, y, z]).expect("read g");
                    start = end;
                }
                let case = format!("level {level}, {valid} rows, blocks of {block}");
                assert_eq!(got_t, times[..valid], "{case}");
                for (axis, column) in got_g.iter().enumerate() {
                    let want: Vec<f64> = noise[..valid].iter().map(|r| r[axis]).collect();
                    assert_eq!(*column, want, "{case}, axis {axis}");
                }
                assert!(tr.read_i64(0..valid + 1, &mut got_t).is_err());
            }
            // The direct path was taken where it could be (a filtered dataset, whole chunks).
            let mut gr = ColumnReader::new(g.clone(), rows, true).expect("g reader");
            assert!(gr.stored.is_some(), "level {level}");
            let mut x = Vec::new();
            let (mut y, mut z) = (Vec::new(), Vec::new());
            gr.read_f64(0..1, &mut [&mut x, &mut y, &mut z])
                .expect("read");
            assert!(gr.read_f64(0..1, &mut [&mut x]).is_err(), "wrong width");
        }
    }

    /// A chunk of noisy f64 keeps its random byte planes in stored blocks (so inflating it
    /// is mostly copying) and still inflates back exactly, with zlib-rs and libdeflate; runs
    /// and patterns still shrink; stored data longer than one block is split.
    #[test]
    fn random_planes_are_stored_and_inflate_back() {
        let mut rnd = xorshift(0x9E37_79B9_7F4A_7C15);
        let noise: Vec<[f64; 3]> = (0..1500)
            .map(|_| std::array::from_fn(|_| (rnd() as f64 / u64::MAX as f64 - 0.5) * 0.05))
            .collect();
        let times: Vec<i64> = (0..1500i64)
            .map(|i| 1_000_000_000 + i * 6_666_667)
            .collect();
        let mut enc = ChunkEncoder::new(1);
        let mut back = vec![0u8; 1 << 17];
        let mut libdeflate = libdeflater::Decompressor::new();
        let mut check = |bytes: &[u8], plain: &[u8], elem: usize| {
            let mut shuffled = Vec::new();
            shuffle(plain, elem, &mut shuffled);
            let (got, rc) =
                zlib_rs::decompress_slice(&mut back, bytes, zlib_rs::InflateConfig::default());
            assert_eq!(rc, zlib_rs::ReturnCode::Ok);
            assert_eq!(got, &shuffled[..]);
            let mut out = vec![0u8; shuffled.len()];
            let n = libdeflate
                .zlib_decompress(bytes, &mut out)
                .expect("libdeflate");
            assert_eq!(&out[..n], &shuffled[..]);
        };
        let mut plain = Vec::new();
        noise.iter().for_each(|v| v.put_le(&mut plain));
        let bytes = enc.encode(&noise).expect("encode").to_vec();
        check(&bytes, &plain, 8);
        // The six low planes of 4500 bytes each are there verbatim as stored blocks.
        let mut shuffled = Vec::new();
        shuffle(&plain, 8, &mut shuffled);
        let n = noise.len() * 3;
        for b in 0..6 {
            let plane = &shuffled[b * n..(b + 1) * n];
            let mut block = vec![0u8];
            block.extend_from_slice(&(n as u16).to_le_bytes());
            block.extend_from_slice(&(!(n as u16)).to_le_bytes());
            block.extend_from_slice(plane);
            assert!(
                bytes.windows(block.len()).any(|w| w == block),
                "plane {b} is not stored"
            );
        }
        assert!(bytes.len() < plain.len(), "{} bytes", bytes.len());
        // Steady time stamps compress well.
        let mut plain_t = Vec::new();
        times.iter().for_each(|v| v.put_le(&mut plain_t));
        let bytes = enc.encode(&times).expect("encode").to_vec();
        check(&bytes, &plain_t, 8);
        assert!(bytes.len() < plain_t.len() / 3, "{} bytes", bytes.len());
        // One plane over the size of a stored block (bytes: elem 1, one plane).
        let big: Vec<u8> = (0..70_000).map(|_| rnd() as u8).collect();
        let bytes = enc.encode(&big).expect("encode").to_vec();
        check(&bytes, &big, 1);
        assert_eq!(bytes.len(), 2 + stored_size(big.len()) + 4);
    }

    /// Unshuffling straight into columns gives what unshuffling into words and scattering
    /// gives: 1, 2 and 3 columns, lengths around the groups of 8 and 24 elements.
    #[test]
    fn unshuffle_into_columns_matches_words() {
        for width in 1..=3usize {
            for rows in 0..40usize {
                let values: Vec<u64> = (0..(rows * width) as u64)
                    .map(|i| (i + 7).wrapping_mul(0x9E37_79B9_7F4A_7C15))
                    .collect();
                let mut plain = Vec::new();
                values.iter().for_each(|v| v.put_le(&mut plain));
                let mut shuffled = Vec::new();
                shuffle(&plain, 8, &mut shuffled);
                let mut cols = vec![vec![0u64; rows]; width];
                unshuffle_into(
                    &shuffled,
                    cols.iter_mut().map(|c| &mut c[..]).collect(),
                    |w| w,
                );
                for (k, col) in cols.iter().enumerate() {
                    let want: Vec<u64> = values.iter().skip(k).step_by(width).copied().collect();
                    assert_eq!(*col, want, "{width} columns, {rows} rows, column {k}");
                }
            }
        }
    }

    #[test]
    fn unshuffle_inverts_shuffle() {
        // Every length around the eight-element groups, including the remainders.
        for len in 0..70u64 {
            let values: Vec<u64> = (0..len)
                .map(|i| (i + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15))
                .collect();
            let mut plain = Vec::new();
            for v in &values {
                v.put_le(&mut plain);
            }
            let mut shuffled = Vec::new();
            shuffle(&plain, 8, &mut shuffled);
            let mut back = Vec::new();
            unshuffle_words(&shuffled, &mut back);
            assert_eq!(back, values, "{len} elements");
        }
    }

    fn direct_vs_pipeline(rows: i64, chunk: usize) {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.h5");
        let file = hdf5::File::create(&path).expect("create");
        let times: Vec<i64> = (0..rows).map(|i| 1_000_000 + 6_666_667 * i).collect();
        let noise: Vec<[f64; 3]> = (0..rows)
            .map(|i| {
                let x = (i as f64 * 0.37).sin() * 1e-3;
                [x, -x * 2.0, 9.81 + x]
            })
            .collect();
        for level in [0u8, 1, 6] {
            let make_1d = |name: &str| {
                let mut b = file.new_dataset::<i64>();
                if level > 0 {
                    b = b.shuffle().deflate(level);
                }
                b.chunk(chunk).shape(0..).create(name).expect("1-D")
            };
            let make_2d = |name: &str| {
                let mut b = file.new_dataset::<f64>();
                if level > 0 {
                    b = b.shuffle().deflate(level);
                }
                b.chunk((chunk, 3))
                    .shape(hdf5::SimpleExtents::new([
                        hdf5::Extent::resizable(0),
                        hdf5::Extent::fixed(3),
                    ]))
                    .create(name)
                    .expect("2-D")
            };
            let (t_pipe, t_direct) = (
                make_1d(&format!("t{level}")),
                make_1d(&format!("td{level}")),
            );
            let (g_pipe, g_direct) = (
                make_2d(&format!("g{level}")),
                make_2d(&format!("gd{level}")),
            );
            t_pipe.resize(rows as usize).expect("resize");
            t_pipe.write(&times).expect("write");
            g_pipe.resize((rows as usize, 3)).expect("resize");
            g_pipe
                .write(ndarray::ArrayView2::from(&noise[..]))
                .expect("write");
            t_direct.resize(rows as usize).expect("resize");
            g_direct.resize((rows as usize, 3)).expect("resize");
            let mut enc = ChunkEncoder::new(level);
            // 7 rows (pipeline), 13 more (pipeline, completes chunk 0), 20 (one direct chunk).
            put_rows(&t_direct, &mut enc, chunk, 0, &times[..7]).expect("1-D head");
            put_rows(&t_direct, &mut enc, chunk, 7, &times[7..]).expect("1-D rest");
            put_rows(&g_direct, &mut enc, chunk, 0, &noise).expect("2-D whole");
            assert_eq!(
                t_direct.read_raw::<i64>().expect("read"),
                t_pipe.read_raw::<i64>().expect("read"),
                "level {level}"
            );
            let g: Vec<f64> = noise.iter().flatten().copied().collect();
            assert_eq!(
                g_direct.read_raw::<f64>().expect("read"),
                g,
                "level {level}"
            );
            assert_eq!(g_pipe.read_raw::<f64>().expect("read"), g, "level {level}");
        }
        // Misaligned requests are refused, not written.
        let ds = file
            .new_dataset::<i64>()
            .chunk(chunk)
            .shape(0..)
            .create("bad")
            .expect("create");
        ds.resize(rows as usize).expect("resize");
        let mut enc = ChunkEncoder::new(1);
        assert!(write_whole_chunks(&ds, &mut enc, chunk, 5, &times[..20]).is_err());
        assert!(write_whole_chunks(&ds, &mut enc, chunk, 0, &times[..25]).is_err());
    }
}
