//! Errors for bad slab parameters and failed solves.

/// Why a model could not be built or evaluated.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SppError {
    /// A parameter is outside its valid range (the message says which and why).
    #[error("invalid parameter {name} = {value}: {reason}")]
    InvalidParameter {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    /// A linear solve of the discrete-ordinates boundary problem failed (singular system).
    #[error("discrete-ordinates solve failed: {0}")]
    Solve(&'static str),
}

/// Checks that `value` is finite and inside `[lo, hi]` (closed bounds unless told).
pub(crate) fn check_range(
    name: &'static str,
    value: f64,
    lo: f64,
    hi: f64,
    reason: &'static str,
) -> Result<(), SppError> {
    if value.is_nan() || value < lo || value > hi {
        return Err(SppError::InvalidParameter {
            name,
            value,
            reason,
        });
    }
    Ok(())
}
