//! The unit reported numbers are in, and how numbers are printed.
//!
//! Demonstrations carry no unit. phasekit assumes positions in metres (NuiSI)
//! and reports lengths in centimetres, as the paper does: a factor 100 from
//! data units. `--unit NAME` and `--unit-scale X` say otherwise, for the
//! evaluate table and the plots alike (`--unit rad --unit-scale 1` for joint
//! angles in radians; `--unit-scale 1` alone: the data's own units).

use crate::bail;
use crate::error::Result;
use clap::Args;

/// Lengths whose factor from metres is known: `--unit NAME` alone sets the scale.
const LENGTHS_FROM_METRES: [(&str, f64); 3] = [("m", 1.0), ("cm", 100.0), ("mm", 1000.0)];

/// The factor of the default unit (centimetres from metres).
pub const DEFAULT_SCALE: f64 = 100.0;

/// `--unit` and `--unit-scale`, shared by `evaluate` and `plot`.
#[derive(Debug, Clone, Default, Args)]
pub struct UnitArgs {
    /// Name of the reported unit: m, cm or mm set the factor from metres; any other name
    /// (e.g. rad) needs --unit-scale [default: cm, or "data units" with --unit-scale 1]
    #[arg(long, value_name = "NAME")]
    pub unit: Option<String>,
    /// Factor from data units to reported units (100: metres → cm, MSE in cm²) [default: 100]
    #[arg(long, value_name = "X")]
    pub unit_scale: Option<f64>,
}

/// A reported unit: values in data units times `scale` are in `name`.
#[derive(Debug, Clone, PartialEq)]
pub struct Unit {
    /// Its name (`cm`, `rad`, `data units`, …).
    pub name: String,
    /// Factor from data units.
    pub scale: f64,
}

impl Default for Unit {
    /// Centimetres from metres.
    fn default() -> Self {
        Unit {
            name: "cm".into(),
            scale: DEFAULT_SCALE,
        }
    }
}

impl Unit {
    /// The unit a factor from data units gives when no name is given: cm and mm
    /// for data in metres (factors 100 and 1000), the data's own units for 1.
    pub fn from_scale(scale: f64) -> Self {
        let name = match LENGTHS_FROM_METRES
            .iter()
            .find(|(n, s)| *s == scale && *n != "m")
        {
            Some((n, _)) => (*n).to_string(),
            None if scale == 1.0 => "data units".to_string(),
            None => format!("data units × {}", num(scale)),
        };
        Unit { name, scale }
    }

    /// `name²`, parenthesised when the name is more than one word.
    pub fn squared(&self) -> String {
        if self.name.chars().all(char::is_alphanumeric) {
            format!("{}²", self.name)
        } else {
            format!("({})²", self.name)
        }
    }
}

impl UnitArgs {
    /// The unit asked for: checks the factor and that a name without a known
    /// factor comes with one.
    pub fn resolve(&self) -> Result<Unit> {
        if let Some(x) = self.unit_scale {
            if !(x.is_finite() && x > 0.0) {
                bail!("--unit-scale must be a positive number, not {x}");
            }
        }
        let Some(name) = self.unit.as_deref().map(str::trim) else {
            return Ok(Unit::from_scale(self.unit_scale.unwrap_or(DEFAULT_SCALE)));
        };
        if name.is_empty() {
            bail!("--unit: empty name");
        }
        let known = LENGTHS_FROM_METRES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, s)| *s);
        let scale = match (self.unit_scale, known) {
            (Some(x), _) => x,
            (None, Some(x)) => x,
            (None, None) => bail!(
                "--unit {name}: give --unit-scale too, the factor from the data's units to {name} \
                 (1 if the data are in {name}); only m, cm and mm have a known factor (from metres)"
            ),
        };
        Ok(Unit {
            name: name.to_string(),
            scale,
        })
    }
}

/// Decimals that show at least four significant digits of `x`, and at least two.
fn decimals(x: f64) -> usize {
    if x == 0.0 || !x.is_finite() {
        return 2;
    }
    (3 - x.abs().log10().floor() as i64).max(2) as usize
}

/// Whether `x` is printed in scientific notation (too large or too small for decimals).
fn scientific(x: f64) -> bool {
    x != 0.0 && x.is_finite() && !(1e-4..1e9).contains(&x.abs())
}

