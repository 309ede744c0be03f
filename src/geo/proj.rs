//! The projected CRSs other than UTM that national and polar DSM collections
//! come in, so that a DSM in longitude and latitude, or in another of these
//! CRSs on the same datum, can be put into a collection's CRS as it is read.
//!
//! [`ProjectedCrs::from_epsg`] knows the UTM zones ([`Utm`]) and a table of
//! others by EPSG code ([`TABLE`]): the polar stereographic CRSs of ArcticDEM,
//! REMA and the NSIDC grids, UPS, Lambert-93, the European LCC and LAEA grids,
//! the US Albers grids, SWEREF99 TM and TM35FIN. Each is one of five methods,
//! with the formulas of EPSG Guidance Note 7-2 (IOGP 373-7-2, 2019) on the
//! ellipsoid; the inverses find the latitude from the conformal (or
//! authalic) quantity by iteration to 1e-14 rad, not by the guidance note's
//! truncated series. The unit tests hold each CRS to PROJ 9.5's answers.
//!
//! Datums: RGF93 (Lambert-93) and SWEREF99 are realisations of ETRS89 and are
//! counted as ETRS89, as PROJ does (a null transformation between them).

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

use super::tm::{Datum, Ellipsoid, TransverseMercator, Utm};

/// A map projection of the ellipsoid: (longitude, latitude) in degrees to
/// (easting, northing) in metres and back.
#[derive(Clone, Debug)]
pub enum Projection {
    TransverseMercator(TransverseMercator),
    PolarStereographic(PolarStereographic),
    LambertConic(LambertConic),
    Albers(Albers),
    LambertAzimuthal(LambertAzimuthal),
}

impl Projection {
    /// (easting, northing) in metres of (longitude, latitude) in degrees.
    pub fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        match self {
            Projection::TransverseMercator(p) => p.forward(lon_deg, lat_deg),
            Projection::PolarStereographic(p) => p.forward(lon_deg, lat_deg),
            Projection::LambertConic(p) => p.forward(lon_deg, lat_deg),
            Projection::Albers(p) => p.forward(lon_deg, lat_deg),
            Projection::LambertAzimuthal(p) => p.forward(lon_deg, lat_deg),
        }
    }

    /// (longitude, latitude) in degrees of (easting, northing) in metres.
    pub fn inverse(&self, easting: f64, northing: f64) -> (f64, f64) {
        match self {
            Projection::TransverseMercator(p) => p.inverse(easting, northing),
            Projection::PolarStereographic(p) => p.inverse(easting, northing),
            Projection::LambertConic(p) => p.inverse(easting, northing),
            Projection::Albers(p) => p.inverse(easting, northing),
            Projection::LambertAzimuthal(p) => p.inverse(easting, northing),
        }
    }

    /// The largest relative difference between a metre on the map and a
    /// metre on the ellipsoid at a point, along the meridian and along the
    /// parallel (the scale error: 0 on a standard line; 0.0354 for UTM at 15
    /// degrees of longitude from its meridian on the equator).
    pub fn scale_error(&self, ellipsoid: Ellipsoid, lon_deg: f64, lat_deg: f64) -> f64 {
        const STEP: f64 = 1e-5;
        let (per_lon, per_lat) = ellipsoid.metres_per_degree(lat_deg);
        let length = |(a, b): (f64, f64), (c, d): (f64, f64)| (c - a).hypot(d - b);
        let along_parallel = length(
            self.forward(lon_deg - STEP, lat_deg),
            self.forward(lon_deg + STEP, lat_deg),
        ) / (2.0 * STEP * per_lon);
        let along_meridian = length(
            self.forward(lon_deg, lat_deg - STEP),
            self.forward(lon_deg, lat_deg + STEP),
        ) / (2.0 * STEP * per_lat);
        (along_parallel - 1.0)
            .abs()
            .max((along_meridian - 1.0).abs())
    }
}

/// A projected CRS in metres that DSMs can be put into: its EPSG code, datum,
/// name and projection; `utm` for the UTM zones.
#[derive(Clone, Debug)]
pub struct ProjectedCrs {
    /// `None` for a UTM zone EPSG does not define (NAD83 south, say).
    pub epsg: Option<u32>,
    pub datum: Datum,
    pub name: String,
    pub projection: Projection,
    pub utm: Option<Utm>,
}

