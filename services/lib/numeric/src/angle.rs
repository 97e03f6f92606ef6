//! Angle wrapping, shared by the heading tracker (thesis §4.1.1), fusion and the renderer's
//! checks. Degrees throughout (`docs/conventions.md`).

/// Wraps an angle into (−half, half] for a period of `2·half` (cheap for the few turns the
/// tracker meets; exact remainder beyond).
#[inline]
pub fn wrap(d: f64, half: f64) -> f64 {
    let period = 2.0 * half;
    let mut w = if d.abs() > 4.0 * period {
        d % period
    } else {
        d
    };
    while w > half {
        w -= period;
    }
    while w <= -half {
        w += period;
    }
    w
}

/// Wraps an angle difference into (−90, 90].
pub fn wrap_half_turn_deg(d: f64) -> f64 {
    wrap(d, 90.0)
}

/// Wraps an angle difference into (−180, 180].
pub fn wrap_turn_deg(d: f64) -> f64 {
    wrap(d, 180.0)
}
