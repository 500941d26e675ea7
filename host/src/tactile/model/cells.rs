//! Bilinear placement shared by the models: a value's two neighbouring entries along an
//! axis, and a position's four neighbouring cells on a grid of cell centres (the lookup
//! table's colour axes and position gains, the light model's response per cell), and
//! a value at every pixel of a frame at the positions the models are given.

/// Bilinear position along an axis of `n` entries: `(index, fraction)`.
#[inline]
pub(super) fn locate(v: f32, n: usize) -> (usize, f32) {
    if n <= 1 {
        return (0, 0.0);
    }
    // NaN compares false everywhere: map it to the first entry.
    let v = if v.is_nan() {
        0.0
    } else {
        v.clamp(0.0, (n - 1) as f32)
    };
    // A table's entries and a model's cells number far below 2³²: through `u32` both
    // conversions are single instructions on x86-64 (a full `usize` one branches on its
    // top bit). The same index and fraction either way.
    if n <= u32::MAX as usize {
        let i = (v as u32).min((n - 2) as u32);
        (i as usize, v - i as f32)
    } else {
        let i = (v as usize).min(n - 2);
        (i, v - i as f32)
    }
}

/// The four bilinear neighbours `(index, weight)` of `(x, y)` ∈ [0, 1]² on a grid of
/// cell centres.
#[inline]
pub(super) fn cell_weights(x: f32, y: f32, cells_x: usize, cells_y: usize) -> [(usize, f32); 4] {
    let (cx, fx) = locate(x * cells_x as f32 - 0.5, cells_x);
    let (cy, fy) = locate(y * cells_y as f32 - 0.5, cells_y);
    let cxn = (cx + 1).min(cells_x - 1);
    let cyn = (cy + 1).min(cells_y - 1);
    [
        (cy * cells_x + cx, (1.0 - fx) * (1.0 - fy)),
        (cy * cells_x + cxn, fx * (1.0 - fy)),
        (cyn * cells_x + cx, (1.0 - fx) * fy),
        (cyn * cells_x + cxn, fx * fy),
    ]
}

/// `at(x / width, y / height)` at every pixel of a `width × height` frame, row by row: a
/// model's value per pixel at the positions reconstruction gives the models, made once
/// so the hot loops do not blend per pixel.
pub(super) fn frame_plane<T>(width: usize, height: usize, at: impl Fn(f32, f32) -> T) -> Vec<T> {
    let (inv_w, inv_h) = (1.0 / width.max(1) as f32, 1.0 / height.max(1) as f32);
    let mut plane = Vec::with_capacity(width * height);
    for y in 0..height {
        let yn = y as f32 * inv_h;
        plane.extend((0..width).map(|x| at(x as f32 * inv_w, yn)));
    }
    plane
}

#[cfg(test)]
mod tests {
    use super::locate;

    /// Through `u32` the index and fraction are the full-width conversion's: at, between
    /// and past the entries, for NaN and the infinities, on small and huge axes.
    #[test]
    fn located_as_the_full_width_conversion_places_it() {
        let wide = |v: f32, n: usize| {
            let v = if v.is_nan() {
                0.0
            } else {
                v.clamp(0.0, (n - 1) as f32)
            };
            let i = (v as usize).min(n - 2);
            (i, v - i as f32)
        };
        let values = [
            -1.0,
            -0.0,
            0.0,
            0.25,
            1.0,
            2.5,
            62.999,
            63.0,
            64.0,
            1e6,
            4.3e9,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for n in [2usize, 3, 64, 1 << 20, u32::MAX as usize] {
            for v in values {
                let (got, want) = (locate(v, n), wide(v, n));
                assert_eq!(
                    (got.0, got.1.to_bits()),
                    (want.0, want.1.to_bits()),
                    "{v} of {n}"
                );
            }
        }
        assert_eq!(locate(5.0, 1), (0, 0.0));
        assert_eq!(locate(5.0, 0), (0, 0.0));
    }
}