impl PartialEq for ProjectedCrs {
    fn eq(&self, other: &ProjectedCrs) -> bool {
        (self.epsg, self.datum, &self.name, self.utm)
            == (other.epsg, other.datum, &other.name, other.utm)
    }
}

impl ProjectedCrs {
    /// The CRS an EPSG code names, when it is a UTM zone or in [`TABLE`].
    pub fn from_epsg(code: u32) -> Option<ProjectedCrs> {
        if let Some(utm) = Utm::from_epsg(code) {
            return Some(ProjectedCrs::utm(utm));
        }
        let entry = TABLE.iter().find(|e| e.epsg == code)?;
        let ellipsoid = entry.datum.ellipsoid();
        let projection = match entry.method {
            Method::PolarStereographicA { north, k0, fe, fn_ } => Projection::PolarStereographic(
                PolarStereographic::with_scale(ellipsoid, north, entry.lon0, k0, fe, fn_),
            ),
            Method::PolarStereographicB { lat_ts } => Projection::PolarStereographic(
                PolarStereographic::with_standard_parallel(ellipsoid, lat_ts, entry.lon0),
            ),
            Method::LambertConic {
                lat0,
                lat1,
                lat2,
                fe,
                fn_,
            } => Projection::LambertConic(LambertConic::new(
                ellipsoid,
                lat0,
                entry.lon0,
                [lat1, lat2],
                fe,
                fn_,
            )),
            Method::Albers {
                lat0,
                lat1,
                lat2,
                fe,
                fn_,
            } => Projection::Albers(Albers::new(
                ellipsoid,
                lat0,
                entry.lon0,
                [lat1, lat2],
                fe,
                fn_,
            )),
            Method::LambertAzimuthal { lat0, fe, fn_ } => Projection::LambertAzimuthal(
                LambertAzimuthal::new(ellipsoid, lat0, entry.lon0, fe, fn_),
            ),
            Method::TransverseMercator { k0, fe } => Projection::TransverseMercator(
                TransverseMercator::new(ellipsoid, entry.lon0, k0, fe, 0.0),
            ),
        };
        Some(ProjectedCrs {
            epsg: Some(code),
            datum: entry.datum,
            name: entry.name.to_string(),
            projection,
            utm: None,
        })
    }

    pub fn utm(utm: Utm) -> ProjectedCrs {
        ProjectedCrs {
            epsg: utm.epsg(),
            datum: utm.datum,
            name: utm.label(),
            projection: Projection::TransverseMercator(utm.projection()),
            utm: Some(utm),
        }
    }

    /// "EPSG:3413, WGS 84 / NSIDC Sea Ice Polar Stereographic North"; "UTM
    /// 37N (WGS 84)" for a zone without a code.
    pub fn label(&self) -> String {
        match self.epsg {
            Some(code) => format!("EPSG:{code}, {}", self.name),
            None => self.name.clone(),
        }
    }
}

