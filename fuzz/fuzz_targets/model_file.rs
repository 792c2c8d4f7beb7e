//! Arbitrary text as a model file: refused with a message, or a model that
//! is consistent enough to predict a frame without panicking.
#![no_main]
use libfuzzer_sys::fuzz_target;
use phasekit_cli::model_file::ModelFile;
use phasekit_cli::pipeline::StreamPredictor;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(model) = ModelFile::from_json(text, Path::new("fuzz.json")) else {
        return;
    };
    if let Ok(mut online) = StreamPredictor::new(&model) {
        let frame = vec![0.0; online.n_in()];
        let _ = online.step(&frame, true);
        let missing = vec![f64::NAN; online.n_in()];
        let _ = online.step(&missing, true);
    }
});
