//! The k-th smallest of many f64 (a median of residuals, every iteration of
//! every pair) selected on integer keys: the same element, in the order of
//! `f64::total_cmp`, for less work per comparison.

/// An integer key whose order is `f64::total_cmp`'s.
#[inline]
pub fn key(x: f64) -> u64 {
    let b = x.to_bits();
    if b >> 63 == 1 {
        !b
    } else {
        b | (1 << 63)
    }
}

/// The value of a [`key`].
#[inline]
pub fn value(k: u64) -> f64 {
    f64::from_bits(if k >> 63 == 1 { k & !(1 << 63) } else { !k })
}

/// The `k`-th smallest (from 0) of the values whose keys are `keys`
/// (reordered); panics when `k` is out of range, as `select_nth_unstable`.
#[inline]
pub fn kth_smallest(keys: &mut [u64], k: usize) -> f64 {
    value(*keys.select_nth_unstable(k).1)
}

/// The `k`-th smallest of `values`.
pub fn kth_of(values: impl Iterator<Item = f64>, k: usize) -> f64 {
    let mut keys: Vec<u64> = values.map(key).collect();
    kth_smallest(&mut keys, k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            any::<f64>(),
            -1e3f64..1e3,
            Just(0.0),
            Just(-0.0),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(f64::NAN),
            Just(-f64::NAN),
        ]
    }

    proptest! {
        /// The same element as `select_nth_unstable_by(total_cmp)`, bit for bit.
        #[test]
        fn selects_as_total_cmp(values in proptest::collection::vec(any_f64(), 1..60), k in 0usize..60) {
            let k = k % values.len();
            let mut plain = values.clone();
            let want = *plain.select_nth_unstable_by(k, f64::total_cmp).1;
            let got = kth_of(values.iter().copied(), k);
            prop_assert_eq!(want.to_bits(), got.to_bits());
        }

        #[test]
        fn keys_round_trip(x in any_f64()) {
            prop_assert_eq!(value(key(x)).to_bits(), x.to_bits());
        }
    }
}
