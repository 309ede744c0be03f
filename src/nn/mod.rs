//! Exact nearest-neighbour search on a DSM grid (the paper's bound, made exact
//! and early-terminating).
//!
//! A DSM is a height field: the reference points are the pixel centres
//! (x_c, y_r, h_cr). For a query q, the pixel right below it gives a distance d
//! that bounds the true nearest neighbour, so only pixels within d horizontally
//! can be nearer (Xu & Qin 2024, Sec. 3.1). We visit square rings around that
//! pixel outward and stop as soon as the nearest possible point of the next ring
//! is farther than the best distance found, which is usually ring 1 or 2. A
//! no-data pixel below the query gives no bound; the rings then run until a valid
//! pixel bounds them or the radius cap (`max_radius_m`) is reached. The result is
//! exactly the brute-force nearest neighbour within the cap.
//!
//! Files: [`frame`] (local metres <-> pixel lattice), [`search`] (the ring
//! search), [`surface`] (the bilinear surface below a query and its tangent
//! plane, grid normals), `plane` (the robust window plane fit both use),
//! [`planes`] (ring planes kept across a pair's runs), [`window`] (a block's
//! share of the reference, copied once for its searches).

pub mod frame;
mod plane;
pub mod planes;
pub mod search;
pub mod surface;
pub mod window;

pub use frame::PixelFrame;
pub use planes::{PlaneTable, WithPlanes};
pub use search::{nearest, nearest_or_within, within_below, Neighbour, NnStats};
pub use surface::{
    normal_at, surface_below, surface_below_memo, PlaneMemo, SurfacePoint, NORMAL_RADIUS_PX,
};
pub use window::Window;
