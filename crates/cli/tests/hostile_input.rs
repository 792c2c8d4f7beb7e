//! Hostile input to the readers of untrusted files (demonstration CSV and NPY
//! files, model files): arbitrary bytes and corrupted versions of real files
//! give an error or a valid result, never a panic or a hang. This is the
//! quick, always-run complement of the coverage-guided fuzz targets in
//! `fuzz/` (`bash fuzz/run.sh`), seeded from the same corpus.

use phasekit_cli::data::{parse_npy, read_csv_from};
use phasekit_cli::model_file::ModelFile;
use phasekit_cli::pipeline::StreamPredictor;
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use std::path::{Path, PathBuf};

fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_f022);
    }
    c.failure_persistence = None;
    c
}

fn corpus(target: &str) -> Vec<Vec<u8>> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fuzz/corpus")
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    let out: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).unwrap()).collect();
    assert!(!out.is_empty(), "empty corpus {}", dir.display());
    out
}

fn check_csv(bytes: &[u8]) {
    if let Ok(t) = read_csv_from(bytes, Path::new("x.csv")) {
        assert_eq!(t.data.len() % t.columns.len(), 0);
        assert!(t.data.iter().all(|v| !v.is_infinite()));
    }
}

fn check_npy(bytes: &[u8]) {
    if let Ok(t) = parse_npy(bytes, Path::new("x.npy")) {
        assert_eq!(t.data.len(), t.n_rows() * t.columns.len());
    }
}

fn check_model(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    if let Ok(m) = ModelFile::from_json(text, Path::new("x.json")) {
        if let Ok(mut s) = StreamPredictor::new(&m) {
            let n = s.n_in();
            let _ = s.step(&vec![0.0; n], true);
            let _ = s.step(&vec![f64::NAN; n], true);
        }
    }
}

/// A corrupted copy of `base`: `edits` bytes overwritten, then cut at `cut`.
fn corrupt(base: &[u8], edits: &[(usize, u8)], cut: usize) -> Vec<u8> {
    let mut v = base.to_vec();
    for &(i, b) in edits {
        if !v.is_empty() {
            let k = i % v.len();
            v[k] = b;
        }
    }
    v.truncate(cut % (v.len() + 1));
    v
}

proptest! {
    #![proptest_config(config(256))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        check_csv(&bytes);
        check_npy(&bytes);
        check_model(&bytes);
        // Behind a valid NPY magic and header length, the header parser sees them.
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        npy.extend((bytes.len() as u16).to_le_bytes());
        npy.extend(&bytes);
        check_npy(&npy);
    }

    #[test]
    fn corrupted_real_files_never_panic(
        pick in any::<usize>(),
        edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..8),
        cut in any::<usize>(),
    ) {
        let csv = corpus("csv_reader");
        check_csv(&corrupt(&csv[pick % csv.len()], &edits, cut));
        let npy = corpus("npy_reader");
        check_npy(&corrupt(&npy[pick % npy.len()], &edits, cut));
        let model = corpus("model_file");
        check_model(&corrupt(&model[pick % model.len()], &edits, cut));
    }
}

fn corpus_named(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fuzz/corpus")
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
        .iter()
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(p).unwrap(),
            )
        })
        .collect()
}

#[test]
fn the_seed_corpus_reads_as_expected() {
    // Which seeds are valid files and which are refused.
    let csv_ok = [
        "demo.csv",
        "missing.csv",
        "nuisi_head.csv",
        "quoted_bom.csv",
    ];
    for (name, f) in corpus_named("csv_reader") {
        check_csv(&f);
        let ok = read_csv_from(&f[..], Path::new(&name)).is_ok();
        assert_eq!(ok, csv_ok.contains(&name.as_str()), "{name}");
    }
    let npy_ok = ["f4_fortran.npy", "f8_c.npy"];
    for (name, f) in corpus_named("npy_reader") {
        check_npy(&f);
        let ok = parse_npy(&f, Path::new(&name)).is_ok();
        assert_eq!(ok, npy_ok.contains(&name.as_str()), "{name}");
    }
    let missing = corpus_named("csv_reader")
        .into_iter()
        .find(|(n, _)| n == "missing.csv")
        .unwrap()
        .1;
    let m = read_csv_from(&missing[..], Path::new("missing.csv")).unwrap();
    assert_eq!(
        m.data.iter().filter(|v| v.is_nan()).count(),
        3,
        "empty, NaN and NA are missing"
    );
    // Every committed model file loads and predicts.
    for f in corpus("model_file") {
        let m =
            ModelFile::from_json(std::str::from_utf8(&f).unwrap(), Path::new("m.json")).unwrap();
        let mut s = StreamPredictor::new(&m).unwrap();
        let n = s.n_in();
        let (mean, _) = s.step(&vec![0.0; n], false).unwrap();
        assert!(mean.iter().all(|v| v.is_finite()));
        // Hostile values: finite predictions, every frame judged, none failing.
        for v in [1e200, -1e308, f64::MAX, 1e-300, f64::NAN, 0.0] {
            let (mean, cov) = s.step(&vec![v; n], true).unwrap();
            assert!(
                mean.iter().chain(cov.unwrap()).all(|x| x.is_finite()),
                "{v}"
            );
        }
        assert!(
            s.step(&vec![0.0; n + 1], false).is_err(),
            "a frame of the wrong length"
        );
    }
}

#[test]
fn truncated_or_retyped_model_files_are_refused_with_a_reason() {
    let text = String::from_utf8(corpus("model_file").remove(0)).unwrap();
    for cut in (0..text.len()).step_by(997) {
        let err = ModelFile::from_json(&text[..cut], Path::new("m.json"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("m.json") && err.contains("truncated"), "{err}");
    }
    let other = text.replacen("\"version\": 1", "\"version\": 99", 1);
    assert_ne!(
        other, text,
        "the corpus model file should hold \"version\": 1"
    );
    let err = ModelFile::from_json(&other, Path::new("m.json"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("version 99 is not supported"), "{err}");
    let nan = text.replacen("\"covariances\": [", "\"covariances\": [-1.0, ", 1);
    let err = ModelFile::from_json(&nan, Path::new("m.json"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("corrupted model file"), "{err}");
}
