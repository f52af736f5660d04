//! Command-line values with a unit: parsed once, refused with the text and the unit.

/// A positive length in µm.
pub fn positive_um(text: &str) -> Result<f64, String> {
    positive(text, "µm")
}

/// A positive length in mm.
pub fn positive_mm(text: &str) -> Result<f64, String> {
    positive(text, "mm")
}

fn positive(text: &str, unit: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("{text:?} is not a positive size in {unit}")),
    }
}
