//! Arbitrary bytes as a demonstration CSV file: a located error or a table
//! whose every value is finite or missing, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use phasekit_cli::data::read_csv_from;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(table) = read_csv_from(data, Path::new("fuzz.csv")) {
        assert!(!table.columns.is_empty());
        assert_eq!(table.data.len() % table.columns.len(), 0);
        assert!(table.data.iter().all(|v| !v.is_infinite()));
    }
});