/// The code of the grid of [`TABLE`] that a method and its parameters define,
/// as a WKT without a code names them (ESRI's and GDAL's WKT 1 names, lower
/// case with underscores: "stereographic_north_pole", "standard_parallel_1");
/// `None` when none matches within 1e-9. The caller has checked that the
/// datum is WGS 84, NAD83 or ETRS89, which count as one here.
pub fn identify(method: &str, params: &[(String, f64)]) -> Option<u32> {
    // WKT 2's "polar_stereographic_(variant_b)", "lambert_conic_conformal_(2sp)"
    let method = method.replace(['(', ')'], "");
    let method = method.as_str();
    let get = |names: &[&str]| {
        (params.iter())
            .find(|(n, _)| names.contains(&n.as_str()))
            .map(|p| p.1)
    };
    let lon0 = get(&[
        "central_meridian",
        "longitude_of_origin",
        "longitude_of_center",
        "longitude_of_natural_origin",
        "longitude_of_false_origin",
    ]);
    let lat0 = get(&[
        "latitude_of_origin",
        "latitude_of_center",
        "latitude_of_natural_origin",
        "latitude_of_false_origin",
    ]);
    let sp = [
        get(&[
            "standard_parallel_1",
            "latitude_of_1st_standard_parallel",
            "latitude_of_standard_parallel",
        ]),
        get(&["standard_parallel_2", "latitude_of_2nd_standard_parallel"]),
    ];
    let k0 = get(&["scale_factor", "scale_factor_at_natural_origin"]).unwrap_or(1.0);
    let false_origin = (
        get(&["false_easting", "easting_at_false_origin"]).unwrap_or(0.0),
        get(&["false_northing", "northing_at_false_origin"]).unwrap_or(0.0),
    );
    let near = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() <= 1e-9 * b.abs().max(1.0));
    let at = |fe: f64, fn_: f64| near(Some(false_origin.0), fe) && near(Some(false_origin.1), fn_);
    let parallels = |lat1: f64, lat2: f64| {
        (near(sp[0], lat1) && near(sp[1], lat2)) || (near(sp[0], lat2) && near(sp[1], lat1))
    };
    let stereographic = matches!(
        method,
        "stereographic_north_pole"
            | "stereographic_south_pole"
            | "polar_stereographic"
            | "polar_stereographic_variant_a"
            | "polar_stereographic_variant_b"
            | "stereographic"
    );
    let found = TABLE.iter().find(|e| {
        near(lon0, e.lon0)
            && match e.method {
                Method::PolarStereographicB { lat_ts } => {
                    stereographic
                        && at(0.0, 0.0)
                        && near(Some(k0), 1.0)
                        && (near(sp[0], lat_ts) || (sp[0].is_none() && near(lat0, lat_ts)))
                }
                Method::PolarStereographicA {
                    north,
                    k0: k,
                    fe,
                    fn_,
                } => {
                    stereographic
                        && at(fe, fn_)
                        && near(Some(k0), k)
                        && near(lat0, if north { 90.0 } else { -90.0 })
                }
                Method::LambertConic {
                    lat0: l,
                    lat1,
                    lat2,
                    fe,
                    fn_,
                } => {
                    (method.starts_with("lambert_conformal_conic")
                        || method.starts_with("lambert_conic_conformal"))
                        && at(fe, fn_)
                        && near(lat0, l)
                        && parallels(lat1, lat2)
                }
                Method::Albers {
                    lat0: l,
                    lat1,
                    lat2,
                    fe,
                    fn_,
                } => {
                    method.starts_with("albers")
                        && at(fe, fn_)
                        && near(lat0, l)
                        && parallels(lat1, lat2)
                }
                Method::LambertAzimuthal { lat0: l, fe, fn_ } => {
                    method == "lambert_azimuthal_equal_area" && at(fe, fn_) && near(lat0, l)
                }
                Method::TransverseMercator { k0: k, fe } => {
                    method == "transverse_mercator"
                        && at(fe, 0.0)
                        && near(Some(k0), k)
                        && near(Some(lat0.unwrap_or(0.0)), 0.0)
                }
            }
    });
    found.map(|e| e.epsg)
}

/// A CRS of [`TABLE`]: code, name, datum, longitude of origin and method.
struct Entry {
    epsg: u32,
    name: &'static str,
    datum: Datum,
    lon0: f64,
    method: Method,
}

/// A method and its parameters (degrees and metres).
enum Method {
    PolarStereographicA {
        north: bool,
        k0: f64,
        fe: f64,
        fn_: f64,
    },
    PolarStereographicB {
        lat_ts: f64,
    },
    LambertConic {
        lat0: f64,
        lat1: f64,
        lat2: f64,
        fe: f64,
        fn_: f64,
    },
    Albers {
        lat0: f64,
        lat1: f64,
        lat2: f64,
        fe: f64,
        fn_: f64,
    },
    LambertAzimuthal {
        lat0: f64,
        fe: f64,
        fn_: f64,
    },
    TransverseMercator {
        k0: f64,
        fe: f64,
    },
}

const fn entry(epsg: u32, name: &'static str, datum: Datum, lon0: f64, method: Method) -> Entry {
    Entry {
        epsg,
        name,
        datum,
        lon0,
        method,
    }
}

/// A universal polar stereographic CRS's method.
const fn ups(north: bool) -> Method {
    Method::PolarStereographicA {
        north,
        k0: 0.994,
        fe: 2_000_000.0,
        fn_: 2_000_000.0,
    }
}

