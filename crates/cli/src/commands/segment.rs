//! `phasekit segment`.

use super::{data_files, read_tables};
use crate::bail;
use crate::cli::{Format, SegmentArgs};
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use crate::output::{self, csv_field};
use crate::pipeline::segment_table;
use phasekit_tsc::Segmentation;
use serde::Serialize;

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

/// Runs `phasekit segment`.
pub fn run(a: &SegmentArgs) -> Result<()> {
    let format = if a.json { Format::Json } else { a.format };
    if format == Format::Md {
        bail!("segment writes csv or json, not md");
    }
    let mf = ModelFile::load(&a.model)?;
    let tables = read_tables(&data_files(&a.data)?, false)?;
    let segs = tables
        .iter()
        .map(|t| segment_table(&mf, t))
        .collect::<Result<Vec<_>>>()?;
    let text = match format {
        Format::Json => {
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
            serde_json::to_string_pretty(&v).map_err(|e| CliError::new(e.to_string()))? + "\n"
        }
        _ => {
            let mut s = String::from("file,frame,state,transition,cluster\n");
            for (t, seg) in tables.iter().zip(&segs) {
                csv_rows(&t.path.display().to_string(), seg, &mut s);
            }
            s
        }
    };
    match &a.output {
        Some(p) => output::write_string(p, &text),
        None => output::print_stdout(&text),
    }
}
