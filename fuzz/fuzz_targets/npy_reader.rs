//! Arbitrary bytes as an NPY file: a clear error or a 2-D table, never a
//! panic, and no allocation beyond what the bytes can hold (libFuzzer's
//! `-rss_limit_mb` and `-malloc_limit_mb` catch a header that claims a huge shape).
#![no_main]
use libfuzzer_sys::fuzz_target;
use phasekit_cli::data::parse_npy;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(table) = parse_npy(data, Path::new("fuzz.npy")) {
        assert_eq!(table.data.len(), table.n_rows() * table.columns.len());
        assert!(table.data.len() * 4 <= data.len());
    }
});