/// The projected CRSs besides UTM, with EPSG's parameters (v11.022), one per
/// line.
#[rustfmt::skip]
const TABLE: [Entry; 19] = {
    use Datum::{Etrs89, Nad83, Wgs84};
    use Method::*;
    [
        entry(3413, "WGS 84 / NSIDC Sea Ice Polar Stereographic North", Wgs84, -45.0, PolarStereographicB { lat_ts: 70.0 }),
        entry(3976, "WGS 84 / NSIDC Sea Ice Polar Stereographic South", Wgs84, 0.0, PolarStereographicB { lat_ts: -70.0 }),
        entry(3031, "WGS 84 / Antarctic Polar Stereographic", Wgs84, 0.0, PolarStereographicB { lat_ts: -71.0 }),
        entry(3995, "WGS 84 / Arctic Polar Stereographic", Wgs84, 0.0, PolarStereographicB { lat_ts: 71.0 }),
        entry(5041, "WGS 84 / UPS North (E,N)", Wgs84, 0.0, ups(true)),
        entry(5042, "WGS 84 / UPS South (E,N)", Wgs84, 0.0, ups(false)),
        entry(32661, "WGS 84 / UPS North (N,E)", Wgs84, 0.0, ups(true)),
        entry(32761, "WGS 84 / UPS South (N,E)", Wgs84, 0.0, ups(false)),
        entry(3571, "WGS 84 / North Pole LAEA Bering Sea", Wgs84, 180.0, LambertAzimuthal { lat0: 90.0, fe: 0.0, fn_: 0.0 }),
        entry(3573, "WGS 84 / North Pole LAEA Canada", Wgs84, -100.0, LambertAzimuthal { lat0: 90.0, fe: 0.0, fn_: 0.0 }),
        entry(6931, "WGS 84 / NSIDC EASE-Grid 2.0 North", Wgs84, 0.0, LambertAzimuthal { lat0: 90.0, fe: 0.0, fn_: 0.0 }),
        entry(6932, "WGS 84 / NSIDC EASE-Grid 2.0 South", Wgs84, 0.0, LambertAzimuthal { lat0: -90.0, fe: 0.0, fn_: 0.0 }),
        entry(2154, "RGF93 v1 / Lambert-93", Etrs89, 3.0, LambertConic { lat0: 46.5, lat1: 49.0, lat2: 44.0, fe: 700_000.0, fn_: 6_600_000.0 }),
        entry(3034, "ETRS89-extended / LCC Europe", Etrs89, 10.0, LambertConic { lat0: 52.0, lat1: 35.0, lat2: 65.0, fe: 4_000_000.0, fn_: 2_800_000.0 }),
        entry(3035, "ETRS89-extended / LAEA Europe", Etrs89, 10.0, LambertAzimuthal { lat0: 52.0, fe: 4_321_000.0, fn_: 3_210_000.0 }),
        entry(3006, "SWEREF99 TM", Etrs89, 15.0, TransverseMercator { k0: 0.9996, fe: 500_000.0 }),
        entry(3067, "ETRS89 / TM35FIN(E,N)", Etrs89, 27.0, TransverseMercator { k0: 0.9996, fe: 500_000.0 }),
        entry(5070, "NAD83 / Conus Albers", Nad83, -96.0, Albers { lat0: 23.0, lat1: 29.5, lat2: 45.5, fe: 0.0, fn_: 0.0 }),
        entry(3338, "NAD83 / Alaska Albers", Nad83, -154.0, Albers { lat0: 50.0, lat1: 55.0, lat2: 65.0, fe: 0.0, fn_: 0.0 }),
    ]
};

/// The quantities of an ellipsoid the methods share.
#[derive(Clone, Copy, Debug)]
struct Shape {
    a: f64,
    e: f64,
    e2: f64,
}

impl Shape {
    fn of(ellipsoid: Ellipsoid) -> Shape {
        let e2 = ellipsoid.f * (2.0 - ellipsoid.f);
        Shape {
            a: ellipsoid.a,
            e: e2.sqrt(),
            e2,
        }
    }