/// `x` with at least four significant digits whatever its magnitude (`0.004312`,
/// `59.06`, `633.74`, `1.235e-7`); `–` when it is not finite. Never `-0.00`.
pub fn sig4(x: f64) -> String {
    if !x.is_finite() {
        return "–".into();
    }
    if scientific(x) {
        return format!("{x:.3e}");
    }
    let s = format!("{:.*}", decimals(x), x);
    if s.starts_with('-') && s.trim_start_matches(['-', '0', '.']).is_empty() {
        s[1..].to_string()
    } else {
        s
    }
}

/// `mean ± std`, both with the decimals that give the mean four significant digits
/// (`59.06 ± 5.90`, `0.004312 ± 0.000913`); the mean alone when `with_std` is false.
pub fn mean_pm(mean: f64, std: f64, with_std: bool) -> String {
    if !mean.is_finite() {
        return "–".into();
    }
    if !with_std {
        return sig4(mean);
    }
    if scientific(mean) {
        return format!("{mean:.3e} ± {std:.1e}");
    }
    let k = decimals(mean);
    format!("{} ± {}", sig4_with(mean, k), sig4_with(std, k))
}

fn sig4_with(x: f64, k: usize) -> String {
    let s = format!("{x:.k$}");
    if s.starts_with('-') && s.trim_start_matches(['-', '0', '.']).is_empty() {
        s[1..].to_string()
    } else {
        s
    }
}

/// A factor as a short number (`100`, `0.5`, `1e-6`).
fn num(x: f64) -> String {
    let s = format!("{x}");
    if s.len() > 8 {
        format!("{x:e}")
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_significant_digits_whatever_the_magnitude() {
        assert_eq!(sig4(0.0043123), "0.004312");
        assert_eq!(sig4(0.43123), "0.4312");
        assert_eq!(sig4(5.9), "5.900");
        assert_eq!(sig4(59.0612), "59.06");
        assert_eq!(sig4(633.744), "633.74");
        assert_eq!(sig4(1082.67), "1082.67");
        assert_eq!(sig4(1.2346e-7), "1.235e-7");
        assert_eq!(sig4(3.1e12), "3.100e12");
        assert_eq!(sig4(0.0), "0.00");
        assert_eq!(sig4(-0.0001), "-0.0001000");
        assert_eq!(sig4(-1e-12), "-1.000e-12");
        assert_eq!(sig4(f64::INFINITY), "–");
        assert_eq!(mean_pm(59.061, 5.9012, true), "59.06 ± 5.90");
        assert_eq!(mean_pm(0.43123, 0.0912, true), "0.4312 ± 0.0912");
        assert_eq!(mean_pm(7.681, 0.38, true), "7.681 ± 0.380");
        assert_eq!(mean_pm(167.91, 11.92, true), "167.91 ± 11.92");
        assert_eq!(mean_pm(f64::NAN, 1.0, true), "–");
        assert_eq!(mean_pm(12.5, 0.0, false), "12.50");
    }

    #[test]
    fn the_printed_digits_of_two_decimals_are_kept() {
        // The tables printed two decimals before: every such digit is still printed.
        for x in [0.5, 3.89, 15.12, 59.06, 319.83, 1082.67, 12345.678] {
            let two = format!("{x:.2}");
            assert!(sig4(x).starts_with(&two), "{x}: {} vs {two}", sig4(x));
        }
    }

    #[test]
    fn units_from_names_and_factors() {
        let r = |unit: Option<&str>, scale: Option<f64>| {
            UnitArgs {
                unit: unit.map(str::to_string),
                unit_scale: scale,
            }
            .resolve()
        };
        assert_eq!(r(None, None).unwrap(), Unit::default());
        assert_eq!(r(None, Some(1000.0)).unwrap().name, "mm");
        assert_eq!(r(None, Some(1.0)).unwrap().name, "data units");
        assert_eq!(r(None, Some(1.0)).unwrap().squared(), "(data units)²");
        assert_eq!(r(None, Some(0.5)).unwrap().name, "data units × 0.5");
        assert_eq!(r(Some("mm"), None).unwrap().scale, 1000.0);
        assert_eq!(r(Some("m"), None).unwrap().scale, 1.0);
        let rad = r(Some("rad"), Some(1.0)).unwrap();
        assert_eq!((rad.name.as_str(), rad.scale), ("rad", 1.0));
        assert_eq!(rad.squared(), "rad²");
        // Data already in cm, reported in cm.
        assert_eq!(r(Some("cm"), Some(1.0)).unwrap().scale, 1.0);
        assert!(r(Some("rad"), None).is_err());
        assert!(r(None, Some(0.0)).is_err());
        assert!(r(None, Some(f64::INFINITY)).is_err());
        assert!(r(Some(" "), Some(1.0)).is_err());
    }
}
