//! Colour maps: viridis (sequential, for magnitudes such as residuals) and a
//! blue-white-red diverging map (for signed height differences; ColorBrewer
//! RdBu reversed), both by linear interpolation between published anchors.

use super::canvas::Color;

const VIRIDIS: [Color; 9] = [
    [68, 1, 84],
    [71, 45, 123],
    [59, 82, 139],
    [44, 114, 142],
    [33, 145, 140],
    [40, 174, 128],
    [94, 201, 98],
    [173, 220, 48],
    [253, 231, 37],
];

const DIVERGING: [Color; 11] = [
    [5, 48, 97],
    [33, 102, 172],
    [67, 147, 195],
    [146, 197, 222],
    [209, 229, 240],
    [247, 247, 247],
    [253, 219, 199],
    [244, 165, 130],
    [214, 96, 77],
    [178, 24, 43],
    [103, 0, 31],
];

/// A colour map over [0, 1] (values outside are clamped).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorMap {
    Viridis,
    Diverging,
}

impl ColorMap {
    pub fn at(self, t: f64) -> Color {
        let anchors: &[Color] = match self {
            ColorMap::Viridis => &VIRIDIS,
            ColorMap::Diverging => &DIVERGING,
        };
        let t = if t.is_nan() { 0.5 } else { t.clamp(0.0, 1.0) };
        let pos = t * (anchors.len() - 1) as f64;
        let k = (pos.floor() as usize).min(anchors.len() - 2);
        let f = pos - k as f64;
        let (a, b) = (anchors[k], anchors[k + 1]);
        [0, 1, 2].map(|i| (a[i] as f64 + (b[i] as f64 - a[i] as f64) * f).round() as u8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_and_middle() {
        assert_eq!(ColorMap::Viridis.at(0.0), VIRIDIS[0]);
        assert_eq!(ColorMap::Viridis.at(2.0), VIRIDIS[8]);
        assert_eq!(ColorMap::Diverging.at(0.5), [247, 247, 247]);
        assert_eq!(ColorMap::Diverging.at(0.05), [19, 75, 135]);
    }
}
