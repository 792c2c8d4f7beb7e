//! `phasekit plot`: reads the model and the demonstrations, draws with [`crate::plot`].

use super::{data_files, read_tables};
use crate::cli::{PlotArgs, PlotKind, View};
use crate::data::read_table;
use crate::error::Result;
use crate::model_file::ModelFile;
use crate::output;
use crate::plot::{
    default_plane, default_xyz, feature_index, prediction_svg, segmentation_svg,
    states_svg_projected, Projection,
};

/// Runs `phasekit plot …`.
pub fn run(a: &PlotArgs) -> Result<()> {
    match &a.kind {
        PlotKind::Segmentation(p) | PlotKind::Prediction(p) => {
            let unit = p.unit.resolve()?;
            let mf = ModelFile::load(&p.model)?;
            let table = read_table(&p.data)?;
            let svg = match &a.kind {
                PlotKind::Segmentation(_) => segmentation_svg(&mf, &table, &unit)?,
                _ => prediction_svg(&mf, &table, &unit)?,
            };
            output::write_string(&p.output, &svg)
        }
        PlotKind::Recognition(p) => super::recognise::plot(p),
        PlotKind::States(p) => {
            let unit = p.unit.resolve()?;
            let mf = ModelFile::load(&p.model)?;
            let tables = read_tables(&data_files(&p.data)?, false)?;
            let pick = |name: &Option<String>, default: usize| {
                name.as_deref()
                    .map(|n| feature_index(&mf, n))
                    .transpose()
                    .map(|k| k.unwrap_or(default))
            };
            let projection = match p.view {
                View::TwoD => {
                    let [dx, dy] = default_plane(&mf);
                    if p.z.is_some() {
                        crate::bail!("--z needs --view 3d");
                    }
                    Projection::plane(pick(&p.x, dx)?, pick(&p.y, dy)?)
                }
                View::ThreeD => {
                    let defaults = default_xyz(&mf);
                    let need = |name: &Option<String>, axis: usize, flag: &str| {
                        match (name, defaults) {
                        (Some(_), _) => pick(name, 0),
                        (None, Some(d)) => Ok(d[axis]),
                        (None, None) => Err(crate::CliError::new(format!(
                            "the robot has no x, y, z position columns: name the 3-D view's features with --x, --y and --z (missing {flag})"
                        ))),
                    }
                    };
                    Projection::oblique(
                        need(&p.x, 0, "--x")?,
                        need(&p.y, 1, "--y")?,
                        need(&p.z, 2, "--z")?,
                    )
                }
            };
            let mut seen = Vec::new();
            for &k in &projection.dims {
                if seen.contains(&k) {
                    crate::bail!(
                        "the axes name the same feature `{}` twice",
                        mf.layout.features[k]
                    );
                }
                seen.push(k);
            }
            let svg = states_svg_projected(&mf, &tables, &projection, &unit)?;
            output::write_string(&p.output, &svg)
        }
    }
}
