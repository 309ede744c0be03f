//! Axis-aligned boxes in CRS coordinates (raster extents, footprints, overlaps):
//! one type with named edges instead of `[min_x, min_y, max_x, max_y]` arrays, and
//! the box algebra (intersection, union, overlap test) written once.
//!
//! On disk a box stays the array `[min_x, min_y, max_x, max_y]` (serde converts).

use serde::{Deserialize, Serialize};

/// A box [min_x, max_x] x [min_y, max_y] in CRS units (metres for a projected CRS).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "[f64; 4]", into = "[f64; 4]")]
pub struct Bounds {
    pub min_x: f64,
    pub min_y: f64,
    pub max_x: f64,
    pub max_y: f64,
}

impl Bounds {
    /// The box spanned by two opposite corners, in any order.
    pub fn from_corners(a: (f64, f64), b: (f64, f64)) -> Self {
        Bounds {
            min_x: a.0.min(b.0),
            min_y: a.1.min(b.1),
            max_x: a.0.max(b.0),
            max_y: a.1.max(b.1),
        }
    }

    /// `[min_x, min_y, max_x, max_y]`.
    pub fn to_array(self) -> [f64; 4] {
        [self.min_x, self.min_y, self.max_x, self.max_y]
    }

    pub fn width(&self) -> f64 {
        self.max_x - self.min_x
    }

    pub fn height(&self) -> f64 {
        self.max_y - self.min_y
    }

    /// The centre (x, y).
    pub fn centre(&self) -> (f64, f64) {
        (
            (self.min_x + self.max_x) / 2.0,
            (self.min_y + self.max_y) / 2.0,
        )
    }

    /// Half the diagonal: the lever arm of a rotation about the centre, metres.
    pub fn half_diagonal(&self) -> f64 {
        0.5 * (self.width().powi(2) + self.height().powi(2)).sqrt()
    }

    /// The common box, even when empty (then min > max on some axis; see
    /// [`intersection`](Self::intersection) for the checked form).
    pub fn clip(&self, other: &Bounds) -> Bounds {
        Bounds {
            min_x: self.min_x.max(other.min_x),
            min_y: self.min_y.max(other.min_y),
            max_x: self.max_x.min(other.max_x),
            max_y: self.max_y.min(other.max_y),
        }
    }

    /// The common box when it has positive area.
    pub fn intersection(&self, other: &Bounds) -> Option<Bounds> {
        let common = self.clip(other);
        (common.max_x > common.min_x && common.max_y > common.min_y).then_some(common)
    }

    /// True when the two boxes share a region of positive area (each edge
    /// strictly inside the other box's span; for boxes with min < max this is
    /// `intersection(..).is_some()`).
    pub fn overlaps(&self, other: &Bounds) -> bool {
        self.min_x < other.max_x
            && other.min_x < self.max_x
            && self.min_y < other.max_y
            && other.min_y < self.max_y
    }

    /// The smallest box containing both.
    pub fn union(&self, other: &Bounds) -> Bounds {
        Bounds {
            min_x: self.min_x.min(other.min_x),
            min_y: self.min_y.min(other.min_y),
            max_x: self.max_x.max(other.max_x),
            max_y: self.max_y.max(other.max_y),
        }
    }

    /// The union of all boxes; None for none.
    pub fn union_all(boxes: impl IntoIterator<Item = Bounds>) -> Option<Bounds> {
        boxes.into_iter().reduce(|acc, b| acc.union(&b))
    }
}

impl From<[f64; 4]> for Bounds {
    fn from(b: [f64; 4]) -> Self {
        Bounds {
            min_x: b[0],
            min_y: b[1],
            max_x: b[2],
            max_y: b[3],
        }
    }
}

impl From<Bounds> for [f64; 4] {
    fn from(b: Bounds) -> Self {
        b.to_array()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intersection_union_and_overlap() {
        let a = Bounds::from([0.0, 0.0, 10.0, 4.0]);
        let b = Bounds::from_corners((12.0, 6.0), (6.0, 2.0));
        assert_eq!(b.to_array(), [6.0, 2.0, 12.0, 6.0]);
        assert_eq!(
            a.intersection(&b).unwrap().to_array(),
            [6.0, 2.0, 10.0, 4.0]
        );
        assert_eq!(a.union(&b).to_array(), [0.0, 0.0, 12.0, 6.0]);
        assert!(a.overlaps(&b));
        // touching edges share no area
        let c = Bounds::from([10.0, 0.0, 20.0, 4.0]);
        assert!(a.intersection(&c).is_none() && !a.overlaps(&c));
        assert_eq!(a.clip(&c).to_array(), [10.0, 0.0, 10.0, 4.0]);
        assert_eq!(
            Bounds::union_all([a, b, c]).unwrap().to_array(),
            [0.0, 0.0, 20.0, 6.0]
        );
        assert!(Bounds::union_all([]).is_none());
    }

    #[test]
    fn measures_and_serde_as_array() {
        let a = Bounds::from([2.0, 1.0, 8.0, 9.0]);
        assert_eq!((a.width(), a.height(), a.centre()), (6.0, 8.0, (5.0, 5.0)));
        assert_eq!(a.half_diagonal(), 5.0);
        let text = serde_json::to_string(&a).unwrap();
        assert_eq!(text, "[2.0,1.0,8.0,9.0]");
        assert_eq!(serde_json::from_str::<Bounds>(&text).unwrap(), a);
    }
}
