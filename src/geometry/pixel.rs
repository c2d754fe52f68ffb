//! Pixel-coordinate arithmetic for the hot sampling loops (crops, the contour refiner's
//! lines): the baseline x86-64 target has no rounding instruction, so `f64::floor` is a
//! libm call per sample there.

/// `x.floor() as i64`, without the call; saturates as the cast does, so a coordinate far
/// outside an image stays outside.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floors_like_the_library() {
        for x in [-2.5, -1.0, -0.5, -1e-12, 0.0, 0.3, 1.0, 2.7, 1e9 + 0.5, -1e9 - 0.5] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
        assert_eq!((floor_i64(-1e30), floor_i64(1e30)), (i64::MIN, i64::MAX));
    }
}
