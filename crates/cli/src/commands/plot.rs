//! `phasekit plot`.

use super::{data_files, read_tables};
use crate::cli::{PlotArgs, PlotKind};
use crate::data::read_table;
use crate::error::Result;
use crate::model_file::ModelFile;
use crate::output;
use crate::plot::{default_plane, feature_index, prediction_svg, segmentation_svg, states_svg};

/// Runs `phasekit plot …`.
pub fn run(a: &PlotArgs) -> Result<()> {
    match &a.kind {
        PlotKind::Segmentation(p) | PlotKind::Prediction(p) => {
            let mf = ModelFile::load(&p.model)?;
            let table = read_table(&p.data)?;
            let svg = match &a.kind {
                PlotKind::Segmentation(_) => segmentation_svg(&mf, &table)?,
                _ => prediction_svg(&mf, &table)?,
            };
            output::write_string(&p.output, &svg)
        }
        PlotKind::States(p) => {
            let mf = ModelFile::load(&p.model)?;
            let tables = read_tables(&data_files(&p.data)?, false)?;
            let [dx, dy] = default_plane(&mf);
            let x =
                p.x.as_deref()
                    .map(|n| feature_index(&mf, n))
                    .transpose()?
                    .unwrap_or(dx);
            let y =
                p.y.as_deref()
                    .map(|n| feature_index(&mf, n))
                    .transpose()?
                    .unwrap_or(dy);
            if x == y {
                crate::bail!(
                    "--x and --y name the same feature `{}`",
                    mf.layout.features[x]
                );
            }
            let svg = states_svg(&mf, &tables, [x, y])?;
            output::write_string(&p.output, &svg)
        }
    }
}