    /// m = cos(phi) / sqrt(1 - e^2 sin^2(phi)).
    fn m(&self, phi: f64) -> f64 {
        phi.cos() / (1.0 - self.e2 * phi.sin().powi(2)).sqrt()
    }

    /// t = tan(pi/4 - phi/2) / ((1 - e sin(phi)) / (1 + e sin(phi)))^(e/2).
    fn t(&self, phi: f64) -> f64 {
        let es = self.e * phi.sin();
        (FRAC_PI_4 - phi / 2.0).tan() / ((1.0 - es) / (1.0 + es)).powf(self.e / 2.0)
    }

    /// The latitude whose `t` is `t` (fixed point, to 1e-14 rad).
    fn phi_of_t(&self, t: f64) -> f64 {
        let mut phi = FRAC_PI_2 - 2.0 * t.atan();
        for _ in 0..30 {
            let es = self.e * phi.sin();
            let next = FRAC_PI_2 - 2.0 * (t * ((1.0 - es) / (1.0 + es)).powf(self.e / 2.0)).atan();
            let done = (next - phi).abs() < 1e-14;
            phi = next;
            if done {
                break;
            }
        }
        phi
    }

    /// The authalic q (EPSG's alpha without the factor): q(phi) = (1 - e^2)
    /// [sin(phi) / (1 - e^2 sin^2(phi)) - ln((1 - e sin(phi)) / (1 + e
    /// sin(phi))) / (2e)].
    fn q(&self, phi: f64) -> f64 {
        let s = phi.sin();
        let es = self.e * s;
        (1.0 - self.e2) * (s / (1.0 - es * es) - ((1.0 - es) / (1.0 + es)).ln() / (2.0 * self.e))
    }

    /// The latitude whose `q` is `q` (Snyder 3-16, Newton's method).
    fn phi_of_q(&self, q: f64) -> f64 {
        let q_pole = self.q(FRAC_PI_2);
        if q.abs() >= q_pole {
            return FRAC_PI_2.copysign(q);
        }
        let mut phi = (q / 2.0).clamp(-1.0, 1.0).asin();
        for _ in 0..30 {
            let s = phi.sin();
            let es = self.e * s;
            let w = 1.0 - es * es;
            let step = w * w / (2.0 * phi.cos())
                * (q / (1.0 - self.e2) - s / w + ((1.0 - es) / (1.0 + es)).ln() / (2.0 * self.e));
            phi += step;
            if step.abs() < 1e-14 {
                break;
            }
        }
        phi
    }
}

/// Longitude difference from `lon0`, radians, within (-pi, pi].
fn lambda(lon_deg: f64, lon0_deg: f64) -> f64 {
    ((lon_deg - lon0_deg + 540.0).rem_euclid(360.0) - 180.0).to_radians()
}

/// Longitude in degrees of `lon0` plus `lambda` radians, within -180..180.
fn longitude(lon0_deg: f64, lambda: f64) -> f64 {
    (lon0_deg + lambda.to_degrees() + 540.0).rem_euclid(360.0) - 180.0
}

/// Polar stereographic, north or south (EPSG 9810 variant A: scale at the
/// pole; 9829 variant B: true scale on a standard parallel).
#[derive(Clone, Debug)]
pub struct PolarStereographic {
    shape: Shape,
    /// +1 about the north pole, -1 about the south.
    sign: f64,
    lon0: f64,
    /// rho = radius * t.
    radius: f64,
    fe: f64,
    fn_: f64,
}

impl PolarStereographic {
    fn with_scale(
        ellipsoid: Ellipsoid,
        north: bool,
        lon0: f64,
        k0: f64,
        fe: f64,
        fn_: f64,
    ) -> PolarStereographic {
        let s = Shape::of(ellipsoid);
        let radius =
            2.0 * s.a * k0 / ((1.0 + s.e).powf(1.0 + s.e) * (1.0 - s.e).powf(1.0 - s.e)).sqrt();
        PolarStereographic {
            shape: s,
            sign: if north { 1.0 } else { -1.0 },
            lon0,
            radius,
            fe,
            fn_,
        }
    }

