//! Where a chunk file's bytes go, for the tests that bound its dead space (the store's own
//! and the simulator's).

use std::path::Path;

/// A chunk file's size, and the bytes of it outside every dataset's chunks: HDF5 metadata
/// plus space no live object uses (dead copies of rewritten chunks; what `h5stat -S` calls
/// unaccounted).
pub fn bytes_outside_chunks(file: &Path) -> (u64, u64) {
    fn raw(g: &hdf5::Group) -> u64 {
        let own: u64 = g.datasets().unwrap().iter().map(|d| d.storage_size()).sum();
        own + g.groups().unwrap().iter().map(raw).sum::<u64>()
    }
    let size = std::fs::metadata(file).unwrap().len();
    let f = hdf5::File::open(file).unwrap();
    (size, size - raw(&f))
}
