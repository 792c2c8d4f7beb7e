//! `phasekit segment`.

use super::data_files;
use super::predict::frame_list;
use crate::cli::{DataFormat, SegmentArgs};
use crate::data::Select;
use crate::error::{CliError, Result};
use crate::inputs::read_tables_select;
use crate::model_file::ModelFile;
use crate::output::{self, csv_field};
use crate::pipeline::segment_table_checked;
use phasekit_tsc::Segmentation;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// One demonstration's segmentation, as `--format json` writes it.
#[derive(Debug, Serialize)]
pub struct FileSegmentation {
    /// The file.
    pub file: String,
    /// Its number of frames.
    pub frames: usize,
    /// State of every frame.
    pub states: Vec<usize>,
    /// Transition frames, in order.
    pub transitions: Vec<usize>,
    /// Cluster of every transition frame (`null` when none).
    pub clusters: Vec<Option<usize>>,
}

/// CSV rows `file,frame,state,transition,cluster` of one segmentation.
pub fn csv_rows(file: &str, seg: &Segmentation, out: &mut String) {
    let mut cluster_at: Vec<Option<Option<usize>>> = vec![None; seg.labels.len()];
    for (i, &t) in seg.transitions.iter().enumerate() {
        if t < cluster_at.len() {
            cluster_at[t] = Some(seg.clusters.get(i).copied().flatten());
        }
    }
    let f = csv_field(file);
    for (t, s) in seg.labels.iter().enumerate() {
        let (flag, cluster) = match cluster_at[t] {
            Some(c) => (1, c.map_or(String::new(), |c| c.to_string())),
            None => (0, String::new()),
        };
        out.push_str(&format!("{f},{t},{s},{flag},{cluster}\n"));
    }
}

/// The NPY bytes of segmentations: rows `file, frame, state, transition,
/// cluster` with `file` the index of the input and a missing cluster NaN.
pub fn segmentation_npy(segs: &[Segmentation]) -> Vec<u8> {
    let mut data = Vec::new();
    for (i, seg) in segs.iter().enumerate() {
        let mut cluster_at: Vec<Option<Option<usize>>> = vec![None; seg.labels.len()];
        for (k, &t) in seg.transitions.iter().enumerate() {
            if t < cluster_at.len() {
                cluster_at[t] = Some(seg.clusters.get(k).copied().flatten());
            }
        }
        for (t, s) in seg.labels.iter().enumerate() {
            let (flag, cluster) = match cluster_at[t] {
                Some(c) => (1.0, c.map_or(f64::NAN, |c| c as f64)),
                None => (0.0, f64::NAN),
            };
            data.extend_from_slice(&[i as f64, t as f64, *s as f64, flag, cluster]);
        }
    }
    crate::npy::write(data.len() / 5, 5, &data)
}

/// Runs `phasekit segment`.
pub fn run(a: &SegmentArgs) -> Result<()> {
    let format = output::data_format(a.format, a.json, a.output.as_deref(), false)?;
    let files = data_files(&a.data)?;
    let inputs: Vec<&Path> = std::iter::once(a.model.as_path())
        .chain(files.iter().map(PathBuf::as_path))
        .collect();
    if let Some(o) = &a.output {
        output::refuse_inputs(&[o.as_path()], &inputs)?;
    }
    let mf = ModelFile::load(&a.model)?;
    // Only the model's columns are read: others (a timestamp, a label) do not matter.
    let needed = [
        mf.layout.human_columns.clone(),
        mf.layout.robot_columns.clone(),
    ]
    .concat();
    let side: Vec<&str> = (0..needed.len())
        .map(|i| {
            if i < mf.layout.human_columns.len() {
                "human's"
            } else {
                "robot's"
            }
        })
        .collect();
    let tables = read_tables_select(
        &files,
        false,
        Select::Names {
            names: &needed,
            side: &side,
        },
    )?;
    let mut segs = Vec::with_capacity(tables.len());
    for t in &tables {
        let (seg, rejected) = segment_table_checked(&mf, t)?;
        if !rejected.is_empty() {
            eprintln!(
                "phasekit: warning: {}: frame{} {} {} density zero under every state of the model (a value far outside the training range, e.g. 1e200): taken as not observed",
                t.path.display(),
                if rejected.len() == 1 { "" } else { "s" },
                frame_list(&rejected),
                if rejected.len() == 1 { "has" } else { "have" },
            );
        }
        segs.push(seg);
    }
    let bytes = match format {
        DataFormat::Json => {
            let v: Vec<FileSegmentation> = tables
                .iter()
                .zip(segs)
                .map(|(t, s)| FileSegmentation {
                    file: t.path.display().to_string(),
                    frames: t.n_rows(),
                    states: s.labels,
                    transitions: s.transitions,
                    clusters: s.clusters,
                })
                .collect();
            (serde_json::to_string_pretty(&v).map_err(|e| CliError::new(e.to_string()))? + "\n")
                .into_bytes()
        }
        DataFormat::Npy => segmentation_npy(&segs),
        DataFormat::Csv => {
            let mut s = String::from("file,frame,state,transition,cluster\n");
            for (t, seg) in tables.iter().zip(&segs) {
                csv_rows(&t.path.display().to_string(), seg, &mut s);
            }
            s.into_bytes()
        }
    };
    output::write_bytes(a.output.as_deref().unwrap_or(Path::new("-")), &bytes)
}