    fn with_standard_parallel(ellipsoid: Ellipsoid, lat_ts: f64, lon0: f64) -> PolarStereographic {
        let s = Shape::of(ellipsoid);
        let sign = lat_ts.signum();
        let phi_f = (sign * lat_ts).to_radians();
        // rho at the standard parallel is a m_F, so radius = a m_F / t_F
        let radius = s.a * s.m(phi_f) / s.t(phi_f);
        PolarStereographic {
            shape: s,
            sign,
            lon0,
            radius,
            fe: 0.0,
            fn_: 0.0,
        }
    }

    pub fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        let rho = self.radius * self.shape.t(self.sign * lat_deg.to_radians());
        let l = lambda(lon_deg, self.lon0);
        (
            self.fe + rho * l.sin(),
            self.fn_ - self.sign * rho * l.cos(),
        )
    }

    pub fn inverse(&self, easting: f64, northing: f64) -> (f64, f64) {
        let (x, y) = (easting - self.fe, northing - self.fn_);
        let phi = self.shape.phi_of_t(x.hypot(y) / self.radius);
        let l = x.atan2(-self.sign * y);
        (longitude(self.lon0, l), (self.sign * phi).to_degrees())
    }
}

/// Lambert Conic Conformal with two standard parallels (EPSG 9802).
#[derive(Clone, Debug)]
pub struct LambertConic {
    shape: Shape,
    lon0: f64,
    n: f64,
    /// a F.
    af: f64,
    /// r at the false origin.
    r0: f64,
    fe: f64,
    fn_: f64,
}

impl LambertConic {
    fn new(
        ellipsoid: Ellipsoid,
        lat0: f64,
        lon0: f64,
        [lat1, lat2]: [f64; 2],
        fe: f64,
        fn_: f64,
    ) -> LambertConic {
        let s = Shape::of(ellipsoid);
        let (p1, p2) = (lat1.to_radians(), lat2.to_radians());
        let n = (s.m(p1).ln() - s.m(p2).ln()) / (s.t(p1).ln() - s.t(p2).ln());
        let af = s.a * s.m(p1) / (n * s.t(p1).powf(n));
        let r0 = af * s.t(lat0.to_radians()).powf(n);
        LambertConic {
            shape: s,
            lon0,
            n,
            af,
            r0,
            fe,
            fn_,
        }
    }

    pub fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        let r = self.af * self.shape.t(lat_deg.to_radians()).powf(self.n);
        let theta = self.n * lambda(lon_deg, self.lon0);
        (
            self.fe + r * theta.sin(),
            self.fn_ + self.r0 - r * theta.cos(),
        )
    }

    pub fn inverse(&self, easting: f64, northing: f64) -> (f64, f64) {
        let (x, y) = (easting - self.fe, self.r0 - (northing - self.fn_));
        let sign = self.n.signum();
        let r = sign * x.hypot(y);
        let theta = (sign * x).atan2(sign * y);
        let phi = self.shape.phi_of_t((r / self.af).powf(1.0 / self.n));
        (longitude(self.lon0, theta / self.n), phi.to_degrees())
    }
}

/// Albers Equal Area (EPSG 9822).
#[derive(Clone, Debug)]
pub struct Albers {
    shape: Shape,
    lon0: f64,
    n: f64,
    c: f64,
    rho0: f64,
    fe: f64,
    fn_: f64,
}

impl Albers {
    fn new(
        ellipsoid: Ellipsoid,
        lat0: f64,
        lon0: f64,
        [lat1, lat2]: [f64; 2],
        fe: f64,
        fn_: f64,
    ) -> Albers {
        let s = Shape::of(ellipsoid);
        let (p1, p2) = (lat1.to_radians(), lat2.to_radians());
        let (m1, m2) = (s.m(p1), s.m(p2));
        let n = (m1 * m1 - m2 * m2) / (s.q(p2) - s.q(p1));
        let c = m1 * m1 + n * s.q(p1);
        let rho0 = s.a * (c - n * s.q(lat0.to_radians())).sqrt() / n;
        Albers {
            shape: s,
            lon0,
            n,
            c,
            rho0,
            fe,
            fn_,
        }
    }

