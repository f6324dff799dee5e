//! Proptest strategies shared by the property tests (`tests/*_props.rs`).

use proptest::prelude::*;

/// A coordinate, m: mostly in −15..90 (the window and around it), sometimes NaN, ±∞, `f32::MAX`
/// or the subnormal `tiny`.
pub fn coord(tiny: f32) -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -15.0f32..90.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
        1 => Just(f32::MAX),
        1 => Just(tiny),
    ]
}