    pub fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        let rho =
            self.shape.a * (self.c - self.n * self.shape.q(lat_deg.to_radians())).sqrt() / self.n;
        let theta = self.n * lambda(lon_deg, self.lon0);
        (
            self.fe + rho * theta.sin(),
            self.fn_ + self.rho0 - rho * theta.cos(),
        )
    }

    pub fn inverse(&self, easting: f64, northing: f64) -> (f64, f64) {
        let (x, y) = (easting - self.fe, self.rho0 - (northing - self.fn_));
        let sign = self.n.signum();
        let rho = x.hypot(y);
        let theta = (sign * x).atan2(sign * y);
        let a = self.shape.a;
        let q = (self.c - rho * rho * self.n * self.n / (a * a)) / self.n;
        let phi = self.shape.phi_of_q(q);
        (longitude(self.lon0, theta / self.n), phi.to_degrees())
    }
}

/// Lambert Azimuthal Equal Area (EPSG 9820), oblique or polar.
#[derive(Clone, Debug)]
pub struct LambertAzimuthal {
    shape: Shape,
    lon0: f64,
    /// `Some(+1 / -1)` for the north / south polar aspect.
    pole: Option<f64>,
    q_pole: f64,
    /// Rq, D and beta0 of the oblique aspect.
    rq: f64,
    d: f64,
    beta0: f64,
    fe: f64,
    fn_: f64,
}

impl LambertAzimuthal {
    fn new(ellipsoid: Ellipsoid, lat0: f64, lon0: f64, fe: f64, fn_: f64) -> LambertAzimuthal {
        let s = Shape::of(ellipsoid);
        let q_pole = s.q(FRAC_PI_2);
        let phi0 = lat0.to_radians();
        let beta0 = (s.q(phi0) / q_pole).clamp(-1.0, 1.0).asin();
        let rq = s.a * (q_pole / 2.0).sqrt();
        let d = s.a * s.m(phi0) / (rq * beta0.cos());
        let pole = (lat0.abs() == 90.0).then(|| lat0.signum());
        LambertAzimuthal {
            shape: s,
            lon0,
            pole,
            q_pole,
            rq,
            d,
            beta0,
            fe,
            fn_,
        }
    }

    pub fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        let l = lambda(lon_deg, self.lon0);
        let q = self.shape.q(lat_deg.to_radians());
        if let Some(sign) = self.pole {
            let rho = self.shape.a * (self.q_pole - sign * q).max(0.0).sqrt();
            return (self.fe + rho * l.sin(), self.fn_ - sign * rho * l.cos());
        }
        let beta = (q / self.q_pole).clamp(-1.0, 1.0).asin();
        let (sb0, cb0) = self.beta0.sin_cos();
        let b = self.rq * (2.0 / (1.0 + sb0 * beta.sin() + cb0 * beta.cos() * l.cos())).sqrt();
        (
            self.fe + b * self.d * beta.cos() * l.sin(),
            self.fn_ + b / self.d * (cb0 * beta.sin() - sb0 * beta.cos() * l.cos()),
        )
    }

    pub fn inverse(&self, easting: f64, northing: f64) -> (f64, f64) {
        let (x, y) = (easting - self.fe, northing - self.fn_);
        let a = self.shape.a;
        if let Some(sign) = self.pole {
            let rho = x.hypot(y);
            let q = sign * (self.q_pole - rho * rho / (a * a));
            let l = x.atan2(-sign * y);
            return (longitude(self.lon0, l), self.shape.phi_of_q(q).to_degrees());
        }
        let rho = (x / self.d).hypot(self.d * y);
        if rho == 0.0 {
            let phi = self.shape.phi_of_q(self.q_pole * self.beta0.sin());
            return (self.lon0, phi.to_degrees());
        }
        let c = 2.0 * (rho / (2.0 * self.rq)).clamp(-1.0, 1.0).asin();
        let (sb0, cb0) = self.beta0.sin_cos();
        let (sc, cc) = c.sin_cos();
        let beta = (cc * sb0 + self.d * y * sc * cb0 / rho)
            .clamp(-1.0, 1.0)
            .asin();
        let l = (x * sc).atan2(self.d * rho * cb0 * cc - self.d * self.d * y * sb0 * sc);
        let phi = self.shape.phi_of_q(self.q_pole * beta.sin());
        (longitude(self.lon0, l), phi.to_degrees())
    }
}

#[cfg(test)]
mod tests;
